// picking-gripper: the gripper server of the picking cell.
#include "libs/runtime/server.h"
#include "services/gripper/service/gripper_service.h"

int main(int argc, char** argv) {
  picking::runtime::ServerSpec spec;
  spec.program = "picking-gripper";
  spec.service = "gripper";
  spec.description = "the gripper service of the picking cell (gRPC: picking.gripper.v1)";
  spec.build = picking::gripper::BuildGripperServices;
  return picking::runtime::RunServerMain(argc, argv, spec);
}
