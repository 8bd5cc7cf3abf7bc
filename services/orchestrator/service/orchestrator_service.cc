#include "services/orchestrator/service/orchestrator_service.h"

namespace picking::orchestrator {
namespace {

// The contract is published in full; RPCs whose implementation has not landed answer
// UNIMPLEMENTED (the generated base class's behaviour), never a made-up result.
class OrchestratorServiceImpl final : public v1::OrchestratorService::Service {};

}  // namespace

runtime::ServiceSet BuildOrchestratorServices(const runtime::Config& config) {
  runtime::ServiceSet set;
  set.Add(std::make_shared<OrchestratorServiceImpl>(),
          v1::OrchestratorService::service_full_name());
  return set;
}

}  // namespace picking::orchestrator
