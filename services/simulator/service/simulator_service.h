#pragma once

#include <memory>

#include "libs/runtime/config.h"
#include "libs/runtime/server.h"
#include "picking/simulator/v1/simulator.grpc.pb.h"

namespace picking::simulator {

/// Builds the simulator server's services from its settings (see docs/services.md).
runtime::ServiceSet BuildSimulatorServices(const runtime::Config& config);

}  // namespace picking::simulator
