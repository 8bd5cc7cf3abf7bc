#include "services/gripper/service/gripper_service.h"

#include <cmath>
#include <stdexcept>
#include <string>

#include "libs/runtime/log.h"
#include "libs/runtime/server.h"
#include "libs/runtime/status.h"
#include "services/gripper/core/serial_gripper.h"
#include "services/gripper/service/sim_gripper.h"

namespace picking::gripper {
namespace {

namespace pb = ::picking::gripper::v1;

pb::JointMode ModeToProto(JointMode mode) {
  switch (mode) {
    case JointMode::kUnactuated:
      return pb::JOINT_MODE_UNACTUATED;
    case JointMode::kFixed:
      return pb::JOINT_MODE_FIXED;
    case JointMode::kKeepVertical:
      return pb::JOINT_MODE_KEEP_VERTICAL;
  }
  return pb::JOINT_MODE_UNSPECIFIED;
}

// A backend's name as the contract names it ("sim", "serial"; a test's fake has none).
pb::GripperBackend BackendToProto(const std::string& name) {
  if (name == "sim") return pb::GRIPPER_BACKEND_SIM;
  if (name == "serial") return pb::GRIPPER_BACKEND_SERIAL;
  return pb::GRIPPER_BACKEND_UNSPECIFIED;
}

JointMode ModeFromProto(pb::JointMode mode) {
  switch (mode) {
    case pb::JOINT_MODE_UNACTUATED:
      return JointMode::kUnactuated;
    case pb::JOINT_MODE_FIXED:
      return JointMode::kFixed;
    case pb::JOINT_MODE_KEEP_VERTICAL:
      return JointMode::kKeepVertical;
    default:
      throw std::invalid_argument("mode: " + std::to_string(static_cast<int>(mode)) +
                                  " is not a joint mode (use JOINT_MODE_UNACTUATED, "
                                  "JOINT_MODE_FIXED or JOINT_MODE_KEEP_VERTICAL)");
  }
}

class GripperServiceImpl final : public pb::GripperService::Service {
 public:
  explicit GripperServiceImpl(std::shared_ptr<Gripper> gripper) : gripper_(std::move(gripper)) {}

  grpc::Status SetVacuum(grpc::ServerContext* context, const pb::SetVacuumRequest* request,
                         pb::SetVacuumResponse* response) override {
    return runtime::Guard([&] {
      // A wait ends early when the caller gives up or the server is stopping.
      const auto cancelled = [context] {
        return context->IsCancelled() || runtime::ShuttingDown();
      };
      const GripperState state =
          gripper_->SetVacuum(request->on(), request->wait_for_seal_s(), cancelled);
      *response->mutable_state() = StateToProto(state);
      return grpc::Status::OK;
    });
  }

  grpc::Status GetState(grpc::ServerContext*, const pb::GetStateRequest*,
                        pb::GetStateResponse* response) override {
    return runtime::Guard([&] {
      *response = StateToProto(gripper_->State());
      return grpc::Status::OK;
    });
  }

  grpc::Status SetJointMode(grpc::ServerContext*, const pb::SetJointModeRequest* request,
                            pb::SetJointModeResponse* response) override {
    return runtime::Guard([&] {
      const JointMode mode = ModeFromProto(request->mode());
      *response->mutable_state() = StateToProto(gripper_->SetJointMode(mode, request->angle_rad()));
      return grpc::Status::OK;
    });
  }

 private:
  std::shared_ptr<Gripper> gripper_;
};

int IntSetting(const runtime::Config& config, const std::string& key, long long fallback,
               long long min, long long max) {
  const long long v = config.GetInt(key, fallback);
  if (v < min || v > max) {
    throw std::invalid_argument("setting '" + key + "' must be in [" + std::to_string(min) + ", " +
                                std::to_string(max) + "], got " + std::to_string(v));
  }
  return static_cast<int>(v);
}

double PositiveSetting(const runtime::Config& config, const std::string& key, double fallback) {
  const double v = config.GetDouble(key, fallback);
  if (!(v > 0.0)) {
    throw std::invalid_argument("setting '" + key + "' must be > 0, got " + std::to_string(v));
  }
  return v;
}

}  // namespace

std::shared_ptr<pb::GripperService::Service> MakeGripperService(std::shared_ptr<Gripper> gripper) {
  if (!gripper) throw std::invalid_argument("MakeGripperService: null gripper");
  return std::make_shared<GripperServiceImpl>(std::move(gripper));
}

pb::GetStateResponse StateToProto(const GripperState& state) {
  pb::GetStateResponse out;
  out.set_kind(state.kind == GripperKind::kShelf ? pb::GRIPPER_KIND_SHELF : pb::GRIPPER_KIND_TOTE);
  out.set_vacuum_on(state.reading.vacuum_on);
  out.set_vacuum_kpa(state.reading.vacuum_kpa);
  out.set_item_attached(state.item_attached);
  // The shelf gripper has no joint: its mode is left unspecified.
  out.set_joint_mode(state.kind == GripperKind::kShelf ? pb::JOINT_MODE_UNSPECIFIED
                                                       : ModeToProto(state.reading.joint_mode));
  out.set_joint_angle_rad(state.reading.joint_angle_rad);
  out.set_accel_x_m_s2(state.reading.gravity_head_m_s2.x());
  out.set_accel_y_m_s2(state.reading.gravity_head_m_s2.y());
  out.set_accel_z_m_s2(state.reading.gravity_head_m_s2.z());
  out.set_backend(BackendToProto(state.backend));
  return out;
}

runtime::ServiceSet BuildGripperServices(const runtime::Config& config) {
  // Every setting is read whichever backend is chosen, so one configuration file can hold
  // both backends' sections.
  const std::string backend = config.GetString("backend", "sim");
  const GripperKind kind = GripperKindFromName(config.GetString("kind", "tote"), "setting 'kind'");
  const std::string device = config.GetString("serial.device", "/dev/ttyUSB0");
  const int baud = IntSetting(config, "serial.baud", 115200, 1, 4000000);
  serial::SerialLinkOptions link;
  link.reply_timeout_s = PositiveSetting(config, "serial.reply_timeout_s", link.reply_timeout_s);
  link.max_attempts = IntSetting(config, "serial.max_attempts", link.max_attempts, 1, 100);
  const std::string sim_address = config.GetString("sim.address", "127.0.0.1:50051");
  const runtime::ChannelFactory sim_channels = runtime::ChannelFactory::FromConfig(config);
  SimGripperOptions sim_options;
  sim_options.kind = kind;
  sim_options.timeout_s = PositiveSetting(config, "sim.timeout_s", sim_options.timeout_s);
  GripperOptions options;
  options.kind = kind;
  options.seal.attach_kpa = config.GetDouble("seal.attach_kpa", options.seal.attach_kpa);
  options.seal.release_kpa = config.GetDouble("seal.release_kpa", options.seal.release_kpa);
  options.poll_interval_s = PositiveSetting(config, "poll_interval_s", options.poll_interval_s);

  std::unique_ptr<GripperBackend> gripper_backend;
  if (backend == "serial") {
    gripper_backend = std::make_unique<SerialGripper>(device, baud, link);
  } else if (backend == "sim") {
    gripper_backend = SimGripper::Connect(sim_address, sim_options, sim_channels);
  } else {
    throw std::invalid_argument("setting 'backend': unknown backend '" + backend +
                                "' (expected sim or serial)");
  }
  auto gripper = std::make_shared<Gripper>(std::move(gripper_backend), options);
  runtime::LogInfo("gripper ready", {{"backend", backend},
                                     {"kind", std::string(GripperKindName(kind))},
                                     {"device", backend == "serial" ? device : sim_address}});
  runtime::ServiceSet set;
  set.Add(MakeGripperService(std::move(gripper)), pb::GripperService::service_full_name());
  return set;
}

}  // namespace picking::gripper
