#include "services/simulator/service/simulator_service.h"

namespace picking::simulator {
namespace {

// The contract is published in full; RPCs whose implementation has not landed answer
// UNIMPLEMENTED (the generated base class's behaviour), never a made-up result.
class SimulatorServiceImpl final : public v1::SimulatorService::Service {};

}  // namespace

runtime::ServiceSet BuildSimulatorServices(const runtime::Config& config) {
  runtime::ServiceSet set;
  set.Add(std::make_shared<SimulatorServiceImpl>(), v1::SimulatorService::service_full_name());
  return set;
}

}  // namespace picking::simulator
