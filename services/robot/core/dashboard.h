#pragma once

#include <chrono>
#include <memory>
#include <string>

#include "services/robot/core/byte_stream.h"

namespace picking::robot {

/// Client of the UR Dashboard Server (TCP port 29999): one command line per request, one
/// reply line per command. Not thread-safe.
class DashboardClient final {
 public:
  static constexpr std::uint16_t kPort = 29999;

  /// Reads the server's greeting ("Connected: Universal Robots Dashboard Server").
  /// @throws StreamError on I/O errors, std::runtime_error on an unexpected greeting.
  explicit DashboardClient(std::unique_ptr<ByteStream> stream,
                           std::chrono::milliseconds timeout = std::chrono::milliseconds(5000));

  /// Sends `command` + "\n" and returns the reply line. @throws std::invalid_argument for a
  /// command with a newline, StreamError on I/O errors.
  std::string Send(const std::string& command);

  // Each throws std::runtime_error with the controller's reply if it is not the success reply.
  void PowerOn();               // "power on" -> "Powering on"
  void BrakeRelease();          // "brake release" -> "Brake releasing"
  void UnlockProtectiveStop();  // "unlock protective stop" -> "Protective stop releasing"
  void Stop();                  // "stop" -> "Stopped"
  /// "robotmode" -> "Robotmode: <MODE>"; returns MODE (e.g. "RUNNING", "POWER_OFF").
  std::string RobotMode();
  /// "safetystatus" -> "Safetystatus: <STATUS>"; returns STATUS (e.g. "NORMAL",
  /// "PROTECTIVE_STOP").
  std::string SafetyStatus();

 private:
  void Expect(const std::string& command, const std::string& success_prefix);
  std::string Value(const std::string& command, const std::string& prefix);

  std::unique_ptr<ByteStream> stream_;
  std::chrono::milliseconds timeout_;
};

}  // namespace picking::robot
