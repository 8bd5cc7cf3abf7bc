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
#include <iomanip>
#include <iostream>
#include <limits>
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

  ScannerReplayTest() : ScannerReplayTest({}) {}
  explicit ScannerReplayTest(const std::vector<std::string>& extra_flags)
      : server_(ServerBinary(kBinary), ReplayFlags(extra_flags)),
        stub_(pb::ScannerService::NewStub(server_.Channel())) {}
  ~ScannerReplayTest() override { EXPECT_EQ(server_.Stop(), 0); }

  static std::vector<std::string> ReplayFlags(const std::vector<std::string>& extra_flags) {
    std::vector<std::string> flags = {
        "--camera=replay", "--replay.dir=" + (dir_->path() / "frames").string(),
        "--calibration.dir=" + (dir_->path() / "calibration").string(),
        "--sensor.nominal_dir=" + (dir_->path() / "no_nominal_sensor").string()};
    flags.insert(flags.end(), extra_flags.begin(), extra_flags.end());
    return flags;
  }

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
  std::vector<pb::ScanStage> stages;
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
  EXPECT_EQ(stages, (std::vector<pb::ScanStage>{pb::SCAN_STAGE_CAPTURE, pb::SCAN_STAGE_DECODE,
                                                pb::SCAN_STAGE_TRIANGULATE, pb::SCAN_STAGE_MERGE}));
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

// The server refines only projector columns by default; decode.refine_rows=true refines the
// rows too and must give a cloud at least as good on the same replayed plane.
class ScannerReplayRowsTest : public ScannerReplayTest {
 protected:
  ScannerReplayRowsTest() : ScannerReplayTest({"--decode.refine_rows=true"}) {}
};

TEST_F(ScannerReplayRowsTest, RefiningRowsTooKeepsThePlaneAccurate) {
  grpc::ClientContext ctx;
  pb::ScanRequest request;
  request.set_frame_id("camera");
  auto reader = stub_->Scan(&ctx, request);
  pb::ScanResponse response;
  std::vector<double> distance_m;
  while (reader->Read(&response)) {
    if (!response.has_cloud()) continue;
    const auto p = DecodeFloats(response.cloud().positions());
    for (std::size_t i = 0; i + 2 < p.size(); i += 3) {
      const Vec3 q{p[i], p[i + 1], p[i + 2]};
      if (q.Finite()) distance_m.push_back(std::abs(kPlaneNormal.Dot(q) - kPlaneOffset));
    }
  }
  const grpc::Status status = reader->Finish();
  ASSERT_TRUE(status.ok()) << status.error_message();
  ASSERT_GT(distance_m.size(), 0.75 * 1280 * 1024);
  const double median_mm = Median(distance_m) * 1e3;
  std::cout << "replayed plane at 1 m, rows refined too: median |distance to plane| " << median_mm
            << " mm\n";
  EXPECT_LT(median_mm, 0.8);
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
  for (int k = 0; k < 4; ++k) {
    grpc::ClientContext ctx;
    pb::ScanRequest request;
    request.set_frame_id("camera");
    if (k == 0) request.set_frame_id("tool");
    if (k == 1) request.set_merge_voxel_m(-0.01);
    if (k == 2) request.mutable_decode()->set_min_white_black_contrast(300);
    if (k == 3) {  // One view more than a scan may have: refused before any capture.
      for (int v = 0; v < 17; ++v) request.add_views();
    }
    auto reader = stub_->Scan(&ctx, request);
    pb::ScanResponse response;
    while (reader->Read(&response)) {
    }
    const grpc::Status status = reader->Finish();
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << k;
    if (k == 3) {
      EXPECT_NE(status.error_message().find("at most 16 views, got 17"), std::string::npos)
          << status.error_message();
    }
  }
}

// A finite but huge tool pose (2e18 m) reached the simulator's ray caster and aborted it;
// the scanner answered UNAVAILABLE. The scanner refuses it as the first service.
TEST_F(ScannerReplayTest, HugeToolPositionsAreInvalidArguments) {
  {
    grpc::ClientContext ctx;
    pb::ScanRequest request;
    request.set_frame_id("camera");
    auto* view = request.add_views();
    view->mutable_x_base_tool()->mutable_position()->set_x(2e18);
    view->mutable_x_base_tool()->mutable_orientation()->set_w(1.0);
    auto reader = stub_->Scan(&ctx, request);
    pb::ScanResponse response;
    while (reader->Read(&response)) {
    }
    const grpc::Status status = reader->Finish();
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << status.error_message();
    EXPECT_NE(status.error_message().find("views[0].X_base_tool.position"), std::string::npos)
        << status.error_message();
  }
  grpc::ClientContext ctx;
  pb::CaptureCalibrationViewRequest request;
  request.set_session("huge_pose");
  request.mutable_x_base_tool()->mutable_position()->set_z(-5e18);
  request.mutable_x_base_tool()->mutable_orientation()->set_w(1.0);
  pb::CaptureCalibrationViewResponse response;
  const grpc::Status status = stub_->CaptureCalibrationView(&ctx, request, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << status.error_message();
  EXPECT_NE(status.error_message().find("X_base_tool.position"), std::string::npos)
      << status.error_message();
  EXPECT_FALSE(fs::exists(dir_->path() / "calibration" / "sessions" / "huge_pose" / "view_000"));
}

// A 10 kB session name was quoted in full: past a client's 8 KB metadata limit the caller saw
// RESOURCE_EXHAUSTED instead of the real status.
TEST_F(ScannerReplayTest, ALongSessionNameGetsAReadableInvalidArgument) {
  grpc::ClientContext ctx;
  pb::CaptureCalibrationViewRequest request;
  request.set_session(std::string(10000, 's'));
  pb::CaptureCalibrationViewResponse response;
  const grpc::Status status = stub_->CaptureCalibrationView(&ctx, request, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << status.error_message();
  EXPECT_NE(status.error_message().find("session 'sss"), std::string::npos);
  EXPECT_LT(status.error_message().size(), 200u) << status.error_message();
}

TEST_F(ScannerReplayTest, CaptureImagesStreamsTheNamedSequence) {
  grpc::ClientContext ctx;
  auto reader = stub_->CaptureImages(&ctx, pb::CaptureImagesRequest());
  pb::CaptureImagesResponse response;
  std::vector<std::string> names;
  std::uint64_t bytes = 0;
  while (reader->Read(&response)) {
    const common::v1::ImageChunk& chunk = response.chunk();
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

  // A board of 2 inner corners per side reached OpenCV's corner finder, which threw: INTERNAL.
  {
    grpc::ClientContext ctx;
    pb::CalibrateRequest request;
    request.set_kind(pb::CALIBRATION_KIND_CAMERA);
    request.set_image_directory((fs::path(PICKING_TEST_DATA_DIR) / "calibration").string());
    request.mutable_board()->set_inner_corners_rows(2);
    status = stub_->Calibrate(&ctx, request, &response);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << status.error_message();
    EXPECT_NE(status.error_message().find("3 to 100 inner corners"), std::string::npos);
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

// A too-long image_directory was INTERNAL "filesystem error: File name too long", and a
// file given as the directory NOT_FOUND "does not exist": both are the caller's mistake.
TEST_F(ScannerCalibrationTest, AnImageDirectoryTooLongOrAFileIsAnInvalidArgument) {
  pb::CalibrateResponse response;
  grpc::Status status = CalibrateCamera("/tmp/" + std::string(10000, 'd'), &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << status.error_message();
  EXPECT_NE(status.error_message().find("too long"), std::string::npos) << status.error_message();
  EXPECT_LT(status.error_message().size(), 300u);
  status = CalibrateCamera("/tmp/" + std::string(300, 'c'), &response);  // one name > NAME_MAX
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << status.error_message();
  EXPECT_NE(status.error_message().find("too long"), std::string::npos) << status.error_message();

  const fs::path file = fs::path(PICKING_TEST_DATA_DIR) / "calibration" / "left01.jpg";
  ASSERT_TRUE(fs::is_regular_file(file));
  status = CalibrateCamera(file.string(), &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << status.error_message();
  EXPECT_NE(status.error_message().find("not a directory"), std::string::npos)
      << status.error_message();
  status = CalibrateCamera((file / "views").string(), &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << status.error_message();
  EXPECT_NE(status.error_message().find("a file where a directory"), std::string::npos)
      << status.error_message();
  // Nothing was calibrated.
  EXPECT_FALSE(fs::exists(dir_.path() / "calibration" / "camera_intrinsics.json"));
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

Vec3 Add(const Vec3& a, const Vec3& b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
Vec3 Scale(double s, const Vec3& v) { return {s * v.x, s * v.y, s * v.z}; }

// A rigid transform X_AB: p_A = R * p_B + p.
struct Rigid {
  Mat3 R;
  Vec3 p;
  Vec3 operator*(const Vec3& v) const { return Add(Apply(R, v), p); }
  Rigid Inverse() const {
    const Mat3 Rt = Transpose(R);
    return {Rt, Scale(-1.0, Apply(Rt, p))};
  }
};

Rigid FromProto(const common::v1::Pose& pose) {
  const auto& q = pose.orientation();
  return {FromQuaternion(q.w(), q.x(), q.y(), q.z()),
          {pose.position().x(), pose.position().y(), pose.position().z()}};
}

// A pinhole camera with OpenCV's distortion (k1, k2, p1, p2, k3), as the scanner's
// CalibrationSet gives it.
struct Intrinsics {
  int width = 0, height = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0;
  double k1 = 0, k2 = 0, p1 = 0, p2 = 0, k3 = 0;

  explicit Intrinsics(const picking::common::v1::CameraIntrinsics& c)
      : width(static_cast<int>(c.width())),
        height(static_cast<int>(c.height())),
        fx(c.fx()),
        fy(c.fy()),
        cx(c.cx()),
        cy(c.cy()) {
    double* k[] = {&k1, &k2, &p1, &p2, &k3};
    for (int i = 0; i < c.distortion_size() && i < 5; ++i) *k[i] = c.distortion(i);
  }
  // Distorted normalised coordinates of the undistorted ones (x, y).
  void Distort(double x, double y, double* xd, double* yd) const {
    const double r2 = x * x + y * y;
    const double radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3));
    *xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x);
    *yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y;
  }
  // Pixel of a point in the camera frame (z > 0).
  void Project(const Vec3& p_C, double* u, double* v) const {
    double xd, yd;
    Distort(p_C.x / p_C.z, p_C.y / p_C.z, &xd, &yd);
    *u = fx * xd + cx;
    *v = fy * yd + cy;
  }
  // The ray through pixel (u, v) as (x, y, 1): undistorted by fixed-point iteration.
  Vec3 Ray(double u, double v) const {
    const double xd = (u - cx) / fx, yd = (v - cy) / fy;
    double x = xd, y = yd;
    for (int it = 0; it < 20; ++it) {
      double dx, dy;
      Distort(x, y, &dx, &dy);
      x -= dx - xd;
      y -= dy - yd;
    }
    return {x, y, 1.0};
  }
  picking::common::v1::CameraIntrinsics ToProto() const {
    picking::common::v1::CameraIntrinsics c;
    c.set_width(width), c.set_height(height), c.set_fx(fx), c.set_fy(fy), c.set_cx(cx),
        c.set_cy(cy);
    for (double k : {k1, k2, p1, p2, k3}) c.add_distortion(k);
    return c;
  }
};

double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  const auto k = static_cast<std::size_t>(q * static_cast<double>(v.size() - 1));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}

// Ground truth of one view: the simulator's depth image (z along the camera axis, NaN where
// nothing is hit) for the camera at X_BaseCamera.
struct TruthView {
  Rigid X_BaseCamera;
  std::vector<float> depth_m;
  int width = 0;
  float at(int u, int v) const { return depth_m[static_cast<std::size_t>(v) * width + u]; }
  // Depth at a sub-pixel position, bilinear over four pixels that see one smooth surface
  // (no neighbour missing or more than 5 mm off); NaN otherwise.
  double Interpolated(double u, double v, int height) const {
    const int u0 = static_cast<int>(std::floor(u)), v0 = static_cast<int>(std::floor(v));
    if (u0 < 0 || v0 < 0 || u0 + 1 >= width || v0 + 1 >= height) return std::nan("");
    const double d00 = at(u0, v0), d10 = at(u0 + 1, v0), d01 = at(u0, v0 + 1),
                 d11 = at(u0 + 1, v0 + 1);
    const double lo = std::min({d00, d10, d01, d11}), hi = std::max({d00, d10, d01, d11});
    if (!std::isfinite(lo) || !std::isfinite(hi) || hi - lo > 0.005) return std::nan("");
    const double a = u - u0, b = v - v0;
    return (1 - b) * ((1 - a) * d00 + a * d10) + b * ((1 - a) * d01 + a * d11);
  }
};

// A cloud streamed by Scan.
struct ScannedCloud {
  grpc::Status status;
  std::uint32_t width = 0, height = 0;
  std::vector<float> xyz;
  pb::ScanSummary summary;
  bool has_sensor_pose = false;
  picking::common::v1::Pose sensor_pose;
  Vec3 at(std::size_t i) const { return {xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]}; }
};

ScannedCloud RunScan(pb::ScannerService::Stub* stub, const pb::ScanRequest& request) {
  ScannedCloud out;
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(240));
  auto reader = stub->Scan(&ctx, request);
  pb::ScanResponse response;
  while (reader->Read(&response)) {
    if (response.has_cloud()) {
      if (response.cloud().has_header()) {
        out.width = response.cloud().header().width();
        out.height = response.cloud().header().height();
        out.has_sensor_pose = response.cloud().header().has_x_frame_sensor();
        out.sensor_pose = response.cloud().header().x_frame_sensor();
      }
      const auto p = DecodeFloats(response.cloud().positions());
      out.xyz.insert(out.xyz.end(), p.begin(), p.end());
    }
    if (response.has_summary()) out.summary = response.summary();
  }
  out.status = reader->Finish();
  return out;
}

// The bin's inner box in the base frame, slightly enlarged: a surface point inside belongs
// to the bin's visible surface (floor, walls, items).
struct Box {
  Vec3 lo{1e9, 1e9, 1e9}, hi{-1e9, -1e9, -1e9};
  bool Contains(const Vec3& p, double margin_m) const {
    return p.x >= lo.x - margin_m && p.x <= hi.x + margin_m && p.y >= lo.y - margin_m &&
           p.y <= hi.y + margin_m && p.z >= lo.z - margin_m && p.z <= hi.z + margin_m;
  }
};

// The scanner with the real simulator: bin_E of pick_layout_1 scanned through
// picking-scanner with the sim backends (realistic rendering: read and shot noise, projector
// defocus, ambient light, the camera's lens distortion), compared pixel by pixel with the
// simulator's ground-truth depth (RenderDepth) of the same camera.
class ScannerWithSimulatorTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    const std::string simulator_binary = ServerBinary("picking-simulator");
    ASSERT_TRUE(fs::exists(simulator_binary))
        << simulator_binary << " is missing: build the picking-simulator target";
    simulator_ = new ServerProcess(simulator_binary);
    sim_stub_ = sim::SimulatorService::NewStub(simulator_->Channel()).release();
    {
      grpc::ClientContext ctx;
      sim::LoadLayoutRequest request;
      request.set_task_json(
          ReadText(std::string(PICKING_DATA_DIR) + "/apc2016/tasks/pick_layout_1.json"));
      request.set_seed(1);
      sim::LoadLayoutResponse response;
      const grpc::Status status = sim_stub_->LoadLayout(&ctx, request, &response);
      ASSERT_TRUE(status.ok()) << status.error_message();
    }
    sim::GetCellResponse cell;
    {
      grpc::ClientContext ctx;
      ASSERT_TRUE(sim_stub_->GetCell(&ctx, sim::GetCellRequest(), &cell).ok());
    }
    const sim::BinInfo* bin = nullptr;
    for (const auto& b : cell.bins()) {
      if (b.bin() == common::v1::CONTAINER_BIN_E) bin = &b;
    }
    ASSERT_NE(bin, nullptr);
    const Rigid X_BaseBin = FromProto(bin->x_base_bin());
    const Vec3 size{bin->size_m().x(), bin->size_m().y(), bin->size_m().z()};
    for (int corner = 0; corner < 8; ++corner) {
      const Vec3 c =
          X_BaseBin * Vec3{(corner & 1 ? 0.5 : -0.5) * size.x, (corner & 2 ? 0.5 : -0.5) * size.y,
                           (corner & 4 ? 0.5 : -0.5) * size.z};
      bin_.lo = {std::min(bin_.lo.x, c.x), std::min(bin_.lo.y, c.y), std::min(bin_.lo.z, c.z)};
      bin_.hi = {std::max(bin_.hi.x, c.x), std::max(bin_.hi.y, c.y), std::max(bin_.hi.z, c.z)};
    }

    dir_ = new TempDir("with_simulator");
    scanner_ = new ServerProcess(ServerBinary(kBinary), ScannerFlags(dir_->path(), Rendering()));
    stub_ = pb::ScannerService::NewStub(scanner_->Channel()).release();
    pb::GetCalibrationResponse calibration;
    {
      grpc::ClientContext ctx;
      ASSERT_TRUE(stub_->GetCalibration(&ctx, pb::GetCalibrationRequest(), &calibration).ok());
    }
    // An empty calibration folder: the scanner uses the nominal sensor, which is also the
    // simulated sensor's true geometry, so the comparison measures decoding and
    // triangulation, not calibration error.
    EXPECT_EQ(calibration.calibration().calibrated_size(), 0);
    camera_ = new Intrinsics(calibration.calibration().camera());
    X_ToolCamera_ = FromProto(calibration.calibration().x_tool_camera());
  }

  static void TearDownTestSuite() {
    if (scanner_ != nullptr) {
      EXPECT_EQ(scanner_->Stop(), 0);
    }
    if (simulator_ != nullptr) {
      EXPECT_EQ(simulator_->Stop(), 0);
    }
    delete stub_;
    delete sim_stub_;
    delete scanner_;
    delete simulator_;
    delete dir_;
    delete camera_;
    stub_ = nullptr, sim_stub_ = nullptr, scanner_ = nullptr, simulator_ = nullptr;
    dir_ = nullptr, camera_ = nullptr;
  }

  // How the simulator renders the scanner's images. picking-scanner sends these with every
  // RenderPatterns call (its sim.* flags), so they change with a new scanner process, not a
  // new simulator. The defaults are the suite's: projector defocus 0.6 projector px, read
  // noise 1.5 DN (plus the scanner's default shot noise, 40 e-/DN), a linear camera.
  struct Rendering {
    double projector_blur_sigma_px = 0.6;
    double read_noise_dn = 1.5;
    double camera_gamma = 1.0;  // Grey level = 255 (irradiance / 255)^(1 / gamma).
  };

  // Flags of a picking-scanner on the suite's simulator with the nominal sensor (an empty
  // calibration folder) and `rendering`, ambient light 0.05 of the projector's white.
  static std::vector<std::string> ScannerFlags(const fs::path& calibration_dir,
                                               const Rendering& rendering) {
    return {"--sim.address=" + simulator_->address(),
            "--calibration.dir=" + calibration_dir.string(),
            "--sim.ambient=0.05",
            "--sim.noise_sigma=" + std::to_string(rendering.read_noise_dn),
            "--sim.projector_blur_sigma_px=" + std::to_string(rendering.projector_blur_sigma_px),
            "--sim.gamma=" + std::to_string(rendering.camera_gamma)};
  }

  // The camera `distance_m` from the middle of the bin's floor (3 cm above it), looking at
  // it from `azimuth_rad` to the side (about the vertical) and `elevation_rad` above.
  static Rigid CameraLookingIntoTheBin(double distance_m, double azimuth_rad,
                                       double elevation_rad) {
    const Vec3 target{0.5 * (bin_.lo.x + bin_.hi.x), 0.5 * (bin_.lo.y + bin_.hi.y),
                      bin_.lo.z + 0.03};
    const Vec3 back{-std::cos(elevation_rad) * std::cos(azimuth_rad),
                    std::cos(elevation_rad) * std::sin(azimuth_rad), std::sin(elevation_rad)};
    const Vec3 p_BaseCamera = Add(target, Scale(distance_m, back));
    const Vec3 z_cam = Normalized(Sub(target, p_BaseCamera));
    const Vec3 x_cam = Normalized(Cross({0, 0, -1}, z_cam));
    const Vec3 y_cam = Cross(z_cam, x_cam);
    return {Mat3{{x_cam, y_cam, z_cam}}, p_BaseCamera};
  }

  // The most views a scan may have, of bin_E from 1 m, turning by about one degree each.
  static pb::ScanRequest SixteenViews() {
    pb::ScanRequest request;
    for (int v = 0; v < 16; ++v) {
      *request.add_views()->mutable_x_base_tool() =
          ToolPoseFor(CameraLookingIntoTheBin(1.0, 0.02 * v, 0.35));
    }
    request.set_frame_id("base");
    return request;
  }

  // The flange pose that puts the camera at X_BaseCamera: X_BaseCamera * X_ToolCamera^-1.
  static common::v1::Pose ToolPoseFor(const Rigid& X_BaseCamera) {
    const Mat3 R_BaseTool = Mul(X_BaseCamera.R, Transpose(X_ToolCamera_.R));
    const Vec3 p_BaseTool = Sub(X_BaseCamera.p, Apply(R_BaseTool, X_ToolCamera_.p));
    return ToPose(R_BaseTool, p_BaseTool);
  }

  // Decoding as the scans below ask for it. Every bit is decided by the sign of pattern -
  // inverse (min_bit_contrast 1 instead of the default 5): with a Gray code an undecided
  // bit only occurs at a stripe edge, where either choice is off by one column at most and
  // the sub-pixel refinement places the pixel between the two columns anyway. The default
  // threshold drops those edge pixels, most of all on dim surfaces where blurred fine
  // stripes have little contrast: bin_E's coverage from 1 m falls from 73 % to 54 % of
  // its pixels with the same median error.
  static pb::DecodeOptions Decode() {
    pb::DecodeOptions decode;
    decode.set_min_bit_contrast(1);
    decode.set_min_neighbours(3);
    return decode;
  }

  static TruthView Truth(const Rigid& X_BaseCamera) {
    TruthView truth;
    truth.X_BaseCamera = X_BaseCamera;
    grpc::ClientContext ctx;
    sim::RenderDepthRequest request;
    const picking::common::v1::CameraIntrinsics c = camera_->ToProto();
    auto* m = request.mutable_camera();
    m->set_width(c.width()), m->set_height(c.height()), m->set_fx(c.fx()), m->set_fy(c.fy()),
        m->set_cx(c.cx()), m->set_cy(c.cy());
    *m->mutable_distortion() = c.distortion();
    *request.mutable_x_base_camera() = ToPose(X_BaseCamera.R, X_BaseCamera.p);
    auto reader = sim_stub_->RenderDepth(&ctx, request);
    sim::RenderDepthResponse response;
    std::string bytes;
    while (reader->Read(&response)) {
      const common::v1::ImageChunk& chunk = response.chunk();
      if (chunk.has_header()) {
        EXPECT_EQ(chunk.header().format(), common::v1::PIXEL_FORMAT_FLOAT32);
        truth.width = static_cast<int>(chunk.header().width());
      }
      bytes += chunk.data();
    }
    const grpc::Status status = reader->Finish();
    EXPECT_TRUE(status.ok()) << status.error_message();
    truth.depth_m = DecodeFloats(bytes);
    EXPECT_EQ(truth.depth_m.size(),
              static_cast<std::size_t>(camera_->width) * static_cast<std::size_t>(camera_->height));
    return truth;
  }

  // Pixels of `truth` whose surface lies in the bin.
  static std::vector<bool> BinSurface(const TruthView& truth) {
    std::vector<bool> in_bin(truth.depth_m.size(), false);
    for (int v = 0; v < camera_->height; ++v) {
      for (int u = 0; u < camera_->width; ++u) {
        const double d = truth.at(u, v);
        if (!std::isfinite(d)) continue;
        const Vec3 p_Base = truth.X_BaseCamera * Scale(d, camera_->Ray(u, v));
        in_bin[static_cast<std::size_t>(v) * truth.width + u] = bin_.Contains(p_Base, 0.005);
      }
    }
    return in_bin;
  }

  static ServerProcess* simulator_;
  static ServerProcess* scanner_;
  static sim::SimulatorService::Stub* sim_stub_;
  static pb::ScannerService::Stub* stub_;
  static TempDir* dir_;
  static Intrinsics* camera_;
  static Rigid X_ToolCamera_;
  static Box bin_;
};
ServerProcess* ScannerWithSimulatorTest::simulator_ = nullptr;
ServerProcess* ScannerWithSimulatorTest::scanner_ = nullptr;
sim::SimulatorService::Stub* ScannerWithSimulatorTest::sim_stub_ = nullptr;
pb::ScannerService::Stub* ScannerWithSimulatorTest::stub_ = nullptr;
TempDir* ScannerWithSimulatorTest::dir_ = nullptr;
Intrinsics* ScannerWithSimulatorTest::camera_ = nullptr;
Rigid ScannerWithSimulatorTest::X_ToolCamera_{};
Box ScannerWithSimulatorTest::bin_{};

// Depth errors of the scanned points of one view against the ground truth at their pixels.
struct DepthErrors {
  std::vector<double> abs_error_m;  // Points with a ground-truth depth.
  std::size_t points = 0;           // Finite scanned points.
  std::size_t without_truth = 0;    // Scanned where the camera sees nothing.
  std::size_t bin_pixels = 0;       // Pixels whose true surface lies in the bin.
  std::size_t bin_scanned = 0;      // ... of which the scan measured.
};

// Compares view `view` of a stacked organised cloud (rows view * height ...), whose points
// are in the frame F with X_FrameCamera, with `truth`.
DepthErrors CompareWithTruth(const ScannedCloud& cloud, int view, const Rigid& X_FrameCamera,
                             const TruthView& truth, const std::vector<bool>& bin_surface,
                             int width, int height) {
  DepthErrors e;
  const Rigid X_CameraFrame = X_FrameCamera.Inverse();
  const std::size_t offset = static_cast<std::size_t>(view) * width * height;
  for (std::size_t i = 0; i < static_cast<std::size_t>(width) * height; ++i) {
    const Vec3 p_Frame = cloud.at(offset + i);
    const bool scanned = p_Frame.Finite();
    if (bin_surface[i]) {
      ++e.bin_pixels;
      if (scanned) ++e.bin_scanned;
    }
    if (!scanned) continue;
    ++e.points;
    const double truth_m = truth.depth_m[i];
    if (!std::isfinite(truth_m)) {
      ++e.without_truth;
      continue;
    }
    e.abs_error_m.push_back(std::abs((X_CameraFrame * p_Frame).z - truth_m));
  }
  return e;
}

// Points with a true depth whose depth is more than 5 mm off.
std::size_t GrossCount(const DepthErrors& e) {
  return static_cast<std::size_t>(std::count_if(e.abs_error_m.begin(), e.abs_error_m.end(),
                                                [](double x) { return x > 0.005; }));
}

// ... as a percentage of the points with a true depth.
double GrossPercent(const DepthErrors& e) {
  return 100.0 * static_cast<double>(GrossCount(e)) /
         static_cast<double>(std::max<std::size_t>(1, e.abs_error_m.size()));
}

// The fraction of the pixels whose true surface lies in the bin that the scan measured.
double BinCoverage(const DepthErrors& e) {
  return static_cast<double>(e.bin_scanned) /
         static_cast<double>(std::max<std::size_t>(1, e.bin_pixels));
}

std::string Describe(const DepthErrors& e, int pixels) {
  std::ostringstream s;
  s.precision(3);
  s << e.points << " points (" << 100.0 * e.points / pixels
    << " % of pixels), |depth error| median " << Percentile(e.abs_error_m, 0.5) * 1e3 << " mm, p90 "
    << Percentile(e.abs_error_m, 0.9) * 1e3 << " mm, p99 " << Percentile(e.abs_error_m, 0.99) * 1e3
    << " mm, " << GrossPercent(e) << " % over 5 mm, " << e.without_truth
    << " where the camera sees nothing; bin surface coverage " << 100.0 * BinCoverage(e) << " % of "
    << e.bin_pixels << " pixels";
  return s.str();
}

double GrossFraction(const DepthErrors& e) {
  return static_cast<double>(GrossCount(e) + e.without_truth) /
         static_cast<double>(std::max<std::size_t>(1, e.points));
}

TEST_F(ScannerWithSimulatorTest, OneViewAtOneMetreMatchesTheTrueDepthInTheCameraFrame) {
  const Rigid X_BaseCamera = CameraLookingIntoTheBin(1.0, 0.0, 0.35);
  pb::ScanRequest request;
  *request.add_views()->mutable_x_base_tool() = ToolPoseFor(X_BaseCamera);
  request.set_frame_id("camera");
  *request.mutable_decode() = Decode();
  const ScannedCloud cloud = RunScan(stub_, request);
  ASSERT_TRUE(cloud.status.ok()) << cloud.status.error_message();
  ASSERT_EQ(cloud.width, static_cast<std::uint32_t>(camera_->width));
  ASSERT_EQ(cloud.height, static_cast<std::uint32_t>(camera_->height));
  ASSERT_EQ(cloud.xyz.size(), 3u * cloud.width * cloud.height);
  ASSERT_EQ(cloud.summary.valid_fraction_size(), 1);
  // One view: the header names the sensor, here the camera frame's own origin.
  ASSERT_TRUE(cloud.has_sensor_pose);
  EXPECT_NEAR(cloud.sensor_pose.position().x(), 0.0, 1e-9);
  EXPECT_NEAR(cloud.sensor_pose.position().z(), 0.0, 1e-9);
  EXPECT_NEAR(std::abs(cloud.sensor_pose.orientation().w()), 1.0, 1e-9);

  const TruthView truth = Truth(X_BaseCamera);
  const std::vector<bool> bin_surface = BinSurface(truth);
  const DepthErrors e =
      CompareWithTruth(cloud, 0, Rigid{Mat3{{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}}, {}}, truth,
                       bin_surface, camera_->width, camera_->height);
  const int pixels = camera_->width * camera_->height;
  std::cout << "bin_E, one view from 1 m, camera frame: " << Describe(e, pixels)
            << "; valid fraction " << cloud.summary.valid_fraction(0) * 100 << " %, capture "
            << cloud.summary.capture_time_s() << " s, processing "
            << cloud.summary.processing_time_s() << " s\n";
  const double median_mm = Percentile(e.abs_error_m, 0.5) * 1e3;
  RecordProperty("median_depth_error_mm", std::to_string(median_mm));
  RecordProperty("p90_depth_error_mm", std::to_string(Percentile(e.abs_error_m, 0.9) * 1e3));
  RecordProperty("bin_coverage", std::to_string(double(e.bin_scanned) / e.bin_pixels));
  ASSERT_GT(e.abs_error_m.size(), 100000u);
  EXPECT_LT(median_mm, 0.5);
  EXPECT_LT(GrossFraction(e), 0.02);
  EXPECT_GT(static_cast<double>(e.bin_scanned) / e.bin_pixels, 0.65);
}

// A figure of the scanner tables in benchmarks/RESULTS.md: two or three significant digits
// (0.085, 0.40, 1.26, 72.9).
std::string TableFigure(double x) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(x < 0.1 ? 3 : x < 10 ? 2 : 1) << x;
  return s.str();
}

// One row of those tables, to paste there: | label | |depth error| median / p90 / p99 |
// over 5 mm (of the points with a true depth, as Describe counts them) | bin surface
// coverage |.
std::string TableRow(const std::string& label, const DepthErrors& e) {
  return "| " + label + " | " + TableFigure(Percentile(e.abs_error_m, 0.5) * 1e3) + " / " +
         TableFigure(Percentile(e.abs_error_m, 0.9) * 1e3) + " / " +
         TableFigure(Percentile(e.abs_error_m, 0.99) * 1e3) + " mm | " +
         TableFigure(GrossPercent(e)) + " % | " + TableFigure(100.0 * BinCoverage(e)) + " % |";
}

// One view scanned through `stub` with the flange at X_BaseTool and `decode`, in the camera
// frame, against `truth` of that camera. Empty (no errors, no pixels) if the scan failed.
DepthErrors ScanOneViewInTheCameraFrame(pb::ScannerService::Stub* stub,
                                        const common::v1::Pose& X_BaseTool,
                                        const pb::DecodeOptions& decode, const TruthView& truth,
                                        const std::vector<bool>& bin_surface, int width,
                                        int height) {
  pb::ScanRequest request;
  *request.add_views()->mutable_x_base_tool() = X_BaseTool;
  request.set_frame_id("camera");
  *request.mutable_decode() = decode;
  const ScannedCloud cloud = RunScan(stub, request);
  EXPECT_TRUE(cloud.status.ok()) << cloud.status.error_message();
  if (!cloud.status.ok() || cloud.xyz.size() != 3u * static_cast<std::size_t>(width) * height) {
    return {};
  }
  return CompareWithTruth(cloud, 0, Rigid{Mat3{{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}}, {}}, truth,
                          bin_surface, width, height);
}

// The table "What the decoding thresholds cost" of benchmarks/RESULTS.md: the view of
// OneViewAtOneMetreMatchesTheTrueDepthInTheCameraFrame decoded with thresholds from
// OpenCV's bit threshold to the most permissive. Each row has a scanner of its own: the
// simulated camera's noise seed advances with every capture a scanner makes, so each
// scanner's first scan renders the same images (seed 1), the rows differ by their decoding
// alone, and they do not depend on which tests ran before. Lower thresholds admit pixels of
// less contrast (stripe edges with undecided bits, dim and grazing surfaces), whose
// correspondences are noisier.
TEST_F(ScannerWithSimulatorTest, DecodeThresholdsTradeCoverageForAccuracy) {
  struct Setting {
    std::string label;
    std::uint32_t min_bit_contrast;          // |pattern - inverse|, grey levels.
    std::uint32_t min_white_black_contrast;  // white - black, grey levels.
  };
  const std::vector<Setting> settings = {
      {"OpenCV's (`min_bit_contrast` 5, white - black >= 20)", 5, 20},
      {"`min_bit_contrast` 3", 3, 20},
      {"`min_bit_contrast` 1 (the test's)", 1, 20},
      {"`min_bit_contrast` 1, white - black >= 12", 1, 12},
      {"`min_bit_contrast` 1, white - black >= 8", 1, 8}};
  const Rigid X_BaseCamera = CameraLookingIntoTheBin(1.0, 0.0, 0.35);
  const TruthView truth = Truth(X_BaseCamera);
  const std::vector<bool> bin_surface = BinSurface(truth);
  TempDir calibration("decode_thresholds");  // Empty: the nominal sensor.
  std::vector<DepthErrors> rows;
  for (const Setting& setting : settings) {
    ServerProcess scanner(ServerBinary(kBinary), ScannerFlags(calibration.path(), Rendering()));
    auto stub = pb::ScannerService::NewStub(scanner.Channel());
    pb::DecodeOptions decode = Decode();
    decode.set_min_bit_contrast(setting.min_bit_contrast);
    decode.set_min_white_black_contrast(setting.min_white_black_contrast);
    rows.push_back(ScanOneViewInTheCameraFrame(stub.get(), ToolPoseFor(X_BaseCamera), decode, truth,
                                               bin_surface, camera_->width, camera_->height));
    EXPECT_EQ(scanner.Stop(), 0);
    ASSERT_GT(rows.back().abs_error_m.size(), 100000u) << setting.label;
  }
  std::cout << "bin_E, one view from 1 m, camera frame, what the decoding thresholds cost:\n"
            << "| decode settings | \\|depth error\\| median / p90 / p99 | over 5 mm "
            << "| bin surface coverage |\n|---|---|---|---|\n";
  for (std::size_t k = 0; k < rows.size(); ++k) {
    std::cout << TableRow(settings[k].label, rows[k]) << "\n";
  }
  // The same images decoded more permissively: every threshold lowered keeps the pixels the
  // stricter one kept.
  for (std::size_t k = 1; k < rows.size(); ++k) {
    EXPECT_GE(BinCoverage(rows[k]), BinCoverage(rows[k - 1]))
        << settings[k].label << " after " << settings[k - 1].label;
  }
  // What the coverage costs: the pixels admitted last are the least accurate.
  EXPECT_LT(Percentile(rows.front().abs_error_m, 0.5), Percentile(rows.back().abs_error_m, 0.5));
  EXPECT_LT(Percentile(rows[2].abs_error_m, 0.5), 0.5e-3) << settings[2].label;
}

// The table "How the rendering realism moves the figures" of benchmarks/RESULTS.md: the
// same view and decoding, the simulator's rendering changed one setting at a time from the
// suite's, then all three at their pessimistic values. The rendering is picking-scanner's
// (its sim.* flags), so each row has a scanner of its own on the suite's simulator; each
// scanner's first scan uses noise seed 1, so the rows share their noise draws.
TEST_F(ScannerWithSimulatorTest, RenderingRealismRaisesTheDepthError) {
  struct Variant {
    std::string label;
    Rendering rendering;  // Projector blur px, read noise DN, camera gamma.
  };
  const std::vector<Variant> variants = {
      {"the test's (blur 0.6 px, read noise 1.5 DN, linear camera)", Rendering()},
      {"sharp projector (blur 0)", Rendering{0.0, 1.5, 1.0}},
      {"projector blur 1.2 px", Rendering{1.2, 1.5, 1.0}},
      {"read noise 3 DN", Rendering{0.6, 3.0, 1.0}},
      {"camera gamma 2.2", Rendering{0.6, 1.5, 2.2}},
      {"all three: blur 1.2 px, 3 DN, gamma 2.2", Rendering{1.2, 3.0, 2.2}}};
  const Rigid X_BaseCamera = CameraLookingIntoTheBin(1.0, 0.0, 0.35);
  const TruthView truth = Truth(X_BaseCamera);
  const std::vector<bool> bin_surface = BinSurface(truth);
  TempDir calibration("rendering");  // Empty: the nominal sensor.
  std::vector<DepthErrors> rows;
  std::vector<double> median_m;
  for (const Variant& variant : variants) {
    ServerProcess scanner(ServerBinary(kBinary),
                          ScannerFlags(calibration.path(), variant.rendering));
    auto stub = pb::ScannerService::NewStub(scanner.Channel());
    rows.push_back(ScanOneViewInTheCameraFrame(stub.get(), ToolPoseFor(X_BaseCamera), Decode(),
                                               truth, bin_surface, camera_->width,
                                               camera_->height));
    EXPECT_EQ(scanner.Stop(), 0);
    ASSERT_GT(rows.back().abs_error_m.size(), 100000u) << variant.label;
    median_m.push_back(Percentile(rows.back().abs_error_m, 0.5));
  }
  std::cout << "bin_E, one view from 1 m, camera frame, how the rendering realism moves the "
            << "figures:\n"
            << "| rendering | \\|depth error\\| median / p90 / p99 | over 5 mm "
            << "| bin surface coverage |\n|---|---|---|---|\n";
  for (std::size_t k = 0; k < rows.size(); ++k) {
    std::cout << TableRow(variants[k].label, rows[k]) << "\n";
  }
  // Defocus is what the sub-pixel refinement is most sensitive to: without it the stripe
  // edges are steeper and located at least as well.
  EXPECT_LE(median_m[1], median_m[0]) << variants[1].label;
  // Every pessimistic setting at once is worse than any one of them.
  for (std::size_t k = 0; k + 1 < median_m.size(); ++k) {
    EXPECT_GT(median_m.back(), median_m[k]) << variants[k].label;
  }
}

// A scan of many views past its deadline went on rendering them one after the other while
// it held the sensor: the client had its DEADLINE_EXCEEDED, but the next scan waited for
// the abandoned one (and a stopping scanner for both). The renders are now child calls of
// the scan's call and end with it.
TEST_F(ScannerWithSimulatorTest, AScanPastItsDeadlineFreesTheSensorAtOnce) {
  const pb::ScanRequest many = SixteenViews();
  {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::milliseconds(1500));
    auto reader = stub_->Scan(&ctx, many);
    pb::ScanResponse response;
    while (reader->Read(&response)) {
    }
    ASSERT_EQ(reader->Finish().error_code(), grpc::StatusCode::DEADLINE_EXCEEDED);
  }
  // One view takes well under a second here; the abandoned scan's 15 other views would have
  // held the sensor for many more.
  pb::ScanRequest one;
  *one.add_views()->mutable_x_base_tool() = ToolPoseFor(CameraLookingIntoTheBin(1.0, 0.0, 0.35));
  one.set_frame_id("base");
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(6));
  auto reader = stub_->Scan(&ctx, one);
  pb::ScanResponse response;
  std::uint64_t points = 0;
  while (reader->Read(&response)) {
    if (response.has_summary()) points = response.summary().point_count();
  }
  const grpc::Status status = reader->Finish();
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_GT(points, 0u);
}

// A scanner asked to stop during a long scan stops within its shutdown grace: the scan's
// renders are cancelled with its call.
TEST_F(ScannerWithSimulatorTest, AScannerStoppedDuringALongScanExitsWithinItsGrace) {
  TempDir dir("stopped_during_scan");
  ServerProcess scanner(ServerBinary(kBinary),
                        {"--sim.address=" + simulator_->address(),
                         "--calibration.dir=" + dir.path().string(), "--shutdown-grace-s=0.5"});
  auto stub = pb::ScannerService::NewStub(scanner.Channel());
  const pb::ScanRequest many = SixteenViews();
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
  auto reader = stub->Scan(&ctx, many);
  pb::ScanResponse response;
  ASSERT_TRUE(reader->Read(&response));  // The first view's progress: the scan runs.
  ASSERT_TRUE(response.has_progress());
  // 16 views take far longer than 5 s; the scanner must not wait for them.
  EXPECT_EQ(scanner.Stop(std::chrono::seconds(5)), 0);
  while (reader->Read(&response)) {
  }
  EXPECT_FALSE(reader->Finish().ok());
}

struct MergedErrors {
  std::vector<double> distance_m;  // Per matched point: its depth difference, metres.
  std::size_t finite = 0;          // Finite merged points.
  std::size_t unmatched = 0;       // ... off every view's smooth true surface.
  std::string per_view;            // Coverage of each view's bin surface, "a %, b %, c %".
  double coverage = 0.0;           // Of all views' bin surface pixels.
};

// The merged cloud against the true surface: each point projected into every view and
// compared with that view's true depth there (bilinear over one smooth surface); the view
// that sees the point's surface gives the smallest difference. Pixels of each view's bin
// surface that some merged point lands on (within 2 mm of their true depth) are covered.
MergedErrors CompareMergedWithTruth(const ScannedCloud& cloud, const std::vector<Rigid>& cameras,
                                    const std::vector<TruthView>& truth,
                                    const std::vector<std::vector<bool>>& bin_surface,
                                    const Intrinsics& camera, int width, int height) {
  const int pixels = width * height;
  MergedErrors out;
  std::vector<std::vector<bool>> covered(cameras.size(), std::vector<bool>(pixels, false));
  std::vector<Rigid> X_CameraBase;
  for (const Rigid& X : cameras) X_CameraBase.push_back(X.Inverse());
  for (std::size_t i = 0; i < cloud.xyz.size() / 3; ++i) {
    const Vec3 p_Base = cloud.at(i);
    if (!p_Base.Finite()) continue;
    ++out.finite;
    double best = std::numeric_limits<double>::infinity();
    for (std::size_t k = 0; k < cameras.size(); ++k) {
      const Vec3 p_C = X_CameraBase[k] * p_Base;
      if (p_C.z <= 0) continue;
      double u, v;
      camera.Project(p_C, &u, &v);
      const double d = truth[k].Interpolated(u, v, height);
      if (!std::isfinite(d)) continue;
      const double error = std::abs(p_C.z - d);
      best = std::min(best, error);
      const int ui = static_cast<int>(std::lround(u)), vi = static_cast<int>(std::lround(v));
      if (error < 0.002) covered[k][static_cast<std::size_t>(vi) * width + ui] = true;
    }
    if (std::isfinite(best)) {
      out.distance_m.push_back(best);
    } else {
      ++out.unmatched;
    }
  }
  std::size_t bin_pixels = 0, bin_covered = 0;
  std::ostringstream per_view;
  for (std::size_t k = 0; k < cameras.size(); ++k) {
    std::size_t n = 0, c = 0;
    for (int i = 0; i < pixels; ++i) {
      if (!bin_surface[k][i]) continue;
      ++n;
      if (covered[k][i]) ++c;
    }
    per_view << (k ? ", " : "") << 100.0 * c / std::max<std::size_t>(1, n) << " %";
    bin_pixels += n;
    bin_covered += c;
  }
  out.per_view = per_view.str();
  out.coverage = static_cast<double>(bin_covered) / std::max<std::size_t>(1, bin_pixels);
  return out;
}

TEST_F(ScannerWithSimulatorTest, ThreeViewsMergedInTheBaseFrameMatchTheTrueSurface) {
  // The paper's three scans of a shelf bin from different angles: straight in and 15
  // degrees to either side, each from 1 m.
  const std::vector<Rigid> cameras = {CameraLookingIntoTheBin(1.0, -0.26, 0.35),
                                      CameraLookingIntoTheBin(1.0, 0.0, 0.35),
                                      CameraLookingIntoTheBin(1.0, 0.26, 0.35)};
  pb::ScanRequest request;
  for (const Rigid& X_BaseCamera : cameras) {
    *request.add_views()->mutable_x_base_tool() = ToolPoseFor(X_BaseCamera);
  }
  request.set_frame_id("base");
  *request.mutable_decode() = Decode();
  const ScannedCloud cloud = RunScan(stub_, request);
  ASSERT_TRUE(cloud.status.ok()) << cloud.status.error_message();
  const int width = camera_->width, height = camera_->height;
  const int pixels = width * height;
  // Without a merge voxel the views are stacked: still organised, view k in rows
  // [k * height, (k + 1) * height).
  ASSERT_EQ(cloud.width, static_cast<std::uint32_t>(width));
  ASSERT_EQ(cloud.height, 3u * static_cast<std::uint32_t>(height));
  ASSERT_EQ(cloud.xyz.size(), 3u * cloud.width * cloud.height);
  ASSERT_EQ(cloud.summary.x_frame_sensor_size(), 3);
  EXPECT_FALSE(cloud.has_sensor_pose);  // Three sensors: their poses are in the summary.

  std::vector<TruthView> truth;
  std::vector<std::vector<bool>> bin_surface;
  for (std::size_t k = 0; k < cameras.size(); ++k) {
    truth.push_back(Truth(cameras[k]));
    bin_surface.push_back(BinSurface(truth.back()));
    // The scanner placed view k where the robot held the camera (hand-eye and pose chain).
    const Rigid X_BaseCamera = FromProto(cloud.summary.x_frame_sensor(static_cast<int>(k)));
    EXPECT_LT(std::sqrt(Sub(X_BaseCamera.p, cameras[k].p).Dot(Sub(X_BaseCamera.p, cameras[k].p))),
              1e-6);
    for (int c = 0; c < 3; ++c) {
      EXPECT_GT(X_BaseCamera.R.col[c].Dot(cameras[k].R.col[c]), 1.0 - 1e-9);
    }
    // Each view, through the base frame, against its own camera's true depth.
    const DepthErrors e = CompareWithTruth(cloud, static_cast<int>(k), cameras[k], truth.back(),
                                           bin_surface.back(), width, height);
    std::cout << "bin_E view " << k << " of 3 in the base frame: " << Describe(e, pixels) << "\n";
    EXPECT_LT(Percentile(e.abs_error_m, 0.5), 0.5e-3) << "view " << k;
    EXPECT_LT(GrossFraction(e), 0.02) << "view " << k;
  }

  const MergedErrors merged =
      CompareMergedWithTruth(cloud, cameras, truth, bin_surface, *camera_, width, height);
  const std::vector<double>& distance_m = merged.distance_m;
  const std::size_t finite = merged.finite, unmatched = merged.unmatched;
  const double coverage = merged.coverage;
  const double median_mm = Percentile(distance_m, 0.5) * 1e3;
  const auto gross = static_cast<std::size_t>(
      std::count_if(distance_m.begin(), distance_m.end(), [](double x) { return x > 0.005; }));
  std::cout << "bin_E, 3 views merged in the base frame: " << finite
            << " points, |depth difference to the true surface| median " << median_mm << " mm, p90 "
            << Percentile(distance_m, 0.9) * 1e3 << " mm, p99 "
            << Percentile(distance_m, 0.99) * 1e3 << " mm, "
            << 100.0 * gross / std::max<std::size_t>(1, finite) << " % over 5 mm, "
            << 100.0 * unmatched / std::max<std::size_t>(1, finite)
            << " % off every smooth true surface (depth edges); the bin surface each view sees is "
            << "covered by the merged cloud to " << merged.per_view << " (" << coverage * 100
            << " % overall); capture " << cloud.summary.capture_time_s() << " s, processing "
            << cloud.summary.processing_time_s() << " s\n";
  RecordProperty("merged_median_error_mm", std::to_string(median_mm));
  RecordProperty("merged_bin_coverage", std::to_string(coverage));
  ASSERT_GT(distance_m.size(), 300000u);
  EXPECT_LT(median_mm, 0.5);
  EXPECT_LT(static_cast<double>(gross + unmatched) / finite, 0.02);
  EXPECT_GT(coverage, 0.75);
}

}  // namespace
}  // namespace picking::testing
