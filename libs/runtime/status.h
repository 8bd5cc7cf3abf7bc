#pragma once

#include <grpcpp/support/status.h>

#include <exception>
#include <string>
#include <utility>

#include "libs/errors/errors.h"

namespace picking::runtime {

/// Maps the exception currently being handled onto a gRPC status with its message
/// (see libs/errors/errors.h for the mapping). Exceptions of other types are bugs and
/// become INTERNAL.
grpc::Status StatusFromCurrentException();

/// Runs `fn` (returning grpc::Status) and turns any exception it throws into a status, so
/// an adapter's handler reads as straight-line code.
template <class Fn>
grpc::Status Guard(Fn&& fn) {
  try {
    return std::forward<Fn>(fn)();
  } catch (...) {
    return StatusFromCurrentException();
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
