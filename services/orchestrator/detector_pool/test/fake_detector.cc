#include "services/orchestrator/detector_pool/test/fake_detector.h"

#include <grpcpp/security/server_credentials.h>
#include <grpcpp/server_builder.h>

#include <optional>
#include <stdexcept>
#include <utility>

namespace picking::orchestrator::testing {
namespace {

namespace detpb = ::picking::detector::v1;
constexpr char kService[] = "picking.detector.v1.DetectorService";

// Reads the stream to its end: the params first, then chunks; returns the points received.
template <class Request, class Params>
grpc::Status ReadStream(grpc::ServerReader<Request>* reader, Params* params,
                        std::uint64_t* points) {
  Request request;
  if (!reader->Read(&request) || !request.has_params()) {
    return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, "the stream must start with params");
  }
  *params = request.params();
  *points = 0;
  while (reader->Read(&request)) *points += request.cloud().point_count();
  return grpc::Status::OK;
}

}  // namespace

bool Rendezvous::Arrive(std::chrono::milliseconds timeout) {
  std::unique_lock<std::mutex> lock(mutex_);
  ++arrived_;
  cv_.notify_all();
  return cv_.wait_for(lock, timeout, [this] { return arrived_ >= count_; });
}

void FakeDetector::SetMode(FakeMode mode, int times) {
  std::lock_guard<std::mutex> lock(mutex_);
  mode_ = mode;
  times_ = times;
}

void FakeDetector::SetRendezvous(std::shared_ptr<Rendezvous> rendezvous) {
  std::lock_guard<std::mutex> lock(mutex_);
  rendezvous_ = std::move(rendezvous);
}

void FakeDetector::Release() {
  std::lock_guard<std::mutex> lock(mutex_);
  released_ = true;
  released_cv_.notify_all();
}

std::vector<std::string> FakeDetector::calls() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return calls_;
}

int FakeDetector::max_concurrent() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return max_running_;
}

grpc::Status FakeDetector::Behave(const std::string& item) {
  std::unique_lock<std::mutex> lock(mutex_);
  calls_.push_back(item);
  ++running_;
  max_running_ = std::max(max_running_, running_);
  FakeMode mode = FakeMode::kAnswer;
  if (times_ != 0) {
    mode = mode_;
    if (times_ > 0) --times_;
  }
  grpc::Status status;
  if (rendezvous_) {
    auto rendezvous = rendezvous_;
    lock.unlock();
    if (!rendezvous->Arrive(std::chrono::seconds(30))) {
      status = grpc::Status(grpc::StatusCode::ABORTED, "the other calls did not come");
    }
    lock.lock();
  }
  if (status.ok()) {
    switch (mode) {
      case FakeMode::kAnswer:
        break;
      case FakeMode::kUnavailable:
        status = grpc::Status(grpc::StatusCode::UNAVAILABLE, "fake: going away");
        break;
      case FakeMode::kInvalidArgument:
        status = grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, "fake: bad cloud");
        break;
      case FakeMode::kNotFound:
        status = grpc::Status(grpc::StatusCode::NOT_FOUND, "fake: no such item");
        break;
      case FakeMode::kHang:
        released_cv_.wait(lock, [this] { return released_; });
        status = grpc::Status(grpc::StatusCode::ABORTED, "fake: released");
        break;
    }
  }
  --running_;
  return status;
}

grpc::Status FakeDetector::Detect(grpc::ServerContext* ctx,
                                  grpc::ServerReader<detpb::DetectRequest>* reader,
                                  detpb::DetectResponse* response) {
  detpb::DetectParams params;
  std::uint64_t points = 0;
  grpc::Status status = ReadStream(reader, &params, &points);
  if (!status.ok()) return status;
  status = Behave(params.queries_size() > 0 ? params.queries(0).item() : "");
  if (!status.ok()) return status;
  for (const auto& query : params.queries()) {
    auto* result = response->add_results();
    result->set_item(query.item());
    result->mutable_status()->set_code(0);
  }
  response->set_points_received(points);
  return grpc::Status::OK;
}

grpc::Status FakeDetector::Verify(grpc::ServerContext* ctx,
                                  grpc::ServerReader<detpb::VerifyRequest>* reader,
                                  detpb::VerifyResponse* response) {
  detpb::VerifyParams params;
  std::uint64_t points = 0;
  grpc::Status status = ReadStream(reader, &params, &points);
  if (!status.ok()) return status;
  status = Behave(params.item());
  if (!status.ok()) return status;
  response->set_score(0.75);
  return grpc::Status::OK;
}

grpc::Status FakeHealth::Check(grpc::ServerContext* ctx,
                               const grpc::health::v1::HealthCheckRequest* request,
                               grpc::health::v1::HealthCheckResponse* response) {
  std::unique_lock<std::mutex> lock(mutex_);
  if (hold_) {
    ++held_;
    cv_.notify_all();
    cv_.wait(lock, [this] { return released_; });
  }
  if (request->service() != "" && request->service() != kService) {
    return grpc::Status(grpc::StatusCode::NOT_FOUND, "unknown service");
  }
  response->set_status(serving_ ? grpc::health::v1::HealthCheckResponse::SERVING
                                : grpc::health::v1::HealthCheckResponse::NOT_SERVING);
  return grpc::Status::OK;
}

grpc::Status FakeHealth::Watch(grpc::ServerContext* ctx,
                               const grpc::health::v1::HealthCheckRequest* request,
                               grpc::ServerWriter<grpc::health::v1::HealthCheckResponse>* writer) {
  using Response = grpc::health::v1::HealthCheckResponse;
  std::unique_lock<std::mutex> lock(mutex_);
  std::optional<bool> sent;
  while (!released_) {
    if (sent != serving_) {
      const bool serving = serving_;
      Response response;
      response.set_status(serving ? Response::SERVING : Response::NOT_SERVING);
      lock.unlock();
      const bool open = writer->Write(response);
      lock.lock();
      if (!open) break;
      sent = serving;
    }
    cv_.wait(lock, [&] { return released_ || sent != serving_; });
  }
  return grpc::Status::OK;
}

void FakeHealth::SetServing(bool serving) {
  std::lock_guard<std::mutex> lock(mutex_);
  serving_ = serving;
  cv_.notify_all();
}

void FakeHealth::HoldChecks() {
  std::lock_guard<std::mutex> lock(mutex_);
  hold_ = true;
}

void FakeHealth::Release() {
  std::lock_guard<std::mutex> lock(mutex_);
  released_ = true;
  cv_.notify_all();
}

bool FakeHealth::WaitForHeldCheck() {
  std::unique_lock<std::mutex> lock(mutex_);
  return cv_.wait_for(lock, std::chrono::seconds(30), [this] { return held_ > 0; });
}

FakeReplica::FakeReplica() { Start(0); }

FakeReplica::~FakeReplica() { Shutdown(); }

void FakeReplica::Start(int port) {
  detector_ = std::make_unique<FakeDetector>();
  health_ = std::make_unique<FakeHealth>();
  grpc::ServerBuilder builder;
  int bound = 0;
  builder.AddListeningPort("127.0.0.1:" + std::to_string(port), grpc::InsecureServerCredentials(),
                           &bound);
  builder.RegisterService(detector_.get());
  builder.RegisterService(health_.get());
  server_ = builder.BuildAndStart();
  if (!server_ || bound == 0) {
    throw std::runtime_error("fake detector: cannot listen on port " + std::to_string(port));
  }
  port_ = bound;
}

void FakeReplica::Shutdown() {
  if (!server_) return;
  detector_->Release();
  health_->Release();
  server_->Shutdown();
  server_->Wait();
  server_.reset();
}

void FakeReplica::Restart() {
  Shutdown();
  Start(port_);
}

void FakeReplica::SetServing(bool serving) { health_->SetServing(serving); }

}  // namespace picking::orchestrator::testing
