#pragma once

#include <map>
#include <string>
#include <vector>

#include "libs/apc/catalogue.h"
#include "libs/apc/task.h"

namespace picking::orchestrator {

/// How easy each item is to pick, in [0, 1]: the order in which a task attempts its targets.
///
/// The default for an item is (4 - difficulty) / 3 (the catalogue's 1-3 difficulty) times the
/// measured success rate of its detection method (the detector's preferred method for it);
/// `items` overrides single items. The file (data/orchestrator/ease.yaml) is meant to be
/// edited as a cell's figures change.
struct EaseTable {
  std::map<std::string, double> method_success;  ///< "ppf", "sift", "range_templates".
  std::map<std::string, double> items;           ///< Per-item overrides.
  double default_method_success = 0.5;           ///< A method without a figure.

  /// Reads the YAML file; throws std::invalid_argument naming the file and key on a value
  /// outside [0, 1], a non-number or an unknown top-level key.
  static EaseTable FromYamlFile(const std::string& path);
  static EaseTable FromYamlText(const std::string& text, const std::string& source_name);

  /// The item's ease; `method` is its preferred detection method.
  double Ease(const apc::Item& item, const std::string& method) const;
};

/// Each item's preferred detection method from the detector's model file
/// (data/detector/models.json: "default".preferred and per model "preferred"). Throws
/// std::invalid_argument naming the file when it cannot be read.
std::map<std::string, std::string> ReadPreferredMethods(const std::string& models_json_path);

/// One target of a task: an item to move out of its container.
struct Target {
  std::string item;
  std::string bin;  ///< Where it is: "bin_A".."bin_L" (pick) or "tote" (stow).
  int copy = 0;     ///< Which copy of the item in that container (0, 1, ...).
  double ease = 0.0;
  int attempts = 0;  ///< Attempts made so far.
  bool done = false;
  bool given_up = false;
  std::string last_failure;  ///< Why the last attempt failed.
  /// Not a target: another item of a target's bin, moved into another bin to make room for
  /// the target (PickTaskOptions::make_room). Its journal keys are "room/...".
  bool making_room = false;
  int room_moves = 0;  ///< Items moved aside for this target so far.
};

/// The targets in the order to attempt them: a pick task's work order, or every item of a
/// stow task's tote; `ease_order` first (items in that order; an
/// item it names that is not in the work order is an error), then the rest by falling ease,
/// ties by bin name. Throws std::invalid_argument naming the item.
std::vector<Target> OrderTargets(const apc::Task& task, const apc::Catalogue& catalogue,
                                 const EaseTable& ease,
                                 const std::map<std::string, std::string>& preferred_method,
                                 const std::vector<std::string>& ease_order);

}  // namespace picking::orchestrator
