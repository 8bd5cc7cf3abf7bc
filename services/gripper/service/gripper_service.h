#pragma once

#include <memory>

#include "libs/runtime/config.h"
#include "libs/runtime/server.h"
#include "picking/gripper/v1/gripper.grpc.pb.h"

namespace picking::gripper {

/// Builds the gripper server's services from its settings (see docs/services.md).
runtime::ServiceSet BuildGripperServices(const runtime::Config& config);

}  // namespace picking::gripper
