#include "services/scanner/service/scanner_service.h"

namespace picking::scanner {
namespace {

// The contract is published in full; RPCs whose implementation has not landed answer
// UNIMPLEMENTED (the generated base class's behaviour), never a made-up result.
class ScannerServiceImpl final : public v1::ScannerService::Service {};

}  // namespace

runtime::ServiceSet BuildScannerServices(const runtime::Config& config) {
  runtime::ServiceSet set;
  set.Add(std::make_shared<ScannerServiceImpl>(), v1::ScannerService::service_full_name());
  return set;
}

}  // namespace picking::scanner
