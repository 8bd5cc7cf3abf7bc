#include "services/detector/core/box_faces.h"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <string>

namespace picking::detector {
namespace {

// Running sums of a point set, for least-squares planes.
struct PlaneSums {
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  Eigen::Matrix3d sum_sq = Eigen::Matrix3d::Zero();
  std::size_t n = 0;

  void Add(const Eigen::Vector3f& p) {
    const Eigen::Vector3d q = p.cast<double>();
    sum += q;
    sum_sq += q * q.transpose();
    ++n;
  }
  Eigen::Vector3d Mean() const { return sum / static_cast<double>(n); }
  // Unit normal of the least-squares plane, turned toward `side`.
  Eigen::Vector3d Normal(const Eigen::Vector3d& side) const {
    const Eigen::Vector3d mean = Mean();
    const Eigen::Matrix3d cov = sum_sq / static_cast<double>(n) - mean * mean.transpose();
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
    Eigen::Vector3d normal = eig.eigenvectors().col(0);
    return normal.dot(side) < 0.0 ? Eigen::Vector3d(-normal) : normal;
  }
};

double Cross2(const Eigen::Vector2d& o, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  return (a.x() - o.x()) * (b.y() - o.y()) - (a.y() - o.y()) * (b.x() - o.x());
}

// Convex hull, counter-clockwise (Andrew's monotone chain); sorts `points`.
std::vector<Eigen::Vector2d> ConvexHull(std::vector<Eigen::Vector2d> points) {
  std::sort(points.begin(), points.end(), [](const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
    return a.x() < b.x() || (a.x() == b.x() && a.y() < b.y());
  });
  if (points.size() < 3) return points;
  std::vector<Eigen::Vector2d> hull(2 * points.size());
  std::size_t k = 0;
  for (const auto& p : points) {
    while (k >= 2 && Cross2(hull[k - 2], hull[k - 1], p) <= 0.0) --k;
    hull[k++] = p;
  }
  for (std::size_t i = points.size() - 1, lower = k + 1; i-- > 0;) {
    while (k >= lower && Cross2(hull[k - 2], hull[k - 1], points[i]) <= 0.0) --k;
    hull[k++] = points[i];
  }
  hull.resize(k - 1);
  return hull;
}

// The patch of `members`: least-squares plane, then the smallest rectangle holding the points
// projected onto it, which has a side along one of their convex hull's edges.
PlanarPatch MakePatch(const geometry::PointCloud& cloud, const std::vector<std::int32_t>& members,
                      const Eigen::Vector3d& side) {
  PlaneSums sums;
  for (std::int32_t i : members) sums.Add(cloud.points[i]);
  const Eigen::Vector3d mean = sums.Mean();
  const Eigen::Vector3d normal = sums.Normal(side);
  const Eigen::Vector3d e1 = normal.unitOrthogonal();
  const Eigen::Vector3d e2 = normal.cross(e1);
  std::vector<Eigen::Vector2d> flat;
  flat.reserve(members.size());
  double sum_sq = 0.0;
  for (std::int32_t i : members) {
    const Eigen::Vector3d d = cloud.points[i].cast<double>() - mean;
    const double off = d.dot(normal);
    sum_sq += off * off;
    flat.emplace_back(d.dot(e1), d.dot(e2));
  }
  const std::vector<Eigen::Vector2d> hull = ConvexHull(std::move(flat));
  PlanarPatch patch;
  patch.normal = normal;
  patch.points = members.size();
  patch.rms_m = std::sqrt(sum_sq / static_cast<double>(members.size()));
  double best_area = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < hull.size(); ++i) {
    const Eigen::Vector2d edge = hull[(i + 1) % hull.size()] - hull[i];
    if (edge.norm() < 1e-9) continue;
    const Eigen::Vector2d d = edge.normalized();
    const Eigen::Vector2d perp(-d.y(), d.x());
    double lo_d = std::numeric_limits<double>::infinity(), hi_d = -lo_d;
    double lo_p = lo_d, hi_p = hi_d;
    for (const auto& h : hull) {
      lo_d = std::min(lo_d, h.dot(d));
      hi_d = std::max(hi_d, h.dot(d));
      lo_p = std::min(lo_p, h.dot(perp));
      hi_p = std::max(hi_p, h.dot(perp));
    }
    const double area = (hi_d - lo_d) * (hi_p - lo_p);
    if (area >= best_area) continue;
    best_area = area;
    const Eigen::Vector2d c = d * (0.5 * (lo_d + hi_d)) + perp * (0.5 * (lo_p + hi_p));
    patch.centre = mean + e1 * c.x() + e2 * c.y();
    patch.axis_u = (e1 * d.x() + e2 * d.y()).normalized();
    patch.axis_v = normal.cross(patch.axis_u);
    patch.half_u = 0.5 * (hi_d - lo_d);
    patch.half_v = 0.5 * (hi_p - lo_p);
  }
  if (!std::isfinite(best_area)) patch.centre = mean;  // Fewer than three distinct points.
  return patch;
}

}  // namespace

void BoxFaceOptions::Validate() const {
  const auto fail = [](const char* what) {
    throw std::invalid_argument(std::string("BoxFaceOptions: ") + what);
  };
  if (!(neighbour_radius_m > 0.0)) fail("neighbour_radius_m must be > 0");
  if (!(normal_tolerance_rad > 0.0 && normal_tolerance_rad < M_PI / 2)) {
    fail("normal_tolerance_rad must be in (0, pi/2)");
  }
  if (!(plane_tolerance_m > 0.0)) fail("plane_tolerance_m must be > 0");
  if (min_points < 3) fail("min_points must be >= 3");
  if (max_patches < 1) fail("max_patches must be >= 1");
  if (!(size_tolerance_m >= 0.0)) fail("size_tolerance_m must be >= 0");
  if (!(size_tolerance_rel >= 0.0)) fail("size_tolerance_rel must be >= 0");
  if (!(whole_side_m >= 0.0)) fail("whole_side_m must be >= 0");
}

std::vector<PlanarPatch> FindPlanarPatches(const geometry::PointCloud& cloud, const KdTree& tree,
                                           const BoxFaceOptions& options) {
  options.Validate();
  if (!cloud.has_normals() || cloud.normals.size() != cloud.points.size()) {
    throw std::invalid_argument("FindPlanarPatches: the cloud needs one normal per point");
  }
  if (tree.size() != cloud.points.size()) {
    throw std::invalid_argument("FindPlanarPatches: the tree is not over the cloud's points");
  }
  const std::size_t n = cloud.points.size();
  const float radius = static_cast<float>(options.neighbour_radius_m);
  const double cos_tolerance = std::cos(options.normal_tolerance_rad);
  // -1: not yet reached; -2: in a patch too small to keep; else the patch's index.
  std::vector<std::int32_t> label(n, -1);
  std::vector<std::vector<std::int32_t>> patches;
  std::vector<std::int32_t> members, neighbours;
  for (std::size_t seed = 0; seed < n; ++seed) {
    if (label[seed] != -1) continue;
    const Eigen::Vector3f& seed_normal = cloud.normals[seed];
    if (!cloud.points[seed].allFinite() || !seed_normal.allFinite()) {
      label[seed] = -2;
      continue;
    }
    const std::int32_t id = static_cast<std::int32_t>(patches.size());
    members.assign(1, static_cast<std::int32_t>(seed));
    label[seed] = id;
    PlaneSums sums;
    sums.Add(cloud.points[seed]);
    Eigen::Vector3d normal = seed_normal.cast<double>();
    Eigen::Vector3d origin = cloud.points[seed].cast<double>();
    std::size_t next_refit = 16;
    for (std::size_t q = 0; q < members.size(); ++q) {
      tree.RadiusSearch(cloud.points[members[q]], radius, &neighbours);
      for (std::int32_t j : neighbours) {
        if (label[j] != -1) continue;
        const Eigen::Vector3f& nj = cloud.normals[j];
        if (!nj.allFinite() || nj.cast<double>().dot(normal) < cos_tolerance) continue;
        if (std::abs((cloud.points[j].cast<double>() - origin).dot(normal)) >
            options.plane_tolerance_m) {
          continue;
        }
        label[j] = id;
        members.push_back(j);
        sums.Add(cloud.points[j]);
        // The seed's normal is one noisy estimate: the plane follows the patch as it grows.
        if (sums.n >= next_refit) {
          normal = sums.Normal(normal);
          origin = sums.Mean();
          next_refit *= 2;
        }
      }
    }
    if (members.size() < options.min_points) {
      for (std::int32_t i : members) label[i] = -2;
      continue;
    }
    patches.push_back(members);
  }
  std::vector<std::size_t> order(patches.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&patches](std::size_t a, std::size_t b) {
    return patches[a].size() > patches[b].size();
  });
  if (order.size() > static_cast<std::size_t>(options.max_patches)) {
    order.resize(static_cast<std::size_t>(options.max_patches));
  }
  std::vector<PlanarPatch> out;
  out.reserve(order.size());
  for (std::size_t i : order) {
    const auto& m = patches[i];
    out.push_back(MakePatch(cloud, m, cloud.normals[m.front()].cast<double>()));
  }
  return out;
}

std::vector<Eigen::Isometry3d> BoxPosesOnPatch(const PlanarPatch& patch,
                                               const Eigen::Vector3d& half_size,
                                               const BoxFaceOptions& options) {
  options.Validate();
  if (!(half_size.array() > 0.0).all() || !half_size.allFinite()) {
    throw std::invalid_argument("BoxPosesOnPatch: the box's half sides must be positive");
  }
  const auto fits = [&options](double patch_half, double face_half) {
    return patch_half <=
           face_half + options.size_tolerance_m + options.size_tolerance_rel * face_half;
  };
  // Where the face's centre can lie along one side of the rectangle: centred, or flush with
  // either end when the face is longer than what is seen of it.
  const auto placements = [&options](double patch_half, double face_half) {
    std::vector<double> at = {0.0};
    if (face_half - patch_half > 0.5 * options.whole_side_m) {
      at.push_back(face_half - patch_half);
      at.push_back(patch_half - face_half);
    }
    return at;
  };
  std::vector<Eigen::Isometry3d> poses;
  for (int k = 0; k < 3; ++k) {
    const int u = (k + 1) % 3, v = (k + 2) % 3;
    for (bool swap : {false, true}) {
      // Item axes along the rectangle's sides.
      const int along_u = swap ? v : u;
      const int along_v = swap ? u : v;
      if (!fits(patch.half_u, half_size[along_u]) || !fits(patch.half_v, half_size[along_v])) {
        continue;
      }
      Eigen::Matrix3d R;
      R.col(k) = patch.normal;
      if (!swap) {
        R.col(u) = patch.axis_u;
        R.col(v) = patch.axis_v;
      } else {
        R.col(v) = patch.axis_u;
        R.col(u) = -patch.axis_v;
      }
      for (double cu : placements(patch.half_u, half_size[along_u])) {
        for (double cv : placements(patch.half_v, half_size[along_v])) {
          Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
          X.linear() = R;
          X.translation() =
              patch.centre + patch.axis_u * cu + patch.axis_v * cv - patch.normal * half_size[k];
          poses.push_back(X);
        }
      }
    }
  }
  return poses;
}

void ContinuationOptions::Validate() const {
  const auto positive = [](double v, const char* what) {
    if (!(v > 0.0) || !std::isfinite(v)) {
      throw std::invalid_argument(std::string("ContinuationOptions: ") + what + " must be > 0");
    }
  };
  positive(offset_m, "offset_m");
  positive(spacing_m, "spacing_m");
  positive(match_radius_m, "match_radius_m");
  positive(plane_tolerance_m, "plane_tolerance_m");
  positive(normal_tolerance_rad, "normal_tolerance_rad");
}

double BoxSurfaceContinuation(const geometry::PointCloud& scene, const KdTree& tree,
                              const Eigen::Isometry3d& X_SceneBox, const Eigen::Vector3d& half_size,
                              const Eigen::Vector3d& viewpoint,
                              const ContinuationOptions& options) {
  options.Validate();
  if (!scene.has_normals() || scene.normals.size() != scene.points.size()) {
    throw std::invalid_argument("BoxSurfaceContinuation: the scene needs one normal per point");
  }
  if (tree.size() != scene.points.size()) {
    throw std::invalid_argument("BoxSurfaceContinuation: the tree is not over the scene's points");
  }
  if (!(half_size.array() > 0.0).all() || !half_size.allFinite()) {
    throw std::invalid_argument("BoxSurfaceContinuation: the box's half sides must be positive");
  }
  const double cos_tolerance = std::cos(options.normal_tolerance_rad);
  const Eigen::Matrix3d& R = X_SceneBox.linear();
  std::size_t continued = 0, probed = 0;
  std::vector<std::int32_t> near;
  for (int k = 0; k < 3; ++k) {
    for (double sign : {1.0, -1.0}) {
      const Eigen::Vector3d n = sign * R.col(k);
      const Eigen::Vector3d face_centre = X_SceneBox.translation() + n * half_size[k];
      if (n.dot(viewpoint - face_centre) <= 0.0) continue;  // Faces away from the sensor.
      // The face's four edges: along axis a, at +-half_size[b] across it.
      for (int a : {(k + 1) % 3, (k + 2) % 3}) {
        const int b = 3 - k - a;
        const int steps = std::max(1, static_cast<int>(2.0 * half_size[a] / options.spacing_m));
        for (double side : {1.0, -1.0}) {
          const Eigen::Vector3d out = side * R.col(b);
          const Eigen::Vector3d edge_mid = face_centre + out * (half_size[b] + options.offset_m);
          for (int i = 0; i < steps; ++i) {
            const double t = -half_size[a] + (i + 0.5) * 2.0 * half_size[a] / steps;
            const Eigen::Vector3d probe = edge_mid + R.col(a) * t;
            ++probed;
            tree.RadiusSearch(probe.cast<float>(), static_cast<float>(options.match_radius_m),
                              &near);
            for (std::int32_t j : near) {
              const Eigen::Vector3d q = scene.points[j].cast<double>();
              const Eigen::Vector3d nq = scene.normals[j].cast<double>();
              if (std::abs((q - face_centre).dot(n)) <= options.plane_tolerance_m &&
                  std::abs(nq.dot(n)) >= cos_tolerance) {
                ++continued;
                break;
              }
            }
          }
        }
      }
    }
  }
  return probed == 0 ? 0.0 : static_cast<double>(continued) / static_cast<double>(probed);
}

std::vector<Eigen::Isometry3d> NearSquareQuarterTurns(const Eigen::Vector3d& half_size,
                                                      const Eigen::Vector3d& p_ItemCentre,
                                                      double tolerance) {
  if (!(half_size.array() > 0.0).all() || !half_size.allFinite() || !p_ItemCentre.allFinite()) {
    throw std::invalid_argument("NearSquareQuarterTurns: half sizes must be positive and finite");
  }
  if (!(tolerance >= 0.0)) {
    throw std::invalid_argument("NearSquareQuarterTurns: tolerance must be >= 0");
  }
  std::vector<Eigen::Isometry3d> turns;
  for (int axis = 0; axis < 3; ++axis) {
    const double a = half_size((axis + 1) % 3);
    const double b = half_size((axis + 2) % 3);
    if (std::abs(a - b) > tolerance * std::max(a, b)) continue;
    turns.push_back(Eigen::Translation3d(p_ItemCentre) *
                    Eigen::AngleAxisd(0.5 * M_PI, Eigen::Vector3d::Unit(axis)) *
                    Eigen::Translation3d(-p_ItemCentre));
  }
  return turns;
}

PosePolish PolishTranslation(
    const Eigen::Isometry3d& X, double score, const std::vector<int>& axes, double step_m,
    int levels, const std::function<std::optional<double>(const Eigen::Isometry3d&)>& score_of) {
  if (!(step_m > 0.0) || !std::isfinite(step_m) || levels < 0) {
    throw std::invalid_argument("PolishTranslation: step_m must be > 0 and levels >= 0");
  }
  for (int axis : axes) {
    if (axis < 0 || axis > 2) throw std::invalid_argument("PolishTranslation: axes are 0, 1, 2");
  }
  if (!score_of) throw std::invalid_argument("PolishTranslation: no score function");
  PosePolish best{X, score, 0};
  double step = step_m;
  for (int level = 0; level < levels; ++level, step *= 0.5) {
    // Bounded: a score that keeps rising a little along a long surface does not walk the
    // pose off along it.
    for (int moves = 0; moves < kMaxPolishMoves; ++moves) {
      // The best of the moves from the current pose; taken when it scores higher.
      Eigen::Isometry3d move_X = best.X;
      double move_score = best.score;
      for (int axis : axes) {
        for (const double sign : {-1.0, 1.0}) {
          Eigen::Isometry3d candidate = best.X;
          candidate.translation() += best.X.linear().col(axis) * (sign * step);
          const std::optional<double> s = score_of(candidate);
          if (!s) {  // out of time: the best pose scored so far
            if (move_score > best.score) {
              best.X = move_X;
              best.score = move_score;
            }
            return best;
          }
          ++best.evaluations;
          if (*s > move_score) {
            move_X = candidate;
            move_score = *s;
          }
        }
      }
      if (!(move_score > best.score)) break;
      best.X = move_X;
      best.score = move_score;
    }
  }
  return best;
}

}  // namespace picking::detector
