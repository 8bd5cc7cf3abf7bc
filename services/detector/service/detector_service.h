#pragma once

#include <memory>

#include "libs/runtime/config.h"
#include "libs/runtime/server.h"
#include "picking/detector/v1/detector.grpc.pb.h"

namespace picking::detector {

/// Builds the detector server's services from its settings (see docs/services.md).
runtime::ServiceSet BuildDetectorServices(const runtime::Config& config);

}  // namespace picking::detector
