#pragma once

#include <Eigen/Geometry>

#include <cstdint>
#include <vector>

#include "libs/geometry/point_cloud.h"

namespace picking::scanner {

/// The shelf's top face in the shelf frame: its four corners, metres, counter-clockwise
/// seen from above, starting at the front-left corner (front = the side facing the robot).
struct ShelfTopModel {
  Eigen::Vector3d p_ShelfFrontLeft;
  Eigen::Vector3d p_ShelfFrontRight;
  Eigen::Vector3d p_ShelfBackRight;
  Eigen::Vector3d p_ShelfBackLeft;

  /// Throws std::invalid_argument when the corners do not form a rectangle (1 mm slack).
  void Validate() const;
};

struct ShelfPoseOptions {
  /// Up direction in the base frame; the top face's normal is within max_tilt_rad of it.
  Eigen::Vector3d up_Base = Eigen::Vector3d::UnitZ();
  /// Rough direction from the shelf toward the robot, in the base frame; the front face's
  /// outward normal is within max_front_angle_rad of it (after removing its up component).
  Eigen::Vector3d front_hint_Base = -Eigen::Vector3d::UnitX();
  double max_tilt_rad = 0.35;
  double max_front_angle_rad = 0.8;
  /// RANSAC inlier distance to a plane, metres.
  double plane_tolerance_m = 0.004;
  int ransac_iterations = 500;
  /// Fewest inliers for a face.
  int min_face_points = 200;
  /// Points within this distance of the front top edge are used to find its ends, metres.
  double edge_band_m = 0.02;
  /// The edge ends are the k-th most extreme points along the edge (robust to outliers).
  int edge_extreme_rank = 3;
  /// The measured front edge length must match the model within this, metres.
  double max_edge_length_error_m = 0.02;
  std::uint32_t seed = 1;
};

struct ShelfPoseResult {
  Eigen::Isometry3d X_BaseShelf = Eigen::Isometry3d::Identity();
  Eigen::Vector3d p_BaseFrontLeft = Eigen::Vector3d::Zero();   ///< Measured corner.
  Eigen::Vector3d p_BaseFrontRight = Eigen::Vector3d::Zero();  ///< Measured corner.
  Eigen::Vector3d top_normal_Base = Eigen::Vector3d::UnitZ();
  Eigen::Vector3d front_normal_Base = -Eigen::Vector3d::UnitX();
  int top_inliers = 0;
  int front_inliers = 0;
  double edge_length_error_m = 0.0;  ///< Measured minus model front edge length.
  double fit_rms_m = 0.0;            ///< RMS of the rigid fit over the corners.
};

/// Finds the shelf pose from a scan of the shelf's top region in the base frame: RANSAC
/// planes for the top face and the front face, their intersection as the front top edge,
/// the edge's ends as the front corners, and a rigid (Kabsch) fit of the model's top corners
/// to the measured corners (the back corners follow from the front normal and the model's
/// depth). Throws std::invalid_argument when the cloud is not in the base frame
/// ("base" or empty frame_id), when a face is not found, or when the measured front edge
/// does not match the model's length.
ShelfPoseResult EstimateShelfPose(const geometry::PointCloud& cloud_Base,
                                  const ShelfTopModel& model, const ShelfPoseOptions& options = {});

/// Least-squares rigid transform X_AB with p_A ~ X_AB * p_B (Kabsch / Umeyama without
/// scale). Throws std::invalid_argument for fewer than 3 pairs or mismatched sizes.
Eigen::Isometry3d FitRigidTransform(const std::vector<Eigen::Vector3d>& p_A,
                                    const std::vector<Eigen::Vector3d>& p_B);

}  // namespace picking::scanner
