#pragma once

#include <Eigen/Geometry>

#include <optional>
#include <string>
#include <vector>

#include "libs/world/mesh.h"
#include "libs/world/ray_scene.h"
#include "libs/world/suction_seal.h"

namespace picking::planner {

/// Options of ModelSeal.
struct ModelSealOptions {
  /// The cup's lip and what it seals on: the simulator's rule (world::MeasureSeal).
  world::SealOptions seal;
  /// How far the cup presses on past its first contact: the compliant cup's compression at
  /// the guarded move's force threshold (10 N on the cup's 2,000 N/m), metres.
  double press_m = 0.005;
  /// The cup's first contact is sought from this far behind the grasp pose to this far in
  /// front of it along the approach (the grasp lies on the item's box, its surface at or
  /// within it), metres.
  double probe_back_m = 0.03;
  double probe_ahead_m = 0.05;
  /// Where the cup does not seal at the grasp, the contact moves across the approach by each
  /// of these distances in turn, in `shift_directions` directions each (metres).
  std::vector<double> shift_m = {0.01, 0.02};
  int shift_directions = 8;
};

/// Where the cup seals on an item's model near a grasp.
struct ModelSealResult {
  bool sealed = false;
  /// The move of the grasp's contact across the approach (base frame) at which the cup seals;
  /// zero where it seals as planned.
  Eigen::Vector3d shift_Base = Eigen::Vector3d::Zero();
  world::SealMeasure measure;  ///< At the grasp as planned when no shift seals.
};

/// The suction test of a grasp against the item's own model: the cup runs along its approach
/// to the model's surface, presses on by `press_m` and must seal there (world::MeasureSeal:
/// one flat patch facing the cup under the whole lip). A scanned model's fuzz, a sphere's
/// curve or a face narrower than the lip fail it; a contact moved a little may pass. It sees
/// the item alone: a neighbour under a thin item's edge is the scan's business. Thread-safe
/// after construction.
class ModelSeal final {
 public:
  /// `mesh_Item`: the item's model in its item frame. Throws std::invalid_argument for an
  /// empty or invalid mesh or bad options.
  ModelSeal(const world::TriangleMesh& mesh_Item, const ModelSealOptions& options);

  /// Throws std::invalid_argument for bad options (the seal's, or press_m, probe_back_m < 0,
  /// probe_ahead_m <= 0, shift_directions < 1, a shift <= 0).
  static void Validate(const ModelSealOptions& options);

  /// The seal of a cup that comes along +z of X_BaseTcp (the grasp's tcp pose) onto the item
  /// at X_BaseItem.
  ModelSealResult Check(const Eigen::Isometry3d& X_BaseItem,
                        const Eigen::Isometry3d& X_BaseTcp) const;

 private:
  /// The seal with the lip at `X_ItemTcp` moved along its +z onto the model and pressed on;
  /// no measure when the cup meets nothing.
  std::optional<world::SealMeasure> PressAndMeasure(const Eigen::Isometry3d& X_ItemTcp) const;

  ModelSealOptions options_;
  world::RayScene scene_Item_;
};

}  // namespace picking::planner
