#pragma once

#include <grpcpp/support/status.h>

#include <cstddef>
#include <exception>
#include <string>
#include <string_view>
#include <utility>

#include "libs/errors/errors.h"

namespace picking::runtime {

/// Longest status message a service sends, bytes. gRPC carries the message in the
/// trailing metadata, and a client with the default 8 KB metadata limit sees
/// RESOURCE_EXHAUSTED instead of the real status when a message quotes a long request
/// string in full; 1 kB leaves room for percent-encoding.
constexpr std::size_t kMaxStatusMessageBytes = 1024;

/// Longest prefix of a request string (a name, a path, a reason) quoted in a message.
constexpr std::size_t kMaxQuotedBytes = 64;

/// `message` if it has at most `max_bytes` bytes, else its first bytes (cut at a UTF-8
/// character boundary) followed by "..." so that the result has at most `max_bytes` bytes.
std::string CutMessage(std::string_view message, std::size_t max_bytes = kMaxStatusMessageBytes);

/// A request string as messages quote it: at most kMaxQuotedBytes, "..." marking a cut.
inline std::string Quoted(std::string_view text) { return CutMessage(text, kMaxQuotedBytes); }

/// `status` with its message cut to kMaxStatusMessageBytes (code and details unchanged).
grpc::Status CutStatus(const grpc::Status& status);

/// The code's name as gRPC writes it ("FAILED_PRECONDITION"); "?" for a number it does not
/// define.
const char* StatusCodeName(grpc::StatusCode code);

/// Maps the exception currently being handled onto a gRPC status with its message
/// (see libs/errors/errors.h for the mapping). Exceptions of other types are bugs and
/// become INTERNAL.
grpc::Status StatusFromCurrentException();

/// Runs `fn` (returning grpc::Status) and turns any exception it throws into a status, so
/// an adapter's handler reads as straight-line code. Every status it returns has its
/// message cut (CutStatus): this is the one place the services bound their messages.
template <class Fn>
grpc::Status Guard(Fn&& fn) {
  try {
    return CutStatus(std::forward<Fn>(fn)());
  } catch (...) {
    return CutStatus(StatusFromCurrentException());
  }
}

inline grpc::Status InvalidArgument(std::string message) {
  return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, std::move(message));
}
inline grpc::Status NotFound(std::string message) {
  return grpc::Status(grpc::StatusCode::NOT_FOUND, std::move(message));
}
inline grpc::Status FailedPrecondition(std::string message) {
  return grpc::Status(grpc::StatusCode::FAILED_PRECONDITION, std::move(message));
}
inline grpc::Status Unavailable(std::string message) {
  return grpc::Status(grpc::StatusCode::UNAVAILABLE, std::move(message));
}

}  // namespace picking::runtime
