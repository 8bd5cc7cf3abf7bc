#pragma once

#include <grpcpp/channel.h>

#include <memory>
#include <string>
#include <vector>

namespace picking::testing {

/// Asks a server's reflection service (grpc.reflection.v1alpha) for the services it
/// exposes. Throws std::runtime_error if the call fails.
std::vector<std::string> ListServicesByReflection(const std::shared_ptr<grpc::Channel>& channel);

/// Asks for the file descriptor that defines `symbol` and returns the names of the files
/// received (the defining file and its dependencies).
std::vector<std::string> FilesContainingSymbol(const std::shared_ptr<grpc::Channel>& channel,
                                               const std::string& symbol);

}  // namespace picking::testing
