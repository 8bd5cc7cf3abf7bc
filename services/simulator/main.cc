// picking-simulator: the simulator server of the picking cell.
#include "libs/runtime/server.h"
#include "services/simulator/service/simulator_service.h"

int main(int argc, char** argv) {
  picking::runtime::ServerSpec spec;
  spec.program = "picking-simulator";
  spec.service = "simulator";
  spec.description = "the simulator service of the picking cell (gRPC: picking.simulator.v1)";
  spec.settings_help = {
      "data_dir=DIR               bundled data (default: $PICKING_DATA_DIR or the source data/)",
      "cell=FILE                  cell description: shelf, tote, table and the gripper with its",
      "                           tool centre point (default <data_dir>/cell/default_cell.yaml)",
      "layout=FILE                APC 2016 task file loaded at start (default none)",
      "seed=N                     layout seed (default 1)",
      "layout_mode=tidy|settled   items side by side, or dropped and settled by physics",
      "tool.cup_radius_m=R        radius of the cup's lip (default 0.015)",
      "contact.stiffness_n_per_m=K  spring of the compliant cup (default 2000)",
      "suction.sealed_kpa / suction.open_kpa=P  vacuum with / without a seal (default 25 / 3)"};
  spec.build = picking::simulator::BuildSimulatorServices;
  return picking::runtime::RunServerMain(argc, argv, spec);
}
