#include "services/planner/core/scene.h"

#include <octomap/OcTree.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/surface/convex_hull.h>

#include <algorithm>
#include <cmath>
#include <iterator>
#include <stdexcept>

namespace picking::planner {
namespace {

constexpr int kKeyOffset = 32768;  // OctoMap's tree_max_val for 16 levels

std::uint64_t PackKey(std::uint32_t kx, std::uint32_t ky, std::uint32_t kz) {
  return (static_cast<std::uint64_t>(kz) << 32) | (static_cast<std::uint64_t>(ky) << 16) | kx;
}

Eigen::Vector3d KeyCentre(std::uint64_t key, double resolution) {
  const int kx = static_cast<int>(key & 0xffff), ky = static_cast<int>((key >> 16) & 0xffff),
            kz = static_cast<int>((key >> 32) & 0xffff);
  return Eigen::Vector3d(kx - kKeyOffset + 0.5, ky - kKeyOffset + 0.5, kz - kKeyOffset + 0.5) *
         resolution;
}

// Cut-outs with their bounds, ready for per-point tests.
struct PreparedCut {
  const SceneCutOut* cut;
  Eigen::AlignedBox3d bounds;
};

std::vector<PreparedCut> Prepare(const std::vector<SceneCutOut>& cut_outs) {
  std::vector<PreparedCut> out;
  for (const auto& c : cut_outs) {
    if (c.hull_Base.planes.empty()) continue;
    out.push_back({&c, c.hull_Base.Bounds(c.margin_m)});
  }
  return out;
}

bool InsideAny(const std::vector<PreparedCut>& cuts, const Eigen::Vector3d& p) {
  for (const auto& c : cuts) {
    if (c.bounds.contains(p) && c.cut->hull_Base.Contains(p, c.cut->margin_m)) return true;
  }
  return false;
}

}  // namespace

Eigen::AlignedBox3d ConvexHull::Bounds(double margin_m) const {
  Eigen::AlignedBox3d box;
  for (const auto& v : vertices) box.extend(v);
  if (!box.isEmpty()) {
    box.min().array() -= margin_m;
    box.max().array() += margin_m;
  }
  return box;
}

ConvexHull ConvexHull::Transformed(const Eigen::Isometry3d& X_NewOld) const {
  ConvexHull out;
  out.planes.reserve(planes.size());
  for (const auto& h : planes) {
    const Eigen::Vector3d n = X_NewOld.linear() * h.head<3>();
    Eigen::Vector4d g;
    g << n, h[3] + n.dot(X_NewOld.translation());
    out.planes.push_back(g);
  }
  for (const auto& v : vertices) out.vertices.push_back(X_NewOld * v);
  return out;
}

ConvexHull ComputeConvexHull(const std::vector<Eigen::Vector3f>& points) {
  if (points.size() < 4) throw std::invalid_argument("convex hull needs at least 4 points");
  pcl::PointCloud<pcl::PointXYZ>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZ>);
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& p : points) {
    if (!p.allFinite()) throw std::invalid_argument("convex hull of non-finite points");
    cloud->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
    centroid += p.cast<double>();
  }
  centroid /= static_cast<double>(points.size());
  pcl::ConvexHull<pcl::PointXYZ> qhull;
  qhull.setDimension(3);
  qhull.setInputCloud(cloud);
  pcl::PointCloud<pcl::PointXYZ> hull_points;
  std::vector<pcl::Vertices> polygons;
  qhull.reconstruct(hull_points, polygons);
  if (polygons.size() < 4) throw std::invalid_argument("convex hull of a flat point set");
  ConvexHull hull;
  for (const auto& p : hull_points) hull.vertices.emplace_back(p.x, p.y, p.z);
  for (const auto& polygon : polygons) {
    if (polygon.vertices.size() < 3) continue;
    // Newell's normal of the facet, turned to point away from the centroid.
    Eigen::Vector3d n = Eigen::Vector3d::Zero();
    const std::size_t k = polygon.vertices.size();
    for (std::size_t i = 0; i < k; ++i) {
      const Eigen::Vector3d a = hull.vertices[polygon.vertices[i]];
      const Eigen::Vector3d b = hull.vertices[polygon.vertices[(i + 1) % k]];
      n += a.cross(b);
    }
    if (n.norm() < 1e-12) continue;
    n.normalize();
    const Eigen::Vector3d p0 = hull.vertices[polygon.vertices[0]];
    if (n.dot(p0 - centroid) < 0.0) n = -n;
    double d = n.dot(p0);
    for (std::uint32_t i : polygon.vertices) d = std::max(d, n.dot(hull.vertices[i]));
    // Merge with a plane of (nearly) the same normal: keep the outer one, so the result
    // still holds every point.
    bool merged = false;
    for (auto& h : hull.planes) {
      if (h.head<3>().dot(n) > std::cos(1e-3)) {
        h[3] = std::max(h[3], d);
        merged = true;
        break;
      }
    }
    if (!merged) hull.planes.emplace_back(n.x(), n.y(), n.z(), d);
  }
  return hull;
}

ScanScene::ScanScene(const ScanSceneOptions& options) : options_(options) {
  if (!(options_.resolution_m >= 0.001 && options_.resolution_m <= 0.2)) {
    throw std::invalid_argument("scene resolution must be within [0.001, 0.2] m");
  }
  if (!(options_.max_extent_m > 0.0 &&
        options_.max_extent_m * 2.0 / options_.resolution_m < 2.0 * kKeyOffset - 2.0)) {
    throw std::invalid_argument("scene extent must be > 0 and fit OctoMap's key range");
  }
  if (!(options_.grid_margin_m > 0.0)) {
    throw std::invalid_argument("scene grid margin must be > 0");
  }
}

bool ScanScene::OnKnownSurface(const Eigen::Vector3f& p) const {
  for (const DistanceGrid* grid : options_.known_surfaces) {
    if (grid->Clearance(p) < options_.known_surface_distance_m) return true;
  }
  return false;
}

SceneUpdateStats ScanScene::Insert(const float* xyz_Base, std::size_t count,
                                   const std::vector<SceneCutOut>& cut_outs) {
  SceneUpdateStats stats;
  stats.points = count;
  const double h = options_.resolution_m;
  Eigen::AlignedBox3d region = options_.region_Base;
  const Eigen::AlignedBox3d reach(Eigen::Vector3d::Constant(-options_.max_extent_m),
                                  Eigen::Vector3d::Constant(options_.max_extent_m));
  region = region.isEmpty() ? reach : region.intersection(reach);
  const std::vector<PreparedCut> cuts = Prepare(cut_outs);

  // Pass 1: the bounds of the points kept, in voxel keys.
  Eigen::Array3i lo = Eigen::Array3i::Constant(1 << 30), hi = Eigen::Array3i::Constant(-(1 << 30));
  for (std::size_t i = 0; i < count; ++i) {
    const float* p = xyz_Base + 3 * i;
    if (!(std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]))) continue;
    const Eigen::Vector3d q(p[0], p[1], p[2]);
    if (!region.contains(q)) continue;
    const Eigen::Array3i k = (q.array() / h).floor().cast<int>();
    lo = lo.min(k);
    hi = hi.max(k);
  }
  std::vector<std::uint64_t> added;
  if ((hi >= lo).all()) {
    const Eigen::Array3i n = hi - lo + 1;
    const std::size_t nxy = static_cast<std::size_t>(n.x()) * n.y();
    std::vector<std::uint64_t> bits((nxy * n.z() + 63) / 64, 0);
    // Pass 2: mark the voxels of the points that are kept.
    for (std::size_t i = 0; i < count; ++i) {
      const float* p = xyz_Base + 3 * i;
      if (!(std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]))) {
        ++stats.points_invalid;
        continue;
      }
      const Eigen::Vector3d q(p[0], p[1], p[2]);
      if (!region.contains(q)) {
        ++stats.points_outside;
        continue;
      }
      if (!cuts.empty() && InsideAny(cuts, q)) {
        ++stats.points_cut;
        continue;
      }
      if (OnKnownSurface(q.cast<float>())) {
        ++stats.points_static;
        continue;
      }
      const Eigen::Array3i k = (q.array() / h).floor().cast<int>() - lo;
      const std::size_t index = k.z() * nxy + static_cast<std::size_t>(k.y()) * n.x() + k.x();
      bits[index >> 6] |= std::uint64_t{1} << (index & 63);
    }
    // The set bits in index order are the keys in sorted order (z, then y, then x).
    for (std::size_t w = 0; w < bits.size(); ++w) {
      std::uint64_t word = bits[w];
      while (word) {
        const int b = __builtin_ctzll(word);
        word &= word - 1;
        const std::size_t index = w * 64 + b;
        const int kz = static_cast<int>(index / nxy);
        const std::size_t rest = index - kz * nxy;
        const int ky = static_cast<int>(rest / n.x()), kx = static_cast<int>(rest % n.x());
        added.push_back(
            PackKey(kx + lo.x() + kKeyOffset, ky + lo.y() + kKeyOffset, kz + lo.z() + kKeyOffset));
      }
    }
  } else {
    for (std::size_t i = 0; i < count; ++i) {
      const float* p = xyz_Base + 3 * i;
      if (!(std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]))) {
        ++stats.points_invalid;
      } else {
        ++stats.points_outside;
      }
    }
  }
  const std::size_t before = keys_.size();
  std::vector<std::uint64_t> merged;
  merged.reserve(keys_.size() + added.size());
  std::set_union(keys_.begin(), keys_.end(), added.begin(), added.end(),
                 std::back_inserter(merged));
  keys_.swap(merged);
  stats.voxels_added = keys_.size() - before;
  stats.voxels_cleared = Cut(cut_outs);
  stats.voxels_total = keys_.size();
  return stats;
}

std::size_t ScanScene::Cut(const std::vector<SceneCutOut>& cut_outs) {
  const std::vector<PreparedCut> cuts = Prepare(cut_outs);
  if (cuts.empty()) return 0;
  const double h = options_.resolution_m;
  const std::size_t before = keys_.size();
  keys_.erase(std::remove_if(keys_.begin(), keys_.end(),
                             [&](std::uint64_t key) { return InsideAny(cuts, KeyCentre(key, h)); }),
              keys_.end());
  return before - keys_.size();
}

std::vector<Eigen::Vector3f> ScanScene::VoxelCentres() const {
  std::vector<Eigen::Vector3f> centres;
  centres.reserve(keys_.size());
  for (std::uint64_t key : keys_) {
    centres.push_back(KeyCentre(key, options_.resolution_m).cast<float>());
  }
  return centres;
}

std::shared_ptr<const ScanObstacles> ScanScene::Snapshot() const {
  auto obstacles = std::make_shared<ScanObstacles>();
  obstacles->num_occupied_voxels = keys_.size();
  DistanceGridOptions grid_options;
  grid_options.resolution_m = options_.resolution_m;
  grid_options.margin_m = options_.grid_margin_m;
  grid_options.seed_allowance_m = 0.0;  // voxel centres are cell centres (aligned grid)
  grid_options.align_to_resolution = true;
  obstacles->voxel_centres_Base = VoxelCentres();
  obstacles->voxel_m = options_.resolution_m;
  obstacles->grid = DistanceGrid::Build(obstacles->voxel_centres_Base, grid_options);
  if (!obstacles->grid.empty()) {
    const DistanceGrid& grid = obstacles->grid;
    obstacles->blocks = BlockBound::FromFunction(
        grid.bounds_F(), 0.02f,
        [&grid](const Eigen::AlignedBox3f& block) { return grid.LowerBoundIn(block); },
        grid.outside_clearance_m());
  }
  if (options_.build_octree) {
    auto tree = std::make_shared<octomap::OcTree>(options_.resolution_m);
    const float occupied = tree->getClampingThresMaxLog();
    for (std::uint64_t key : keys_) {
      const octomap::OcTreeKey k(static_cast<octomap::key_type>(key & 0xffff),
                                 static_cast<octomap::key_type>((key >> 16) & 0xffff),
                                 static_cast<octomap::key_type>((key >> 32) & 0xffff));
      tree->setNodeValue(k, occupied, /*lazy_eval=*/true);
    }
    tree->updateInnerOccupancy();
    obstacles->octree = std::move(tree);
  }
  return obstacles;
}

}  // namespace picking::planner
