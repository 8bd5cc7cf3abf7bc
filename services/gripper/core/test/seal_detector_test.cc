#include "services/gripper/core/seal_detector.h"

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>

namespace picking::gripper {
namespace {

TEST(SealDetectorTest, AttachesAtTheAttachThresholdAndReleasesBelowTheReleaseThreshold) {
  SealDetector seal(SealOptions{15.0, 10.0});
  EXPECT_FALSE(seal.Update(true, 5.0));
  EXPECT_FALSE(seal.Update(true, 14.99));
  EXPECT_TRUE(seal.Update(true, 15.0));
  // Inside the hysteresis band the decision holds.
  EXPECT_TRUE(seal.Update(true, 12.0));
  EXPECT_TRUE(seal.Update(true, 10.0));
  EXPECT_FALSE(seal.Update(true, 9.99));
  // Coming back up into the band does not attach again.
  EXPECT_FALSE(seal.Update(true, 12.0));
  EXPECT_TRUE(seal.Update(true, 20.0));
}

TEST(SealDetectorTest, PumpOffOrUnreadableLevelDetaches) {
  SealDetector seal;
  EXPECT_TRUE(seal.Update(true, 30.0));
  EXPECT_FALSE(seal.Update(false, 30.0));  // Pump off: residual vacuum is not a grip.
  EXPECT_TRUE(seal.Update(true, 30.0));
  EXPECT_FALSE(seal.Update(true, std::nan("")));
  EXPECT_TRUE(seal.Update(true, 30.0));
  seal.Reset();
  EXPECT_FALSE(seal.attached());
}

TEST(SealDetectorTest, RejectsThresholdsWithoutHysteresis) {
  EXPECT_THROW(SealDetector(SealOptions{10.0, 10.0}), std::invalid_argument);
  EXPECT_THROW(SealDetector(SealOptions{10.0, 12.0}), std::invalid_argument);
  EXPECT_THROW(SealDetector(SealOptions{10.0, -1.0}), std::invalid_argument);
  EXPECT_THROW(SealDetector(SealOptions{std::nan(""), 1.0}), std::invalid_argument);
}

}  // namespace
}  // namespace picking::gripper
