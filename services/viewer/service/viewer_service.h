#pragma once

#include <string>

#include "libs/runtime/config.h"
#include "libs/runtime/server.h"

namespace picking::viewer {

/// The viewer's settings (docs/services.md, `picking-viewer --help`).
struct ViewerSettings {
  /// Where the page is served: HOST:PORT, port 0 for a free one.
  std::string http_listen = "0.0.0.0:8080";
  std::string orchestrator_address = "orchestrator:50051";
  std::string robot_address = "robot:50051";
  std::string data_dir;   ///< The cell, the arm's meshes, the item models.
  std::string cell_path;  ///< Default <data_dir>/cell/default_cell.yaml.
  std::string web_dir;    ///< The page's files; default <data_dir>/viewer.
  /// three.js as Debian's libjs-three installs it.
  std::string three_dir = "/usr/share/javascript/three";
  double arm_rate_hz = 10.0;  ///< How often the arm's joints are read, (0.5, 50].
  int max_tasks = 8;          ///< Tasks followed at once (one per task id pages ask for).

  /// Reads and checks the settings; throws std::invalid_argument naming the key.
  static ViewerSettings FromConfig(const runtime::Config& config);
};

/// The viewer: an HTTP server (the page, its files, /api/...) beside the gRPC health service;
/// a client of the orchestrator (the tasks and their events) and the robot (the arm).
runtime::ServiceSet BuildViewerServices(const runtime::Config& config);

}  // namespace picking::viewer
