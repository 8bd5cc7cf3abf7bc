#include "libs/world/mesh_ray_caster.h"

#include <algorithm>
#include <stdexcept>

#include "libs/world/mesh_utils.h"

namespace picking::world {
namespace {

constexpr std::uint32_t kLeafSize = 4;

bool RayBox(const Eigen::Vector3d& o, const Eigen::Vector3d& inv_d, const Eigen::Vector3f& lo,
            const Eigen::Vector3f& hi, double t_min, double t_max) {
  for (int k = 0; k < 3; ++k) {
    double t0 = (lo[k] - o[k]) * inv_d[k];
    double t1 = (hi[k] - o[k]) * inv_d[k];
    if (t0 > t1) std::swap(t0, t1);
    // NaN from 0 * inf (ray in the slab plane) must not reject: compare so NaN passes.
    if (t0 > t_min) t_min = t0;
    if (t1 < t_max) t_max = t1;
    if (t_min > t_max) return false;
  }
  return true;
}

// Moller-Trumbore, both faces. Returns the distance or a negative value.
double RayTriangle(const Eigen::Vector3d& o, const Eigen::Vector3d& d, const Eigen::Vector3d& a,
                   const Eigen::Vector3d& b, const Eigen::Vector3d& c) {
  const Eigen::Vector3d e1 = b - a;
  const Eigen::Vector3d e2 = c - a;
  const Eigen::Vector3d p = d.cross(e2);
  const double det = e1.dot(p);
  if (std::abs(det) < 1e-15) return -1.0;
  const double inv = 1.0 / det;
  const Eigen::Vector3d s = o - a;
  const double u = s.dot(p) * inv;
  // A small tolerance keeps rays through shared edges from slipping between two triangles.
  constexpr double kEdge = 1e-9;
  if (u < -kEdge || u > 1.0 + kEdge) return -1.0;
  const Eigen::Vector3d q = s.cross(e1);
  const double v = d.dot(q) * inv;
  if (v < -kEdge || u + v > 1.0 + kEdge) return -1.0;
  return e2.dot(q) * inv;
}

}  // namespace

MeshRayCaster::MeshRayCaster(TriangleMesh mesh) : mesh_(std::move(mesh)) {
  Validate(mesh_);
  if (mesh_.empty())
    throw std::invalid_argument("MeshRayCaster: mesh '" + mesh_.name + "' is empty");
  const auto n = static_cast<std::uint32_t>(mesh_.triangles.size());
  order_.resize(n);
  centroids_.resize(n);
  for (std::uint32_t t = 0; t < n; ++t) {
    order_[t] = t;
    const auto& tri = mesh_.triangles[t];
    centroids_[t] =
        (mesh_.vertices[tri[0]] + mesh_.vertices[tri[1]] + mesh_.vertices[tri[2]]) / 3.0f;
  }
  nodes_.reserve(2 * n / kLeafSize + 1);
  Build(0, n);
}

std::uint32_t MeshRayCaster::Build(std::uint32_t begin, std::uint32_t end) {
  const auto index = static_cast<std::uint32_t>(nodes_.size());
  nodes_.emplace_back();
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::max());
  Eigen::Vector3f hi = -lo;
  Eigen::Vector3f clo = lo, chi = hi;
  for (std::uint32_t i = begin; i < end; ++i) {
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3f& v = mesh_.vertices[mesh_.triangles[order_[i]][k]];
      lo = lo.cwiseMin(v);
      hi = hi.cwiseMax(v);
    }
    clo = clo.cwiseMin(centroids_[order_[i]]);
    chi = chi.cwiseMax(centroids_[order_[i]]);
  }
  nodes_[index].lo = lo;
  nodes_[index].hi = hi;
  if (end - begin <= kLeafSize) {
    nodes_[index].first = begin;
    nodes_[index].count = end - begin;
    return index;
  }
  int axis = 0;
  (chi - clo).maxCoeff(&axis);
  const std::uint32_t mid = begin + (end - begin) / 2;
  std::nth_element(
      order_.begin() + begin, order_.begin() + mid, order_.begin() + end,
      [&](std::uint32_t a, std::uint32_t b) { return centroids_[a][axis] < centroids_[b][axis]; });
  Build(begin, mid);  // left child is index + 1
  const std::uint32_t right = Build(mid, end);
  nodes_[index].first = right;
  nodes_[index].count = 0;
  return index;
}

template <typename Visit>
void MeshRayCaster::Traverse(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_min,
                             double& t_max, Visit&& visit) const {
  const Eigen::Vector3d inv_d = d.cwiseInverse();
  std::uint32_t stack[128];
  int top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const Node& node = nodes_[stack[--top]];
    if (!RayBox(o, inv_d, node.lo, node.hi, t_min, t_max)) continue;
    if (node.count > 0) {
      for (std::uint32_t i = node.first; i < node.first + node.count; ++i) {
        const std::uint32_t t = order_[i];
        const auto& tri = mesh_.triangles[t];
        const double dist = RayTriangle(o, d, mesh_.vertices[tri[0]].cast<double>(),
                                        mesh_.vertices[tri[1]].cast<double>(),
                                        mesh_.vertices[tri[2]].cast<double>());
        if (dist >= t_min && dist <= t_max) visit(t, dist, t_max);
      }
    } else {
      const std::uint32_t self = static_cast<std::uint32_t>(&node - nodes_.data());
      stack[top++] = node.first;
      stack[top++] = self + 1;
    }
  }
}

std::optional<MeshRayHit> MeshRayCaster::Cast(const Eigen::Vector3d& origin,
                                              const Eigen::Vector3d& direction, double t_min,
                                              double t_max) const {
  if (!(direction.norm() > 0.0) || !origin.allFinite()) {
    throw std::invalid_argument("MeshRayCaster::Cast: bad ray");
  }
  const Eigen::Vector3d d = direction.normalized();
  std::optional<MeshRayHit> best;
  Traverse(origin, d, t_min, t_max, [&](std::uint32_t t, double dist, double& t_max_ref) {
    best = MeshRayHit{dist, t, FaceNormal(mesh_, t).cast<double>()};
    t_max_ref = dist;
  });
  return best;
}

std::vector<MeshRayHit> MeshRayCaster::CastAll(const Eigen::Vector3d& origin,
                                               const Eigen::Vector3d& direction, double t_min,
                                               double t_max) const {
  if (!(direction.norm() > 0.0) || !origin.allFinite()) {
    throw std::invalid_argument("MeshRayCaster::CastAll: bad ray");
  }
  const Eigen::Vector3d d = direction.normalized();
  std::vector<MeshRayHit> hits;
  double limit = t_max;
  Traverse(origin, d, t_min, limit, [&](std::uint32_t t, double dist, double&) {
    hits.push_back({dist, t, FaceNormal(mesh_, t).cast<double>()});
  });
  std::sort(hits.begin(), hits.end(),
            [](const MeshRayHit& a, const MeshRayHit& b) { return a.distance_m < b.distance_m; });
  return hits;
}

}  // namespace picking::world
