#include "services/detector/service/detector_service.h"

namespace picking::detector {
namespace {

// The contract is published in full; RPCs whose implementation has not landed answer
// UNIMPLEMENTED (the generated base class's behaviour), never a made-up result.
class DetectorServiceImpl final : public v1::DetectorService::Service {};

}  // namespace

runtime::ServiceSet BuildDetectorServices(const runtime::Config& config) {
  runtime::ServiceSet set;
  set.Add(std::make_shared<DetectorServiceImpl>(), v1::DetectorService::service_full_name());
  return set;
}

}  // namespace picking::detector
