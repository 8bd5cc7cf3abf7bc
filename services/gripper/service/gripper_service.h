#pragma once

#include <memory>

#include "libs/runtime/config.h"
#include "libs/runtime/server.h"
#include "picking/gripper/v1/gripper.grpc.pb.h"
#include "services/gripper/core/gripper.h"

namespace picking::gripper {

/// The GripperService adapter over a core Gripper: proto <-> core types and status codes
/// (INVALID_ARGUMENT for NaN, out-of-range or unspecified values; FAILED_PRECONDITION for
/// the shelf gripper's joint; UNAVAILABLE when the controller or simulator does not answer;
/// DEADLINE_EXCEEDED when no seal comes within wait_for_seal_s).
std::shared_ptr<v1::GripperService::Service> MakeGripperService(std::shared_ptr<Gripper> gripper);

/// Core state -> proto.
v1::GetStateResponse StateToProto(const GripperState& state);

/// Builds the gripper server's services from its settings (see docs/services.md):
/// `backend` (sim | serial), `kind` (shelf | tote), `serial.*`, `sim.*`, `seal.*`,
/// `poll_interval_s`. Throws std::invalid_argument for a bad setting and UnavailableError
/// when the serial device cannot be opened.
runtime::ServiceSet BuildGripperServices(const runtime::Config& config);

}  // namespace picking::gripper
