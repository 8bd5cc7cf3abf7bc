#pragma once

#include <ostream>
#include <string>

namespace picking::cli {

/// `picking call ADDRESS SERVICE/METHOD [JSON]`: calls any method of any server by name,
/// without generated code. The method's request and reply types are resolved through the
/// server's reflection service (grpc.reflection.v1), the request is read from `json`
/// (protobuf's JSON mapping; "{}" when empty) and each reply is printed to `out` as one line of
/// JSON (proto field names). Streaming methods get the one request, and print every reply.
///
/// Returns the exit status: 0 the call succeeded; 2 bad usage, an unknown service or method,
/// or a request that is not the method's request type; 3 reflection or the call failed (the
/// message and the status code go to `err`).
int Call(const std::string& address, const std::string& method, const std::string& json,
         std::ostream& out, std::ostream& err);

}  // namespace picking::cli
