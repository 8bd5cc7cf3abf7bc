#include "services/gripper/service/sim_gripper.h"

#include <grpcpp/client_context.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>

#include "libs/errors/errors.h"
#include "libs/proto_convert/proto_convert.h"
#include "services/gripper/core/keep_vertical.h"

namespace picking::gripper {
namespace {

namespace sim = ::picking::simulator::v1;

void SetDeadline(grpc::ClientContext* ctx, double timeout_s) {
  ctx->set_deadline(std::chrono::system_clock::now() +
                    std::chrono::duration_cast<std::chrono::system_clock::duration>(
                        std::chrono::duration<double>(timeout_s)));
}

// The simulator's answer as an error a caller can act on.
void Check(const grpc::Status& status, const std::string& address, const char* rpc) {
  if (status.ok()) return;
  const std::string message = std::string("simulator at ") + address + ": " + rpc + " failed (" +
                              std::to_string(static_cast<int>(status.error_code())) +
                              "): " + status.error_message();
  if (status.error_code() == grpc::StatusCode::FAILED_PRECONDITION) {
    throw PreconditionError(message);
  }
  if (status.error_code() == grpc::StatusCode::INVALID_ARGUMENT) {
    // The simulated cell's gripper has no joint, or a smaller range than this gripper's.
    throw PreconditionError(message);
  }
  throw UnavailableError(message);
}

}  // namespace

SimGripper::SimGripper(std::unique_ptr<sim::SimulatorService::StubInterface> stub,
                       std::string address, const SimGripperOptions& options)
    : stub_(std::move(stub)), address_(std::move(address)), options_(options) {
  if (!stub_) throw std::invalid_argument("SimGripper: null simulator stub");
  if (!(options.timeout_s > 0.0) || !std::isfinite(options.timeout_s)) {
    throw std::invalid_argument("sim.timeout_s must be > 0");
  }
  if (!(options.sealed_kpa > options.open_kpa) || !(options.open_kpa >= 0.0)) {
    throw std::invalid_argument("sim gripper: need 0 <= open_kpa < sealed_kpa");
  }
  if (!(options.max_joint_angle_rad > 0.0)) {
    throw std::invalid_argument("sim gripper: max_joint_angle_rad must be > 0");
  }
}

std::unique_ptr<SimGripper> SimGripper::Connect(const std::string& address,
                                                const SimGripperOptions& options,
                                                const runtime::ChannelFactory& channels) {
  if (address.empty() || address.find(':') == std::string::npos) {
    throw std::invalid_argument("sim.address must be HOST:PORT, got '" + address + "'");
  }
  auto channel = channels.Connect(address);
  return std::make_unique<SimGripper>(sim::SimulatorService::NewStub(channel), address, options);
}

Eigen::Vector3d SimGripper::ToolGravity(sim::GetGroundTruthResponse* truth) {
  grpc::ClientContext ctx;
  SetDeadline(&ctx, options_.timeout_s);
  Check(stub_->GetGroundTruth(&ctx, sim::GetGroundTruthRequest(), truth), address_,
        "GetGroundTruth");
  Eigen::Isometry3d X_BaseTool = Eigen::Isometry3d::Identity();
  if (truth->has_x_base_tool()) {
    try {
      X_BaseTool = proto_convert::PoseFromProto(truth->x_base_tool(), "X_base_tool");
    } catch (const std::invalid_argument& e) {
      throw UnavailableError("simulator at " + address_ + " sent a bad tool pose: " + e.what());
    }
  }
  const Eigen::Vector3d g_base(0.0, 0.0, -kGravity_m_s2);
  return X_BaseTool.linear().transpose() * g_base;
}

double SimGripper::HangingAngle(const Eigen::Vector3d& g_tool) const {
  // A limp joint lets the head hang along gravity (within the joint's travel); with gravity
  // along the joint axis any angle is at rest, so the last one stays.
  if (std::hypot(g_tool.y(), g_tool.z()) < 1e-6) return angle_rad_;
  return std::clamp(VerticalJointAngle(g_tool), -options_.max_joint_angle_rad,
                    options_.max_joint_angle_rad);
}

double SimGripper::JointAngleLocked(const Eigen::Vector3d& g_tool) {
  if (options_.kind == GripperKind::kShelf) return 0.0;
  switch (mode_) {
    case JointMode::kFixed:
      angle_rad_ = fixed_angle_rad_;
      break;
    case JointMode::kKeepVertical:
      angle_rad_ = HangingAngle(g_tool);
      break;
    case JointMode::kUnactuated:
      if (!vacuum_on_) angle_rad_ = HangingAngle(g_tool);
      break;
  }
  return angle_rad_;
}

void SimGripper::SetVacuum(bool on) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (on && !vacuum_on_ && mode_ == JointMode::kUnactuated && options_.kind == GripperKind::kTote) {
    // Where the limp head hangs when the vacuum locks it.
    sim::GetGroundTruthResponse truth;
    JointAngleLocked(ToolGravity(&truth));
  }
  grpc::ClientContext ctx;
  SetDeadline(&ctx, options_.timeout_s);
  sim::SetSuctionRequest request;
  request.set_on(on);
  sim::SetSuctionResponse response;
  Check(stub_->SetSuction(&ctx, request, &response), address_, "SetSuction");
  vacuum_on_ = on;
  if (!on) {
    vacuum_kpa_ = 0.0;
    sealed_on_item_ = false;
    return;
  }
  vacuum_kpa_ = response.vacuum_kpa() > 0.0
                    ? response.vacuum_kpa()
                    : (response.sealed() ? options_.sealed_kpa : options_.open_kpa);
  sealed_on_item_ = response.sealed() && !response.attached_item().name().empty();
}

GripperReading SimGripper::Read() {
  std::lock_guard<std::mutex> lock(mutex_);
  sim::GetGroundTruthResponse truth;
  const Eigen::Vector3d g_tool = ToolGravity(&truth);
  if (sealed_on_item_ && truth.attached_item().name().empty()) {
    // The item came off (dropped, knocked off): the cup is open now.
    sealed_on_item_ = false;
    vacuum_kpa_ = std::min(vacuum_kpa_, options_.open_kpa);
  }
  GripperReading r;
  r.vacuum_on = vacuum_on_;
  r.vacuum_kpa = vacuum_kpa_;
  r.joint_mode = mode_;
  r.joint_angle_rad = JointAngleLocked(g_tool);
  // The simulated head follows a keep-vertical or limp joint when the gripper is read.
  if (options_.kind == GripperKind::kTote) {
    PushHeadLocked(r.joint_angle_rad, truth.gripper_head_angle_rad(), /*required=*/false);
  }
  r.gravity_head_m_s2 = GravityInHead(g_tool, r.joint_angle_rad);
  return r;
}

void SimGripper::SetJointMode(JointMode mode, double angle_rad) {
  if (options_.kind == GripperKind::kShelf) {
    throw PreconditionError("the simulated shelf gripper has no servo joint");
  }
  std::lock_guard<std::mutex> lock(mutex_);
  const JointMode old_mode = mode_;
  const double old_fixed = fixed_angle_rad_;
  mode_ = mode;
  if (mode == JointMode::kFixed) fixed_angle_rad_ = angle_rad;
  try {
    sim::GetGroundTruthResponse truth;
    PushHeadLocked(JointAngleLocked(ToolGravity(&truth)), truth.gripper_head_angle_rad(),
                   /*required=*/true);
  } catch (...) {
    mode_ = old_mode;  // the simulator refused: nothing changes
    fixed_angle_rad_ = old_fixed;
    throw;
  }
}

void SimGripper::PushHeadLocked(double angle_rad, double world_angle_rad, bool required) {
  if (std::abs(angle_rad - world_angle_rad) < 1e-9) return;
  grpc::ClientContext ctx;
  SetDeadline(&ctx, options_.timeout_s);
  sim::SetGripperHeadRequest request;
  request.set_angle_rad(angle_rad);
  sim::SetGripperHeadResponse response;
  const grpc::Status status = stub_->SetGripperHead(&ctx, request, &response);
  // While the head follows gravity, a turn the cell blocks leaves it where it was.
  if (!required && status.error_code() == grpc::StatusCode::FAILED_PRECONDITION) return;
  Check(status, address_, "SetGripperHead");
}

}  // namespace picking::gripper
