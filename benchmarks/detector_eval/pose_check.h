#pragma once

#include <Eigen/Geometry>

#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "libs/geometry/point_cloud.h"

namespace picking::detector_eval {

/// The rotations (item frame) that map a model with the given symmetry note onto itself:
/// "box": identity and the half turns about x, y, z; "cylinder-x" / "cylinder-z": turns about
/// the axis in `step_rad` steps, each also flipped end over end; "sphere": identity only (the
/// error is then the centre distance, see PoseError); anything else ("none"): identity.
std::vector<Eigen::Matrix3d> SymmetryRotations(const std::string& symmetry,
                                               double step_rad = 5.0 * 3.14159265358979 / 180.0);

/// Error of an estimated pose against the true one, by the closest symmetric pose.
struct PoseErrorResult {
  /// Mean distance between the model points placed by the estimate and by the closest
  /// symmetric true pose (ADD), metres. For "sphere": the centre distance.
  double add_m = 0.0;
  double translation_m = 0.0;  ///< Item origin distance, metres.
  double rotation_rad = 0.0;   ///< Angle of the remaining rotation to that symmetric pose.
};

/// `model`: points in the item frame (a subsample suffices). Throws std::invalid_argument on
/// an empty model.
PoseErrorResult PoseError(const geometry::PointCloud& model, const std::string& symmetry,
                          const Eigen::Isometry3d& X_BaseItem_estimate,
                          const Eigen::Isometry3d& X_BaseItem_true);

}  // namespace picking::detector_eval

namespace picking::detector {
struct Detection;
}

namespace picking::detector_eval {

/// Every candidate pose of an evaluation with the evidence under its score, one CSV row each,
/// for fitting and checking the detector's confidence offline (--candidates_csv). Writes
/// nothing when opened with an empty path.
class CandidateLog {
 public:
  explicit CandidateLog(const std::string& path);
  /// `scene`: where it was seen (e.g. "layout1:bin_A" or "frame3"); `rank`: 0 for the best.
  void Add(const std::string& source, const std::string& scene, int rank, bool correct,
           const detector::Detection& d);

 private:
  std::unique_ptr<std::ofstream> out_;
};

}  // namespace picking::detector_eval
