#pragma once

#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "libs/runtime/config.h"

namespace grpc {
class Service;
}

namespace picking::runtime {

/// The gRPC services one server exposes, built from its configuration.
struct ServiceSet {
  /// Registers a service implementation under its full proto name (e.g.
  /// picking::robot::v1::RobotService::service_full_name()), which the health service
  /// reports as SERVING.
  void Add(std::shared_ptr<grpc::Service> service, std::string full_name);

  std::vector<std::shared_ptr<grpc::Service>> services;
  std::vector<std::string> full_names;
  /// Called once after the server stops accepting calls, before the process exits: stop
  /// backends, flush journals.
  std::function<void()> on_shutdown;
};

/// What a service's main() hands to RunServerMain.
struct ServerSpec {
  std::string program;      ///< Executable name, e.g. "picking-robot".
  std::string service;      ///< Short name used in logs, e.g. "robot".
  std::string description;  ///< One line for --help.
  std::string default_listen = "127.0.0.1:0";
  /// Extra settings accepted as --key=value or in the config file, for --help.
  std::vector<std::string> settings_help;
  /// Builds the services. May throw std::invalid_argument for bad settings (the server
  /// then exits with status 2 and the message) or std::runtime_error when a backend
  /// cannot start (status 1).
  std::function<ServiceSet(const Config&)> build;
};

/// The shared server runtime. Parses the flags
///   --listen=HOST:PORT   (port 0 picks a free port)
///   --config=FILE        (YAML settings; --key=value flags override them)
///   --log-level=LEVEL    (debug, info, warning, error)
///   --shutdown-grace-s=S (how long in-flight calls may run on after SIGTERM; default 5)
///   --max-message-mb=N   (largest gRPC message accepted or sent; default 64)
/// and the settings tls.cert, tls.key, tls.ca (TLS, mutual with the CA; plaintext without them;
/// see tls.h and ServerCredentialsFor),
/// builds the services, enables the standard health service (grpc.health.v1: "" and each
/// service SERVING) and server reflection (v1alpha and v1), binds, prints exactly one line
/// `listening on HOST:PORT` with the bound port to stdout, serves until SIGTERM or SIGINT,
/// then stops cleanly (health NOT_SERVING, new calls refused, in-flight calls finish within
/// the grace period) and returns the process exit status (0 on a clean stop).
int RunServerMain(int argc, char** argv, const ServerSpec& spec);

/// True once the server has been asked to stop. Long-running handlers (state streams,
/// trajectory execution) poll this to end promptly.
bool ShuttingDown();

/// Blocks until the server is asked to stop or `timeout` passes; returns ShuttingDown().
bool WaitForShutdown(std::chrono::milliseconds timeout);

}  // namespace picking::runtime
