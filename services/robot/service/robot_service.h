#pragma once

#include <memory>

#include "libs/runtime/config.h"
#include "libs/runtime/server.h"
#include "picking/robot/v1/robot.grpc.pb.h"

namespace picking::robot {

/// Builds the robot server's services from its settings (see docs/services.md).
runtime::ServiceSet BuildRobotServices(const runtime::Config& config);

}  // namespace picking::robot
