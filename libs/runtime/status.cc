#include "libs/runtime/status.h"

#include "libs/runtime/log.h"

namespace picking::runtime {

const char* StatusCodeName(grpc::StatusCode code) {
  switch (code) {
    case grpc::OK:
      return "OK";
    case grpc::CANCELLED:
      return "CANCELLED";
    case grpc::UNKNOWN:
      return "UNKNOWN";
    case grpc::INVALID_ARGUMENT:
      return "INVALID_ARGUMENT";
    case grpc::DEADLINE_EXCEEDED:
      return "DEADLINE_EXCEEDED";
    case grpc::NOT_FOUND:
      return "NOT_FOUND";
    case grpc::ALREADY_EXISTS:
      return "ALREADY_EXISTS";
    case grpc::PERMISSION_DENIED:
      return "PERMISSION_DENIED";
    case grpc::RESOURCE_EXHAUSTED:
      return "RESOURCE_EXHAUSTED";
    case grpc::FAILED_PRECONDITION:
      return "FAILED_PRECONDITION";
    case grpc::ABORTED:
      return "ABORTED";
    case grpc::OUT_OF_RANGE:
      return "OUT_OF_RANGE";
    case grpc::UNIMPLEMENTED:
      return "UNIMPLEMENTED";
    case grpc::INTERNAL:
      return "INTERNAL";
    case grpc::UNAVAILABLE:
      return "UNAVAILABLE";
    case grpc::DATA_LOSS:
      return "DATA_LOSS";
    case grpc::UNAUTHENTICATED:
      return "UNAUTHENTICATED";
    default:
      return "?";
  }
}

std::string CutMessage(std::string_view message, std::size_t max_bytes) {
  if (message.size() <= max_bytes) return std::string(message);
  constexpr std::string_view kEllipsis = "...";
  if (max_bytes <= kEllipsis.size()) return std::string(kEllipsis.substr(0, max_bytes));
  std::size_t keep = max_bytes - kEllipsis.size();
  // Never split a UTF-8 sequence: back up over continuation bytes (10xxxxxx).
  while (keep > 0 && (static_cast<unsigned char>(message[keep]) & 0xC0) == 0x80) --keep;
  std::string out(message.substr(0, keep));
  out += kEllipsis;
  return out;
}

grpc::Status CutStatus(const grpc::Status& status) {
  if (status.error_message().size() <= kMaxStatusMessageBytes) return status;
  return grpc::Status(status.error_code(), CutMessage(status.error_message()),
                      status.error_details());
}

grpc::Status StatusFromCurrentException() {
  try {
    throw;
  } catch (const NotFoundError& e) {
    return grpc::Status(grpc::StatusCode::NOT_FOUND, e.what());
  } catch (const std::invalid_argument& e) {
    return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, e.what());
  } catch (const PreconditionError& e) {
    return grpc::Status(grpc::StatusCode::FAILED_PRECONDITION, e.what());
  } catch (const UnavailableError& e) {
    return grpc::Status(grpc::StatusCode::UNAVAILABLE, e.what());
  } catch (const TimeoutError& e) {
    return grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED, e.what());
  } catch (const CancelledError& e) {
    return grpc::Status(grpc::StatusCode::CANCELLED, e.what());
  } catch (const DataLossError& e) {
    return grpc::Status(grpc::StatusCode::DATA_LOSS, e.what());
  } catch (const ResourceExhaustedError& e) {
    return grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED, e.what());
  } catch (const std::exception& e) {
    LogError("internal error", {{"error", e.what()}});
    return grpc::Status(grpc::StatusCode::INTERNAL, std::string("internal error: ") + e.what());
  } catch (...) {
    LogError("internal error", {{"error", "unknown exception"}});
    return grpc::Status(grpc::StatusCode::INTERNAL, "internal error: unknown exception");
  }
}

}  // namespace picking::runtime
