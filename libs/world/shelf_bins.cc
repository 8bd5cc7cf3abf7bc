#include "libs/world/shelf_bins.h"

#include <algorithm>
#include <optional>
#include <stdexcept>

#include "libs/world/mesh_ray_caster.h"
#include "libs/world/mesh_utils.h"

namespace picking::world {
namespace {

struct Gap {
  double lo, hi;
};

// Free gaps along a ray crossing the whole mesh: intervals between consecutive hits.
std::vector<Gap> FreeGaps(const MeshRayCaster& caster, const Eigen::Vector3d& origin,
                          const Eigen::Vector3d& dir, double min_len, double max_len) {
  const auto hits = caster.CastAll(origin, dir);
  std::vector<Gap> gaps;
  for (std::size_t i = 0; i + 1 < hits.size(); ++i) {
    const double len = hits[i + 1].distance_m - hits[i].distance_m;
    if (len >= min_len && len <= max_len) {
      gaps.push_back({hits[i].distance_m, hits[i + 1].distance_m});
    }
  }
  return gaps;
}

// Running minimum / maximum of the hits of one kind; a ray may miss near the open front (walls
// and ceilings can end before the floor does), but some ray must hit.
struct Extreme {
  double value;
  bool found = false;
  void Min(double v) {
    value = found ? std::min(value, v) : v;
    found = true;
  }
  void Max(double v) {
    value = found ? std::max(value, v) : v;
    found = true;
  }
  double Get(const std::string& what) const {
    if (!found) throw std::runtime_error("MeasureBins: no " + what + " found");
    return value;
  }
};

}  // namespace

std::vector<BinGeometry> MeasureBins(const TriangleMesh& shelf_S,
                                     const MeasureBinsOptions& options) {
  if (options.rows <= 0 || options.columns <= 0 || options.depth_samples < 2 ||
      options.lateral_samples < 1) {
    throw std::invalid_argument(
        "MeasureBins: rows, columns, depth_samples >= 2 and "
        "lateral_samples must be positive");
  }
  const MeshRayCaster caster(shelf_S);
  const Eigen::AlignedBox3d bounds = Bounds(shelf_S);
  const double x_probe =
      bounds.center().x() + options.probe_depth_fraction * (bounds.max().x() - bounds.center().x());
  // Slightly off the centre line so the ray does not run along a mesh edge of a symmetric mesh.
  const double y_probe = bounds.center().y() + 0.0123 * bounds.sizes().y();
  const double margin = 0.1;

  // 1. Rows, from the top.
  const Eigen::Vector3d up_origin(x_probe, y_probe, bounds.min().z() - margin);
  std::vector<Gap> rows = FreeGaps(caster, up_origin, Eigen::Vector3d::UnitZ(),
                                   options.min_row_height_m, options.max_row_height_m);
  if (static_cast<int>(rows.size()) < options.rows) {
    throw std::runtime_error("MeasureBins: found " + std::to_string(rows.size()) +
                             " rows of plausible height, expected " + std::to_string(options.rows));
  }
  // The bins are the highest `rows` gaps (a pod may have taller storage below).
  std::sort(rows.begin(), rows.end(), [](const Gap& a, const Gap& b) { return a.lo > b.lo; });
  rows.resize(options.rows);

  std::vector<BinGeometry> bins;
  for (int r = 0; r < options.rows; ++r) {
    const double z_mid = up_origin.z() + 0.5 * (rows[r].lo + rows[r].hi);
    // 2. Columns, from the left seen from the front (-y).
    const Eigen::Vector3d side_origin(x_probe, bounds.min().y() - margin, z_mid);
    const std::vector<Gap> cols = FreeGaps(caster, side_origin, Eigen::Vector3d::UnitY(),
                                           options.min_column_width_m, options.max_column_width_m);
    if (static_cast<int>(cols.size()) != options.columns) {
      throw std::runtime_error("MeasureBins: row " + std::to_string(r) + " has " +
                               std::to_string(cols.size()) + " bins of plausible width, expected " +
                               std::to_string(options.columns));
    }
    for (int c = 0; c < options.columns; ++c) {
      BinGeometry bin;
      bin.row = r;
      bin.column = c;
      bin.name = std::string("bin_") + static_cast<char>('A' + r * options.columns + c);
      const std::string who = bin.name + ": ";
      // Off the exact middle so rays do not run along the edges of a symmetric mesh.
      const double y_mid =
          side_origin.y() + 0.5 * (cols[c].lo + cols[c].hi) + 0.0037 * (cols[c].hi - cols[c].lo);
      const Eigen::Vector3d centre(x_probe, y_mid, z_mid);
      // 3a. Back wall: the closest of a grid of rays toward -x (the back panel may have
      // slits, e.g. where the pod's halves meet).
      const double half_w = 0.5 * (cols[c].hi - cols[c].lo);
      const double half_h = 0.5 * (rows[r].hi - rows[r].lo);
      Extreme back;
      for (double fy : {-0.6, -0.3, 0.0, 0.3, 0.6}) {
        for (double fz : {-0.6, 0.0, 0.6}) {
          const auto hit = caster.Cast({x_probe, y_mid + fy * half_w, z_mid + fz * half_h},
                                       -Eigen::Vector3d::UnitX());
          if (hit) back.Max(x_probe - hit->distance_m);
        }
      }
      const double back_x = back.Get(who + "back wall");
      // 3b. Opening: the largest x at which a ray down from mid height still meets the floor
      // within the row.
      const double row_half = 0.5 * (rows[r].hi - rows[r].lo);
      const auto has_floor = [&](double x) {
        const auto hit =
            caster.Cast({x, y_mid, z_mid}, -Eigen::Vector3d::UnitZ(), 0.0, row_half + 0.05);
        return hit.has_value();
      };
      double inside = x_probe;
      if (!has_floor(inside)) throw std::runtime_error("MeasureBins: " + who + "no floor");
      double outside = bounds.max().x() + 0.01;
      if (has_floor(outside)) {
        throw std::runtime_error("MeasureBins: " + who + "floor extends past the mesh bounds");
      }
      while (outside - inside > 5e-4) {
        const double mid = 0.5 * (inside + outside);
        (has_floor(mid) ? inside : outside) = mid;
      }
      bin.opening_x_m = inside;
      // 3c. Floor, ceiling and walls over the depth and width.
      Extreme floor_min, floor_max, ceiling_min, left_max, right_min;
      const double x0 = back_x + 0.005;
      const double x1 = bin.opening_x_m - 0.002;
      const double half_width = 0.5 * (cols[c].hi - cols[c].lo);
      const double row_height = rows[r].hi - rows[r].lo;
      const auto cast = [&](const Eigen::Vector3d& p, const Eigen::Vector3d& dir,
                            double limit) -> std::optional<double> {
        const auto hit = caster.Cast(p, dir, 0.0, limit);
        if (!hit) return std::nullopt;
        return hit->distance_m;
      };
      for (int i = 0; i < options.depth_samples; ++i) {
        const double x = x0 + (x1 - x0) * i / (options.depth_samples - 1);
        for (int j = 0; j < options.lateral_samples; ++j) {
          const double f = (j + 1.0) / (options.lateral_samples + 1.0) - 0.5;
          const Eigen::Vector3d p(x, y_mid + f * 1.6 * half_width, z_mid);
          if (const auto d = cast(p, -Eigen::Vector3d::UnitZ(), row_height)) {
            floor_min.Min(z_mid - *d);
            floor_max.Max(z_mid - *d);
          }
          if (const auto d = cast(p, Eigen::Vector3d::UnitZ(), row_height)) {
            ceiling_min.Min(z_mid + *d);
          }
        }
        for (double fz : {-0.35, 0.0, 0.35}) {
          const Eigen::Vector3d p(x, y_mid, z_mid + fz * row_height);
          if (const auto d = cast(p, -Eigen::Vector3d::UnitY(), 2 * half_width)) {
            left_max.Max(y_mid - *d);
          }
          if (const auto d = cast(p, Eigen::Vector3d::UnitY(), 2 * half_width)) {
            right_min.Min(y_mid + *d);
          }
        }
      }
      bin.inner_S = Eigen::AlignedBox3d(
          Eigen::Vector3d(back_x, left_max.Get(who + "left wall"), floor_min.Get(who + "floor")),
          Eigen::Vector3d(bin.opening_x_m, right_min.Get(who + "right wall"),
                          ceiling_min.Get(who + "ceiling")));
      bin.floor_max_z_m = floor_max.Get(who + "floor");
      bins.push_back(bin);
    }
  }
  return bins;
}

}  // namespace picking::world
