// Integration test of the picking-detector server binary through its generated client.
//
// The server runs with the test manifest tests/data/detector/models.json (the PCL milk carton,
// a partial view of the Stanford bunny, one catalogue shape). The scene is the real Kinect
// scene milk_cartoon_all_small_clorox.pcd, in which the milk model's true pose is the
// identity; the test moves the whole scene by a seeded random transform and expects the
// detector to find the milk at that transform.
//
// DetectorBinScanTest (at the end) drives the detector with simulated shelf-bin scans made by
// the picking-simulator and picking-scanner servers, judged by the simulator's ground truth.
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <map>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "picking/detector/v1/detector.grpc.pb.h"
#include "picking/scanner/v1/scanner.grpc.pb.h"
#include "picking/simulator/v1/simulator.grpc.pb.h"
#include "tests/harness/server_process.h"
#include "tests/harness/service_checks.h"

namespace picking::testing {
namespace {

namespace pb = ::picking::detector::v1;
namespace common = ::picking::common::v1;

const char kBinary[] = "picking-detector";
constexpr double kPi = 3.14159265358979323846;

std::string TestData(const std::string& relative) {
  return std::string(PICKING_TEST_DATA_DIR) + "/" + relative;
}

// --- A minimal reader of the PCL scene (PCD binary_compressed x y z rgba) ----------------------
// The test links neither PCL nor the geometry library: it decodes the file itself.

struct Scene {
  std::uint32_t width = 0;
  std::uint32_t height = 0;
  std::vector<float> xyz;         // 3 per point, NaN for missing pixels.
  std::vector<std::uint8_t> rgb;  // 3 per point.
  std::size_t size() const { return xyz.size() / 3; }
};

// LZF decompression (the format PCL's binary_compressed uses).
std::vector<std::uint8_t> LzfDecompress(const std::uint8_t* in, std::size_t in_size,
                                        std::size_t out_size) {
  std::vector<std::uint8_t> out(out_size);
  std::size_t ip = 0;
  std::size_t op = 0;
  while (ip < in_size) {
    unsigned ctrl = in[ip++];
    if (ctrl < 32) {  // Literal run of ctrl + 1 bytes.
      const std::size_t n = ctrl + 1;
      if (ip + n > in_size || op + n > out_size) throw std::runtime_error("LZF: literal overrun");
      std::memcpy(&out[op], &in[ip], n);
      ip += n;
      op += n;
    } else {  // Back reference.
      std::size_t len = ctrl >> 5;
      if (len == 7) len += in[ip++];
      len += 2;
      const std::size_t back = ((ctrl & 0x1f) << 8) + in[ip++] + 1;
      if (back > op || op + len > out_size) throw std::runtime_error("LZF: bad back reference");
      for (std::size_t i = 0; i < len; ++i, ++op) out[op] = out[op - back];
    }
  }
  if (op != out_size) throw std::runtime_error("LZF: short output");
  return out;
}

Scene ReadMilkScene() {
  const std::string path = TestData("pointclouds/milk_cartoon_all_small_clorox.pcd");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot open " + path);
  Scene scene;
  std::string line;
  std::size_t points = 0;
  while (std::getline(in, line)) {
    std::istringstream fields(line);
    std::string key;
    fields >> key;
    if (key == "FIELDS" && line != "FIELDS x y z rgba") throw std::runtime_error("fields: " + line);
    if (key == "WIDTH") fields >> scene.width;
    if (key == "HEIGHT") fields >> scene.height;
    if (key == "POINTS") fields >> points;
    if (key == "DATA") {
      if (line != "DATA binary_compressed") throw std::runtime_error("data: " + line);
      break;
    }
  }
  std::uint32_t sizes[2];
  in.read(reinterpret_cast<char*>(sizes), sizeof(sizes));
  std::vector<std::uint8_t> compressed(sizes[0]);
  in.read(reinterpret_cast<char*>(compressed.data()), sizes[0]);
  if (!in || points != static_cast<std::size_t>(scene.width) * scene.height ||
      sizes[1] != points * 16) {
    throw std::runtime_error("unexpected layout of " + path);
  }
  const std::vector<std::uint8_t> raw = LzfDecompress(compressed.data(), sizes[0], sizes[1]);
  // Field-major: all x, all y, all z, all rgba.
  scene.xyz.resize(points * 3);
  scene.rgb.resize(points * 3);
  for (std::size_t i = 0; i < points; ++i) {
    for (int axis = 0; axis < 3; ++axis) {
      std::memcpy(&scene.xyz[3 * i + axis], &raw[(axis * points + i) * 4], 4);
    }
    std::uint32_t rgba;
    std::memcpy(&rgba, &raw[(3 * points + i) * 4], 4);
    scene.rgb[3 * i] = static_cast<std::uint8_t>((rgba >> 16) & 0xff);
    scene.rgb[3 * i + 1] = static_cast<std::uint8_t>((rgba >> 8) & 0xff);
    scene.rgb[3 * i + 2] = static_cast<std::uint8_t>(rgba & 0xff);
  }
  return scene;
}

// A rigid transform (the test links no linear algebra library): p -> R p + t.
struct Transform {
  std::array<std::array<double, 3>, 3> R{{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}};
  std::array<double, 3> t{0, 0, 0};

  std::array<double, 3> Apply(const std::array<double, 3>& p) const {
    std::array<double, 3> q = t;
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) q[r] += R[r][c] * p[c];
    }
    return q;
  }
  std::array<double, 3> Rotate(const std::array<double, 3>& v) const {
    std::array<double, 3> q{0, 0, 0};
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) q[r] += R[r][c] * v[c];
    }
    return q;
  }
};

// Rotation of the unit quaternion (w, x, y, z).
std::array<std::array<double, 3>, 3> RotationOf(double w, double x, double y, double z) {
  const double n = std::sqrt(w * w + x * x + y * y + z * z);
  w /= n;
  x /= n;
  y /= n;
  z /= n;
  return {{{1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)},
           {2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)},
           {2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}}};
}

Scene Transformed(const Scene& scene, const Transform& X) {
  Scene out = scene;
  for (std::size_t i = 0; i < scene.size(); ++i) {
    const std::array<double, 3> p = {scene.xyz[3 * i], scene.xyz[3 * i + 1], scene.xyz[3 * i + 2]};
    if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) continue;
    const std::array<double, 3> q = X.Apply(p);
    for (int a = 0; a < 3; ++a) out.xyz[3 * i + a] = static_cast<float>(q[a]);
  }
  return out;
}

common::Pose ToPose(const Transform& X) {
  common::Pose pose;
  pose.mutable_position()->set_x(X.t[0]);
  pose.mutable_position()->set_y(X.t[1]);
  pose.mutable_position()->set_z(X.t[2]);
  // Rotation matrix to quaternion (Shepperd's method).
  const auto& R = X.R;
  double w, x, y, z;
  const double trace = R[0][0] + R[1][1] + R[2][2];
  if (trace > 0) {
    const double s = 2.0 * std::sqrt(1.0 + trace);
    w = 0.25 * s;
    x = (R[2][1] - R[1][2]) / s;
    y = (R[0][2] - R[2][0]) / s;
    z = (R[1][0] - R[0][1]) / s;
  } else if (R[0][0] > R[1][1] && R[0][0] > R[2][2]) {
    const double s = 2.0 * std::sqrt(1.0 + R[0][0] - R[1][1] - R[2][2]);
    w = (R[2][1] - R[1][2]) / s;
    x = 0.25 * s;
    y = (R[0][1] + R[1][0]) / s;
    z = (R[0][2] + R[2][0]) / s;
  } else if (R[1][1] > R[2][2]) {
    const double s = 2.0 * std::sqrt(1.0 + R[1][1] - R[0][0] - R[2][2]);
    w = (R[0][2] - R[2][0]) / s;
    x = (R[0][1] + R[1][0]) / s;
    y = 0.25 * s;
    z = (R[1][2] + R[2][1]) / s;
  } else {
    const double s = 2.0 * std::sqrt(1.0 + R[2][2] - R[0][0] - R[1][1]);
    w = (R[1][0] - R[0][1]) / s;
    x = (R[0][2] + R[2][0]) / s;
    y = (R[1][2] + R[2][1]) / s;
    z = 0.25 * s;
  }
  pose.mutable_orientation()->set_w(w);
  pose.mutable_orientation()->set_x(x);
  pose.mutable_orientation()->set_y(y);
  pose.mutable_orientation()->set_z(z);
  return pose;
}

Transform FromPose(const common::Pose& pose) {
  Transform X;
  X.t = {pose.position().x(), pose.position().y(), pose.position().z()};
  X.R = RotationOf(pose.orientation().w(), pose.orientation().x(), pose.orientation().y(),
                   pose.orientation().z());
  return X;
}

double TranslationError(const Transform& a, const Transform& b) {
  double sum = 0.0;
  for (int i = 0; i < 3; ++i) sum += (a.t[i] - b.t[i]) * (a.t[i] - b.t[i]);
  return std::sqrt(sum);
}

// Angle of R_a^T R_b, radians.
double RotationErrorRad(const Transform& a, const Transform& b) {
  double trace = 0.0;
  for (int i = 0; i < 3; ++i) {
    for (int k = 0; k < 3; ++k) trace += a.R[k][i] * b.R[k][i];
  }
  return std::acos(std::clamp(0.5 * (trace - 1.0), -1.0, 1.0));
}

// The scene as PointCloudChunks of at most 65,536 points, the sensor pose in the header.
std::vector<common::PointCloudChunk> ToChunks(const Scene& scene, const Transform& X_BaseSensor) {
  std::vector<common::PointCloudChunk> chunks;
  const std::size_t n = scene.size();
  constexpr std::size_t kPerChunk = 65536;
  for (std::size_t offset = 0; offset < n; offset += kPerChunk) {
    const std::size_t count = std::min(kPerChunk, n - offset);
    common::PointCloudChunk chunk;
    if (offset == 0) {
      auto* h = chunk.mutable_header();
      h->set_frame_id("base");
      h->set_point_count(n);
      h->set_width(scene.width);
      h->set_height(scene.height);
      h->set_has_colors(true);
      *h->mutable_x_frame_sensor() = ToPose(X_BaseSensor);
    }
    chunk.set_point_offset(offset);
    chunk.set_point_count(static_cast<std::uint32_t>(count));
    chunk.set_positions(std::string(reinterpret_cast<const char*>(&scene.xyz[3 * offset]),
                                    count * 3 * sizeof(float)));
    chunk.set_colors(std::string(reinterpret_cast<const char*>(&scene.rgb[3 * offset]), count * 3));
    chunks.push_back(std::move(chunk));
  }
  return chunks;
}

// --- Standard server checks -----------------------------------------------------------------

TEST(DetectorServerTest, ServesHealthAndReflectionAndStopsCleanly) {
  ExpectStandardServerBehaviour(ServerBinary(kBinary), "picking.detector.v1.DetectorService",
                                "picking/detector/v1/detector.proto");
}

TEST(DetectorServerTest, RejectsBadFlags) { ExpectRejectsBadFlags(ServerBinary(kBinary)); }

TEST(DetectorServerTest, RejectsABrokenManifest) {
  const std::string dir = ::testing::TempDir() + "/detector_bad_manifest";
  std::filesystem::create_directories(dir);
  const std::string manifest = dir + "/models.json";
  std::ofstream(manifest) << R"({"models": {"milk": {"source": "scan:milk.pcd", "colour": 1}}})";
  const ProgramResult r =
      RunProgram(ServerBinary(kBinary), {"--listen=127.0.0.1:0", "--models=" + manifest});
  EXPECT_EQ(r.exit_status, 2) << r.output;
  EXPECT_NE(r.output.find("models.milk.colour"), std::string::npos) << r.output;
}

TEST(DetectorServerTest, RejectsANonPositiveTimeBudgetScale) {
  const ProgramResult r =
      RunProgram(ServerBinary(kBinary), {"--listen=127.0.0.1:0", "--time_budget_scale=0"});
  EXPECT_EQ(r.exit_status, 2) << r.output;
  EXPECT_NE(r.output.find("time_budget_scale"), std::string::npos) << r.output;
}

TEST(DetectorServerTest, RejectsAnUnknownBudgetClock) {
  const ProgramResult r =
      RunProgram(ServerBinary(kBinary), {"--listen=127.0.0.1:0", "--budget_clock=wall"});
  EXPECT_EQ(r.exit_status, 2) << r.output;
  EXPECT_NE(r.output.find("budget_clock"), std::string::npos) << r.output;
}

// --- Detection on the real scene ------------------------------------------------------------

// The cloud chunks after a call's first message (Detect and Verify alike), then the end of
// the call and its status.
template <typename Request, typename Writer>
grpc::Status WriteChunksAndFinish(Writer& writer,
                                  const std::vector<common::PointCloudChunk>& chunks) {
  for (const auto& chunk : chunks) {
    Request request;
    *request.mutable_cloud() = chunk;
    if (!writer.Write(request)) break;
  }
  writer.WritesDone();
  return writer.Finish();
}

// A Verify call: the params for `item` at X_BaseItem, then the cloud chunks.
grpc::Status StreamVerify(pb::DetectorService::Stub& stub, const std::string& item,
                          const Transform& X_BaseItem,
                          const std::vector<common::PointCloudChunk>& chunks,
                          pb::VerifyResponse* response) {
  grpc::ClientContext ctx;
  auto writer = stub.Verify(&ctx, response);
  pb::VerifyRequest request;
  request.mutable_params()->set_item(item);
  *request.mutable_params()->mutable_x_frame_item() = ToPose(X_BaseItem);
  writer->Write(request);
  return WriteChunksAndFinish<pb::VerifyRequest>(*writer, chunks);
}

class DetectorSceneTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    cache_dir_ = new std::string(::testing::TempDir() + "/detector_server_test_cache");
    std::filesystem::remove_all(*cache_dir_);
    // The items' time budgets are judged on a clock that stands still: the searches are those
    // of a quiet machine however busy this one is.
    server_ = new ServerProcess(ServerBinary(kBinary),
                                {"--models=" + TestData("detector/models.json"),
                                 "--cache_dir=" + *cache_dir_, "--budget_clock=frozen"});
    scene_ = new Scene(ReadMilkScene());
    std::mt19937 rng(20160707);
    std::normal_distribution<double> normal(0.0, 1.0);
    std::uniform_real_distribution<double> uniform(-0.5, 0.5);
    X_BaseScene_ = new Transform();
    const double w = normal(rng), x = normal(rng), y = normal(rng), z = normal(rng);
    X_BaseScene_->R = RotationOf(w, x, y, z);
    X_BaseScene_->t = {uniform(rng), uniform(rng), uniform(rng)};
    // The scene was captured by a sensor at the origin of its own frame.
    chunks_ = new std::vector<common::PointCloudChunk>(
        ToChunks(Transformed(*scene_, *X_BaseScene_), *X_BaseScene_));
  }
  static void TearDownTestSuite() {
    EXPECT_EQ(server_->Stop(), 0);
    delete server_;
    delete scene_;
    delete X_BaseScene_;
    delete chunks_;
    std::filesystem::remove_all(*cache_dir_);
    delete cache_dir_;
  }

  static std::unique_ptr<pb::DetectorService::Stub> Stub() {
    return pb::DetectorService::NewStub(server_->Channel());
  }

  static grpc::Status Detect(const pb::DetectParams& params,
                             const std::vector<common::PointCloudChunk>& chunks,
                             pb::DetectResponse* response, bool send_params = true) {
    auto stub = Stub();
    grpc::ClientContext ctx;
    auto writer = stub->Detect(&ctx, response);
    if (send_params) {
      pb::DetectRequest request;
      *request.mutable_params() = params;
      writer->Write(request);
    }
    return WriteChunksAndFinish<pb::DetectRequest>(*writer, chunks);
  }

  static grpc::Status Verify(const Transform& X_BaseItem, pb::VerifyResponse* response) {
    return StreamVerify(*Stub(), "milk", X_BaseItem, *chunks_, response);
  }

  static pb::DetectParams Query(std::initializer_list<std::string> items, pb::Method method) {
    pb::DetectParams params;
    for (const auto& item : items) {
      auto* q = params.add_queries();
      q->set_item(item);
      q->set_method(method);
    }
    return params;
  }

  static std::string* cache_dir_;
  static ServerProcess* server_;
  static Scene* scene_;
  static Transform* X_BaseScene_;
  static std::vector<common::PointCloudChunk>* chunks_;
};
std::string* DetectorSceneTest::cache_dir_ = nullptr;
ServerProcess* DetectorSceneTest::server_ = nullptr;
Scene* DetectorSceneTest::scene_ = nullptr;
Transform* DetectorSceneTest::X_BaseScene_ = nullptr;
std::vector<common::PointCloudChunk>* DetectorSceneTest::chunks_ = nullptr;

// A method that cannot run says so, and why, rather than answering like "not seen": SIFT on
// the milk, whose model has no colours (no SIFT views).
TEST_F(DetectorSceneTest, AMethodThatCannotRunSaysWhy) {
  pb::DetectResponse response;
  const grpc::Status status = Detect(Query({"milk"}, pb::METHOD_SIFT), *chunks_, &response);
  ASSERT_TRUE(status.ok()) << status.error_message();
  ASSERT_EQ(response.results_size(), 1);
  const pb::ItemResult& milk = response.results(0);
  EXPECT_EQ(milk.status().code(), 0) << milk.status().message();
  EXPECT_EQ(milk.detections_size(), 0);
  ASSERT_EQ(milk.attempts_size(), 1);
  EXPECT_EQ(milk.attempts(0).method(), pb::METHOD_SIFT);
  EXPECT_EQ(milk.attempts(0).outcome(), pb::MethodAttempt::OUTCOME_CANNOT_RUN);
  EXPECT_NE(milk.attempts(0).reason().find("no SIFT views"), std::string::npos)
      << milk.attempts(0).reason();
}

// One batch: the milk is found at the scene's transform, an unknown item gets NOT_FOUND
// without hiding the others, and the bunny (not in the scene) gets no detection.
TEST_F(DetectorSceneTest, DetectsMilkAndReportsEachItemSeparately) {
  pb::DetectResponse response;
  const grpc::Status status =
      Detect(Query({"milk", "no_such_item", "bunny"}, pb::METHOD_PPF), *chunks_, &response);
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(response.points_received(), scene_->size());
  EXPECT_GT(response.points_after_preprocessing(), 100000u);
  ASSERT_EQ(response.results_size(), 3);

  const pb::ItemResult& milk = response.results(0);
  EXPECT_EQ(milk.item(), "milk");
  EXPECT_EQ(milk.status().code(), 0) << milk.status().message();
  ASSERT_EQ(milk.detections_size(), 1);
  ASSERT_EQ(milk.methods_tried_size(), 1);
  EXPECT_EQ(milk.methods_tried(0), pb::METHOD_PPF);
  ASSERT_EQ(milk.attempts_size(), 1);
  EXPECT_EQ(milk.attempts(0).method(), pb::METHOD_PPF);
  EXPECT_EQ(milk.attempts(0).outcome(), pb::MethodAttempt::OUTCOME_ACCEPTED);
  EXPECT_TRUE(milk.attempts(0).reason().empty());
  EXPECT_GT(milk.attempts(0).best_score(), 0.5);
  const pb::Detection& d = milk.detections(0);
  EXPECT_EQ(d.method(), pb::METHOD_PPF);
  const Transform X_BaseMilk = FromPose(d.x_frame_item());
  EXPECT_LT(TranslationError(X_BaseMilk, *X_BaseScene_), 0.005);
  EXPECT_LT(RotationErrorRad(X_BaseMilk, *X_BaseScene_), 2.0 * kPi / 180.0);
  EXPECT_GT(d.score(), 0.5);
  // The evidence under the score: most of what the sensor would see of the milk is supported.
  EXPECT_GT(d.visible_points(), 100u);
  EXPECT_GT(d.supported_points(), d.visible_points() / 2);
  EXPECT_LE(d.supported_points() + d.occluded_points() + d.conflict_points(), d.visible_points());
  EXPECT_GT(d.fitness(), 0.3);
  EXPECT_LT(d.inlier_rmse_m(), 0.01);
  EXPECT_GT(d.timings().total_s(), 0.0);

  const pb::ItemResult& unknown = response.results(1);
  EXPECT_EQ(unknown.item(), "no_such_item");
  EXPECT_EQ(unknown.status().code(), static_cast<int>(grpc::StatusCode::NOT_FOUND));
  EXPECT_NE(unknown.status().message().find("no_such_item"), std::string::npos);
  EXPECT_EQ(unknown.detections_size(), 0);

  const pb::ItemResult& bunny = response.results(2);
  EXPECT_EQ(bunny.item(), "bunny");
  EXPECT_EQ(bunny.status().code(), 0) << bunny.status().message();
  EXPECT_EQ(bunny.detections_size(), 0)
      << "made-up bunny pose, score " << bunny.detections(0).score();
}

TEST_F(DetectorSceneTest, VerifyScoresTheTruePoseHighAndAShiftedPoseLow) {
  pb::VerifyResponse truth;
  ASSERT_TRUE(Verify(*X_BaseScene_, &truth).ok());
  EXPECT_GT(truth.score(), 0.7);
  EXPECT_GT(truth.visible_model_points(), 100u);
  EXPECT_GT(truth.supported_model_points(), truth.visible_model_points() / 2);

  Transform shifted = *X_BaseScene_;
  // 3 cm along the sensor's x axis (sideways as seen from the sensor).
  const std::array<double, 3> step = X_BaseScene_->Rotate({0.03, 0.0, 0.0});
  for (int i = 0; i < 3; ++i) shifted.t[i] += step[i];
  pb::VerifyResponse wrong;
  ASSERT_TRUE(Verify(shifted, &wrong).ok());
  EXPECT_LT(wrong.score(), 0.3);
  EXPECT_LT(wrong.score(), truth.score() - 0.4);
}

// A 10 kB item name was quoted in full: a client with gRPC's default 8 KB metadata limit
// saw RESOURCE_EXHAUSTED instead of NOT_FOUND.
TEST_F(DetectorSceneTest, ALongUnknownItemNameGetsAReadableNotFound) {
  pb::VerifyResponse response;
  const grpc::Status s =
      StreamVerify(*Stub(), std::string(10000, 'm'), *X_BaseScene_, *chunks_, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::NOT_FOUND) << s.error_message();
  EXPECT_NE(s.error_message().find("unknown item 'mmm"), std::string::npos);
  EXPECT_LT(s.error_message().size(), 400u) << s.error_message();
}

TEST_F(DetectorSceneTest, ListModelsListsTheManifest) {
  pb::VerifyResponse verified;  // Verifying the milk builds its model.
  ASSERT_TRUE(Verify(*X_BaseScene_, &verified).ok());
  auto stub = Stub();
  grpc::ClientContext ctx;
  pb::ListModelsResponse response;
  ASSERT_TRUE(stub->ListModels(&ctx, pb::ListModelsRequest(), &response).ok());
  ASSERT_EQ(response.models_size(), 3);
  EXPECT_GE(response.cache_format_version(), 1u);
  std::map<std::string, pb::ModelInfo> by_item;
  for (const auto& m : response.models()) by_item[m.item()] = m;
  ASSERT_EQ(by_item.count("milk"), 1u);
  ASSERT_EQ(by_item.count("bunny"), 1u);
  ASSERT_EQ(by_item.count("crayola_24_ct"), 1u);
  const pb::ModelInfo& milk = by_item["milk"];
  EXPECT_EQ(milk.source(), pb::MODEL_SOURCE_SCAN);
  EXPECT_EQ(milk.symmetry(), pb::MODEL_SYMMETRY_NONE);
  EXPECT_EQ(milk.preferred_method(), pb::METHOD_PPF);
  EXPECT_EQ(milk.fallbacks_size(), 0);
  // The milk carton is about 20 cm tall.
  EXPECT_GT(milk.diameter_m(), 0.15);
  EXPECT_LT(milk.diameter_m(), 0.4);
  EXPECT_GT(milk.model_points(), 100u);
  const pb::ModelInfo& crayola = by_item["crayola_24_ct"];
  EXPECT_EQ(crayola.source(), pb::MODEL_SOURCE_SHAPE);
  EXPECT_EQ(crayola.symmetry(), pb::MODEL_SYMMETRY_BOX);
  ASSERT_EQ(crayola.fallbacks_size(), 1);
  EXPECT_EQ(crayola.fallbacks(0), pb::METHOD_RANGE_TEMPLATES);
}

// --- Bad requests ---------------------------------------------------------------------------

TEST_F(DetectorSceneTest, StreamWithoutParamsIsInvalid) {
  pb::DetectResponse response;
  const grpc::Status s = Detect({}, *chunks_, &response, /*send_params=*/false);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_NE(s.error_message().find("params"), std::string::npos) << s.error_message();
}

TEST_F(DetectorSceneTest, EmptyCloudIsInvalid) {
  pb::DetectResponse response;
  // No cloud at all.
  grpc::Status s = Detect(Query({"milk"}, pb::METHOD_PPF), {}, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  // A header announcing zero points.
  common::PointCloudChunk empty;
  empty.mutable_header()->set_frame_id("base");
  empty.mutable_header()->set_point_count(0);
  empty.mutable_header()->set_width(0);
  empty.mutable_header()->set_height(1);
  s = Detect(Query({"milk"}, pb::METHOD_PPF), {empty}, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  // Only NaN points.
  Scene nan;
  nan.width = 1000;
  nan.height = 1;
  nan.xyz.assign(3000, std::numeric_limits<float>::quiet_NaN());
  nan.rgb.assign(3000, 0);
  s = Detect(Query({"milk"}, pb::METHOD_PPF), ToChunks(nan, Transform()), &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  // Only infinite points were reported as "(all NaN)".
  Scene inf = nan;
  inf.xyz.assign(3000, std::numeric_limits<float>::infinity());
  s = Detect(Query({"milk"}, pb::METHOD_PPF), ToChunks(inf, Transform()), &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_NE(s.error_message().find("NaN or infinite"), std::string::npos) << s.error_message();
}

// A header of width = height = 0 with 11,825 points was taken as an unorganised cloud; the
// contract says point_count = width * height.
TEST_F(DetectorSceneTest, AHeaderWhoseShapeDisagreesWithItsPointCountIsInvalid) {
  std::vector<common::PointCloudChunk> chunks = *chunks_;
  chunks.front().mutable_header()->set_width(0);
  chunks.front().mutable_header()->set_height(0);
  pb::DetectResponse response;
  const grpc::Status s = Detect(Query({"milk"}, pb::METHOD_PPF), chunks, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_NE(s.error_message().find("width * height (0 * 0)"), std::string::npos)
      << s.error_message();
}

// Verify with a sensor pose at 1e308 m answered "KdTree: point 0 is not finite", naming no
// field of the request.
TEST_F(DetectorSceneTest, VerifyRefusesAHugeSensorPoseNamingTheField) {
  grpc::ClientContext ctx;
  pb::VerifyResponse response;
  auto writer = Stub()->Verify(&ctx, &response);
  pb::VerifyRequest request;
  request.mutable_params()->set_item("milk");
  *request.mutable_params()->mutable_x_frame_item() = ToPose(*X_BaseScene_);
  auto* sensor = request.mutable_params()->mutable_x_frame_sensor();
  sensor->mutable_orientation()->set_w(1.0);
  sensor->mutable_position()->set_z(1e308);
  writer->Write(request);
  const grpc::Status s = WriteChunksAndFinish<pb::VerifyRequest>(*writer, *chunks_);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_NE(s.error_message().find("params.X_frame_sensor.position"), std::string::npos)
      << s.error_message();
}

TEST_F(DetectorSceneTest, BrokenChunkStreamIsInvalid) {
  pb::DetectResponse response;
  // A chunk is missing: the runs do not tile the cloud.
  std::vector<common::PointCloudChunk> gap = *chunks_;
  gap.erase(gap.begin() + 1);
  grpc::Status s = Detect(Query({"milk"}, pb::METHOD_PPF), gap, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  // The last chunk is cut short.
  std::vector<common::PointCloudChunk> truncated = *chunks_;
  truncated.pop_back();
  s = Detect(Query({"milk"}, pb::METHOD_PPF), truncated, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  // Positions whose byte count does not match point_count.
  std::vector<common::PointCloudChunk> short_bytes = {chunks_->front()};
  short_bytes[0].mutable_positions()->resize(short_bytes[0].positions().size() - 4);
  s = Detect(Query({"milk"}, pb::METHOD_PPF), short_bytes, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
}

TEST_F(DetectorSceneTest, RegionOutsideTheCloudIsInvalid) {
  pb::DetectParams params = Query({"milk"}, pb::METHOD_PPF);
  auto* region = params.mutable_region();
  Transform far;
  far.t = {50.0, 50.0, 50.0};
  *region->mutable_x_frame_region() = ToPose(far);
  region->mutable_size_m()->set_x(0.3);
  region->mutable_size_m()->set_y(0.3);
  region->mutable_size_m()->set_z(0.3);
  pb::DetectResponse response;
  const grpc::Status s = Detect(params, *chunks_, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
}

// The sensor's intrinsics sent with the request (a commodity camera's): the milk is found with
// the Kinect's; impossible ones are refused naming the field, before any detection.
TEST_F(DetectorSceneTest, TheRequestCarriesTheCamerasIntrinsics) {
  pb::DetectParams params = Query({"milk"}, pb::METHOD_PPF);
  common::CameraIntrinsics* camera = params.mutable_camera();
  camera->set_width(640);
  camera->set_height(480);
  camera->set_fx(525.0);
  camera->set_fy(525.0);
  camera->set_cx(319.5);
  camera->set_cy(239.5);
  pb::DetectResponse response;
  grpc::Status s = Detect(params, *chunks_, &response);
  ASSERT_TRUE(s.ok()) << s.error_message();
  ASSERT_EQ(response.results_size(), 1);
  ASSERT_EQ(response.results(0).detections_size(), 1);
  EXPECT_LT(
      TranslationError(FromPose(response.results(0).detections(0).x_frame_item()), *X_BaseScene_),
      0.005);

  camera->set_fx(-1.0);
  s = Detect(params, *chunks_, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("params.camera"), std::string::npos) << s.error_message();
  camera->set_fx(525.0);
  for (int i = 0; i < 6; ++i) camera->add_distortion(0.01);
  s = Detect(params, *chunks_, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("params.camera.distortion"), std::string::npos)
      << s.error_message();
  camera->clear_distortion();
  camera->set_width(0);
  s = Detect(params, *chunks_, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
}

// --- The detector on simulated shelf-bin scans ------------------------------------------------
// picking-simulator lays out pick_layout_1 (seed 1), picking-scanner scans a bin from 0.55 m in
// front of its opening (the simulator renders the 42 Gray-code captures, the scanner decodes
// and triangulates them into the base frame), and the scan goes to picking-detector with the
// bin as region and the bundled model manifest data/detector/models.json. The simulator's
// ground truth judges the poses.

namespace sim = ::picking::simulator::v1;
namespace scan = ::picking::scanner::v1;

Transform Compose(const Transform& a, const Transform& b) {
  Transform out;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      out.R[r][c] = 0.0;
      for (int k = 0; k < 3; ++k) out.R[r][c] += a.R[r][k] * b.R[k][c];
    }
  }
  out.t = a.Apply(b.t);
  return out;
}

Transform Inverse(const Transform& a) {
  Transform out;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) out.R[r][c] = a.R[c][r];
  }
  const std::array<double, 3> t = out.Rotate(a.t);
  out.t = {-t[0], -t[1], -t[2]};
  return out;
}

std::array<double, 3> Normalized(const std::array<double, 3>& v) {
  const double n = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  return {v[0] / n, v[1] / n, v[2] / n};
}

std::array<double, 3> Cross(const std::array<double, 3>& a, const std::array<double, 3>& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

// Angle between the item frames' axes, up to the half turns of a box (about x, y or z).
double BoxRotationErrorRad(const Transform& a, const Transform& b) {
  double best = RotationErrorRad(a, b);
  for (int axis = 0; axis < 3; ++axis) {
    Transform flipped = b;
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) flipped.R[r][c] = c == axis ? b.R[r][c] : -b.R[r][c];
    }
    best = std::min(best, RotationErrorRad(a, flipped));
  }
  return best;
}

// Angle between the item frames' x axes (a cylinder along x), either direction.
double AxisErrorRad(const Transform& a, const Transform& b) {
  double dot = 0.0;
  for (int r = 0; r < 3; ++r) dot += a.R[r][0] * b.R[r][0];
  return std::acos(std::min(1.0, std::abs(dot)));
}

class DetectorBinScanTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    for (const char* name : {"picking-simulator", "picking-scanner"}) {
      ASSERT_TRUE(std::filesystem::exists(ServerBinary(name)))
          << ServerBinary(name) << " is missing: build the " << name << " target";
    }
    layout_ = new std::string(
        ReadText(std::string(PICKING_DATA_DIR) + "/apc2016/tasks/pick_layout_1.json"));
    simulator_ = new ServerProcess(ServerBinary("picking-simulator"));
    sim_stub_ = sim::SimulatorService::NewStub(simulator_->Channel()).release();
    LoadLayout(*layout_);
    sim::GetCellResponse cell;
    {
      grpc::ClientContext ctx;
      ASSERT_TRUE(sim_stub_->GetCell(&ctx, sim::GetCellRequest(), &cell).ok());
    }
    bins_ = new std::map<int, sim::BinInfo>();
    for (const auto& b : cell.bins()) (*bins_)[b.bin()] = b;

    dir_ = new std::string(::testing::TempDir() + "/detector_bin_scan_test");
    std::filesystem::remove_all(*dir_);
    std::filesystem::create_directories(*dir_ + "/calibration");
    scanner_ = new ServerProcess(
        ServerBinary("picking-scanner"),
        {"--sim.address=" + simulator_->address(), "--calibration.dir=" + *dir_ + "/calibration"});
    scan_stub_ = scan::ScannerService::NewStub(scanner_->Channel()).release();
    scan::GetCalibrationResponse calibration;
    {
      grpc::ClientContext ctx;
      ASSERT_TRUE(
          scan_stub_->GetCalibration(&ctx, scan::GetCalibrationRequest(), &calibration).ok());
    }
    X_ToolCamera_ = new Transform(FromPose(calibration.calibration().x_tool_camera()));
    // The tests run beside others on few cores: budgets judged on a clock that stands still
    // keep the detector's search that of a quiet machine (benchmarks/detector_eval measures
    // the time of a call).
    detector_ = new ServerProcess(ServerBinary(kBinary),
                                  {"--cache_dir=" + *dir_ + "/cache", "--budget_clock=frozen"});
  }

  static void TearDownTestSuite() {
    for (ServerProcess* server : {detector_, scanner_, simulator_}) {
      if (server != nullptr) {
        EXPECT_EQ(server->Stop(), 0);
      }
      delete server;
    }
    detector_ = scanner_ = simulator_ = nullptr;
    delete sim_stub_;
    delete scan_stub_;
    delete bins_;
    delete X_ToolCamera_;
    delete layout_;
    if (dir_ != nullptr) std::filesystem::remove_all(*dir_);
    delete dir_;
  }

  static void LoadLayout(const std::string& task_json) {
    grpc::ClientContext ctx;
    sim::LoadLayoutRequest request;
    request.set_task_json(task_json);
    request.set_seed(1);
    sim::LoadLayoutResponse response;
    const grpc::Status status = sim_stub_->LoadLayout(&ctx, request, &response);
    ASSERT_TRUE(status.ok()) << status.error_message();
  }

  // True poses of `item` in `bin`, from the simulator.
  static std::vector<Transform> TruePoses(common::Container bin, const std::string& item) {
    grpc::ClientContext ctx;
    sim::GetGroundTruthResponse truth;
    EXPECT_TRUE(sim_stub_->GetGroundTruth(&ctx, sim::GetGroundTruthRequest(), &truth).ok());
    std::vector<Transform> out;
    for (const auto& s : truth.items()) {
      if (s.container() == bin && s.item().name() == item) out.push_back(FromPose(s.x_base_item()));
    }
    return out;
  }

  static Transform X_BaseBin(common::Container bin) {
    return FromPose(bins_->at(bin).x_base_bin());
  }
  static std::array<double, 3> BinSize(common::Container bin) {
    const auto& s = bins_->at(bin).size_m();
    return {s.x(), s.y(), s.z()};
  }

  // The camera 0.55 m in front of the bin's opening (+x of the bin frame), `lateral_m` to the
  // side and `height_m` above its centre, looking at the middle of its floor.
  static Transform CameraPose(common::Container bin, double lateral_m = 0.0,
                              double height_m = 0.1) {
    const std::array<double, 3> size = BinSize(bin);
    const std::array<double, 3> target{0.0, 0.0, -0.5 * size[2] + 0.03};
    const std::array<double, 3> eye{0.5 * size[0] + 0.55, lateral_m, height_m};
    const std::array<double, 3> z =
        Normalized({target[0] - eye[0], target[1] - eye[1], target[2] - eye[2]});
    const std::array<double, 3> x = Normalized(Cross({0.0, 0.0, -1.0}, z));
    const std::array<double, 3> y = Cross(z, x);
    Transform X_BinCamera;
    for (int r = 0; r < 3; ++r) X_BinCamera.R[r] = {x[r], y[r], z[r]};
    X_BinCamera.t = eye;
    return Compose(X_BaseBin(bin), X_BinCamera);
  }

  // Scans `bin` from each camera pose (default: the one CameraPose); the scanner stacks the
  // views' organised clouds. The chunks are ready for Detect (the header carries the first
  // view's sensor pose).
  static std::vector<common::PointCloudChunk> ScanBin(common::Container bin,
                                                      std::vector<Transform> cameras = {}) {
    if (cameras.empty()) cameras.push_back(CameraPose(bin));
    const Transform X_BaseCamera = cameras.front();
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(240));
    scan::ScanRequest request;
    for (const Transform& X : cameras) {
      *request.add_views()->mutable_x_base_tool() = ToPose(Compose(X, Inverse(*X_ToolCamera_)));
    }
    request.set_frame_id("base");
    request.set_with_normals(true);
    request.set_with_intensities(true);
    request.mutable_decode()->set_min_neighbours(3);
    auto reader = scan_stub_->Scan(&ctx, request);
    std::vector<common::PointCloudChunk> chunks;
    scan::ScanResponse response;
    while (reader->Read(&response)) {
      if (response.has_cloud()) chunks.push_back(response.cloud());
    }
    const grpc::Status status = reader->Finish();
    EXPECT_TRUE(status.ok()) << status.error_message();
    if (!chunks.empty()) {
      *chunks.front().mutable_header()->mutable_x_frame_sensor() = ToPose(X_BaseCamera);
    }
    return chunks;
  }

  static pb::DetectParams BinQuery(common::Container bin, const std::string& item,
                                   pb::Method method = pb::METHOD_UNSPECIFIED) {
    pb::DetectParams params;
    auto* q = params.add_queries();
    q->set_item(item);
    q->set_method(method);
    *params.mutable_region()->mutable_x_frame_region() = ToPose(X_BaseBin(bin));
    const std::array<double, 3> size = BinSize(bin);
    params.mutable_region()->mutable_size_m()->set_x(size[0]);
    params.mutable_region()->mutable_size_m()->set_y(size[1]);
    params.mutable_region()->mutable_size_m()->set_z(size[2]);
    params.mutable_region()->set_wall_margin_m(0.01);
    return params;
  }

  static grpc::Status Detect(const pb::DetectParams& params,
                             const std::vector<common::PointCloudChunk>& chunks,
                             pb::DetectResponse* response) {
    auto stub = pb::DetectorService::NewStub(detector_->Channel());
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
    auto writer = stub->Detect(&ctx, response);
    pb::DetectRequest first;
    *first.mutable_params() = params;
    writer->Write(first);
    return WriteChunksAndFinish<pb::DetectRequest>(*writer, chunks);
  }

  static double Diameter(const std::string& item) {
    auto stub = pb::DetectorService::NewStub(detector_->Channel());
    grpc::ClientContext ctx;
    pb::ListModelsResponse models;
    EXPECT_TRUE(stub->ListModels(&ctx, pb::ListModelsRequest(), &models).ok());
    for (const auto& m : models.models()) {
      if (m.item() == item && m.diameter_m() > 0.0) return m.diameter_m();
    }
    ADD_FAILURE() << item << " has no built model";
    return 0.0;
  }

  // Detects `item` in a scan of `bin` (from `cameras`, default the one CameraPose; several are
  // stacked views, each camera's pose then in X_frame_sensor) and checks it against the
  // simulator's ground truth.
  static void ExpectFound(common::Container bin, const std::string& item, bool cylinder,
                          pb::Method method = pb::METHOD_UNSPECIFIED,
                          const std::vector<Transform>& cameras = {}) {
    const std::vector<common::PointCloudChunk> chunks = ScanBin(bin, cameras);
    ASSERT_FALSE(chunks.empty());
    pb::DetectParams params = BinQuery(bin, item, method);
    if (cameras.size() > 1) {
      for (const Transform& X : cameras) *params.add_x_frame_sensor() = ToPose(X);
    }
    pb::DetectResponse response;
    const grpc::Status status = Detect(params, chunks, &response);
    ASSERT_TRUE(status.ok()) << status.error_message();
    ASSERT_EQ(response.results_size(), 1);
    const pb::ItemResult& result = response.results(0);
    EXPECT_EQ(result.status().code(), 0) << result.status().message();
    ASSERT_GE(result.detections_size(), 1) << item << " not found";
    EXPECT_LT(response.points_after_preprocessing(), response.points_received());
    const pb::Detection& d = result.detections(0);
    if (method != pb::METHOD_UNSPECIFIED) {
      EXPECT_EQ(d.method(), method);
    }
    const Transform X_found = FromPose(d.x_frame_item());
    const std::vector<Transform> truth = TruePoses(bin, item);
    ASSERT_FALSE(truth.empty());
    double translation = 1e9, rotation = 1e9;
    for (const Transform& X_true : truth) {
      if (TranslationError(X_found, X_true) < translation) {
        translation = TranslationError(X_found, X_true);
        rotation = cylinder ? AxisErrorRad(X_found, X_true) : BoxRotationErrorRad(X_found, X_true);
      }
    }
    const double diameter = Diameter(item);
    EXPECT_LT(translation, 0.1 * diameter) << item;
    EXPECT_LT(rotation, 10.0 * kPi / 180.0) << item;
    EXPECT_GT(d.score(), 0.5);
    std::cout << item << " (" << pb::Method_Name(d.method()) << "): " << translation * 1000
              << " mm, " << rotation * 180.0 / kPi << " deg from the truth, score " << d.score()
              << ", " << response.points_after_preprocessing() << " of "
              << response.points_received() << " points in the bin, " << d.timings().total_s()
              << " s\n";
  }

  static std::string* layout_;
  static std::string* dir_;
  static ServerProcess* simulator_;
  static ServerProcess* scanner_;
  static ServerProcess* detector_;
  static sim::SimulatorService::Stub* sim_stub_;
  static scan::ScannerService::Stub* scan_stub_;
  static std::map<int, sim::BinInfo>* bins_;
  static Transform* X_ToolCamera_;
};
std::string* DetectorBinScanTest::layout_ = nullptr;
std::string* DetectorBinScanTest::dir_ = nullptr;
ServerProcess* DetectorBinScanTest::simulator_ = nullptr;
ServerProcess* DetectorBinScanTest::scanner_ = nullptr;
ServerProcess* DetectorBinScanTest::detector_ = nullptr;
sim::SimulatorService::Stub* DetectorBinScanTest::sim_stub_ = nullptr;
scan::ScannerService::Stub* DetectorBinScanTest::scan_stub_ = nullptr;
std::map<int, sim::BinInfo>* DetectorBinScanTest::bins_ = nullptr;
Transform* DetectorBinScanTest::X_ToolCamera_ = nullptr;

TEST_F(DetectorBinScanTest, FindsTheTissueBoxInBinA) {
  ExpectFound(common::CONTAINER_BIN_A, "kleenex_tissue_box", /*cylinder=*/false);
}

// The tissue box's print: Detect reports how well it fits, and Verify, given the true pose
// turned by half a turn about the box's short axis (the same shape), reports the turn whose
// print fits: the true one.
TEST_F(DetectorBinScanTest, VerifyReportsTheTurnOfTheTissueBoxWhosePrintFits) {
  const std::vector<common::PointCloudChunk> chunks = ScanBin(common::CONTAINER_BIN_A);
  ASSERT_FALSE(chunks.empty());
  const std::vector<Transform> truth = TruePoses(common::CONTAINER_BIN_A, "kleenex_tissue_box");
  ASSERT_EQ(truth.size(), 1u);
  auto stub = pb::DetectorService::NewStub(detector_->Channel());
  const auto verify = [&](const Transform& X, pb::VerifyResponse* response) {
    return StreamVerify(*stub, "kleenex_tissue_box", X, chunks, response);
  };
  pb::VerifyResponse at_truth;
  ASSERT_TRUE(verify(truth[0], &at_truth).ok());
  ASSERT_TRUE(at_truth.has_appearance());
  EXPECT_GT(at_truth.appearance(), 0.5);
  EXPECT_GT(at_truth.score(), 0.5);
  EXPECT_LT(RotationErrorRad(FromPose(at_truth.x_frame_item_appearance()), truth[0]),
            2.0 * kPi / 180.0);

  Transform turned = truth[0];  // Half a turn about the item's z axis.
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 2; ++c) turned.R[r][c] = -truth[0].R[r][c];
  }
  pb::VerifyResponse at_turned;
  ASSERT_TRUE(verify(turned, &at_turned).ok());
  ASSERT_TRUE(at_turned.has_appearance());
  EXPECT_GT(at_turned.appearance(), 0.5);  // Of the fitting turn (sampled a little apart).
  EXPECT_LT(RotationErrorRad(FromPose(at_turned.x_frame_item_appearance()), truth[0]),
            2.0 * kPi / 180.0);
}

TEST_F(DetectorBinScanTest, FindsThePaperTowelsInBinD) {
  ExpectFound(common::CONTAINER_BIN_D, "kleenex_paper_towels", /*cylinder=*/true);
}

TEST_F(DetectorBinScanTest, RangeTemplatesFindThePaperTowelsInBinD) {
  ExpectFound(common::CONTAINER_BIN_D, "kleenex_paper_towels", /*cylinder=*/true,
              pb::METHOD_RANGE_TEMPLATES);
}

// The same layout without the tissue box in bin A: nothing is reported there, not even
// with the item's whole chain, and the call is still OK.
TEST_F(DetectorBinScanTest, ReportsNothingForAnItemThatIsNotInTheBin) {
  std::string layout = *layout_;
  const std::string bin_a = "\"kleenex_tissue_box\",";
  const std::size_t at = layout.find(bin_a);
  ASSERT_NE(at, std::string::npos);
  layout.erase(at, bin_a.size());
  const std::string order = "\"item\": \"kleenex_tissue_box\"";
  const std::size_t order_at = layout.find(order);
  ASSERT_NE(order_at, std::string::npos);
  layout.replace(order_at, order.size(), "\"item\": \"creativity_chenille_stems\"");
  LoadLayout(layout);
  ASSERT_TRUE(TruePoses(common::CONTAINER_BIN_A, "kleenex_tissue_box").empty());
  const std::vector<common::PointCloudChunk> chunks = ScanBin(common::CONTAINER_BIN_A);
  LoadLayout(*layout_);
  ASSERT_FALSE(chunks.empty());
  pb::DetectResponse response;
  const grpc::Status status =
      Detect(BinQuery(common::CONTAINER_BIN_A, "kleenex_tissue_box"), chunks, &response);
  ASSERT_TRUE(status.ok()) << status.error_message();
  ASSERT_EQ(response.results_size(), 1);
  EXPECT_EQ(response.results(0).status().code(), 0);
  EXPECT_EQ(response.results(0).detections_size(), 0);
  EXPECT_GE(response.results(0).methods_tried_size(), 1);
}

// Three views of the bin (the middle one and 0.15 m to either side, 0.25 m above the bin's
// middle), stacked by the scanner: the detector takes each view's sensor pose, compensates
// each view's shading and verifies from all three.
TEST_F(DetectorBinScanTest, FindsTheTissueBoxInThreeStackedViews) {
  const common::Container bin = common::CONTAINER_BIN_A;
  ExpectFound(bin, "kleenex_tissue_box", /*cylinder=*/false, pb::METHOD_UNSPECIFIED,
              {CameraPose(bin), CameraPose(bin, -0.15, 0.25), CameraPose(bin, 0.15, 0.25)});
}

TEST_F(DetectorBinScanTest, RejectsViewPosesThatDoNotFitTheStackedViews) {
  const common::Container bin = common::CONTAINER_BIN_A;
  const std::vector<Transform> cameras = {CameraPose(bin), CameraPose(bin, 0.15, 0.25)};
  const std::vector<common::PointCloudChunk> chunks = ScanBin(bin, cameras);
  ASSERT_FALSE(chunks.empty());
  pb::DetectResponse response;
  // Three poses for two stacked views.
  pb::DetectParams params = BinQuery(bin, "kleenex_tissue_box");
  for (const Transform& X : {cameras[0], cameras[1], cameras[1]}) {
    *params.add_x_frame_sensor() = ToPose(X);
  }
  grpc::Status status = Detect(params, chunks, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("multiple of the view count"), std::string::npos)
      << status.error_message();
  // A pose that is not a rotation.
  params = BinQuery(bin, "kleenex_tissue_box");
  for (const Transform& X : cameras) *params.add_x_frame_sensor() = ToPose(X);
  params.mutable_x_frame_sensor(1)->mutable_orientation()->set_w(5.0);
  status = Detect(params, chunks, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("X_frame_sensor[1]"), std::string::npos)
      << status.error_message();
}

TEST_F(DetectorBinScanTest, RejectsBadRegionsAndReportsUnknownItems) {
  const std::vector<common::PointCloudChunk> chunks = ScanBin(common::CONTAINER_BIN_D);
  ASSERT_FALSE(chunks.empty());
  pb::DetectResponse response;
  // Another bin's region holds no point of this scan.
  EXPECT_EQ(Detect(BinQuery(common::CONTAINER_BIN_L, "kleenex_paper_towels"), chunks, &response)
                .error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
  pb::DetectParams params = BinQuery(common::CONTAINER_BIN_D, "kleenex_paper_towels");
  params.mutable_region()->set_wall_margin_m(-0.01);
  EXPECT_EQ(Detect(params, chunks, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  params = BinQuery(common::CONTAINER_BIN_D, "kleenex_paper_towels");
  params.mutable_region()->mutable_size_m()->set_y(0.0);
  EXPECT_EQ(Detect(params, chunks, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  // An unknown item fails alone.
  response.Clear();
  params = BinQuery(common::CONTAINER_BIN_D, "no_such_item");
  ASSERT_TRUE(Detect(params, chunks, &response).ok());
  ASSERT_EQ(response.results_size(), 1);
  EXPECT_EQ(response.results(0).status().code(), grpc::StatusCode::NOT_FOUND);
}

}  // namespace
}  // namespace picking::testing
