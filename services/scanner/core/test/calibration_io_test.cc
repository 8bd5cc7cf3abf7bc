#include "services/scanner/core/calibration_io.h"

#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

namespace picking::scanner {
namespace {

namespace fs = std::filesystem;

class CalibrationIoTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("calibration_io_test_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string Path(const std::string& name) const { return (dir_ / name).string(); }

  static std::string Read(const std::string& path) {
    std::ifstream in(path);
    std::stringstream s;
    s << in.rdbuf();
    return s.str();
  }
  static void Write(const std::string& path, const std::string& text) {
    std::ofstream(path) << text;
  }

  static IntrinsicsFile SampleIntrinsics() {
    IntrinsicsFile file;
    file.intrinsics.width = 1280;
    file.intrinsics.height = 1024;
    file.intrinsics.fx = 1450.5;
    file.intrinsics.fy = 1451.25;
    file.intrinsics.cx = 640.125;
    file.intrinsics.cy = 511.75;
    file.intrinsics.distortion = {-0.08, 0.05, 0.001, -0.002, 0.0};
    file.info.timestamp_utc = "2016-07-01T12:00:00Z";
    file.info.error = 0.21;
    return file;
  }

  fs::path dir_;
};

// Expects `f` to throw std::runtime_error whose message holds every string of `parts`.
template <typename F>
void ExpectErrorMentions(F f, std::initializer_list<std::string> parts) {
  try {
    f();
    FAIL() << "expected an error";
  } catch (const std::runtime_error& e) {
    for (const std::string& part : parts) {
      EXPECT_NE(std::string(e.what()).find(part), std::string::npos)
          << "'" << e.what() << "' does not mention '" << part << "'";
    }
  }
}

TEST_F(CalibrationIoTest, IntrinsicsRoundTrip) {
  const IntrinsicsFile saved = SampleIntrinsics();
  for (CalibrationKind kind :
       {CalibrationKind::kCameraIntrinsics, CalibrationKind::kProjectorIntrinsics}) {
    const std::string path = Path(CalibrationKindName(kind) + ".json");
    SaveIntrinsics(path, kind, saved);
    const IntrinsicsFile loaded = LoadIntrinsics(path, kind);
    EXPECT_EQ(loaded.intrinsics.width, 1280u);
    EXPECT_EQ(loaded.intrinsics.height, 1024u);
    EXPECT_DOUBLE_EQ(loaded.intrinsics.fx, saved.intrinsics.fx);
    EXPECT_DOUBLE_EQ(loaded.intrinsics.fy, saved.intrinsics.fy);
    EXPECT_DOUBLE_EQ(loaded.intrinsics.cx, saved.intrinsics.cx);
    EXPECT_DOUBLE_EQ(loaded.intrinsics.cy, saved.intrinsics.cy);
    for (int i = 0; i < 5; ++i) {
      EXPECT_DOUBLE_EQ(loaded.intrinsics.distortion[i], saved.intrinsics.distortion[i]);
    }
    EXPECT_EQ(loaded.info.timestamp_utc, "2016-07-01T12:00:00Z");
    EXPECT_DOUBLE_EQ(loaded.info.error, 0.21);
    EXPECT_NE(Read(path).find("\"format_version\": 1"), std::string::npos);
  }
}

TEST_F(CalibrationIoTest, PoseRoundTripForEveryPoseKind) {
  PoseFile saved;
  saved.pose = Eigen::Isometry3d::Identity();
  saved.pose.linear() =
      Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
  saved.pose.translation() = Eigen::Vector3d(0.12, -0.03, 0.4);
  saved.info.error = 0.0012;
  saved.info.error_unit = "m";
  for (CalibrationKind kind : {CalibrationKind::kCameraProjectorExtrinsics,
                               CalibrationKind::kHandEye, CalibrationKind::kShelfPose}) {
    const std::string path = Path(CalibrationKindName(kind) + ".json");
    SavePose(path, kind, saved);
    const PoseFile loaded = LoadPose(path, kind);
    EXPECT_TRUE(loaded.pose.isApprox(saved.pose, 1e-12));
    EXPECT_EQ(loaded.info.error_unit, "m");
    EXPECT_FALSE(loaded.info.timestamp_utc.empty());  // filled with the time of saving
  }
}

TEST_F(CalibrationIoTest, WrongKindIsRejected) {
  const std::string path = Path("camera.json");
  SaveIntrinsics(path, CalibrationKind::kCameraIntrinsics, SampleIntrinsics());
  ExpectErrorMentions([&] { LoadIntrinsics(path, CalibrationKind::kProjectorIntrinsics); },
                      {path, "kind", "projector_intrinsics"});
  EXPECT_THROW(LoadPose(path, CalibrationKind::kHandEye), std::runtime_error);
}

TEST_F(CalibrationIoTest, WrongVersionIsRejected) {
  const std::string path = Path("camera.json");
  SaveIntrinsics(path, CalibrationKind::kCameraIntrinsics, SampleIntrinsics());
  std::string text = Read(path);
  text.replace(text.find("\"format_version\": 1"), 19, "\"format_version\": 2");
  Write(path, text);
  ExpectErrorMentions([&] { LoadIntrinsics(path, CalibrationKind::kCameraIntrinsics); },
                      {path, "format_version"});
}

TEST_F(CalibrationIoTest, MissingOrBadFieldIsNamed) {
  const std::string path = Path("camera.json");
  SaveIntrinsics(path, CalibrationKind::kCameraIntrinsics, SampleIntrinsics());
  const std::string original = Read(path);
  std::string text = original;
  text.replace(text.find("\"fy\""), 4, "\"fz\"");
  Write(path, text);
  ExpectErrorMentions([&] { LoadIntrinsics(path, CalibrationKind::kCameraIntrinsics); },
                      {path, "values.fy", "missing"});
  text = original;
  text.replace(text.find("\"width\": 1280"), 13, "\"width\": -5");
  Write(path, text);
  ExpectErrorMentions([&] { LoadIntrinsics(path, CalibrationKind::kCameraIntrinsics); },
                      {"values.width"});
  Write(path, "{ not json");
  ExpectErrorMentions([&] { LoadIntrinsics(path, CalibrationKind::kCameraIntrinsics); },
                      {path, "JSON"});
  ExpectErrorMentions(
      [&] { LoadIntrinsics(Path("absent.json"), CalibrationKind::kCameraIntrinsics); },
      {"absent.json"});
}

TEST_F(CalibrationIoTest, FailedSaveKeepsThePreviousFile) {
  const std::string path = Path("camera.json");
  SaveIntrinsics(path, CalibrationKind::kCameraIntrinsics, SampleIntrinsics());
  const std::string before = Read(path);
  IntrinsicsFile bad = SampleIntrinsics();
  bad.intrinsics.fx = -1.0;  // a failed calibration
  EXPECT_THROW(SaveIntrinsics(path, CalibrationKind::kCameraIntrinsics, bad),
               std::invalid_argument);
  EXPECT_EQ(Read(path), before);
  // Unwritable destination folder: the error names the file, no temporary is left behind.
  EXPECT_THROW(SaveIntrinsics(Path("missing_dir/camera.json"), CalibrationKind::kCameraIntrinsics,
                              SampleIntrinsics()),
               std::runtime_error);
  int files = 0;
  for (const auto& entry : fs::directory_iterator(dir_)) {
    (void)entry;
    ++files;
  }
  EXPECT_EQ(files, 1);
  // Saving over the file replaces it completely.
  IntrinsicsFile changed = SampleIntrinsics();
  changed.intrinsics.fx = 1500.0;
  SaveIntrinsics(path, CalibrationKind::kCameraIntrinsics, changed);
  EXPECT_DOUBLE_EQ(LoadIntrinsics(path, CalibrationKind::kCameraIntrinsics).intrinsics.fx, 1500.0);
}

TEST_F(CalibrationIoTest, NonRigidPoseIsNotSaved) {
  PoseFile bad;
  bad.pose.linear() *= 2.0;
  EXPECT_THROW(SavePose(Path("pose.json"), CalibrationKind::kHandEye, bad), std::invalid_argument);
  EXPECT_FALSE(fs::exists(Path("pose.json")));
}

}  // namespace
}  // namespace picking::scanner
