// picking-orchestrator: the orchestrator server of the picking cell.
#include "libs/runtime/server.h"
#include "services/orchestrator/service/orchestrator_service.h"

int main(int argc, char** argv) {
  picking::runtime::ServerSpec spec;
  spec.program = "picking-orchestrator";
  spec.service = "orchestrator";
  spec.description = "the orchestrator service of the picking cell (gRPC: picking.orchestrator.v1)";
  spec.build = picking::orchestrator::BuildOrchestratorServices;
  return picking::runtime::RunServerMain(argc, argv, spec);
}
