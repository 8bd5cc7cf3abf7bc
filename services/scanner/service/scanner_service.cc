#include "services/scanner/service/scanner_service.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <mutex>
#include <optional>
#include <regex>
#include <sstream>
#include <stdexcept>

#include "libs/apc/catalogue.h"
#include "libs/errors/errors.h"
#include "libs/proto_convert/proto_convert.h"
#include "libs/runtime/log.h"
#include "libs/runtime/server.h"
#include "libs/runtime/status.h"
#include "services/scanner/core/aravis_camera.h"
#include "services/scanner/core/calibration.h"
#include "services/scanner/core/calibration_io.h"
#include "services/scanner/core/calibration_shelf.h"
#include "services/scanner/core/dlpc350.h"
#include "services/scanner/core/merge.h"
#include "services/scanner/core/replay_camera.h"
#include "services/scanner/core/scan_pipeline.h"
#include "services/scanner/core/sim_backends.h"
#include "services/scanner/service/calibration_store.h"
#include "services/scanner/service/sim_clients.h"

namespace picking::scanner {
namespace {

namespace fs = std::filesystem;
namespace pb = ::picking::scanner::v1;
namespace pc = ::picking::proto_convert;

// Views of one Scan: the paper takes 3 of a shelf bin and 2 of the tote; each view is a
// full pattern sequence (about a second), so the bound keeps one call's work bounded.
constexpr int kMaxScanViews = 16;
constexpr int kMinCalibrationViews = 3;

// Server-wide defaults of a scan, from the settings.
struct ScanDefaults {
  int min_contrast = 20;
  // 1 rather than a larger margin: a pixel on a stripe edge has |pattern - inverse| near 0 in
  // its finest bits, and the sub-pixel refinement places such pixels correctly, so a larger
  // threshold only removes good points (bin_E at 1 m in simulation: 72.9 % of the bin's
  // visible surface covered with 1, 53.6 % with 5, median depth error 0.075 mm either way).
  int min_bit_contrast = 1;
  // Sub-pixel refinement of the projector rows as well as the columns. With the projector
  // beside the camera depth comes from the column; the rows add ~0.01 mm of median depth
  // accuracy (bin_E at 1 m: 0.085 -> 0.075 mm) for twice the refinement time.
  bool refine_rows = false;
  double max_residual_m = 0.001;
  double reference_distance_m = 1.0;  // Where max_residual_m is converted to projector px.
  double min_depth_m = 0.1;
  double max_depth_m = 3.0;
  int normals_step = 2;
  double exposure_us = 8000.0;
  double frame_timeout_s = 2.0;
  int dropped_frame_retries = 2;  // Software trigger: takes of a frame that came incomplete.
  // How frames are started: by the projector's trigger output (hardware), by the scanner
  // (software), or by the camera's own clock (free run).
  TriggerMode trigger_mode = TriggerMode::kHardware;
  std::string trigger_line = "Line0";
};

struct ServiceOptions {
  ScanDefaults scan;
  ChessboardSpec board;
  ShelfTopModel shelf_top;
  std::string sessions_dir;
};

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

// The scan pipeline of a calibration state, or null when camera, projector or their pose
// are missing.
std::shared_ptr<ScanPipeline> MakePipeline(const CalibrationState& s) {
  if (!s.camera || !s.projector || !s.X_CameraProjector) return nullptr;
  const camera::PinholeCamera projector = s.projector->ToPinholeCamera();
  return std::make_shared<ScanPipeline>(
      ScanCalibration{s.camera->ToPinholeCamera(), projector, *s.X_CameraProjector, s.X_ToolCamera},
      PatternSequence(projector.width(), projector.height()));
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
  static const std::regex kPattern("[A-Za-z0-9_-]{1,64}");
  if (!std::regex_match(name, kPattern)) {
    throw std::invalid_argument("session '" + runtime::Quoted(name) +
                                "' must match [A-Za-z0-9_-]{1,64}");
  }
}

std::string ViewDirName(int index) {
  std::ostringstream s;
  s << "view_" << std::setw(3) << std::setfill('0') << index;
  return s.str();
}

std::string ImageFileName(int index) {
  std::ostringstream s;
  s << "img_" << std::setw(2) << std::setfill('0') << index << ".png";
  return s.str();
}

// A pose as one line "x y z qx qy qz qw" (metres, unit quaternion).
void WritePoseFile(const std::string& path, const Eigen::Isometry3d& X) {
  const Eigen::Quaterniond q(X.linear());
  std::ofstream out(path);
  out << std::setprecision(17) << X.translation().x() << ' ' << X.translation().y() << ' '
      << X.translation().z() << ' ' << q.x() << ' ' << q.y() << ' ' << q.z() << ' ' << q.w()
      << '\n';
  if (!out) throw std::runtime_error("cannot write " + path);
}

std::optional<Eigen::Isometry3d> ReadPoseFile(const std::string& path) {
  std::ifstream in(path);
  if (!in) return std::nullopt;
  double v[7];
  for (double& x : v) {
    if (!(in >> x) || !std::isfinite(x)) throw std::runtime_error(path + ": malformed pose");
  }
  const Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
  if (std::abs(q.norm() - 1.0) > 1e-3) throw std::runtime_error(path + ": quaternion not unit");
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = q.normalized().toRotationMatrix();
  X.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
  return X;
}

bool IsImageFile(const fs::path& p) {
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), ::tolower);
  return ext == ".png" || ext == ".jpg" || ext == ".jpeg" || ext == ".bmp" || ext == ".pgm";
}

std::vector<fs::path> SortedEntries(const fs::path& dir, bool directories) {
  std::vector<fs::path> out;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (directories ? e.is_directory() : (e.is_regular_file() && IsImageFile(e.path()))) {
      out.push_back(e.path());
    }
  }
  std::sort(out.begin(), out.end());
  return out;
}

// One stored calibration view: its folder, robot pose if known.
struct StoredView {
  std::string name;
  fs::path dir;
  std::optional<Eigen::Isometry3d> X_BaseTool;
};

class ScannerServiceImpl final : public pb::ScannerService::Service {
 public:
  ScannerServiceImpl(ServiceOptions options, CalibrationStore store,
                     std::unique_ptr<CameraBackend> camera,
                     std::unique_ptr<ProjectorBackend> projector,
                     std::shared_ptr<SimSensorLink> sim_link,
                     std::shared_ptr<SimulatorClient> simulator,
                     std::shared_ptr<RobotPoseClient> robot)
      : options_(std::move(options)),
        store_(std::move(store)),
        camera_(std::move(camera)),
        projector_(std::move(projector)),
        sim_link_(std::move(sim_link)),
        simulator_(std::move(simulator)),
        robot_(std::move(robot)) {
    try {
      state_ = store_.Load();
    } catch (const std::runtime_error& e) {
      throw std::invalid_argument(
          std::string("setting 'calibration.dir': ") + e.what() +
          "; the scanner does not start with a calibration it cannot read (put back a good "
          "file, e.g. from history/, or remove it to use the nominal value)");
    }
    pipeline_ = MakePipeline(state_);
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
            progress.mutable_progress()->set_stage(ScanStageName(stage));
            writer->Write(progress);
          });
      std::vector<common::v1::PointCloudChunk> chunks = pc::CloudToChunks(result.cloud);
      // One view has one sensor pose, which consumers use for visibility reasoning; a merge
      // of several views has none (each view's pose is in the summary).
      if (result.views.size() == 1 && !chunks.empty()) {
        *chunks.front().mutable_header()->mutable_sensor_pose() =
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
        *summary->add_x_frame_camera() = pc::PoseToProto(v.X_FrameCamera);
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
                             grpc::ServerWriter<common::v1::ImageChunk>* writer) override {
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
        for (const auto& chunk : pc::ImageToChunks(image)) {
          if (!writer->Write(chunk))
            return grpc::Status(grpc::StatusCode::CANCELLED, "client gone");
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
      const fs::path session = fs::path(options_.sessions_dir) / request->session();
      fs::create_directories(session);
      const int index = static_cast<int>(SortedEntries(session, true).size());
      const fs::path tmp = session / (".tmp_" + ViewDirName(index));
      fs::remove_all(tmp);
      fs::create_directories(tmp);
      for (std::size_t i = 0; i < images.size(); ++i) {
        WriteGrayImage((tmp / ImageFileName(static_cast<int>(i))).string(), images[i]);
      }
      if (X_BaseTool) WritePoseFile((tmp / "X_base_tool.txt").string(), *X_BaseTool);
      fs::rename(tmp, session / ViewDirName(index));
      std::vector<Eigen::Vector2d> corners;
      response->set_view_index(static_cast<std::uint32_t>(index));
      response->set_chessboard_found(DetectChessboard(images[0], options_.board, &corners));
      response->set_views_in_session(static_cast<std::uint32_t>(index + 1));
      return grpc::Status::OK;
    });
  }

  grpc::Status Calibrate(grpc::ServerContext*, const pb::CalibrateRequest* request,
                         pb::CalibrateResponse* response) override {
    return runtime::Guard([&] {
      const ChessboardSpec board = BoardFrom(*request);
      std::lock_guard<std::mutex> lock(calibration_mutex_);
      switch (request->kind()) {
        case pb::CALIBRATION_KIND_CAMERA:
          CalibrateCameraKind(*request, board, response);
          break;
        case pb::CALIBRATION_KIND_PROJECTOR:
          CalibrateProjectorKind(*request, board, response);
          break;
        case pb::CALIBRATION_KIND_HAND_EYE:
          CalibrateHandEyeKind(*request, board, response);
          break;
        case pb::CALIBRATION_KIND_SHELF_POSE:
          CalibrateShelfKind(*request, response);
          break;
        default:
          throw std::invalid_argument("kind: unknown or unspecified calibration kind " +
                                      std::to_string(request->kind()));
      }
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
    std::shared_ptr<ScanPipeline> pipeline = MakePipeline(next);
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
    settings.exposure_us = exposure_s > 0 ? exposure_s * 1e6 : options_.scan.exposure_us;
    settings.frame_timeout_s = options_.scan.frame_timeout_s;
    settings.dropped_frame_retries = options_.scan.dropped_frame_retries;
    settings.trigger_mode = options_.scan.trigger_mode;
    settings.hardware_trigger_line = options_.scan.trigger_line;
    try {
      camera_->Configure(settings);
    } catch (const CameraError& e) {
      throw UnavailableError(std::string("camera: ") + e.what());
    }
  }

  ScanOptions ScanOptionsFrom(const pb::ScanRequest& request, const ScanPipeline& pipeline) const {
    const ScanDefaults& d = options_.scan;
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
    ChessboardSpec board = options_.board;
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

  // The image directory of a Calibrate request. A path the OS refuses (too long) or that
  // names a file is the caller's mistake, INVALID_ARGUMENT; only a path that does not exist
  // is NOT_FOUND. The error_code overloads keep filesystem errors from becoming INTERNAL.
  static fs::path CheckedImageDirectory(const std::string& text) {
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

  // The views of the request's source: a session's views, or one view per image / per
  // subfolder of an image directory.
  std::vector<StoredView> ViewsOf(const pb::CalibrateRequest& request, bool sequences) const {
    std::vector<StoredView> views;
    if (request.source_case() == pb::CalibrateRequest::kSession) {
      CheckSessionName(request.session());
      const fs::path dir = fs::path(options_.sessions_dir) / request.session();
      if (!fs::is_directory(dir)) {
        throw NotFoundError("calibration session '" + request.session() + "' does not exist");
      }
      for (const auto& v : SortedEntries(dir, true)) {
        if (v.filename().string().rfind("view_", 0) != 0) continue;
        views.push_back({v.filename().string(), v, ReadPoseFile((v / "X_base_tool.txt").string())});
      }
    } else if (request.source_case() == pb::CalibrateRequest::kImageDirectory) {
      const fs::path dir = CheckedImageDirectory(request.image_directory());
      if (sequences) {
        for (const auto& v : SortedEntries(dir, true)) {
          views.push_back(
              {v.filename().string(), v, ReadPoseFile((v / "X_base_tool.txt").string())});
        }
      } else {
        for (const auto& f : SortedEntries(dir, false))
          views.push_back({f.filename().string(), f, {}});
      }
    } else {
      throw std::invalid_argument("source: give a session or an image_directory");
    }
    return views;
  }

  // The white image of a view (a single image file, or img_00 of a sequence folder).
  static GrayImage WhiteImage(const StoredView& v) {
    if (fs::is_directory(v.dir)) return ReadGrayImage((v.dir / ImageFileName(0)).string());
    return ReadGrayImage(v.dir.string());
  }

  static std::vector<GrayImage> SequenceImages(const StoredView& v, int count) {
    const std::vector<fs::path> files = SortedEntries(v.dir, false);
    if (static_cast<int>(files.size()) != count) {
      throw std::invalid_argument("view " + v.name + " holds " + std::to_string(files.size()) +
                                  " images, the sequence has " + std::to_string(count));
    }
    std::vector<GrayImage> images;
    for (const auto& f : files) images.push_back(ReadGrayImage(f.string()));
    return images;
  }

  // Chessboard views with a detectable board; FAILED_PRECONDITION for fewer than 3.
  std::vector<ChessboardView> BoardViews(const std::vector<StoredView>& views,
                                         const ChessboardSpec& board,
                                         std::vector<const StoredView*>* used) const {
    std::vector<ChessboardView> out;
    for (const auto& v : views) {
      GrayImage image = WhiteImage(v);
      std::vector<Eigen::Vector2d> corners;
      if (!DetectChessboard(image, board, &corners)) continue;
      out.push_back({v.name, std::move(image)});
      if (used) used->push_back(&v);
    }
    if (static_cast<int>(out.size()) < kMinCalibrationViews) {
      throw PreconditionError("calibration needs at least " + std::to_string(kMinCalibrationViews) +
                              " views with the " + std::to_string(board.inner_corners_x) + " x " +
                              std::to_string(board.inner_corners_y) + " chessboard in sight, got " +
                              std::to_string(out.size()) + " of " + std::to_string(views.size()));
    }
    return out;
  }

  void CalibrateCameraKind(const pb::CalibrateRequest& request, const ChessboardSpec& board,
                           pb::CalibrateResponse* response) {
    const std::vector<StoredView> views = ViewsOf(request, /*sequences=*/false);
    const std::vector<ChessboardView> board_views = BoardViews(views, board, nullptr);
    CameraCalibrationOptions options;
    options.board = board;
    options.skip_views_without_board = true;
    const CameraCalibrationResult result = CalibrateCamera(board_views, options);
    CalibrationState next = State();
    next.camera = result.intrinsics;
    next.camera_calibrated = true;
    MakePipeline(next);  // Throws (nothing saved) if the result cannot be used.
    IntrinsicsFile file{result.intrinsics, {"", result.rms_px, "px"}};
    response->set_calibration_file(store_.SaveIntrinsics(CalibrationKind::kCameraIntrinsics, file));
    MakeCurrent(next);
    response->set_rms_reprojection_error_px(result.rms_px);
    for (double e : result.per_view_rms_px) response->add_per_view_error_px(e);
    response->set_views_used(static_cast<std::uint32_t>(result.used_views.size()));
  }

  // The projector the scanner drives: the projector device's size when there is one, else
  // the current (calibrated or nominal) projector intrinsics' size.
  PatternSequence ProjectorPatterns(const CalibrationState& current) const {
    if (projector_) {
      return PatternSequence(static_cast<int>(projector_->width()),
                             static_cast<int>(projector_->height()));
    }
    if (current.projector) {
      return PatternSequence(static_cast<int>(current.projector->width),
                             static_cast<int>(current.projector->height));
    }
    throw PreconditionError(
        "projector calibration: the projector size is unknown (no projector device and no "
        "projector_intrinsics.json in calibration.dir or sensor.nominal_dir)");
  }

  // "view_001 (reason); view_004 (reason)" for an error message, at most `limit` entries.
  static std::string ListReasons(const std::vector<std::pair<std::string, std::string>>& skipped,
                                 std::size_t limit = 6) {
    std::string out;
    for (std::size_t i = 0; i < skipped.size() && i < limit; ++i) {
      out += (i ? "; " : "") + skipped[i].first + ": " + skipped[i].second;
    }
    if (skipped.size() > limit) out += "; and " + std::to_string(skipped.size() - limit) + " more";
    return out;
  }

  void CalibrateProjectorKind(const pb::CalibrateRequest& request, const ChessboardSpec& board,
                              pb::CalibrateResponse* response) {
    const CalibrationState current = State();
    const PatternSequence patterns = ProjectorPatterns(current);
    ProjectorCalibrationOptions options;
    options.board = board;
    options.projector.width = static_cast<std::uint32_t>(patterns.projector_width());
    options.projector.height = static_cast<std::uint32_t>(patterns.projector_height());
    options.projector.column_bits = patterns.column_bits();
    options.projector.row_bits = patterns.row_bits();
    options.decode.min_contrast = options_.scan.min_contrast;
    options.decode.min_bit_difference = options_.scan.min_bit_contrast;
    ProjectorCalibrator calibrator(options);
    const std::vector<StoredView> views = ViewsOf(request, /*sequences=*/true);
    std::vector<std::pair<std::string, std::string>> skipped;
    for (const auto& v : views) {
      try {
        calibrator.AddView(v.name, SequenceImages(v, options.projector.image_count()));
      } catch (const std::invalid_argument& e) {
        skipped.emplace_back(v.name, e.what());
        runtime::LogWarning("projector calibration: view skipped",
                            {{"view", v.name}, {"reason", e.what()}});
      }
    }
    if (calibrator.view_count() < kMinCalibrationViews) {
      throw PreconditionError(
          "projector calibration needs at least " + std::to_string(kMinCalibrationViews) +
          " views with the " + std::to_string(board.inner_corners_x) + " x " +
          std::to_string(board.inner_corners_y) + " chessboard and the " +
          std::to_string(options.projector.image_count()) + "-image Gray-code sequence of the " +
          std::to_string(options.projector.width) + " x " +
          std::to_string(options.projector.height) + " projector, got " +
          std::to_string(calibrator.view_count()) + " of " + std::to_string(views.size()) +
          (skipped.empty() ? std::string() : " (" + ListReasons(skipped) + ")"));
    }
    ProjectorCalibrationResult result;
    try {
      result = calibrator.Calibrate();
    } catch (const std::invalid_argument& e) {
      throw PreconditionError(std::string("projector calibration: ") + e.what());
    }
    CalibrationState next = current;
    next.camera = result.camera;
    next.projector = result.projector;
    next.X_CameraProjector = result.X_CameraProjector;
    next.camera_calibrated = true;
    next.projector_calibrated = true;
    MakePipeline(next);  // Throws (nothing saved) if the result cannot be used.
    store_.SaveIntrinsics(CalibrationKind::kCameraIntrinsics,
                          {result.camera, {"", result.camera_rms_px, "px"}});
    store_.SaveIntrinsics(CalibrationKind::kProjectorIntrinsics,
                          {result.projector, {"", result.projector_rms_px, "px"}});
    response->set_calibration_file(
        store_.SavePose(CalibrationKind::kCameraProjectorExtrinsics,
                        {result.X_CameraProjector, {"", result.stereo_rms_px, "px"}}));
    // The pose as stored (a quaternion), so that a restarted scanner has the same values.
    next.X_CameraProjector =
        LoadPose(response->calibration_file(), CalibrationKind::kCameraProjectorExtrinsics).pose;
    MakeCurrent(next);
    response->set_rms_reprojection_error_px(result.stereo_rms_px);
    response->set_views_used(static_cast<std::uint32_t>(calibrator.view_count()));
    runtime::LogInfo("projector calibrated",
                     {{"views", std::to_string(calibrator.view_count())},
                      {"skipped", std::to_string(skipped.size())},
                      {"projector_rms_px", std::to_string(result.projector_rms_px)},
                      {"stereo_rms_px", std::to_string(result.stereo_rms_px)}});
  }

  // Hand-eye (camera on the wrist): the board pose in each view from the current camera
  // intrinsics (cv::solvePnP), paired with the robot pose of the view.
  void CalibrateHandEyeKind(const pb::CalibrateRequest& request, const ChessboardSpec& board,
                            pb::CalibrateResponse* response) {
    const CalibrationState current = State();
    if (!current.camera) {
      throw PreconditionError(
          "hand-eye calibration needs the camera intrinsics (calibrate the "
          "camera first)");
    }
    const std::vector<StoredView> views = ViewsOf(request, /*sequences=*/true);
    std::vector<std::pair<std::string, std::string>> skipped;
    std::vector<Eigen::Isometry3d> X_BaseTool, X_CameraBoard;
    std::vector<double> rms_px;
    for (const auto& v : views) {
      if (!v.X_BaseTool) {
        skipped.emplace_back(v.name, "no robot pose (X_base_tool.txt)");
        continue;
      }
      const GrayImage image = WhiteImage(v);
      if (image.width != current.camera->width || image.height != current.camera->height) {
        throw PreconditionError(
            "hand-eye calibration: view " + v.name + " is " + std::to_string(image.width) + " x " +
            std::to_string(image.height) + " pixels but the camera intrinsics are for " +
            std::to_string(current.camera->width) + " x " + std::to_string(current.camera->height));
      }
      BoardPose pose;
      if (!EstimateBoardPose(image, board, *current.camera, &pose)) {
        skipped.emplace_back(v.name, "chessboard not found");
        continue;
      }
      X_BaseTool.push_back(*v.X_BaseTool);
      X_CameraBoard.push_back(pose.X_CameraBoard);
      rms_px.push_back(pose.rms_px);
    }
    if (static_cast<int>(X_BaseTool.size()) < kMinCalibrationViews) {
      throw PreconditionError(
          "hand-eye calibration needs at least " + std::to_string(kMinCalibrationViews) +
          " views with a robot pose and the " + std::to_string(board.inner_corners_x) + " x " +
          std::to_string(board.inner_corners_y) + " chessboard in sight, got " +
          std::to_string(X_BaseTool.size()) + " of " + std::to_string(views.size()) +
          (skipped.empty() ? std::string() : " (" + ListReasons(skipped) + ")"));
    }
    HandEyeResult result;
    try {
      result = CalibrateHandEye(X_BaseTool, X_CameraBoard);
    } catch (const std::invalid_argument& e) {
      // The core's messages start with "hand-eye calibration".
      throw PreconditionError(std::string(e.what()) +
                              " (turn the wrist about different axes between views)");
    }
    CalibrationState next = current;
    next.X_ToolCamera = result.X_ToolCamera;
    next.hand_eye_calibrated = true;
    MakePipeline(next);
    response->set_calibration_file(store_.SavePose(
        CalibrationKind::kHandEye, {result.X_ToolCamera, {"", result.translation_rms_m, "m"}}));
    next.X_ToolCamera = LoadPose(response->calibration_file(), CalibrationKind::kHandEye).pose;
    MakeCurrent(next);
    double sum_sq = 0.0;
    for (double e : rms_px) {
      response->add_per_view_error_px(e);
      sum_sq += e * e;
    }
    response->set_rms_reprojection_error_px(std::sqrt(sum_sq / static_cast<double>(rms_px.size())));
    response->set_views_used(static_cast<std::uint32_t>(X_BaseTool.size()));
    response->set_residual_translation_m(result.translation_rms_m);
    response->set_residual_rotation_rad(result.rotation_rms_rad);
    runtime::LogInfo("hand-eye calibrated",
                     {{"views", std::to_string(X_BaseTool.size())},
                      {"skipped", std::to_string(skipped.size())},
                      {"translation_rms_m", std::to_string(result.translation_rms_m)}});
  }

  void CalibrateShelfKind(const pb::CalibrateRequest& request, pb::CalibrateResponse* response) {
    const CalibrationState current = State();
    if (!current.X_ToolCamera) {
      throw PreconditionError("shelf pose calibration needs the hand-eye calibration");
    }
    const std::shared_ptr<ScanPipeline> pipeline = Pipeline();
    ScanOptions options;
    options.with_normals = false;
    options.with_intensities = false;
    options.decode.min_contrast = options_.scan.min_contrast;
    options.decode.min_bit_contrast = options_.scan.min_bit_contrast;
    options.triangulation.min_depth_m = options_.scan.min_depth_m;
    options.triangulation.max_depth_m = options_.scan.max_depth_m;
    std::vector<geometry::PointCloud> clouds;
    const std::vector<StoredView> views = ViewsOf(request, /*sequences=*/true);
    std::vector<std::pair<std::string, std::string>> skipped;
    for (const auto& v : views) {
      if (!v.X_BaseTool) {
        skipped.emplace_back(v.name, "no robot pose (X_base_tool.txt)");
        continue;
      }
      geometry::PointCloud cloud;
      double valid_fraction = 0.0;
      try {
        cloud = pipeline->ProcessView(SequenceImages(v, pipeline->patterns().num_images()), options,
                                      &valid_fraction);
      } catch (const std::invalid_argument& e) {
        skipped.emplace_back(v.name, e.what());
        continue;
      }
      if (valid_fraction <= 0.0) {
        skipped.emplace_back(v.name, "no pixel decodes (is the projector lighting the shelf?)");
        continue;
      }
      TransformCloud(*v.X_BaseTool * *current.X_ToolCamera, "base", &cloud);
      clouds.push_back(std::move(cloud));
    }
    if (clouds.empty()) {
      throw PreconditionError(
          "shelf pose calibration needs at least one scan of the shelf's top front edge with "
          "its robot pose, got none of " +
          std::to_string(views.size()) + " views" +
          (skipped.empty() ? std::string() : " (" + ListReasons(skipped) + ")"));
    }
    const geometry::PointCloud merged = MergeClouds(clouds).cloud;
    ShelfPoseResult result;
    try {
      result = EstimateShelfPose(merged, options_.shelf_top);
    } catch (const std::invalid_argument& e) {
      throw PreconditionError(std::string("shelf pose: ") + e.what());
    }
    CalibrationState next = current;
    next.X_BaseShelf = result.X_BaseShelf;
    next.shelf_calibrated = true;
    response->set_calibration_file(store_.SavePose(
        CalibrationKind::kShelfPose, {result.X_BaseShelf, {"", result.fit_rms_m, "m"}}));
    next.X_BaseShelf = LoadPose(response->calibration_file(), CalibrationKind::kShelfPose).pose;
    MakeCurrent(next);
    response->set_views_used(static_cast<std::uint32_t>(clouds.size()));
    response->set_residual_translation_m(result.fit_rms_m);
    response->set_residual_rotation_rad(std::acos(
        std::clamp(result.top_normal_Base.dot(result.X_BaseShelf.linear().col(2)), -1.0, 1.0)));
  }

  const ServiceOptions options_;
  const CalibrationStore store_;
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

// The simulated sensor's true geometry: the nominal files.
SimSensorModel LoadSimModel(const std::string& dir) {
  const std::string base = dir + "/";
  try {
    SimSensorModel model{
        LoadIntrinsics(base + "camera_intrinsics.json", CalibrationKind::kCameraIntrinsics)
            .intrinsics.ToPinholeCamera(),
        LoadIntrinsics(base + "projector_intrinsics.json", CalibrationKind::kProjectorIntrinsics)
            .intrinsics.ToPinholeCamera()};
    model.X_CameraProjector =
        LoadPose(base + "camera_projector.json", CalibrationKind::kCameraProjectorExtrinsics).pose;
    model.X_ToolCamera = LoadPose(base + "hand_eye.json", CalibrationKind::kHandEye).pose;
    return model;
  } catch (const std::runtime_error& e) {
    throw std::invalid_argument(std::string("setting 'sensor.nominal_dir': ") + e.what());
  }
}

ShelfTopModel ShelfTopFrom(const std::vector<double>& v) {
  if (v.size() != 12) {
    throw std::invalid_argument("setting 'shelf.top_corners_m' needs 12 numbers (4 corners)");
  }
  ShelfTopModel m{Eigen::Vector3d(v[0], v[1], v[2]), Eigen::Vector3d(v[3], v[4], v[5]),
                  Eigen::Vector3d(v[6], v[7], v[8]), Eigen::Vector3d(v[9], v[10], v[11])};
  m.Validate();
  return m;
}

}  // namespace

std::vector<std::string> ScannerSettingsHelp() {
  return {
      "camera=sim|aravis|replay (default sim)",
      "projector=sim|dlpc350|none (default: sim with camera=sim, none with replay, dlpc350 "
      "with aravis)",
      "sim.address=HOST:PORT of picking-simulator (default 127.0.0.1:50051)",
      "sim.timeout_s, sim.ambient, sim.noise_sigma, sim.gamma, sim.electrons_per_dn, "
      "sim.projector_blur_sigma_px, sim.seed: simulated rendering",
      "robot.address=HOST:PORT of picking-robot for poses of views without one (default none)",
      "robot.timeout_s=2",
      "aravis.device=ID (default: first camera; a GigE Vision camera also by its IP address)",
      "replay.dir=FOLDER of PNG or PGM frames, played in name order (camera=replay)",
      "dlpc350.device=/dev/hidrawN (projector=dlpc350)",
      "calibration.dir=FOLDER of the current calibration files (default <data>/scanner)",
      "sensor.nominal_dir=FOLDER of the nominal (simulated) sensor (default "
      "<data>/scanner/sim_sensor)",
      "decode.min_contrast=20, decode.min_bit_contrast=1, decode.max_residual_m=0.001, "
      "decode.reference_distance_m=1, decode.refine_rows=false (sub-pixel rows too)",
      "scan.min_depth_m=0.1, scan.max_depth_m=3, scan.normals_step=2",
      "camera.exposure_us=8000, camera.frame_timeout_s=2 (wait for a frame beyond its exposure)",
      "camera.dropped_frame_retries=2 (software trigger: take an incomplete frame again)",
      "camera.trigger=hardware|software|free_run (default: hardware with a projector, free_run "
      "with projector=none), camera.trigger_line=Line0 (GenICam line of the projector's "
      "trigger output)",
      "board.inner_corners_cols=9, board.inner_corners_rows=6, board.square_size_m=0.025",
      "shelf.top_corners_m=12 numbers (shelf frame top corners)",
  };
}

namespace {

SimRenderSettings SimRenderSettingsFrom(const runtime::Config& config) {
  SimRenderSettings render;
  render.timeout_s = config.GetDouble("sim.timeout_s", render.timeout_s);
  render.ambient = config.GetDouble("sim.ambient", render.ambient);
  render.noise_sigma = config.GetDouble("sim.noise_sigma", render.noise_sigma);
  render.gamma = config.GetDouble("sim.gamma", render.gamma);
  render.electrons_per_dn = config.GetDouble("sim.electrons_per_dn", render.electrons_per_dn);
  render.projector_blur_sigma_px =
      config.GetDouble("sim.projector_blur_sigma_px", render.projector_blur_sigma_px);
  return render;
}

TriggerMode TriggerModeFrom(const std::string& trigger) {
  if (trigger == "hardware") return TriggerMode::kHardware;
  if (trigger == "software") return TriggerMode::kSoftware;
  if (trigger == "free_run") return TriggerMode::kFreeRun;
  throw std::invalid_argument(
      "setting 'camera.trigger' must be hardware, software or free_run, got '" + trigger + "'");
}

void ValidateScanDefaults(const ScanDefaults& d) {
  if (d.dropped_frame_retries < 0) {
    throw std::invalid_argument("setting 'camera.dropped_frame_retries' must be >= 0, got " +
                                std::to_string(d.dropped_frame_retries));
  }
  if (d.trigger_line.empty()) throw std::invalid_argument("setting 'camera.trigger_line' is empty");
  if (!(d.exposure_us > 0)) throw std::invalid_argument("setting 'camera.exposure_us' must be > 0");
  if (!(d.frame_timeout_s > 0)) {
    throw std::invalid_argument("setting 'camera.frame_timeout_s' must be > 0");
  }
  if (d.min_contrast < 0 || d.min_contrast > 255) {
    throw std::invalid_argument("setting 'decode.min_contrast' must be in [0, 255]");
  }
  if (d.min_bit_contrast < 0 || d.min_bit_contrast > 255) {
    throw std::invalid_argument("setting 'decode.min_bit_contrast' must be in [0, 255]");
  }
  if (!(d.max_residual_m > 0))
    throw std::invalid_argument("setting 'decode.max_residual_m' must be > 0");
  if (!(d.reference_distance_m > 0)) {
    throw std::invalid_argument("setting 'decode.reference_distance_m' must be > 0");
  }
  if (!(d.min_depth_m > 0 && d.max_depth_m > d.min_depth_m)) {
    throw std::invalid_argument(
        "settings 'scan.min_depth_m' / 'scan.max_depth_m': need 0 < min < max");
  }
  if (d.normals_step < 1) throw std::invalid_argument("setting 'scan.normals_step' must be >= 1");
}

// Decoding, depth range and camera defaults of every scan (decode.*, scan.*, camera.*).
ScanDefaults ScanDefaultsFrom(const runtime::Config& config, const std::string& projector_kind) {
  ScanDefaults d;
  d.min_contrast = static_cast<int>(config.GetInt("decode.min_contrast", d.min_contrast));
  d.min_bit_contrast =
      static_cast<int>(config.GetInt("decode.min_bit_contrast", d.min_bit_contrast));
  d.refine_rows = config.GetBool("decode.refine_rows", d.refine_rows);
  d.max_residual_m = config.GetDouble("decode.max_residual_m", d.max_residual_m);
  d.reference_distance_m = config.GetDouble("decode.reference_distance_m", d.reference_distance_m);
  d.min_depth_m = config.GetDouble("scan.min_depth_m", d.min_depth_m);
  d.max_depth_m = config.GetDouble("scan.max_depth_m", d.max_depth_m);
  d.normals_step = static_cast<int>(config.GetInt("scan.normals_step", d.normals_step));
  d.exposure_us = config.GetDouble("camera.exposure_us", d.exposure_us);
  d.frame_timeout_s = config.GetDouble("camera.frame_timeout_s", d.frame_timeout_s);
  d.dropped_frame_retries =
      static_cast<int>(config.GetInt("camera.dropped_frame_retries", d.dropped_frame_retries));
  d.trigger_mode = TriggerModeFrom(
      config.GetString("camera.trigger", projector_kind == "none" ? "free_run" : "hardware"));
  d.trigger_line = config.GetString("camera.trigger_line", d.trigger_line);
  ValidateScanDefaults(d);
  return d;
}

ServiceOptions ServiceOptionsFrom(const runtime::Config& config, const std::string& projector_kind,
                                  const std::string& calibration_dir) {
  ServiceOptions options;
  options.scan = ScanDefaultsFrom(config, projector_kind);
  options.board.inner_corners_x = static_cast<int>(config.GetInt("board.inner_corners_cols", 9));
  options.board.inner_corners_y = static_cast<int>(config.GetInt("board.inner_corners_rows", 6));
  options.board.square_size_m = config.GetDouble("board.square_size_m", 0.025);
  options.board.Validate();
  // Kiva pod top face in the shelf frame (x to the shelf's right, y toward its back, z up).
  options.shelf_top = ShelfTopFrom(config.GetDoubles(
      "shelf.top_corners_m", {0.0, 0.0, 1.9, 0.87, 0.0, 1.9, 0.87, 0.87, 1.9, 0.0, 0.87, 1.9}));
  options.sessions_dir = (fs::path(calibration_dir) / "sessions").string();
  return options;
}

// The sensor the settings name: the simulated pair, or a real or replayed camera with a
// real projector or none.
struct ScannerDevices {
  std::shared_ptr<SimulatorClient> simulator;
  std::shared_ptr<SimSensorLink> link;
  std::unique_ptr<CameraBackend> camera;
  std::unique_ptr<ProjectorBackend> projector;
};

ScannerDevices SimDevicesFrom(const runtime::Config& config, const std::string& nominal_dir,
                              const runtime::ChannelFactory& channels) {
  ScannerDevices devices;
  const std::string sim_address = config.GetString("sim.address", "127.0.0.1:50051");
  const long long sim_seed = config.GetInt("sim.seed", 1);
  devices.simulator =
      std::make_shared<SimulatorClient>(sim_address, SimRenderSettingsFrom(config), channels);
  devices.link = std::make_shared<SimSensorLink>(
      [simulator = devices.simulator] { return simulator->ToolPose(); });
  SimSensorModel model = LoadSimModel(nominal_dir);
  const auto pw = static_cast<std::uint32_t>(model.projector.width());
  const auto ph = static_cast<std::uint32_t>(model.projector.height());
  devices.camera = std::make_unique<SimCamera>(devices.link, devices.simulator, std::move(model),
                                               static_cast<std::uint64_t>(sim_seed));
  devices.projector = std::make_unique<SimProjector>(devices.link, pw, ph);
  return devices;
}

ScannerDevices HardwareDevicesFrom(const std::string& camera_kind,
                                   const std::string& projector_kind,
                                   const runtime::Config& config) {
  const std::string aravis_device = config.GetString("aravis.device", "");
  const std::string replay_dir = config.GetString("replay.dir", "");
  const std::string dlpc350_device = config.GetString("dlpc350.device", "/dev/hidraw0");
  ScannerDevices devices;
  try {
    if (camera_kind == "replay") {
      if (replay_dir.empty())
        throw std::invalid_argument("setting 'replay.dir' is required with camera=replay");
      devices.camera = std::make_unique<ReplayCamera>(replay_dir);
    } else if (camera_kind == "aravis") {
      devices.camera = std::make_unique<AravisCamera>(aravis_device);
    } else {
      throw std::invalid_argument("setting 'camera' must be sim, aravis or replay, got '" +
                                  camera_kind + "'");
    }
    if (projector_kind == "dlpc350") {
      devices.projector = std::make_unique<Dlpc350Projector>(
          std::make_unique<dlpc350::HidrawTransport>(dlpc350_device));
    } else if (projector_kind != "none") {
      throw std::invalid_argument("setting 'projector' must be sim, dlpc350 or none, got '" +
                                  projector_kind + "'");
    }
  } catch (const CameraError& e) {
    throw std::runtime_error(std::string("camera: ") + e.what());
  } catch (const ProjectorError& e) {
    throw std::runtime_error(std::string("projector: ") + e.what());
  }
  return devices;
}

}  // namespace

runtime::ServiceSet BuildScannerServices(const runtime::Config& config) {
  const std::string data_dir = apc::DefaultDataDir();
  const std::string camera_kind = config.GetString("camera", "sim");
  const std::string default_projector = camera_kind == "sim"      ? "sim"
                                        : camera_kind == "aravis" ? "dlpc350"
                                                                  : "none";
  const std::string projector_kind = config.GetString("projector", default_projector);
  // The simulator and the robot service are called with this server's own tls.* settings.
  const runtime::ChannelFactory channels = runtime::ChannelFactory::FromConfig(config);
  const std::string calibration_dir =
      config.GetString("calibration.dir", (fs::path(data_dir) / "scanner").string());
  const std::string nominal_dir = config.GetString(
      "sensor.nominal_dir", (fs::path(data_dir) / "scanner" / "sim_sensor").string());
  ServiceOptions options = ServiceOptionsFrom(config, projector_kind, calibration_dir);

  if ((camera_kind == "sim") != (projector_kind == "sim")) {
    throw std::invalid_argument(camera_kind == "sim"
                                    ? "setting 'projector': camera=sim needs projector=sim"
                                    : "setting 'projector': projector=sim needs camera=sim");
  }
  // Every setting is read whichever sensor is chosen, so that one file serves them all.
  ScannerDevices devices;
  if (camera_kind == "sim") {
    devices = SimDevicesFrom(config, nominal_dir, channels);
    for (const char* key : {"aravis.device", "replay.dir", "dlpc350.device"}) {
      config.GetString(key, "");
    }
  } else {
    config.GetString("sim.address", "");
    config.GetInt("sim.seed", 1);
    SimRenderSettingsFrom(config);
    devices = HardwareDevicesFrom(camera_kind, projector_kind, config);
  }
  const std::string robot_address = config.GetString("robot.address", "");
  const double robot_timeout_s = config.GetDouble("robot.timeout_s", 2.0);
  std::shared_ptr<RobotPoseClient> robot;
  if (!robot_address.empty())
    robot = std::make_shared<RobotPoseClient>(robot_address, robot_timeout_s, channels);

  CalibrationStore store(calibration_dir, nominal_dir);
  auto service = std::make_shared<ScannerServiceImpl>(
      std::move(options), std::move(store), std::move(devices.camera), std::move(devices.projector),
      std::move(devices.link), std::move(devices.simulator), std::move(robot));
  runtime::LogInfo("scanner configured", {{"camera", camera_kind},
                                          {"projector", projector_kind},
                                          {"calibration.dir", calibration_dir}});
  runtime::ServiceSet set;
  set.Add(service, pb::ScannerService::service_full_name());
  return set;
}

}  // namespace picking::scanner
