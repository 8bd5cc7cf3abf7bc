// picking-simulator: the simulator server of the picking cell.
#include "libs/runtime/server.h"
#include "services/simulator/service/simulator_service.h"

int main(int argc, char** argv) {
  picking::runtime::ServerSpec spec;
  spec.program = "picking-simulator";
  spec.service = "simulator";
  spec.description = "the simulator service of the picking cell (gRPC: picking.simulator.v1)";
  spec.build = picking::simulator::BuildSimulatorServices;
  return picking::runtime::RunServerMain(argc, argv, spec);
}
