// Integration test of the picking-scanner server binary through its generated client.
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "picking/scanner/v1/scanner.grpc.pb.h"
#include "picking/simulator/v1/simulator.grpc.pb.h"
#include "tests/harness/server_process.h"
#include "tests/harness/service_checks.h"

namespace picking::testing {
namespace {

namespace fs = std::filesystem;
namespace pb = ::picking::scanner::v1;

const char kBinary[] = "picking-scanner";

TEST(ScannerServerTest, ServesHealthAndReflectionAndStopsCleanly) {
  ExpectStandardServerBehaviour(ServerBinary(kBinary), "picking.scanner.v1.ScannerService",
                                "picking/scanner/v1/scanner.proto");
}

TEST(ScannerServerTest, RejectsBadFlags) { ExpectRejectsBadFlags(ServerBinary(kBinary)); }

// ---------------------------------------------------------------------------------------
// A minimal PNG writer (8-bit grey, stored deflate blocks), so that the test renders its
// replay images without the scanner's own libraries.

std::uint32_t Crc32(const std::uint8_t* data, std::size_t n, std::uint32_t crc = 0) {
  static const std::array<std::uint32_t, 256> table = [] {
    std::array<std::uint32_t, 256> t{};
    for (std::uint32_t i = 0; i < 256; ++i) {
      std::uint32_t c = i;
      for (int k = 0; k < 8; ++k) c = (c & 1) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
      t[i] = c;
    }
    return t;
  }();
  crc = ~crc;
  for (std::size_t i = 0; i < n; ++i) crc = table[(crc ^ data[i]) & 0xFF] ^ (crc >> 8);
  return ~crc;
}

void PutU32(std::vector<std::uint8_t>* out, std::uint32_t v) {
  for (int s = 24; s >= 0; s -= 8) out->push_back(static_cast<std::uint8_t>(v >> s));
}

void PutChunk(std::vector<std::uint8_t>* out, const char* type,
              const std::vector<std::uint8_t>& data) {
  PutU32(out, static_cast<std::uint32_t>(data.size()));
  std::vector<std::uint8_t> body(type, type + 4);
  body.insert(body.end(), data.begin(), data.end());
  out->insert(out->end(), body.begin(), body.end());
  PutU32(out, Crc32(body.data(), body.size()));
}

void WritePng(const std::string& path, int width, int height, const std::vector<std::uint8_t>& px) {
  std::vector<std::uint8_t> raw;  // Filter byte 0 before each row.
  raw.reserve(static_cast<std::size_t>(width + 1) * height);
  for (int y = 0; y < height; ++y) {
    raw.push_back(0);
    raw.insert(raw.end(), px.begin() + static_cast<std::ptrdiff_t>(y) * width,
               px.begin() + static_cast<std::ptrdiff_t>(y + 1) * width);
  }
  std::vector<std::uint8_t> z{0x78, 0x01};
  for (std::size_t pos = 0; pos < raw.size(); pos += 65535) {
    const std::size_t n = std::min<std::size_t>(65535, raw.size() - pos);
    z.push_back(pos + n == raw.size() ? 1 : 0);
    z.push_back(static_cast<std::uint8_t>(n & 0xFF));
    z.push_back(static_cast<std::uint8_t>(n >> 8));
    z.push_back(static_cast<std::uint8_t>(~n & 0xFF));
    z.push_back(static_cast<std::uint8_t>((~n >> 8) & 0xFF));
    z.insert(z.end(), raw.begin() + static_cast<std::ptrdiff_t>(pos),
             raw.begin() + static_cast<std::ptrdiff_t>(pos + n));
  }
  std::uint32_t a = 1, b = 0;
  for (std::uint8_t c : raw) {
    a = (a + c) % 65521;
    b = (b + a) % 65521;
  }
  PutU32(&z, (b << 16) | a);
  std::vector<std::uint8_t> png{0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
  std::vector<std::uint8_t> ihdr;
  PutU32(&ihdr, static_cast<std::uint32_t>(width));
  PutU32(&ihdr, static_cast<std::uint32_t>(height));
  ihdr.insert(ihdr.end(), {8, 0, 0, 0, 0});  // 8-bit greyscale, no interlace.
  PutChunk(&png, "IHDR", ihdr);
  PutChunk(&png, "IDAT", z);
  PutChunk(&png, "IEND", {});
  std::ofstream out(path, std::ios::binary);
  out.write(reinterpret_cast<const char*>(png.data()), static_cast<std::streamsize>(png.size()));
  ASSERT_TRUE(out.good()) << path;
}

// ---------------------------------------------------------------------------------------
// The scanner geometry used for the replay: undistorted pinhole camera and projector.

struct Pinhole {
  int width, height;
  double fx, fy, cx, cy;
};
constexpr Pinhole kCamera{1280, 1024, 1800.0, 1800.0, 639.5, 511.5};
constexpr Pinhole kProjector{912, 1140, 1100.0, 1100.0, 455.5, 569.5};
constexpr int kColumnBits = 10;
constexpr int kRowBits = 11;

struct Vec3 {
  double x, y, z;
  double Dot(const Vec3& o) const { return x * o.x + y * o.y + z * o.z; }
  bool Finite() const { return std::isfinite(x) && std::isfinite(y) && std::isfinite(z); }
};

Vec3 Normalized(const Vec3& v) {
  const double n = std::sqrt(v.Dot(v));
  return {v.x / n, v.y / n, v.z / n};
}

// X_CameraProjector: the projector 0.15 m to the camera's right, turned about the camera's y
// axis by -kToeIn so that the optical axes cross at 1 m.
const double kBaselineM = 0.15;
const double kToeInRad = std::atan2(0.15, 1.0);

// p_Projector = R^T (p_Camera - t), R = rotation about y by -kToeIn.
Vec3 ProjectorFromCamera(const Vec3& p) {
  const double c = std::cos(-kToeInRad), s = std::sin(-kToeInRad);
  const Vec3 d{p.x - kBaselineM, p.y, p.z};
  return {c * d.x - s * d.z, d.y, s * d.x + c * d.z};
}

// The plane { p_Camera : n . p = d } at about 1 m, tilted.
const Vec3 kPlaneNormal = Normalized({0.15, -0.1, 1.0});
const double kPlaneOffset = kPlaneNormal.z;  // Through (0, 0, 1 m).

// Renders the 44 captures of the Gray-code sequence (white, black, column bits and inverse,
// row bits and inverse) of the plane, with ambient light and seeded noise.
void RenderPlaneSequence(const fs::path& dir) {
  fs::create_directories(dir);
  const std::size_t n = static_cast<std::size_t>(kCamera.width) * kCamera.height;
  std::vector<int> column(n, -1), row(n, -1);
  for (int v = 0; v < kCamera.height; ++v) {
    for (int u = 0; u < kCamera.width; ++u) {
      const Vec3 ray{(u - kCamera.cx) / kCamera.fx, (v - kCamera.cy) / kCamera.fy, 1.0};
      const double t = kPlaneOffset / kPlaneNormal.Dot(ray);
      const Vec3 p = ProjectorFromCamera({ray.x * t, ray.y * t, t});
      const double c = kProjector.fx * p.x / p.z + kProjector.cx;
      const double r = kProjector.fy * p.y / p.z + kProjector.cy;
      const int ci = static_cast<int>(std::lround(c)), ri = static_cast<int>(std::lround(r));
      if (ci < 0 || ri < 0 || ci >= kProjector.width || ri >= kProjector.height) continue;
      column[static_cast<std::size_t>(v) * kCamera.width + u] = ci;
      row[static_cast<std::size_t>(v) * kCamera.width + u] = ri;
    }
  }
  std::mt19937 rng(11);
  std::normal_distribution<double> noise(0.0, 1.5);
  auto write = [&](int index, auto lit) {
    std::vector<std::uint8_t> px(n);
    for (std::size_t i = 0; i < n; ++i) {
      const double level = 25.0 + (column[i] >= 0 && lit(i) ? 170.0 : 0.0) + noise(rng);
      px[i] = static_cast<std::uint8_t>(std::clamp(std::lround(level), 0L, 255L));
    }
    std::ostringstream name;
    name << "frame_" << (index < 10 ? "0" : "") << index << ".png";
    WritePng((dir / name.str()).string(), kCamera.width, kCamera.height, px);
  };
  auto gray = [](int x) { return x ^ (x >> 1); };
  int index = 0;
  write(index++, [](std::size_t) { return true; });
  write(index++, [](std::size_t) { return false; });
  for (int axis = 0; axis < 2; ++axis) {
    const int bits = axis == 0 ? kColumnBits : kRowBits;
    const std::vector<int>& code = axis == 0 ? column : row;
    for (int b = 0; b < bits; ++b) {
      for (int inverse = 0; inverse < 2; ++inverse) {
        write(index++, [&](std::size_t i) {
          const bool on = (gray(code[i]) >> (bits - 1 - b)) & 1;
          return inverse ? !on : on;
        });
      }
    }
  }
}

std::string IntrinsicsJson(const char* kind, const Pinhole& p) {
  std::ostringstream s;
  s.precision(17);
  s << R"({"format_version": 1, "kind": ")" << kind
    << R"(", "timestamp_utc": "2016-07-01T00:00:00Z", "error": 0.0, "error_unit": "px", )"
    << R"("values": {"width": )" << p.width << ", \"height\": " << p.height << ", \"fx\": " << p.fx
    << ", \"fy\": " << p.fy << ", \"cx\": " << p.cx << ", \"cy\": " << p.cy
    << R"(, "distortion": [0, 0, 0, 0, 0]}})";
  return s.str();
}

// The camera-projector pose file of the rig above.
std::string CameraProjectorJson() {
  const char* kind = "camera_projector_extrinsics";
  const char* parent = "camera";
  const char* child = "projector";
  const double half = -kToeInRad / 2;
  std::ostringstream s;
  s.precision(17);
  s << R"({"format_version": 1, "kind": ")" << kind
    << R"(", "timestamp_utc": "2016-07-01T00:00:00Z", "error": 0.0, "error_unit": "m", )"
    << R"("values": {"parent_frame": ")" << parent << R"(", "child_frame": ")" << child
    << R"(", "translation_m": [)" << kBaselineM << R"(, 0, 0], "rotation_xyzw": [0, )"
    << std::sin(half) << ", 0, " << std::cos(half) << "]}}";
  return s.str();
}

void WriteText(const fs::path& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
  ASSERT_TRUE(out.good()) << path;
}

// A scratch folder per test, removed at the end.
class TempDir {
 public:
  explicit TempDir(const std::string& name)
      : path_(fs::temp_directory_path() /
              ("picking_scanner_" + name + "_" + std::to_string(::getpid()))) {
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~TempDir() { fs::remove_all(path_); }
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

std::vector<float> DecodeFloats(const std::string& bytes) {
  std::vector<float> out(bytes.size() / 4);
  std::memcpy(out.data(), bytes.data(), out.size() * 4);
  return out;
}

double Median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

// ---------------------------------------------------------------------------------------

class ScannerReplayTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir("replay");
    RenderPlaneSequence(dir_->path() / "frames");
    const fs::path calibration = dir_->path() / "calibration";
    fs::create_directories(calibration);
    WriteText(calibration / "camera_intrinsics.json", IntrinsicsJson("camera_intrinsics", kCamera));
    WriteText(calibration / "projector_intrinsics.json",
              IntrinsicsJson("projector_intrinsics", kProjector));
    WriteText(calibration / "camera_projector.json", CameraProjectorJson());
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }

  ScannerReplayTest()
      : server_(ServerBinary(kBinary),
                {"--camera=replay", "--replay.dir=" + (dir_->path() / "frames").string(),
                 "--calibration.dir=" + (dir_->path() / "calibration").string(),
                 "--sensor.nominal_dir=" + (dir_->path() / "no_nominal_sensor").string()}),
        stub_(pb::ScannerService::NewStub(server_.Channel())) {}
  ~ScannerReplayTest() override { EXPECT_EQ(server_.Stop(), 0); }

  static TempDir* dir_;
  ServerProcess server_;
  std::unique_ptr<pb::ScannerService::Stub> stub_;
};
TempDir* ScannerReplayTest::dir_ = nullptr;

TEST_F(ScannerReplayTest, ScanOfAPlaneStreamsACloudOnThePlane) {
  grpc::ClientContext ctx;
  pb::ScanRequest request;
  request.set_frame_id("camera");
  request.set_with_normals(true);
  request.set_with_intensities(true);
  request.mutable_decode()->set_min_neighbours(3);
  auto reader = stub_->Scan(&ctx, request);
  pb::ScanResponse response;
  std::vector<std::string> stages;
  int chunks = 0;
  std::uint64_t expected_points = 0;
  std::vector<float> xyz, normals;
  bool summary_seen = false;
  pb::ScanSummary summary;
  while (reader->Read(&response)) {
    ASSERT_FALSE(summary_seen) << "the summary must be the last message";
    if (response.has_progress()) stages.push_back(response.progress().stage());
    if (response.has_cloud()) {
      const auto& chunk = response.cloud();
      if (chunks == 0) {
        ASSERT_TRUE(chunk.has_header());
        EXPECT_EQ(chunk.header().frame_id(), "camera");
        EXPECT_EQ(chunk.header().width(), 1280u);
        EXPECT_EQ(chunk.header().height(), 1024u);
        EXPECT_TRUE(chunk.header().has_normals());
        EXPECT_TRUE(chunk.header().has_intensities());
        expected_points = chunk.header().point_count();
      }
      EXPECT_EQ(chunk.point_offset(), xyz.size() / 3);
      const auto p = DecodeFloats(chunk.positions());
      const auto n = DecodeFloats(chunk.normals());
      ASSERT_EQ(p.size(), 3u * chunk.point_count());
      ASSERT_EQ(n.size(), p.size());
      xyz.insert(xyz.end(), p.begin(), p.end());
      normals.insert(normals.end(), n.begin(), n.end());
      ++chunks;
    }
    if (response.has_summary()) {
      summary = response.summary();
      summary_seen = true;
    }
  }
  const grpc::Status status = reader->Finish();
  ASSERT_TRUE(status.ok()) << status.error_message();
  ASSERT_TRUE(summary_seen);
  EXPECT_EQ(stages, (std::vector<std::string>{"capture", "decode", "triangulate", "merge"}));
  EXPECT_GT(chunks, 1) << "a megapixel cloud must arrive in several chunks";
  ASSERT_EQ(xyz.size(), 3 * expected_points);

  std::vector<double> distance_m;
  double normal_dot = 0;
  std::size_t normal_count = 0;
  for (std::size_t i = 0; i < xyz.size(); i += 3) {
    const Vec3 p{xyz[i], xyz[i + 1], xyz[i + 2]};
    if (!p.Finite()) continue;
    distance_m.push_back(std::abs(kPlaneNormal.Dot(p) - kPlaneOffset));
    const Vec3 n{normals[i], normals[i + 1], normals[i + 2]};
    if (n.Finite()) normal_dot += -n.Dot(kPlaneNormal), ++normal_count;
  }
  ASSERT_EQ(distance_m.size(), summary.point_count());
  ASSERT_EQ(summary.valid_fraction_size(), 1);
  const double coverage = static_cast<double>(distance_m.size()) / (1280.0 * 1024.0);
  const double median_mm = Median(distance_m) * 1e3;
  std::cout << "replayed plane at 1 m: " << distance_m.size() << " points (" << coverage * 100
            << " % of pixels, valid fraction " << summary.valid_fraction(0) * 100
            << " %), median |distance to plane| " << median_mm << " mm, processing "
            << summary.processing_time_s() << " s\n";
  RecordProperty("median_plane_error_mm", std::to_string(median_mm));
  EXPECT_GT(summary.valid_fraction(0), 0.8);
  EXPECT_GT(coverage, 0.75);
  // One projector column step moves a point about z^2 / (b f_p) = 6 mm in depth here; with
  // integer columns the median error lies near a quarter step (1.5 mm). The scan refines
  // correspondences to sub-pixel stripe edges; these replayed images are hard-edged (no
  // area sampling), so an edge is only located to between two camera pixels.
  EXPECT_LT(median_mm, 0.8);
  // Normals face the camera. They are rough: neighbouring pixels see the same projector
  // column, so depth steps by up to a column between them.
  EXPECT_GT(normal_dot / normal_count, 0.5);
  EXPECT_GE(summary.processing_time_s(), 0.0);
}

TEST_F(ScannerReplayTest, BaseFrameScanWithoutHandEyeIsAFailedPrecondition) {
  grpc::ClientContext ctx;
  pb::ScanRequest request;  // frame_id "" = base.
  auto* view = request.add_views();
  view->mutable_x_base_tool()->mutable_orientation()->set_w(1.0);
  auto reader = stub_->Scan(&ctx, request);
  pb::ScanResponse response;
  while (reader->Read(&response)) {
  }
  const grpc::Status status = reader->Finish();
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << status.error_message();
  EXPECT_NE(status.error_message().find("hand-eye"), std::string::npos) << status.error_message();
}

TEST_F(ScannerReplayTest, BadScanRequestsAreInvalidArguments) {
  for (int k = 0; k < 3; ++k) {
    grpc::ClientContext ctx;
    pb::ScanRequest request;
    request.set_frame_id("camera");
    if (k == 0) request.set_frame_id("tool");
    if (k == 1) request.set_merge_voxel_m(-0.01);
    if (k == 2) request.mutable_decode()->set_min_white_black_contrast(300);
    auto reader = stub_->Scan(&ctx, request);
    pb::ScanResponse response;
    while (reader->Read(&response)) {
    }
    EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::INVALID_ARGUMENT) << k;
  }
}

TEST_F(ScannerReplayTest, CaptureImagesStreamsTheNamedSequence) {
  grpc::ClientContext ctx;
  auto reader = stub_->CaptureImages(&ctx, pb::CaptureImagesRequest());
  common::v1::ImageChunk chunk;
  std::vector<std::string> names;
  std::uint64_t bytes = 0;
  while (reader->Read(&chunk)) {
    if (chunk.has_header()) {
      names.push_back(chunk.header().name());
      EXPECT_EQ(chunk.header().index(), names.size() - 1);
      EXPECT_EQ(chunk.header().format(), common::v1::PIXEL_FORMAT_MONO8);
    }
    bytes += chunk.data().size();
  }
  ASSERT_TRUE(reader->Finish().ok());
  ASSERT_EQ(names.size(), 44u);
  EXPECT_EQ(names[0], "white");
  EXPECT_EQ(names[1], "black");
  EXPECT_EQ(names[2], "pattern/col/0");
  EXPECT_EQ(names[3], "pattern/col/0/inverse");
  EXPECT_EQ(names[22], "pattern/row/0");
  EXPECT_EQ(bytes, 44ull * 1280 * 1024);
}

TEST_F(ScannerReplayTest, CalibrationSessionsAreStoredAndNeedTheBoard) {
  // The replayed plane shows no chessboard: the view is stored, but cannot calibrate.
  grpc::ClientContext ctx;
  pb::CaptureCalibrationViewRequest request;
  request.set_session("plane_only");
  pb::CaptureCalibrationViewResponse response;
  ASSERT_TRUE(stub_->CaptureCalibrationView(&ctx, request, &response).ok());
  EXPECT_FALSE(response.chessboard_found());
  EXPECT_GE(response.views_in_session(), 1u);
  EXPECT_TRUE(fs::exists(dir_->path() / "calibration" / "sessions" / "plane_only" / "view_000" /
                         "img_43.png"));

  grpc::ClientContext ctx2;
  pb::CalibrateRequest calibrate;
  calibrate.set_kind(pb::CALIBRATION_KIND_CAMERA);
  calibrate.set_session("plane_only");
  pb::CalibrateResponse calibrated;
  const grpc::Status status = stub_->Calibrate(&ctx2, calibrate, &calibrated);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << status.error_message();

  grpc::ClientContext ctx3;
  request.set_session("../escape");
  EXPECT_EQ(stub_->CaptureCalibrationView(&ctx3, request, &response).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
}

class ScannerCalibrationTest : public ::testing::Test {
 protected:
  ScannerCalibrationTest()
      : dir_("calibrate"),
        server_(ServerBinary(kBinary),
                {"--calibration.dir=" + (dir_.path() / "calibration").string()}),
        stub_(pb::ScannerService::NewStub(server_.Channel())) {}
  ~ScannerCalibrationTest() override { EXPECT_EQ(server_.Stop(), 0); }

  pb::CalibrationSet Current() {
    grpc::ClientContext ctx;
    pb::GetCalibrationResponse response;
    const grpc::Status status = stub_->GetCalibration(&ctx, pb::GetCalibrationRequest(), &response);
    EXPECT_TRUE(status.ok()) << status.error_message();
    return response.calibration();
  }

  grpc::Status CalibrateCamera(const std::string& image_directory, pb::CalibrateResponse* out) {
    grpc::ClientContext ctx;
    pb::CalibrateRequest request;
    request.set_kind(pb::CALIBRATION_KIND_CAMERA);
    request.set_image_directory(image_directory);
    request.mutable_board()->set_inner_corners_cols(9);
    request.mutable_board()->set_inner_corners_rows(6);
    request.mutable_board()->set_square_size_m(0.025);
    return stub_->Calibrate(&ctx, request, out);
  }

  TempDir dir_;
  ServerProcess server_;
  std::unique_ptr<pb::ScannerService::Stub> stub_;
};

TEST_F(ScannerCalibrationTest, StartsFromTheNominalSimulatedSensor) {
  const pb::CalibrationSet set = Current();
  EXPECT_EQ(set.camera().width(), 1280u);
  EXPECT_EQ(set.camera().height(), 1024u);
  EXPECT_EQ(set.projector().width(), 912u);
  EXPECT_EQ(set.projector().height(), 1140u);
  EXPECT_TRUE(set.has_x_tool_camera());
  const auto& t = set.x_camera_projector().position();
  const double baseline_m = std::sqrt(t.x() * t.x() + t.y() * t.y() + t.z() * t.z());
  EXPECT_GT(baseline_m, 0.1);
  EXPECT_LT(baseline_m, 0.2);
  EXPECT_EQ(set.calibrated_size(), 0);  // All nominal.
}

TEST_F(ScannerCalibrationTest, CameraCalibrationFromAnImageDirectory) {
  const pb::CalibrationSet before = Current();

  // Two images are too few: refused, nothing changes.
  const fs::path few = dir_.path() / "few";
  fs::create_directories(few);
  for (const char* name : {"left01.jpg", "left02.jpg"}) {
    fs::copy_file(fs::path(PICKING_TEST_DATA_DIR) / "calibration" / name, few / name);
  }
  pb::CalibrateResponse response;
  grpc::Status status = CalibrateCamera(few.string(), &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << status.error_message();
  EXPECT_EQ(Current().SerializeAsString(), before.SerializeAsString());
  EXPECT_FALSE(fs::exists(dir_.path() / "calibration" / "camera_intrinsics.json"));

  // Unknown session and folder.
  {
    grpc::ClientContext ctx;
    pb::CalibrateRequest request;
    request.set_kind(pb::CALIBRATION_KIND_CAMERA);
    request.set_session("never_captured");
    status = stub_->Calibrate(&ctx, request, &response);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND) << status.error_message();
  }
  status = CalibrateCamera((dir_.path() / "missing").string(), &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND) << status.error_message();
  {
    grpc::ClientContext ctx;
    pb::CalibrateRequest request;
    request.set_image_directory(few.string());
    status = stub_->Calibrate(&ctx, request, &response);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << status.error_message();
  }

  // The OpenCV sample views (9 x 6 inner corners).
  status = CalibrateCamera((fs::path(PICKING_TEST_DATA_DIR) / "calibration").string(), &response);
  ASSERT_TRUE(status.ok()) << status.error_message();
  std::cout << "camera calibration: RMS " << response.rms_reprojection_error_px() << " px over "
            << response.views_used() << " views\n";
  EXPECT_LT(response.rms_reprojection_error_px(), 0.5);
  EXPECT_GE(response.views_used(), 10u);
  EXPECT_EQ(response.per_view_error_px_size(), static_cast<int>(response.views_used()));
  EXPECT_EQ(response.file_format_version(), 1u);
  EXPECT_TRUE(fs::exists(response.calibration_file())) << response.calibration_file();
  EXPECT_EQ(fs::path(response.calibration_file()),
            dir_.path() / "calibration" / "camera_intrinsics.json");
  EXPECT_TRUE(fs::exists(dir_.path() / "calibration" / "history"));

  const pb::CalibrationSet after = Current();
  EXPECT_EQ(after.camera().width(), 640u);
  EXPECT_EQ(after.camera().height(), 480u);
  EXPECT_GT(after.camera().fx(), 400.0);
  EXPECT_LT(after.camera().fx(), 700.0);
  ASSERT_EQ(after.calibrated_size(), 1);
  EXPECT_EQ(after.calibrated(0), pb::CALIBRATION_KIND_CAMERA);
  EXPECT_EQ(response.calibration().SerializeAsString(), after.SerializeAsString());
  // The projector and hand-eye values are untouched.
  EXPECT_EQ(after.projector().SerializeAsString(), before.projector().SerializeAsString());
  EXPECT_EQ(after.x_tool_camera().SerializeAsString(), before.x_tool_camera().SerializeAsString());

  // A failed calibration keeps the new current one.
  status = CalibrateCamera(few.string(), &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_EQ(Current().SerializeAsString(), after.SerializeAsString());
}

TEST_F(ScannerCalibrationTest, ARestartedServerLoadsTheCalibratedFile) {
  pb::CalibrateResponse response;
  ASSERT_TRUE(
      CalibrateCamera((fs::path(PICKING_TEST_DATA_DIR) / "calibration").string(), &response).ok());
  ServerProcess second(ServerBinary(kBinary),
                       {"--calibration.dir=" + (dir_.path() / "calibration").string()});
  auto stub = pb::ScannerService::NewStub(second.Channel());
  grpc::ClientContext ctx;
  pb::GetCalibrationResponse loaded;
  ASSERT_TRUE(stub->GetCalibration(&ctx, pb::GetCalibrationRequest(), &loaded).ok());
  EXPECT_EQ(loaded.calibration().camera().width(), 640u);
  EXPECT_NEAR(loaded.calibration().camera().fx(), response.calibration().camera().fx(), 1e-9);
  EXPECT_EQ(second.Stop(), 0);
}

// ---------------------------------------------------------------------------------------
// The scanner with the real simulator: a shelf bin of pick_layout_1 scanned from in front of
// it, compared with the simulator's cell geometry (the bin's floor).

namespace sim = ::picking::simulator::v1;

struct Mat3 {
  Vec3 col[3];  // Columns: the rotated x, y, z axes.
};

Vec3 Sub(const Vec3& a, const Vec3& b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
Vec3 Cross(const Vec3& a, const Vec3& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
Vec3 Apply(const Mat3& R, const Vec3& v) {
  return {R.col[0].x * v.x + R.col[1].x * v.y + R.col[2].x * v.z,
          R.col[0].y * v.x + R.col[1].y * v.y + R.col[2].y * v.z,
          R.col[0].z * v.x + R.col[1].z * v.y + R.col[2].z * v.z};
}
Mat3 Transpose(const Mat3& R) {
  return {{{R.col[0].x, R.col[1].x, R.col[2].x},
           {R.col[0].y, R.col[1].y, R.col[2].y},
           {R.col[0].z, R.col[1].z, R.col[2].z}}};
}
Mat3 Mul(const Mat3& A, const Mat3& B) {
  return {{Apply(A, B.col[0]), Apply(A, B.col[1]), Apply(A, B.col[2])}};
}
Mat3 FromQuaternion(double w, double x, double y, double z) {
  return {{{1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)},
           {2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)},
           {2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)}}};
}
common::v1::Pose ToPose(const Mat3& R, const Vec3& p) {
  // Shepperd's method on the rotation matrix m(r, c) = R.col[c][r].
  auto m = [&](int r, int c) {
    const Vec3& v = R.col[c];
    return r == 0 ? v.x : r == 1 ? v.y : v.z;
  };
  double w, x, y, z;
  const double trace = m(0, 0) + m(1, 1) + m(2, 2);
  if (trace > 0) {
    const double s = 2 * std::sqrt(1 + trace);
    w = 0.25 * s, x = (m(2, 1) - m(1, 2)) / s, y = (m(0, 2) - m(2, 0)) / s,
    z = (m(1, 0) - m(0, 1)) / s;
  } else if (m(0, 0) > m(1, 1) && m(0, 0) > m(2, 2)) {
    const double s = 2 * std::sqrt(1 + m(0, 0) - m(1, 1) - m(2, 2));
    w = (m(2, 1) - m(1, 2)) / s, x = 0.25 * s, y = (m(0, 1) + m(1, 0)) / s,
    z = (m(0, 2) + m(2, 0)) / s;
  } else if (m(1, 1) > m(2, 2)) {
    const double s = 2 * std::sqrt(1 + m(1, 1) - m(0, 0) - m(2, 2));
    w = (m(0, 2) - m(2, 0)) / s, x = (m(0, 1) + m(1, 0)) / s, y = 0.25 * s,
    z = (m(1, 2) + m(2, 1)) / s;
  } else {
    const double s = 2 * std::sqrt(1 + m(2, 2) - m(0, 0) - m(1, 1));
    w = (m(1, 0) - m(0, 1)) / s, x = (m(0, 2) + m(2, 0)) / s, y = (m(1, 2) + m(2, 1)) / s,
    z = 0.25 * s;
  }
  common::v1::Pose pose;
  pose.mutable_position()->set_x(p.x);
  pose.mutable_position()->set_y(p.y);
  pose.mutable_position()->set_z(p.z);
  pose.mutable_orientation()->set_w(w);
  pose.mutable_orientation()->set_x(x);
  pose.mutable_orientation()->set_y(y);
  pose.mutable_orientation()->set_z(z);
  return pose;
}

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

TEST(ScannerWithSimulatorTest, ScanOfAShelfBinMatchesTheSimulatedCell) {
  const std::string simulator_binary = ServerBinary("picking-simulator");
  ASSERT_TRUE(fs::exists(simulator_binary))
      << simulator_binary << " is missing: build the picking-simulator target";
  ServerProcess simulator(simulator_binary);
  auto sim_stub = sim::SimulatorService::NewStub(simulator.Channel());
  {
    grpc::ClientContext ctx;
    sim::LoadLayoutRequest request;
    request.set_task_json(
        ReadText(std::string(PICKING_DATA_DIR) + "/apc2016/tasks/pick_layout_1.json"));
    request.set_seed(1);
    sim::LoadLayoutResponse response;
    const grpc::Status status = sim_stub->LoadLayout(&ctx, request, &response);
    ASSERT_TRUE(status.ok()) << status.error_message();
  }
  sim::GetCellResponse cell;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(sim_stub->GetCell(&ctx, sim::GetCellRequest(), &cell).ok());
  }
  const sim::BinInfo* bin = nullptr;
  for (const auto& b : cell.bins()) {
    if (b.bin() == common::v1::CONTAINER_BIN_E) bin = &b;
  }
  ASSERT_NE(bin, nullptr);
  const auto& q = bin->x_base_bin().orientation();
  const Mat3 R_BaseBin = FromQuaternion(q.w(), q.x(), q.y(), q.z());
  const Vec3 p_BaseBin{bin->x_base_bin().position().x(), bin->x_base_bin().position().y(),
                       bin->x_base_bin().position().z()};
  // The bin's inner box in the base frame (size_m holds its extents along the bin frame's
  // axes: the shelf's x and y, and z up).
  Vec3 lo{1e9, 1e9, 1e9}, hi{-1e9, -1e9, -1e9};
  const Vec3 size_bin{bin->size_m().x(), bin->size_m().y(), bin->size_m().z()};
  for (int corner = 0; corner < 8; ++corner) {
    const Vec3 c_bin{(corner & 1 ? 0.5 : -0.5) * size_bin.x, (corner & 2 ? 0.5 : -0.5) * size_bin.y,
                     (corner & 4 ? 0.5 : -0.5) * size_bin.z};
    const Vec3 c = Apply(R_BaseBin, c_bin);
    lo = {std::min(lo.x, p_BaseBin.x + c.x), std::min(lo.y, p_BaseBin.y + c.y),
          std::min(lo.z, p_BaseBin.z + c.z)};
    hi = {std::max(hi.x, p_BaseBin.x + c.x), std::max(hi.y, p_BaseBin.y + c.y),
          std::max(hi.z, p_BaseBin.z + c.z)};
  }
  const double floor_z = lo.z;
  std::cout << "bin_E box in base: [" << lo.x << ", " << hi.x << "] x [" << lo.y << ", " << hi.y
            << "] x [" << lo.z << ", " << hi.z << "]\n";

  TempDir dir("with_simulator");
  ServerProcess scanner(ServerBinary(kBinary), {"--sim.address=" + simulator.address(),
                                                "--calibration.dir=" + dir.path().string(),
                                                "--sim.noise_sigma=1.5", "--sim.ambient=0.05"});
  auto stub = pb::ScannerService::NewStub(scanner.Channel());
  pb::GetCalibrationResponse calibration;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(stub->GetCalibration(&ctx, pb::GetCalibrationRequest(), &calibration).ok());
  }
  const auto& tc = calibration.calibration().x_tool_camera();
  const Mat3 R_ToolCamera = FromQuaternion(tc.orientation().w(), tc.orientation().x(),
                                           tc.orientation().y(), tc.orientation().z());
  const Vec3 p_ToolCamera{tc.position().x(), tc.position().y(), tc.position().z()};

  // The camera 0.55 m in front of the bin's opening and 0.1 m above its centre, looking at
  // the middle of the bin floor.
  const Vec3 target{0.5 * (lo.x + hi.x), 0.5 * (lo.y + hi.y), floor_z + 0.03};
  const Vec3 p_BaseCamera{lo.x - 0.55, target.y, 0.5 * (lo.z + hi.z) + 0.1};
  const Vec3 z_cam = Normalized(Sub(target, p_BaseCamera));
  const Vec3 x_cam = Normalized(Cross({0, 0, -1}, z_cam));
  const Vec3 y_cam = Cross(z_cam, x_cam);
  const Mat3 R_BaseCamera{{x_cam, y_cam, z_cam}};
  // X_BaseTool = X_BaseCamera * X_ToolCamera^-1.
  const Mat3 R_BaseTool = Mul(R_BaseCamera, Transpose(R_ToolCamera));
  const Vec3 r = Apply(R_BaseTool, p_ToolCamera);
  const Vec3 p_BaseTool = Sub(p_BaseCamera, r);

  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(240));
  pb::ScanRequest request;
  *request.add_views()->mutable_x_base_tool() = ToPose(R_BaseTool, p_BaseTool);
  request.set_frame_id("base");
  request.mutable_decode()->set_min_neighbours(3);
  auto reader = stub->Scan(&ctx, request);
  pb::ScanResponse response;
  std::vector<float> xyz;
  pb::ScanSummary summary;
  while (reader->Read(&response)) {
    if (response.has_cloud()) {
      const auto p = DecodeFloats(response.cloud().positions());
      xyz.insert(xyz.end(), p.begin(), p.end());
    }
    if (response.has_summary()) summary = response.summary();
  }
  const grpc::Status status = reader->Finish();
  ASSERT_TRUE(status.ok()) << status.error_message();
  ASSERT_EQ(summary.valid_fraction_size(), 1);

  // The contract exposes no rendered depth, and the bin floor is not flat (the pod's boards
  // rise toward the front lip), so the check against the cell is one-sided: no surface of
  // the bin lies below its inner box's lowest floor point, so a scanned point there is an
  // error. Points on the lip's front face (the first centimetre) are left out.
  std::size_t in_bin = 0, below_floor = 0;
  for (std::size_t i = 0; i + 2 < xyz.size(); i += 3) {
    const Vec3 p{xyz[i], xyz[i + 1], xyz[i + 2]};
    if (!p.Finite()) continue;
    if (p.x < lo.x + 0.01 || p.x > hi.x || p.y < lo.y + 0.01 || p.y > hi.y - 0.01) continue;
    if (p.z < lo.z - 0.05 || p.z > hi.z) continue;
    ++in_bin;
    if (p.z < floor_z - 0.003) ++below_floor;
  }
  ASSERT_GT(in_bin, 10000u);
  const double below_fraction = static_cast<double>(below_floor) / static_cast<double>(in_bin);
  std::cout << "bin_E scan from 0.55 m in front: valid fraction " << summary.valid_fraction(0) * 100
            << " %, " << summary.point_count() << " points, " << in_bin << " inside the bin, "
            << below_fraction * 100 << " % more than 3 mm below its lowest floor point; capture "
            << summary.capture_time_s() << " s, processing " << summary.processing_time_s()
            << " s\n";
  RecordProperty("valid_fraction", std::to_string(summary.valid_fraction(0)));
  RecordProperty("below_floor_fraction", std::to_string(below_fraction));
  EXPECT_GT(summary.valid_fraction(0), 0.3);
  EXPECT_LT(below_fraction, 0.01);
  EXPECT_EQ(scanner.Stop(), 0);
  EXPECT_EQ(simulator.Stop(), 0);
}

}  // namespace
}  // namespace picking::testing
