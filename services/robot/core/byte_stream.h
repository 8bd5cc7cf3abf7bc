#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>

namespace picking::robot {

/// Thrown by ByteStream on connection loss, timeout or socket errors.
class StreamError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A bidirectional, ordered byte stream (a TCP connection in production, anything in tests).
/// Write and Read may be called from different threads; two concurrent readers (or writers)
/// are not allowed.
class ByteStream {
 public:
  virtual ~ByteStream() = default;
  /// Writes all bytes. @throws StreamError if the stream is closed or broken.
  virtual void WriteAll(const std::string& bytes) = 0;
  /// Reads exactly `size` bytes, waiting at most `timeout` for them.
  /// @throws StreamError on end of stream, error or timeout.
  virtual std::string ReadExact(std::size_t size, std::chrono::milliseconds timeout) = 0;
  /// Reads up to and including the next '\n' (returned without "\r\n"/"\n").
  /// @throws StreamError on end of stream, error, timeout or a line over 64 KiB.
  virtual std::string ReadLine(std::chrono::milliseconds timeout) = 0;
  /// Shuts the stream down; blocked readers return with StreamError. Idempotent.
  virtual void Close() = 0;
};

/// A connected TCP stream (IPv4 or IPv6, TCP_NODELAY set).
class TcpStream final : public ByteStream {
 public:
  /// Connects to host:port within `timeout`. @throws StreamError naming host and port.
  static std::unique_ptr<TcpStream> Connect(const std::string& host, std::uint16_t port,
                                            std::chrono::milliseconds timeout);
  /// Takes ownership of a connected socket descriptor.
  explicit TcpStream(int fd);
  ~TcpStream() override;
  TcpStream(const TcpStream&) = delete;
  TcpStream& operator=(const TcpStream&) = delete;

  void WriteAll(const std::string& bytes) override;
  std::string ReadExact(std::size_t size, std::chrono::milliseconds timeout) override;
  std::string ReadLine(std::chrono::milliseconds timeout) override;
  void Close() override;

 private:
  // Appends at least one byte to buffer_ or throws.
  void Fill(std::chrono::steady_clock::time_point deadline);

  int fd_;
  std::string buffer_;
};

/// A listening TCP socket on the loopback interface (servers in tests, local simulators).
class TcpListener final {
 public:
  /// Binds 127.0.0.1:`port` (0 = any free port) and listens. @throws StreamError.
  explicit TcpListener(std::uint16_t port = 0);
  ~TcpListener();
  TcpListener(const TcpListener&) = delete;
  TcpListener& operator=(const TcpListener&) = delete;

  /// The bound port.
  std::uint16_t port() const { return port_; }
  /// Waits at most `timeout` for a connection. @throws StreamError on timeout or after Close().
  std::unique_ptr<TcpStream> Accept(std::chrono::milliseconds timeout);
  /// Stops listening; a blocked Accept returns with StreamError.
  void Close();

 private:
  int fd_;
  std::uint16_t port_ = 0;
};

}  // namespace picking::robot
