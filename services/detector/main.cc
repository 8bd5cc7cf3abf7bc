// picking-detector: the detector server of the picking cell.
#include "libs/runtime/server.h"
#include "services/detector/service/detector_service.h"

int main(int argc, char** argv) {
  picking::runtime::ServerSpec spec;
  spec.program = "picking-detector";
  spec.service = "detector";
  spec.description = "the detector service of the picking cell (gRPC: picking.detector.v1)";
  spec.settings_help = {
      "data_dir=DIR            bundled data (default: $PICKING_DATA_DIR or the source data/)",
      "models=FILE             model manifest JSON (default <data_dir>/detector/models.json)",
      "catalogue=FILE          APC item catalogue for shape models "
      "(default <data_dir>/apc2016/items/item_data.csv)",
      "cache_dir=DIR           built-model cache (default ~/.cache/picking/detector)",
      "preload=BOOL            build every model before serving (default false: on first use)",
      "max_points=N            largest cloud accepted, points (default 5000000)",
      "time_budget_scale=F     multiplies every item's time budget (default 1)",
      "budget_clock=thread_cpu|steady|frozen  clock of the items' time budgets (default "
      "thread_cpu: the CPU time of the thread serving the call, so other work on the machine "
      "slows a search down but does not cut it short; steady: wall time; frozen: budgets never "
      "run out, every method searches to its end, for tests)",
      "camera.width|height|fx|fy|cx|cy=V  intrinsics for unorganised clouds "
      "(default 640x480, 525, 525, 319.5, 239.5)"};
  spec.build = picking::detector::BuildDetectorServices;
  return picking::runtime::RunServerMain(argc, argv, spec);
}
