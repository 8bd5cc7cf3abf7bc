#pragma once

namespace grpc {
class ServerBuilder;
}

namespace picking::runtime {

/// Adds grpc.reflection.v1.ServerReflection to the server `builder` builds, beside the
/// v1alpha service that gRPC's reflection plugin adds: current tools (grpcurl, grpcui,
/// Postman) ask for v1 first, and Debian's gRPC 1.51 serves only v1alpha. Both answer from
/// the process's generated descriptor pool, which this also makes hold
/// grpc/health/v1/health.proto, so that the health service's methods resolve too.
void AddReflectionV1(grpc::ServerBuilder& builder);

}  // namespace picking::runtime
