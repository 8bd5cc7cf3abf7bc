#include "services/gripper/service/gripper_service.h"

namespace picking::gripper {
namespace {

// The contract is published in full; RPCs whose implementation has not landed answer
// UNIMPLEMENTED (the generated base class's behaviour), never a made-up result.
class GripperServiceImpl final : public v1::GripperService::Service {};

}  // namespace

runtime::ServiceSet BuildGripperServices(const runtime::Config& config) {
  runtime::ServiceSet set;
  set.Add(std::make_shared<GripperServiceImpl>(), v1::GripperService::service_full_name());
  return set;
}

}  // namespace picking::gripper
