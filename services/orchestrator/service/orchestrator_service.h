#pragma once

#include <memory>

#include "libs/runtime/config.h"
#include "libs/runtime/server.h"
#include "picking/orchestrator/v1/orchestrator.grpc.pb.h"

namespace picking::orchestrator {

/// Builds the orchestrator server's services from its settings (see docs/services.md).
runtime::ServiceSet BuildOrchestratorServices(const runtime::Config& config);

}  // namespace picking::orchestrator
