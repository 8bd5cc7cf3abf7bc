// picking-detector: the detector server of the picking cell.
#include "libs/runtime/server.h"
#include "services/detector/service/detector_service.h"

int main(int argc, char** argv) {
  picking::runtime::ServerSpec spec;
  spec.program = "picking-detector";
  spec.service = "detector";
  spec.description = "the detector service of the picking cell (gRPC: picking.detector.v1)";
  spec.build = picking::detector::BuildDetectorServices;
  return picking::runtime::RunServerMain(argc, argv, spec);
}
