#pragma once

#include <memory>

#include "libs/runtime/config.h"
#include "libs/runtime/server.h"
#include "picking/scanner/v1/scanner.grpc.pb.h"

namespace picking::scanner {

/// Builds the scanner server's services from its settings (see docs/services.md).
runtime::ServiceSet BuildScannerServices(const runtime::Config& config);

}  // namespace picking::scanner
