#pragma once

#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include "services/gripper/core/serial_protocol.h"

namespace picking::gripper::serial {

/// Opens a serial device for the micro controller: raw mode, 8 data bits, no parity, one
/// stop bit, no flow control, non-blocking, at `baud` (one of the standard rates 9600 ..
/// 921600; 115200 for the gripper's controller). Works for /dev/ttyUSB*, /dev/ttyACM* and
/// pseudo-terminals. Throws std::invalid_argument for an unsupported rate and UnavailableError
/// naming the device when it cannot be opened or is not a terminal.
int OpenSerialPort(const std::string& device, int baud);

/// Timeouts and retries of the request/reply exchange.
struct SerialLinkOptions {
  /// How long to wait for the reply to one attempt, seconds (> 0).
  double reply_timeout_s = 0.2;
  /// Attempts per command before giving up (>= 1). Every command of the protocol is
  /// idempotent, so an attempt whose reply was lost is simply sent again.
  int max_attempts = 3;
};

/// Counters of what went wrong on the line, for logs and tests.
struct SerialLinkStats {
  std::uint64_t commands = 0;        ///< Transact() calls.
  std::uint64_t sent_lines = 0;      ///< Lines written, retries included.
  std::uint64_t retries = 0;         ///< Attempts after the first.
  std::uint64_t timeouts = 0;        ///< Attempts that got no matching reply in time.
  std::uint64_t garbled_lines = 0;   ///< Received lines discarded: checksum, framing, syntax.
  std::uint64_t overlong_lines = 0;  ///< Received lines discarded for their length.
  std::uint64_t stale_replies = 0;   ///< Valid replies to an earlier sequence number.
  std::uint64_t reopens = 0;         ///< Times the device was opened again after an I/O error.
};

/// The host side of the line protocol over a file descriptor: numbers each command, writes
/// it, waits with poll() for the reply with the same number, discards garbled, partial and
/// stale lines (counting them), and retries on timeout. Thread safe: one exchange at a time.
class SerialLink final {
 public:
  /// `open` returns a new file descriptor (the link owns and closes it); it is called now
  /// and again after an I/O error (e.g. a USB adapter unplugged and back). `name` names the
  /// device in error messages.
  SerialLink(std::function<int()> open, std::string name, const SerialLinkOptions& options = {});
  ~SerialLink();
  SerialLink(const SerialLink&) = delete;
  SerialLink& operator=(const SerialLink&) = delete;

  /// Sends `command` (e.g. "V1", "S -30.00", "Q") and returns the fields of its OK reply.
  /// Throws UnavailableError after max_attempts without a reply or on an I/O error;
  /// std::invalid_argument for `ERR <seq> ARG ...`; PreconditionError for
  /// `ERR <seq> NOSERVO ...`; UnavailableError for any other ERR.
  std::vector<std::string> Transact(std::string_view command);

  SerialLinkStats stats() const;
  const std::string& name() const { return name_; }

 private:
  void EnsureOpen();
  void CloseFd();
  void WriteAll(const std::string& line);
  // Reads until a line arrives or the deadline passes; false on timeout.
  bool ReadLine(std::int64_t deadline_ms, std::string* line);

  std::function<int()> open_;
  std::string name_;
  SerialLinkOptions options_;
  mutable std::mutex mutex_;
  int fd_ = -1;
  std::uint32_t next_seq_ = 1;
  LineReader reader_;
  SerialLinkStats stats_;
};

}  // namespace picking::gripper::serial
