#include "services/scanner/core/aravis_camera.h"

#include <gtest/gtest.h>

#include <algorithm>

namespace picking::scanner {
namespace {

class AravisCameraTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { fake_id_ = EnableAravisFakeCamera(); }
  static std::string fake_id_;
};

std::string AravisCameraTest::fake_id_;

TEST_F(AravisCameraTest, FakeCameraIsListed) {
  const std::vector<std::string> ids = ListAravisCameras();
  EXPECT_NE(std::find(ids.begin(), ids.end(), fake_id_), ids.end());
}

TEST_F(AravisCameraTest, CapturesConsecutiveMono8FramesFreeRunning) {
  AravisCamera camera(fake_id_, 8);
  EXPECT_EQ(camera.device_id(), fake_id_);
  ASSERT_GT(camera.width(), 0u);
  ASSERT_GT(camera.height(), 0u);
  CameraSettings settings;
  settings.trigger_mode = TriggerMode::kFreeRun;
  settings.exposure_us = 20000.0;
  settings.frame_timeout_s = 5.0;
  camera.Configure(settings);
  const std::vector<Frame> frames = camera.Capture(3);
  ASSERT_EQ(frames.size(), 3u);
  for (const Frame& frame : frames) {
    EXPECT_EQ(frame.image.width, camera.width());
    EXPECT_EQ(frame.image.height, camera.height());
    EXPECT_EQ(frame.image.pixels.size(),
              static_cast<std::size_t>(camera.width()) * camera.height());
    // The fake camera renders a diagonal ramp: not a constant image.
    const auto [lo, hi] = std::minmax_element(frame.image.pixels.begin(), frame.image.pixels.end());
    EXPECT_LT(*lo, *hi);
  }
  EXPECT_EQ(frames[1].frame_id, frames[0].frame_id + 1);
  EXPECT_EQ(frames[2].frame_id, frames[1].frame_id + 1);
  // A second capture works too.
  EXPECT_EQ(camera.Capture(2).size(), 2u);
}

TEST_F(AravisCameraTest, SoftwareTriggeredCapture) {
  AravisCamera camera(fake_id_, 8);
  CameraSettings settings;
  settings.trigger_mode = TriggerMode::kSoftware;
  settings.exposure_us = 1000.0;
  settings.frame_timeout_s = 5.0;
  camera.Configure(settings);
  const std::vector<Frame> frames = camera.Capture(2);
  ASSERT_EQ(frames.size(), 2u);
  EXPECT_EQ(frames[1].frame_id, frames[0].frame_id + 1);
}

TEST_F(AravisCameraTest, ErrorsAreClear) {
  try {
    AravisCamera camera("No-Such-Camera-42");
    FAIL() << "expected an error";
  } catch (const CameraError& e) {
    EXPECT_NE(std::string(e.what()).find("No-Such-Camera-42"), std::string::npos) << e.what();
  }
  AravisCamera camera(fake_id_, 4);
  EXPECT_THROW(camera.Capture(1), CameraError);  // not configured
  CameraSettings bad;
  bad.exposure_us = -1.0;
  EXPECT_THROW(camera.Configure(bad), std::invalid_argument);
  // A trigger line the camera does not have is named in the error.
  CameraSettings settings;
  settings.trigger_mode = TriggerMode::kHardware;
  settings.hardware_trigger_line = "NoSuchLine";
  settings.frame_timeout_s = 0.2;
  try {
    camera.Configure(settings);
    FAIL() << "expected an error";
  } catch (const CameraError& e) {
    EXPECT_NE(std::string(e.what()).find("NoSuchLine"), std::string::npos) << e.what();
  }
  settings.hardware_trigger_line = "Line0";
  EXPECT_NO_THROW(camera.Configure(settings));
  EXPECT_THROW(camera.Capture(0), std::invalid_argument);
}

// Hardware trigger: the camera is armed before the trigger source starts. The in-process fake
// camera stands in for the projector's trigger output with pulses of its own (25 Hz).
TEST_F(AravisCameraTest, ArmedHardwareTriggeredCaptureThenSoftwareTrigger) {
  AravisCamera camera(fake_id_, 8);
  CameraSettings settings;
  settings.trigger_mode = TriggerMode::kHardware;
  settings.hardware_trigger_line = "Line0";
  settings.exposure_us = 1000.0;
  settings.frame_timeout_s = 5.0;
  camera.Configure(settings);
  camera.Arm(3);
  std::vector<Frame> frames = camera.Capture(3);
  ASSERT_EQ(frames.size(), 3u);
  EXPECT_NO_THROW(CheckConsecutiveFrameIds(frames));
  settings.trigger_mode = TriggerMode::kSoftware;
  camera.Configure(settings);
  camera.Arm(3);
  frames = camera.Capture(3);
  ASSERT_EQ(frames.size(), 3u);
  EXPECT_NO_THROW(CheckConsecutiveFrameIds(frames));
  // Capture without Arm arms by itself; Arm checks its count.
  EXPECT_EQ(camera.Capture(2).size(), 2u);
  EXPECT_THROW(camera.Arm(0), std::invalid_argument);
}

TEST_F(AravisCameraTest, ArmNeedsConfigure) {
  AravisCamera camera(fake_id_, 4);
  EXPECT_THROW(camera.Arm(2), CameraError);
}

}  // namespace
}  // namespace picking::scanner
