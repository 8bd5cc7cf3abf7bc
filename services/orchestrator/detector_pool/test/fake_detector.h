#pragma once

#include <grpcpp/server.h>

#include <chrono>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "grpc/health/v1/health.grpc.pb.h"
#include "picking/detector/v1/detector.grpc.pb.h"

/// An in-process stand-in for picking-detector that the pool's tests steer: answer, fail with
/// a chosen status, hang until released, or meet other calls before answering. It serves
/// grpc.health.v1 like the real server.
namespace picking::orchestrator::testing {

/// What a fake does with a call.
enum class FakeMode {
  kAnswer,           ///< One OK result per query (item names echoed), score 0.75 for Verify.
  kUnavailable,      ///< UNAVAILABLE, as a replica going away answers.
  kInvalidArgument,  ///< INVALID_ARGUMENT, as for a bad cloud.
  kNotFound,         ///< NOT_FOUND.
  kHang,             ///< No answer until Release() (the client's deadline or cancel ends it).
};

/// Holds calls (across fakes) until `count` of them have arrived: proof that they ran at once.
class Rendezvous final {
 public:
  explicit Rendezvous(int count) : count_(count) {}
  /// False when the others did not come within `timeout`.
  bool Arrive(std::chrono::milliseconds timeout);

 private:
  std::mutex mutex_;
  std::condition_variable cv_;
  int count_;
  int arrived_ = 0;
};

class FakeDetector final : public picking::detector::v1::DetectorService::Service {
 public:
  grpc::Status Detect(grpc::ServerContext* ctx,
                      grpc::ServerReader<picking::detector::v1::DetectRequest>* reader,
                      picking::detector::v1::DetectResponse* response) override;
  grpc::Status Verify(grpc::ServerContext* ctx,
                      grpc::ServerReader<picking::detector::v1::VerifyRequest>* reader,
                      picking::detector::v1::VerifyResponse* response) override;

  /// `mode` for the next `times` calls (-1: every call), kAnswer after them.
  void SetMode(FakeMode mode, int times = -1);
  /// Every later call first waits at `rendezvous` (ABORTED if the others do not come).
  void SetRendezvous(std::shared_ptr<Rendezvous> rendezvous);
  /// Ends every hang, now and later.
  void Release();

  /// The first queried item of each call received (Verify: its item), in arrival order.
  std::vector<std::string> calls() const;
  /// Most calls that were running at once.
  int max_concurrent() const;

 private:
  // Records the call, then hangs, fails or meets the rendezvous as told; OK means answer.
  grpc::Status Behave(const std::string& item);

  mutable std::mutex mutex_;
  std::condition_variable released_cv_;
  FakeMode mode_ = FakeMode::kAnswer;
  int times_ = 0;
  bool released_ = false;
  std::shared_ptr<Rendezvous> rendezvous_;
  std::vector<std::string> calls_;
  int running_ = 0;
  int max_running_ = 0;
};

/// grpc.health.v1 as the real servers answer it ("" and the detector service), which can also
/// be told to hold checks until released.
class FakeHealth final : public grpc::health::v1::Health::Service {
 public:
  grpc::Status Check(grpc::ServerContext* ctx, const grpc::health::v1::HealthCheckRequest* request,
                     grpc::health::v1::HealthCheckResponse* response) override;
  /// Streams the status and every change of it (gRPC's client-side health checking), until
  /// Release() or the client goes away.
  grpc::Status Watch(grpc::ServerContext* ctx, const grpc::health::v1::HealthCheckRequest* request,
                     grpc::ServerWriter<grpc::health::v1::HealthCheckResponse>* writer) override;
  void SetServing(bool serving);
  /// Later Checks wait until Release() (or the client's cancel, seen at release).
  void HoldChecks();
  void Release();
  /// Blocks until a held check has arrived; false after 30 s without one.
  bool WaitForHeldCheck();

 private:
  std::mutex mutex_;
  std::condition_variable cv_;
  bool serving_ = true;
  bool hold_ = false;
  bool released_ = false;
  int held_ = 0;
};

/// A FakeDetector and a FakeHealth served on 127.0.0.1 (a free port), SERVING.
class FakeReplica final {
 public:
  FakeReplica();
  ~FakeReplica();
  FakeReplica(const FakeReplica&) = delete;
  FakeReplica& operator=(const FakeReplica&) = delete;

  /// Stops serving (releases hangs first); the port is then refused.
  void Shutdown();
  /// Serves again on the same port with a fresh FakeDetector.
  void Restart();
  /// Sets the detector service's health status.
  void SetServing(bool serving);

  FakeDetector& detector() { return *detector_; }
  FakeHealth& health() { return *health_; }
  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }
  int port() const { return port_; }

 private:
  void Start(int port);

  std::unique_ptr<FakeDetector> detector_;
  std::unique_ptr<FakeHealth> health_;
  std::unique_ptr<grpc::Server> server_;
  int port_ = 0;
};

}  // namespace picking::orchestrator::testing
