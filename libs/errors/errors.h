#pragma once

#include <stdexcept>
#include <string>

/// Error types the core libraries throw for conditions a caller can act on. They carry no
/// gRPC dependency; service adapters map them onto status codes (libs/runtime/status.h):
///   std::invalid_argument   -> INVALID_ARGUMENT (bad input: NaN, malformed file, limits)
///   NotFoundError           -> NOT_FOUND        (unknown item, bin, session, model)
///   PreconditionError       -> FAILED_PRECONDITION (valid request, wrong state now)
///   UnavailableError        -> UNAVAILABLE      (hardware or peer service unreachable)
///   TimeoutError            -> DEADLINE_EXCEEDED (a device did not answer in time)
///   DataLossError           -> DATA_LOSS        (dropped frame, truncated stream)
///   ResourceExhaustedError  -> RESOURCE_EXHAUSTED (does not fit: bin full, too many points)
namespace picking {

class NotFoundError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

class PreconditionError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class UnavailableError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class TimeoutError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// The work was abandoned because its call was cancelled (the client left, the server stops).
class CancelledError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class DataLossError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class ResourceExhaustedError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

}  // namespace picking
