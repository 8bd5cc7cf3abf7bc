#include "services/scanner/service/sim_clients.h"

#include <grpcpp/client_context.h>
#include <grpcpp/server_context.h>

#include <chrono>
#include <cmath>
#include <stdexcept>

#include "libs/errors/errors.h"
#include "libs/proto_convert/proto_convert.h"

namespace picking::scanner {
namespace {

namespace pc = ::picking::proto_convert;
namespace simpb = ::picking::simulator::v1;

std::shared_ptr<grpc::Channel> MakeChannel(const std::string& address,
                                           const runtime::ChannelFactory& channels) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);
  args.SetMaxSendMessageSize(64 << 20);
  return channels.Connect(address, args);
}

void SetDeadline(grpc::ClientContext* ctx, double timeout_s) {
  ctx->set_deadline(std::chrono::system_clock::now() +
                    std::chrono::microseconds(static_cast<long long>(timeout_s * 1e6)));
}

[[noreturn]] void ThrowStatus(const grpc::Status& status, const std::string& what,
                              const std::string& address) {
  const std::string message = what + " at " + address + ": " + status.error_message();
  if (status.error_code() == grpc::StatusCode::UNAVAILABLE ||
      status.error_code() == grpc::StatusCode::DEADLINE_EXCEEDED) {
    throw UnavailableError(message);
  }
  if (status.error_code() == grpc::StatusCode::FAILED_PRECONDITION) {
    throw PreconditionError(message);
  }
  throw std::runtime_error(message);
}

common::v1::CameraIntrinsics ToModel(const camera::PinholeCamera& c) {
  return pc::CameraToProto(c);
}

}  // namespace

SimulatorClient::SimulatorClient(const std::string& address, const SimRenderSettings& settings,
                                 const runtime::ChannelFactory& channels)
    : address_(address), settings_(settings) {
  if (address_.empty()) throw std::invalid_argument("setting 'sim.address' is empty");
  if (!(settings_.timeout_s > 0))
    throw std::invalid_argument("setting 'sim.timeout_s' must be > 0");
  if (!(settings_.electrons_per_dn >= 0) || !std::isfinite(settings_.electrons_per_dn)) {
    throw std::invalid_argument("setting 'sim.electrons_per_dn' must be finite and >= 0");
  }
  // The simulator's limit (simulator.proto, RenderOptions): a larger blur would fail every
  // scan, so it is refused at start.
  if (!(settings_.projector_blur_sigma_px >= 0) || !(settings_.projector_blur_sigma_px <= 20)) {
    throw std::invalid_argument("setting 'sim.projector_blur_sigma_px' must be in [0, 20]");
  }
  stub_ = simpb::SimulatorService::NewStub(MakeChannel(address_, channels));
}

std::vector<GrayImage> SimulatorClient::Render(const PatternRenderRequest& request) {
  simpb::RenderPatternsRequest req;
  *req.mutable_camera() = ToModel(request.camera);
  *req.mutable_x_base_camera() = pc::PoseToProto(request.X_BaseCamera);
  *req.mutable_projector() = ToModel(request.projector);
  *req.mutable_x_base_projector() = pc::PoseToProto(request.X_BaseProjector);
  for (const PatternImage& p : request.patterns) {
    auto* pattern = req.add_patterns();
    switch (p.kind) {
      case PatternImage::Kind::kWhite:
        pattern->set_solid_level(1.0);
        break;
      case PatternImage::Kind::kBlack:
        pattern->set_solid_level(0.0);
        break;
      case PatternImage::Kind::kColumnBit:
      case PatternImage::Kind::kRowBit: {
        const bool rows = p.kind == PatternImage::Kind::kRowBit;
        auto* stripe = pattern->mutable_gray_code();
        stripe->set_rows(rows);
        stripe->set_bit(static_cast<std::uint32_t>(p.bit));
        stripe->set_bit_count(
            static_cast<std::uint32_t>(rows ? request.row_bits : request.column_bits));
        stripe->set_inverted(p.inverse);
        break;
      }
    }
  }
  auto* options = req.mutable_options();
  options->set_ambient(settings_.ambient);
  options->set_noise_sigma(settings_.noise_sigma);
  options->set_gamma(settings_.gamma);
  options->set_electrons_per_dn(settings_.electrons_per_dn);
  options->set_projector_blur_sigma_px(settings_.projector_blur_sigma_px);
  options->set_exposure(request.exposure);
  options->set_seed(request.seed);

  const grpc::ServerContext* parent = nullptr;
  {
    std::lock_guard<std::mutex> lock(parent_mutex_);
    parent = parent_;
  }
  // A child call ends at the earlier of the two deadlines (gRPC propagates the parent's).
  std::unique_ptr<grpc::ClientContext> ctx_owner =
      parent ? grpc::ClientContext::FromServerContext(*parent)
             : std::make_unique<grpc::ClientContext>();
  grpc::ClientContext& ctx = *ctx_owner;
  SetDeadline(&ctx, settings_.timeout_s);
  auto reader = stub_->RenderPatterns(&ctx, req);
  pc::ImageAssembler assembler;
  std::vector<GrayImage> images;
  simpb::RenderPatternsResponse response;
  std::string stream_error;
  while (reader->Read(&response)) {
    if (!stream_error.empty()) continue;
    try {
      if (!assembler.Add(response.chunk())) continue;
    } catch (const std::invalid_argument& e) {
      stream_error = e.what();
      ctx.TryCancel();
      continue;
    }
    pc::Image image = assembler.TakeCompleted();
    if (image.format != common::v1::PIXEL_FORMAT_MONO8) {
      stream_error = "image '" + image.name + "' is not MONO8";
      ctx.TryCancel();
      continue;
    }
    GrayImage gray;
    gray.width = image.width;
    gray.height = image.height;
    gray.pixels = std::move(image.data);
    images.push_back(std::move(gray));
  }
  const grpc::Status status = reader->Finish();
  if (!stream_error.empty()) {
    throw std::runtime_error("RenderPatterns at " + address_ + ": " + stream_error);
  }
  if (!status.ok() && parent != nullptr) {
    // A call past its deadline also counts as cancelled: the deadline is asked first.
    if (std::chrono::system_clock::now() >= parent->deadline()) {
      throw TimeoutError("the capture did not finish within the call's deadline");
    }
    if (parent->IsCancelled()) throw CancelledError("the scan's call was cancelled");
  }
  if (!status.ok()) ThrowStatus(status, "RenderPatterns", address_);
  return images;
}

void SimulatorClient::SetParentCall(const grpc::ServerContext* parent) {
  std::lock_guard<std::mutex> lock(parent_mutex_);
  parent_ = parent;
}

Eigen::Isometry3d SimulatorClient::ToolPose() {
  grpc::ClientContext ctx;
  SetDeadline(&ctx, std::min(settings_.timeout_s, 5.0));
  simpb::GetGroundTruthResponse response;
  const grpc::Status status =
      stub_->GetGroundTruth(&ctx, simpb::GetGroundTruthRequest(), &response);
  if (!status.ok()) ThrowStatus(status, "GetGroundTruth", address_);
  if (!response.has_x_base_tool()) {
    throw PreconditionError("the simulator at " + address_ + " reports no arm pose yet");
  }
  return pc::PoseFromProto(response.x_base_tool(), "GetGroundTruth.X_base_tool");
}

RobotPoseClient::RobotPoseClient(const std::string& address, double timeout_s,
                                 const runtime::ChannelFactory& channels)
    : address_(address), timeout_s_(timeout_s) {
  if (address_.empty()) throw std::invalid_argument("setting 'robot.address' is empty");
  if (!(timeout_s_ > 0)) throw std::invalid_argument("setting 'robot.timeout_s' must be > 0");
  stub_ = robot::v1::RobotService::NewStub(MakeChannel(address_, channels));
}

Eigen::Isometry3d RobotPoseClient::ToolPose() {
  grpc::ClientContext ctx;
  SetDeadline(&ctx, timeout_s_);
  robot::v1::GetStateResponse response;
  const grpc::Status status = stub_->GetState(&ctx, robot::v1::GetStateRequest(), &response);
  if (!status.ok()) ThrowStatus(status, "robot GetState", address_);
  return pc::PoseFromProto(response.x_base_tool(), "robot GetState.X_base_tool");
}

}  // namespace picking::scanner
