#include "services/gripper/core/testing/fake_micro_controller.h"

#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdlib.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>

#include "services/gripper/core/serial_protocol.h"

namespace picking::gripper::testing {
namespace {

constexpr double kPi = 3.14159265358979323846;

[[noreturn]] void Fail(const std::string& what) {
  throw std::runtime_error("fake micro controller: " + what + ": " + std::strerror(errno));
}

double MoveToward(double from, double to, double max_step) {
  return from + std::clamp(to - from, -max_step, max_step);
}

}  // namespace

FakeMicroController::FakeMicroController(const FakeMicroControllerOptions& options)
    : options_(options), g_tool_(0.0, 0.0, kGravity_m_s2), controller_(options.controller) {
  master_fd_ = ::posix_openpt(O_RDWR | O_NOCTTY);
  if (master_fd_ < 0) Fail("posix_openpt");
  ::fcntl(master_fd_, F_SETFD, FD_CLOEXEC);
  if (::grantpt(master_fd_) != 0 || ::unlockpt(master_fd_) != 0) Fail("grantpt/unlockpt");
  char name[128];
  if (::ptsname_r(master_fd_, name, sizeof(name)) != 0) Fail("ptsname_r");
  slave_path_ = name;
  // Keep one slave descriptor open for the fake's lifetime: without any open slave the
  // master reports a hang-up, and the host may open and close the device several times.
  // Raw mode at once, so nothing written by either side is echoed back.
  slave_fd_ = ::open(name, O_RDWR | O_NOCTTY | O_CLOEXEC);
  if (slave_fd_ < 0) Fail("open slave");
  termios tio{};
  if (::tcgetattr(slave_fd_, &tio) != 0) Fail("tcgetattr");
  ::cfmakeraw(&tio);
  if (::tcsetattr(slave_fd_, TCSANOW, &tio) != 0) Fail("tcsetattr");
  if (::pipe2(wake_pipe_, O_CLOEXEC) != 0) Fail("pipe2");
  thread_ = std::thread([this] { Run(); });
}

FakeMicroController::~FakeMicroController() {
  const char stop = 'x';
  (void)!::write(wake_pipe_[1], &stop, 1);
  if (thread_.joinable()) thread_.join();
  for (int fd : {master_fd_, slave_fd_, wake_pipe_[0], wake_pipe_[1]}) {
    if (fd >= 0) ::close(fd);
  }
}

void FakeMicroController::Run() {
  serial::LineReader reader(serial::kMaxLineBytes);
  while (true) {
    pollfd fds[2] = {{master_fd_, POLLIN, 0}, {wake_pipe_[0], POLLIN, 0}};
    if (::poll(fds, 2, -1) < 0) {
      if (errno == EINTR) continue;
      return;
    }
    if (fds[1].revents != 0) return;
    if ((fds[0].revents & POLLIN) == 0) continue;
    char buf[256];
    const ssize_t n = ::read(master_fd_, buf, sizeof(buf));
    if (n <= 0) continue;
    reader.Append(std::string_view(buf, static_cast<std::size_t>(n)));
    while (auto line = reader.Next()) HandleLine(*line);
  }
}

void FakeMicroController::HandleLine(const std::string& raw) {
  if (raw.empty() || raw == "\r") return;  // The host's resynchronising newline.
  std::string reply_body;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    // A partial line glued to a complete one: the part from the last '$' is the command.
    const std::size_t start = raw.rfind('$');
    const auto body =
        start == std::string::npos ? std::nullopt : serial::DecodeLine(raw.substr(start));
    const auto command = body ? serial::ParseCommand(*body) : std::nullopt;
    if (!command) {
      ++garbled_commands_;
      return;  // Garbled commands are discarded silently; the host retries.
    }
    if (silent_) return;
    Tick();
    reply_body = Execute(command->seq, command->verb, command->args);
    if (drop_ > 0) {
      --drop_;
      return;
    }
  }
  std::string line = serial::EncodeLine(reply_body);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (garble_ > 0) {
      --garble_;
      // Change one character of the body: the checksum no longer matches.
      char& c = line[1 + (line.size() - 5) / 2];
      c = c == '7' ? '8' : '7';
    } else if (truncate_ > 0) {
      --truncate_;
      line.resize(line.size() / 2);
    }
  }
  Write(line);
}

std::string FakeMicroController::Execute(std::uint32_t seq, const std::string& verb,
                                         const std::vector<std::string>& args) {
  std::string text = verb;
  for (const auto& a : args) text += " " + a;
  commands_.push_back(text);
  if ((verb == "V1" || verb == "V0") && args.empty()) {
    relay_ = verb == "V1";
    return serial::OkBody(seq);
  }
  if (verb == "Q" && args.empty()) {
    serial::Telemetry t;
    t.vacuum_kpa = kpa_;
    t.gravity_head_m_s2 = options_.has_servo ? GravityInHead(g_tool_, q_rad_) : g_tool_;
    t.joint_deg = q_rad_ * 180.0 / kPi;
    t.mode = mode_;
    t.relay_on = relay_;
    return serial::OkBody(seq, serial::FormatTelemetry(t));
  }
  if (verb == "S" && args.size() == 1) {
    if (!options_.has_servo) return serial::ErrBody(seq, "NOSERVO no servo fitted");
    const auto deg = serial::ParseNumber(args[0]);
    if (!deg) return serial::ErrBody(seq, "ARG angle is not a number");
    if (std::abs(*deg) * kPi / 180.0 > options_.servo_limit_rad + 1e-9) {
      return serial::ErrBody(seq, "ARG angle out of range");
    }
    target_rad_ = *deg * kPi / 180.0;
    return serial::OkBody(seq);
  }
  if (verb == "M" && args.size() == 1) {
    if (!options_.has_servo) return serial::ErrBody(seq, "NOSERVO no servo fitted");
    const auto mode = serial::ModeFromCode(args[0]);
    if (!mode) return serial::ErrBody(seq, "ARG unknown mode");
    if (*mode == JointMode::kKeepVertical && mode_ != JointMode::kKeepVertical) {
      controller_.Reset();
    }
    mode_ = *mode;
    return serial::OkBody(seq);
  }
  return serial::ErrBody(seq, "CMD unknown command");
}

void FakeMicroController::Tick() {
  const double target_kpa = relay_ ? (item_ ? options_.sealed_kpa : options_.open_kpa) : 0.0;
  kpa_ += (target_kpa - kpa_) * options_.vacuum_rise_fraction;
  if (!options_.has_servo) return;
  const int steps =
      std::max(1, static_cast<int>(std::lround(options_.tick_s / options_.control_dt_s)));
  const double dt = options_.tick_s / steps;
  const double max_step = options_.servo_rate_rad_s * dt;
  for (int i = 0; i < steps; ++i) {
    double goal = q_rad_;
    switch (mode_) {
      case JointMode::kUnactuated:
        // The limp joint lets the head hang along gravity, until the vacuum seals the
        // joint's play and locks it where it is.
        if (!relay_ && std::hypot(g_tool_.y(), g_tool_.z()) > 1e-9) {
          goal = VerticalJointAngle(g_tool_);
        }
        break;
      case JointMode::kFixed:
        goal = target_rad_;
        break;
      case JointMode::kKeepVertical:
        goal = controller_.Step(GravityInHead(g_tool_, q_rad_), q_rad_, dt).command_rad;
        break;
    }
    goal = std::clamp(goal, -options_.servo_limit_rad, options_.servo_limit_rad);
    q_rad_ = MoveToward(q_rad_, goal, max_step);
  }
}

void FakeMicroController::Write(const std::string& bytes) {
  std::lock_guard<std::mutex> lock(write_mutex_);
  std::size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(master_fd_, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return;
    done += static_cast<std::size_t>(n);
  }
}

void FakeMicroController::SetItemUnderCup(bool item) {
  std::lock_guard<std::mutex> lock(mutex_);
  item_ = item;
}

void FakeMicroController::SetToolGravity(const Eigen::Vector3d& g_tool) {
  std::lock_guard<std::mutex> lock(mutex_);
  g_tool_ = g_tool;
}

void FakeMicroController::GarbleNextReplies(int n) {
  std::lock_guard<std::mutex> lock(mutex_);
  garble_ = n;
}

void FakeMicroController::TruncateNextReplies(int n) {
  std::lock_guard<std::mutex> lock(mutex_);
  truncate_ = n;
}

void FakeMicroController::DropNextReplies(int n) {
  std::lock_guard<std::mutex> lock(mutex_);
  drop_ = n;
}

void FakeMicroController::SetSilent(bool silent) {
  std::lock_guard<std::mutex> lock(mutex_);
  silent_ = silent;
}

void FakeMicroController::SendRaw(const std::string& bytes) { Write(bytes); }

std::vector<std::string> FakeMicroController::commands() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return commands_;
}

int FakeMicroController::garbled_commands() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return garbled_commands_;
}

bool FakeMicroController::relay_on() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return relay_;
}

double FakeMicroController::vacuum_kpa() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return kpa_;
}

JointMode FakeMicroController::mode() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return mode_;
}

double FakeMicroController::joint_angle_rad() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return q_rad_;
}

double FakeMicroController::fixed_target_rad() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return target_rad_;
}

Eigen::Vector3d FakeMicroController::GravityHead() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return GravityInHead(g_tool_, q_rad_);
}

}  // namespace picking::gripper::testing
