#pragma once

#include <memory>

#include "libs/runtime/config.h"
#include "libs/runtime/server.h"
#include "picking/simulator/v1/simulator.grpc.pb.h"
#include "services/simulator/core/arm_collision.h"
#include "services/simulator/core/sim_world.h"

namespace picking::simulator {

/// Options of the simulator service adapter.
struct SimulatorServiceOptions {
  /// Vacuum reported by SetSuction when the cup seals, and when it is on without a seal, kPa.
  double sealed_kpa = 25.0;
  double open_kpa = 3.0;
  /// Most patterns one RenderPatterns call may ask for.
  int max_patterns = 256;
  /// How LoadLayout (and the `layout` setting) lays items out: tidy or settled by physics.
  LayoutMode layout_mode = LayoutMode::kTidy;
  /// Throws std::invalid_argument naming the field: need 0 <= open_kpa < sealed_kpa, finite,
  /// and max_patterns > 0.
  void Validate() const;
};

/// The gRPC adapter of picking.simulator.v1.SimulatorService over a SimWorld. Every call
/// holds one mutex around the world, so calls are serialised; a refused request (any status
/// but OK) leaves the world unchanged. `collisions` checks the arm placed by SetArmJoints;
/// the world must have UR10 kinematics and the same gripper X_ToolTcp as
/// `collisions->gripper()` (both from one cell description).
/// RenderPatterns and RenderDepth share one scene renderer that is kept between calls (its
/// BVH and per-camera-model ray tables are reused; LoadLayout rebuilds it, moved items are
/// re-posed), so they are serialised with each other.
/// Throws std::invalid_argument for a null world or checker, different grippers or bad
/// options.
std::shared_ptr<v1::SimulatorService::Service> MakeSimulatorService(
    std::unique_ptr<SimWorld> world, std::unique_ptr<ArmCollisionChecker> collisions,
    const SimulatorServiceOptions& options = {});

/// Builds the simulator server's services from its settings (see docs/services.md):
/// data_dir, cell (the cell description, with the gripper's tool centre point), layout, seed,
/// tool.cup_radius_m, contact.stiffness_n_per_m, suction.sealed_kpa, suction.open_kpa. Throws
/// std::invalid_argument for a bad setting, cell description or layout file,
/// std::runtime_error when the cell's meshes or the UR10 model cannot be read.
runtime::ServiceSet BuildSimulatorServices(const runtime::Config& config);

}  // namespace picking::simulator
