#include "services/scanner/core/replay_camera.h"

#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>
#include <fstream>

namespace picking::scanner {
namespace {

namespace fs = std::filesystem;

class ReplayCameraTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("replay_camera_test_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  void WriteImage(const std::string& name, std::uint32_t w, std::uint32_t h, std::uint8_t value) {
    GrayImage image(w, h, value);
    image.at(0, 0) = static_cast<std::uint8_t>(value + 1);
    WriteGrayImage((dir_ / name).string(), image);
  }

  fs::path dir_;
};

TEST_F(ReplayCameraTest, PlaysImagesInNameOrder) {
  WriteImage("frame_002.png", 16, 8, 20);
  WriteImage("frame_000.png", 16, 8, 0);
  WriteImage("frame_001.png", 16, 8, 10);
  std::ofstream((dir_ / "notes.txt").string()) << "not an image";
  ReplayCamera camera(dir_.string());
  EXPECT_EQ(camera.image_count(), 3u);
  EXPECT_EQ(camera.width(), 16u);
  EXPECT_EQ(camera.height(), 8u);
  camera.Configure({});
  std::vector<Frame> frames = camera.Capture(2);
  ASSERT_EQ(frames.size(), 2u);
  EXPECT_EQ(frames[0].image.at(5, 5), 0);
  EXPECT_EQ(frames[0].image.at(0, 0), 1);
  EXPECT_EQ(frames[1].image.at(5, 5), 10);
  EXPECT_EQ(frames[0].frame_id, 0u);
  EXPECT_EQ(frames[1].frame_id, 1u);
  // Only one image is left: asking for two fails and consumes nothing.
  EXPECT_THROW(camera.Capture(2), CameraTimeoutError);
  EXPECT_EQ(camera.next_index(), 2u);
  frames = camera.Capture(1);
  EXPECT_EQ(frames[0].image.at(5, 5), 20);
  camera.Rewind();
  EXPECT_EQ(camera.Capture(1)[0].image.at(5, 5), 0);
  EXPECT_THROW(camera.Capture(0), std::invalid_argument);
}

TEST_F(ReplayCameraTest, MixedSizesNameTheFile) {
  WriteImage("a.png", 16, 8, 0);
  WriteImage("b.png", 8, 8, 0);
  try {
    ReplayCamera camera(dir_.string());
    FAIL() << "expected an error";
  } catch (const CameraError& e) {
    EXPECT_NE(std::string(e.what()).find("b.png"), std::string::npos) << e.what();
  }
}

TEST_F(ReplayCameraTest, EmptyOrMissingFolderIsAnError) {
  EXPECT_THROW(ReplayCamera(dir_.string()), CameraError);
  EXPECT_THROW(ReplayCamera((dir_ / "missing").string()), CameraError);
  std::ofstream((dir_ / "broken.png").string()) << "not a png";
  try {
    ReplayCamera camera(dir_.string());
    FAIL() << "expected an error";
  } catch (const CameraError& e) {
    EXPECT_NE(std::string(e.what()).find("broken.png"), std::string::npos) << e.what();
  }
}

TEST_F(ReplayCameraTest, BadSettingsAreRejected) {
  WriteImage("a.png", 4, 4, 0);
  ReplayCamera camera(dir_.string());
  CameraSettings settings;
  settings.frame_timeout_s = 0.0;
  EXPECT_THROW(camera.Configure(settings), std::invalid_argument);
}

TEST(CameraBackendTest, DroppedFramesAreDetected) {
  std::vector<Frame> frames(3);
  frames[0].frame_id = 7;
  frames[1].frame_id = 8;
  frames[2].frame_id = 9;
  EXPECT_NO_THROW(CheckConsecutiveFrameIds(frames));
  frames[2].frame_id = 11;
  try {
    CheckConsecutiveFrameIds(frames);
    FAIL() << "expected an error";
  } catch (const DroppedFrameError& e) {
    EXPECT_NE(std::string(e.what()).find("11"), std::string::npos) << e.what();
  }
  EXPECT_NO_THROW(CheckConsecutiveFrameIds(std::vector<Frame>{}));
  // The id list form: a frame taken again after an incomplete one keeps the count going.
  EXPECT_NO_THROW(CheckConsecutiveFrameIds(std::vector<std::uint64_t>{4, 5, 6}));
  EXPECT_THROW(CheckConsecutiveFrameIds(std::vector<std::uint64_t>{4, 6}), DroppedFrameError);
}

// GigE Vision 1.x block ids are 16 bit and skip 0: 65535 is followed by 1.
TEST(CameraBackendTest, SixteenBitFrameCounterWrapsWithoutALoss) {
  std::vector<Frame> frames(3);
  frames[0].frame_id = 65534;
  frames[1].frame_id = 65535;
  frames[2].frame_id = 1;
  EXPECT_NO_THROW(CheckConsecutiveFrameIds(frames));
  frames[2].frame_id = 2;  // Frame 1 lost across the wrap.
  EXPECT_THROW(CheckConsecutiveFrameIds(frames), DroppedFrameError);
  frames[2].frame_id = 0;
  EXPECT_THROW(CheckConsecutiveFrameIds(frames), DroppedFrameError);
}

// A recording that lost a frame replays the loss: ids come from the file names.
TEST_F(ReplayCameraTest, FrameIdsFollowTheNumbersInTheFileNames) {
  for (const char* name : {"frame_007.png", "frame_008.png", "frame_010.png", "frame_011.png"}) {
    WriteImage(name, 16, 8, 0);
  }
  ReplayCamera camera(dir_.string());
  camera.Configure({});
  const std::vector<Frame> first = camera.Capture(2);
  EXPECT_EQ(first[0].frame_id, 7u);
  EXPECT_EQ(first[1].frame_id, 8u);
  camera.Rewind();
  try {
    camera.Capture(3);
    FAIL() << "expected a dropped frame";
  } catch (const DroppedFrameError& e) {
    EXPECT_NE(std::string(e.what()).find("expected 9"), std::string::npos) << e.what();
  }
  EXPECT_EQ(camera.next_index(), 3u);  // Consumed, as a camera's frames would be.
  EXPECT_EQ(camera.Capture(1)[0].frame_id, 11u);
}

TEST_F(ReplayCameraTest, NamesWithoutNumbersGiveIndices) {
  WriteImage("a.png", 16, 8, 0);
  WriteImage("b7.png", 16, 8, 0);
  ReplayCamera camera(dir_.string());
  camera.Configure({});
  const std::vector<Frame> frames = camera.Capture(2);
  EXPECT_EQ(frames[0].frame_id, 0u);
  EXPECT_EQ(frames[1].frame_id, 1u);
}

TEST_F(ReplayCameraTest, ArmingChangesNothingAndChecksItsCount) {
  WriteImage("frame_000.png", 16, 8, 0);
  WriteImage("frame_001.png", 16, 8, 10);
  ReplayCamera camera(dir_.string());
  camera.Configure({});
  camera.Arm(2);
  EXPECT_EQ(camera.next_index(), 0u);
  EXPECT_EQ(camera.Capture(2)[1].image.at(5, 5), 10);
  EXPECT_THROW(camera.Arm(0), std::invalid_argument);
}

}  // namespace
}  // namespace picking::scanner
