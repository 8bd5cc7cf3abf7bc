#pragma once

#include <grpcpp/channel.h>
#include <grpcpp/client_context.h>
#include <grpcpp/support/status.h>

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "libs/runtime/channel.h"
#include "libs/runtime/config.h"
#include "picking/common/v1/data.pb.h"
#include "picking/detector/v1/detector.grpc.pb.h"

/// The orchestrator's client side of detection: a pool of picking-detector replicas that
/// spreads independent calls over them, retries a call on another replica when one is
/// unreachable or too slow, and takes dead replicas out (and back in) by health checks.
namespace picking::orchestrator {

/// A cloud as the detector's client streams take it: PointCloudChunks in order, the first
/// with the header (the scanner's Scan stream gives them so; for a geometry::PointCloud use
/// proto_convert::CloudToChunks). Shared, because retries, hedges and the jobs of one scan
/// (views, methods, candidate items) send the same chunks.
using SharedCloud = std::shared_ptr<const std::vector<picking::common::v1::PointCloudChunk>>;

/// What the pool reports to an observer (logging, tests). Called from the pool's threads with
/// no lock held; it must be thread-safe and must not block for long.
struct PoolEvent {
  enum class Kind {
    kAttemptStarted,   ///< An attempt is about to be sent to `replica` (`hedge`: a copy).
    kAttemptSent,      ///< The whole request (params, cloud) is written to `replica`'s stream.
    kAttemptFinished,  ///< An attempt on `replica` ended with `status`.
    kHealthChanged,    ///< `replica` was taken out (`healthy` false) or brought back.
  };
  Kind kind = Kind::kAttemptStarted;
  std::string replica;
  bool hedge = false;
  grpc::Status status;
  bool healthy = true;
};

/// Settings of the pool (the orchestrator's `detector.*` settings, see FromConfig and
/// docs/services.md).
struct DetectorPoolOptions {
  /// The replicas: "host:port" each (one channel per replica, so the pool knows which one
  /// answered and can take one out), or "dns:///name:port" (a name resolving to many addresses,
  /// e.g. a Kubernetes headless service: one channel whose round_robin policy spreads calls
  /// over every address and whose client-side health checking skips dead ones; the pool sees
  /// it as one replica). At least one; no duplicates.
  std::vector<std::string> endpoints;
  /// Deadline of each attempt, seconds (> 0). A call that retries may take up to
  /// max_attempts x deadline_s plus the backoffs.
  double deadline_s = 30.0;
  /// Attempts per call, hedged copies included (>= 1).
  int max_attempts = 3;
  /// Wait before an attempt on a replica this call already tried (never before trying a fresh
  /// replica): backoff_initial_s, then times backoff_multiplier, at most backoff_max_s.
  double backoff_initial_s = 0.1;
  double backoff_multiplier = 2.0;
  double backoff_max_s = 2.0;
  /// Period of the background health checks, seconds; 0: no background thread (checks only by
  /// CheckHealthNow()).
  double health_period_s = 1.0;
  /// Deadline of one health check, seconds (> 0). A replica that does not answer SERVING within
  /// it is taken out.
  double health_timeout_s = 1.0;
  /// The grpc.health.v1 service name checked (the detector reports it SERVING).
  std::string health_service = "picking.detector.v1.DetectorService";
  /// Hedging, seconds (0: off): when an attempt has not answered after this long and another
  /// healthy replica is idle, a copy goes there; the first answer wins and the other is
  /// cancelled. Less than deadline_s. (gRPC C++ 1.51 ignores hedging in a service config.)
  double hedge_delay_s = 0.0;
  /// Calls one replica runs at once in DetectAll / VerifyAll (>= 1): a detection uses all of
  /// a replica's cores, so more than one mostly queues.
  int max_in_flight_per_replica = 1;
  /// Calls DetectAll / VerifyAll run at once; 0: healthy replicas x max_in_flight_per_replica.
  /// Set it for a dns:/// target, which counts as one replica however many addresses it has.
  int max_in_flight = 0;
  /// Longest wait between reconnection attempts of a replica's channel, seconds (> 0): bounds
  /// how long a restarted replica stays unreachable after it answers again.
  double reconnect_backoff_max_s = 2.0;
  /// Largest message sent or received, MiB (>= 1); the servers' --max-message-mb.
  int max_message_mb = 64;

  /// How the replicas' channels are made: plaintext by default; the orchestrator passes one
  /// from its tls.* settings.
  runtime::ChannelFactory channels;

  /// Observer of attempts and health changes; may be empty.
  std::function<void(const PoolEvent&)> on_event;
  /// How the pool waits out a backoff (seconds); empty: std::this_thread::sleep_for. Tests
  /// inject one that records the waits.
  std::function<void(double)> sleep_s;

  /// Throws std::invalid_argument naming the first bad setting (as the `detector.*` key).
  void Validate() const;
};

/// The replicas by default: every address the name `detector` resolves to (the compose service
/// scaled to several containers, or a Kubernetes headless service).
inline constexpr const char* kDefaultEndpoints = "dns:///detector:50051";

/// Reads the orchestrator's settings: `detector.endpoints` (default kDefaultEndpoints;
/// comma-separated or a YAML sequence), `detector.deadline_s`, `detector.max_attempts`,
/// `detector.backoff_initial_s`, `detector.backoff_multiplier`, `detector.backoff_max_s`,
/// `detector.health_period_s`, `detector.health_timeout_s`, `detector.hedge_delay_s`,
/// `detector.max_in_flight_per_replica`, `detector.max_in_flight`,
/// `detector.reconnect_backoff_max_s`, `detector.max_message_mb`; the defaults are those of
/// DetectorPoolOptions. Validated; throws std::invalid_argument naming the key.
DetectorPoolOptions FromConfig(const runtime::Config& config);

/// One Detect job: the request parameters and the scan.
struct DetectCall {
  picking::detector::v1::DetectParams params;
  SharedCloud cloud;  ///< Not null.
  /// Deadline of each attempt of this call, seconds; 0: the pool's deadline_s.
  double deadline_s = 0.0;
  /// Time the whole call may take, retries and backoffs included, seconds (0: no limit): no
  /// attempt runs past it and none starts after it (a task's time left).
  double budget_s = 0.0;
};

/// One Verify job.
struct VerifyCall {
  picking::detector::v1::VerifyParams params;
  SharedCloud cloud;        ///< Not null.
  double deadline_s = 0.0;  ///< As in DetectCall.
  double budget_s = 0.0;    ///< As in DetectCall.
};

/// One attempt of a call on one replica.
struct AttemptReport {
  std::string replica;  ///< The endpoint as configured.
  /// The address gRPC sent to (e.g. "ipv4:10.1.2.3:50051"; for a dns:/// replica, which of
  /// its addresses); empty when no connection was made.
  std::string peer;
  grpc::Status status;  ///< CANCELLED for the loser of a hedge.
  double duration_s = 0.0;
  bool hedge = false;  ///< Sent as a hedged copy.
};

/// The result of a call through the pool.
template <class Response>
struct CallOutcome {
  /// OK when a replica answered; otherwise the status of the call that decided it (a status
  /// that is not retried, or the last failed attempt when every attempt failed).
  grpc::Status status;
  Response response;    ///< The answer, when status is OK.
  std::string replica;  ///< Who answered (the replica of the deciding attempt).
  std::string peer;     ///< Its address, as AttemptReport::peer.
  /// Every attempt in the order they were sent, the deciding one included.
  std::vector<AttemptReport> attempts;

  bool ok() const { return status.ok(); }
  /// The attempts that failed (neither the answer nor a cancelled hedge loser).
  std::vector<AttemptReport> failed_attempts() const;
};
using DetectOutcome = CallOutcome<picking::detector::v1::DetectResponse>;
using VerifyOutcome = CallOutcome<picking::detector::v1::VerifyResponse>;

/// One replica as the pool sees it.
struct ReplicaSnapshot {
  std::string endpoint;
  bool healthy = true;
  int in_flight = 0;               ///< Attempts running now (hedges included).
  std::uint64_t calls_served = 0;  ///< Attempts the replica answered (any status it sent).
  std::uint64_t failures = 0;      ///< Attempts that ended UNAVAILABLE or DEADLINE_EXCEEDED.
  std::string last_error;          ///< Message of the last failure or failed health check.
};

/// The pool. Thread-safe: any number of threads may call Detect, DetectAsync, Verify,
/// DetectAll, VerifyAll, CheckHealthNow and Snapshot at once. The destructor stops the health
/// thread at once (an in-flight check is cancelled); no call may be running when it starts.
///
/// Picking a replica: among healthy ones (every replica when none is healthy: stale flags must
/// not fail a task), those this call has not tried yet, then the least loaded, round robin
/// among equals. UNAVAILABLE and DEADLINE_EXCEEDED are retried on another replica (the same
/// one only when no other is left, after a backoff); UNAVAILABLE also takes the replica out
/// until a health check finds it SERVING, whereas a missed deadline says the job was slow, not
/// that the replica is gone (a hung replica fails its health check). Other statuses
/// (INVALID_ARGUMENT, NOT_FOUND, ...) are the request's and end the call.
class DetectorPool final {
 public:
  /// Validates the options (std::invalid_argument) and creates the channels; connects lazily.
  explicit DetectorPool(DetectorPoolOptions options);
  ~DetectorPool();
  DetectorPool(const DetectorPool&) = delete;
  DetectorPool& operator=(const DetectorPool&) = delete;

  /// One call with retries (and a hedge when enabled). Throws std::invalid_argument for a
  /// null cloud; every other failure is in the outcome.
  DetectOutcome Detect(const DetectCall& call);
  VerifyOutcome Verify(const VerifyCall& call);

  /// Detect on a thread of its own, for a job that overlaps other work (the next target's
  /// detection while the arm moves). The future must be waited for before the pool is
  /// destroyed. Throws std::invalid_argument at once for a null cloud.
  std::future<DetectOutcome> DetectAsync(DetectCall call);

  /// Independent jobs at once on different replicas (at most max_in_flight, see the options);
  /// outcomes in the order of `calls`. Throws std::invalid_argument (before sending anything)
  /// when a call has a null cloud.
  std::vector<DetectOutcome> DetectAll(const std::vector<DetectCall>& calls);
  std::vector<VerifyOutcome> VerifyAll(const std::vector<VerifyCall>& calls);

  /// One Detect call's item queries spread over the replicas: split into as many jobs as
  /// ConcurrencyLimit() allows (query i to job i mod n, so the first query, the target, leads
  /// the first job), run at once by DetectAll, and the answers joined into one response in
  /// the queries' order, as one replica would have given it. Every job gets the same scan,
  /// region and views (each replica prepares the scene itself). With one replica, or one
  /// query, it is Detect. The outcome's status is the first failed job's (its attempts and
  /// replica); `attempts` lists every job's. Throws std::invalid_argument for a null cloud.
  DetectOutcome DetectSpread(const DetectCall& call);

  /// Checks every replica now (grpc.health.v1 Check, in parallel, each within
  /// health_timeout_s, waiting for a connection): SERVING brings a replica back, anything
  /// else takes it out. Returns when all checks are done.
  void CheckHealthNow();

  /// The replicas in configuration order.
  std::vector<ReplicaSnapshot> Snapshot() const;

  /// How many calls DetectAll / VerifyAll run at once now.
  int ConcurrencyLimit() const;

  const DetectorPoolOptions& options() const { return options_; }

 private:
  using Clock = std::chrono::steady_clock;
  struct Replica;
  template <class Response>
  struct Race;

  // A replica reserved for one attempt (its in_flight counted), or none.
  std::optional<std::size_t> Reserve(const std::vector<std::size_t>& tried,
                                     std::optional<std::size_t> last, bool hedge);
  // Accounts the end of an attempt on `replica`; `cancelled` when the pool cancelled it.
  void Release(std::size_t replica, const grpc::Status& status, bool cancelled);
  void SetHealthy(std::size_t replica, bool healthy, const std::string& why);
  void Emit(const PoolEvent& event) const;
  void Backoff(int waits_so_far) const;
  void HealthLoop();

  template <class Response, class Params>
  CallOutcome<Response> Run(const Params& params, const SharedCloud& cloud, double deadline_s,
                            double budget_s);
  template <class Response>
  std::optional<std::size_t> WaitForFinished(Race<Response>& race, Clock::time_point hedge_at);
  template <class Response>
  void Launch(Race<Response>& race, std::size_t replica, bool hedge);
  template <class Outcome, class Call, class Fn>
  std::vector<Outcome> RunAll(const std::vector<Call>& calls, Fn&& one);

  const DetectorPoolOptions options_;
  std::vector<std::unique_ptr<Replica>> replicas_;

  mutable std::mutex mutex_;  // Guards the replicas' counters and flags, rr_next_, stopping_.
  std::size_t rr_next_ = 0;   // Round-robin cursor among equally loaded replicas.
  bool stopping_ = false;
  std::vector<grpc::ClientContext*> health_checks_;  // In flight, to cancel on destruction.
  std::condition_variable stop_cv_;
  std::thread health_thread_;
};

}  // namespace picking::orchestrator
