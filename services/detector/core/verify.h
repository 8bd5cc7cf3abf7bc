#pragma once

#include <Eigen/Geometry>

#include <memory>
#include <vector>

#include "libs/geometry/point_cloud.h"
#include "services/detector/core/appearance.h"
#include "services/detector/core/detection.h"

namespace picking::detector {

struct VerifyOptions;
struct VerifyResult;

/// A sensor position from which a scan was taken: the camera's pose in the base frame and
/// its intrinsics.
struct SensorView {
  Eigen::Isometry3d X_BaseSensor;
  PinholeCamera camera;
};

/// A scene prepared for verifying many poses: a k-d tree of its points and, for each sensor
/// that took part in the scan, the depth image the scene projects to in that sensor.
class VerificationScene final {
 public:
  /// `scene`: points in the base frame (NaN allowed), with intensities (or colours, taken as
  /// their luma) for the appearance check; `X_BaseSensor`: pose of the camera that saw it;
  /// `camera`: its intrinsics. Throws std::invalid_argument when the scene has no finite
  /// point or a channel's length differs from the point count.
  VerificationScene(const geometry::PointCloud& scene, const Eigen::Isometry3d& X_BaseSensor,
                    const PinholeCamera& camera);
  /// A scene merged from the scans of several sensor positions (`sensors`, at least one;
  /// the first is the reference, whose frame the scene is kept in). A model point counts as
  /// visible when any sensor faces it unhidden by the model itself (but not when only other
  /// sensors than the reference do and none of them measured a depth along its ray), as
  /// occluded when every sensor that measured a depth there saw something in front of it,
  /// and as a conflict when the reference sensor saw through it (Verify; another sensor's
  /// depth image is the merged scene, which behind a surface that sensor missed holds what
  /// the others saw beyond it). Throws as above, and when
  /// `sensors` is empty or a pose is not finite.
  VerificationScene(const geometry::PointCloud& scene, std::vector<SensorView> sensors);
  ~VerificationScene();
  VerificationScene(const VerificationScene&) = delete;
  VerificationScene& operator=(const VerificationScene&) = delete;

  /// The reference sensor's intrinsics and pose.
  const PinholeCamera& camera() const { return sensors_.front().camera; }
  const Eigen::Isometry3d& X_BaseSensor() const { return sensors_.front().X_BaseSensor; }
  const std::vector<SensorView>& sensors() const { return sensors_; }
  /// Nearest measured depth (z in the frame of sensor `sensor`, metres) at pixel (u, v) of
  /// that sensor, NaN if none.
  float DepthAt(int u, int v, std::size_t sensor = 0) const;

 private:
  friend VerifyResult Verify(const VerificationScene&, const geometry::PointCloud&,
                             const Eigen::Isometry3d&, const VerifyOptions&);
  struct Impl;
  std::vector<SensorView> sensors_;
  std::unique_ptr<Impl> impl_;
};

struct VerifyOptions {
  /// A visible model point is supported by a scene point closer than this, metres.
  double distance_tolerance_m = 0.005;
  /// ... whose normal (when both have normals) is within this angle, radians.
  double normal_tolerance_rad = 0.6;
  /// A measured depth this much in front of a model point means the point is occluded by
  /// something else (not counted), metres.
  double occlusion_margin_m = 0.01;
  /// A measured depth this much behind a model point means the model would float in space the
  /// sensor saw as empty: a conflict, metres.
  double conflict_margin_m = 0.01;
  /// Each conflict cancels this many supported points in the score: a surface the sensor
  /// saw through is strong evidence against the pose.
  double conflict_weight = 1.0;
  /// The outline: the reference sensor's measured depth this far outside the model's drawn
  /// silhouette (metres, > 0) is compared with the model's surface carried on across the
  /// silhouette; within outline_margin_m (> 0) of it, the scene's surface continues past the
  /// model's edge (VerifyResult::num_outline_continued). An item shows that along the edges it
  /// stands on or touches a neighbour by; a pose laid into a larger surface (a box on a face of
  /// a bigger one, an item sunk into the table) shows it all round. The continued fraction,
  /// drawn towards outline_prior by outline_prior_samples samples (a few samples say little),
  /// scales the score by 1 above outline_free_fraction down to 0 at 1 (outline_factor).
  /// false: the outline is measured but leaves the score as it is.
  bool outline_check = true;
  double outline_distance_m = 0.01;
  double outline_margin_m = 0.01;
  double outline_prior = 0.3;          ///< In [0, 1].
  double outline_prior_samples = 8.0;  ///< >= 0.
  double outline_free_fraction = 0.5;  ///< In [0, 1).
  /// Model points are subsampled (deterministic stride) to at most this many.
  int max_model_points = 4000;
  /// Fewer unoccluded visible points than this gives score 0.
  int min_visible_points = 20;
  /// Appearance: when the model has albedo (its `intensities`) and the scene intensities,
  /// the supported points' albedo (but where the sensor grazes the surface,
  /// AppearanceOptions::min_sample_cos) is correlated with the scene's shading-compensated
  /// intensity (VerifyResult::appearance). A correlation below min_appearance_correlation
  /// (with evidence) means the printing contradicts the pose (another item of the same
  /// shape, or a wrong turn of a symmetric one): the score is then multiplied by
  /// appearance_contradiction_scale (in [0, 1]). The default 1 only reports it: without
  /// `symmetries` a box or cylinder pose that is right up to a symmetric turn (e.g. from
  /// range templates) would be taken for a contradiction (DetectPpf resolves the turns and
  /// rejects contradicted hypotheses itself).
  AppearanceOptions appearance;
  double min_appearance_correlation = 0.2;
  double appearance_contradiction_scale = 1.0;
  /// The model's symmetry rotations R_II' (ObjectModel::symmetries(); identity first; empty:
  /// the identity only). The appearance is that of the best turn X_BaseItem * R, reported in
  /// VerifyResult::X_BaseItem_appearance.
  std::vector<Eigen::Isometry3d> symmetries;
};

struct VerifyResult {
  /// support_score times outline_factor.
  double score = 0.0;
  /// (supported - conflict_weight * conflicts) / (visible - occluded), clamped to [0, 1].
  double support_score = 0.0;
  /// What the scene past the silhouette leaves of the score, [0, 1] (VerifyOptions::outline_...).
  double outline_factor = 1.0;
  std::size_t num_model_points = 0;  ///< After subsampling.
  /// Facing a sensor, in its image and not hidden by the model itself there.
  std::size_t num_visible = 0;
  /// Visible, but behind measured scene surface in every sensor that measured a depth there.
  std::size_t num_occluded = 0;
  std::size_t num_supported = 0;
  std::size_t num_conflicts = 0;   ///< Visible points in free space a sensor measured.
  double conflict_fraction = 0.0;  ///< num_conflicts / (num_visible - num_occluded).
  double inlier_rmse_m = 0.0;      ///< RMS distance of the supported points to the scene.
  /// Samples just outside the model's silhouette in the reference sensor where it measured a
  /// depth not in front of the model (an occluder there says nothing), and of those the ones
  /// where the scene's surface continues the model's (the rest drop away behind it).
  std::size_t num_outline = 0;
  std::size_t num_outline_continued = 0;
  /// Samples past the silhouette where the sensor measured a surface in front of the model.
  std::size_t num_outline_hidden = 0;
  /// Model albedo against scene intensity over the supported points (not defined without
  /// albedo, scene intensities or texture contrast).
  AppearanceScore appearance;
  /// X_BaseItem turned by the symmetry whose albedo explains the scene best (X_BaseItem
  /// itself without symmetries or evidence), and that symmetry's index.
  Eigen::Isometry3d X_BaseItem_appearance = Eigen::Isometry3d::Identity();
  int appearance_symmetry = 0;
  /// True when the appearance has evidence and its correlation is below
  /// min_appearance_correlation (the score is then scaled by appearance_contradiction_scale).
  bool appearance_contradicts = false;
};

/// Scores a pose hypothesis X_BaseItem of `model` (points with normals, item frame; optional
/// albedo in `intensities`) against the scene: back-face culling and a point-splat z-buffer
/// per sensor give the model points a sensor would see; each is then supported (scene point
/// within tolerance), occluded, in conflict (free-space violation) or unsupported; the supported
/// points' albedo is compared with the scene's intensities (see VerifyOptions). Throws
/// std::invalid_argument when the model has no normals, is empty, has an albedo channel of
/// another length or the options are invalid.
VerifyResult Verify(const VerificationScene& scene, const geometry::PointCloud& model,
                    const Eigen::Isometry3d& X_BaseItem, const VerifyOptions& options = {});

/// Mean distance to the nearest neighbour over (a subsample of) the cloud's finite points,
/// metres; 0 for fewer than two points.
double MeanPointSpacing(const geometry::PointCloud& cloud);

}  // namespace picking::detector
