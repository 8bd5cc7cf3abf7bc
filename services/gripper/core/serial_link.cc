#include "services/gripper/core/serial_link.h"

#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <termios.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <stdexcept>

#include "libs/errors/errors.h"

namespace picking::gripper::serial {
namespace {

std::int64_t NowMs() {
  return std::chrono::duration_cast<std::chrono::milliseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

speed_t BaudConstant(int baud) {
  switch (baud) {
    case 9600:
      return B9600;
    case 19200:
      return B19200;
    case 38400:
      return B38400;
    case 57600:
      return B57600;
    case 115200:
      return B115200;
    case 230400:
      return B230400;
    case 460800:
      return B460800;
    case 921600:
      return B921600;
    default:
      throw std::invalid_argument("serial.baud: unsupported rate " + std::to_string(baud) +
                                  " (use 9600, 19200, 38400, 57600, 115200, 230400, 460800 or "
                                  "921600)");
  }
}

}  // namespace

int OpenSerialPort(const std::string& device, int baud) {
  const speed_t speed = BaudConstant(baud);
  const int fd = ::open(device.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    throw UnavailableError("cannot open gripper serial device " + device + ": " +
                           std::strerror(errno));
  }
  termios tio{};
  if (::tcgetattr(fd, &tio) != 0) {
    const int err = errno;
    ::close(fd);
    throw UnavailableError("gripper serial device " + device +
                           " is not a terminal: " + std::strerror(err));
  }
  ::cfmakeraw(&tio);
  tio.c_cflag &= ~(CSIZE | PARENB | CSTOPB | CRTSCTS);
  tio.c_cflag |= CS8 | CLOCAL | CREAD;
  tio.c_iflag &= ~(IXON | IXOFF | IXANY);
  tio.c_cc[VMIN] = 0;
  tio.c_cc[VTIME] = 0;
  ::cfsetispeed(&tio, speed);
  ::cfsetospeed(&tio, speed);
  if (::tcsetattr(fd, TCSANOW, &tio) != 0) {
    const int err = errno;
    ::close(fd);
    throw UnavailableError("cannot configure gripper serial device " + device + ": " +
                           std::strerror(err));
  }
  ::tcflush(fd, TCIOFLUSH);
  return fd;
}

SerialLink::SerialLink(std::function<int()> open, std::string name,
                       const SerialLinkOptions& options)
    : open_(std::move(open)), name_(std::move(name)), options_(options) {
  if (!open_) throw std::invalid_argument("SerialLink: null open function");
  if (!(options.reply_timeout_s > 0.0) || !std::isfinite(options.reply_timeout_s)) {
    throw std::invalid_argument("serial.reply_timeout_s must be > 0");
  }
  if (options.max_attempts < 1) throw std::invalid_argument("serial.max_attempts must be >= 1");
  EnsureOpen();
}

SerialLink::~SerialLink() { CloseFd(); }

void SerialLink::CloseFd() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

void SerialLink::EnsureOpen() {
  if (fd_ >= 0) return;
  fd_ = open_();
  if (fd_ < 0) throw UnavailableError("cannot open " + name_);
  reader_.Clear();
  // A newline ends whatever partial line the controller may hold from before, so the
  // first command is parsed on its own.
  WriteAll("\n");
}

void SerialLink::WriteAll(const std::string& line) {
  std::size_t written = 0;
  const std::int64_t deadline =
      NowMs() + static_cast<std::int64_t>(options_.reply_timeout_s * 1000.0) + 1;
  while (written < line.size()) {
    const ssize_t n = ::write(fd_, line.data() + written, line.size() - written);
    if (n > 0) {
      written += static_cast<std::size_t>(n);
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK) {
      const int err = errno;
      CloseFd();
      throw UnavailableError("write to " + name_ + " failed: " + std::strerror(err));
    }
    const std::int64_t left = deadline - NowMs();
    if (left <= 0) throw UnavailableError("write to " + name_ + " timed out");
    pollfd pfd{fd_, POLLOUT, 0};
    ::poll(&pfd, 1, static_cast<int>(left));
  }
}

bool SerialLink::ReadLine(std::int64_t deadline_ms, std::string* line) {
  while (true) {
    if (auto next = reader_.Next()) {
      *line = std::move(*next);
      return true;
    }
    const std::int64_t left = deadline_ms - NowMs();
    if (left <= 0) return false;
    pollfd pfd{fd_, POLLIN, 0};
    const int ready = ::poll(&pfd, 1, static_cast<int>(left));
    if (ready < 0) {
      if (errno == EINTR) continue;
      const int err = errno;
      CloseFd();
      throw UnavailableError("poll on " + name_ + " failed: " + std::strerror(err));
    }
    if (ready == 0) continue;
    char buf[256];
    const ssize_t n = ::read(fd_, buf, sizeof(buf));
    if (n > 0) {
      reader_.Append(std::string_view(buf, static_cast<std::size_t>(n)));
      continue;
    }
    if (n < 0 && (errno == EINTR || errno == EAGAIN || errno == EWOULDBLOCK)) continue;
    // n == 0 (hang-up) or an error such as EIO when the adapter disappears.
    const std::string why = n == 0 ? std::string("hang-up") : std::strerror(errno);
    CloseFd();
    throw UnavailableError("read from " + name_ + " failed: " + why);
  }
}

std::vector<std::string> SerialLink::Transact(std::string_view command) {
  std::lock_guard<std::mutex> lock(mutex_);
  ++stats_.commands;
  if (fd_ < 0) {
    EnsureOpen();
    ++stats_.reopens;
  }
  const std::uint32_t seq = next_seq_;
  next_seq_ = next_seq_ >= kMaxSeq ? 0 : next_seq_ + 1;
  const std::string line = EncodeLine(CommandBody(seq, command));
  const auto timeout_ms = static_cast<std::int64_t>(std::ceil(options_.reply_timeout_s * 1000.0));
  for (int attempt = 1; attempt <= options_.max_attempts; ++attempt) {
    if (attempt > 1) ++stats_.retries;
    WriteAll(line);
    ++stats_.sent_lines;
    const std::int64_t deadline = NowMs() + timeout_ms;
    std::string received;
    while (true) {
      const std::size_t overlong_before = reader_.overlong_lines();
      const bool got = ReadLine(deadline, &received);
      stats_.overlong_lines += reader_.overlong_lines() - overlong_before;
      if (!got) {
        ++stats_.timeouts;
        break;
      }
      if (received.empty() || received == "\r") continue;
      std::string_view view = received;
      // A partial line glued to a complete one: the part from the last '$' may be whole.
      const std::size_t start = view.rfind('$');
      if (start != std::string_view::npos && start > 0) {
        ++stats_.garbled_lines;
        view.remove_prefix(start);
      }
      const auto body = DecodeLine(view);
      if (!body) {
        ++stats_.garbled_lines;
        continue;
      }
      const auto reply = ParseReply(*body);
      if (!reply) {
        ++stats_.garbled_lines;
        continue;
      }
      if (reply->seq != seq) {
        ++stats_.stale_replies;
        continue;
      }
      if (reply->ok) return reply->fields;
      const std::string& reason = reply->fields.front();
      std::string detail;
      for (const auto& f : reply->fields) detail += (detail.empty() ? "" : " ") + f;
      const std::string message =
          "gripper controller on " + name_ + " refused '" + std::string(command) + "': " + detail;
      if (reason == "ARG") throw std::invalid_argument(message);
      if (reason == "NOSERVO") throw PreconditionError(message);
      throw UnavailableError(message);
    }
  }
  throw UnavailableError("gripper controller on " + name_ + " did not answer '" +
                         std::string(command) + "' (" + std::to_string(options_.max_attempts) +
                         " attempts, " + FormatNumber(options_.reply_timeout_s, 3) + " s each)");
}

SerialLinkStats SerialLink::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

}  // namespace picking::gripper::serial
