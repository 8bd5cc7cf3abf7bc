#pragma once

#include <grpcpp/channel.h>
#include <grpcpp/support/status.h>

#include <chrono>
#include <memory>
#include <string>
#include <vector>

namespace picking::testing {

/// One call of any RPC kind (unary, client, server or bidirectional streaming) with
/// already-serialized request messages: the same wire protocol carries all four, so the
/// fuzzer needs no generated stubs and can send bytes no stub would.
struct GenericCallPlan {
  std::string method_path;            // "/picking.robot.v1.RobotService/MoveJoints".
  std::vector<std::string> requests;  // Serialized messages, sent in order.
  int cancel_after_writes = -1;       // Cancel the call after this many writes (>= 0).
  int cancel_after_reads = -1;        // Cancel after this many responses (>= 0).
  std::chrono::milliseconds deadline{10000};
};

struct GenericCallResult {
  grpc::Status status;
  int responses = 0;
  std::string first_response;  // Serialized, empty if none.
  std::chrono::milliseconds elapsed{0};
  /// The call did not finish within its deadline plus a grace period: the client cancelled
  /// it itself. gRPC ends a call at its deadline, so this means something is stuck.
  bool hung = false;
};

GenericCallResult GenericCall(const std::shared_ptr<grpc::Channel>& channel,
                              const GenericCallPlan& plan);

/// grpc.health.v1 Check for the whole server ("") answers SERVING within `timeout`.
bool HealthServing(const std::shared_ptr<grpc::Channel>& channel,
                   std::chrono::milliseconds timeout);

}  // namespace picking::testing
