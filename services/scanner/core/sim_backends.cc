#include "services/scanner/core/sim_backends.h"

#include <stdexcept>
#include <string>
#include <utility>

#include "libs/errors/errors.h"

namespace picking::scanner {
namespace {

void CheckRigid(const Eigen::Isometry3d& X, const char* what) {
  const Eigen::Matrix3d R = X.linear();
  if (!X.matrix().allFinite() || !(R.transpose() * R).isApprox(Eigen::Matrix3d::Identity(), 1e-6) ||
      R.determinant() < 0) {
    throw std::invalid_argument(std::string(what) + " is not a finite rigid transform");
  }
}

}  // namespace

SimSensorLink::SimSensorLink(std::function<Eigen::Isometry3d()> tool_pose_source)
    : tool_pose_source_(std::move(tool_pose_source)) {}

void SimSensorLink::SetToolPose(const std::optional<Eigen::Isometry3d>& X_BaseTool) {
  if (X_BaseTool) CheckRigid(*X_BaseTool, "SimSensorLink: X_BaseTool");
  std::lock_guard<std::mutex> lock(mutex_);
  X_BaseTool_ = X_BaseTool;
}

Eigen::Isometry3d SimSensorLink::ToolPose() const {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (X_BaseTool_) return *X_BaseTool_;
  }
  if (!tool_pose_source_) {
    throw PreconditionError("simulated camera: no robot pose is known for this capture");
  }
  return tool_pose_source_();
}

void SimSensorLink::LoadSequence(const ProjectorSequenceSettings& settings) {
  settings.Validate();
  std::lock_guard<std::mutex> lock(mutex_);
  sequence_ = settings;
  running_ = false;
  next_pattern_ = 0;
}

void SimSensorLink::Start() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!sequence_) throw ProjectorError("simulated projector: Start without a loaded sequence");
  running_ = true;
  next_pattern_ = 0;
}

void SimSensorLink::Stop() {
  std::lock_guard<std::mutex> lock(mutex_);
  running_ = false;
}

std::vector<PatternImage> SimSensorLink::TakePatterns(int count,
                                                      ProjectorSequenceSettings* settings) {
  if (count <= 0) throw std::invalid_argument("Capture: count must be > 0");
  std::lock_guard<std::mutex> lock(mutex_);
  if (!sequence_ || !running_) {
    throw CameraTimeoutError("simulated camera: no trigger, the projector runs no sequence");
  }
  const int total = sequence_->image_count();
  if (next_pattern_ + count > total) {
    throw CameraTimeoutError("simulated camera: asked for " + std::to_string(count) +
                             " frames but the projector sequence has only " +
                             std::to_string(total - next_pattern_) + " patterns left");
  }
  // The order of services/scanner/core/patterns.h: white, black, column bits, row bits.
  std::vector<PatternImage> patterns;
  patterns.reserve(count);
  for (int k = next_pattern_; k < next_pattern_ + count; ++k) {
    PatternImage image;
    if (k == 0) {
      image.kind = PatternImage::Kind::kWhite;
    } else if (k == 1) {
      image.kind = PatternImage::Kind::kBlack;
    } else {
      const int bit_index = (k - 2) / 2;
      image.inverse = ((k - 2) % 2) == 1;
      if (bit_index < sequence_->column_bits) {
        image.kind = PatternImage::Kind::kColumnBit;
        image.bit = bit_index;
      } else {
        image.kind = PatternImage::Kind::kRowBit;
        image.bit = bit_index - sequence_->column_bits;
      }
    }
    patterns.push_back(image);
  }
  next_pattern_ += count;
  if (next_pattern_ == total) running_ = false;  // The sequence runs once.
  if (settings) *settings = *sequence_;
  return patterns;
}

SimProjector::SimProjector(std::shared_ptr<SimSensorLink> link, std::uint32_t width,
                           std::uint32_t height)
    : link_(std::move(link)), width_(width), height_(height) {
  if (!link_) throw std::invalid_argument("SimProjector: link is null");
  if (width_ == 0 || height_ == 0) throw std::invalid_argument("SimProjector: size must be > 0");
}

void SimProjector::LoadSequence(const ProjectorSequenceSettings& settings) {
  settings.Validate();
  if ((1u << settings.column_bits) < width_ || (1u << settings.row_bits) < height_) {
    throw std::invalid_argument("SimProjector: " + std::to_string(settings.column_bits) +
                                " column bits and " + std::to_string(settings.row_bits) +
                                " row bits cannot number " + std::to_string(width_) + " x " +
                                std::to_string(height_) + " mirrors");
  }
  link_->LoadSequence(settings);
}

void SimProjector::Start() { link_->Start(); }
void SimProjector::Stop() { link_->Stop(); }

SimCamera::SimCamera(std::shared_ptr<SimSensorLink> link, std::shared_ptr<PatternRenderer> renderer,
                     SimSensorModel model, std::uint64_t seed)
    : link_(std::move(link)),
      renderer_(std::move(renderer)),
      model_(std::move(model)),
      seed_(seed) {
  if (!link_) throw std::invalid_argument("SimCamera: link is null");
  if (!renderer_) throw std::invalid_argument("SimCamera: renderer is null");
  CheckRigid(model_.X_CameraProjector, "SimCamera: X_CameraProjector");
  CheckRigid(model_.X_ToolCamera, "SimCamera: X_ToolCamera");
  settings_.trigger_mode = TriggerMode::kHardware;
}

void SimCamera::Configure(const CameraSettings& settings) {
  ValidateCameraSettings(settings);
  settings_ = settings;
}

std::vector<Frame> SimCamera::Capture(int count) {
  ProjectorSequenceSettings sequence;
  // Pose first: if it is unknown nothing is consumed from the sequence.
  const Eigen::Isometry3d X_BaseTool = link_->ToolPose();
  std::vector<PatternImage> patterns = link_->TakePatterns(count, &sequence);
  PatternRenderRequest request{model_.camera, X_BaseTool * model_.X_ToolCamera, model_.projector,
                               X_BaseTool * model_.X_ToolCamera * model_.X_CameraProjector};
  request.column_bits = sequence.column_bits;
  request.row_bits = sequence.row_bits;
  request.patterns = std::move(patterns);
  request.exposure = settings_.exposure_us / kNominalExposureUs;
  request.seed = seed_ + captures_++;
  std::vector<GrayImage> images = renderer_->Render(request);
  if (static_cast<int>(images.size()) != count) {
    throw CameraError("simulated camera: the renderer returned " + std::to_string(images.size()) +
                      " images for " + std::to_string(count) + " patterns");
  }
  std::vector<Frame> frames;
  frames.reserve(images.size());
  for (std::size_t i = 0; i < images.size(); ++i) {
    if (images[i].width != width() || images[i].height != height() ||
        images[i].pixels.size() != static_cast<std::size_t>(width()) * height()) {
      throw CameraError("simulated camera: rendered image " + std::to_string(i) + " is " +
                        std::to_string(images[i].width) + " x " + std::to_string(images[i].height) +
                        ", expected " + std::to_string(width()) + " x " + std::to_string(height()));
    }
    Frame frame;
    frame.image = std::move(images[i]);
    frame.frame_id = next_frame_id_++;
    frame.timestamp_s = static_cast<double>(frame.frame_id) * sequence.frame_period_us * 1e-6;
    frames.push_back(std::move(frame));
  }
  return frames;
}

}  // namespace picking::scanner
