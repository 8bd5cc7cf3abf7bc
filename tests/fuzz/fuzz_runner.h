#pragma once

#include <grpcpp/channel.h>

#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace picking::testing {

/// A valid call the fuzzer starts from: the request messages in protobuf text format (one
/// per stream message; one for a unary call).
struct FuzzSeed {
  std::string method;  // e.g. "MoveJoints".
  std::vector<std::string> requests_text;
  /// Sent once unmutated before fuzzing starts; it must answer OK, which proves the seed
  /// reaches past validation (a fuzzer whose seeds are all refused tests little).
  bool must_succeed = true;
};

/// One server under fuzzing. Every RPC of `service` is called; one without a seed starts
/// from the empty request.
struct FuzzTarget {
  std::string service;  // Full name, e.g. "picking.robot.v1.RobotService".
  std::shared_ptr<grpc::Channel> channel;
  std::vector<FuzzSeed> seeds;
  std::vector<std::string> dictionary;  // Meaningful strings (item names, sessions).
  std::chrono::milliseconds default_deadline{10000};
  std::map<std::string, std::chrono::milliseconds> deadlines;  // Per method.
  std::map<std::string, int> weights;                          // Per method; default 1.
  /// False once the server process has exited.
  std::function<bool()> alive;
  /// A snapshot of the state a refused call must not change (the simulator's ground
  /// truth); compared before and after every refused call. Optional.
  std::function<std::string()> truth;
  /// Brings the server back to a state where calls can succeed (e.g. resets a protective
  /// stop a fuzzed call triggered); run after every call. Optional.
  std::function<void()> restore;
};

struct FuzzOptions {
  std::uint64_t seed = 20161;
  int calls = 300;
  int health_every = 20;  // Calls between health checks.
};

/// The budget and seed from PICKING_FUZZ_CALLS and PICKING_FUZZ_SEED when set (the longer
/// run: `PICKING_FUZZ_CALLS=20000 ctest -L fuzz`), else `default_calls` and a fixed seed.
FuzzOptions FuzzOptionsFromEnvironment(int default_calls);

struct FuzzReport {
  int calls = 0;
  std::map<std::string, std::map<std::string, int>> codes;  // method -> status code -> count.
  std::map<std::string, long> slowest_ms;                   // method -> longest call.
  std::vector<std::string> failures;  // One line each (the first ones in full).
  int failure_count = 0;
  std::string Summary() const;
};

/// Sends `options.calls` seeded mutated calls (structure-aware mutations, stream-level
/// drops and repeats, byte-level mutations, random bytes, cancelled calls) and checks after
/// each that the server is alive, that the call ended within its deadline, that the status
/// is not INTERNAL or UNKNOWN (except gRPC's own answer to bytes that do not parse as the
/// request), that the error message is short, and that a refused call left the truth
/// snapshot unchanged (not checked for the call right after a cancelled one, which the
/// server may still be finishing). Stops early once the server has died.
FuzzReport RunFuzz(const FuzzTarget& target, const FuzzOptions& options);

}  // namespace picking::testing
