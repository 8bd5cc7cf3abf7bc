// picking-gripper: the gripper server of the picking cell.
#include "libs/runtime/server.h"
#include "services/gripper/service/gripper_service.h"

int main(int argc, char** argv) {
  picking::runtime::ServerSpec spec;
  spec.program = "picking-gripper";
  spec.service = "gripper";
  spec.description = "the gripper service of the picking cell (gRPC: picking.gripper.v1)";
  spec.settings_help = {
      "backend=sim|serial          where the gripper is (default sim)",
      "kind=shelf|tote             which gripper is mounted (default shelf)",
      "serial.device=PATH          the micro controller's serial device (default /dev/ttyUSB0)",
      "serial.baud=N               line speed (default 115200)",
      "serial.reply_timeout_s=S    wait for one reply (default 0.2)",
      "serial.max_attempts=N       attempts per command (default 3)",
      "sim.address=HOST:PORT       picking-simulator (default 127.0.0.1:50051)",
      "sim.timeout_s=S             deadline of each simulator call (default 2)",
      "seal.attach_kpa=P           vacuum that counts as a seal (default 15)",
      "seal.release_kpa=P          vacuum below which a seal is lost (default 10)",
      "poll_interval_s=S           vacuum polling while waiting for a seal (default 0.02)"};
  spec.build = picking::gripper::BuildGripperServices;
  return picking::runtime::RunServerMain(argc, argv, spec);
}
