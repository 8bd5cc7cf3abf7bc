#include "libs/apc/scoring.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <stdexcept>

#include "libs/apc/bins.h"

namespace picking::apc {
namespace {

// One physical copy of an item and the location it started in.
struct Copy {
  std::string name;
  std::string origin;
};

using Places = std::map<std::string, std::vector<Copy>>;

bool IsLocation(const std::string& name) {
  return IsBinName(name) || name == kToteLocation || name == kGripperLocation;
}

struct Replay {
  Places places;  // Every bin, the tote and the gripper; copies in arrival order.
  std::vector<Copy> outside;
};

Replay Run(const Task& initial, const std::vector<Event>& events) {
  Replay replay;
  for (int i = 0; i < kNumBins; ++i) replay.places[BinName(i)];
  replay.places[kToteLocation];
  replay.places[kGripperLocation];
  for (const auto& [bin, items] : initial.bin_contents) {
    if (!IsBinName(bin)) throw std::invalid_argument("initial task has unknown bin " + bin);
    for (const std::string& item : items) replay.places[bin].push_back({item, bin});
  }
  for (const std::string& item : initial.tote_contents) {
    replay.places[kToteLocation].push_back({item, kToteLocation});
  }
  for (std::size_t i = 0; i < events.size(); ++i) {
    const Event& event = events[i];
    const std::string label = "event " + std::to_string(i) + " (" + event.item + ")";
    if (event.kind == EventKind::kDrop &&
        !(event.height_m >= 0.0 && std::isfinite(event.height_m))) {
      throw std::invalid_argument(label + ": drop height must be finite and >= 0");
    }
    if (event.kind == EventKind::kProtruding) {
      if (!IsBinName(event.from)) {
        throw std::invalid_argument(label + ": protrusion from \"" + event.from +
                                    "\", which is not a bin");
      }
      if (!(event.protrusion_m >= 0.0 && std::isfinite(event.protrusion_m))) {
        throw std::invalid_argument(label + ": protrusion must be finite and >= 0");
      }
    }
    if (event.kind != EventKind::kMove && event.kind != EventKind::kOutside) continue;
    if (!IsLocation(event.from)) {
      throw std::invalid_argument(label + ": unknown location \"" + event.from + "\"");
    }
    if (event.kind == EventKind::kMove && !IsLocation(event.to)) {
      throw std::invalid_argument(label + ": unknown location \"" + event.to + "\"");
    }
    std::vector<Copy>& source = replay.places[event.from];
    // The copy that arrived last is taken first (it lies on top).
    const auto it = std::find_if(source.rbegin(), source.rend(),
                                 [&](const Copy& c) { return c.name == event.item; });
    if (it == source.rend()) {
      throw std::invalid_argument(label + ": " + event.from + " does not hold \"" + event.item +
                                  "\" at that point");
    }
    Copy copy = *it;
    source.erase(std::next(it).base());
    if (event.kind == EventKind::kMove) {
      replay.places[event.to].push_back(std::move(copy));
    } else {
      replay.outside.push_back(std::move(copy));
    }
  }
  return replay;
}

std::map<std::string, int> Count(const std::vector<std::string>& items) {
  std::map<std::string, int> counts;
  for (const std::string& item : items) ++counts[item];
  return counts;
}

std::map<std::string, int> Count(const std::vector<Copy>& copies) {
  std::map<std::string, int> counts;
  for (const Copy& copy : copies) ++counts[copy.name];
  return counts;
}

const std::vector<std::string>& Contents(const Task& task, const std::string& location) {
  static const std::vector<std::string> kEmpty;
  if (location == kToteLocation) return task.tote_contents;
  const auto it = task.bin_contents.find(location);
  return it == task.bin_contents.end() ? kEmpty : it->second;
}

void CheckSame(const std::string& location, const std::map<std::string, int>& replayed,
               const std::map<std::string, int>& stated) {
  std::map<std::string, std::pair<int, int>> all;
  for (const auto& [item, n] : replayed) all[item].first = n;
  for (const auto& [item, n] : stated) all[item].second = n;
  for (const auto& [item, n] : all) {
    if (n.first != n.second) {
      throw std::invalid_argument("true final state disagrees with the events: " + location +
                                  " holds " + std::to_string(n.second) + " x " + item +
                                  ", the events leave " + std::to_string(n.first));
    }
  }
}

}  // namespace

std::string_view ScoreRuleName(ScoreRule rule) {
  switch (rule) {
    case ScoreRule::kTargetItem:
      return "target_item";
    case ScoreRule::kStowedItem:
      return "stowed_item";
    case ScoreRule::kItemBonus:
      return "item_bonus";
    case ScoreRule::kOutside:
      return "outside";
    case ScoreRule::kMisreported:
      return "misreported";
    case ScoreRule::kDamageMinor:
      return "damage_minor";
    case ScoreRule::kDamageMajor:
      return "damage_major";
    case ScoreRule::kDrop:
      return "drop";
    case ScoreRule::kProtruding:
      return "protruding";
  }
  return "unknown";
}

Event MoveEvent(std::string item, std::string from, std::string to) {
  Event e;
  e.kind = EventKind::kMove;
  e.item = std::move(item);
  e.from = std::move(from);
  e.to = std::move(to);
  return e;
}

Event DropEvent(std::string item, double height_m) {
  Event e;
  e.kind = EventKind::kDrop;
  e.item = std::move(item);
  e.height_m = height_m;
  return e;
}

Event DamageEvent(std::string item, bool major) {
  Event e;
  e.kind = major ? EventKind::kDamageMajor : EventKind::kDamageMinor;
  e.item = std::move(item);
  return e;
}

Event OutsideEvent(std::string item, std::string from) {
  Event e;
  e.kind = EventKind::kOutside;
  e.item = std::move(item);
  e.from = std::move(from);
  return e;
}

Event ProtrudingEvent(std::string item, std::string bin, double protrusion_m) {
  Event e;
  e.kind = EventKind::kProtruding;
  e.item = std::move(item);
  e.from = std::move(bin);
  e.protrusion_m = protrusion_m;
  return e;
}

WorldState ReplayEvents(const Task& initial, const std::vector<Event>& events) {
  const Replay replay = Run(initial, events);
  WorldState state;
  state.places.kind = initial.kind;
  for (const auto& [location, copies] : replay.places) {
    std::vector<std::string> names;
    for (const Copy& copy : copies) names.push_back(copy.name);
    if (location == kToteLocation) {
      state.places.tote_contents = std::move(names);
    } else if (location == kGripperLocation) {
      state.gripper_contents = std::move(names);
    } else {
      state.places.bin_contents[location] = std::move(names);
    }
  }
  for (const Copy& copy : replay.outside) state.outside.push_back(copy.name);
  return state;
}

ScoreReport Score(const ScoringInput& input, const Catalogue& catalogue,
                  const ScoringRules& rules) {
  const Replay replay = Run(input.initial, input.events);
  for (const auto& [location, copies] : replay.places) {
    const auto stated = location == kGripperLocation ? Count(input.true_gripper_contents)
                                                     : Count(Contents(input.true_final, location));
    CheckSame(location, Count(copies), stated);
  }
  for (const auto& [bin, items] : input.true_final.bin_contents) {
    if (!IsBinName(bin)) throw std::invalid_argument("true final state has unknown bin " + bin);
  }

  ScoreReport report;
  auto add = [&report](ScoreRule rule, int points, const std::string& item, std::string reason) {
    report.lines.push_back({rule, points, item, std::move(reason)});
    report.total += points;
  };
  auto bin_points = [&](const std::string& bin) {
    const std::size_t n = Contents(input.initial, bin).size();
    if (n >= 5) return rules.points_large_bin;
    if (n >= 3) return rules.points_medium_bin;
    return rules.points_small_bin;
  };
  auto bonus = [&](const std::string& item) {
    const int points = catalogue.at(item).bonus;
    if (points != 0) {
      add(ScoreRule::kItemBonus, points, item, "bonus of " + item);
    }
  };
  auto population = [&](const std::string& bin) {
    return std::to_string(Contents(input.initial, bin).size());
  };

  if (input.initial.kind == TaskKind::kPick) {
    std::vector<bool> used(replay.places.at(kToteLocation).size(), false);
    const std::vector<Copy>& tote = replay.places.at(kToteLocation);
    for (const WorkOrderEntry& entry : input.initial.work_order) {
      for (std::size_t i = 0; i < tote.size(); ++i) {
        if (used[i] || tote[i].name != entry.item || tote[i].origin != entry.bin) continue;
        used[i] = true;
        add(ScoreRule::kTargetItem, bin_points(entry.bin), entry.item,
            "picked " + entry.item + " from " + entry.bin + " (" + population(entry.bin) +
                " items at the start) into the tote");
        bonus(entry.item);
        break;
      }
    }
  } else {
    for (int b = 0; b < kNumBins; ++b) {
      const std::string bin = BinName(b);
      for (const Copy& copy : replay.places.at(bin)) {
        if (copy.origin != kToteLocation) continue;
        add(ScoreRule::kStowedItem, bin_points(bin), copy.name,
            "stowed " + copy.name + " from the tote into " + bin + " (" + population(bin) +
                " items at the start)");
        if (rules.stow_item_bonus) bonus(copy.name);
      }
    }
  }

  for (const Copy& copy : replay.outside) {
    add(ScoreRule::kOutside, rules.penalty_outside, copy.name,
        copy.name + " ended outside the bins, the tote and the gripper");
  }

  // Misreported: every item really in a bin or the tote that the output does not list there.
  std::vector<std::string> locations;
  for (int b = 0; b < kNumBins; ++b) locations.push_back(BinName(b));
  locations.push_back(kToteLocation);
  for (const std::string& location : locations) {
    const auto real = Count(Contents(input.true_final, location));
    const auto reported = Count(Contents(input.reported, location));
    for (const auto& [item, n] : real) {
      const auto it = reported.find(item);
      const int listed = it == reported.end() ? 0 : it->second;
      for (int k = listed; k < n; ++k) {
        add(ScoreRule::kMisreported, rules.penalty_misreported, item,
            item + " is in " + location + " but the output file does not say so");
      }
    }
  }

  for (const Event& event : input.events) {
    switch (event.kind) {
      case EventKind::kDamageMinor:
        add(ScoreRule::kDamageMinor, rules.penalty_damage_minor, event.item,
            "minor damage to " + event.item);
        break;
      case EventKind::kDamageMajor:
        add(ScoreRule::kDamageMajor, rules.penalty_damage_major, event.item,
            "major damage to " + event.item);
        break;
      case EventKind::kDrop:
        if (event.height_m > rules.drop_height_limit_m) {
          add(ScoreRule::kDrop, rules.penalty_drop, event.item,
              event.item + " dropped from " + std::to_string(event.height_m) + " m");
        }
        break;
      case EventKind::kProtruding:
        if (event.protrusion_m > rules.protrusion_limit_m) {
          add(ScoreRule::kProtruding, rules.penalty_protruding, event.item,
              event.item + " protrudes " + std::to_string(event.protrusion_m) + " m out of " +
                  event.from);
        }
        break;
      case EventKind::kMove:
      case EventKind::kOutside:
        break;
    }
  }
  return report;
}

}  // namespace picking::apc
