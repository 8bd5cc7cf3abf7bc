#include "services/scanner/service/scanner_service.h"

#include <chrono>
#include <cmath>
#include <filesystem>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <system_error>
#include <utility>

#include "libs/errors/errors.h"
#include "libs/proto_convert/proto_convert.h"
#include "libs/runtime/log.h"
#include "libs/runtime/server.h"
#include "libs/runtime/status.h"
#include "services/scanner/core/calibration.h"
#include "services/scanner/core/calibration_io.h"
#include "services/scanner/core/calibration_store.h"
#include "services/scanner/core/calibration_workflow.h"
#include "services/scanner/core/capture_store.h"
#include "services/scanner/core/replay_camera.h"
#include "services/scanner/core/scan_pipeline.h"
#include "services/scanner/service/scanner_devices.h"
#include "services/scanner/service/scanner_settings.h"
#include "services/scanner/service/sim_clients.h"

namespace picking::scanner {
namespace {

namespace fs = std::filesystem;
namespace pb = ::picking::scanner::v1;
namespace pc = ::picking::proto_convert;

// Views of one Scan: the paper takes 3 of a shelf bin and 2 of the tote; each view is a
// full pattern sequence (about a second), so the bound keeps one call's work bounded.
constexpr int kMaxScanViews = 16;

pb::ScanStage ToProto(ScanStage stage) {
  switch (stage) {
    case ScanStage::kCapture:
      return pb::SCAN_STAGE_CAPTURE;
    case ScanStage::kDecode:
      return pb::SCAN_STAGE_DECODE;
    case ScanStage::kTriangulate:
      return pb::SCAN_STAGE_TRIANGULATE;
    case ScanStage::kMerge:
      return pb::SCAN_STAGE_MERGE;
  }
  throw std::logic_error("ToProto: invalid ScanStage");
}

common::v1::CameraIntrinsics IntrinsicsToProto(const CameraIntrinsics& c) {
  common::v1::CameraIntrinsics out;
  out.set_width(c.width);
  out.set_height(c.height);
  out.set_fx(c.fx);
  out.set_fy(c.fy);
  out.set_cx(c.cx);
  out.set_cy(c.cy);
  for (double k : c.distortion) out.add_distortion(k);
  return out;
}

pb::CalibrationSet StateToProto(const CalibrationState& s) {
  pb::CalibrationSet out;
  if (s.camera) *out.mutable_camera() = IntrinsicsToProto(*s.camera);
  if (s.projector) *out.mutable_projector() = IntrinsicsToProto(*s.projector);
  if (s.X_CameraProjector)
    *out.mutable_x_camera_projector() = pc::PoseToProto(*s.X_CameraProjector);
  if (s.X_ToolCamera) *out.mutable_x_tool_camera() = pc::PoseToProto(*s.X_ToolCamera);
  if (s.X_BaseShelf) *out.mutable_x_base_shelf() = pc::PoseToProto(*s.X_BaseShelf);
  if (s.camera_calibrated) out.add_calibrated(pb::CALIBRATION_KIND_CAMERA);
  if (s.projector_calibrated) out.add_calibrated(pb::CALIBRATION_KIND_PROJECTOR);
  if (s.hand_eye_calibrated) out.add_calibrated(pb::CALIBRATION_KIND_HAND_EYE);
  if (s.shelf_calibrated) out.add_calibrated(pb::CALIBRATION_KIND_SHELF_POSE);
  return out;
}

std::string PatternName(const PatternImage& p) {
  switch (p.kind) {
    case PatternImage::Kind::kWhite:
      return "white";
    case PatternImage::Kind::kBlack:
      return "black";
    case PatternImage::Kind::kColumnBit:
    case PatternImage::Kind::kRowBit:
      return std::string("pattern/") + (p.kind == PatternImage::Kind::kRowBit ? "row/" : "col/") +
             std::to_string(p.bit) + (p.inverse ? "/inverse" : "");
  }
  return "unknown";
}

void CheckSessionName(const std::string& name) {
  if (!IsValidSessionName(name)) {
    throw std::invalid_argument("session '" + runtime::Quoted(name) + "' must match " +
                                kSessionNamePattern);
  }
}

// The image directory of a Calibrate request. A path the OS refuses (too long) or that
// names a file is the caller's mistake, INVALID_ARGUMENT; only a path that does not exist
// is NOT_FOUND. The error_code overloads keep filesystem errors from becoming INTERNAL.
fs::path CheckedImageDirectory(const std::string& text) {
  const std::string quoted = "image_directory '" + runtime::Quoted(text) + "'";
  if (text.empty()) throw std::invalid_argument("image_directory is empty");
  std::error_code ec;
  const fs::file_status status = fs::status(text, ec);
  if (ec == std::errc::filename_too_long) {
    throw std::invalid_argument(quoted + " is too long for the scanner host (" +
                                std::to_string(text.size()) + " bytes)");
  }
  if (ec == std::errc::not_a_directory) {
    throw std::invalid_argument(quoted + " has a file where a directory is expected");
  }
  if (status.type() == fs::file_type::not_found) {
    throw NotFoundError(quoted + " does not exist on the scanner host");
  }
  if (ec) throw std::invalid_argument(quoted + " cannot be read: " + ec.message());
  if (status.type() != fs::file_type::directory) {
    throw std::invalid_argument(quoted + " is not a directory");
  }
  return text;
}

// The calibration workflows with the server's decoding defaults and shelf; skipped views
// are logged as they are found, so a calibration that fails still leaves them in the log.
CalibrationWorkflowOptions WorkflowOptionsFrom(const ScannerSettings& settings) {
  CalibrationWorkflowOptions options;
  options.min_contrast = settings.scan.min_contrast;
  options.min_bit_contrast = settings.scan.min_bit_contrast;
  options.min_depth_m = settings.scan.min_depth_m;
  options.max_depth_m = settings.scan.max_depth_m;
  options.shelf_top = settings.shelf_top;
  options.on_view_skipped = [](const std::string& calibration, const SkippedView& view) {
    runtime::LogWarning(calibration + ": view skipped",
                        {{"view", view.name}, {"reason", view.reason}});
  };
  return options;
}

void SetCalibrateResponse(const CalibrationRun& run, const std::string& calibration_file,
                          pb::CalibrateResponse* response) {
  response->set_calibration_file(calibration_file);
  response->set_rms_reprojection_error_px(run.rms_reprojection_error_px);
  for (double e : run.per_view_error_px) response->add_per_view_error_px(e);
  response->set_views_used(static_cast<std::uint32_t>(run.views_used));
  response->set_residual_translation_m(run.residual_translation_m);
  response->set_residual_rotation_rad(run.residual_rotation_rad);
}

void LogCalibrated(pb::CalibrationKind kind, const CalibrationRun& run) {
  if (kind == pb::CALIBRATION_KIND_PROJECTOR) {
    runtime::LogInfo("projector calibrated",
                     {{"views", std::to_string(run.views_used)},
                      {"skipped", std::to_string(run.skipped.size())},
                      {"projector_rms_px", std::to_string(run.projector_rms_px)},
                      {"stereo_rms_px", std::to_string(run.rms_reprojection_error_px)}});
  } else if (kind == pb::CALIBRATION_KIND_HAND_EYE) {
    runtime::LogInfo("hand-eye calibrated",
                     {{"views", std::to_string(run.views_used)},
                      {"skipped", std::to_string(run.skipped.size())},
                      {"translation_rms_m", std::to_string(run.residual_translation_m)}});
  }
}

class ScannerServiceImpl final : public pb::ScannerService::Service {
 public:
  ScannerServiceImpl(ScannerSettings settings, CalibrationStore store, ScannerDevices devices)
      : settings_(std::move(settings)),
        store_(std::move(store)),
        captures_(settings_.sessions_dir()),
        workflow_(WorkflowOptionsFrom(settings_)),
        camera_(std::move(devices.camera)),
        projector_(std::move(devices.projector)),
        sim_link_(std::move(devices.link)),
        simulator_(std::move(devices.simulator)),
        robot_(std::move(devices.robot)) {
    try {
      state_ = store_.Load();
    } catch (const std::runtime_error& e) {
      throw std::invalid_argument(
          std::string("setting 'calibration.dir': ") + e.what() +
          "; the scanner does not start with a calibration it cannot read (put back a good "
          "file, e.g. from history/, or remove it to use the nominal value)");
    }
    pipeline_ = MakeScanPipeline(state_);
    devices_.camera = camera_.get();
    devices_.projector = projector_.get();
    auto* replay = dynamic_cast<ReplayCamera*>(camera_.get());
    devices_.before_capture = [this, replay](const std::optional<Eigen::Isometry3d>& X_BaseTool) {
      if (sim_link_) sim_link_->SetToolPose(X_BaseTool);
      const int count = Pipeline()->patterns().num_images();
      // A recording plays in a loop: start again when it cannot give a whole sequence.
      if (replay && replay->next_index() + count > replay->image_count()) replay->Rewind();
      // The camera waits for its trigger before the projector starts the sequence.
      try {
        camera_->Arm(count);
      } catch (const CameraError& e) {
        throw UnavailableError(std::string("camera: ") + e.what());
      }
    };
  }

  grpc::Status Scan(grpc::ServerContext* context, const pb::ScanRequest* request,
                    grpc::ServerWriter<pb::ScanResponse>* writer) override {
    return runtime::Guard([&] {
      const DeviceSession device(this, context);
      const std::shared_ptr<ScanPipeline> pipeline = Pipeline();
      const ScanOptions options = ScanOptionsFrom(*request, *pipeline);
      if (request->views_size() > kMaxScanViews) {
        throw std::invalid_argument("a scan has at most " + std::to_string(kMaxScanViews) +
                                    " views, got " + std::to_string(request->views_size()));
      }
      std::vector<ScanViewSpec> views;
      for (int i = 0; i < request->views_size(); ++i) {
        const auto& v = request->views(i);
        ScanViewSpec spec;
        if (v.has_x_base_tool()) {
          spec.X_BaseTool =
              pc::PoseFromProto(v.x_base_tool(), "views[" + std::to_string(i) + "].X_base_tool");
        }
        if (v.has_joints()) {
          pc::JointsFromProto(v.joints(), "views[" + std::to_string(i) + "].joints");
        }
        views.push_back(spec);
      }
      if (views.empty()) views.emplace_back();
      for (auto& v : views) {
        if (!v.X_BaseTool) v.X_BaseTool = CurrentToolPose(options.frame == ScanFrame::kBase);
      }
      ConfigureCamera(0.0);
      const ScanResult result =
          pipeline->Run(devices_, views, options, [&](int view, int count, ScanStage stage) {
            pb::ScanResponse progress;
            progress.mutable_progress()->set_view_index(static_cast<std::uint32_t>(view));
            progress.mutable_progress()->set_view_count(static_cast<std::uint32_t>(count));
            progress.mutable_progress()->set_stage(ToProto(stage));
            writer->Write(progress);
          });
      std::vector<common::v1::PointCloudChunk> chunks = pc::CloudToChunks(result.cloud);
      // One view has one sensor pose, which consumers use for visibility reasoning; a merge
      // of several views has none (each view's pose is in the summary).
      if (result.views.size() == 1 && !chunks.empty()) {
        *chunks.front().mutable_header()->mutable_x_frame_sensor() =
            pc::PoseToProto(result.views.front().X_FrameCamera);
      }
      for (auto& chunk : chunks) {
        pb::ScanResponse out;
        *out.mutable_cloud() = std::move(chunk);
        if (!writer->Write(out)) return grpc::Status(grpc::StatusCode::CANCELLED, "client gone");
      }
      pb::ScanResponse out;
      auto* summary = out.mutable_summary();
      summary->set_point_count(result.num_points);
      for (const auto& v : result.views) {
        summary->add_valid_fraction(v.valid_fraction);
        *summary->add_x_frame_sensor() = pc::PoseToProto(v.X_FrameCamera);
      }
      summary->set_capture_time_s(result.capture_time_s);
      summary->set_processing_time_s(result.processing_time_s);
      writer->Write(out);
      runtime::LogInfo("scan", {{"views", std::to_string(result.views.size())},
                                {"points", std::to_string(result.num_points)},
                                {"capture_s", std::to_string(result.capture_time_s)},
                                {"processing_s", std::to_string(result.processing_time_s)}});
      return grpc::Status::OK;
    });
  }

  grpc::Status CaptureImages(grpc::ServerContext* context, const pb::CaptureImagesRequest* request,
                             grpc::ServerWriter<pb::CaptureImagesResponse>* writer) override {
    return runtime::Guard([&] {
      if (!std::isfinite(request->exposure_s()) || request->exposure_s() < 0 ||
          request->exposure_s() > 10.0) {
        throw std::invalid_argument("exposure_s must be in [0, 10] seconds");
      }
      const DeviceSession device(this, context);
      const std::shared_ptr<ScanPipeline> pipeline = Pipeline();
      ConfigureCamera(request->exposure_s());
      const std::vector<GrayImage> images =
          pipeline->Capture(devices_, CurrentToolPose(/*required=*/false));
      for (std::size_t i = 0; i < images.size(); ++i) {
        pc::Image image;
        image.width = images[i].width;
        image.height = images[i].height;
        image.name = PatternName(pipeline->patterns().Describe(static_cast<int>(i)));
        image.index = static_cast<std::uint32_t>(i);
        image.data = images[i].pixels;
        for (auto& chunk : pc::ImageToChunks(image)) {
          pb::CaptureImagesResponse out;
          *out.mutable_chunk() = std::move(chunk);
          if (!writer->Write(out)) return grpc::Status(grpc::StatusCode::CANCELLED, "client gone");
        }
      }
      return grpc::Status::OK;
    });
  }

  grpc::Status CaptureCalibrationView(grpc::ServerContext* context,
                                      const pb::CaptureCalibrationViewRequest* request,
                                      pb::CaptureCalibrationViewResponse* response) override {
    return runtime::Guard([&] {
      CheckSessionName(request->session());
      std::optional<Eigen::Isometry3d> X_BaseTool;
      if (request->has_x_base_tool()) {
        X_BaseTool = pc::PoseFromProto(request->x_base_tool(), "X_base_tool");
      }
      const DeviceSession device(this, context);
      const std::shared_ptr<ScanPipeline> pipeline = Pipeline();
      if (!X_BaseTool) X_BaseTool = CurrentToolPose(/*required=*/false);
      ConfigureCamera(0.0);
      const std::vector<GrayImage> images = pipeline->Capture(devices_, X_BaseTool);
      const int index = captures_.AddView(request->session(), images, X_BaseTool);
      std::vector<Eigen::Vector2d> corners_px;
      response->set_view_index(static_cast<std::uint32_t>(index));
      response->set_chessboard_found(DetectChessboard(images[0], settings_.board, &corners_px));
      response->set_views_in_session(static_cast<std::uint32_t>(index + 1));
      return grpc::Status::OK;
    });
  }

  // A failed calibration changes nothing: the run is stored, then made current, only once
  // the workflow has accepted it.
  grpc::Status Calibrate(grpc::ServerContext*, const pb::CalibrateRequest* request,
                         pb::CalibrateResponse* response) override {
    return runtime::Guard([&] {
      const ChessboardSpec board = BoardFrom(*request);
      std::lock_guard<std::mutex> lock(calibration_mutex_);
      CalibrationRun run = RunCalibration(*request, board);
      const std::string calibration_file = SaveCalibrationRun(store_, &run);
      MakeCurrent(run.state);
      SetCalibrateResponse(run, calibration_file, response);
      LogCalibrated(request->kind(), run);
      response->set_file_format_version(kCalibrationFormatVersion);
      *response->mutable_calibration() = StateToProto(State());
      return grpc::Status::OK;
    });
  }

  grpc::Status GetCalibration(grpc::ServerContext*, const pb::GetCalibrationRequest*,
                              pb::GetCalibrationResponse* response) override {
    return runtime::Guard([&] {
      *response->mutable_calibration() = StateToProto(State());
      return grpc::Status::OK;
    });
  }

 private:
  CalibrationState State() {
    std::lock_guard<std::mutex> lock(state_mutex_);
    return state_;
  }

  std::shared_ptr<ScanPipeline> Pipeline() {
    std::lock_guard<std::mutex> lock(state_mutex_);
    if (!pipeline_) {
      throw PreconditionError(
          "no camera, projector or camera-projector calibration: nothing to scan with (see "
          "calibration.dir " +
          store_.dir() + ")");
    }
    return pipeline_;
  }

  // Makes `next` current: builds its pipeline first, so a state that cannot scan is refused
  // before anything changes.
  void MakeCurrent(const CalibrationState& next) {
    std::shared_ptr<ScanPipeline> pipeline = MakeScanPipeline(next);
    std::lock_guard<std::mutex> lock(state_mutex_);
    state_ = next;
    pipeline_ = std::move(pipeline);
  }

  // The sensor, held for one call: waits for the capture before it no longer than the call
  // may (its deadline, its cancellation, the server's stop) and makes the simulator's renders
  // children of the call, so that no capture outlives the call it serves.
  class DeviceSession {
   public:
    DeviceSession(ScannerServiceImpl* scanner, const grpc::ServerContext* context)
        : scanner_(scanner) {
      while (!scanner_->device_mutex_.try_lock_for(std::chrono::milliseconds(100))) {
        if (context->IsCancelled()) throw CancelledError("the call was cancelled");
        if (runtime::ShuttingDown()) throw UnavailableError("the scanner is stopping");
        if (std::chrono::system_clock::now() >= context->deadline()) {
          throw TimeoutError("the sensor was busy with another capture until the call's deadline");
        }
      }
      if (scanner_->simulator_) scanner_->simulator_->SetParentCall(context);
    }
    ~DeviceSession() {
      if (scanner_->simulator_) scanner_->simulator_->SetParentCall(nullptr);
      scanner_->device_mutex_.unlock();
    }
    DeviceSession(const DeviceSession&) = delete;
    DeviceSession& operator=(const DeviceSession&) = delete;

   private:
    ScannerServiceImpl* scanner_;
  };

  // The flange pose now: robot service, else the simulated arm. nullopt if neither is
  // configured and `required` is false.
  std::optional<Eigen::Isometry3d> CurrentToolPose(bool required) {
    if (robot_) return robot_->ToolPose();
    if (simulator_) {
      if (!required) return std::nullopt;  // The simulated camera asks the simulator itself.
      return simulator_->ToolPose();
    }
    if (required) {
      throw PreconditionError(
          "a view has no X_base_tool and no robot service is configured (robot.address)");
    }
    return std::nullopt;
  }

  void ConfigureCamera(double exposure_s) {
    CameraSettings settings;
    settings.exposure_us = exposure_s > 0 ? exposure_s * 1e6 : settings_.scan.exposure_us;
    settings.frame_timeout_s = settings_.scan.frame_timeout_s;
    settings.dropped_frame_retries = settings_.scan.dropped_frame_retries;
    settings.trigger_mode = settings_.scan.trigger_mode;
    settings.hardware_trigger_line = settings_.scan.trigger_line;
    try {
      camera_->Configure(settings);
    } catch (const CameraError& e) {
      throw UnavailableError(std::string("camera: ") + e.what());
    }
  }

  ScanOptions ScanOptionsFrom(const pb::ScanRequest& request, const ScanPipeline& pipeline) const {
    const ScanSettings& d = settings_.scan;
    const auto& dec = request.decode();
    ScanOptions o;
    if (dec.min_white_black_contrast() > 255) {
      throw std::invalid_argument("decode.min_white_black_contrast must be <= 255");
    }
    if (dec.min_bit_contrast() > 255) {
      throw std::invalid_argument("decode.min_bit_contrast must be <= 255");
    }
    if (!std::isfinite(dec.max_triangulation_residual_m()) ||
        dec.max_triangulation_residual_m() < 0 || dec.max_triangulation_residual_m() > 1.0) {
      throw std::invalid_argument("decode.max_triangulation_residual_m must be in [0, 1] m");
    }
    if (dec.min_neighbours() > 8) throw std::invalid_argument("decode.min_neighbours must be <= 8");
    o.decode.min_contrast = dec.min_white_black_contrast()
                                ? static_cast<int>(dec.min_white_black_contrast())
                                : d.min_contrast;
    o.decode.min_bit_contrast =
        dec.min_bit_contrast() ? static_cast<int>(dec.min_bit_contrast()) : d.min_bit_contrast;
    o.refinement.refine_rows = d.refine_rows;
    const double residual_m = dec.max_triangulation_residual_m() > 0
                                  ? dec.max_triangulation_residual_m()
                                  : d.max_residual_m;
    o.triangulation.max_residual_projector_px =
        residual_m * pipeline.calibration().projector.fx() / d.reference_distance_m;
    o.triangulation.min_depth_m = d.min_depth_m;
    o.triangulation.max_depth_m = d.max_depth_m;
    o.triangulation.remove_isolated = dec.min_neighbours() > 0;
    o.triangulation.min_neighbors = static_cast<int>(dec.min_neighbours());
    o.normals.step = d.normals_step;
    o.with_normals = request.with_normals();
    o.with_intensities = request.with_intensities();
    if (request.frame_id().empty() || request.frame_id() == "base") {
      o.frame = ScanFrame::kBase;
    } else if (request.frame_id() == "camera") {
      o.frame = ScanFrame::kCamera;
    } else {
      throw std::invalid_argument("frame_id must be \"base\" or \"camera\", got \"" +
                                  request.frame_id() + "\"");
    }
    if (!std::isfinite(request.merge_voxel_m()) || request.merge_voxel_m() < 0) {
      throw std::invalid_argument("merge_voxel_m must be a finite number >= 0");
    }
    o.merge.voxel_m = request.merge_voxel_m();
    if (request.has_crop()) {
      const Eigen::Vector3d lo = pc::VectorFromProto(request.crop().min(), "crop.min");
      const Eigen::Vector3d hi = pc::VectorFromProto(request.crop().max(), "crop.max");
      o.crop = std::make_pair(lo, hi);
    }
    return o;
  }

  ChessboardSpec BoardFrom(const pb::CalibrateRequest& request) const {
    ChessboardSpec board = settings_.board;
    if (request.has_board()) {
      const auto& b = request.board();
      // 0 keeps the configured value; OpenCV's corner finder needs 3 or more per side.
      const auto side_ok = [](std::uint32_t n) { return n == 0 || (n >= 3 && n <= 100); };
      if (!side_ok(b.inner_corners_cols()) || !side_ok(b.inner_corners_rows())) {
        throw std::invalid_argument("board: 3 to 100 inner corners per side, got " +
                                    std::to_string(b.inner_corners_cols()) + " x " +
                                    std::to_string(b.inner_corners_rows()));
      }
      if (b.inner_corners_cols()) board.inner_corners_x = static_cast<int>(b.inner_corners_cols());
      if (b.inner_corners_rows()) board.inner_corners_y = static_cast<int>(b.inner_corners_rows());
      if (b.square_size_m() != 0.0) {
        if (!(b.square_size_m() > 0 && b.square_size_m() <= 1.0)) {
          throw std::invalid_argument("board.square_size_m must be in (0, 1]");
        }
        board.square_size_m = b.square_size_m();
      }
    }
    board.Validate();
    return board;
  }

  // The views of the request's source: a session's views, or one view per image / per
  // subfolder of an image directory. Checked when the workflow lists them, after the
  // calibration state.
  ViewSource ViewSourceOf(const pb::CalibrateRequest& request) const {
    return [this, &request](ViewLayout layout) -> std::vector<StoredView> {
      switch (request.source_case()) {
        case pb::CalibrateRequest::kSession:
          CheckSessionName(request.session());
          return captures_.SessionViews(request.session());
        case pb::CalibrateRequest::kImageDirectory:
          return ImageDirectoryViews(CheckedImageDirectory(request.image_directory()), layout);
        default:
          throw std::invalid_argument("source: give a session or an image_directory");
      }
    };
  }

  CalibrationRun RunCalibration(const pb::CalibrateRequest& request, const ChessboardSpec& board) {
    const ViewSource source = ViewSourceOf(request);
    switch (request.kind()) {
      case pb::CALIBRATION_KIND_CAMERA:
        return workflow_.Camera(source, board, State());
      case pb::CALIBRATION_KIND_PROJECTOR:
        return workflow_.Projector(source, board, State(), projector_.get());
      case pb::CALIBRATION_KIND_HAND_EYE:
        return workflow_.HandEye(source, board, State());
      case pb::CALIBRATION_KIND_SHELF_POSE: {
        const CalibrationState current = State();
        const std::shared_ptr<ScanPipeline> pipeline = Pipeline();
        return workflow_.ShelfPose(source, current, *pipeline);
      }
      default:
        throw std::invalid_argument("kind: unknown or unspecified calibration kind " +
                                    std::to_string(request.kind()));
    }
  }

  const ScannerSettings settings_;
  const CalibrationStore store_;
  const CaptureStore captures_;
  const CalibrationWorkflow workflow_;
  std::unique_ptr<CameraBackend> camera_;
  std::unique_ptr<ProjectorBackend> projector_;
  std::shared_ptr<SimSensorLink> sim_link_;
  std::shared_ptr<SimulatorClient> simulator_;
  std::shared_ptr<RobotPoseClient> robot_;
  ScanDevices devices_;

  std::timed_mutex device_mutex_;  // One capture at a time (DeviceSession).
  std::mutex calibration_mutex_;   // One calibration at a time.
  std::mutex state_mutex_;         // Guards state_ and pipeline_.
  CalibrationState state_;
  std::shared_ptr<ScanPipeline> pipeline_;
};

}  // namespace

runtime::ServiceSet BuildScannerServices(const runtime::Config& config) {
  // The simulator and the robot service are called with this server's own tls.* settings.
  const runtime::ChannelFactory channels = runtime::ChannelFactory::FromConfig(config);
  ScannerSettings settings = ScannerSettings::FromConfig(config);
  ScannerDevices devices = OpenScannerDevices(settings, channels);
  CalibrationStore store(settings.calibration_dir, settings.nominal_dir);
  const SensorSettings sensor = settings.sensor;
  const std::string calibration_dir = settings.calibration_dir;
  auto service = std::make_shared<ScannerServiceImpl>(std::move(settings), std::move(store),
                                                      std::move(devices));
  runtime::LogInfo("scanner configured", {{"camera", sensor.camera},
                                          {"projector", sensor.projector},
                                          {"calibration.dir", calibration_dir}});
  runtime::ServiceSet set;
  set.Add(service, pb::ScannerService::service_full_name());
  return set;
}

}  // namespace picking::scanner
