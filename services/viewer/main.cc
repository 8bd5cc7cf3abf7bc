// picking-viewer: a live web view of the picking cell and its tasks.
#include "libs/runtime/server.h"
#include "services/viewer/service/viewer_service.h"

int main(int argc, char** argv) {
  picking::runtime::ServerSpec spec;
  spec.program = "picking-viewer";
  spec.service = "viewer";
  spec.description =
      "a live 3D view of the cell and its tasks in the browser (HTTP), a client of the "
      "orchestrator and the robot; gRPC: health only";
  spec.settings_help = {
      "http_listen=HOST:PORT   where the page is served (default 0.0.0.0:8080; port 0: a",
      "                        free one, logged as `serving the page url=...`)",
      "orchestrator.address=HOST:PORT  the orchestrator (default orchestrator:50051)",
      "robot.address=HOST:PORT the robot, for the arm's joints (default robot:50051)",
      "data_dir=DIR            bundled data (default: $PICKING_DATA_DIR or the source data/)",
      "cell=FILE               cell description (default <data_dir>/cell/default_cell.yaml)",
      "web_dir=DIR             the page's files (default <data_dir>/viewer)",
      "three_dir=DIR           three.js (default /usr/share/javascript/three, libjs-three)",
      "arm_rate_hz=HZ          how often the arm is read (default 10)",
      "max_tasks=N             tasks followed at once (default 8)",
  };
  spec.build = picking::viewer::BuildViewerServices;
  return picking::runtime::RunServerMain(argc, argv, spec);
}
