#include "services/orchestrator/core/work_list.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <stdexcept>

namespace picking::orchestrator {
namespace {

double Fraction(const YAML::Node& node, const std::string& where) {
  double value = 0.0;
  try {
    value = node.as<double>();
  } catch (const YAML::Exception&) {
    throw std::invalid_argument(where + ": expected a number in [0, 1]");
  }
  if (!std::isfinite(value) || value < 0.0 || value > 1.0) {
    throw std::invalid_argument(where + ": " + std::to_string(value) + " is outside [0, 1]");
  }
  return value;
}

std::map<std::string, double> FractionMap(const YAML::Node& node, const std::string& where) {
  std::map<std::string, double> out;
  if (!node) return out;
  if (!node.IsMap()) throw std::invalid_argument(where + ": expected a mapping");
  for (const auto& entry : node) {
    const std::string key = entry.first.as<std::string>();
    out[key] = Fraction(entry.second, where + "." + key);
  }
  return out;
}

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::invalid_argument(path + ": cannot open");
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

}  // namespace

EaseTable EaseTable::FromYamlText(const std::string& text, const std::string& source_name) {
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument(source_name + ": malformed YAML: " + e.what());
  }
  EaseTable table;
  if (!root || root.IsNull()) return table;
  if (!root.IsMap()) throw std::invalid_argument(source_name + ": expected a mapping");
  for (const auto& entry : root) {
    const std::string key = entry.first.as<std::string>();
    if (key == "method_success") {
      table.method_success = FractionMap(entry.second, source_name + ": method_success");
    } else if (key == "items") {
      table.items = FractionMap(entry.second, source_name + ": items");
    } else if (key == "default_method_success") {
      table.default_method_success = Fraction(entry.second, source_name + ": " + key);
    } else if (key != "version") {
      throw std::invalid_argument(source_name + ": unknown key '" + key +
                                  "' (expected method_success, items, default_method_success)");
    }
  }
  return table;
}

EaseTable EaseTable::FromYamlFile(const std::string& path) {
  return FromYamlText(ReadText(path), path);
}

double EaseTable::Ease(const apc::Item& item, const std::string& method) const {
  const auto override_it = items.find(item.name);
  if (override_it != items.end()) return override_it->second;
  const auto method_it = method_success.find(method);
  const double success =
      method_it == method_success.end() ? default_method_success : method_it->second;
  const int difficulty = std::clamp(item.difficulty, 1, 3);
  return (4.0 - difficulty) / 3.0 * success;
}

std::map<std::string, std::string> ReadPreferredMethods(const std::string& models_json_path) {
  nlohmann::json document;
  try {
    document = nlohmann::json::parse(ReadText(models_json_path));
  } catch (const nlohmann::json::exception& e) {
    throw std::invalid_argument(models_json_path + ": " + e.what());
  }
  const std::string fallback = document.value("/default/preferred"_json_pointer, "ppf");
  std::map<std::string, std::string> out;
  if (document.contains("models") && document["models"].is_object()) {
    for (const auto& [name, model] : document["models"].items()) {
      out[name] = model.is_object() ? model.value("preferred", fallback) : fallback;
    }
  }
  out[""] = fallback;  // for items the file does not list
  return out;
}

std::vector<Target> OrderTargets(const apc::Task& task, const apc::Catalogue& catalogue,
                                 const EaseTable& ease,
                                 const std::map<std::string, std::string>& preferred_method,
                                 const std::vector<std::string>& ease_order) {
  std::vector<apc::WorkOrderEntry> entries = task.work_order;
  if (task.kind == apc::TaskKind::kStow) {
    entries.clear();
    for (const std::string& item : task.tote_contents) entries.push_back({"tote", item});
  }
  std::vector<Target> targets;
  std::map<std::pair<std::string, std::string>, int> copies;
  for (const apc::WorkOrderEntry& entry : entries) {
    const apc::Item& item = catalogue.at(entry.item);
    auto method = preferred_method.find(entry.item);
    if (method == preferred_method.end()) method = preferred_method.find("");
    const std::string method_name = method == preferred_method.end() ? "ppf" : method->second;
    Target target{entry.item, entry.bin, copies[{entry.bin, entry.item}]++};
    target.ease = ease.Ease(item, method_name);
    targets.push_back(target);
  }
  // Rank: position in `ease_order` first, then falling ease, then bin.
  std::map<std::string, int> rank;
  for (std::size_t i = 0; i < ease_order.size(); ++i) {
    const bool listed = std::any_of(targets.begin(), targets.end(),
                                    [&](const Target& t) { return t.item == ease_order[i]; });
    if (!listed) {
      throw std::invalid_argument("ease_order[" + std::to_string(i) + "]: '" + ease_order[i] +
                                  "' is not among the task's targets");
    }
    rank.emplace(ease_order[i], static_cast<int>(i));
  }
  auto rank_of = [&](const Target& t) {
    const auto it = rank.find(t.item);
    return it == rank.end() ? static_cast<int>(ease_order.size()) : it->second;
  };
  std::stable_sort(targets.begin(), targets.end(), [&](const Target& a, const Target& b) {
    if (rank_of(a) != rank_of(b)) return rank_of(a) < rank_of(b);
    if (a.ease != b.ease) return a.ease > b.ease;
    return a.bin < b.bin;
  });
  return targets;
}

}  // namespace picking::orchestrator
