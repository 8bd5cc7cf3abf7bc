#pragma once

#include <memory>

#include "libs/runtime/config.h"
#include "libs/runtime/server.h"
#include "picking/detector/v1/detector.grpc.pb.h"

namespace picking::detector {

/// Builds the detector server's services from its settings (see docs/services.md,
/// picking-detector): `models`, `data_dir`, `catalogue`, `cache_dir`, `max_points`,
/// `preload`, `time_budget_scale`, `budget_clock`, `camera.*`. Throws std::invalid_argument for a
/// bad setting or manifest and std::runtime_error when `preload` is on and a model cannot be built.
runtime::ServiceSet BuildDetectorServices(const runtime::Config& config);

}  // namespace picking::detector
