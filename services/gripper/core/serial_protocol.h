#pragma once

#include <Eigen/Core>

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "services/gripper/core/gripper_types.h"

/// The ASCII line protocol between the gripper service and the gripper's micro controller
/// (docs/gripper-serial-protocol.md). Every line is `$<body>*HH\n`: HH is the XOR of the body's
/// bytes as two upper-case hex digits (as in NMEA 0183). Commands carry a sequence number
/// (`<seq> <verb> [args]`), replies echo it (`OK <seq> [payload]` or `ERR <seq> <reason>`).
/// Numbers use '.' as the decimal separator whatever the locale.
namespace picking::gripper::serial {

/// Longest line either side sends, including `$`, `*HH` and the newline.
constexpr std::size_t kMaxLineBytes = 128;
/// Sequence numbers run 0..kMaxSeq and wrap.
constexpr std::uint32_t kMaxSeq = 65535;

/// XOR of the bytes of `body`.
std::uint8_t Checksum(std::string_view body);

/// `$<body>*HH\n`. Throws std::invalid_argument if the body contains '$', '*', a control
/// character, or makes the line longer than kMaxLineBytes.
std::string EncodeLine(std::string_view body);

/// The body of one received line (without its newline; a trailing '\r' is ignored), or
/// nothing when it is garbled: no '$' start, no '*HH' end, wrong checksum, or bytes before
/// '$' (a partial line glued to the next).
std::optional<std::string> DecodeLine(std::string_view line);

/// Splits a body into its space-separated fields.
std::vector<std::string> SplitFields(std::string_view body);

/// A decimal number in the protocol's format ("%.*f", C locale).
std::string FormatNumber(double value, int decimals);
/// Parses a whole field as a finite decimal number; nothing if it is not one.
std::optional<double> ParseNumber(std::string_view field);
/// Parses a whole field as a sequence number in [0, kMaxSeq].
std::optional<std::uint32_t> ParseSeq(std::string_view field);

/// A decoded command: `<seq> <verb> [args...]`.
struct Command {
  std::uint32_t seq = 0;
  std::string verb;
  std::vector<std::string> args;
};
std::string CommandBody(std::uint32_t seq, std::string_view command);
std::optional<Command> ParseCommand(std::string_view body);

/// A decoded reply.
struct Reply {
  bool ok = false;
  std::uint32_t seq = 0;
  /// OK: the payload's fields; ERR: the reason code followed by any detail words.
  std::vector<std::string> fields;
};
std::string OkBody(std::uint32_t seq, std::string_view payload = {});
std::string ErrBody(std::uint32_t seq, std::string_view reason);
std::optional<Reply> ParseReply(std::string_view body);

/// One-letter codes of the joint modes on the wire: U, F, K.
char ModeCode(JointMode mode);
std::optional<JointMode> ModeFromCode(std::string_view code);

/// The answer to `Q`: `P <kpa> A <ax> <ay> <az> J <deg> M <mode> R <relay>`.
struct Telemetry {
  double vacuum_kpa = 0.0;                                      ///< Gauge vacuum, kPa.
  Eigen::Vector3d gravity_head_m_s2 = Eigen::Vector3d::Zero();  ///< Head frame, m/s^2.
  double joint_deg = 0.0;                                       ///< Servo angle, degrees.
  JointMode mode = JointMode::kUnactuated;
  bool relay_on = false;  ///< Vacuum pump relay.
};
std::string FormatTelemetry(const Telemetry& telemetry);
/// Throws std::invalid_argument naming the missing or malformed field.
Telemetry ParseTelemetry(const std::vector<std::string>& fields);

/// Splits a byte stream into lines. Lines longer than the limit are dropped up to their
/// newline and counted, so a stream of noise without newlines cannot grow the buffer.
class LineReader final {
 public:
  explicit LineReader(std::size_t max_line_bytes = kMaxLineBytes);

  void Append(std::string_view bytes);
  /// The next complete line without its '\n', or nothing.
  std::optional<std::string> Next();
  /// Drops the partial line being received.
  void Clear();

  std::size_t overlong_lines() const { return overlong_lines_; }

 private:
  std::size_t max_line_bytes_;
  std::string buffer_;
  bool skipping_ = false;
  std::size_t overlong_lines_ = 0;
};

}  // namespace picking::gripper::serial
