#include "services/scanner/core/triangulation.h"

#include "services/scanner/core/decoder.h"
#include "services/scanner/core/synthetic_capture.h"

#include <gtest/gtest.h>
#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <random>
#include <stdexcept>

namespace picking::scanner {
namespace {

struct Plane {
  Eigen::Vector3d normal;  // Unit, pointing away from the camera (normal.z > 0).
  double offset_m;         // normal . p == offset_m
};

Plane FitPlane(const geometry::PointCloud& cloud) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  std::size_t n = 0;
  for (const auto& p : cloud.points) {
    if (std::isnan(p.z())) continue;
    mean += p.cast<double>();
    ++n;
  }
  mean /= static_cast<double>(n);
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (const auto& p : cloud.points) {
    if (std::isnan(p.z())) continue;
    const Eigen::Vector3d d = p.cast<double>() - mean;
    scatter += d * d.transpose();
  }
  Eigen::Vector3d normal =
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(scatter).eigenvectors().col(0);
  if (normal.z() < 0) normal = -normal;
  return {normal, normal.dot(mean)};
}

SyntheticPlane TruePlane() {
  SyntheticPlane plane;
  plane.normal = Eigen::Vector3d(0.2, -0.1, 1.0).normalized();
  plane.offset_m = plane.normal.dot(Eigen::Vector3d(0, 0, 1.0));  // Through (0, 0, 1 m).
  return plane;
}

// The correspondences of the noise-free TruePlane() seen by `rig`.
CorrespondenceMap DecodeTruePlane(const ScannerRig& rig) {
  const PatternSequence patterns;
  SyntheticScene scene;
  scene.planes.push_back(TruePlane());
  const SyntheticCapture capture =
      RenderSyntheticCapture(rig, patterns, scene, SyntheticCaptureOptions{});
  return GrayCodeDecoder(patterns).Decode(capture.views());
}

TEST(TriangulationTest, RecoversAPlaneAtOneMetreWithRealisticNoise) {
  const ScannerRig rig = MakeExampleRig(1280, 1024);
  const PatternSequence patterns;
  SyntheticScene scene;
  scene.planes.push_back(TruePlane());
  SyntheticCaptureOptions options;
  options.blur_sigma_px = 0.6;
  options.noise_sigma = 2.0;
  options.gamma = 1.3;
  options.ambient_level = 25.0;
  options.seed = 3;
  const SyntheticCapture capture = RenderSyntheticCapture(rig, patterns, scene, options);
  const CorrespondenceMap map = GrayCodeDecoder(patterns).Decode(capture.views());
  const Triangulator triangulator(rig.camera, rig.projector, rig.X_CameraProjector);
  const ImageView white = capture.views()[PatternSequence::kWhiteIndex];
  const TriangulationResult result = triangulator.Run(map, &white);

  ASSERT_EQ(result.cloud.width, 1280u);
  ASSERT_EQ(result.cloud.height, 1024u);
  ASSERT_EQ(result.cloud.intensities.size(), result.cloud.points.size());
  EXPECT_EQ(result.cloud.frame_id, "camera");
  EXPECT_GT(result.num_points, map.num_valid * 95 / 100);

  const Plane fitted = FitPlane(result.cloud);
  const SyntheticPlane truth = TruePlane();
  const double distance_error_m = std::abs(fitted.offset_m - truth.offset_m);
  const double angle_rad = std::acos(std::min(1.0, fitted.normal.dot(truth.normal)));
  std::vector<double> depth_errors;
  for (std::size_t i = 0; i < result.cloud.points.size(); ++i) {
    const float z = result.cloud.points[i].z();
    if (!std::isnan(z)) depth_errors.push_back(std::abs(z - capture.depth_m[i]));
  }
  std::nth_element(depth_errors.begin(), depth_errors.begin() + depth_errors.size() / 2,
                   depth_errors.end());
  const double median_depth_error_m = depth_errors[depth_errors.size() / 2];
  std::cout << "plane at 1 m: " << result.num_points << " points, plane distance error "
            << distance_error_m * 1e3 << " mm, normal error " << angle_rad * 1e3
            << " mrad, median |depth error| " << median_depth_error_m * 1e3 << " mm\n";
  RecordProperty("median_depth_error_mm", std::to_string(median_depth_error_m * 1e3));
  EXPECT_LT(distance_error_m, 0.5e-3);
  EXPECT_LT(angle_rad, 1e-3);
  // Integer projector columns quantise depth in steps of about 6 mm here.
  EXPECT_LT(median_depth_error_m, 2.5e-3);
}

// Projector distortion is modelled exactly: every point projects back onto (within the
// half-pixel quantisation) the projector pixel it was decoded from, also at the image edges
// where the distortion moves pixels by several pixels.
TEST(TriangulationTest, PointsReprojectOntoTheirProjectorPixel) {
  const ScannerRig rig = MakeExampleRig(640, 512);
  const CorrespondenceMap map = DecodeTruePlane(rig);
  const Triangulator triangulator(rig.camera, rig.projector, rig.X_CameraProjector);
  const TriangulationResult result = triangulator.Run(map);
  const Eigen::Isometry3d X_ProjectorCamera = rig.X_CameraProjector.inverse();
  double max_column_error = 0;
  double max_row_error = 0;
  double max_distortion_shift = 0;
  for (std::size_t i = 0; i < map.valid.size(); ++i) {
    const Eigen::Vector3f& p = result.cloud.points[i];
    if (std::isnan(p.z())) continue;
    const Eigen::Vector3d p_Projector = X_ProjectorCamera * p.cast<double>();
    const auto uv = rig.projector.Project(p_Projector);
    ASSERT_TRUE(uv.has_value());
    max_column_error = std::max(max_column_error, std::abs(uv->x() - map.column[i]));
    max_row_error = std::max(max_row_error, std::abs(uv->y() - map.row[i]));
    const Eigen::Vector2d ideal(1100.0 * p_Projector.x() / p_Projector.z() + 455.5,
                                1100.0 * p_Projector.y() / p_Projector.z() + 569.5);
    max_distortion_shift = std::max(max_distortion_shift, (ideal - *uv).norm());
  }
  EXPECT_GT(result.num_points, map.num_valid * 99 / 100);
  EXPECT_GT(max_distortion_shift, 3.0);  // The test would notice distortion being ignored.
  EXPECT_LT(max_column_error, 0.55);
  EXPECT_LT(max_row_error, 0.55);
}

// Sub-pixel maps holding whole numbers (e.g. rows left integer by the refiner) take the
// integer path's projector rays: the points and counts equal those of the integer map.
// Sub-pixel columns with integer rows reproject onto their sub-pixel column.
TEST(TriangulationTest, IntegerSubpixelMapsMatchTheIntegerMap) {
  const ScannerRig rig = MakeExampleRig(640, 512);
  const CorrespondenceMap map = DecodeTruePlane(rig);
  CorrespondenceMap whole = map;
  whole.column_subpixel.assign(map.valid.size(), std::nanf(""));
  whole.row_subpixel.assign(map.valid.size(), std::nanf(""));
  for (std::size_t i = 0; i < map.valid.size(); ++i) {
    if (!map.valid[i]) continue;
    whole.column_subpixel[i] = map.column[i];
    whole.row_subpixel[i] = map.row[i];
  }
  const Triangulator triangulator(rig.camera, rig.projector, rig.X_CameraProjector);
  const TriangulationResult expected = triangulator.Run(map);
  const TriangulationResult actual = triangulator.Run(whole);
  EXPECT_EQ(actual.num_points, expected.num_points);
  EXPECT_EQ(actual.num_rejected_residual, expected.num_rejected_residual);
  EXPECT_EQ(actual.num_rejected_depth, expected.num_rejected_depth);
  EXPECT_EQ(actual.num_removed_isolated, expected.num_removed_isolated);
  std::size_t mismatches = 0;
  for (std::size_t i = 0; i < map.valid.size(); ++i) {
    const Eigen::Vector3f& a = actual.cloud.points[i];
    const Eigen::Vector3f& e = expected.cloud.points[i];
    mismatches += !(a == e || (std::isnan(a.z()) && std::isnan(e.z())));
  }
  EXPECT_EQ(mismatches, 0u);
  EXPECT_GT(expected.num_points, map.num_valid * 99 / 100);

  // Columns a third of a mirror to the right, rows integer: the points move onto the
  // shifted column (up to the effect of the row being off by up to half a mirror: the
  // least-squares point of two rays that miss each other reprojects slightly off the column
  // where the rows are not perpendicular to the epipolar plane).
  CorrespondenceMap shifted = whole;
  for (std::size_t i = 0; i < map.valid.size(); ++i) {
    if (map.valid[i] && map.column[i] + 1 < rig.projector.width()) {
      shifted.column_subpixel[i] += 1.0f / 3.0f;
    }
  }
  const TriangulationResult moved = triangulator.Run(shifted);
  const Eigen::Isometry3d X_ProjectorCamera = rig.X_CameraProjector.inverse();
  std::vector<double> column_errors;
  for (std::size_t i = 0; i < map.valid.size(); ++i) {
    const Eigen::Vector3f& p = moved.cloud.points[i];
    if (std::isnan(p.z())) continue;
    const auto uv = rig.projector.Project(X_ProjectorCamera * p.cast<double>());
    ASSERT_TRUE(uv.has_value());
    column_errors.push_back(std::abs(uv->x() - shifted.column_subpixel[i]));
  }
  ASSERT_GT(column_errors.size(), map.num_valid * 99 / 100);
  const double max_column_error = *std::max_element(column_errors.begin(), column_errors.end());
  std::nth_element(column_errors.begin(), column_errors.begin() + column_errors.size() / 2,
                   column_errors.end());
  const double median_column_error = column_errors[column_errors.size() / 2];
  std::cout << "shifted columns, integer rows: |reprojected column - column| median "
            << median_column_error << " px, max " << max_column_error << " px\n";
  EXPECT_LT(median_column_error, 0.02);
  EXPECT_LT(max_column_error, 0.15);
}

// Points with correspondences inconsistent with the geometry are rejected by the residual.
TEST(TriangulationTest, RejectsInconsistentCorrespondences) {
  const ScannerRig rig = MakeExampleRig(320, 256);
  CorrespondenceMap map = DecodeTruePlane(rig);
  TriangulationOptions options;
  options.remove_isolated = false;
  const Triangulator triangulator(rig.camera, rig.projector, rig.X_CameraProjector, options);
  const TriangulationResult clean = triangulator.Run(map);
  EXPECT_EQ(clean.num_rejected_residual, 0u);
  EXPECT_EQ(clean.num_points, map.num_valid);

  // Move every 10th valid pixel's row by 8 to 40 rows, off its epipolar line.
  std::size_t corrupted = 0;
  for (std::size_t i = 0; i < map.valid.size(); ++i) {
    if (!map.valid[i] || i % 10 != 0) continue;
    const int shift = 8 + static_cast<int>(i % 33);
    map.row[i] =
        static_cast<std::uint16_t>(map.row[i] >= 600 ? map.row[i] - shift : map.row[i] + shift);
    ++corrupted;
  }
  const TriangulationResult result = triangulator.Run(map);
  EXPECT_EQ(result.num_rejected_residual, corrupted);
  EXPECT_EQ(result.num_points, map.num_valid - corrupted);
}

TEST(TriangulationTest, RemovesIsolatedPoints) {
  const ScannerRig rig = MakeExampleRig(320, 256);
  CorrespondenceMap map = DecodeTruePlane(rig);
  // Keep a solid block and one lone pixel.
  const std::size_t lone = 40 * 320 + 40;
  for (int y = 0; y < 256; ++y) {
    for (int x = 0; x < 320; ++x) {
      const std::size_t i = static_cast<std::size_t>(y) * 320 + x;
      const bool keep = (x >= 100 && x < 200 && y >= 100 && y < 200) || i == lone;
      if (!keep && map.valid[i]) {
        map.valid[i] = 0;
        --map.num_valid;
      }
    }
  }
  ASSERT_TRUE(map.valid[lone]);
  const Triangulator triangulator(rig.camera, rig.projector, rig.X_CameraProjector);
  const TriangulationResult result = triangulator.Run(map);
  EXPECT_TRUE(std::isnan(result.cloud.points[lone].z()));
  EXPECT_EQ(result.num_removed_isolated, 1u);
  EXPECT_EQ(result.num_points, 100u * 100u);
  EXPECT_TRUE(result.cloud.intensities.empty());
}

TEST(TriangulationTest, RejectsBadInput) {
  const ScannerRig rig = MakeExampleRig(64, 48);
  const Triangulator triangulator(rig.camera, rig.projector, rig.X_CameraProjector);
  CorrespondenceMap map;
  map.width = 64;
  map.height = 48;
  map.column.assign(64 * 48, 0);
  map.row.assign(64 * 48, 0);
  map.valid.assign(64 * 48, 0);
  EXPECT_NO_THROW(triangulator.Run(map));

  CorrespondenceMap wrong_size = map;
  wrong_size.width = 32;
  EXPECT_THROW(triangulator.Run(wrong_size), std::invalid_argument);
  CorrespondenceMap short_buffer = map;
  short_buffer.row.pop_back();
  EXPECT_THROW(triangulator.Run(short_buffer), std::invalid_argument);
  CorrespondenceMap outside = map;
  outside.valid[5] = 1;
  outside.column[5] = 912;
  try {
    triangulator.Run(outside);
    ADD_FAILURE() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("outside the 912 x 1140 projector"), std::string::npos)
        << e.what();
  }
  std::vector<std::uint8_t> small(10 * 10);
  const ImageView wrong_intensity = MakeImageView(small.data(), 10, 10);
  EXPECT_THROW(triangulator.Run(map, &wrong_intensity), std::invalid_argument);

  TriangulationOptions bad;
  bad.min_depth_m = 2.0;
  bad.max_depth_m = 1.0;
  EXPECT_THROW(Triangulator(rig.camera, rig.projector, rig.X_CameraProjector, bad),
               std::invalid_argument);
  bad = TriangulationOptions{};
  bad.min_neighbors = 9;
  EXPECT_THROW(Triangulator(rig.camera, rig.projector, rig.X_CameraProjector, bad),
               std::invalid_argument);
  Eigen::Isometry3d scaled = rig.X_CameraProjector;
  scaled.linear() *= 2.0;
  EXPECT_THROW(Triangulator(rig.camera, rig.projector, scaled), std::invalid_argument);
}

}  // namespace
}  // namespace picking::scanner
