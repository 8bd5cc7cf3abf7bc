#include "services/scanner/core/synthetic_capture.h"

#include "services/scanner/core/calibration.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <stdexcept>

namespace picking::scanner {
namespace {

SyntheticScene TiltedPlane() {
  SyntheticScene scene;
  SyntheticPlane plane;
  plane.normal = Eigen::Vector3d(0.2, -0.1, 1.0).normalized();
  plane.offset_m = plane.normal.dot(Eigen::Vector3d(0, 0, 1.0));
  scene.planes.push_back(plane);
  return scene;
}

TEST(SyntheticCaptureTest, GroundTruthCoordinatesRoundToTheLitMirror) {
  const ScannerRig rig = MakeExampleRig(320, 256);
  const PatternSequence patterns;
  const SyntheticCapture capture =
      RenderSyntheticCapture(rig, patterns, TiltedPlane(), SyntheticCaptureOptions{});
  std::size_t lit = 0;
  for (std::size_t i = 0; i < capture.column.size(); ++i) {
    if (capture.column[i] < 0) {
      EXPECT_TRUE(std::isnan(capture.column_exact[i]));
      EXPECT_TRUE(std::isnan(capture.row_exact[i]));
      continue;
    }
    ++lit;
    ASSERT_LE(std::abs(capture.column_exact[i] - capture.column[i]), 0.5f);
    ASSERT_LE(std::abs(capture.row_exact[i] - capture.row[i]), 0.5f);
  }
  EXPECT_GT(lit, capture.column.size() * 9 / 10);
}

// Area sampling mixes the two sides of a stripe edge inside a pixel; point sampling never
// does. Away from edges both agree.
TEST(SyntheticCaptureTest, AreaSamplingMixesPixelsAtStripeEdges) {
  const ScannerRig rig = MakeExampleRig(320, 256);
  const PatternSequence patterns;
  SyntheticCaptureOptions point_options;
  point_options.ambient_level = 20.0;
  SyntheticCaptureOptions area_options = point_options;
  area_options.samples_per_axis = 4;
  const SyntheticCapture point =
      RenderSyntheticCapture(rig, patterns, TiltedPlane(), point_options);
  const SyntheticCapture area = RenderSyntheticCapture(rig, patterns, TiltedPlane(), area_options);
  EXPECT_TRUE(point.column == area.column);  // The ground truth is the pixel centre's.

  // The coarsest column bit has one edge (the middle of the projector), the finest an edge
  // every second column.
  const int coarse = patterns.ColumnImageIndex(0, false);
  const int fine = patterns.ColumnImageIndex(patterns.column_bits() - 1, false);
  const auto count_mixed = [&](const SyntheticCapture& capture, int k) {
    std::size_t mixed = 0;
    for (std::size_t i = 0; i < capture.column.size(); ++i) {
      if (capture.column[i] < 0) continue;
      const int on = capture.images[PatternSequence::kWhiteIndex][i];
      const int off = capture.images[PatternSequence::kBlackIndex][i];
      const int value = capture.images[k][i];
      mixed += value > off + 0.2 * (on - off) && value < on - 0.2 * (on - off);
    }
    return mixed;
  };
  EXPECT_EQ(count_mixed(point, fine), 0u);
  EXPECT_EQ(count_mixed(point, coarse), 0u);
  // 320 camera pixels see ~400 columns: nearly every pixel holds a fine-stripe edge.
  EXPECT_GT(count_mixed(area, fine), area.column.size() / 4);
  EXPECT_LT(count_mixed(area, coarse), area.column.size() / 50);

  // The all-white image is smooth shading: the average over the pixel ~ the centre value.
  for (std::size_t i = 0; i < area.column.size(); ++i) {
    if (area.column[i] < 0) continue;
    ASSERT_LE(std::abs(area.images[PatternSequence::kWhiteIndex][i] -
                       point.images[PatternSequence::kWhiteIndex][i]),
              2)
        << "pixel " << i;
  }
}

TEST(SyntheticCaptureTest, RejectsBadOptions) {
  const ScannerRig rig = MakeExampleRig(32, 24);
  const PatternSequence patterns;
  SyntheticCaptureOptions options;
  options.samples_per_axis = 0;
  EXPECT_THROW(RenderSyntheticCapture(rig, patterns, TiltedPlane(), options),
               std::invalid_argument);
  options.samples_per_axis = 17;
  EXPECT_THROW(RenderSyntheticCapture(rig, patterns, TiltedPlane(), options),
               std::invalid_argument);
  options = SyntheticCaptureOptions{};
  options.gamma = 0.0;
  EXPECT_THROW(RenderSyntheticCapture(rig, patterns, TiltedPlane(), options),
               std::invalid_argument);
  options = SyntheticCaptureOptions{};
  options.noise_sigma = -1.0;
  EXPECT_THROW(RenderSyntheticCapture(rig, patterns, TiltedPlane(), options),
               std::invalid_argument);
}

CameraIntrinsics IntrinsicsOf(const camera::PinholeCamera& c) {
  CameraIntrinsics k;
  k.width = static_cast<std::uint32_t>(c.width());
  k.height = static_cast<std::uint32_t>(c.height());
  k.fx = c.fx();
  k.fy = c.fy();
  k.cx = c.cx();
  k.cy = c.cy();
  k.distortion = {c.distortion().k1, c.distortion().k2, c.distortion().p1, c.distortion().p2,
                  c.distortion().k3};
  return k;
}

GrayImage WhiteImage(const SyntheticCapture& capture) {
  GrayImage image(static_cast<std::uint32_t>(capture.width),
                  static_cast<std::uint32_t>(capture.height));
  image.pixels = capture.images[0];
  return image;
}

// A rendered chessboard is found where it was put, in either half-turn orientation: the
// dark square outside the first corner fixes the board frame.
TEST(SyntheticCaptureTest, ChessboardPoseIsRecoveredInBothOrientations) {
  const ScannerRig rig = MakeExampleRig(640, 512);
  const PatternSequence patterns(64, 64);  // Only the white image is used.
  SyntheticChessboard board;
  board.square_size_m = 0.03;
  const Eigen::Vector3d centre_Board(4 * 0.03, 2.5 * 0.03, 0.0);
  Eigen::Isometry3d X_CameraCentre = Eigen::Isometry3d::Identity();
  X_CameraCentre.linear() = (Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 0.4, 0).normalized()) *
                             Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitZ()))
                                .toRotationMatrix();
  X_CameraCentre.translation() = Eigen::Vector3d(0.02, -0.01, 0.9);
  const ChessboardSpec spec{9, 6, 0.03};
  SyntheticCaptureOptions options;
  options.samples_per_axis = 3;
  options.blur_sigma_px = 0.5;
  options.noise_sigma = 1.0;
  for (double turn : {0.0, M_PI}) {
    Eigen::Isometry3d X_CentreBoard = Eigen::Isometry3d::Identity();
    X_CentreBoard.linear() = Eigen::AngleAxisd(turn, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    X_CentreBoard.translation() = -(X_CentreBoard.linear() * centre_Board);
    board.X_CameraBoard = X_CameraCentre * X_CentreBoard;
    SyntheticScene scene;
    scene.boards.push_back(board);
    const SyntheticCapture capture = RenderSyntheticCapture(rig, patterns, scene, options);
    const auto origin_px = rig.camera.Project(board.X_CameraBoard.translation());
    ASSERT_TRUE(origin_px.has_value());
    BoardPose pose;
    ASSERT_TRUE(EstimateBoardPose(WhiteImage(capture), spec, IntrinsicsOf(rig.camera), &pose))
        << "turn " << turn;
    EXPECT_LT((pose.corners_px.front() - *origin_px).norm(), 3.0) << "turn " << turn;
    EXPECT_LT(pose.rms_px, 0.3);
    EXPECT_LT((pose.X_CameraBoard.translation() - board.X_CameraBoard.translation()).norm(), 0.002)
        << "turn " << turn;
    const double angle_rad =
        Eigen::AngleAxisd(pose.X_CameraBoard.linear().transpose() * board.X_CameraBoard.linear())
            .angle();
    EXPECT_LT(angle_rad, 0.01) << "turn " << turn;
  }
  // A board that is not in the picture, and a camera of another size.
  SyntheticScene empty;
  empty.planes.push_back(TiltedPlane().planes[0]);
  BoardPose pose;
  EXPECT_FALSE(EstimateBoardPose(
      WhiteImage(RenderSyntheticCapture(rig, patterns, empty, SyntheticCaptureOptions{})), spec,
      IntrinsicsOf(rig.camera), &pose));
  EXPECT_THROW(EstimateBoardPose(GrayImage(320, 256, 0), spec, IntrinsicsOf(rig.camera), &pose),
               std::invalid_argument);
}

// A box is seen at the distance of its nearest face, lit on the faces the projector sees.
TEST(SyntheticCaptureTest, BoxFacesAreAtTheirDistance) {
  const ScannerRig rig = MakeExampleRig(320, 256);
  const PatternSequence patterns;
  SyntheticBox box;
  box.X_CameraBox.translation() = Eigen::Vector3d(0.0, 0.0, 1.2);
  box.half_size_m = Eigen::Vector3d(0.2, 0.15, 0.1);
  SyntheticScene scene;
  scene.boxes.push_back(box);
  const SyntheticCapture capture =
      RenderSyntheticCapture(rig, patterns, scene, SyntheticCaptureOptions{});
  const auto at = [&](double x_m, double y_m, double z_m) {
    const auto uv = rig.camera.Project(Eigen::Vector3d(x_m, y_m, z_m));
    const std::size_t i = static_cast<std::size_t>(std::lround(uv->y())) * capture.width +
                          static_cast<std::size_t>(std::lround(uv->x()));
    return i;
  };
  const std::size_t front = at(0.05, 0.02, 1.1);
  EXPECT_NEAR(capture.depth_m[front], 1.1, 1e-4);
  EXPECT_GE(capture.column[front], 0);
  // Beside the box: nothing.
  EXPECT_TRUE(std::isnan(capture.depth_m[at(0.3, 0.0, 1.1)]));
  SyntheticScene bad = scene;
  bad.boxes[0].half_size_m.x() = 0.0;
  EXPECT_THROW(RenderSyntheticCapture(rig, patterns, bad, SyntheticCaptureOptions{}),
               std::invalid_argument);
}

}  // namespace
}  // namespace picking::scanner
