#pragma once

#include <memory>
#include <string>

#include "services/gripper/core/gripper_backend.h"
#include "services/gripper/core/serial_link.h"

namespace picking::gripper {

/// The gripper's micro controller on a serial line (docs/gripper-serial-protocol.md): vacuum
/// relay, vacuum sensor, servo and accelerometer. The controller itself runs the servo
/// modes, including keep-vertical (KeepVerticalController is its control law).
class SerialGripper final : public GripperBackend {
 public:
  /// Opens `device` (OpenSerialPort: raw 8N1 at `baud`); throws as OpenSerialPort does.
  SerialGripper(const std::string& device, int baud, const serial::SerialLinkOptions& options = {});
  /// Over an existing link (tests pass one whose open function returns a pseudo-terminal).
  explicit SerialGripper(std::unique_ptr<serial::SerialLink> link);

  std::string name() const override { return "serial"; }
  void SetVacuum(bool on) override;
  GripperReading Read() override;
  void SetJointMode(JointMode mode, double angle_rad) override;

  serial::SerialLinkStats stats() const { return link_->stats(); }

 private:
  std::unique_ptr<serial::SerialLink> link_;
};

}  // namespace picking::gripper
