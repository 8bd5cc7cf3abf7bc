// picking-scanner: the scanner server of the picking cell.
#include "libs/runtime/server.h"
#include "services/scanner/service/scanner_service.h"

int main(int argc, char** argv) {
  picking::runtime::ServerSpec spec;
  spec.program = "picking-scanner";
  spec.service = "scanner";
  spec.description = "the scanner service of the picking cell (gRPC: picking.scanner.v1)";
  spec.settings_help = picking::scanner::ScannerSettingsHelp();
  spec.build = picking::scanner::BuildScannerServices;
  return picking::runtime::RunServerMain(argc, argv, spec);
}
