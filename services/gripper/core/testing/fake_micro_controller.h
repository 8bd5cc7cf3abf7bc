#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "services/gripper/core/gripper_types.h"
#include "services/gripper/core/keep_vertical.h"

namespace picking::gripper::testing {

/// The simulated physics behind the fake controller.
struct FakeMicroControllerOptions {
  bool has_servo = true;     ///< false: the shelf gripper's controller (ERR NOSERVO).
  double sealed_kpa = 30.0;  ///< Vacuum level with an item sealed on the cup, kPa.
  double open_kpa = 4.0;     ///< Vacuum level of an open cup (no item), kPa.
  /// Each command is one tick of simulated time; per tick the vacuum level moves this
  /// fraction of the way to its target (0 with the relay off).
  double vacuum_rise_fraction = 0.5;
  double tick_s = 0.1;            ///< Simulated time per command, seconds.
  double control_dt_s = 0.01;     ///< Servo and controller step inside a tick, seconds.
  double servo_rate_rad_s = 4.0;  ///< How fast the servo (or the swinging head) moves.
  double servo_limit_rad = 1.5707963267948966;
  KeepVerticalOptions controller;  ///< The keep-vertical control law.
};

/// A stand-in for the gripper's micro controller on the master side of a pseudo-terminal:
/// a thread parses the protocol's command lines from the slave side, simulates the vacuum,
/// servo and accelerometer deterministically (one tick per command, no wall-clock time), and
/// answers. Faults can be injected: garbled or dropped replies, unsolicited noise, a cup that
/// never seals, a controller that stays silent.
class FakeMicroController final {
 public:
  /// Creates the pseudo-terminal pair (posix_openpt) and starts the thread. Throws
  /// std::runtime_error if the system has no pseudo-terminals.
  explicit FakeMicroController(const FakeMicroControllerOptions& options = {});
  ~FakeMicroController();
  FakeMicroController(const FakeMicroController&) = delete;
  FakeMicroController& operator=(const FakeMicroController&) = delete;

  /// Path of the slave side (e.g. /dev/pts/7): what the host opens as its serial device.
  const std::string& device_path() const { return slave_path_; }

  // The simulated world.
  /// true: an item is under the cup and the vacuum reaches sealed_kpa; false: it never
  /// rises above open_kpa.
  void SetItemUnderCup(bool item);
  /// Gravity in the tool frame, m/s^2 (the arm's tool orientation).
  void SetToolGravity(const Eigen::Vector3d& g_tool);

  // Faults.
  /// The next `n` replies have one byte changed, so their checksum fails.
  void GarbleNextReplies(int n);
  /// The next `n` replies are cut in half (no newline); the command is executed.
  void TruncateNextReplies(int n);
  /// The next `n` commands are executed but not answered.
  void DropNextReplies(int n);
  /// No command is answered (or executed) while set: an unplugged controller.
  void SetSilent(bool silent);
  /// Writes raw bytes to the host now (noise, partial lines, unsolicited lines).
  void SendRaw(const std::string& bytes);

  // Observation.
  /// Every executed command as received without its sequence number, e.g. "S -30.00".
  std::vector<std::string> commands() const;
  /// Command lines discarded for a bad checksum or framing.
  int garbled_commands() const;
  bool relay_on() const;
  double vacuum_kpa() const;
  JointMode mode() const;
  double joint_angle_rad() const;
  double fixed_target_rad() const;
  /// Gravity the accelerometer reads now, head frame.
  Eigen::Vector3d GravityHead() const;

 private:
  void Run();
  void HandleLine(const std::string& line);
  std::string Execute(std::uint32_t seq, const std::string& verb,
                      const std::vector<std::string>& args);
  void Tick();
  void Write(const std::string& bytes);

  const FakeMicroControllerOptions options_;
  int master_fd_ = -1;
  int slave_fd_ = -1;
  int wake_pipe_[2] = {-1, -1};
  std::string slave_path_;

  mutable std::mutex mutex_;
  std::mutex write_mutex_;
  // World and controller state, guarded by mutex_.
  bool item_ = true;
  Eigen::Vector3d g_tool_;
  bool relay_ = false;
  double kpa_ = 0.0;
  JointMode mode_ = JointMode::kUnactuated;
  double q_rad_ = 0.0;
  double target_rad_ = 0.0;
  KeepVerticalController controller_;
  int garble_ = 0;
  int truncate_ = 0;
  int drop_ = 0;
  bool silent_ = false;
  std::vector<std::string> commands_;
  int garbled_commands_ = 0;

  std::thread thread_;
};

}  // namespace picking::gripper::testing
