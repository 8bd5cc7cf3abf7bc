#include "services/gripper/core/serial_gripper.h"

#include <cmath>
#include <stdexcept>

#include "libs/errors/errors.h"

namespace picking::gripper {
namespace {

constexpr double kPi = 3.14159265358979323846;

}  // namespace

SerialGripper::SerialGripper(const std::string& device, int baud,
                             const serial::SerialLinkOptions& options)
    : link_(std::make_unique<serial::SerialLink>(
          [device, baud] { return serial::OpenSerialPort(device, baud); }, device, options)) {}

SerialGripper::SerialGripper(std::unique_ptr<serial::SerialLink> link) : link_(std::move(link)) {
  if (!link_) throw std::invalid_argument("SerialGripper: null link");
}

void SerialGripper::SetVacuum(bool on) { link_->Transact(on ? "V1" : "V0"); }

GripperReading SerialGripper::Read() {
  const std::vector<std::string> fields = link_->Transact("Q");
  serial::Telemetry t;
  try {
    t = serial::ParseTelemetry(fields);
  } catch (const std::invalid_argument& e) {
    // The line's checksum was right, so this is firmware speaking another dialect.
    throw UnavailableError("gripper controller on " + link_->name() +
                           " sent unreadable telemetry: " + e.what());
  }
  GripperReading r;
  r.vacuum_on = t.relay_on;
  r.vacuum_kpa = t.vacuum_kpa;
  r.joint_mode = t.mode;
  r.joint_angle_rad = t.joint_deg * kPi / 180.0;
  r.gravity_head_m_s2 = t.gravity_head_m_s2;
  return r;
}

void SerialGripper::SetJointMode(JointMode mode, double angle_rad) {
  if (mode == JointMode::kFixed) {
    // The held angle first, then the mode, so the servo never holds a stale angle.
    link_->Transact("S " + serial::FormatNumber(angle_rad * 180.0 / kPi, 2));
  }
  link_->Transact(std::string("M ") + serial::ModeCode(mode));
}

}  // namespace picking::gripper
