#include "libs/runtime/status.h"

#include "libs/runtime/log.h"

namespace picking::runtime {

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
