#include "benchmarks/detector_eval/pose_check.h"

#include "services/detector/core/detection.h"

#include <cmath>
#include <iomanip>
#include <limits>
#include <stdexcept>

namespace picking::detector_eval {

std::vector<Eigen::Matrix3d> SymmetryRotations(const std::string& symmetry, double step_rad) {
  std::vector<Eigen::Matrix3d> out = {Eigen::Matrix3d::Identity()};
  if (symmetry == "box") {
    for (const Eigen::Vector3d& axis :
         {Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitY(), Eigen::Vector3d::UnitZ()}) {
      out.push_back(Eigen::AngleAxisd(M_PI, axis).toRotationMatrix());
    }
  } else if (symmetry == "cylinder-x" || symmetry == "cylinder-z") {
    const Eigen::Vector3d axis =
        symmetry == "cylinder-x" ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitZ();
    const Eigen::Vector3d across = Eigen::Vector3d::UnitY();
    out.clear();
    const int steps = std::max(1, static_cast<int>(std::lround(2.0 * M_PI / step_rad)));
    for (int flip = 0; flip < 2; ++flip) {
      for (int k = 0; k < steps; ++k) {
        const Eigen::Matrix3d R =
            Eigen::AngleAxisd(2.0 * M_PI * k / steps, axis).toRotationMatrix();
        out.push_back(flip ? Eigen::Matrix3d(R * Eigen::AngleAxisd(M_PI, across)) : R);
      }
    }
  }
  return out;
}

PoseErrorResult PoseError(const geometry::PointCloud& model, const std::string& symmetry,
                          const Eigen::Isometry3d& X_BaseItem_estimate,
                          const Eigen::Isometry3d& X_BaseItem_true) {
  if (model.empty()) throw std::invalid_argument("PoseError: empty model");
  PoseErrorResult best;
  best.translation_m = (X_BaseItem_estimate.translation() - X_BaseItem_true.translation()).norm();
  if (symmetry == "sphere") {
    best.add_m = best.translation_m;
    return best;
  }
  best.add_m = std::numeric_limits<double>::infinity();
  const std::size_t stride = std::max<std::size_t>(1, model.size() / 500);
  for (const Eigen::Matrix3d& S : SymmetryRotations(symmetry)) {
    Eigen::Isometry3d X_true = X_BaseItem_true;
    X_true.linear() = X_BaseItem_true.linear() * S;
    double sum = 0.0;
    std::size_t n = 0;
    for (std::size_t i = 0; i < model.size(); i += stride) {
      const Eigen::Vector3d p = model.points[i].cast<double>();
      if (!p.allFinite()) continue;
      sum += (X_BaseItem_estimate * p - X_true * p).norm();
      ++n;
    }
    const double add = n > 0 ? sum / static_cast<double>(n) : 0.0;
    if (add < best.add_m) {
      best.add_m = add;
      best.rotation_rad =
          Eigen::AngleAxisd(X_BaseItem_estimate.linear().transpose() * X_true.linear()).angle();
    }
  }
  return best;
}

}  // namespace picking::detector_eval

namespace picking::detector_eval {

CandidateLog::CandidateLog(const std::string& path) {
  if (path.empty()) return;
  out_ = std::make_unique<std::ofstream>(path);
  if (!*out_) throw std::runtime_error("cannot write '" + path + "'");
  *out_ << "source,scene,item,rank,correct,method,score,fitness,inlier_rmse_m,appearance,"
           "visible,occluded,supported,conflicts,outline,outline_continued,outline_hidden\n";
}

void CandidateLog::Add(const std::string& source, const std::string& scene, int rank, bool correct,
                       const detector::Detection& d) {
  if (!out_) return;
  *out_ << source << "," << scene << "," << d.item << "," << rank << "," << (correct ? 1 : 0) << ","
        << d.method << "," << std::setprecision(6) << d.score << "," << d.fitness << ","
        << d.inlier_rmse_m << "," << d.appearance << "," << d.visible_points << ","
        << d.occluded_points << "," << d.supported_points << "," << d.conflict_points << ","
        << d.outline_points << "," << d.outline_continued << "," << d.outline_hidden << "\n";
  out_->flush();
}

}  // namespace picking::detector_eval
