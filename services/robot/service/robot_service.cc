#include "services/robot/service/robot_service.h"

namespace picking::robot {
namespace {

// The contract is published in full; RPCs whose implementation has not landed answer
// UNIMPLEMENTED (the generated base class's behaviour), never a made-up result.
class RobotServiceImpl final : public v1::RobotService::Service {};

}  // namespace

runtime::ServiceSet BuildRobotServices(const runtime::Config& config) {
  runtime::ServiceSet set;
  set.Add(std::make_shared<RobotServiceImpl>(), v1::RobotService::service_full_name());
  return set;
}

}  // namespace picking::robot
