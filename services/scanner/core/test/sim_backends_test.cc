#include "services/scanner/core/sim_backends.h"

#include <gtest/gtest.h>

#include <memory>
#include <stdexcept>

#include "libs/errors/errors.h"

namespace picking::scanner {
namespace {

// Records what it was asked and returns images whose pixels encode the pattern index.
class RecordingRenderer final : public PatternRenderer {
 public:
  std::vector<GrayImage> Render(const PatternRenderRequest& request) override {
    requests.push_back(request);
    std::vector<GrayImage> images;
    for (std::size_t i = 0; i < request.patterns.size(); ++i) {
      images.emplace_back(request.camera.width(), request.camera.height(),
                          static_cast<std::uint8_t>(i));
    }
    if (wrong_size) images.back() = GrayImage(1, 1);
    return images;
  }
  std::vector<PatternRenderRequest> requests;
  bool wrong_size = false;
};

SimSensorModel Model() {
  SimSensorModel model{camera::PinholeCamera(64, 48, 60, 60, 31.5, 23.5),
                       camera::PinholeCamera(912, 1140, 1100, 1100, 455.5, 569.5)};
  model.X_CameraProjector.translation() = Eigen::Vector3d(0.15, 0, 0);
  model.X_ToolCamera.translation() = Eigen::Vector3d(0, 0.05, 0.1);
  return model;
}

TEST(SimBackendsTest, CameraRendersTheRunningSequenceFromTheToolPose) {
  auto link = std::make_shared<SimSensorLink>();
  auto renderer = std::make_shared<RecordingRenderer>();
  SimProjector projector(link, 912, 1140);
  SimCamera camera(link, renderer, Model(), 5);
  EXPECT_EQ(camera.width(), 64u);

  Eigen::Isometry3d X_BaseTool = Eigen::Isometry3d::Identity();
  X_BaseTool.translation() = Eigen::Vector3d(0.5, 0.0, 0.8);
  X_BaseTool.linear() = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix();
  link->SetToolPose(X_BaseTool);
  projector.LoadSequence({});
  projector.Start();
  const std::vector<Frame> first = camera.Capture(4);
  const std::vector<Frame> rest = camera.Capture(40);
  ASSERT_EQ(first.size(), 4u);
  ASSERT_EQ(rest.size(), 40u);
  EXPECT_EQ(rest.front().frame_id, first.back().frame_id + 1);
  CheckConsecutiveFrameIds(rest);

  ASSERT_EQ(renderer->requests.size(), 2u);
  const PatternRenderRequest& r0 = renderer->requests[0];
  EXPECT_EQ(r0.patterns[0].kind, PatternImage::Kind::kWhite);
  EXPECT_EQ(r0.patterns[1].kind, PatternImage::Kind::kBlack);
  EXPECT_EQ(r0.patterns[2].kind, PatternImage::Kind::kColumnBit);
  EXPECT_FALSE(r0.patterns[2].inverse);
  EXPECT_TRUE(r0.patterns[3].inverse);
  // The whole sequence as requested matches PatternSequence's description of it.
  const PatternSequence sequence;
  std::vector<PatternImage> all = r0.patterns;
  all.insert(all.end(), renderer->requests[1].patterns.begin(),
             renderer->requests[1].patterns.end());
  ASSERT_EQ(static_cast<int>(all.size()), sequence.num_images());
  for (int i = 0; i < sequence.num_images(); ++i) {
    const PatternImage expected = sequence.Describe(i);
    EXPECT_EQ(all[i].kind, expected.kind) << i;
    EXPECT_EQ(all[i].bit, expected.bit) << i;
    EXPECT_EQ(all[i].inverse, expected.inverse) << i;
  }
  const Eigen::Isometry3d X_BaseCamera = X_BaseTool * Model().X_ToolCamera;
  EXPECT_TRUE(r0.X_BaseCamera.isApprox(X_BaseCamera, 1e-12));
  EXPECT_TRUE(r0.X_BaseProjector.isApprox(X_BaseCamera * Model().X_CameraProjector, 1e-12));
  EXPECT_NE(r0.seed, renderer->requests[1].seed);
  // The sequence ran once: a further capture waits for a trigger in vain.
  EXPECT_THROW(camera.Capture(1), CameraTimeoutError);
}

TEST(SimBackendsTest, CaptureWithoutARunningProjectorTimesOut) {
  auto link = std::make_shared<SimSensorLink>([] { return Eigen::Isometry3d::Identity(); });
  auto renderer = std::make_shared<RecordingRenderer>();
  SimProjector projector(link, 912, 1140);
  SimCamera camera(link, renderer, Model());
  EXPECT_THROW(camera.Capture(44), CameraTimeoutError);
  projector.LoadSequence({});
  EXPECT_THROW(camera.Capture(44), CameraTimeoutError);  // Loaded, not started.
  projector.Start();
  EXPECT_THROW(camera.Capture(45), CameraTimeoutError);  // More than the sequence has.
  EXPECT_EQ(camera.Capture(44).size(), 44u);             // Nothing was consumed before.
  EXPECT_TRUE(renderer->requests[0].X_BaseCamera.isApprox(Model().X_ToolCamera, 1e-12));
}

TEST(SimBackendsTest, RefusesBadSequencesPosesAndRendererOutput) {
  auto link = std::make_shared<SimSensorLink>();
  auto renderer = std::make_shared<RecordingRenderer>();
  SimProjector projector(link, 912, 1140);
  ProjectorSequenceSettings too_few_bits;
  too_few_bits.column_bits = 9;  // 512 < 912 columns.
  EXPECT_THROW(projector.LoadSequence(too_few_bits), std::invalid_argument);
  EXPECT_THROW(projector.Start(), ProjectorError);

  SimCamera camera(link, renderer, Model());
  projector.LoadSequence({});
  projector.Start();
  EXPECT_THROW(camera.Capture(44), PreconditionError);  // No pose and no pose source.
  Eigen::Isometry3d bad = Eigen::Isometry3d::Identity();
  bad.translation().x() = std::nan("");
  EXPECT_THROW(link->SetToolPose(bad), std::invalid_argument);
  link->SetToolPose(Eigen::Isometry3d::Identity());
  renderer->wrong_size = true;
  EXPECT_THROW(camera.Capture(44), CameraError);
  EXPECT_THROW(SimCamera(link, nullptr, Model()), std::invalid_argument);
}

}  // namespace
}  // namespace picking::scanner
