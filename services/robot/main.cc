// picking-robot: the robot server of the picking cell.
#include "libs/runtime/server.h"
#include "services/robot/service/robot_service.h"

int main(int argc, char** argv) {
  picking::runtime::ServerSpec spec;
  spec.program = "picking-robot";
  spec.service = "robot";
  spec.description = "the robot service of the picking cell (gRPC: picking.robot.v1)";
  spec.build = picking::robot::BuildRobotServices;
  return picking::runtime::RunServerMain(argc, argv, spec);
}
