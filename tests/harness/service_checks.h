#pragma once

#include <string>

namespace picking::testing {

/// The checks every server must pass, shared by the per-service integration tests: starts
/// `binary` on port 0, then
///  - grpc.health.v1 Check answers SERVING for "" and for `service_full_name`, and
///    NOT_FOUND for an unknown service;
///  - reflection lists `service_full_name` and the health service, and returns the
///    descriptor of `proto_file` for the service symbol;
///  - SIGTERM stops it with exit status 0.
/// Uses GoogleTest assertions.
void ExpectStandardServerBehaviour(const std::string& binary, const std::string& service_full_name,
                                   const std::string& proto_file);

/// A bad flag or setting makes the binary exit with status 2 and a message naming it.
void ExpectRejectsBadFlags(const std::string& binary);

}  // namespace picking::testing
