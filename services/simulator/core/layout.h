#pragma once

#include <Eigen/Geometry>

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "libs/apc/task.h"
#include "libs/world/cell_config.h"
#include "libs/world/item_models.h"
#include "libs/world/ray_scene.h"

namespace picking::simulator {

/// How a task's items are laid out: side by side on their containers' floors, none
/// touching (LayoutPlanner), or dropped one at a time and settled by rigid-body physics, so
/// that they stack, lean and stand on end (PhysicsLayout, physics_layout.h).
enum class LayoutMode { kTidy, kSettled };

/// "tidy" or "settled"; throws std::invalid_argument naming the value otherwise.
LayoutMode LayoutModeFromString(const std::string& text);

/// Options of the layout planner. Defaults suit the APC 2016 pod and tote.
struct LayoutOptions {
  LayoutMode mode = LayoutMode::kTidy;  ///< SimWorld::LoadTask: which of the two layouts.
  int candidates_per_item = 400;        ///< Random poses tried per item; the lowest feasible wins.
  double wall_margin_m = 0.004;         ///< Minimal gap between an item and the bin walls / back.
  double opening_margin_m = 0.01;    ///< Minimal gap between an item and the bin's opening plane.
  double clearance_m = 0.001;        ///< Gap between an item and the surface it rests on.
  double yaw_jitter_rad = 0.15;      ///< Items are turned by 0 or 90 deg plus up to this much.
  double tote_stack_height_m = 0.1;  ///< Items in the tote may reach this far above its rim.
};

/// An item could not be placed. The message names the container and the item.
class LayoutError final : public std::runtime_error {
 public:
  LayoutError(const std::string& container, const std::string& what);
  const std::string& container() const { return container_; }

 private:
  std::string container_;
};

/// Where the layout put one item.
struct PlacedItem {
  std::string name;
  std::string container;  ///< "bin_A".."bin_L" or "tote".
  Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();
};

/// A place items are laid out in: a bin or the tote, as a box in a frame R whose z is up.
struct LayoutRegion {
  std::string name;
  Eigen::Isometry3d X_BaseRegion = Eigen::Isometry3d::Identity();
  Eigen::AlignedBox3d box_R;  ///< Free volume; its top is the ceiling items must stay under.
};

/// Regions of the cell: the 12 bins (in the shelf frame, minus margins at walls and opening)
/// and the tote (its inner volume in the tote frame, up to tote_stack_height_m above the rim).
std::vector<LayoutRegion> LayoutRegions(const world::CellModel& cell, const LayoutOptions& options);

/// Places items resting on their largest face (-z of the item frame down), on the floor of
/// their region or stably on top of a flat-topped item (its centre over the supporting
/// surface), inside the region, not overlapping each other (oriented-box test of their bounding
/// boxes) and not touching the cell: each candidate's support is the highest surface under a
/// grid over its footprint, found by ray casting `static_scene` (which holds shelf, tote and
/// table) and from the items already placed. Items go in order of decreasing footprint; each
/// one takes the lowest of `candidates_per_item` random poses (seeded, so reproducible).
class LayoutPlanner final {
 public:
  LayoutPlanner(const world::CellModel& cell, const world::ItemModelLibrary& models,
                const world::RayScene& static_scene, LayoutOptions options = {});

  /// Layout of a whole task (bins A..L, then the tote). Throws LayoutError naming the bin if
  /// an item does not fit, apc::UnknownItemError for an unknown item.
  std::vector<PlacedItem> Plan(const apc::Task& task, std::uint32_t seed) const;

  /// Places `items` in `region` next to `existing` (items already there, with their poses).
  /// Throws LayoutError naming the region if one does not fit.
  std::vector<PlacedItem> PlaceIn(const std::string& region, const std::vector<std::string>& items,
                                  const std::vector<PlacedItem>& existing,
                                  std::uint32_t seed) const;

  const std::vector<LayoutRegion>& regions() const { return regions_; }

 private:
  const world::CellModel& cell_;
  const world::ItemModelLibrary& models_;
  const world::RayScene& static_scene_;
  LayoutOptions options_;
  std::vector<LayoutRegion> regions_;
};

}  // namespace picking::simulator
