// picking-orchestrator: the orchestrator server of the picking cell.
#include "libs/runtime/server.h"
#include "services/orchestrator/service/orchestrator_service.h"

int main(int argc, char** argv) {
  picking::runtime::ServerSpec spec;
  spec.program = "picking-orchestrator";
  spec.service = "orchestrator";
  spec.description = "the orchestrator service of the picking cell (gRPC: picking.orchestrator.v1)";
  spec.settings_help = {
      "scanner.address=HOST:PORT   the cell's services (default <name>:50051, the compose",
      "                            and Kubernetes service names); likewise planner.address,",
      "                            robot.address, gripper.address",
      "detector.endpoints=LIST     detector replicas: host:port,... or dns:///name:port",
      "                            (default dns:///detector:50051); detector.deadline_s,",
      "                            detector.max_attempts, ... (docs/services.md)",
      "tasks_dir=DIR           each task's journal, output file and report (default",
      "                        ./picking-tasks)",
      "data_dir=DIR            bundled data (default: $PICKING_DATA_DIR or the source data/)",
      "cell=FILE               cell description, for the bins (default",
      "                        <data_dir>/cell/default_cell.yaml)",
      "ease=FILE               ease of each item, the order of the targets (default",
      "                        <data_dir>/orchestrator/ease.yaml)",
      "detector_models=FILE    each item's preferred detection method (default",
      "                        <data_dir>/detector/models.json)",
      "time_limit_s=S          task clock, robot time (default 900, the rules' 15 minutes)",
      "max_attempts=N          attempts per target (default 2)",
      "min_time_per_item_s=S   skip a target with less task time left (default 25)",
      "detect_ahead=BOOL       take the next bin's views while a target is detected, and",
      "                        detect it while the arm picks (default true)",
      "stow.table=never|in_doubt|always  which stowed items are set down on the table and",
      "                        told apart there first (in_doubt: those another tote item's",
      "                        detection fills as well; default never)",
      "pick.table=never|in_doubt  whether a pick target in doubt with another item of its",
      "                        bin is taken anyway and told apart on the table (default never)",
      "pick.make_room=BOOL     move another item that stands in a target's way into a bin",
      "                        without targets left, then try the target again (default true)",
      "pick.max_room_moves=N   items moved aside per target, 0-12 (default 1)",
      "shutdown_wait_s=S       how long SIGTERM waits for a task's current step (default 3)",
      "viewer.url=URL          the viewer's page (picking-viewer): the report links each",
      "                        item to its view there (default: no links)",
  };
  spec.build = picking::orchestrator::BuildOrchestratorServices;
  return picking::runtime::RunServerMain(argc, argv, spec);
}
