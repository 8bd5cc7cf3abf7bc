#include "services/simulator/core/rgbd_sensor.h"

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>
#include <vector>

namespace picking::simulator {
namespace {

// Square in the z = 0 plane of its frame, half size `half_m`, normal +z.
world::TriangleMesh Square(double half_m, float albedo = 0.6f) {
  world::TriangleMesh mesh;
  const float h = static_cast<float>(half_m);
  mesh.vertices = {{-h, -h, 0.0f}, {h, -h, 0.0f}, {h, h, 0.0f}, {-h, h, 0.0f}};
  mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
  mesh.albedo = albedo;
  return mesh;
}

// A pose that puts a Square at depth z in front of the camera (identity pose), facing it.
Eigen::Isometry3d Facing(double x, double y, double z) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(x, y, z);
  X.linear() = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix();
  return X;
}

// The camera looking along base +x (as at the shelf), z up in the base frame.
Eigen::Isometry3d CameraLookingAlongX() {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  Eigen::Matrix3d R;
  R.col(0) = -Eigen::Vector3d::UnitY();  // image right
  R.col(1) = -Eigen::Vector3d::UnitZ();  // image down
  R.col(2) = Eigen::Vector3d::UnitX();   // forward
  X.linear() = R;
  return X;
}

// One frame of a 20 cm square (a box's front) 0.8 m ahead of a wall 1.2 m ahead.
RgbdFrame BoxBeforeAWall() {
  const world::TriangleMesh wall = Square(3.0);
  const world::TriangleMesh box_front = Square(0.1);
  const StructuredLightRenderer renderer(
      {{&wall, Facing(0.0, 0.0, 1.2)}, {&box_front, Facing(0.0, 0.0, 0.8)}});
  return RenderRgbd(renderer, XtionDepthCamera(), Eigen::Isometry3d::Identity(), {});
}

// Standard deviation of the measured depth against `z_true` over the valid pixels.
double DepthSpread(const RgbdFrame& frame, double z_true) {
  double sum_sq = 0.0;
  std::size_t n = 0;
  for (float z : frame.depth_m) {
    if (std::isnan(z)) continue;
    sum_sq += (z - z_true) * (z - z_true);
    ++n;
  }
  return n ? std::sqrt(sum_sq / n) : 0.0;
}

TEST(RgbdSensorTest, DepthNoiseGrowsWithTheSquareOfTheDistance) {
  const world::TriangleMesh wall = Square(3.0);
  std::vector<double> spread;
  for (const double z : {0.8, 1.6}) {
    const StructuredLightRenderer renderer({{&wall, Facing(0.0, 0.0, z)}});
    const RgbdFrame frame =
        RenderRgbd(renderer, XtionDepthCamera(), Eigen::Isometry3d::Identity(), {});
    // Beyond the one-pixel band at the image border (no surface beside it there is none).
    EXPECT_GT(frame.valid(), 0.95 * frame.size()) << z;
    // The model: Nguyen et al.'s sigma, and the 1/8-pixel disparity steps' uniform error.
    const double sigma = 0.0012 + 0.0019 * (z - 0.4) * (z - 0.4);
    const double step = z * z / (570.3 * 0.075) * 0.125;
    const double expected = std::sqrt(sigma * sigma + step * step / 12.0);
    EXPECT_NEAR(DepthSpread(frame, z), expected, 0.15 * expected) << z;
    spread.push_back(DepthSpread(frame, z));
  }
  EXPECT_GT(spread[1], 2.0 * spread[0]);
}

TEST(RgbdSensorTest, ANearBoxCastsTheProjectorsShadowOnTheWallBehindIt) {
  // The projector stands 7.5 cm to the camera's right (+x): the wall left of the box is
  // hidden from it, 0.075 * (1.2 - 0.8) / 0.8 = 3.75 cm, about 18 pixels at 1.2 m.
  const RgbdFrame frame = BoxBeforeAWall();
  const int w = frame.camera.width();
  const int row = frame.camera.height() / 2;
  // The box's edges in the middle row: 570.3 * 0.1 / 0.8 = 71 pixels from the centre.
  const int left_edge = 319 - 71, right_edge = 320 + 71;
  auto hole = [&](int column) { return std::isnan(frame.depth_m[std::size_t(row) * w + column]); };
  int holes_left = 0, holes_right = 0;
  for (int c = left_edge - 40; c < left_edge - 1; ++c) holes_left += hole(c);
  for (int c = right_edge + 2; c < right_edge + 40; ++c) holes_right += hole(c);
  EXPECT_GE(holes_left, 14);
  EXPECT_LE(holes_left, 22);
  EXPECT_EQ(holes_right, 0);
  // The discontinuity itself is a hole on both sides (the matching window straddles it).
  EXPECT_TRUE(hole(right_edge));
  EXPECT_TRUE(hole(right_edge + 1) || hole(right_edge - 1));
  // The box is measured at its depth.
  EXPECT_NEAR(frame.depth_m[std::size_t(row) * w + 320], 0.8, 0.01);
}

TEST(RgbdSensorTest, ADarkSurfaceReturnsTooLittleOfThePatternAndLeavesAHole) {
  for (const float albedo : {0.02f, 0.6f}) {
    const world::TriangleMesh wall = Square(3.0, albedo);
    const StructuredLightRenderer renderer({{&wall, Facing(0.0, 0.0, 1.0)}});
    const RgbdFrame frame =
        RenderRgbd(renderer, XtionDepthCamera(), Eigen::Isometry3d::Identity(), {});
    if (albedo < 0.03f) {
      EXPECT_EQ(frame.valid(), 0u);
    } else {
      EXPECT_GT(frame.valid(), 0.95 * frame.size());
    }
  }
}

TEST(RgbdSensorTest, GrazingSurfacesAndSurfacesOutOfRangeLeaveHoles) {
  const world::TriangleMesh wall = Square(3.0);
  // Tilted by 85 degrees about the camera's y axis: seen almost edge on.
  Eigen::Isometry3d X = Facing(0.0, 0.0, 1.0);
  X.linear() = Eigen::AngleAxisd(85.0 * M_PI / 180.0, Eigen::Vector3d::UnitY()) * X.linear();
  const StructuredLightRenderer grazing({{&wall, X}});
  EXPECT_LT(RenderRgbd(grazing, XtionDepthCamera(), Eigen::Isometry3d::Identity(), {}).valid(),
            0.05 * XtionDepthCamera().width() * XtionDepthCamera().height());
  const StructuredLightRenderer far({{&wall, Facing(0.0, 0.0, 4.5)}});
  EXPECT_EQ(RenderRgbd(far, XtionDepthCamera(), Eigen::Isometry3d::Identity(), {}).valid(), 0u);
}

TEST(RgbdSensorTest, TheColourImageShowsTheSurfacesColourLitFromAbove) {
  // A red floor under the camera and a red wall ahead, the camera looking along base +x.
  world::TriangleMesh red = Square(2.0);
  red.vertex_colors.assign(red.vertices.size(), {200, 30, 30});
  Eigen::Isometry3d X_floor = Eigen::Isometry3d::Identity();
  X_floor.translation() = Eigen::Vector3d(1.0, 0.0, -0.5);  // normal +z: faces the ceiling
  Eigen::Isometry3d X_wall = Eigen::Isometry3d::Identity();
  X_wall.translation() = Eigen::Vector3d(2.0, 0.0, 0.0);
  X_wall.linear() = Eigen::AngleAxisd(-M_PI / 2, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const StructuredLightRenderer renderer({{&red, X_floor}, {&red, X_wall}});
  const RgbdFrame frame = RenderRgbd(renderer, XtionDepthCamera(), CameraLookingAlongX(), {});
  const int w = frame.camera.width();
  const auto& floor = frame.rgb[std::size_t(470) * w + 320];  // bottom of the image
  const auto& wall_px = frame.rgb[std::size_t(200) * w + 320];
  ASSERT_EQ(frame.object_index[std::size_t(470) * w + 320], 0);
  ASSERT_EQ(frame.object_index[std::size_t(200) * w + 320], 1);
  EXPECT_GT(floor[0], 2 * floor[1]);  // red
  EXPECT_GT(wall_px[0], 2 * wall_px[1]);
  EXPECT_GT(floor[0], wall_px[0] + 20);  // the floor faces the light, the wall does not
}

TEST(RgbdSensorTest, FramesAreRepeatableAndTheNoiseChangesFromFrameToFrame) {
  const world::TriangleMesh wall = Square(3.0);
  const StructuredLightRenderer renderer({{&wall, Facing(0.0, 0.0, 1.5)}});
  const auto render = [&](std::uint64_t frame) {
    return RenderRgbd(renderer, XtionDepthCamera(), Eigen::Isometry3d::Identity(), {}, frame);
  };
  const RgbdFrame a = render(3), b = render(3), c = render(4);
  ASSERT_EQ(a.size(), b.size());
  int same = 0, different = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (std::isnan(a.depth_m[i])) continue;
    EXPECT_EQ(a.depth_m[i], b.depth_m[i]);
    same += a.depth_m[i] == c.depth_m[i];
    different += a.depth_m[i] != c.depth_m[i];
  }
  EXPECT_GT(different, same / 4);
}

TEST(RgbdSensorTest, TheOrganisedCloudHoldsThePixelsRaysAtTheirDepths) {
  const RgbdFrame frame = BoxBeforeAWall();
  const geometry::PointCloud cloud = ToOrganisedCloud(frame);
  ASSERT_EQ(cloud.width, 640u);
  ASSERT_EQ(cloud.height, 480u);
  ASSERT_EQ(cloud.colors.size(), cloud.size());
  EXPECT_EQ(cloud.frame_id, "camera");
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (std::isnan(frame.depth_m[i])) {
      EXPECT_TRUE(std::isnan(cloud.points[i].z()));
      continue;
    }
    ASSERT_FLOAT_EQ(cloud.points[i].z(), frame.depth_m[i]);
    const int column = static_cast<int>(i % 640), row = static_cast<int>(i / 640);
    EXPECT_NEAR(cloud.points[i].x(), (column - 319.5) / 570.3 * frame.depth_m[i], 1e-5);
    EXPECT_NEAR(cloud.points[i].y(), (row - 239.5) / 570.3 * frame.depth_m[i], 1e-5);
  }
}

TEST(RgbdSensorTest, BadOptionsAndPosesAreRefusedByName) {
  const world::TriangleMesh wall = Square(1.0);
  const StructuredLightRenderer renderer({{&wall, Facing(0.0, 0.0, 1.0)}});
  RgbdSensorOptions options;
  options.baseline_m = -0.1;
  try {
    RenderRgbd(renderer, XtionDepthCamera(), Eigen::Isometry3d::Identity(), options);
    FAIL() << "a negative baseline was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("baseline_m"), std::string::npos) << e.what();
  }
  options = {};
  options.max_depth_m = std::nan("");
  EXPECT_THROW(options.Validate(), std::invalid_argument);
  Eigen::Isometry3d bad = Eigen::Isometry3d::Identity();
  bad.translation().x() = std::nan("");
  EXPECT_THROW(RenderRgbd(renderer, XtionDepthCamera(), bad, {}), std::invalid_argument);
}

}  // namespace
}  // namespace picking::simulator
