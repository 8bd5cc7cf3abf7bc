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
      "ur10.max_acceleration_rad_s2=A  joint acceleration limit (default 2.5)",
      "hand_eye=FILE           camera in the flange frame, for the scan poses",
      "                        (default <data_dir>/scanner/sim_sensor/hand_eye.json)",
      "grasps=FILE             suction points per item (default <data_dir>/planner/grasps.yaml)",
      "search.step_m=M         cartesian search step (default 0.02)",
      "search.node_budget=N    nodes per cartesian search (default 1500)",
      "search.time_budget_s=S  search time of one PlanPick over all its grasps; then a",
      "                        typed 'search budget spent' refusal (default 1)",
      "guarded_distance_m=M    the descent stops this short of the grasp (default 0.05)",
      "scene.cut_margin_m=M    growth of the target's hull when cut out (default 0.02)",
      "scene.ttl_s=S           scenes kept after their last use (default 120)",
      "scene.max_scenes=N      scenes kept at most (default 32)",
      "max_plan_time_s=S       longest planning call without a deadline (default 30)"};
  spec.build = picking::planner::BuildPlannerServices;
  return picking::runtime::RunServerMain(argc, argv, spec);
}
