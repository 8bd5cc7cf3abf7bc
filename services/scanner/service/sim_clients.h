#pragma once

#include <Eigen/Geometry>

#include <memory>
#include <mutex>
#include <string>

#include "libs/runtime/channel.h"
#include "picking/robot/v1/robot.grpc.pb.h"
#include "picking/simulator/v1/simulator.grpc.pb.h"
#include "services/scanner/core/sim_backends.h"

namespace picking::scanner {

/// How the simulator renders the scanner's images (picking.simulator.v1.RenderOptions).
struct SimRenderSettings {
  double ambient = 0.03;     ///< Ambient light relative to the projector's white.
  double noise_sigma = 1.0;  ///< Camera noise, grey levels.
  double gamma = 1.0;        ///< Camera response gamma.
  /// Shot noise: electrons per grey level (conversion gain of an 8-bit camera with a
  /// ~10,000 e- full well, as the paper's Flea3); 0 = read noise only.
  double electrons_per_dn = 40.0;
  /// Projector defocus: Gaussian blur of the projected image, sigma in projector pixels;
  /// 0 = perfectly sharp.
  double projector_blur_sigma_px = 0.6;
  double timeout_s = 30.0;  ///< Deadline of one RenderPatterns call, seconds.
};

/// PatternRenderer served by picking-simulator's RenderPatterns, plus the simulated arm's
/// pose from GetGroundTruth. An unreachable simulator or a call past its deadline throws
/// picking::UnavailableError naming the address; other refusals std::runtime_error with the
/// simulator's message.
class SimulatorClient final : public PatternRenderer {
 public:
  /// Over a channel from `channels` (plaintext or TLS); connects lazily.
  /// @throws std::invalid_argument for an empty address, a non-positive timeout or a
  ///   negative or non-finite noise or blur setting.
  SimulatorClient(const std::string& address, const SimRenderSettings& settings,
                  const runtime::ChannelFactory& channels);

  std::vector<GrayImage> Render(const PatternRenderRequest& request) override;
  /// Makes the following Render calls children of `parent` (nullptr: none): they end by its
  /// deadline and are cancelled with it, so a capture never outlives the call it serves, nor
  /// the server's shutdown (which cancels every call). Past the parent's deadline Render
  /// throws picking::TimeoutError, after its cancellation picking::CancelledError.
  void SetParentCall(const grpc::ServerContext* parent);
  /// The simulated arm's flange pose now, X_BaseTool (GetGroundTruth.X_base_tool; the camera
  /// is mounted on the flange, not on the suction cup). @throws picking::PreconditionError
  /// before the arm is placed.
  Eigen::Isometry3d ToolPose();

 private:
  std::string address_;
  SimRenderSettings settings_;
  std::unique_ptr<simulator::v1::SimulatorService::Stub> stub_;
  std::mutex parent_mutex_;
  const grpc::ServerContext* parent_ = nullptr;
};

/// The robot service's current flange pose (picking.robot.v1 GetState).
class RobotPoseClient final {
 public:
  /// Over a channel from `channels` (plaintext or TLS); connects lazily.
  /// @throws std::invalid_argument for an empty address or a non-positive timeout.
  RobotPoseClient(const std::string& address, double timeout_s,
                  const runtime::ChannelFactory& channels);
  /// Throws picking::UnavailableError when the robot service cannot be reached.
  Eigen::Isometry3d ToolPose();

 private:
  std::string address_;
  double timeout_s_;
  std::unique_ptr<robot::v1::RobotService::Stub> stub_;
};

}  // namespace picking::scanner
