#include "services/planner/core/distance_grid.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace picking::planner {
namespace {

// "Far": large but finite, so the parabola intersections stay well defined.
constexpr double kFar = 1e20;

// Felzenszwalb & Huttenlocher's 1-D squared distance transform of f (n samples, unit
// spacing) into d: the lower envelope of the parabolas (q - p)^2 + f(p). v and z are scratch
// space of at least n and n + 1 entries.
void Transform1d(const double* f, int n, double* d, int* v, double* z) {
  int k = 0;
  v[0] = 0;
  z[0] = -kFar;
  z[1] = kFar;
  for (int q = 1; q < n; ++q) {
    double s = ((f[q] + double(q) * q) - (f[v[k]] + double(v[k]) * v[k])) / (2.0 * (q - v[k]));
    while (s <= z[k]) {
      --k;
      s = ((f[q] + double(q) * q) - (f[v[k]] + double(v[k]) * v[k])) / (2.0 * (q - v[k]));
    }
    ++k;
    v[k] = q;
    z[k] = s;
    z[k + 1] = kFar;
  }
  k = 0;
  for (int q = 0; q < n; ++q) {
    while (z[k + 1] < q) ++k;
    const double dq = double(q - v[k]);
    d[q] = dq * dq + f[v[k]];
  }
}

// Runs the 1-D transform along one axis of the nx * ny * nz volume (stride of the axis,
// count along it, and the strides/counts of the other two).
void TransformAxis(std::vector<double>& volume, int n, std::size_t stride, int n1,
                   std::size_t stride1, int n2, std::size_t stride2) {
  std::vector<double> f(n), d(n), z(n + 1);
  std::vector<int> v(n);
  for (int b = 0; b < n2; ++b) {
    for (int a = 0; a < n1; ++a) {
      const std::size_t base = a * stride1 + b * stride2;
      for (int i = 0; i < n; ++i) f[i] = volume[base + i * stride];
      Transform1d(f.data(), n, d.data(), v.data(), z.data());
      for (int i = 0; i < n; ++i) volume[base + i * stride] = d[i];
    }
  }
}

}  // namespace

DistanceGrid DistanceGrid::Build(const std::vector<Eigen::Vector3f>& seeds_F,
                                 const DistanceGridOptions& options, std::size_t max_cells) {
  if (!(options.resolution_m > 0.0) || !std::isfinite(options.resolution_m)) {
    throw std::invalid_argument("distance grid resolution must be finite and > 0");
  }
  if (!(options.margin_m > 0.0) || !std::isfinite(options.margin_m)) {
    throw std::invalid_argument("distance grid margin must be finite and > 0");
  }
  if (!(options.seed_allowance_m >= 0.0) || !std::isfinite(options.seed_allowance_m)) {
    throw std::invalid_argument("distance grid seed allowance must be finite and >= 0");
  }
  DistanceGrid grid;
  grid.resolution_ = static_cast<float>(options.resolution_m);
  grid.inv_resolution_ = 1.f / grid.resolution_;
  // 10 micrometres cover the float rounding of the query arithmetic.
  grid.allowance_m_ = static_cast<float>(0.5 * std::sqrt(3.0) * options.resolution_m +
                                         options.seed_allowance_m + 1e-5);
  grid.outside_clearance_m_ = 1e3f;
  if (seeds_F.empty()) return grid;

  Eigen::AlignedBox3f box;
  for (const auto& p : seeds_F) {
    if (!p.allFinite()) throw std::invalid_argument("distance grid: non-finite seed point");
    box.extend(p);
  }
  const double h = options.resolution_m;
  Eigen::Vector3d lo = box.min().cast<double>().array() - options.margin_m;
  Eigen::Vector3d hi = box.max().cast<double>().array() + options.margin_m;
  if (options.align_to_resolution) {
    lo = (lo / h).array().floor() * h;
    hi = (hi / h).array().ceil() * h;
  }
  const Eigen::Vector3d cells = ((hi - lo) / h).array().ceil().max(1.0);
  if (cells.prod() > static_cast<double>(max_cells)) {
    throw std::invalid_argument("distance grid of " + std::to_string(cells.prod()) +
                                " cells exceeds the limit of " + std::to_string(max_cells));
  }
  grid.nx_ = static_cast<int>(cells.x());
  grid.ny_ = static_cast<int>(cells.y());
  grid.nz_ = static_cast<int>(cells.z());
  grid.origin_F_ = lo.cast<float>();
  grid.size_f_ = Eigen::Vector3f(grid.nx_, grid.ny_, grid.nz_);
  grid.outside_clearance_m_ = static_cast<float>(options.margin_m - options.seed_allowance_m);

  const std::size_t nxy = static_cast<std::size_t>(grid.nx_) * grid.ny_;
  std::vector<double> volume(nxy * grid.nz_, kFar);
  for (const auto& p : seeds_F) {
    const Eigen::Vector3d u = (p.cast<double>() - lo) / h;
    const int ix = std::clamp(static_cast<int>(u.x()), 0, grid.nx_ - 1);
    const int iy = std::clamp(static_cast<int>(u.y()), 0, grid.ny_ - 1);
    const int iz = std::clamp(static_cast<int>(u.z()), 0, grid.nz_ - 1);
    volume[iz * nxy + static_cast<std::size_t>(iy) * grid.nx_ + ix] = 0.0;
  }
  TransformAxis(volume, grid.nx_, 1, grid.ny_, grid.nx_, grid.nz_, nxy);
  TransformAxis(volume, grid.ny_, grid.nx_, grid.nx_, 1, grid.nz_, nxy);
  TransformAxis(volume, grid.nz_, nxy, grid.nx_, 1, grid.ny_, grid.nx_);

  grid.distance_01mm_.resize(volume.size());
  const double to_units = h * 1e4;  // cells -> 0.1 mm
  for (std::size_t i = 0; i < volume.size(); ++i) {
    const double d = std::sqrt(volume[i]) * to_units;
    grid.distance_01mm_[i] = static_cast<std::uint16_t>(std::min(65535.0, std::floor(d)));
  }
  return grid;
}

void DistanceGrid::Tighten(float band_m,
                           const std::vector<std::array<Eigen::Vector3f, 3>>& triangles_F) {
  if (!(band_m >= 0.f) || !std::isfinite(band_m)) {
    throw std::invalid_argument("distance grid: the exact band must be finite and >= 0");
  }
  if (distance_01mm_.empty()) return;
  // Stored values hold (bound at the centre + allowance) in 0.1 mm, rounded down, so that
  // Clearance keeps one formula for tightened and seeded cells. A band cell starts at the
  // band (no triangle nearer) and takes the nearest triangle's distance; a triangle farther
  // than the band from a cell cannot lower it. A cell outside the band is farther than the
  // band from every triangle (its seeded bound says so), so no triangle lowers it either.
  exact_cap_01mm_ =
      static_cast<std::uint16_t>(std::min(65535.f, std::floor((band_m + allowance_m_) * 1e4f)));
  for (std::uint16_t& d : distance_01mm_) {
    if (d < exact_cap_01mm_) d = exact_cap_01mm_;
  }
  // Larger triangles first: the plane test in TightenNear then skips most cells of the
  // small ones.
  std::vector<std::pair<float, std::size_t>> by_area;
  by_area.reserve(triangles_F.size());
  for (std::size_t i = 0; i < triangles_F.size(); ++i) {
    const auto& t = triangles_F[i];
    by_area.emplace_back(-(t[1] - t[0]).cross(t[2] - t[0]).norm(), i);
  }
  std::sort(by_area.begin(), by_area.end());
  for (const auto& [minus_area, i] : by_area) TightenNear(triangles_F[i], band_m);
}

void DistanceGrid::TightenNear(const std::array<Eigen::Vector3f, 3>& t, float band_m) {
  const Eigen::Vector3i max_cell(nx_ - 1, ny_ - 1, nz_ - 1);
  auto cell_of = [&](const Eigen::Vector3f& p) -> Eigen::Vector3i {
    const Eigen::Vector3f u = ((p - origin_F_) * inv_resolution_).array().floor();
    return u.cwiseMax(0.f).cwiseMin(max_cell.cast<float>()).cast<int>();
  };
  const Eigen::Vector3i lo = cell_of(t[0].cwiseMin(t[1]).cwiseMin(t[2]).array() - band_m);
  const Eigen::Vector3i hi = cell_of(t[0].cwiseMax(t[1]).cwiseMax(t[2]).array() + band_m);
  // Walk the cells along the axis k nearest the normal only within the band's slab around
  // the triangle's plane (the band over |n_k| either side), so that a large panel visits the
  // cells near it and not its whole bounding box. A degenerate triangle visits its box.
  Eigen::Vector3f n = (t[1] - t[0]).cross(t[2] - t[0]);
  const bool flat = n.norm() > 1e-12f;
  n = flat ? n.normalized() : Eigen::Vector3f::UnitZ();
  int k = 0;
  n.cwiseAbs().maxCoeff(&k);
  const int i_axis = (k + 1) % 3, j_axis = (k + 2) % 3;
  const float half_k = flat ? band_m / std::abs(n[k]) + 0.5f * resolution_ : 1e9f;
  const std::size_t nxy = static_cast<std::size_t>(nx_) * ny_;
  const std::size_t stride_k = k == 0 ? 1 : k == 1 ? static_cast<std::size_t>(nx_) : nxy;
  Eigen::Vector3i c = lo;
  for (c[j_axis] = lo[j_axis]; c[j_axis] <= hi[j_axis]; ++c[j_axis]) {
    for (c[i_axis] = lo[i_axis]; c[i_axis] <= hi[i_axis]; ++c[i_axis]) {
      Eigen::Vector3f centre = origin_F_ + (c.cast<float>().array() + 0.5f).matrix() * resolution_;
      const float on_plane = t[0][k] - (n[i_axis] * (centre[i_axis] - t[0][i_axis]) +
                                        n[j_axis] * (centre[j_axis] - t[0][j_axis])) /
                                           n[k];
      const float k_lo = (on_plane - half_k - origin_F_[k]) * inv_resolution_;
      const float k_hi = (on_plane + half_k - origin_F_[k]) * inv_resolution_;
      const int from = std::max<float>(lo[k], std::floor(std::max(k_lo, -1.f)));
      const int to = std::min<float>(hi[k], std::floor(std::min(k_hi, 1e7f)));
      c[k] = from;
      std::size_t i = c.z() * nxy + static_cast<std::size_t>(c.y()) * nx_ + c.x();
      for (int m = from; m <= to; ++m, i += stride_k) {
        centre[k] = origin_F_[k] + (m + 0.5f) * resolution_;
        // The plane's distance is a lower bound of the triangle's: most cells of a small
        // triangle already hold a nearer panel's distance.
        if (flat && std::floor((std::abs(n.dot(centre - t[0])) + allowance_m_) * 1e4f) >=
                        distance_01mm_[i]) {
          continue;
        }
        const float d = std::sqrt(PointTriangleDistance2(centre, t[0], t[1], t[2]));
        const float units = std::floor((d + allowance_m_) * 1e4f);
        if (units < distance_01mm_[i]) distance_01mm_[i] = static_cast<std::uint16_t>(units);
      }
    }
  }
}

float PointTriangleDistance2(const Eigen::Vector3f& p, const Eigen::Vector3f& a,
                             const Eigen::Vector3f& b, const Eigen::Vector3f& c) {
  const Eigen::Vector3f ab = b - a, ac = c - a, ap = p - a;
  const float d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0.f && d2 <= 0.f) return ap.squaredNorm();
  const Eigen::Vector3f bp = p - b;
  const float d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0.f && d4 <= d3) return bp.squaredNorm();
  const float vc = d1 * d4 - d3 * d2;
  if (vc <= 0.f && d1 >= 0.f && d3 <= 0.f) {
    const float v = d1 / (d1 - d3);
    return (a + v * ab - p).squaredNorm();
  }
  const Eigen::Vector3f cp = p - c;
  const float d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0.f && d5 <= d6) return cp.squaredNorm();
  const float vb = d5 * d2 - d1 * d6;
  if (vb <= 0.f && d2 >= 0.f && d6 <= 0.f) {
    const float w = d2 / (d2 - d6);
    return (a + w * ac - p).squaredNorm();
  }
  const float va = d3 * d6 - d5 * d4;
  if (va <= 0.f && (d4 - d3) >= 0.f && (d5 - d6) >= 0.f) {
    const float w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return (b + w * (c - b) - p).squaredNorm();
  }
  const float denom = 1.f / (va + vb + vc);
  const float v = vb * denom, w = vc * denom;
  return (a + ab * v + ac * w - p).squaredNorm();
}

DistanceGrid::Bounds DistanceGrid::NearBounds(const Eigen::Vector3f& p_F) const {
  constexpr float kInfinity = std::numeric_limits<float>::infinity();
  const Eigen::Vector3f u = (p_F - origin_F_) * inv_resolution_;
  if (!(u.x() >= 0.f && u.y() >= 0.f && u.z() >= 0.f && u.x() < size_f_.x() &&
        u.y() < size_f_.y() && u.z() < size_f_.z())) {
    return {outside_clearance_m_, kInfinity};
  }
  // The centres around p: cells floor(u - 0.5) and the next, kept inside the grid (a centre
  // farther away still gives valid, looser bounds).
  const Eigen::Vector3f v = u.array() - 0.5f;
  const Eigen::Vector3i max_cell(nx_ - 1, ny_ - 1, nz_ - 1);
  const Eigen::Vector3i first =
      v.array().floor().cast<int>().max(0).min((max_cell.array() - 1).max(0)).matrix();
  Bounds bounds{-kInfinity, kInfinity};
  for (int k = 0; k < 8; ++k) {
    const Eigen::Vector3i cell =
        (first + Eigen::Vector3i(k & 1, (k >> 1) & 1, (k >> 2) & 1)).cwiseMin(max_cell);
    const std::uint16_t stored =
        distance_01mm_[(static_cast<std::size_t>(cell.z()) * ny_ + cell.y()) * nx_ + cell.x()];
    const float away = ((cell.cast<float>().array() + 0.5f).matrix() - u).norm() * resolution_;
    const float at_centre = stored * 1e-4f - allowance_m_;
    bounds.lower_m = std::max(bounds.lower_m, at_centre - away);
    if (stored < exact_cap_01mm_) {
      // The stored value was rounded down by up to 0.1 mm.
      bounds.upper_m = std::min(bounds.upper_m, at_centre + 1e-4f + away + 1e-5f);
    }
  }
  return bounds;
}

float DistanceGrid::LowerBoundIn(const Eigen::AlignedBox3f& box_F) const {
  if (distance_01mm_.empty()) return outside_clearance_m_;
  const Eigen::Vector3f lo = (box_F.min() - origin_F_) * inv_resolution_;
  const Eigen::Vector3f hi = (box_F.max() - origin_F_) * inv_resolution_;
  float bound = std::numeric_limits<float>::infinity();
  if ((lo.array() < 0.f).any() || (hi.array() >= size_f_.array()).any()) {
    bound = outside_clearance_m_;
  }
  const Eigen::Vector3i a = lo.array().floor().max(0.f).cast<int>();
  const Eigen::Vector3i b = hi.array().floor().min(size_f_.array() - 1.f).cast<int>();
  std::uint16_t smallest = 65535;
  for (int z = a.z(); z <= b.z(); ++z) {
    for (int y = a.y(); y <= b.y(); ++y) {
      const std::size_t row = (static_cast<std::size_t>(z) * ny_ + y) * nx_;
      for (int x = a.x(); x <= b.x(); ++x) smallest = std::min(smallest, distance_01mm_[row + x]);
    }
  }
  if (a.x() <= b.x() && a.y() <= b.y() && a.z() <= b.z()) {
    // Any point of a cell is within half its diagonal of the centre the value was taken at.
    bound = std::min(bound, smallest * 1e-4f - allowance_m_ - 0.5f * std::sqrt(3.f) * resolution_);
  }
  return bound;
}

BlockBound BlockBound::FromFunction(
    const Eigen::AlignedBox3f& box_F, float block_m,
    const std::function<float(const Eigen::AlignedBox3f&)>& lower_bound_in,
    float outside_clearance_m) {
  if (box_F.isEmpty() || !(block_m > 0.f)) {
    throw std::invalid_argument("block bound: the box must not be empty, the blocks > 0");
  }
  BlockBound blocks;
  const Eigen::Vector3i n = (box_F.sizes() / block_m).array().ceil().max(1.f).cast<int>();
  blocks.origin_F_ = box_F.min();
  blocks.inv_block_m_ = 1.f / block_m;
  blocks.size_f_ = n.cast<float>();
  blocks.nx_ = n.x();
  blocks.ny_ = n.y();
  blocks.outside_clearance_m_ = outside_clearance_m;
  blocks.bound_01mm_.resize(static_cast<std::size_t>(n.x()) * n.y() * n.z());
  std::size_t i = 0;
  for (int z = 0; z < n.z(); ++z) {
    for (int y = 0; y < n.y(); ++y) {
      for (int x = 0; x < n.x(); ++x, ++i) {
        const Eigen::Vector3f lo = box_F.min() + Eigen::Vector3f(x, y, z) * block_m;
        const float d =
            lower_bound_in(Eigen::AlignedBox3f(lo, lo + Eigen::Vector3f::Constant(block_m)));
        blocks.bound_01mm_[i] =
            static_cast<std::uint16_t>(std::clamp(std::floor(d * 1e4f), 0.f, 65535.f));
      }
    }
  }
  return blocks;
}

Eigen::AlignedBox3f DistanceGrid::bounds_F() const {
  return Eigen::AlignedBox3f(origin_F_, origin_F_ + size_f_ * resolution_);
}

void SampleSurface(const std::vector<Eigen::Vector3f>& vertices,
                   const std::vector<std::array<std::uint32_t, 3>>& triangles,
                   const Eigen::Isometry3d& X_FMesh, double gap_m,
                   std::vector<Eigen::Vector3f>* points_F) {
  if (!(gap_m > 0.0)) throw std::invalid_argument("SampleSurface: gap must be > 0");
  const Eigen::Isometry3f X = X_FMesh.cast<float>();
  const float max_edge = static_cast<float>(gap_m * std::sqrt(3.0));
  for (const auto& t : triangles) {
    const Eigen::Vector3f a = X * vertices.at(t[0]), b = X * vertices.at(t[1]),
                          c = X * vertices.at(t[2]);
    const float longest = std::max({(b - a).norm(), (c - b).norm(), (a - c).norm()});
    const int n = std::max(1, static_cast<int>(std::ceil(longest / max_edge)));
    // Vertices of the n x n subdivision: every small triangle's edges are the big one's / n.
    for (int i = 0; i <= n; ++i) {
      for (int j = 0; j <= n - i; ++j) {
        const float u = float(i) / n, v = float(j) / n;
        points_F->push_back(a + u * (b - a) + v * (c - a));
      }
    }
  }
}

}  // namespace picking::planner
