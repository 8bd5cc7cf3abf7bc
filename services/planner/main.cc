// picking-planner: the planner server of the picking cell.
#include "libs/runtime/server.h"
#include "services/planner/service/planner_service.h"

int main(int argc, char** argv) {
  picking::runtime::ServerSpec spec;
  spec.program = "picking-planner";
  spec.service = "planner";
  spec.description = "the planner service of the picking cell (gRPC: picking.planner.v1)";
  spec.build = picking::planner::BuildPlannerServices;
  return picking::runtime::RunServerMain(argc, argv, spec);
}
