#pragma once

#include <Eigen/Geometry>

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "libs/apc/task.h"
#include "libs/world/cell_config.h"
#include "libs/world/item_models.h"
#include "services/simulator/core/layout.h"

namespace picking::simulator {

/// Options of PhysicsLayout. Defaults suit the APC 2016 pod and tote with items of a few
/// hundred grams; every length in metres, time in seconds.
struct SettleOptions {
  double time_step_s = 1.0 / 240.0;  ///< Fixed step of the rigid-body solver (> 0).
  int solver_iterations = 20;        ///< Constraint solver iterations per step (>= 1).
  /// Steps allowed for one dropped item (and everything it disturbs) to come to rest.
  int max_steps_per_item = 1200;
  /// The items are at rest when, over a window of `rest_time_s`, none moved or turned more
  /// than these mean speeds allow.
  double rest_linear_speed_m_per_s = 0.005;
  double rest_angular_speed_rad_per_s = 0.05;
  double rest_time_s = 0.25;
  double friction = 0.8;  ///< Coulomb friction, items and cell alike (>= 0).
  /// Velocity damping, fractions lost per second (in [0, 1]): stand-ins for the air, the
  /// soft packaging and the rolling resistance that stop real items tumbling out of a bin.
  double linear_damping = 0.1;
  double angular_damping = 0.3;
  double density_kg_per_m3 = 300.0;  ///< Of an item's box; sets its mass (> 0).
  double item_margin_m = 0.0005;     ///< Bullet's collision margin of the item boxes (>= 0).
  int candidates_per_item = 40;      ///< Drop poses tried per item; the lowest wins (>= 1).
  /// Probability that an item is dropped on its largest face; otherwise on any of its six
  /// faces (standing on end, on its side).
  double flat_probability = 0.5;
  /// Half the items are released square to the container's walls; the others turned by up to
  /// this much from square.
  double yaw_jitter_rad = 0.35;
  double max_tilt_rad = 0.2;       ///< Random tilt of the dropped item about a horizontal axis.
  double drop_gap_m = 0.005;       ///< Gap under the dropped item's lowest point at release.
  double wall_margin_m = 0.003;    ///< Free gap to walls and back at release.
  double opening_margin_m = 0.03;  ///< Gap to a bin's opening plane at release.
  /// Items in the tote may reach this far above its rim at release.
  double tote_stack_height_m = 0.1;
  /// A settled item's box may stick out of its container's free box by this much (a bin's
  /// opening plane included; a tote's top is its rim plus tote_stack_height_m).
  double containment_tolerance_m = 0.01;
  /// Deepest contact allowed at rest (between items: the overlap of their boxes; with the
  /// container: Bullet's contact depth); a deeper pile is settled again.
  double max_penetration_m = 0.0009;
  /// Tries per container before a layout is refused; each retry has another seed and drops
  /// more tidily, the last (of two or more) flat, square to the walls and untilted, packed
  /// against the walls and each other.
  int attempts = 6;
};

/// The figures of one settled layout.
struct SettleResult {
  /// Rest pose of every item: for Settle(), bins A..L in the task's order, then the tote.
  std::vector<PlacedItem> items;
  int steps = 0;                   ///< Solver steps, over all containers and attempts.
  int retries = 0;                 ///< Containers settled again after a failed attempt.
  double max_penetration_m = 0.0;  ///< Deepest contact at rest, item-item or item-cell.
  double max_speed_m_per_s = 0.0;  ///< Fastest item at the end.
};

/// The items of one container after they settled again from where they were
/// (PhysicsLayout::Resettle and Release).
struct RestResult {
  /// Rest pose of every item, parallel to the input; an item that left the container is where
  /// it left the simulation (see left_container).
  std::vector<PlacedItem> items;
  /// Parallel to `items`: the item was simulated (it lost its support, or it is the released
  /// one); the others were fixed obstacles and keep their poses exactly.
  std::vector<bool> loose;
  /// Parallel to `items`: the item fell out of the container (over a bin's front lip, or out
  /// of the simulation) and was taken out of it below the container's floor.
  std::vector<bool> left_container;
  /// Release: how far the released item fell before it first touched anything (the container
  /// or an item), straight down from its release pose; every point of it, its lowest point
  /// included, falls by this much. 0 for Resettle.
  double drop_height_m = 0.0;
  /// Release: how far the released item was raised before its fall because its box at the
  /// release pose overlapped an item already there (0: it did not).
  double release_lift_m = 0.0;
  int steps = 0;         ///< Solver steps.
  bool at_rest = false;  ///< False: the step budget ended first; the poses are the last ones.
  double max_penetration_m = 0.0;  ///< Deepest contact at the end, item-item or item-cell.
};

/// Lays out items by dropping them into their container and letting rigid-body physics
/// (Bullet 3.24, single threaded, fixed step, no wall clock) settle them under gravity with
/// friction against the container and each other: items stack, lean on walls and on each
/// other, stand on end.
///
/// Model and limits: each item is a box (its model's box_I), also cylinders, spheres and
/// concave scans (a ball rests on its box's face; a bowl does not nest). Each container is
/// simulated on its own, its walls as static boxes measured from the cell's meshes by rays:
/// a bin's floor follows the pod's profile along its centre line (flat, then rising toward
/// the lip), side and back walls and ceiling are planes, the front is open; the tote is its
/// inner box up to the rim. (Settling on the pod's triangle mesh was measured first: the
/// convex-triangle contacts kept items jittering and most layouts never came to rest.)
///
/// Items go in one at a time, in order of decreasing footprint, each released at the lowest
/// of `candidates_per_item` seeded poses (position, face down, yaw, tilt) whose bounding box
/// clears the items already there, and the pile settles before the next one. A container
/// whose items do not fit, come to rest, stay inside or stay apart (max_penetration_m) is
/// settled again with another seed, more tidily each time (`attempts`); the last attempt
/// packs the items flat and square against the walls and each other (and where no random
/// pose finds room, any attempt tries that packing for the item). The result depends only on
/// the inputs and the seed.
///
/// Construction measures the containers once; Settle and SettleIn are const but not thread
/// safe (they share the containers' Bullet shapes).
class PhysicsLayout final {
 public:
  /// Throws std::invalid_argument for options out of range or not finite.
  PhysicsLayout(const world::CellModel& cell, const world::ItemModelLibrary& models,
                SettleOptions options = {});
  ~PhysicsLayout();
  PhysicsLayout(const PhysicsLayout&) = delete;
  PhysicsLayout& operator=(const PhysicsLayout&) = delete;

  /// Settles a whole task (bins A..L, then the tote). Throws apc::UnknownItemError for an
  /// unknown item, LayoutError naming the container (and the item) for a bin name that is
  /// not one, or when after `attempts` tries an item does not fit under the ceiling, ends
  /// outside its container or does not come to rest.
  SettleResult Settle(const apc::Task& task, std::uint32_t seed) const;

  /// Drops `items` into `container` ("bin_A".."bin_L" or "tote") where `existing` items
  /// already lie; those are fixed obstacles (they do not move) and are not returned. Throws
  /// as Settle, and LayoutError naming the container and item for an existing pose that is
  /// not finite.
  SettleResult SettleIn(const std::string& container, const std::vector<std::string>& items,
                        const std::vector<PlacedItem>& existing, std::uint32_t seed) const;

  /// Lets the items of `container` that `removed` supported settle again from their poses,
  /// now that it is gone: the items whose boxes touched its box (within 2 mm) with their
  /// centres above its lowest point, and in turn the items touching those from above, are
  /// bodies starting at rest where they are; the others are fixed obstacles (so that a pile
  /// at rest, tidy or settled, is not stirred by a pick elsewhere in it). The solver steps
  /// (as Settle, fixed step) until no body moved faster than the rest speeds over
  /// rest_time_s, or max_steps_per_item steps have passed. A body that falls out of the
  /// container (over a bin's open front) is taken out of the simulation and flagged. Throws
  /// apc::UnknownItemError for an unknown item, LayoutError naming the container (and item)
  /// for an unknown container or a pose that is not a finite rigid transform.
  RestResult Resettle(const std::string& container, const std::vector<PlacedItem>& items,
                      const PlacedItem& removed) const;

  /// Lets `items[released]` go at its pose in `container`: it falls under gravity from rest
  /// onto what lies below it and settles; the other items are fixed obstacles. Where its box
  /// at the release pose overlaps another item's box, it is first raised until clear (in
  /// 1 mm steps, release_lift_m). RestResult::drop_height_m is its fall until first contact.
  /// Throws as Resettle, and std::out_of_range for `released` past the items.
  RestResult Release(const std::string& container, const std::vector<PlacedItem>& items,
                     std::size_t released) const;

  /// The bin or the tote whose free box holds, seen from above, the whole footprint of a box
  /// (half sizes `half`, its centre at X_BaseBox) with its centre above the container's floor
  /// and, for a bin, below its ceiling; none otherwise (over the table, the floor, a wall).
  std::optional<std::string> ContainerUnder(const Eigen::Vector3d& half,
                                            const Eigen::Isometry3d& X_BaseBox) const;

  const SettleOptions& options() const { return options_; }

 private:
  struct Impl;
  RestResult SettleFrom(const std::string& container, const std::vector<PlacedItem>& items,
                        const std::optional<PlacedItem>& removed,
                        std::optional<std::size_t> released) const;

  const world::ItemModelLibrary& models_;
  SettleOptions options_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace picking::simulator
