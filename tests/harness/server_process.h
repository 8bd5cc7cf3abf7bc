#pragma once

#include <grpcpp/channel.h>
#include <sys/types.h>

#include <chrono>
#include <memory>
#include <string>
#include <vector>

#include "libs/runtime/channel.h"

namespace picking::testing {

/// Path of a server executable built into build/bin/ (e.g. "picking-robot").
std::string ServerBinary(const std::string& name);

/// Runs a real server binary for an integration test: starts it with
/// `--listen=127.0.0.1:0` and the given extra flags, reads the bound port from its first
/// stdout line (`listening on HOST:PORT`), and gives a channel to it. The server's stderr
/// (its log) goes to the test's stderr.
class ServerProcess final {
 public:
  /// Throws std::runtime_error if the binary cannot start or does not print its port
  /// within `startup_timeout` (the message includes what it printed).
  explicit ServerProcess(const std::string& binary, std::vector<std::string> extra_args = {},
                         std::chrono::milliseconds startup_timeout = std::chrono::seconds(60));
  ~ServerProcess();
  ServerProcess(const ServerProcess&) = delete;
  ServerProcess& operator=(const ServerProcess&) = delete;

  const std::string& address() const { return address_; }
  int port() const { return port_; }
  pid_t pid() const { return pid_; }

  /// A new plaintext channel to the server, with a message size limit suited to scan data.
  std::shared_ptr<grpc::Channel> Channel() const;
  /// The same over a channel from `channels` (e.g. TLS with a client certificate, for a
  /// server started with --tls.* flags).
  std::shared_ptr<grpc::Channel> Channel(const runtime::ChannelFactory& channels) const;

  /// Sends SIGTERM and waits for the exit. Returns the exit status, or 128 + signal if it
  /// was killed by a signal; -1 if it did not exit within `timeout` (it is then killed).
  int Stop(std::chrono::milliseconds timeout = std::chrono::seconds(30));

  bool running() const { return pid_ > 0; }

  /// False once the process has exited (for any reason); `exit_status` then holds its
  /// status as Stop() reports it. Does not block.
  bool Alive();
  int exit_status() const { return exit_status_; }

 private:
  int WaitExit(std::chrono::milliseconds timeout);

  pid_t pid_ = -1;
  int stdout_fd_ = -1;
  std::string address_;
  int port_ = 0;
  int exit_status_ = -1;
};

/// Runs a program to completion and returns its exit status and combined output. Used to
/// check that a server refuses bad flags.
struct ProgramResult {
  int exit_status = -1;
  std::string output;
};
ProgramResult RunProgram(const std::string& binary, const std::vector<std::string>& args,
                         std::chrono::milliseconds timeout = std::chrono::seconds(60));

}  // namespace picking::testing
