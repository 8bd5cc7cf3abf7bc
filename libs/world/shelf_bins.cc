#include "libs/world/shelf_bins.h"

#include <algorithm>
#include <limits>
#include <optional>
#include <stdexcept>

#include "libs/world/mesh_utils.h"
#include "libs/world/ray_scene.h"

namespace picking::world {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

struct Gap {
  double lo, hi;
};

// Free gaps along a ray crossing the whole mesh: intervals between consecutive hits.
std::vector<Gap> FreeGaps(const RayScene& scene, const Eigen::Vector3d& origin,
                          const Eigen::Vector3d& dir, double min_len, double max_len) {
  const auto hits = scene.CastAll(origin, dir);
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
  double value = 0.0;
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

// Where the rays start: the probe's depth inside the shelf, slightly off the centre line so
// rays do not run along the mesh edges of a symmetric mesh.
struct Probe {
  const RayScene& scene;
  Eigen::AlignedBox3d bounds;
  double x = 0.0, y = 0.0;
  double margin = 0.1;
};

// 1. The bins' rows, from the top: the highest `rows` gaps of plausible height up the shelf (a
// pod may have taller storage below), as heights along the ray from up_origin_z.
std::vector<Gap> FindRows(const Probe& probe, const MeasureBinsOptions& options,
                          double up_origin_z) {
  const Eigen::Vector3d up_origin(probe.x, probe.y, up_origin_z);
  std::vector<Gap> rows = FreeGaps(probe.scene, up_origin, Eigen::Vector3d::UnitZ(),
                                   options.min_row_height_m, options.max_row_height_m);
  if (static_cast<int>(rows.size()) < options.rows) {
    throw std::runtime_error("MeasureBins: found " + std::to_string(rows.size()) +
                             " rows of plausible height, expected " + std::to_string(options.rows));
  }
  std::sort(rows.begin(), rows.end(), [](const Gap& a, const Gap& b) { return a.lo > b.lo; });
  rows.resize(options.rows);
  return rows;
}

// 3a. The back wall's x: the closest of a grid of rays toward -x (the back panel may have
// slits, e.g. where the pod's halves meet).
double BackWallX(const Probe& probe, double y_mid, double z_mid, double half_w, double half_h,
                 const std::string& who) {
  Extreme back;
  for (double fy : {-0.6, -0.3, 0.0, 0.3, 0.6}) {
    for (double fz : {-0.6, 0.0, 0.6}) {
      const auto hit = probe.scene.Cast({probe.x, y_mid + fy * half_w, z_mid + fz * half_h},
                                        -Eigen::Vector3d::UnitX(), kInf);
      if (hit) back.Max(probe.x - hit->distance_m);
    }
  }
  return back.Get(who + "back wall");
}

// 3b. The opening's x: the largest x at which a ray down from mid height still meets the
// floor within the row (bisection).
double OpeningX(const Probe& probe, double y_mid, double z_mid, double row_half,
                const std::string& who) {
  const auto has_floor = [&](double x) {
    return probe.scene.Cast({x, y_mid, z_mid}, -Eigen::Vector3d::UnitZ(), row_half + 0.05)
        .has_value();
  };
  double inside = probe.x;
  if (!has_floor(inside)) throw std::runtime_error("MeasureBins: " + who + "no floor");
  double outside = probe.bounds.max().x() + 0.01;
  if (has_floor(outside)) {
    throw std::runtime_error("MeasureBins: " + who + "floor extends past the mesh bounds");
  }
  while (outside - inside > 5e-4) {
    const double mid = 0.5 * (inside + outside);
    (has_floor(mid) ? inside : outside) = mid;
  }
  return inside;
}

// 3c. Floor, ceiling and walls over the bin's depth and width: its inner box (the floor's
// lowest point, the walls' and ceiling's innermost) and the floor's highest point.
void MeasureInside(const Probe& probe, const MeasureBinsOptions& options, double back_x,
                   double y_mid, double z_mid, double half_width, double row_height,
                   const std::string& who, BinGeometry* bin) {
  Extreme floor_min, floor_max, ceiling_min, left_max, right_min;
  const double x0 = back_x + 0.005;
  const double x1 = bin->opening_x_m - 0.002;
  const auto cast = [&](const Eigen::Vector3d& p, const Eigen::Vector3d& dir,
                        double limit) -> std::optional<double> {
    const auto hit = probe.scene.Cast(p, dir, limit);
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
  bin->inner_S = Eigen::AlignedBox3d(
      Eigen::Vector3d(back_x, left_max.Get(who + "left wall"), floor_min.Get(who + "floor")),
      Eigen::Vector3d(bin->opening_x_m, right_min.Get(who + "right wall"),
                      ceiling_min.Get(who + "ceiling")));
  bin->floor_max_z_m = floor_max.Get(who + "floor");
}

}  // namespace

std::vector<BinGeometry> MeasureBins(const TriangleMesh& shelf_S,
                                     const MeasureBinsOptions& options) {
  if (options.rows <= 0 || options.columns <= 0 || options.depth_samples < 2 ||
      options.lateral_samples < 1) {
    throw std::invalid_argument(
        "MeasureBins: rows, columns, depth_samples >= 2 and "
        "lateral_samples must be positive");
  }
  if (shelf_S.empty()) {
    throw std::invalid_argument("MeasureBins: mesh '" + shelf_S.name + "' is empty");
  }
  RayScene scene(HitDistance::kDouble);
  scene.Add(0, shelf_S, Eigen::Isometry3d::Identity());
  scene.Commit();
  Probe probe{scene, Bounds(shelf_S)};
  probe.x = probe.bounds.center().x() +
            options.probe_depth_fraction * (probe.bounds.max().x() - probe.bounds.center().x());
  probe.y = probe.bounds.center().y() + 0.0123 * probe.bounds.sizes().y();
  const double up_origin_z = probe.bounds.min().z() - probe.margin;
  const std::vector<Gap> rows = FindRows(probe, options, up_origin_z);

  std::vector<BinGeometry> bins;
  for (int r = 0; r < options.rows; ++r) {
    const double z_mid = up_origin_z + 0.5 * (rows[r].lo + rows[r].hi);
    // 2. Columns, from the left seen from the front (-y).
    const double side_origin_y = probe.bounds.min().y() - probe.margin;
    const std::vector<Gap> cols =
        FreeGaps(scene, Eigen::Vector3d(probe.x, side_origin_y, z_mid), Eigen::Vector3d::UnitY(),
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
          side_origin_y + 0.5 * (cols[c].lo + cols[c].hi) + 0.0037 * (cols[c].hi - cols[c].lo);
      const double half_w = 0.5 * (cols[c].hi - cols[c].lo);
      const double half_h = 0.5 * (rows[r].hi - rows[r].lo);
      const double back_x = BackWallX(probe, y_mid, z_mid, half_w, half_h, who);
      bin.opening_x_m = OpeningX(probe, y_mid, z_mid, half_h, who);
      MeasureInside(probe, options, back_x, y_mid, z_mid, half_w, rows[r].hi - rows[r].lo, who,
                    &bin);
      bins.push_back(bin);
    }
  }
  return bins;
}

Eigen::AlignedBox3d MeasureToteInner(const TriangleMesh& tote_T) {
  const Eigen::AlignedBox3d bounds_T = Bounds(tote_T);
  const Eigen::Vector3d mid_T = bounds_T.center();
  if (tote_T.empty()) {
    throw std::invalid_argument("MeasureToteInner: mesh '" + tote_T.name + "' is empty");
  }
  RayScene scene(HitDistance::kDouble);
  scene.Add(0, tote_T, Eigen::Isometry3d::Identity());
  scene.Commit();
  const auto distance = [&](const Eigen::Vector3d& direction) {
    const auto hit = scene.Cast(mid_T, direction, bounds_T.sizes().norm());
    if (!hit) throw std::runtime_error("MeasureToteInner: the tote mesh has no wall or floor");
    return hit->distance_m;
  };
  const Eigen::Vector3d lo(mid_T.x() - distance(-Eigen::Vector3d::UnitX()),
                           mid_T.y() - distance(-Eigen::Vector3d::UnitY()),
                           mid_T.z() - distance(-Eigen::Vector3d::UnitZ()));
  const Eigen::Vector3d hi(mid_T.x() + distance(Eigen::Vector3d::UnitX()),
                           mid_T.y() + distance(Eigen::Vector3d::UnitY()), bounds_T.max().z());
  return Eigen::AlignedBox3d(lo, hi);
}

std::vector<BinScanView> CellBinScanViews() {
  BinScanView middle;
  BinScanView right = middle;
  right.lateral_offset_m = -0.15;
  right.height_above_centre_m = 0.25;
  BinScanView left = right;
  left.lateral_offset_m = 0.15;
  return {middle, right, left};
}

Eigen::Vector3d BinScanEye_S(const BinGeometry& bin, const BinScanView& view) {
  const Eigen::Vector3d c = bin.inner_S.center();
  return {bin.opening_x_m + view.standoff_m, c.y() + view.lateral_offset_m,
          c.z() + view.height_above_centre_m};
}

Eigen::Vector3d BinScanTarget_S(const BinGeometry& bin, const BinScanView& view) {
  const Eigen::Vector3d c = bin.inner_S.center();
  return {c.x(), c.y(), bin.inner_S.min().z() + view.aim_above_floor_m};
}

}  // namespace picking::world
