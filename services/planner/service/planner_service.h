#pragma once

#include <memory>

#include "libs/runtime/config.h"
#include "libs/runtime/server.h"
#include "picking/planner/v1/planner.grpc.pb.h"

namespace picking::planner {

/// Builds the planner server's services from its settings (see docs/services.md).
runtime::ServiceSet BuildPlannerServices(const runtime::Config& config);

}  // namespace picking::planner
