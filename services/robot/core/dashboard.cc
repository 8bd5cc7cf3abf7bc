#include "services/robot/core/dashboard.h"

#include <stdexcept>

namespace picking::robot {

DashboardClient::DashboardClient(std::unique_ptr<ByteStream> stream,
                                 std::chrono::milliseconds timeout)
    : stream_(std::move(stream)), timeout_(timeout) {
  if (!stream_) throw std::invalid_argument("DashboardClient: null stream");
  const std::string greeting = stream_->ReadLine(timeout_);
  if (greeting.rfind("Connected: Universal Robots Dashboard Server", 0) != 0) {
    throw std::runtime_error("Dashboard server: unexpected greeting '" + greeting + "'");
  }
}

std::string DashboardClient::Send(const std::string& command) {
  if (command.find('\n') != std::string::npos) {
    throw std::invalid_argument("Dashboard command contains a newline");
  }
  stream_->WriteAll(command + "\n");
  return stream_->ReadLine(timeout_);
}

void DashboardClient::Expect(const std::string& command, const std::string& success_prefix) {
  const std::string reply = Send(command);
  if (reply.rfind(success_prefix, 0) != 0) {
    throw std::runtime_error("Dashboard '" + command + "' failed: " + reply);
  }
}

std::string DashboardClient::Value(const std::string& command, const std::string& prefix) {
  const std::string reply = Send(command);
  if (reply.rfind(prefix, 0) != 0) {
    throw std::runtime_error("Dashboard '" + command + "': unexpected reply '" + reply + "'");
  }
  std::string value = reply.substr(prefix.size());
  while (!value.empty() && value.front() == ' ') value.erase(0, 1);
  return value;
}

void DashboardClient::PowerOn() { Expect("power on", "Powering on"); }
void DashboardClient::BrakeRelease() { Expect("brake release", "Brake releasing"); }
void DashboardClient::UnlockProtectiveStop() {
  Expect("unlock protective stop", "Protective stop releasing");
}
void DashboardClient::Stop() { Expect("stop", "Stopped"); }
std::string DashboardClient::RobotMode() { return Value("robotmode", "Robotmode:"); }
std::string DashboardClient::SafetyStatus() { return Value("safetystatus", "Safetystatus:"); }

}  // namespace picking::robot
