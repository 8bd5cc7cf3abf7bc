#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "libs/apc/catalogue.h"
#include "libs/apc/task.h"

namespace picking::apc {

/// Location names used by events besides the bin names "bin_A".."bin_L".
inline constexpr const char* kToteLocation = "tote";
inline constexpr const char* kGripperLocation = "gripper";

/// What happened to an item during a task, as the judges (or the simulator) record it.
enum class EventKind {
  kMove,         ///< `item` moved from `from` to `to` (bins, "tote", "gripper").
  kDrop,         ///< `item` was dropped from `height_m` metres.
  kDamageMinor,  ///< Minor damage to `item` (a catalogue item or "shelf").
  kDamageMajor,  ///< Major damage to `item` (a catalogue item or "shelf").
  kOutside,      ///< `item` left `from` and ended outside any bin, the tote and the gripper.
  kProtruding,   ///< `item` left protruding `protrusion_m` metres out of bin `from`.
};

struct Event {
  EventKind kind = EventKind::kMove;
  std::string item;
  std::string from;           ///< kMove, kOutside, kProtruding: a location.
  std::string to;             ///< kMove: a location.
  double height_m = 0.0;      ///< kDrop: height of the fall, metres.
  double protrusion_m = 0.0;  ///< kProtruding: how far the item sticks out, metres.
};

Event MoveEvent(std::string item, std::string from, std::string to);
Event DropEvent(std::string item, double height_m);
Event DamageEvent(std::string item, bool major);
Event OutsideEvent(std::string item, std::string from);
Event ProtrudingEvent(std::string item, std::string bin, double protrusion_m);

/// Where every item really is: bins and tote as a Task (kind and work order unused), plus
/// what the gripper holds.
struct WorldState {
  Task places;
  std::vector<std::string> gripper_contents;
  std::vector<std::string> outside;  ///< Items that left the bins, tote and gripper.
};

/// Applies the move and outside events in order to `initial`. Throws std::invalid_argument
/// naming the event index when an event takes an item from a location that does not hold it,
/// names an unknown location, or has a negative or non-finite drop height or protrusion (a
/// protrusion must name a bin).
WorldState ReplayEvents(const Task& initial, const std::vector<Event>& events);

/// Point values of the rules; defaults are the APC 2016 rules (start-jsk/jsk_apc
/// doc/apc2016_rules.rst).
struct ScoringRules {
  int points_small_bin = 10;      ///< Bin that held 0-2 items at the start.
  int points_medium_bin = 15;     ///< 3-4 items.
  int points_large_bin = 20;      ///< 5 or more items.
  bool stow_item_bonus = true;    ///< Add the catalogue bonus to stowed items too.
  int penalty_outside = -10;      ///< Per item outside any bin, the tote and the gripper.
  int penalty_misreported = -10;  ///< Per item in a bin or the tote misreported in the output.
  int penalty_damage_minor = -5;
  int penalty_damage_major = -20;
  int penalty_drop = -5;
  double drop_height_limit_m = 0.3;  ///< Drops from strictly higher than this are penalised.
  int penalty_protruding = -5;
  double protrusion_limit_m = 0.005;  ///< Protrusions strictly beyond this are penalised.
};

/// Everything the score depends on.
struct ScoringInput {
  Task initial;               ///< The task file at the start (kind decides pick or stow).
  std::vector<Event> events;  ///< In the order they happened.
  Task reported;              ///< The output file the system wrote.
  Task true_final;            ///< Where the items really are in the bins and the tote.
  std::vector<std::string> true_gripper_contents;  ///< Held by the gripper at the end.
};

enum class ScoreRule {
  kTargetItem,   ///< Pick: a work-order item moved from its bin into the tote.
  kStowedItem,   ///< Stow: an item moved from the tote into a bin.
  kItemBonus,    ///< The catalogue bonus of a scored item.
  kOutside,      ///< Item ended outside any bin, the tote and the gripper.
  kMisreported,  ///< Item's final position wrong in the output file.
  kDamageMinor,
  kDamageMajor,
  kDrop,
  kProtruding,
};

/// Stable lower-case name of a rule for logs and reports, e.g. "target_item".
std::string_view ScoreRuleName(ScoreRule rule);

struct ScoreLine {
  ScoreRule rule;
  int points;          ///< Positive for an award, negative for a penalty.
  std::string item;    ///< Item (or "shelf") the line is about.
  std::string reason;  ///< One sentence for a human.
};

struct ScoreReport {
  int total = 0;  ///< Sum of the points of all lines.
  std::vector<ScoreLine> lines;
};

/// Scores a pick or stow attempt by the APC 2016 rules.
///
/// Pick: each work-order entry (bin B, item I) scores when a copy of I that started in B is in
/// the tote at the end: 10/15/20 points by how many items B held at the start, plus I's
/// bonus. Stow: each item that started in the tote and ends in a bin scores by how many items
/// that bin held at the start, plus its bonus (ScoringRules::stow_item_bonus).
/// Penalties: one line per kOutside event, per damage event, per drop higher than the limit,
/// per protrusion beyond the limit, and per item in a bin or the tote whose location the
/// reported output does not list.
///
/// Throws std::invalid_argument when the events are inconsistent with `initial` (see
/// ReplayEvents) or when replaying them does not give `true_final` and
/// `true_gripper_contents` (message names the location and item), and UnknownItemError for a
/// scored item missing from `catalogue`.
ScoreReport Score(const ScoringInput& input, const Catalogue& catalogue,
                  const ScoringRules& rules = {});

}  // namespace picking::apc
