// The detector's request-level preparation (PrepareScene): the region's crop, walls and
// floor, the camera, stacked views, and the errors the service maps to its fields.
#include "services/detector/core/detect_in_region.h"

#include <gtest/gtest.h>

#include <vector>

#include "services/detector/core/test/bin_scene_test_util.h"

namespace picking::detector {
namespace {

using testing::BinScene;

BinScene MakeBinScene() { return testing::MakeBinScene(/*floor_z_m=*/-0.099, /*with_nan=*/false); }

TEST(PrepareScene, ARegionWithAWallMarginKeepsTheItemOnly) {
  const BinScene s = MakeBinScene();
  SceneOptions options;
  options.region = s.bin;
  options.wall_margin_m = 0.01;
  const PreparedScene prepared = PrepareScene(s.cloud, Eigen::Isometry3d::Identity(), options);
  EXPECT_EQ(prepared.finite_points, s.item_points);
  for (const auto& p : prepared.cloud.points) {
    if (p.allFinite()) EXPECT_TRUE(s.bin.Contains(p.cast<double>(), 1e-6));
  }
  // The floor went with the walls: the range templates do not look for it again.
  EXPECT_FALSE(prepared.context.remove_dominant_plane);
  // An unorganised cloud: no intrinsics to fit, the fallback camera.
  EXPECT_FALSE(prepared.intrinsics_fitted);
  ASSERT_TRUE(prepared.camera.has_value());
  EXPECT_EQ(prepared.camera->width(), options.fallback_camera.width());
}

TEST(PrepareScene, WithoutAMarginTheRegionIsOnlyCropped) {
  const BinScene s = MakeBinScene();
  SceneOptions options;
  options.region = s.bin;
  const PreparedScene prepared = PrepareScene(s.cloud, Eigen::Isometry3d::Identity(), options);
  EXPECT_EQ(prepared.finite_points, s.cloud.size() - 100);
  EXPECT_TRUE(prepared.context.remove_dominant_plane);
  // No region at all: the whole cloud.
  EXPECT_EQ(PrepareScene(s.cloud, Eigen::Isometry3d::Identity(), {}).finite_points, s.cloud.size());
}

TEST(PrepareScene, BadRegionsAndViewsAreTypedErrors) {
  const BinScene s = MakeBinScene();
  SceneOptions away;
  away.region = s.bin;
  away.region->X_BaseBox.translation() += Eigen::Vector3d(5.0, 0.0, 0.0);
  EXPECT_THROW(PrepareScene(s.cloud, Eigen::Isometry3d::Identity(), away), EmptyRegionError);
  SceneOptions empty;  // within the cloud's bounds, above the item, where nothing is
  empty.region = OrientedBox{s.bin.X_BaseBox * Eigen::Translation3d(0.0, 0.0, 0.05),
                             Eigen::Vector3d::Constant(0.05)};
  EXPECT_THROW(PrepareScene(s.cloud, Eigen::Isometry3d::Identity(), empty), EmptyRegionError);
  SceneOptions margin;
  margin.region = s.bin;
  margin.wall_margin_m = 0.15;  // more than half the bin's smallest side
  EXPECT_THROW(PrepareScene(s.cloud, Eigen::Isometry3d::Identity(), margin), std::invalid_argument);
  SceneOptions views;  // two views for an unorganised cloud
  views.view_poses = {Eigen::Isometry3d::Identity(), Eigen::Isometry3d::Identity()};
  EXPECT_THROW(PrepareScene(s.cloud, Eigen::Isometry3d::Identity(), views), ViewPosesError);
}

// Intrinsics the caller gives are used as they are, not fitted.
TEST(PrepareScene, GivenIntrinsicsAreUsedAsTheyAre) {
  const BinScene s = MakeBinScene();
  SceneOptions options;
  options.camera = PinholeCamera(1280, 960, 1000.0, 1001.0, 640.0, 480.0);
  const PreparedScene prepared = PrepareScene(s.cloud, Eigen::Isometry3d::Identity(), options);
  ASSERT_TRUE(prepared.camera.has_value());
  EXPECT_EQ(prepared.camera->width(), 1280);
  EXPECT_DOUBLE_EQ(prepared.camera->fy(), 1001.0);
  EXPECT_FALSE(prepared.intrinsics_fitted);
}

}  // namespace
}  // namespace picking::detector
