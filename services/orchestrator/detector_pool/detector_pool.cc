#include "services/orchestrator/detector_pool/detector_pool.h"

#include <grpc/grpc.h>
#include <grpcpp/support/channel_arguments.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cmath>
#include <deque>
#include <exception>
#include <sstream>
#include <stdexcept>
#include <utility>

#include "grpc/health/v1/health.grpc.pb.h"

namespace picking::orchestrator {
namespace {

namespace detpb = ::picking::detector::v1;
namespace healthpb = ::grpc::health::v1;
using Chunks = std::vector<picking::common::v1::PointCloudChunk>;

constexpr char kDnsScheme[] = "dns:";

bool Retryable(grpc::StatusCode code) {
  return code == grpc::StatusCode::UNAVAILABLE || code == grpc::StatusCode::DEADLINE_EXCEEDED;
}

bool IsDns(const std::string& endpoint) { return endpoint.rfind(kDnsScheme, 0) == 0; }

[[noreturn]] void Bad(const std::string& key, const std::string& what) {
  throw std::invalid_argument("detector." + key + ": " + what);
}

// "host:port", "[v6]:port" or "dns:///name:port" (also "dns://authority/name:port").
void ValidateEndpoint(const std::string& endpoint) {
  std::string hostport = endpoint;
  if (IsDns(endpoint)) {
    const std::size_t slash = endpoint.find('/', std::string(kDnsScheme).size() + 2);
    if (endpoint.compare(0, 6, "dns://") != 0 || slash == std::string::npos) {
      Bad("endpoints", "'" + endpoint + "' is not dns:///name:port");
    }
    hostport = endpoint.substr(slash + 1);
  } else if (endpoint.find("://") != std::string::npos || endpoint.find('/') != std::string::npos) {
    Bad("endpoints", "'" + endpoint + "' is neither host:port nor dns:///name:port");
  }
  const std::size_t colon = hostport.rfind(':');
  if (colon == std::string::npos || colon == 0) {
    Bad("endpoints", "'" + endpoint + "' has no host:port");
  }
  const std::string port = hostport.substr(colon + 1);
  const bool digits =
      !port.empty() && port.size() <= 5 &&
      std::all_of(port.begin(), port.end(), [](unsigned char c) { return std::isdigit(c) != 0; });
  if (!digits || std::stoi(port) < 1 || std::stoi(port) > 65535) {
    Bad("endpoints", "'" + endpoint + "' has no port in 1..65535");
  }
}

std::vector<std::string> SplitList(const std::string& text) {
  std::vector<std::string> items;
  std::stringstream in(text);
  std::string item;
  while (std::getline(in, item, ',')) {
    const auto first = item.find_first_not_of(" \t");
    const auto last = item.find_last_not_of(" \t");
    items.push_back(first == std::string::npos ? "" : item.substr(first, last - first + 1));
  }
  return items;
}

std::chrono::system_clock::duration Seconds(double s) {
  return std::chrono::duration_cast<std::chrono::system_clock::duration>(
      std::chrono::duration<double>(s));
}

// The first message carries the params, then one message per chunk. A failed Write means the
// call is already over (the server answered early or the deadline passed): Finish says why.
template <class Request, class Params, class Writer>
grpc::Status WriteAll(Writer& writer, const Params& params, const Chunks& chunks,
                      const std::function<void()>& sent) {
  Request first;
  *first.mutable_params() = params;
  bool open = writer.Write(first);
  for (std::size_t i = 0; open && i < chunks.size(); ++i) {
    Request request;
    *request.mutable_cloud() = chunks[i];
    open = writer.Write(request);
  }
  if (open && writer.WritesDone()) sent();
  return writer.Finish();
}

grpc::Status Stream(detpb::DetectorService::Stub& stub, grpc::ClientContext* ctx,
                    const detpb::DetectParams& params, const Chunks& chunks,
                    detpb::DetectResponse* response, const std::function<void()>& sent) {
  auto writer = stub.Detect(ctx, response);
  return WriteAll<detpb::DetectRequest>(*writer, params, chunks, sent);
}

grpc::Status Stream(detpb::DetectorService::Stub& stub, grpc::ClientContext* ctx,
                    const detpb::VerifyParams& params, const Chunks& chunks,
                    detpb::VerifyResponse* response, const std::function<void()>& sent) {
  auto writer = stub.Verify(ctx, response);
  return WriteAll<detpb::VerifyRequest>(*writer, params, chunks, sent);
}

std::shared_ptr<grpc::Channel> MakeChannel(const std::string& endpoint,
                                           const DetectorPoolOptions& options) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(options.max_message_mb << 20);
  args.SetMaxSendMessageSize(options.max_message_mb << 20);
  const int max_backoff_ms = static_cast<int>(std::ceil(options.reconnect_backoff_max_s * 1e3));
  args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, std::min(100, max_backoff_ms));
  args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, max_backoff_ms);
  // Its own connections: gRPC otherwise shares subchannels (and their reconnect backoff)
  // between channels to the same address, so another client's failures would leak in.
  args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
  if (IsDns(endpoint)) {
    // round_robin over every resolved address; its client-side health checking keeps calls
    // off addresses whose health service does not say SERVING (pick_first ignores it).
    args.SetServiceConfigJSON(R"({"loadBalancingConfig": [{"round_robin": {}}],)"
                              R"( "healthCheckConfig": {"serviceName": ")" +
                              options.health_service + R"("}})");
  }
  return options.channels.Connect(endpoint, args);
}

}  // namespace

// --- Options -------------------------------------------------------------------------------

void DetectorPoolOptions::Validate() const {
  if (endpoints.empty()) Bad("endpoints", "at least one endpoint is needed");
  for (std::size_t i = 0; i < endpoints.size(); ++i) {
    ValidateEndpoint(endpoints[i]);
    if (std::find(endpoints.begin(), endpoints.begin() + i, endpoints[i]) !=
        endpoints.begin() + i) {
      Bad("endpoints", "'" + endpoints[i] + "' is listed twice");
    }
  }
  auto positive = [](double v) { return std::isfinite(v) && v > 0; };
  auto non_negative = [](double v) { return std::isfinite(v) && v >= 0; };
  if (!positive(deadline_s)) Bad("deadline_s", "must be > 0");
  if (max_attempts < 1) Bad("max_attempts", "must be >= 1");
  if (!non_negative(backoff_initial_s)) Bad("backoff_initial_s", "must be >= 0");
  if (!std::isfinite(backoff_multiplier) || backoff_multiplier < 1) {
    Bad("backoff_multiplier", "must be >= 1");
  }
  if (!non_negative(backoff_max_s) || backoff_max_s < backoff_initial_s) {
    Bad("backoff_max_s", "must be >= backoff_initial_s");
  }
  if (!non_negative(health_period_s)) Bad("health_period_s", "must be >= 0 (0: off)");
  if (!positive(health_timeout_s)) Bad("health_timeout_s", "must be > 0");
  if (!non_negative(hedge_delay_s) || (hedge_delay_s > 0 && hedge_delay_s >= deadline_s)) {
    Bad("hedge_delay_s", "must be >= 0 (0: off) and less than deadline_s");
  }
  if (max_in_flight_per_replica < 1) Bad("max_in_flight_per_replica", "must be >= 1");
  if (max_in_flight < 0) Bad("max_in_flight", "must be >= 0 (0: automatic)");
  if (!positive(reconnect_backoff_max_s)) Bad("reconnect_backoff_max_s", "must be > 0");
  if (max_message_mb < 1 || max_message_mb > 2047) Bad("max_message_mb", "must be in 1..2047");
}

DetectorPoolOptions FromConfig(const runtime::Config& config) {
  DetectorPoolOptions o;
  const std::string endpoints = config.GetString("detector.endpoints", kDefaultEndpoints);
  o.endpoints = SplitList(endpoints);
  for (const auto& e : o.endpoints) {
    if (e.empty()) Bad("endpoints", "an empty element in '" + endpoints + "'");
  }
  auto integer = [&](const std::string& key, int default_value) {
    const long long v = config.GetInt("detector." + key, default_value);
    if (v < -1'000'000 || v > 1'000'000) Bad(key, "out of range");
    return static_cast<int>(v);
  };
  auto real = [&](const std::string& key, double v) {
    return config.GetDouble("detector." + key, v);
  };
  o.deadline_s = real("deadline_s", o.deadline_s);
  o.max_attempts = integer("max_attempts", o.max_attempts);
  o.backoff_initial_s = real("backoff_initial_s", o.backoff_initial_s);
  o.backoff_multiplier = real("backoff_multiplier", o.backoff_multiplier);
  o.backoff_max_s = real("backoff_max_s", o.backoff_max_s);
  o.health_period_s = real("health_period_s", o.health_period_s);
  o.health_timeout_s = real("health_timeout_s", o.health_timeout_s);
  o.hedge_delay_s = real("hedge_delay_s", o.hedge_delay_s);
  o.max_in_flight_per_replica = integer("max_in_flight_per_replica", o.max_in_flight_per_replica);
  o.max_in_flight = integer("max_in_flight", o.max_in_flight);
  o.reconnect_backoff_max_s = real("reconnect_backoff_max_s", o.reconnect_backoff_max_s);
  o.max_message_mb = integer("max_message_mb", o.max_message_mb);
  o.Validate();
  return o;
}

template <class Response>
std::vector<AttemptReport> CallOutcome<Response>::failed_attempts() const {
  std::vector<AttemptReport> failed;
  for (const auto& a : attempts) {
    if (!a.status.ok() && a.status.error_code() != grpc::StatusCode::CANCELLED) {
      failed.push_back(a);
    }
  }
  return failed;
}
template struct CallOutcome<detpb::DetectResponse>;
template struct CallOutcome<detpb::VerifyResponse>;

// --- The pool's state ------------------------------------------------------------------------

struct DetectorPool::Replica {
  std::string endpoint;
  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<detpb::DetectorService::Stub> stub;
  std::unique_ptr<healthpb::Health::Stub> health;
  // Guarded by the pool's mutex_.
  bool healthy = true;
  int in_flight = 0;
  std::uint64_t served = 0;
  std::uint64_t failures = 0;
  std::string last_error;
};

// The attempts of one call. Only the calling thread launches and reaps attempts; an attempt's
// thread touches its own Slot and, under `mutex`, `finished`.
template <class Response>
struct DetectorPool::Race {
  struct Slot {
    std::size_t replica = 0;
    bool hedge = false;
    grpc::ClientContext ctx;
    Response response;
    grpc::Status status;
    std::string peer;
    double duration_s = 0.0;
    std::atomic<bool> cancelled{false};  // Set by the caller before it cancels ctx.
    std::thread thread;
  };
  // Sends the request on a stub; calls the last argument once the whole request is sent.
  std::function<grpc::Status(detpb::DetectorService::Stub&, grpc::ClientContext*, Response*,
                             const std::function<void()>&)>
      stream;
  std::chrono::system_clock::duration deadline{};  // Of each attempt.
  std::chrono::system_clock::time_point budget_end = std::chrono::system_clock::time_point::max();
  std::vector<std::unique_ptr<Slot>> slots;
  int running = 0;
  std::mutex mutex;
  std::condition_variable cv;
  std::deque<std::size_t> finished;  // Slots whose attempt ended, not yet reaped.
};

DetectorPool::DetectorPool(DetectorPoolOptions options) : options_(std::move(options)) {
  options_.Validate();
  for (const auto& endpoint : options_.endpoints) {
    auto replica = std::make_unique<Replica>();
    replica->endpoint = endpoint;
    replica->channel = MakeChannel(endpoint, options_);
    replica->stub = detpb::DetectorService::NewStub(replica->channel);
    replica->health = healthpb::Health::NewStub(replica->channel);
    replicas_.push_back(std::move(replica));
  }
  if (options_.health_period_s > 0) health_thread_ = std::thread([this] { HealthLoop(); });
}

DetectorPool::~DetectorPool() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
    for (grpc::ClientContext* ctx : health_checks_) ctx->TryCancel();
  }
  stop_cv_.notify_all();
  if (health_thread_.joinable()) health_thread_.join();
}

void DetectorPool::Emit(const PoolEvent& event) const {
  if (options_.on_event) options_.on_event(event);
}

std::optional<std::size_t> DetectorPool::Reserve(const std::vector<std::size_t>& tried,
                                                 std::optional<std::size_t> last, bool hedge) {
  std::lock_guard<std::mutex> lock(mutex_);
  const std::size_t n = replicas_.size();
  auto was_tried = [&](std::size_t i) {
    return std::find(tried.begin(), tried.end(), i) != tried.end();
  };
  const bool any_healthy =
      std::any_of(replicas_.begin(), replicas_.end(), [](const auto& r) { return r->healthy; });
  std::vector<bool> allowed(n, false);
  for (std::size_t i = 0; i < n; ++i) {
    const Replica& r = *replicas_[i];
    if (hedge) {
      // A copy only goes where it costs nobody anything: healthy, idle, not failed before.
      allowed[i] = r.healthy && r.in_flight == 0 && !was_tried(i);
    } else {
      // With every flag down the flags are stale rather than every replica dead: try anyway.
      allowed[i] = r.healthy || !any_healthy;
    }
  }
  if (!hedge) {
    auto count = [&] { return std::count(allowed.begin(), allowed.end(), true); };
    std::vector<bool> fresh = allowed;
    for (std::size_t i = 0; i < n; ++i) fresh[i] = fresh[i] && !was_tried(i);
    if (std::count(fresh.begin(), fresh.end(), true) > 0) {
      allowed = fresh;
    } else if (last && count() > 1) {
      allowed[*last] = false;
    }
  }
  std::optional<std::size_t> best;
  for (std::size_t k = 0; k < n; ++k) {
    const std::size_t i = (rr_next_ + k) % n;
    if (allowed[i] && (!best || replicas_[i]->in_flight < replicas_[*best]->in_flight)) best = i;
  }
  if (!best) return std::nullopt;
  rr_next_ = (*best + 1) % n;
  ++replicas_[*best]->in_flight;
  return best;
}

void DetectorPool::Release(std::size_t index, const grpc::Status& status, bool cancelled) {
  bool taken_out = false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    Replica& r = *replicas_[index];
    --r.in_flight;
    if (status.ok() || (!cancelled && !Retryable(status.error_code()))) {
      ++r.served;
    } else if (!cancelled) {
      ++r.failures;
      r.last_error = status.error_message();
      if (status.error_code() == grpc::StatusCode::UNAVAILABLE && r.healthy) {
        r.healthy = false;
        taken_out = true;
      }
    }
  }
  if (taken_out) {
    PoolEvent event;
    event.kind = PoolEvent::Kind::kHealthChanged;
    event.replica = replicas_[index]->endpoint;
    event.status = status;
    event.healthy = false;
    Emit(event);
  }
}

void DetectorPool::SetHealthy(std::size_t index, bool healthy, const std::string& why) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    Replica& r = *replicas_[index];
    if (!healthy) r.last_error = why;
    if (r.healthy == healthy) return;
    r.healthy = healthy;
  }
  PoolEvent event;
  event.kind = PoolEvent::Kind::kHealthChanged;
  event.replica = replicas_[index]->endpoint;
  event.healthy = healthy;
  if (!healthy) event.status = grpc::Status(grpc::StatusCode::UNAVAILABLE, why);
  Emit(event);
}

void DetectorPool::Backoff(int waits_so_far) const {
  const double delay_s =
      std::min(options_.backoff_max_s,
               options_.backoff_initial_s * std::pow(options_.backoff_multiplier, waits_so_far));
  if (delay_s <= 0) return;
  if (options_.sleep_s) {
    options_.sleep_s(delay_s);
  } else {
    std::this_thread::sleep_for(std::chrono::duration<double>(delay_s));
  }
}

// --- Calls -----------------------------------------------------------------------------------

template <class Response>
void DetectorPool::Launch(Race<Response>& race, std::size_t replica, bool hedge) {
  using Slot = typename Race<Response>::Slot;
  auto owned = std::make_unique<Slot>();
  Slot* slot = owned.get();
  slot->replica = replica;
  slot->hedge = hedge;
  slot->ctx.set_deadline(
      std::min(std::chrono::system_clock::now() + race.deadline, race.budget_end));
  const std::size_t index = race.slots.size();
  race.slots.push_back(std::move(owned));
  ++race.running;
  slot->thread = std::thread([this, &race, slot, index] {
    PoolEvent event;
    event.replica = replicas_[slot->replica]->endpoint;
    event.hedge = slot->hedge;
    Emit(event);
    const auto start = Clock::now();
    slot->status =
        race.stream(*replicas_[slot->replica]->stub, &slot->ctx, &slot->response, [this, &event] {
          event.kind = PoolEvent::Kind::kAttemptSent;
          Emit(event);
        });
    slot->duration_s = std::chrono::duration<double>(Clock::now() - start).count();
    slot->peer = slot->ctx.peer();
    Release(slot->replica, slot->status, slot->cancelled);
    event.kind = PoolEvent::Kind::kAttemptFinished;
    event.status = slot->status;
    Emit(event);
    {
      std::lock_guard<std::mutex> lock(race.mutex);
      race.finished.push_back(index);
      race.cv.notify_all();
    }
  });
}

// The next finished attempt, or none when `hedge_at` came first (never when it is max()).
template <class Response>
std::optional<std::size_t> DetectorPool::WaitForFinished(Race<Response>& race,
                                                         Clock::time_point hedge_at) {
  std::unique_lock<std::mutex> lock(race.mutex);
  auto any = [&race] { return !race.finished.empty(); };
  if (hedge_at != Clock::time_point::max()) {
    if (!race.cv.wait_until(lock, hedge_at, any)) return std::nullopt;
  } else {
    race.cv.wait(lock, any);
  }
  const std::size_t index = race.finished.front();
  race.finished.pop_front();
  return index;
}

template <class Response, class Params>
CallOutcome<Response> DetectorPool::Run(const Params& params, const SharedCloud& cloud,
                                        double deadline_s, double budget_s) {
  if (!cloud) throw std::invalid_argument("detector pool: a call without a cloud");
  Race<Response> race;
  race.stream = [&params, &cloud](detpb::DetectorService::Stub& stub, grpc::ClientContext* ctx,
                                  Response* response, const std::function<void()>& sent) {
    return Stream(stub, ctx, params, *cloud, response, sent);
  };
  race.deadline = Seconds(deadline_s > 0 ? deadline_s : options_.deadline_s);
  if (budget_s > 0) race.budget_end = std::chrono::system_clock::now() + Seconds(budget_s);
  auto budget_left = [&race] { return std::chrono::system_clock::now() < race.budget_end; };
  const bool hedging = options_.hedge_delay_s > 0;

  std::vector<std::size_t> tried;  // Replicas that failed this call.
  std::optional<std::size_t> decided, last_failed_slot;
  Clock::time_point hedge_at = Clock::time_point::max();  // max(): no hedge to send.
  int started = 0;
  int backoffs = 0;
  while (!decided) {
    if (race.running == 0) {
      if (started >= options_.max_attempts) break;
      const std::size_t replica =
          *Reserve(tried, tried.empty() ? std::nullopt : std::optional(tried.back()), false);
      if (std::find(tried.begin(), tried.end(), replica) != tried.end()) Backoff(backoffs++);
      if (started > 0 && !budget_left()) {  // The first attempt always runs.
        Release(replica, grpc::Status::CANCELLED, /*cancelled=*/true);
        break;
      }
      Launch(race, replica, false);
      ++started;
      if (hedging)
        hedge_at = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                      std::chrono::duration<double>(options_.hedge_delay_s));
    }
    const std::optional<std::size_t> done = WaitForFinished(race, hedge_at);
    if (!done) {  // Still no answer after the hedge delay.
      hedge_at = Clock::time_point::max();
      if (started < options_.max_attempts && budget_left()) {
        if (const auto idle = Reserve(tried, std::nullopt, true)) {
          Launch(race, *idle, true);
          ++started;
        }
      }
      continue;
    }
    auto& slot = *race.slots[*done];
    slot.thread.join();
    --race.running;
    if (slot.status.ok() || !Retryable(slot.status.error_code())) {
      decided = done;
    } else {
      tried.push_back(slot.replica);
      last_failed_slot = done;
    }
  }
  // The losers of a hedge: their answer is not needed any more.
  for (auto& slot : race.slots) {
    if (!slot->thread.joinable()) continue;
    slot->cancelled = true;
    slot->ctx.TryCancel();
    slot->thread.join();
  }

  CallOutcome<Response> outcome;
  for (const auto& slot : race.slots) {
    outcome.attempts.push_back(AttemptReport{replicas_[slot->replica]->endpoint, slot->peer,
                                             slot->status, slot->duration_s, slot->hedge});
  }
  auto& deciding = *race.slots[decided ? *decided : *last_failed_slot];
  outcome.status = deciding.status;
  outcome.replica = replicas_[deciding.replica]->endpoint;
  outcome.peer = deciding.peer;
  if (decided) outcome.response = std::move(deciding.response);
  return outcome;
}

DetectOutcome DetectorPool::Detect(const DetectCall& call) {
  return Run<detpb::DetectResponse>(call.params, call.cloud, call.deadline_s, call.budget_s);
}

std::future<DetectOutcome> DetectorPool::DetectAsync(DetectCall call) {
  if (!call.cloud) throw std::invalid_argument("detector pool: a call without a cloud");
  return std::async(std::launch::async, [this, call = std::move(call)] { return Detect(call); });
}

VerifyOutcome DetectorPool::Verify(const VerifyCall& call) {
  return Run<detpb::VerifyResponse>(call.params, call.cloud, call.deadline_s, call.budget_s);
}

int DetectorPool::ConcurrencyLimit() const {
  if (options_.max_in_flight > 0) return options_.max_in_flight;
  std::lock_guard<std::mutex> lock(mutex_);
  const auto healthy =
      std::count_if(replicas_.begin(), replicas_.end(), [](const auto& r) { return r->healthy; });
  return static_cast<int>(std::max<long>(1, healthy)) * options_.max_in_flight_per_replica;
}

template <class Outcome, class Call, class Fn>
std::vector<Outcome> DetectorPool::RunAll(const std::vector<Call>& calls, Fn&& one) {
  for (std::size_t i = 0; i < calls.size(); ++i) {
    if (!calls[i].cloud) {
      throw std::invalid_argument("detector pool: call " + std::to_string(i) + " has no cloud");
    }
  }
  std::vector<Outcome> outcomes(calls.size());
  const std::size_t workers = std::min(calls.size(), static_cast<std::size_t>(ConcurrencyLimit()));
  std::atomic<std::size_t> next{0};
  std::mutex error_mutex;
  std::exception_ptr error;
  // Each worker takes the next job when it is done with one, so a slow job does not hold back
  // the others and at most `workers` calls run at once.
  auto work = [&] {
    for (std::size_t i; (i = next++) < calls.size();) {
      try {
        outcomes[i] = one(calls[i]);
      } catch (...) {
        std::lock_guard<std::mutex> lock(error_mutex);
        if (!error) error = std::current_exception();
      }
    }
  };
  std::vector<std::thread> threads;
  for (std::size_t w = 0; w < workers; ++w) threads.emplace_back(work);
  for (auto& t : threads) t.join();
  if (error) std::rethrow_exception(error);
  return outcomes;
}

std::vector<DetectOutcome> DetectorPool::DetectAll(const std::vector<DetectCall>& calls) {
  return RunAll<DetectOutcome>(calls, [this](const DetectCall& c) { return Detect(c); });
}

DetectOutcome DetectorPool::DetectSpread(const DetectCall& call) {
  if (!call.cloud) throw std::invalid_argument("detector pool: the call has no cloud");
  const int queries = call.params.queries_size();
  const int jobs = std::min(queries, ConcurrencyLimit());
  if (jobs <= 1) return Detect(call);
  std::vector<DetectCall> calls(jobs, call);
  for (DetectCall& c : calls) c.params.clear_queries();
  for (int i = 0; i < queries; ++i) *calls[i % jobs].params.add_queries() = call.params.queries(i);
  std::vector<DetectOutcome> parts = DetectAll(calls);
  DetectOutcome joined;
  std::vector<std::string> replicas;
  for (DetectOutcome& part : parts) {
    joined.attempts.insert(joined.attempts.end(), part.attempts.begin(), part.attempts.end());
    if (!part.ok() && joined.status.ok()) {
      joined.status = part.status;
      joined.replica = part.replica;
      joined.peer = part.peer;
    }
    if (std::find(replicas.begin(), replicas.end(), part.replica) == replicas.end()) {
      replicas.push_back(part.replica);
    }
  }
  for (int j = 0; j < jobs && joined.ok(); ++j) {
    if (parts[j].response.results_size() != calls[j].params.queries_size()) {
      joined.status =
          grpc::Status(grpc::StatusCode::INTERNAL,
                       "detector " + parts[j].replica + " answered " +
                           std::to_string(parts[j].response.results_size()) + " results for " +
                           std::to_string(calls[j].params.queries_size()) + " queries");
      joined.replica = parts[j].replica;
    }
  }
  if (!joined.ok()) return joined;
  // Query i is result i / jobs of job i % jobs.
  for (int i = 0; i < queries; ++i) {
    *joined.response.add_results() = parts[i % jobs].response.results(i / jobs);
  }
  joined.response.set_points_received(parts[0].response.points_received());
  joined.response.set_points_after_preprocessing(parts[0].response.points_after_preprocessing());
  for (const std::string& r : replicas) joined.replica += (joined.replica.empty() ? "" : ",") + r;
  joined.peer = parts[0].peer;
  return joined;
}

std::vector<VerifyOutcome> DetectorPool::VerifyAll(const std::vector<VerifyCall>& calls) {
  return RunAll<VerifyOutcome>(calls, [this](const VerifyCall& c) { return Verify(c); });
}

// --- Health ----------------------------------------------------------------------------------

void DetectorPool::CheckHealthNow() {
  struct Check {
    grpc::ClientContext ctx;
    healthpb::HealthCheckRequest request;
    healthpb::HealthCheckResponse response;
    grpc::Status status;
  };
  const std::size_t n = replicas_.size();
  std::vector<std::unique_ptr<Check>> checks;
  for (std::size_t i = 0; i < n; ++i) {
    auto check = std::make_unique<Check>();
    check->ctx.set_deadline(std::chrono::system_clock::now() + Seconds(options_.health_timeout_s));
    // Waits for a connection (within the deadline) instead of failing at once while the
    // channel is between reconnection attempts: a replica that came back is seen as soon as
    // its channel reconnects.
    check->ctx.set_wait_for_ready(true);
    check->request.set_service(options_.health_service);
    checks.push_back(std::move(check));
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stopping_) return;
    for (auto& c : checks) health_checks_.push_back(&c->ctx);
  }
  // One thread per replica: a dead replica's check waits out its deadline without holding up
  // the others'. (Blocking calls rather than gRPC's callback API keep the hand-off between
  // threads visible to ThreadSanitizer.)
  std::vector<std::thread> threads;
  for (std::size_t i = 0; i < n; ++i) {
    threads.emplace_back([this, i, c = checks[i].get()] {
      c->status = replicas_[i]->health->Check(&c->ctx, c->request, &c->response);
    });
  }
  for (auto& t : threads) t.join();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (auto& c : checks) {
      health_checks_.erase(std::find(health_checks_.begin(), health_checks_.end(), &c->ctx));
    }
  }
  for (std::size_t i = 0; i < n; ++i) {
    const Check& c = *checks[i];
    const bool serving =
        c.status.ok() && c.response.status() == healthpb::HealthCheckResponse::SERVING;
    std::string why;
    if (!c.status.ok()) {
      why = "health check: " + c.status.error_message();
    } else if (!serving) {
      why =
          "health check: " + healthpb::HealthCheckResponse::ServingStatus_Name(c.response.status());
    }
    SetHealthy(i, serving, why);
  }
}

void DetectorPool::HealthLoop() {
  const auto period = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(options_.health_period_s));
  std::unique_lock<std::mutex> lock(mutex_);
  while (!stopping_) {
    if (stop_cv_.wait_for(lock, period, [this] { return stopping_; })) break;
    lock.unlock();
    CheckHealthNow();
    lock.lock();
  }
}

std::vector<ReplicaSnapshot> DetectorPool::Snapshot() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<ReplicaSnapshot> out;
  for (const auto& r : replicas_) {
    out.push_back(ReplicaSnapshot{r->endpoint, r->healthy, r->in_flight, r->served, r->failures,
                                  r->last_error});
  }
  return out;
}

}  // namespace picking::orchestrator
