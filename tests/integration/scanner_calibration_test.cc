// Integration test of the picking-scanner server binary: every calibration kind through the
// Calibrate RPC on captures rendered with the scanner's synthetic capture code (a known
// camera, projector, hand-eye and shelf pose), the stored calibration files and what happens
// on bad input, and the aravis camera backend against Aravis's fake GigE Vision camera.
#include <fcntl.h>
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <memory>
#include <random>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "libs/camera/pinhole_camera.h"
#include "picking/scanner/v1/scanner.grpc.pb.h"
#include "services/scanner/core/calibration.h"
#include "services/scanner/core/calibration_io.h"
#include "services/scanner/core/patterns.h"
#include "services/scanner/core/replay_camera.h"
#include "services/scanner/core/synthetic_capture.h"
#include "tests/harness/server_process.h"

namespace picking::testing {
namespace {

namespace fs = std::filesystem;
namespace pb = ::picking::scanner::v1;
using Eigen::Isometry3d;
using Eigen::Vector3d;
using scanner::CalibrationKind;
using scanner::GrayImage;

const char kBinary[] = "picking-scanner";
constexpr double kPi = 3.14159265358979323846;

// ---------------------------------------------------------------------------------------
// The true sensor: a 640 x 480 camera and a 456 x 570 projector (half a LightCrafter 4500:
// 9 column and 10 row bits, 40 images per view), the projector 12 cm to the camera's right.

camera::PinholeCamera TrueCamera() {
  camera::Distortion d;
  d.k1 = -0.06;
  d.k2 = 0.03;
  return camera::PinholeCamera(640, 480, 640.0, 641.5, 323.0, 237.5, d);
}

camera::PinholeCamera TrueProjector() {
  camera::Distortion d;
  d.k1 = 0.02;
  return camera::PinholeCamera(456, 570, 600.0, 603.0, 229.5, 300.0, d);
}

Isometry3d TrueCameraProjector() {
  Isometry3d X = Isometry3d::Identity();
  X.translation() = Vector3d(0.12, 0.005, 0.0);
  X.linear() = (Eigen::AngleAxisd(-std::atan2(0.12, 0.7), Vector3d::UnitY()) *
                Eigen::AngleAxisd(0.01, Vector3d::UnitX()))
                   .toRotationMatrix();
  return X;
}

Isometry3d TrueToolCamera() {
  Isometry3d X = Isometry3d::Identity();
  X.translation() = Vector3d(0.02, -0.06, 0.11);
  X.linear() = Eigen::AngleAxisd(0.05, Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  return X;
}

const scanner::ChessboardSpec kBoard{9, 6, 0.025};
constexpr double kBoardMarginM = 0.02;

scanner::CameraIntrinsics Intrinsics(const camera::PinholeCamera& c, double focal_scale = 1.0) {
  scanner::CameraIntrinsics k;
  k.width = static_cast<std::uint32_t>(c.width());
  k.height = static_cast<std::uint32_t>(c.height());
  k.fx = c.fx() * focal_scale;
  k.fy = c.fy() * focal_scale;
  k.cx = c.cx();
  k.cy = c.cy();
  k.distortion = {c.distortion().k1, c.distortion().k2, c.distortion().p1, c.distortion().p2,
                  c.distortion().k3};
  return k;
}

// Writes the files of sensor.nominal_dir.
void WriteNominal(const fs::path& dir, const scanner::CameraIntrinsics& camera,
                  const scanner::CameraIntrinsics& projector, const Isometry3d& X_CameraProjector,
                  const Isometry3d& X_ToolCamera) {
  fs::create_directories(dir);
  scanner::SaveIntrinsics((dir / "camera_intrinsics.json").string(),
                          CalibrationKind::kCameraIntrinsics, {camera, {"", 0.0, "px"}});
  scanner::SaveIntrinsics((dir / "projector_intrinsics.json").string(),
                          CalibrationKind::kProjectorIntrinsics, {projector, {"", 0.0, "px"}});
  scanner::SavePose((dir / "camera_projector.json").string(),
                    CalibrationKind::kCameraProjectorExtrinsics,
                    {X_CameraProjector, {"", 0.0, "m"}});
  scanner::SavePose((dir / "hand_eye.json").string(), CalibrationKind::kHandEye,
                    {X_ToolCamera, {"", 0.0, "m"}});
}

// Renders the 40 captures of one view of `scene` (camera frame) with the true sensor;
// `samples_per_axis`^2 rays per pixel (area sampling: sharper sub-pixel corners, slower).
std::vector<GrayImage> Render(const scanner::SyntheticScene& scene, std::uint32_t seed,
                              int samples_per_axis = 1) {
  const scanner::ScannerRig rig{TrueCamera(), TrueProjector(), TrueCameraProjector()};
  scanner::SyntheticCaptureOptions options;
  options.samples_per_axis = samples_per_axis;
  options.blur_sigma_px = samples_per_axis > 1 ? 0.5 : 0.7;
  options.noise_sigma = 1.0;
  options.seed = seed;
  const scanner::SyntheticCapture capture = scanner::RenderSyntheticCapture(
      rig, scanner::PatternSequence(rig.projector.width(), rig.projector.height()), scene, options);
  std::vector<GrayImage> images;
  for (const auto& pixels : capture.images) {
    GrayImage image(static_cast<std::uint32_t>(capture.width),
                    static_cast<std::uint32_t>(capture.height));
    image.pixels = pixels;
    images.push_back(std::move(image));
  }
  return images;
}

scanner::SyntheticScene BoardScene(const Isometry3d& X_CameraBoard) {
  scanner::SyntheticScene scene;
  scanner::SyntheticChessboard board;
  board.X_CameraBoard = X_CameraBoard;
  board.inner_corners_x = kBoard.inner_corners_x;
  board.inner_corners_y = kBoard.inner_corners_y;
  board.square_size_m = kBoard.square_size_m;
  board.margin_m = kBoardMarginM;
  scene.boards.push_back(board);
  return scene;
}

// A grey wall 1 m ahead and no chessboard.
scanner::SyntheticScene WallScene() {
  scanner::SyntheticScene scene;
  scanner::SyntheticPlane wall;
  wall.normal = Vector3d(0.1, 0.0, 1.0).normalized();
  wall.offset_m = wall.normal.z();
  wall.albedo = 0.5;
  scene.planes.push_back(wall);
  return scene;
}

std::string Numbered(const std::string& prefix, int index, int digits,
                     const std::string& extension = ".png") {
  std::ostringstream s;
  s << prefix << std::setw(digits) << std::setfill('0') << index << extension;
  return s.str();
}

// One view folder: img_00.pgm ... img_39.pgm in sequence order (uncompressed, quick to
// write), and the robot pose if given.
void WriteViewFolder(const fs::path& dir, const std::vector<GrayImage>& images,
                     const Isometry3d* X_BaseTool) {
  fs::create_directories(dir);
  for (std::size_t i = 0; i < images.size(); ++i) {
    scanner::WriteGrayImage((dir / Numbered("img_", static_cast<int>(i), 2, ".pgm")).string(),
                            images[i]);
  }
  if (X_BaseTool != nullptr) {
    const Eigen::Quaterniond q(X_BaseTool->linear());
    std::ofstream out(dir / "X_base_tool.txt");
    out << std::setprecision(17) << X_BaseTool->translation().x() << ' '
        << X_BaseTool->translation().y() << ' ' << X_BaseTool->translation().z() << ' ' << q.x()
        << ' ' << q.y() << ' ' << q.z() << ' ' << q.w() << '\n';
    ASSERT_TRUE(out.good());
  }
}

// The replay camera's folder (the calibrations read their own folders; the camera is only
// opened): one PNG frame.
void WriteReplayFrame(const fs::path& dir, const GrayImage& image) {
  fs::create_directories(dir);
  scanner::WriteGrayImage((dir / "frame_0000.png").string(), image);
}

// The paper's outer corners are inside both images, 5 px from the border.
bool BoardVisible(const Isometry3d& X_CameraBoard) {
  const double s = kBoard.square_size_m;
  const Isometry3d X_ProjectorBoard = TrueCameraProjector().inverse() * X_CameraBoard;
  for (double bx : {-s - kBoardMarginM, kBoard.inner_corners_x * s + kBoardMarginM}) {
    for (double by : {-s - kBoardMarginM, kBoard.inner_corners_y * s + kBoardMarginM}) {
      const Vector3d p_Board(bx, by, 0.0);
      for (const auto& [X, device] : {std::make_pair(X_CameraBoard, TrueCamera()),
                                      std::make_pair(X_ProjectorBoard, TrueProjector())}) {
        const Vector3d p = X * p_Board;
        if (p.z() <= 0.1) return false;
        const auto uv = device.Project(p);
        if (!uv || uv->x() < 5 || uv->y() < 5 || uv->x() > device.width() - 6.0 ||
            uv->y() > device.height() - 6.0) {
          return false;
        }
      }
    }
  }
  return true;
}

// Board poses in the camera frame, tilted about varied axes, all corners in both images.
std::vector<Isometry3d> BoardPoses(int count, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> depth(0.55, 0.75), offset(-0.04, 0.04), tilt(0.2, 0.55),
      spin(-0.3, 0.3), angle(0.0, 2.0 * kPi);
  const Vector3d c_Board((kBoard.inner_corners_x - 1) * kBoard.square_size_m / 2.0,
                         (kBoard.inner_corners_y - 1) * kBoard.square_size_m / 2.0, 0.0);
  std::vector<Isometry3d> poses;
  for (int attempt = 0; attempt < 100000 && static_cast<int>(poses.size()) < count; ++attempt) {
    const double axis_angle = angle(rng);
    const Vector3d axis(std::cos(axis_angle), std::sin(axis_angle), 0.0);
    Isometry3d X = Isometry3d::Identity();
    X.linear() =
        (Eigen::AngleAxisd(tilt(rng), axis) * Eigen::AngleAxisd(spin(rng), Vector3d::UnitZ()))
            .toRotationMatrix();
    X.translation() = Vector3d(offset(rng), offset(rng), depth(rng)) - X.linear() * c_Board;
    if (BoardVisible(X)) poses.push_back(X);
  }
  EXPECT_EQ(static_cast<int>(poses.size()), count);
  return poses;
}

// A scratch folder per fixture, removed at the end.
class TempDir {
 public:
  explicit TempDir(const std::string& name)
      : path_(fs::temp_directory_path() /
              ("picking_scanner_calibration_" + name + "_" + std::to_string(::getpid()))) {
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~TempDir() { fs::remove_all(path_); }
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

std::string ReadFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

std::size_t CountFiles(const fs::path& dir) {
  if (!fs::is_directory(dir)) return 0;
  return static_cast<std::size_t>(
      std::distance(fs::directory_iterator(dir), fs::directory_iterator()));
}

Isometry3d PoseFromProto(const common::v1::Pose& p) {
  Isometry3d X = Isometry3d::Identity();
  X.translation() = Vector3d(p.position().x(), p.position().y(), p.position().z());
  X.linear() = Eigen::Quaterniond(p.orientation().w(), p.orientation().x(), p.orientation().y(),
                                  p.orientation().z())
                   .normalized()
                   .toRotationMatrix();
  return X;
}

common::v1::Pose PoseToProto(const Isometry3d& X) {
  common::v1::Pose p;
  p.mutable_position()->set_x(X.translation().x());
  p.mutable_position()->set_y(X.translation().y());
  p.mutable_position()->set_z(X.translation().z());
  const Eigen::Quaterniond q(X.linear());
  p.mutable_orientation()->set_x(q.x());
  p.mutable_orientation()->set_y(q.y());
  p.mutable_orientation()->set_z(q.z());
  p.mutable_orientation()->set_w(q.w());
  return p;
}

double AngleBetween(const Isometry3d& A, const Isometry3d& B) {
  return Eigen::AngleAxisd(A.linear().transpose() * B.linear()).angle();
}

bool Calibrated(const pb::CalibrationSet& set, pb::CalibrationKind kind) {
  for (int k : set.calibrated())
    if (k == kind) return true;
  return false;
}

// A scanner server on a calibration folder and a nominal sensor folder, with a replayed
// camera (the replay folder is only read for captures).
class ScannerServer {
 public:
  ScannerServer(const fs::path& calibration_dir, const fs::path& nominal_dir,
                const fs::path& replay_dir)
      : server_(ServerBinary(kBinary), {"--camera=replay", "--replay.dir=" + replay_dir.string(),
                                        "--calibration.dir=" + calibration_dir.string(),
                                        "--sensor.nominal_dir=" + nominal_dir.string()}),
        stub_(pb::ScannerService::NewStub(server_.Channel())) {}
  ~ScannerServer() { EXPECT_EQ(server_.Stop(), 0); }

  pb::CalibrationSet Current() {
    grpc::ClientContext ctx;
    pb::GetCalibrationResponse response;
    const grpc::Status status = stub_->GetCalibration(&ctx, pb::GetCalibrationRequest(), &response);
    EXPECT_TRUE(status.ok()) << status.error_message();
    return response.calibration();
  }

  grpc::Status Calibrate(pb::CalibrationKind kind, const std::string& image_directory,
                         const std::string& session, pb::CalibrateResponse* response) {
    grpc::ClientContext ctx;
    pb::CalibrateRequest request;
    request.set_kind(kind);
    if (!session.empty()) {
      request.set_session(session);
    } else {
      request.set_image_directory(image_directory);
    }
    request.mutable_board()->set_inner_corners_cols(kBoard.inner_corners_x);
    request.mutable_board()->set_inner_corners_rows(kBoard.inner_corners_y);
    request.mutable_board()->set_square_size_m(kBoard.square_size_m);
    return stub_->Calibrate(&ctx, request, response);
  }

  pb::ScannerService::Stub& stub() { return *stub_; }

 private:
  ServerProcess server_;
  std::unique_ptr<pb::ScannerService::Stub> stub_;
};

// The calibration folder's files, to check that a failed calibration leaves them alone.
std::map<std::string, std::string> Snapshot(const fs::path& calibration_dir) {
  std::map<std::string, std::string> files;
  if (!fs::is_directory(calibration_dir)) return files;
  for (const auto& e : fs::recursive_directory_iterator(calibration_dir)) {
    if (e.is_regular_file() && e.path().extension() == ".json") {
      files[fs::relative(e.path(), calibration_dir).string()] = ReadFile(e.path());
    }
  }
  return files;
}

// Starts the server on `calibration_dir` and expects it to refuse, naming the file.
void ExpectRefusedAtStart(const fs::path& calibration_dir, const fs::path& nominal_dir,
                          const fs::path& replay_dir, const std::string& file) {
  const ProgramResult result =
      RunProgram(ServerBinary(kBinary),
                 {"--listen=127.0.0.1:0", "--camera=replay", "--replay.dir=" + replay_dir.string(),
                  "--calibration.dir=" + calibration_dir.string(),
                  "--sensor.nominal_dir=" + nominal_dir.string()},
                 std::chrono::seconds(30));
  EXPECT_EQ(result.exit_status, 2) << "(-1: the server started anyway) " << result.output;
  EXPECT_NE(result.output.find(file), std::string::npos) << result.output;
  EXPECT_NE(result.output.find("format_version"), std::string::npos) << result.output;
  EXPECT_NE(result.output.find("unsupported version 2"), std::string::npos) << result.output;
}

// Copies `calibration_dir` and rewrites `file`'s format_version to 2.
fs::path WithWrongVersion(const fs::path& calibration_dir, const std::string& file,
                          const fs::path& where) {
  fs::remove_all(where);
  fs::create_directories(where);
  for (const auto& e : fs::directory_iterator(calibration_dir)) {
    if (e.is_regular_file()) fs::copy_file(e.path(), where / e.path().filename());
  }
  const std::string text = ReadFile(where / file);
  const std::string changed =
      std::regex_replace(text, std::regex("\"format_version\"\\s*:\\s*1"), "\"format_version\": 2");
  EXPECT_NE(changed, text);
  std::ofstream(where / file, std::ios::trunc) << changed;
  return where;
}

// ---------------------------------------------------------------------------------------
// Projector (and camera-projector stereo) calibration from a folder of Gray-code captures.

class ProjectorCalibrationThroughRpc : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir("projector");
    const fs::path root = dir_->path();
    // Nominal values 5 % off in focal length: the calibration must find the true ones.
    WriteNominal(root / "nominal", Intrinsics(TrueCamera(), 1.05),
                 Intrinsics(TrueProjector(), 0.95), TrueCameraProjector(), TrueToolCamera());
    const std::vector<Isometry3d> poses = BoardPoses(kViews, 2016);
    for (int i = 0; i < kViews; ++i) {
      const std::vector<GrayImage> images =
          Render(BoardScene(poses[i]), 100 + i, /*samples_per_axis=*/2);
      WriteViewFolder(root / "captures" / ("pose_" + std::to_string(i)), images, nullptr);
      if (i == 0) WriteReplayFrame(root / "replay", images[0]);
    }
    // A view without the board: skipped, and named when too few remain.
    WriteViewFolder(root / "captures" / "pose_wall", Render(WallScene(), 99), nullptr);
    fs::create_directories(root / "few");
    for (const char* view : {"pose_0", "pose_1", "pose_wall"}) {
      fs::copy(root / "captures" / view, root / "few" / view);
    }
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  static constexpr int kViews = 7;
  static TempDir* dir_;
};
TempDir* ProjectorCalibrationThroughRpc::dir_ = nullptr;

TEST_F(ProjectorCalibrationThroughRpc, RecoversTheProjectorStoresItAndKeepsItOnFailure) {
  const fs::path root = dir_->path();
  const fs::path calibration = root / "calibration";
  auto server = std::make_unique<ScannerServer>(calibration, root / "nominal", root / "replay");
  const pb::CalibrationSet nominal = server->Current();
  EXPECT_EQ(nominal.projector().width(), 456u);
  EXPECT_FALSE(Calibrated(nominal, pb::CALIBRATION_KIND_PROJECTOR));

  // Two usable views and one without the board: refused, the reason names the bad view.
  pb::CalibrateResponse response;
  grpc::Status status =
      server->Calibrate(pb::CALIBRATION_KIND_PROJECTOR, (root / "few").string(), "", &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << status.error_message();
  EXPECT_NE(status.error_message().find("at least 3"), std::string::npos) << status.error_message();
  EXPECT_NE(status.error_message().find("got 2 of 3"), std::string::npos) << status.error_message();
  EXPECT_NE(status.error_message().find("pose_wall"), std::string::npos) << status.error_message();
  EXPECT_NE(status.error_message().find("chessboard not found"), std::string::npos)
      << status.error_message();
  EXPECT_EQ(server->Current().SerializeAsString(), nominal.SerializeAsString());
  EXPECT_TRUE(Snapshot(calibration).empty());

  // All views: the true projector within 1 %.
  status = server->Calibrate(pb::CALIBRATION_KIND_PROJECTOR, (root / "captures").string(), "",
                             &response);
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(response.views_used(), static_cast<std::uint32_t>(kViews));
  EXPECT_EQ(response.file_format_version(), 1u);
  EXPECT_EQ(fs::path(response.calibration_file()), calibration / "camera_projector.json");
  const camera::PinholeCamera truth = TrueProjector();
  const picking::common::v1::CameraIntrinsics& p = response.calibration().projector();
  std::cout << "projector through the RPC: fx " << p.fx() << " fy " << p.fy() << " cx " << p.cx()
            << " cy " << p.cy() << " (true " << truth.fx() << ", " << truth.fy() << ", "
            << truth.cx() << ", " << truth.cy() << "), stereo RMS "
            << response.rms_reprojection_error_px() << " px\n";
  EXPECT_EQ(p.width(), 456u);
  EXPECT_EQ(p.height(), 570u);
  EXPECT_NEAR(p.fx(), truth.fx(), 0.01 * truth.fx());
  EXPECT_NEAR(p.fy(), truth.fy(), 0.01 * truth.fy());
  EXPECT_NEAR(p.cx(), truth.cx(), 0.01 * truth.cx());
  EXPECT_NEAR(p.cy(), truth.cy(), 0.01 * truth.cy());
  EXPECT_NEAR(response.calibration().camera().fx(), TrueCamera().fx(), 0.01 * TrueCamera().fx());
  const Isometry3d X_CameraProjector = PoseFromProto(response.calibration().x_camera_projector());
  EXPECT_LT((X_CameraProjector.translation() - TrueCameraProjector().translation()).norm(), 0.003);
  EXPECT_LT(AngleBetween(X_CameraProjector, TrueCameraProjector()), 0.5 * kPi / 180.0);
  EXPECT_LT(response.rms_reprojection_error_px(), 0.5);
  EXPECT_TRUE(Calibrated(response.calibration(), pb::CALIBRATION_KIND_PROJECTOR));
  EXPECT_TRUE(Calibrated(response.calibration(), pb::CALIBRATION_KIND_CAMERA));
  const pb::CalibrationSet after = server->Current();
  EXPECT_EQ(after.SerializeAsString(), response.calibration().SerializeAsString());
  // The stored file holds what the server uses, in the current format.
  const scanner::IntrinsicsFile stored = scanner::LoadIntrinsics(
      (calibration / "projector_intrinsics.json").string(), CalibrationKind::kProjectorIntrinsics);
  EXPECT_DOUBLE_EQ(stored.intrinsics.fx, p.fx());
  EXPECT_GT(stored.info.error, 0.0);

  // A failed calibration afterwards keeps the new calibration and its files.
  const auto files = Snapshot(calibration);
  status =
      server->Calibrate(pb::CALIBRATION_KIND_PROJECTOR, (root / "few").string(), "", &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_EQ(server->Current().SerializeAsString(), after.SerializeAsString());
  EXPECT_EQ(Snapshot(calibration), files);

  // A restarted server loads the stored calibration.
  server.reset();
  server = std::make_unique<ScannerServer>(calibration, root / "nominal", root / "replay");
  EXPECT_EQ(server->Current().SerializeAsString(), after.SerializeAsString());
  server.reset();

  // A calibration file of another format version is refused at start, naming it.
  ExpectRefusedAtStart(
      WithWrongVersion(calibration, "projector_intrinsics.json", root / "wrong_version"),
      root / "nominal", root / "replay", "projector_intrinsics.json");
}

// ---------------------------------------------------------------------------------------
// Hand-eye calibration from a session captured with CaptureCalibrationView and robot poses.

class HandEyeCalibrationThroughRpc : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir("hand_eye");
    const fs::path root = dir_->path();
    // The camera intrinsics are known (true); the nominal hand-eye is 2 cm and 3 degrees off.
    Isometry3d nominal_hand_eye = TrueToolCamera();
    nominal_hand_eye.translation() += Vector3d(0.02, 0.0, -0.01);
    nominal_hand_eye.linear() =
        nominal_hand_eye.linear() * Eigen::AngleAxisd(0.05, Vector3d::UnitX()).toRotationMatrix();
    WriteNominal(root / "nominal", Intrinsics(TrueCamera()), Intrinsics(TrueProjector()),
                 TrueCameraProjector(), nominal_hand_eye);
    // The board lies still in the base frame; the robot moves the camera around it. The
    // replayed recording holds one 40-image sequence per view, the last one without the board.
    Isometry3d X_BaseBoard = Isometry3d::Identity();
    X_BaseBoard.translation() = Vector3d(0.9, -0.1, 0.05);
    X_BaseBoard.linear() = Eigen::AngleAxisd(kPi, Vector3d::UnitX()).toRotationMatrix();
    const std::vector<Isometry3d> X_CameraBoard = BoardPoses(kViews, 7);
    int frame = 0;
    const auto record = [&](const std::vector<GrayImage>& images) {
      for (const GrayImage& image : images) {
        scanner::WriteGrayImage((root / "frames" / Numbered("frame_", frame++, 4, ".pgm")).string(),
                                image);
      }
    };
    fs::create_directories(root / "frames");
    for (int i = 0; i < kViews; ++i) {
      const Isometry3d X_BaseCamera = X_BaseBoard * X_CameraBoard[i].inverse();
      X_BaseTool_.push_back(X_BaseCamera * TrueToolCamera().inverse());
      record(Render(BoardScene(X_CameraBoard[i]), 200 + i));
    }
    X_BaseTool_.push_back(X_BaseTool_[0]);
    record(Render(WallScene(), 299));
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
    X_BaseTool_.clear();
  }

  static pb::CaptureCalibrationViewResponse Capture(ScannerServer& server,
                                                    const std::string& session,
                                                    const Isometry3d& X_BaseTool) {
    grpc::ClientContext ctx;
    pb::CaptureCalibrationViewRequest request;
    request.set_session(session);
    *request.mutable_x_base_tool() = PoseToProto(X_BaseTool);
    pb::CaptureCalibrationViewResponse response;
    const grpc::Status status = server.stub().CaptureCalibrationView(&ctx, request, &response);
    EXPECT_TRUE(status.ok()) << status.error_message();
    return response;
  }

  static constexpr int kViews = 5;
  static TempDir* dir_;
  static std::vector<Isometry3d> X_BaseTool_;
};
TempDir* HandEyeCalibrationThroughRpc::dir_ = nullptr;
std::vector<Isometry3d> HandEyeCalibrationThroughRpc::X_BaseTool_;

TEST_F(HandEyeCalibrationThroughRpc, RecoversToolCameraFromASessionAndKeepsItOnFailure) {
  const fs::path root = dir_->path();
  const fs::path calibration = root / "calibration";
  auto server = std::make_unique<ScannerServer>(calibration, root / "nominal", root / "frames");
  const pb::CalibrationSet nominal = server->Current();

  // The recording in order: kViews board views, then the view without the board.
  for (int i = 0; i <= kViews; ++i) {
    const pb::CaptureCalibrationViewResponse r = Capture(*server, "wrist", X_BaseTool_[i]);
    EXPECT_EQ(r.view_index(), static_cast<std::uint32_t>(i));
    EXPECT_EQ(r.chessboard_found(), i < kViews) << "view " << i;
  }
  EXPECT_TRUE(fs::exists(calibration / "sessions" / "wrist" / "view_000" / "X_base_tool.txt"));
  // The recording starts again: two board views in another session are too few.
  for (int i = 0; i < 2; ++i) Capture(*server, "two_views", X_BaseTool_[i]);
  // Three views where the wrist only moved, never turned: X_ToolCamera is not observable.
  for (int i = 2; i < 5; ++i) {
    Isometry3d X_BaseTool = X_BaseTool_[0];
    X_BaseTool.translation() += Vector3d(0.03 * i, -0.02 * i, 0.01 * i);
    Capture(*server, "no_turns", X_BaseTool);
  }

  pb::CalibrateResponse response;
  grpc::Status status =
      server->Calibrate(pb::CALIBRATION_KIND_HAND_EYE, "", "two_views", &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << status.error_message();
  EXPECT_NE(status.error_message().find("at least 3"), std::string::npos) << status.error_message();
  status = server->Calibrate(pb::CALIBRATION_KIND_HAND_EYE, "", "no_turns", &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << status.error_message();
  EXPECT_NE(status.error_message().find("degenerate"), std::string::npos) << status.error_message();
  EXPECT_EQ(server->Current().SerializeAsString(), nominal.SerializeAsString());
  EXPECT_TRUE(Snapshot(calibration).empty());

  status = server->Calibrate(pb::CALIBRATION_KIND_HAND_EYE, "", "wrist", &response);
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(response.views_used(), static_cast<std::uint32_t>(kViews));
  EXPECT_EQ(response.per_view_error_px_size(), kViews);
  EXPECT_EQ(fs::path(response.calibration_file()), calibration / "hand_eye.json");
  const Isometry3d X_ToolCamera = PoseFromProto(response.calibration().x_tool_camera());
  const double translation_error_mm =
      (X_ToolCamera.translation() - TrueToolCamera().translation()).norm() * 1e3;
  const double rotation_error_deg = AngleBetween(X_ToolCamera, TrueToolCamera()) * 180.0 / kPi;
  std::cout << "hand-eye through the RPC: X_ToolCamera off by " << translation_error_mm
            << " mm and " << rotation_error_deg << " deg; board spread "
            << response.residual_translation_m() * 1e3 << " mm, corner RMS "
            << response.rms_reprojection_error_px() << " px\n";
  EXPECT_LT(translation_error_mm, 2.0);
  EXPECT_LT(rotation_error_deg, 0.5);
  EXPECT_LT(response.residual_translation_m(), 0.002);
  EXPECT_TRUE(Calibrated(response.calibration(), pb::CALIBRATION_KIND_HAND_EYE));
  EXPECT_FALSE(Calibrated(response.calibration(), pb::CALIBRATION_KIND_CAMERA));
  const pb::CalibrationSet after = server->Current();
  EXPECT_EQ(after.SerializeAsString(), response.calibration().SerializeAsString());

  const auto files = Snapshot(calibration);
  status = server->Calibrate(pb::CALIBRATION_KIND_HAND_EYE, "", "two_views", &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  status = server->Calibrate(pb::CALIBRATION_KIND_HAND_EYE, "", "never_captured", &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND) << status.error_message();
  EXPECT_EQ(server->Current().SerializeAsString(), after.SerializeAsString());
  EXPECT_EQ(Snapshot(calibration), files);

  server.reset();
  server = std::make_unique<ScannerServer>(calibration, root / "nominal", root / "frames");
  EXPECT_EQ(server->Current().SerializeAsString(), after.SerializeAsString());
  server.reset();

  ExpectRefusedAtStart(WithWrongVersion(calibration, "hand_eye.json", root / "wrong_version"),
                       root / "nominal", root / "frames", "hand_eye.json");
}

// ---------------------------------------------------------------------------------------
// Shelf pose from scans of the shelf's top front corners (a box the size of the Kiva pod).

Isometry3d TrueBaseShelf() {
  Isometry3d X = Isometry3d::Identity();
  X.linear() = Eigen::AngleAxisd(-kPi / 2 + 0.035, Vector3d::UnitZ()).toRotationMatrix();
  X.translation() = Vector3d(1.05, 0.44, -0.55);
  return X;
}

// The camera at p_BaseEye looking at p_BaseTarget, image x to the right, y down.
Isometry3d LookAt(const Vector3d& p_BaseEye, const Vector3d& p_BaseTarget) {
  const Vector3d z = (p_BaseTarget - p_BaseEye).normalized();
  const Vector3d x = z.cross(Vector3d::UnitZ()).normalized();
  Isometry3d X = Isometry3d::Identity();
  X.linear().col(0) = x;
  X.linear().col(1) = z.cross(x);
  X.linear().col(2) = z;
  X.translation() = p_BaseEye;
  return X;
}

std::vector<GrayImage> RenderShelf(const Isometry3d& X_BaseCamera, std::uint32_t seed) {
  scanner::SyntheticBox shelf;
  Isometry3d X_ShelfCentre = Isometry3d::Identity();
  X_ShelfCentre.translation() = Vector3d(0.435, 0.435, 0.95);
  shelf.X_CameraBox = X_BaseCamera.inverse() * TrueBaseShelf() * X_ShelfCentre;
  shelf.half_size_m = Vector3d(0.435, 0.435, 0.95);
  shelf.albedo = 0.7;
  scanner::SyntheticScene scene;
  scene.boxes.push_back(shelf);
  return Render(scene, seed);
}

class ShelfCalibrationThroughRpc : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir("shelf");
    const fs::path root = dir_->path();
    WriteNominal(root / "nominal", Intrinsics(TrueCamera()), Intrinsics(TrueProjector()),
                 TrueCameraProjector(), TrueToolCamera());
    // One view of each top front corner, aimed 10 cm inside it along the edge.
    const Isometry3d X_BaseShelf = TrueBaseShelf();
    const Vector3d p_BaseLeft = X_BaseShelf * Vector3d(0.10, 0.0, 1.9);
    const Vector3d p_BaseRight = X_BaseShelf * Vector3d(0.77, 0.0, 1.9);
    int seed = 300;
    for (const auto& [name, target] :
         {std::make_pair("left", p_BaseLeft), std::make_pair("right", p_BaseRight)}) {
      const Isometry3d X_BaseCamera = LookAt(target + Vector3d(-0.7, 0.0, 0.4), target);
      const Isometry3d X_BaseTool = X_BaseCamera * TrueToolCamera().inverse();
      const std::vector<GrayImage> images = RenderShelf(X_BaseCamera, seed++);
      WriteViewFolder(root / "corners" / name, images, &X_BaseTool);
      WriteReplayFrame(root / "replay", images[0]);
    }
    // Bad scans: the first has no robot pose, the second looks over the shelf at nothing.
    const Isometry3d X_BaseCamera = LookAt(p_BaseLeft + Vector3d(-0.7, 0.0, 0.4), p_BaseLeft);
    WriteViewFolder(root / "bad" / "no_pose", RenderShelf(X_BaseCamera, seed++), nullptr);
    const Isometry3d X_BaseSky =
        LookAt(p_BaseLeft + Vector3d(-0.7, 0.0, 0.4), p_BaseLeft + Vector3d(0.0, 0.0, 1.5));
    const Isometry3d X_BaseToolSky = X_BaseSky * TrueToolCamera().inverse();
    WriteViewFolder(root / "bad" / "over_the_shelf", RenderShelf(X_BaseSky, seed++),
                    &X_BaseToolSky);
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  static TempDir* dir_;
};
TempDir* ShelfCalibrationThroughRpc::dir_ = nullptr;

TEST_F(ShelfCalibrationThroughRpc, RecoversTheShelfPoseAndKeepsItOnFailure) {
  const fs::path root = dir_->path();
  const fs::path calibration = root / "calibration";
  auto server = std::make_unique<ScannerServer>(calibration, root / "nominal", root / "replay");
  const pb::CalibrationSet nominal = server->Current();

  pb::CalibrateResponse response;
  grpc::Status status =
      server->Calibrate(pb::CALIBRATION_KIND_SHELF_POSE, (root / "bad").string(), "", &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << status.error_message();
  EXPECT_NE(status.error_message().find("no robot pose"), std::string::npos)
      << status.error_message();
  EXPECT_NE(status.error_message().find("over_the_shelf"), std::string::npos)
      << status.error_message();
  EXPECT_EQ(server->Current().SerializeAsString(), nominal.SerializeAsString());
  EXPECT_TRUE(Snapshot(calibration).empty());

  status = server->Calibrate(pb::CALIBRATION_KIND_SHELF_POSE, (root / "corners").string(), "",
                             &response);
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(response.views_used(), 2u);
  EXPECT_EQ(fs::path(response.calibration_file()), calibration / "shelf_pose.json");
  const Isometry3d X_BaseShelf = PoseFromProto(response.calibration().x_base_shelf());
  const double translation_error_mm =
      (X_BaseShelf.translation() - TrueBaseShelf().translation()).norm() * 1e3;
  const double rotation_error_deg = AngleBetween(X_BaseShelf, TrueBaseShelf()) * 180.0 / kPi;
  std::cout << "shelf pose through the RPC: X_BaseShelf off by " << translation_error_mm
            << " mm and " << rotation_error_deg << " deg (fit RMS "
            << response.residual_translation_m() * 1e3 << " mm)\n";
  EXPECT_LT(translation_error_mm, 10.0);
  EXPECT_LT(rotation_error_deg, 1.0);
  EXPECT_TRUE(Calibrated(response.calibration(), pb::CALIBRATION_KIND_SHELF_POSE));
  const pb::CalibrationSet after = server->Current();
  EXPECT_EQ(after.SerializeAsString(), response.calibration().SerializeAsString());

  const auto files = Snapshot(calibration);
  status =
      server->Calibrate(pb::CALIBRATION_KIND_SHELF_POSE, (root / "bad").string(), "", &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_EQ(server->Current().SerializeAsString(), after.SerializeAsString());
  EXPECT_EQ(Snapshot(calibration), files);

  server.reset();
  server = std::make_unique<ScannerServer>(calibration, root / "nominal", root / "replay");
  EXPECT_EQ(server->Current().SerializeAsString(), after.SerializeAsString());
  server.reset();

  ExpectRefusedAtStart(WithWrongVersion(calibration, "shelf_pose.json", root / "wrong_version"),
                       root / "nominal", root / "replay", "shelf_pose.json");
}

// ---------------------------------------------------------------------------------------
// A recording that lost a frame: the replayed capture is a dropped frame, the next is fine.

TEST(ScannerDroppedFrameTest, ADroppedFrameIsDataLossAndTheNextCaptureWorks) {
  TempDir dir("dropped_frame");
  WriteNominal(dir.path() / "nominal", Intrinsics(TrueCamera()), Intrinsics(TrueProjector()),
               TrueCameraProjector(), TrueToolCamera());
  // Two sequences of 40 frames, numbered 0 to 80 without frame 17.
  fs::create_directories(dir.path() / "frames");
  const GrayImage grey(640, 480, 90);
  for (int id = 0; id <= 80; ++id) {
    if (id == 17) continue;
    scanner::WriteGrayImage((dir.path() / "frames" / Numbered("frame_", id, 4, ".pgm")).string(),
                            grey);
  }
  ScannerServer server(dir.path() / "calibration", dir.path() / "nominal", dir.path() / "frames");
  for (int round = 0; round < 2; ++round) {
    grpc::ClientContext ctx;
    auto reader = server.stub().CaptureImages(&ctx, pb::CaptureImagesRequest());
    pb::CaptureImagesResponse response;
    int images = 0;
    while (reader->Read(&response)) images += response.chunk().has_header() ? 1 : 0;
    const grpc::Status status = reader->Finish();
    if (round == 0) {
      EXPECT_EQ(status.error_code(), grpc::StatusCode::DATA_LOSS) << status.error_message();
      EXPECT_NE(status.error_message().find("dropped frame"), std::string::npos)
          << status.error_message();
      EXPECT_NE(status.error_message().find("expected 17"), std::string::npos)
          << status.error_message();
      EXPECT_EQ(images, 0);
    } else {
      EXPECT_TRUE(status.ok()) << status.error_message();
      EXPECT_EQ(images, 40);
    }
  }
}

// ---------------------------------------------------------------------------------------
// The aravis backend against Aravis's fake GigE Vision camera (arv-fake-gv-camera-0.8 on the
// loopback interface; 512 x 512 Mono8).

// Runs the fake camera until destroyed; ready once it listens. It drops each stream packet
// with probability `lost_per_thousand` / 1000 and never resends one.
class FakeGigECamera {
 public:
  explicit FakeGigECamera(int lost_per_thousand = 0) {
    const std::string lost = std::to_string(lost_per_thousand);
    int fds[2];
    if (::pipe(fds) != 0) throw std::runtime_error("pipe failed");
    pid_ = ::fork();
    if (pid_ == 0) {
      ::dup2(fds[1], STDERR_FILENO);
      ::dup2(fds[1], STDOUT_FILENO);
      ::close(fds[0]);
      ::close(fds[1]);
      ::execlp("arv-fake-gv-camera-0.8", "arv-fake-gv-camera-0.8", "-i", "127.0.0.1", "-r",
               lost.c_str(), "-d", "device:3", static_cast<char*>(nullptr));
      ::_exit(127);
    }
    ::close(fds[1]);
    fd_ = fds[0];
    // Wait for "Listening" (its log line once the sockets are bound), at most 20 s.
    std::string log;
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(20);
    while (log.find("Listening") == std::string::npos) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
                            deadline - std::chrono::steady_clock::now())
                            .count();
      pollfd p{fd_, POLLIN, 0};
      if (left <= 0 || ::poll(&p, 1, static_cast<int>(left)) <= 0) break;
      char buffer[4096];
      const ssize_t n = ::read(fd_, buffer, sizeof(buffer));
      if (n <= 0) break;
      log.append(buffer, static_cast<std::size_t>(n));
    }
    if (log.find("Listening") == std::string::npos) {
      Stop();
      throw std::runtime_error(
          "arv-fake-gv-camera-0.8 (aravis-tools) did not start listening on 127.0.0.1: " + log);
    }
    // Keep draining its log so that it never blocks on a full pipe.
    drain_ = std::thread([fd = fd_] {
      char buffer[4096];
      while (::read(fd, buffer, sizeof(buffer)) > 0) {
      }
    });
  }
  ~FakeGigECamera() { Stop(); }

 private:
  void Stop() {
    if (pid_ > 0) {
      ::kill(pid_, SIGTERM);
      int status = 0;
      ::waitpid(pid_, &status, 0);
      pid_ = -1;
    }
    if (drain_.joinable()) drain_.join();
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  }
  pid_t pid_ = -1;
  int fd_ = -1;
  std::thread drain_;
};

class ScannerAravisTest : public ::testing::Test {
 protected:
  explicit ScannerAravisTest(int lost_per_thousand = 0)
      : dir_("aravis"), fake_camera_(lost_per_thousand) {
    scanner::CameraIntrinsics camera = Intrinsics(TrueCamera());
    camera.width = 512;
    camera.height = 512;
    camera.cx = 255.5;
    camera.cy = 255.5;
    WriteNominal(dir_.path() / "nominal", camera, Intrinsics(TrueProjector()),
                 TrueCameraProjector(), TrueToolCamera());
  }

  std::vector<std::string> Args(const std::string& trigger) const {
    return {"--camera=aravis",
            "--aravis.device=127.0.0.1",
            "--projector=none",
            "--camera.trigger=" + trigger,
            "--camera.exposure_us=2000",
            "--camera.frame_timeout_s=0.5",
            "--calibration.dir=" + (dir_.path() / "calibration").string(),
            "--sensor.nominal_dir=" + (dir_.path() / "nominal").string()};
  }

  // CaptureImages: the status and the number of images received.
  static grpc::Status CaptureImages(pb::ScannerService::Stub& stub, int* images) {
    grpc::ClientContext ctx;
    auto reader = stub.CaptureImages(&ctx, pb::CaptureImagesRequest());
    pb::CaptureImagesResponse response;
    *images = 0;
    while (reader->Read(&response)) {
      const common::v1::ImageChunk& chunk = response.chunk();
      if (chunk.has_header()) {
        ++*images;
        EXPECT_EQ(chunk.header().width(), 512u);
      }
    }
    return reader->Finish();
  }

  TempDir dir_;
  FakeGigECamera fake_camera_;
};

TEST_F(ScannerAravisTest, SoftwareTriggeredSequencesFromTheFakeGigECamera) {
  ServerProcess server(ServerBinary(kBinary), Args("software"));
  auto stub = pb::ScannerService::NewStub(server.Channel());
  int images = 0;
  const grpc::Status captured = CaptureImages(*stub, &images);
  ASSERT_TRUE(captured.ok()) << captured.error_message();
  EXPECT_EQ(images, 40);
  // A second sequence, stored as a calibration view.
  grpc::ClientContext ctx;
  pb::CaptureCalibrationViewRequest request;
  request.set_session("gige");
  pb::CaptureCalibrationViewResponse response;
  const grpc::Status status = stub->CaptureCalibrationView(&ctx, request, &response);
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_FALSE(response.chessboard_found());  // The fake camera shows a ramp.
  EXPECT_EQ(CountFiles(dir_.path() / "calibration" / "sessions" / "gige" / "view_000"), 40u);
  EXPECT_EQ(server.Stop(), 0);
}

// The projector's trigger pulses never reach the camera: each capture ends with
// DEADLINE_EXCEEDED naming the camera and its trigger line, and the server keeps serving.
TEST_F(ScannerAravisTest, ACameraThatTimesOutIsADeadlineAndTheScannerStaysUsable) {
  ServerProcess server(ServerBinary(kBinary), Args("hardware"));
  auto stub = pb::ScannerService::NewStub(server.Channel());
  for (int round = 0; round < 2; ++round) {
    int images = 0;
    const grpc::Status status = CaptureImages(*stub, &images);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED)
        << "round " << round << ": " << status.error_message();
    EXPECT_NE(status.error_message().find("127.0.0.1"), std::string::npos)
        << status.error_message();
    EXPECT_NE(status.error_message().find("did not arrive"), std::string::npos)
        << status.error_message();
    EXPECT_NE(status.error_message().find("Line0"), std::string::npos) << status.error_message();
    EXPECT_EQ(images, 0);
  }
  grpc::ClientContext ctx;
  pb::GetCalibrationResponse calibration;
  EXPECT_TRUE(stub->GetCalibration(&ctx, pb::GetCalibrationRequest(), &calibration).ok());
  EXPECT_EQ(calibration.calibration().camera().width(), 512u);
  EXPECT_EQ(server.Stop(), 0);
  // The camera was left stopped and released: the next scanner captures from it at once.
  ServerProcess next(ServerBinary(kBinary), Args("software"));
  auto next_stub = pb::ScannerService::NewStub(next.Channel());
  int images = 0;
  const grpc::Status status = CaptureImages(*next_stub, &images);
  EXPECT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(images, 40);
  EXPECT_EQ(next.Stop(), 0);
}

// A camera on a lossy link: the fake camera drops 0.1 % of its packets, so about one frame
// in five arrives incomplete (it never resends). Software-triggered frames are taken again
// until whole, and every capture still delivers its 40 images. With up to 30 takes of a
// frame, a capture fails with probability below 1e-18.
class ScannerLossyAravisTest : public ScannerAravisTest {
 protected:
  ScannerLossyAravisTest() : ScannerAravisTest(1) {}
};

TEST_F(ScannerLossyAravisTest, IncompleteSoftwareTriggeredFramesAreTakenAgain) {
  std::vector<std::string> args = Args("software");
  args.push_back("--camera.dropped_frame_retries=30");
  ServerProcess server(ServerBinary(kBinary), args);
  auto stub = pb::ScannerService::NewStub(server.Channel());
  for (int round = 0; round < 2; ++round) {
    int images = 0;
    const grpc::Status status = CaptureImages(*stub, &images);
    ASSERT_TRUE(status.ok()) << "round " << round << ": " << status.error_message();
    EXPECT_EQ(images, 40);
  }
  EXPECT_EQ(server.Stop(), 0);
}

// Half the packets lost: no frame is ever whole. After its retries the capture ends with
// DATA_LOSS naming the camera, the frame and the retries, and the scanner keeps serving.
class ScannerBrokenLinkAravisTest : public ScannerAravisTest {
 protected:
  ScannerBrokenLinkAravisTest() : ScannerAravisTest(500) {}
};

TEST_F(ScannerBrokenLinkAravisTest, AFrameThatNeverArrivesWholeIsDataLoss) {
  std::vector<std::string> args = Args("software");
  args.push_back("--camera.dropped_frame_retries=1");
  ServerProcess server(ServerBinary(kBinary), args);
  auto stub = pb::ScannerService::NewStub(server.Channel());
  int images = 0;
  const grpc::Status status = CaptureImages(*stub, &images);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::DATA_LOSS) << status.error_message();
  for (const char* part : {"127.0.0.1", "frame 0 of 40 arrived incomplete", "after 1 retries"}) {
    EXPECT_NE(status.error_message().find(part), std::string::npos) << status.error_message();
  }
  EXPECT_EQ(images, 0);
  grpc::ClientContext ctx;
  pb::GetCalibrationResponse calibration;
  EXPECT_TRUE(stub->GetCalibration(&ctx, pb::GetCalibrationRequest(), &calibration).ok());
  EXPECT_EQ(server.Stop(), 0);
}

// A negative retry count is refused at start, naming the setting.
TEST(ScannerAravisSettingsTest, NegativeRetriesAreRefused) {
  const ProgramResult result = RunProgram(
      ServerBinary(kBinary), {"--listen=127.0.0.1:0", "--camera.dropped_frame_retries=-1"},
      std::chrono::seconds(30));
  EXPECT_EQ(result.exit_status, 2) << "(-1: the server started anyway) " << result.output;
  EXPECT_NE(result.output.find("camera.dropped_frame_retries"), std::string::npos) << result.output;
}

}  // namespace
}  // namespace picking::testing
