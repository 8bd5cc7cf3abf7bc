#include "services/detector/core/detection.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <iomanip>
#include <set>
#include <sstream>
#include <stdexcept>
#include <utility>

namespace picking::detector {
namespace {

using Json = nlohmann::json;

// A parse or validation error naming the source and the field path.
[[noreturn]] void Fail(const std::string& source, const std::string& field,
                       const std::string& what) {
  throw std::runtime_error(source + ": field '" + field + "': " + what);
}

void CheckKeys(const Json& node, const std::set<std::string>& allowed, const std::string& source,
               const std::string& path) {
  if (!node.is_object()) Fail(source, path, "expected an object");
  for (const auto& [key, value] : node.items()) {
    (void)value;
    if (allowed.count(key) == 0) Fail(source, path.empty() ? key : path + "." + key, "unknown key");
  }
}

Method ParseMethod(const Json& node, const std::string& source, const std::string& path) {
  if (!node.is_string()) Fail(source, path, "expected a method name string");
  try {
    return MethodFromString(node.get<std::string>());
  } catch (const std::invalid_argument& e) {
    Fail(source, path, e.what());
  }
}

double ParseNumber(const Json& node, const std::string& source, const std::string& path) {
  if (!node.is_number()) Fail(source, path, "expected a number");
  return node.get<double>();
}

Thresholds ParseThresholds(const Json& node, Thresholds base, const std::string& source,
                           const std::string& path) {
  CheckKeys(node, {"min_score", "min_fitness", "max_inlier_rmse_m"}, source, path);
  if (node.contains("min_score"))
    base.min_score = ParseNumber(node["min_score"], source, path + ".min_score");
  if (node.contains("min_fitness"))
    base.min_fitness = ParseNumber(node["min_fitness"], source, path + ".min_fitness");
  if (node.contains("max_inlier_rmse_m"))
    base.max_inlier_rmse_m =
        ParseNumber(node["max_inlier_rmse_m"], source, path + ".max_inlier_rmse_m");
  try {
    base.Validate();
  } catch (const std::invalid_argument& e) {
    Fail(source, path, e.what());
  }
  return base;
}

ObjectConfig ParseObject(const Json& node, ObjectConfig base, const std::string& source,
                         const std::string& path) {
  CheckKeys(node, {"preferred", "fallbacks", "thresholds", "method_thresholds", "time_budget_s"},
            source, path);
  if (node.contains("time_budget_s"))
    base.time_budget_s = ParseNumber(node["time_budget_s"], source, path + ".time_budget_s");
  if (node.contains("preferred"))
    base.preferred = ParseMethod(node["preferred"], source, path + ".preferred");
  if (node.contains("fallbacks")) {
    const Json& list = node["fallbacks"];
    if (!list.is_array()) Fail(source, path + ".fallbacks", "expected a list of method names");
    base.fallbacks.clear();
    for (std::size_t i = 0; i < list.size(); ++i) {
      base.fallbacks.push_back(
          ParseMethod(list[i], source, path + ".fallbacks[" + std::to_string(i) + "]"));
    }
  }
  if (node.contains("thresholds")) {
    base.thresholds =
        ParseThresholds(node["thresholds"], base.thresholds, source, path + ".thresholds");
  }
  if (node.contains("method_thresholds")) {
    const Json& map = node["method_thresholds"];
    if (!map.is_object()) Fail(source, path + ".method_thresholds", "expected an object");
    for (const auto& [key, value] : map.items()) {
      const std::string sub = path + ".method_thresholds." + key;
      Method method;
      try {
        method = MethodFromString(key);
      } catch (const std::invalid_argument& e) {
        Fail(source, sub, e.what());
      }
      base.method_thresholds[method] = ParseThresholds(value, base.thresholds, source, sub);
    }
  }
  try {
    base.Validate();
  } catch (const std::invalid_argument& e) {
    Fail(source, path, e.what());
  }
  return base;
}

// 1-based line of a byte offset in text.
std::size_t LineOf(const std::string& text, std::size_t byte) {
  byte = std::min(byte, text.size());
  return 1 + static_cast<std::size_t>(std::count(text.begin(), text.begin() + byte, '\n'));
}

}  // namespace

std::string ToString(Method method) {
  switch (method) {
    case Method::kPpf:
      return "ppf";
    case Method::kSift:
      return "sift";
    case Method::kRangeTemplates:
      return "range_templates";
  }
  throw std::logic_error("ToString: invalid Method value");
}

Method MethodFromString(const std::string& name) {
  if (name == "ppf") return Method::kPpf;
  if (name == "sift") return Method::kSift;
  if (name == "range_templates") return Method::kRangeTemplates;
  throw std::invalid_argument("unknown detection method '" + name +
                              "' (expected ppf, sift or range_templates)");
}

void Thresholds::Validate() const {
  if (!(min_score >= 0.0 && min_score <= 1.0))
    throw std::invalid_argument("min_score must be in [0, 1]");
  if (!(min_fitness >= 0.0 && min_fitness <= 1.0))
    throw std::invalid_argument("min_fitness must be in [0, 1]");
  if (!(max_inlier_rmse_m > 0.0) || !std::isfinite(max_inlier_rmse_m))
    throw std::invalid_argument("max_inlier_rmse_m must be positive and finite");
}

bool Thresholds::Accepts(const Detection& detection) const {
  return detection.score >= min_score && detection.fitness >= min_fitness &&
         detection.inlier_rmse_m <= max_inlier_rmse_m;
}

std::vector<Method> ObjectConfig::Order() const {
  std::vector<Method> order{preferred};
  order.insert(order.end(), fallbacks.begin(), fallbacks.end());
  return order;
}

const Thresholds& ObjectConfig::ThresholdsFor(Method method) const {
  const auto it = method_thresholds.find(method);
  return it == method_thresholds.end() ? thresholds : it->second;
}

void ObjectConfig::Validate() const {
  std::set<Method> seen;
  for (Method m : Order()) {
    if (!seen.insert(m).second)
      throw std::invalid_argument("method '" + ToString(m) +
                                  "' appears more than once in preferred + fallbacks");
  }
  if (!(time_budget_s >= 0.0) || !std::isfinite(time_budget_s)) {
    throw std::invalid_argument("time_budget_s must be finite and >= 0, got " +
                                std::to_string(time_budget_s));
  }
  thresholds.Validate();
  for (const auto& [method, t] : method_thresholds) {
    try {
      t.Validate();
    } catch (const std::invalid_argument& e) {
      throw std::invalid_argument("method_thresholds." + ToString(method) + ": " + e.what());
    }
  }
}

DetectorConfig::DetectorConfig(ObjectConfig default_config,
                               std::map<std::string, ObjectConfig> objects)
    : default_(std::move(default_config)), objects_(std::move(objects)) {
  default_.Validate();
  for (auto& [name, config] : objects_) {
    if (name.empty()) throw std::invalid_argument("DetectorConfig: empty item name");
    config.item = name;
    config.Validate();
  }
}

DetectorConfig DetectorConfig::LoadFile(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path + ": cannot open detector configuration file");
  std::stringstream buffer;
  buffer << in.rdbuf();
  return Parse(buffer.str(), path);
}

DetectorConfig DetectorConfig::Parse(const std::string& text, const std::string& source_name) {
  Json root;
  try {
    root = Json::parse(text);
  } catch (const Json::parse_error& e) {
    throw std::runtime_error(source_name + ":" + std::to_string(LineOf(text, e.byte)) +
                             ": JSON syntax error: " + e.what());
  }
  CheckKeys(root, {"default", "objects"}, source_name, "");
  ObjectConfig default_config;
  if (root.contains("default"))
    default_config = ParseObject(root["default"], default_config, source_name, "default");
  default_config.item.clear();
  std::map<std::string, ObjectConfig> objects;
  if (root.contains("objects")) {
    const Json& map = root["objects"];
    if (!map.is_object()) Fail(source_name, "objects", "expected an object keyed by item name");
    for (const auto& [name, node] : map.items()) {
      if (name.empty()) Fail(source_name, "objects", "empty item name");
      ObjectConfig config = ParseObject(node, default_config, source_name, "objects." + name);
      config.item = name;
      objects.emplace(name, std::move(config));
    }
  }
  return DetectorConfig(std::move(default_config), std::move(objects));
}

ObjectConfig DetectorConfig::ForItem(const std::string& item) const {
  const auto it = objects_.find(item);
  if (it != objects_.end()) return it->second;
  ObjectConfig config = default_;
  config.item = item;
  return config;
}

DetectionChain::DetectionChain(DetectorConfig config,
                               std::vector<std::shared_ptr<Estimator>> estimators)
    : config_(std::move(config)) {
  for (const auto& estimator : estimators) {
    if (!estimator) throw std::invalid_argument("DetectionChain: null estimator");
    if (!estimators_.emplace(estimator->method(), estimator).second)
      throw std::invalid_argument("DetectionChain: two estimators for method '" +
                                  ToString(estimator->method()) + "'");
  }
}

const char* ToString(AttemptOutcome outcome) {
  switch (outcome) {
    case AttemptOutcome::kAccepted:
      return "accepted";
    case AttemptOutcome::kBelowThresholds:
      return "below thresholds";
    case AttemptOutcome::kNoCandidate:
      return "no candidate";
    case AttemptOutcome::kCannotRun:
      return "cannot run";
    case AttemptOutcome::kFailed:
      return "failed";
    case AttemptOutcome::kUnavailable:
      return "unavailable";
    case AttemptOutcome::kNotStarted:
      return "not started";
  }
  return "unknown";
}

namespace {

// Why the best of a method's candidates was not accepted: each threshold it missed.
std::string BelowThresholdsReason(const Detection& best, const Thresholds& t) {
  std::ostringstream why;
  why << std::setprecision(3) << "best candidate below the thresholds:";
  if (best.score < t.min_score) why << " score " << best.score << " < " << t.min_score << ";";
  if (best.fitness < t.min_fitness) {
    why << " fitness " << best.fitness << " < " << t.min_fitness << ";";
  }
  if (best.inlier_rmse_m > t.max_inlier_rmse_m) {
    why << " inlier rmse " << best.inlier_rmse_m << " m > " << t.max_inlier_rmse_m << " m;";
  }
  std::string reason = why.str();
  if (reason.back() == ';') reason.pop_back();
  return reason;
}

// Runs one method's estimator and records how it ended.
ChainAttempt TryMethod(Estimator& estimator, Method method, const EstimatorInput& input,
                       const Thresholds& thresholds) {
  ChainAttempt attempt;
  attempt.method = method;
  const auto start = std::chrono::steady_clock::now();
  std::vector<Detection> candidates;
  try {
    candidates = estimator.Estimate(input);
    attempt.outcome = AttemptOutcome::kNoCandidate;
    attempt.reason = "no candidate pose";
  } catch (const MethodNotApplicableError& e) {
    attempt.outcome = AttemptOutcome::kCannotRun;
    attempt.reason = e.what();
  } catch (const NoCandidateError& e) {
    attempt.outcome = AttemptOutcome::kNoCandidate;
    attempt.reason = e.what();
  } catch (const std::exception& e) {
    attempt.error = e.what();
    attempt.outcome = AttemptOutcome::kFailed;
    attempt.reason = e.what();
  }
  attempt.duration_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  attempt.num_candidates = candidates.size();
  if (candidates.empty()) return attempt;
  // Estimators return their candidates best first (score with the appearance as a bonus:
  // SortByScore), so the first accepted one is taken; if none is accepted, the first is
  // kept for the record. Picking by score alone here would undo the appearance's ranking
  // and report a neighbour of the same shape whose printing does not match.
  for (const Detection& d : candidates) {
    if (!thresholds.Accepts(d)) continue;
    attempt.accepted = true;
    attempt.outcome = AttemptOutcome::kAccepted;
    attempt.reason.clear();
    attempt.best = d;
    if (attempt.best->item.empty()) attempt.best->item = input.item;
    if (attempt.best->method.empty()) attempt.best->method = ToString(method);
    return attempt;
  }
  attempt.best = candidates.front();
  attempt.outcome = AttemptOutcome::kBelowThresholds;
  attempt.reason = BelowThresholdsReason(candidates.front(), thresholds);
  return attempt;
}

}  // namespace

ChainResult DetectionChain::Run(const EstimatorInput& input) const {
  if (input.scene == nullptr) throw std::invalid_argument("DetectionChain::Run: null scene");
  const ObjectConfig object = config_.ForItem(input.item);
  EstimatorInput budgeted = input;
  if (object.time_budget_s > 0.0) {
    const auto budget = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
        std::chrono::duration<double>(object.time_budget_s));
    const auto start = input.budget_start.value_or(input.clock.Now());
    budgeted.budget_end = std::min(input.budget_end, start + budget);
  }
  ChainResult result;
  bool first = true;
  bool budget_spent = false;
  for (Method method : object.Order()) {
    budget_spent = budget_spent || (!first && input.clock.Now() > budgeted.budget_end);
    first = false;
    const auto it = estimators_.find(method);
    if (budget_spent || it == estimators_.end()) {
      ChainAttempt attempt;
      attempt.method = method;
      attempt.available = it != estimators_.end();
      attempt.outcome = budget_spent ? AttemptOutcome::kNotStarted : AttemptOutcome::kUnavailable;
      attempt.reason = budget_spent ? "not started: the item's time budget was spent"
                                    : "no estimator for this method in this detector";
      result.attempts.push_back(std::move(attempt));
      continue;
    }
    result.attempts.push_back(
        TryMethod(*it->second, method, budgeted, object.ThresholdsFor(method)));
    if (result.attempts.back().accepted) {
      result.detection = result.attempts.back().best;
      return result;
    }
  }
  return result;
}

}  // namespace picking::detector
