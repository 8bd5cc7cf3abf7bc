#include "services/simulator/core/layout.h"

#include <algorithm>
#include <cmath>
#include <optional>
#include <random>

#include "libs/apc/bins.h"
#include "libs/world/mesh_utils.h"

namespace picking::simulator {

LayoutError::LayoutError(const std::string& container, const std::string& what)
    : std::runtime_error("layout of " + container + ": " + what), container_(container) {}

namespace {

// An item's footprint and height in the region frame: a rectangle turned by `yaw` about z.
struct Footprint {
  Eigen::Vector2d centre;
  double yaw = 0.0;
  Eigen::Vector2d half;  // half extents along the rotated axes
  double z_bottom = 0.0, z_top = 0.0;
  bool flat_top = true;

  Eigen::Matrix2d R() const { return Eigen::Rotation2Dd(yaw).toRotationMatrix(); }
  bool Contains(const Eigen::Vector2d& p, double margin = 0.0) const {
    const Eigen::Vector2d local = R().transpose() * (p - centre);
    return std::abs(local.x()) <= half.x() + margin && std::abs(local.y()) <= half.y() + margin;
  }
};

// Separating axis test of two rectangles in the plane (touching counts as overlap).
bool Overlap2d(const Footprint& a, const Footprint& b, double gap) {
  const Eigen::Matrix2d ra = a.R(), rb = b.R();
  const Eigen::Vector2d d = b.centre - a.centre;
  for (const Eigen::Matrix2d* r : {&ra, &rb}) {
    for (int k = 0; k < 2; ++k) {
      const Eigen::Vector2d axis = r->col(k);
      const double pa =
          a.half.x() * std::abs(axis.dot(ra.col(0))) + a.half.y() * std::abs(axis.dot(ra.col(1)));
      const double pb =
          b.half.x() * std::abs(axis.dot(rb.col(0))) + b.half.y() * std::abs(axis.dot(rb.col(1)));
      if (std::abs(axis.dot(d)) > pa + pb + gap) return false;
    }
  }
  return true;
}

bool FlatTopped(const world::ItemModel& model) {
  return model.shape.kind == world::ShapeKind::kBox || model.shape.kind == world::ShapeKind::kScan;
}

}  // namespace

LayoutMode LayoutModeFromString(const std::string& text) {
  if (text == "tidy") return LayoutMode::kTidy;
  if (text == "settled") return LayoutMode::kSettled;
  throw std::invalid_argument("layout mode '" + text.substr(0, 40) +
                              "' is not 'tidy' or 'settled'");
}

std::vector<LayoutRegion> LayoutRegions(const world::CellModel& cell,
                                        const LayoutOptions& options) {
  std::vector<LayoutRegion> regions;
  for (const auto& bin : cell.bins) {
    LayoutRegion r;
    r.name = bin.name;
    r.X_BaseRegion = cell.config.X_BaseShelf;
    const Eigen::Vector3d lo =
        bin.inner_S.min() + Eigen::Vector3d(options.wall_margin_m, options.wall_margin_m, 0.0);
    const Eigen::Vector3d hi =
        bin.inner_S.max() -
        Eigen::Vector3d(options.opening_margin_m, options.wall_margin_m, options.wall_margin_m);
    r.box_R = Eigen::AlignedBox3d(lo, hi);
    regions.push_back(r);
  }
  // The tote: its inner box as the cell measured it from the mesh, up to
  // tote_stack_height_m above the rim.
  LayoutRegion tote;
  tote.name = "tote";
  tote.X_BaseRegion = cell.config.X_BaseTote;
  const Eigen::AlignedBox3d& box = cell.tote_inner_T();
  tote.box_R = Eigen::AlignedBox3d(
      box.min(), box.max() + Eigen::Vector3d(0.0, 0.0, options.tote_stack_height_m));
  regions.push_back(tote);
  return regions;
}

LayoutPlanner::LayoutPlanner(const world::CellModel& cell, const world::ItemModelLibrary& models,
                             const world::RayScene& static_scene, LayoutOptions options)
    : cell_(cell),
      models_(models),
      static_scene_(static_scene),
      options_(options),
      regions_(LayoutRegions(cell, options)) {
  if (options_.candidates_per_item < 1) {
    throw std::invalid_argument("LayoutOptions::candidates_per_item must be >= 1");
  }
}

std::vector<PlacedItem> LayoutPlanner::Plan(const apc::Task& task, std::uint32_t seed) const {
  // Validate every name before any work, so the error names the first unknown item.
  for (const auto& [bin, items] : task.bin_contents) {
    if (!apc::IsBinName(bin)) throw LayoutError(bin, "not a bin name");
    for (const auto& item : items) models_.catalogue().at(item);
  }
  for (const auto& item : task.tote_contents) models_.catalogue().at(item);
  std::vector<PlacedItem> placed;
  std::uint32_t k = 0;
  for (const auto& [bin, items] : task.bin_contents) {
    const auto more = PlaceIn(bin, items, {}, seed * 7919u + (++k));
    placed.insert(placed.end(), more.begin(), more.end());
  }
  const auto tote = PlaceIn("tote", task.tote_contents, {}, seed * 7919u + 1000u);
  placed.insert(placed.end(), tote.begin(), tote.end());
  return placed;
}

namespace {

// The footprints of the items already in the region.
std::vector<Footprint> OccupiedFootprints(const std::vector<PlacedItem>& existing,
                                          const world::ItemModelLibrary& models,
                                          const Eigen::Isometry3d& X_RegionBase) {
  std::vector<Footprint> occupied;
  for (const PlacedItem& p : existing) {
    const auto model = models.Get(p.name);
    const Eigen::AlignedBox3d b = world::Bounds(model->mesh, X_RegionBase * p.X_BaseItem);
    Footprint f;
    f.centre = b.center().head<2>();
    f.half = 0.5 * b.sizes().head<2>();
    f.z_bottom = b.min().z();
    f.z_top = b.max().z();
    f.flat_top = FlatTopped(*model);
    occupied.push_back(f);
  }
  return occupied;
}

// A height sample under a footprint: local footprint coordinates, height in the region.
using HeightSample = std::pair<Eigen::Vector2d, double>;

// The static cell's floor under a 5 x 5 grid of the footprint; none where a ray misses it.
std::optional<std::vector<HeightSample>> FloorUnder(const Footprint& f, const LayoutRegion& region,
                                                    const world::RayScene& scene) {
  constexpr int kGrid = 5;
  const Eigen::AlignedBox3d& box = region.box_R;
  const Eigen::Isometry3d X_RegionBase = region.X_BaseRegion.inverse();
  const Eigen::Matrix2d R = f.R();
  std::vector<HeightSample> samples;
  for (int i = 0; i < kGrid; ++i) {
    for (int j = 0; j < kGrid; ++j) {
      const Eigen::Vector2d local((2.0 * i / (kGrid - 1) - 1) * f.half.x(),
                                  (2.0 * j / (kGrid - 1) - 1) * f.half.y());
      const Eigen::Vector2d p = f.centre + R * local;
      const Eigen::Vector3d p_Base =
          region.X_BaseRegion * Eigen::Vector3d(p.x(), p.y(), box.max().z());
      const Eigen::Vector3d down = region.X_BaseRegion.linear() * -Eigen::Vector3d::UnitZ();
      const auto hit = scene.Cast(p_Base, down, box.sizes().z() + 0.05);
      if (!hit) return std::nullopt;
      samples.push_back({local, (X_RegionBase * hit->p_BaseHit).z()});
    }
  }
  return samples;
}

// Rests the footprint on the floor samples and the items it overlaps (sets z_bottom and
// z_top); false where it would lie on a round item, stick out of the region's top, or not
// be carried around its centre (on items: the samples at its resting height must surround
// the centre; the floor's slight slope toward the pod's lip is tolerated).
bool Rest(Footprint* f, std::vector<HeightSample> samples, const std::vector<Footprint>& occupied,
          double height_m, double top_z, double clearance_m) {
  double floor_support = -std::numeric_limits<double>::infinity();
  for (const auto& [local, h] : samples) floor_support = std::max(floor_support, h);
  double support = floor_support;
  const Eigen::Matrix2d R = f->R();
  for (const Footprint& o : occupied) {
    if (!Overlap2d(*f, o, clearance_m)) continue;
    for (auto& [local, h] : samples) {
      if (o.Contains(f->centre + R * local)) h = std::max(h, o.flat_top ? o.z_top : 1e9);
    }
    support = std::max(support, o.z_top);
  }
  if (support > 1e8) return false;  // over a round item
  f->z_bottom = support + clearance_m;
  f->z_top = f->z_bottom + height_m;
  if (f->z_top > top_z) return false;
  if (floor_support >= support - 1e-9) return true;  // on the floor
  Eigen::Vector2d lo(1e9, 1e9), hi(-1e9, -1e9);
  for (const auto& [local, h] : samples) {
    if (h >= support - 0.003) {
      lo = lo.cwiseMin(local);
      hi = hi.cwiseMax(local);
    }
  }
  const double inset = 0.25;
  return lo.x() <= -inset * f->half.x() && hi.x() >= inset * f->half.x() &&
         lo.y() <= -inset * f->half.y() && hi.y() >= inset * f->half.y();
}

// The item's pose in the base frame from its footprint.
Eigen::Isometry3d PoseOf(const Footprint& f, const world::ItemModel& model,
                         const LayoutRegion& region) {
  Eigen::Isometry3d X_RegionItem = Eigen::Isometry3d::Identity();
  X_RegionItem.translation() =
      Eigen::Vector3d(f.centre.x(), f.centre.y(), f.z_bottom - model.box_I.min().z());
  X_RegionItem.linear() = Eigen::AngleAxisd(f.yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  // Centre of the bounding box is the item frame origin up to box_I's offset.
  X_RegionItem.translation().head<2>() -= (X_RegionItem.linear() * model.box_I.center()).head<2>();
  return region.X_BaseRegion * X_RegionItem;
}

// The lowest of `candidates_per_item` random footprints of the item that rest in the region
// (none if no candidate does).
std::optional<Footprint> LowestSpot(const world::ItemModel& model, const LayoutRegion& region,
                                    const std::vector<Footprint>& occupied,
                                    const world::RayScene& static_scene,
                                    const LayoutOptions& options, std::mt19937* rng) {
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const Eigen::AlignedBox3d& box = region.box_R;
  const Eigen::Vector3d size = model.box_I.sizes();
  std::optional<Footprint> best;
  for (int c = 0; c < options.candidates_per_item; ++c) {
    Footprint f;
    f.yaw = (unit(*rng) < 0.5 ? 0.0 : M_PI / 2) + (2 * unit(*rng) - 1) * options.yaw_jitter_rad;
    f.half = 0.5 * size.head<2>();
    f.flat_top = FlatTopped(model);
    const Eigen::Matrix2d R = f.R();
    // Axis-aligned half extents of the turned footprint.
    const Eigen::Vector2d ext(std::abs(R(0, 0)) * f.half.x() + std::abs(R(0, 1)) * f.half.y(),
                              std::abs(R(1, 0)) * f.half.x() + std::abs(R(1, 1)) * f.half.y());
    const double x_lo = box.min().x() + ext.x(), x_hi = box.max().x() - ext.x();
    const double y_lo = box.min().y() + ext.y(), y_hi = box.max().y() - ext.y();
    if (x_lo > x_hi || y_lo > y_hi) continue;
    f.centre =
        Eigen::Vector2d(x_lo + unit(*rng) * (x_hi - x_lo), y_lo + unit(*rng) * (y_hi - y_lo));
    const auto floor = FloorUnder(f, region, static_scene);
    if (!floor) continue;
    if (!Rest(&f, *floor, occupied, size.z(), box.max().z(), options.clearance_m)) continue;
    if (!best || f.z_bottom < best->z_bottom - 1e-9) best = f;
  }
  return best;
}

}  // namespace

std::vector<PlacedItem> LayoutPlanner::PlaceIn(const std::string& region_name,
                                               const std::vector<std::string>& items,
                                               const std::vector<PlacedItem>& existing,
                                               std::uint32_t seed) const {
  const auto region_it = std::find_if(regions_.begin(), regions_.end(),
                                      [&](const LayoutRegion& r) { return r.name == region_name; });
  if (region_it == regions_.end()) throw LayoutError(region_name, "unknown bin or container");
  const LayoutRegion& region = *region_it;
  std::vector<Footprint> occupied =
      OccupiedFootprints(existing, models_, region.X_BaseRegion.inverse());

  // The largest footprints first.
  std::vector<std::shared_ptr<const world::ItemModel>> models;
  for (const auto& name : items) models.push_back(models_.Get(name));
  std::vector<std::size_t> order(items.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    const Eigen::Vector3d sa = models[a]->box_I.sizes(), sb = models[b]->box_I.sizes();
    return sa.x() * sa.y() > sb.x() * sb.y();
  });

  std::mt19937 rng(seed);
  std::vector<PlacedItem> placed(items.size());
  for (std::size_t idx : order) {
    const world::ItemModel& model = *models[idx];
    const std::optional<Footprint> spot =
        LowestSpot(model, region, occupied, static_scene_, options_, &rng);
    if (!spot) {
      throw LayoutError(region_name, "no room for '" + model.item->name + "' (" +
                                         std::to_string(items.size()) + " items to place)");
    }
    occupied.push_back(*spot);
    placed[idx] = {model.item->name, region_name, PoseOf(*spot, model, region)};
  }
  return placed;
}

}  // namespace picking::simulator
