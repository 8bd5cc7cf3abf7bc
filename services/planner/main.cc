// picking-planner: the planner server of the picking cell.
#include "libs/runtime/server.h"
#include "services/planner/service/planner_service.h"

int main(int argc, char** argv) {
  picking::runtime::ServerSpec spec;
  spec.program = "picking-planner";
  spec.service = "planner";
  spec.description = "the planner service of the picking cell (gRPC: picking.planner.v1)";
  spec.settings_help = {
      "data_dir=DIR            bundled data (default: $PICKING_DATA_DIR or the source data/)",
      "cell=FILE               cell description; its gripper's X_ToolTcp is the tool centre",
      "                        point (default <data_dir>/cell/default_cell.yaml)",
      "ur10.max_acceleration_rad_s2=A  joint acceleration limit (default 2.5)"};
  spec.build = picking::planner::BuildPlannerServices;
  return picking::runtime::RunServerMain(argc, argv, spec);
}
