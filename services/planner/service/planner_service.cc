#include "services/planner/service/planner_service.h"

namespace picking::planner {
namespace {

// The contract is published in full; RPCs whose implementation has not landed answer
// UNIMPLEMENTED (the generated base class's behaviour), never a made-up result.
class PlannerServiceImpl final : public v1::PlannerService::Service {};

}  // namespace

runtime::ServiceSet BuildPlannerServices(const runtime::Config& config) {
  runtime::ServiceSet set;
  set.Add(std::make_shared<PlannerServiceImpl>(), v1::PlannerService::service_full_name());
  return set;
}

}  // namespace picking::planner
