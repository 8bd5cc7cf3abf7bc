#pragma once

#include <memory>
#include <string>
#include <vector>

#include "libs/runtime/config.h"
#include "libs/runtime/server.h"
#include "picking/scanner/v1/scanner.grpc.pb.h"

namespace picking::scanner {

/// The settings the scanner server reads, for --help (see docs/services.md).
std::vector<std::string> ScannerSettingsHelp();

/// Builds the scanner server's services from its settings (see docs/services.md).
/// @throws std::invalid_argument for bad settings (unknown backend, missing replay folder,
///   malformed calibration file), std::runtime_error when a device cannot be opened.
runtime::ServiceSet BuildScannerServices(const runtime::Config& config);

}  // namespace picking::scanner
