#include "services/robot/core/byte_stream.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace picking::robot {
namespace {

constexpr std::size_t kMaxLine = 64 * 1024;

std::string Errno(const std::string& what) { return what + ": " + std::strerror(errno); }

int RemainingMs(std::chrono::steady_clock::time_point deadline) {
  const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
      deadline - std::chrono::steady_clock::now());
  return left.count() < 0 ? 0 : static_cast<int>(left.count());
}

// Waits until fd is readable (or writable); false on timeout.
bool WaitFor(int fd, short events, std::chrono::steady_clock::time_point deadline) {
  while (true) {
    pollfd p{fd, events, 0};
    const int n = ::poll(&p, 1, RemainingMs(deadline));
    if (n > 0) return true;
    if (n == 0) return false;
    if (errno != EINTR) throw StreamError(Errno("poll"));
  }
}

}  // namespace

std::unique_ptr<TcpStream> TcpStream::Connect(const std::string& host, std::uint16_t port,
                                              std::chrono::milliseconds timeout) {
  const std::string where = host + ":" + std::to_string(port);
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* addresses = nullptr;
  const int rc = ::getaddrinfo(host.c_str(), std::to_string(port).c_str(), &hints, &addresses);
  if (rc != 0) throw StreamError("cannot resolve " + where + ": " + ::gai_strerror(rc));
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  std::string last_error = "no address";
  for (addrinfo* a = addresses; a != nullptr; a = a->ai_next) {
    const int fd = ::socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC, a->ai_protocol);
    if (fd < 0) {
      last_error = Errno("socket");
      continue;
    }
    const int flags = ::fcntl(fd, F_GETFL, 0);
    ::fcntl(fd, F_SETFL, flags | O_NONBLOCK);
    int result = ::connect(fd, a->ai_addr, a->ai_addrlen);
    if (result != 0 && errno == EINPROGRESS) {
      if (WaitFor(fd, POLLOUT, deadline)) {
        int error = 0;
        socklen_t len = sizeof(error);
        ::getsockopt(fd, SOL_SOCKET, SO_ERROR, &error, &len);
        result = error == 0 ? 0 : -1;
        errno = error;
      } else {
        errno = ETIMEDOUT;
      }
    }
    if (result == 0) {
      ::fcntl(fd, F_SETFL, flags);
      ::freeaddrinfo(addresses);
      return std::make_unique<TcpStream>(fd);
    }
    last_error = Errno("connect");
    ::close(fd);
  }
  ::freeaddrinfo(addresses);
  throw StreamError("cannot connect to " + where + ": " + last_error);
}

TcpStream::TcpStream(int fd) : fd_(fd) {
  const int one = 1;
  ::setsockopt(fd_, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
}

TcpStream::~TcpStream() {
  Close();
  ::close(fd_);
}

void TcpStream::Close() { ::shutdown(fd_, SHUT_RDWR); }

void TcpStream::WriteAll(const std::string& bytes) {
  std::size_t sent = 0;
  while (sent < bytes.size()) {
    const ssize_t n = ::send(fd_, bytes.data() + sent, bytes.size() - sent, MSG_NOSIGNAL);
    if (n < 0) {
      if (errno == EINTR) continue;
      throw StreamError(Errno("send"));
    }
    sent += static_cast<std::size_t>(n);
  }
}

void TcpStream::Fill(std::chrono::steady_clock::time_point deadline) {
  if (!WaitFor(fd_, POLLIN, deadline)) throw StreamError("read timed out");
  char chunk[4096];
  while (true) {
    const ssize_t n = ::recv(fd_, chunk, sizeof(chunk), 0);
    if (n > 0) {
      buffer_.append(chunk, static_cast<std::size_t>(n));
      return;
    }
    if (n == 0) throw StreamError("connection closed by peer");
    if (errno != EINTR) throw StreamError(Errno("recv"));
  }
}

std::string TcpStream::ReadExact(std::size_t size, std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (buffer_.size() < size) Fill(deadline);
  std::string out = buffer_.substr(0, size);
  buffer_.erase(0, size);
  return out;
}

std::string TcpStream::ReadLine(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  std::size_t newline;
  while ((newline = buffer_.find('\n')) == std::string::npos) {
    if (buffer_.size() > kMaxLine) throw StreamError("line longer than 64 KiB");
    Fill(deadline);
  }
  std::string line = buffer_.substr(0, newline);
  buffer_.erase(0, newline + 1);
  if (!line.empty() && line.back() == '\r') line.pop_back();
  return line;
}

TcpListener::TcpListener(std::uint16_t port) {
  fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd_ < 0) throw StreamError(Errno("socket"));
  const int one = 1;
  ::setsockopt(fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  address.sin_port = htons(port);
  if (::bind(fd_, reinterpret_cast<sockaddr*>(&address), sizeof(address)) != 0 ||
      ::listen(fd_, 8) != 0) {
    const std::string error = Errno("bind/listen on 127.0.0.1:" + std::to_string(port));
    ::close(fd_);
    throw StreamError(error);
  }
  socklen_t len = sizeof(address);
  ::getsockname(fd_, reinterpret_cast<sockaddr*>(&address), &len);
  port_ = ntohs(address.sin_port);
}

TcpListener::~TcpListener() {
  Close();
  ::close(fd_);
}

void TcpListener::Close() { ::shutdown(fd_, SHUT_RDWR); }

std::unique_ptr<TcpStream> TcpListener::Accept(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  if (!WaitFor(fd_, POLLIN, deadline)) throw StreamError("accept timed out");
  const int fd = ::accept4(fd_, nullptr, nullptr, SOCK_CLOEXEC);
  if (fd < 0) throw StreamError(Errno("accept"));
  return std::make_unique<TcpStream>(fd);
}

}  // namespace picking::robot
