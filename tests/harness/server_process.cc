#include "tests/harness/server_process.h"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>

#ifndef PICKING_BIN_DIR
#error "PICKING_BIN_DIR must name the directory holding the server binaries"
#endif

namespace picking::testing {
namespace {

int StatusFromWait(int wstatus) {
  if (WIFEXITED(wstatus)) return WEXITSTATUS(wstatus);
  if (WIFSIGNALED(wstatus)) return 128 + WTERMSIG(wstatus);
  return -1;
}

// Waits for a child to exit without polling in a sleep loop: a pidfd becomes readable
// when the process ends.
int WaitPid(pid_t pid, std::chrono::milliseconds timeout, bool* exited) {
  *exited = false;
  const int pidfd = static_cast<int>(syscall(SYS_pidfd_open, pid, 0));
  if (pidfd >= 0) {
    pollfd p{pidfd, POLLIN, 0};
    const int r = poll(&p, 1, static_cast<int>(timeout.count()));
    close(pidfd);
    if (r <= 0) return -1;
  }
  int wstatus = 0;
  const pid_t w = waitpid(pid, &wstatus, pidfd >= 0 ? 0 : 0);
  if (w != pid) return -1;
  *exited = true;
  return StatusFromWait(wstatus);
}

// Reads from `fd` until `stop` is found or the deadline passes; returns what was read.
std::string ReadUntil(int fd, const std::string& stop, std::chrono::milliseconds timeout,
                      bool* found) {
  *found = false;
  std::string text;
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  char buf[4096];
  while (true) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) return text;
    pollfd p{fd, POLLIN, 0};
    const int r = poll(&p, 1, static_cast<int>(left.count()));
    if (r < 0 && errno == EINTR) continue;
    if (r <= 0) return text;
    const ssize_t n = read(fd, buf, sizeof(buf));
    if (n <= 0) return text;  // EOF: the process closed stdout (exited).
    text.append(buf, static_cast<std::size_t>(n));
    if (text.find(stop) != std::string::npos) {
      *found = true;
      return text;
    }
  }
}

pid_t Spawn(const std::string& binary, const std::vector<std::string>& args, int* out_fd,
            bool merge_stderr) {
  int fds[2];
  if (pipe2(fds, O_CLOEXEC) != 0) throw std::runtime_error("pipe failed");
  const pid_t pid = fork();
  if (pid < 0) throw std::runtime_error("fork failed");
  if (pid == 0) {
    dup2(fds[1], STDOUT_FILENO);
    if (merge_stderr) dup2(fds[1], STDERR_FILENO);
    std::vector<char*> argv;
    argv.push_back(const_cast<char*>(binary.c_str()));
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    execv(binary.c_str(), argv.data());
    const std::string msg = "cannot exec " + binary + ": " + std::strerror(errno) + "\n";
    (void)!write(STDERR_FILENO, msg.data(), msg.size());
    _exit(127);
  }
  close(fds[1]);
  *out_fd = fds[0];
  return pid;
}

}  // namespace

std::string ServerBinary(const std::string& name) {
  return std::string(PICKING_BIN_DIR) + "/" + name;
}

ServerProcess::ServerProcess(const std::string& binary, std::vector<std::string> extra_args,
                             std::chrono::milliseconds startup_timeout) {
  std::vector<std::string> args{"--listen=127.0.0.1:0"};
  args.insert(args.end(), extra_args.begin(), extra_args.end());
  pid_ = Spawn(binary, args, &stdout_fd_, /*merge_stderr=*/false);
  bool found = false;
  const std::string text = ReadUntil(stdout_fd_, "\n", startup_timeout, &found);
  const std::string prefix = "listening on ";
  const auto pos = text.find(prefix);
  if (!found || pos != 0) {
    Stop(std::chrono::seconds(5));
    throw std::runtime_error(binary + " did not report its port; it printed: '" + text + "'");
  }
  address_ = text.substr(prefix.size(), text.find('\n') - prefix.size());
  port_ = std::stoi(address_.substr(address_.rfind(':') + 1));
  if (port_ <= 0) throw std::runtime_error("bad port in '" + text + "'");
}

ServerProcess::~ServerProcess() {
  if (pid_ > 0) {
    kill(pid_, SIGKILL);
    int wstatus = 0;
    waitpid(pid_, &wstatus, 0);
  }
  if (stdout_fd_ >= 0) close(stdout_fd_);
}

std::shared_ptr<grpc::Channel> ServerProcess::Channel() const {
  return Channel(runtime::ChannelFactory());
}

std::shared_ptr<grpc::Channel> ServerProcess::Channel(
    const runtime::ChannelFactory& channels) const {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 * 1024 * 1024);
  args.SetMaxSendMessageSize(64 * 1024 * 1024);
  return channels.Connect(address_, args);
}

int ServerProcess::WaitExit(std::chrono::milliseconds timeout) {
  bool exited = false;
  const int status = WaitPid(pid_, timeout, &exited);
  if (exited) {
    pid_ = -1;
    return status;
  }
  return -1;
}

bool ServerProcess::Alive() {
  if (pid_ <= 0) return false;
  int wstatus = 0;
  if (waitpid(pid_, &wstatus, WNOHANG) != pid_) return true;
  exit_status_ = StatusFromWait(wstatus);
  pid_ = -1;
  return false;
}

int ServerProcess::Stop(std::chrono::milliseconds timeout) {
  if (pid_ <= 0) return -1;
  kill(pid_, SIGTERM);
  const int status = WaitExit(timeout);
  if (pid_ > 0) {
    kill(pid_, SIGKILL);
    int wstatus = 0;
    waitpid(pid_, &wstatus, 0);
    pid_ = -1;
    return -1;
  }
  return status;
}

ProgramResult RunProgram(const std::string& binary, const std::vector<std::string>& args,
                         std::chrono::milliseconds timeout) {
  int fd = -1;
  const pid_t pid = Spawn(binary, args, &fd, /*merge_stderr=*/true);
  ProgramResult result;
  bool found = false;
  // Read to EOF (the marker never appears), bounded by the timeout.
  result.output = ReadUntil(fd, std::string("\0\x01\x02", 3), timeout, &found);
  close(fd);
  bool exited = false;
  result.exit_status = WaitPid(pid, std::chrono::seconds(5), &exited);
  if (!exited) {
    kill(pid, SIGKILL);
    int wstatus = 0;
    waitpid(pid, &wstatus, 0);
    result.exit_status = -1;
  }
  return result;
}

}  // namespace picking::testing
