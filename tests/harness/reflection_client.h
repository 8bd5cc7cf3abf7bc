#pragma once

#include <grpcpp/channel.h>

#include <memory>
#include <string>
#include <vector>

namespace picking::testing {

/// The versions of the reflection service a server answers: grpc.reflection.v1alpha (gRPC's
/// own plugin) and grpc.reflection.v1 (the one current tools ask for first).
enum class ReflectionVersion { kV1Alpha, kV1 };

/// Asks a server's reflection service for the services it exposes. Throws
/// std::runtime_error if the call fails.
std::vector<std::string> ListServicesByReflection(
    const std::shared_ptr<grpc::Channel>& channel,
    ReflectionVersion version = ReflectionVersion::kV1Alpha);

/// Asks for the file descriptor that defines `symbol` and returns the names of the files
/// received (the defining file and its dependencies). Throws std::runtime_error if the call
/// fails or the server answers with an error (the message includes the server's).
std::vector<std::string> FilesContainingSymbol(
    const std::shared_ptr<grpc::Channel>& channel, const std::string& symbol,
    ReflectionVersion version = ReflectionVersion::kV1Alpha);

}  // namespace picking::testing
