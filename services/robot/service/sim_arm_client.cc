#include "services/robot/service/sim_arm_client.h"

#include <grpcpp/client_context.h>

#include <chrono>
#include <cmath>
#include <stdexcept>

#include "libs/errors/errors.h"
#include "libs/proto_convert/proto_convert.h"

namespace picking::robot {
namespace {

namespace sim = ::picking::simulator::v1;
namespace pc = ::picking::proto_convert;

void SetDeadline(grpc::ClientContext* ctx, double timeout_s) {
  ctx->set_deadline(std::chrono::system_clock::now() +
                    std::chrono::duration_cast<std::chrono::system_clock::duration>(
                        std::chrono::duration<double>(timeout_s)));
}

std::string Describe(const grpc::Status& status, const std::string& address, const char* rpc) {
  return "simulator at " + address + ": " + rpc + " failed (code " +
         std::to_string(static_cast<int>(status.error_code())) + "): " + status.error_message();
}

// UNAVAILABLE and DEADLINE_EXCEEDED mean the simulator cannot be reached; anything else is a
// refusal of this particular request.
void Check(const grpc::Status& status, const std::string& address, const char* rpc) {
  if (status.ok()) return;
  const std::string message = Describe(status, address, rpc);
  if (status.error_code() == grpc::StatusCode::UNAVAILABLE ||
      status.error_code() == grpc::StatusCode::DEADLINE_EXCEEDED) {
    throw UnavailableError(message);
  }
  throw std::runtime_error(message);
}

// What a contact touched, for messages: the item's name, else the static object's.
std::string ContactName(const sim::ProbeContactResponse& response) {
  if (!response.item().name().empty()) return response.item().name();
  switch (response.surface()) {
    case sim::CONTACT_SURFACE_SHELF:
      return "shelf";
    case sim::CONTACT_SURFACE_TOTE:
      return "tote";
    case sim::CONTACT_SURFACE_TABLE:
      return "table";
    case sim::CONTACT_SURFACE_ITEM:
      return "an item";
    default:
      return "cell";
  }
}

std::array<double, 6> ToArray(const JointVector& q) {
  std::array<double, 6> a{};
  for (int i = 0; i < 6; ++i) a[i] = q[i];
  return a;
}

}  // namespace

std::shared_ptr<SimulatorArmClient> SimulatorArmClient::Connect(
    const std::string& address, const SimulatorArmClientOptions& options,
    const runtime::ChannelFactory& channels) {
  if (address.empty() || address.find(':') == std::string::npos) {
    throw std::invalid_argument("sim.address must be HOST:PORT, got '" + address + "'");
  }
  auto channel = channels.Connect(address);
  return std::make_shared<SimulatorArmClient>(sim::SimulatorService::NewStub(channel), address,
                                              options);
}

SimulatorArmClient::SimulatorArmClient(
    std::unique_ptr<simulator::v1::SimulatorService::StubInterface> stub, std::string address,
    const SimulatorArmClientOptions& options)
    : stub_(std::move(stub)), address_(std::move(address)), options_(options) {
  if (!stub_) throw std::invalid_argument("SimulatorArmClient: null simulator stub");
  if (!std::isfinite(options_.timeout_s) || options_.timeout_s <= 0.0) {
    throw std::invalid_argument("sim.timeout_s must be finite and > 0");
  }
  if (!options_.initial_joints_rad.allFinite()) {
    throw std::invalid_argument("sim.initial_joints_rad must be 6 finite values");
  }
}

double SimulatorArmClient::ReadHeadAngle() {
  grpc::ClientContext ctx;
  SetDeadline(&ctx, options_.timeout_s);
  sim::GetGroundTruthResponse truth;
  const grpc::Status status = stub_->GetGroundTruth(&ctx, sim::GetGroundTruthRequest(), &truth);
  // No layout yet (FAILED_PRECONDITION): the head is as the world started, straight.
  if (status.error_code() == grpc::StatusCode::FAILED_PRECONDITION) return 0.0;
  Check(status, address_, "GetGroundTruth");
  if (!std::isfinite(truth.gripper_head_angle_rad())) {
    throw std::runtime_error("simulator at " + address_ + " sent a non-finite head angle");
  }
  return truth.gripper_head_angle_rad();
}

JointVector SimulatorArmClient::ReadJoints() {
  grpc::ClientContext ctx;
  SetDeadline(&ctx, options_.timeout_s);
  sim::GetGroundTruthResponse truth;
  const grpc::Status status = stub_->GetGroundTruth(&ctx, sim::GetGroundTruthRequest(), &truth);
  const bool knows_arm = status.ok() && truth.arm_joints().positions_rad_size() > 0;
  if (!status.ok() && status.error_code() != grpc::StatusCode::FAILED_PRECONDITION) {
    Check(status, address_, "GetGroundTruth");
  }
  if (!knows_arm) {
    // A fresh world: the arm starts at the configured joints.
    const ArmPlacement placement = PlaceArm(options_.initial_joints_rad);
    if (placement.in_collision) {
      throw std::runtime_error(
          "simulator at " + address_ +
          ": the initial arm joints are in collision: " + placement.collision_detail);
    }
    return options_.initial_joints_rad;
  }
  try {
    const std::array<double, 6> q = pc::JointsFromProto(truth.arm_joints(), "arm_joints");
    JointVector v;
    for (int i = 0; i < 6; ++i) v[i] = q[i];
    return v;
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error("simulator at " + address_ + " sent bad arm joints: " + e.what());
  }
}

void SimulatorArmClient::CheckReachable() {
  grpc::ClientContext ctx;
  SetDeadline(&ctx, options_.timeout_s);
  sim::GetGroundTruthResponse truth;
  const grpc::Status status = stub_->GetGroundTruth(&ctx, sim::GetGroundTruthRequest(), &truth);
  if (status.error_code() == grpc::StatusCode::FAILED_PRECONDITION) return;  // it answered
  Check(status, address_, "GetGroundTruth");
}

ArmPlacement SimulatorArmClient::PlaceArm(const JointVector& q_rad) {
  grpc::ClientContext ctx;
  SetDeadline(&ctx, options_.timeout_s);
  sim::SetArmJointsRequest request;
  *request.mutable_joints() = pc::JointsToProto(ToArray(q_rad));
  sim::SetArmJointsResponse response;
  Check(stub_->SetArmJoints(&ctx, request, &response), address_, "SetArmJoints");
  ArmPlacement placement;
  placement.in_collision = response.in_collision();
  placement.collision_detail = response.collision_detail();
  if (response.has_x_base_tcp()) {
    try {
      placement.X_BaseTcp = pc::PoseFromProto(response.x_base_tcp(), "X_base_tcp");
    } catch (const std::invalid_argument& e) {
      throw std::runtime_error("simulator at " + address_ +
                               " sent a bad SetArmJoints pose: " + e.what());
    }
  }
  return placement;
}

ContactProbe SimulatorArmClient::Probe(const Eigen::Isometry3d& X_BaseTool,
                                       const Eigen::Vector3d& direction_tcp,
                                       double max_distance_m) {
  grpc::ClientContext ctx;
  SetDeadline(&ctx, options_.timeout_s);
  sim::ProbeContactRequest request;
  *request.mutable_x_base_tool() = pc::PoseToProto(X_BaseTool);
  *request.mutable_direction_tcp() = pc::VectorToProto(direction_tcp);
  request.set_max_distance_m(max_distance_m);
  sim::ProbeContactResponse response;
  Check(stub_->ProbeContact(&ctx, request, &response), address_, "ProbeContact");
  ContactProbe probe;
  probe.contact = response.contact();
  if (probe.contact) {
    if (!std::isfinite(response.distance_m()) || !std::isfinite(response.stiffness_n_per_m()) ||
        response.stiffness_n_per_m() < 0.0) {
      throw std::runtime_error(
          "simulator at " + address_ +
          " sent a contact with a non-finite distance or a negative stiffness");
    }
    probe.distance_m = response.distance_m();
    probe.stiffness_n_per_m = response.stiffness_n_per_m();
    probe.what = ContactName(response);
  }
  return probe;
}

}  // namespace picking::robot
