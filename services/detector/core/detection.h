#pragma once

#include <Eigen/Geometry>

#include <chrono>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "libs/camera/pinhole_camera.h"
#include "libs/geometry/point_cloud.h"
#include "services/detector/core/budget_clock.h"

namespace picking::detector {

/// The sensor model of the detector is the shared one of libs/camera (pinhole with OpenCV
/// distortion; camera frame x right, y down, z forward, metres; pixel centres at integer
/// coordinates).
using camera::Distortion;
using camera::PinholeCamera;

/// The three pose estimation methods of the detector.
enum class Method { kPpf, kSift, kRangeTemplates };

/// "ppf", "sift", "range_templates".
std::string ToString(Method method);
/// Inverse of ToString. Throws std::invalid_argument naming the bad value.
Method MethodFromString(const std::string& name);

/// Wall-clock durations of the stages that produced a detection, seconds.
struct DetectionTimings {
  double preprocess_s = 0.0;
  double estimate_s = 0.0;
  double refine_s = 0.0;
  double verify_s = 0.0;
  double total_s = 0.0;
};

/// One detected instance of an item.
struct Detection {
  std::string item;
  /// Pose of the item's model frame in the robot base frame (the scene cloud's frame).
  Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();
  /// Confidence in [0, 1] (for verified detections: the supported visible surface fraction).
  double score = 0.0;
  /// Name of the method that produced it (ToString(Method) for the built-in ones).
  std::string method;
  /// Fraction of the model points used in the last alignment that have a scene partner.
  double fitness = 0.0;
  /// RMS distance of those partners, metres.
  double inlier_rmse_m = 0.0;
  /// Correlation of the model's printed texture (albedo) with the scan's intensities at the
  /// pose, [-1, 1] (appearance.h); NaN when there is no evidence (no texture, too few points).
  double appearance = std::numeric_limits<double>::quiet_NaN();
  /// The evidence under a verified score (Verify), in model points: facing a sensor,
  /// hidden there behind other surfaces, supported by the scan, and in space the sensor saw
  /// through. All 0 without verification.
  std::size_t visible_points = 0;
  std::size_t occluded_points = 0;
  std::size_t supported_points = 0;
  std::size_t conflict_points = 0;
  /// Samples just past the pose's silhouette where the sensor measured a surface not in front
  /// of it, and of those the ones where that surface continues the model's (VerifyResult).
  std::size_t outline_points = 0;
  std::size_t outline_continued = 0;
  std::size_t outline_hidden = 0;  ///< ... and where a surface in front of it hid its outline.
  /// What the outline leaves of the score (VerifyResult::outline_factor): an estimator's search
  /// ranks its poses by their support, and scales each answer's score by this at the end.
  double outline_factor = 1.0;
  DetectionTimings timings;
};

/// Acceptance thresholds of a method's detections.
struct Thresholds {
  double min_score = 0.5;           ///< Detection.score must be >= this; in [0, 1].
  double min_fitness = 0.0;         ///< Detection.fitness must be >= this; in [0, 1].
  double max_inlier_rmse_m = 0.01;  ///< Detection.inlier_rmse_m must be <= this; > 0.

  /// Throws std::invalid_argument naming the bad field.
  void Validate() const;
  bool Accepts(const Detection& detection) const;
};

/// How one item is detected: the preferred method first, then the fallbacks in order.
struct ObjectConfig {
  std::string item;
  Method preferred = Method::kPpf;
  std::vector<Method> fallbacks;
  Thresholds thresholds;
  /// Per-method overrides of `thresholds`.
  std::map<Method, Thresholds> method_thresholds;
  /// Time budget of one detection call for this item, seconds (>= 0; 0: none), counted from
  /// the start of the work on the item (in the detector service, for a call's first item,
  /// from when its cloud has arrived: the shared pre-processing is part of it). No fallback
  /// method is started once it is spent, and the methods stop their searches, refinements
  /// and verifications at it and report what they found so far: "nothing found" within the
  /// budget instead of a call of many seconds. The preferred method always runs. The default
  /// keeps a call under the goal of one second per item (benchmarks/RESULTS.md, simulated
  /// shelf bins) with room for the refinement and verification under way when it ends.
  double time_budget_s = 0.8;

  /// preferred followed by fallbacks.
  std::vector<Method> Order() const;
  const Thresholds& ThresholdsFor(Method method) const;
  /// Throws std::invalid_argument on duplicated methods or invalid thresholds.
  void Validate() const;
};

/// Per-object detector configuration with a default for items not listed.
///
/// File format (JSON):
/// ```
/// {"default": {"preferred": "ppf", "fallbacks": ["range_templates"],
///              "thresholds": {"min_score": 0.5, "min_fitness": 0.0,
///                             "max_inlier_rmse_m": 0.01}},
///  "objects": {"expo_dry_erase_board_eraser": {
///                "preferred": "sift", "fallbacks": ["ppf", "range_templates"],
///                "thresholds": {"min_score": 0.6}, "time_budget_s": 2.0,
///                "method_thresholds": {"sift": {"min_score": 0.4}}}}}
/// ```
/// Every field is optional; an object's unspecified fields inherit from `default`. Unknown
/// keys are errors.
class DetectorConfig final {
 public:
  /// Every item uses `default_config` (its `item` field is ignored).
  explicit DetectorConfig(ObjectConfig default_config = {},
                          std::map<std::string, ObjectConfig> objects = {});

  /// Throws std::runtime_error naming the file, line and field on bad content, or when the
  /// file cannot be read.
  static DetectorConfig LoadFile(const std::string& path);
  /// `source_name` is used in error messages.
  static DetectorConfig Parse(const std::string& text, const std::string& source_name = "<string>");

  /// The item's configuration (the default one, with `item` set, for unlisted items).
  ObjectConfig ForItem(const std::string& item) const;
  const ObjectConfig& default_config() const { return default_; }
  const std::map<std::string, ObjectConfig>& objects() const { return objects_; }

 private:
  ObjectConfig default_;
  std::map<std::string, ObjectConfig> objects_;
};

/// What an estimator gets: the scene in the base frame and where the sensor was.
struct EstimatorInput {
  std::string item;
  /// Scene cloud, points in the base frame; organised when it came from the scanner.
  const geometry::PointCloud* scene = nullptr;
  /// Pose of the sensor (camera) frame in the base frame at capture time.
  Eigen::Isometry3d X_BaseSensor = Eigen::Isometry3d::Identity();
  /// Intrinsics of the sensor, when known (needed by SIFT EPnP and range templates).
  std::optional<PinholeCamera> camera;
  /// End of the call's time budget (set by DetectionChain::Run from the item's
  /// time_budget_s): an estimator with a long search stops it here and returns what it found.
  /// A time point of `clock`.
  std::chrono::steady_clock::time_point budget_end = std::chrono::steady_clock::time_point::max();
  /// When the work on the item began (e.g. before a shared pre-processing), a time point of
  /// `clock`: DetectionChain::Run counts the item's time_budget_s from here; unset, from the
  /// start of Run.
  std::optional<std::chrono::steady_clock::time_point> budget_start;
  /// The clock the budget is judged by, in the chain and in every estimator's search (the
  /// steady clock by default; a test's own clock makes the search independent of the load).
  BudgetClock clock;
};

/// A pose estimation strategy (PPF, SIFT, range templates, or a fake in tests).
class Estimator {
 public:
  virtual ~Estimator() = default;
  /// The method this estimator implements.
  virtual Method method() const = 0;
  /// Candidate detections of input.item, best first; empty when nothing was found. May throw
  /// on bad input; the chain records the message and moves on to the next method.
  virtual std::vector<Detection> Estimate(const EstimatorInput& input) = 0;
};

/// Thrown by an estimator whose method cannot run on this item or scan, for a reason a person
/// can act on (the model has no SIFT views, the scan has no intensities, no range templates):
/// the chain records the reason (AttemptOutcome::kCannotRun) and moves on.
class MethodNotApplicableError final : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Thrown by an estimator that ran and found no candidate, with why (no cluster of a
/// plausible size, no template matched): the chain records it (AttemptOutcome::kNoCandidate).
class NoCandidateError final : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// How one method's attempt ended.
enum class AttemptOutcome {
  kAccepted,         ///< A candidate passed the method's thresholds.
  kBelowThresholds,  ///< Candidates, none passing (reason: the best one's figures).
  kNoCandidate,      ///< The method ran and found nothing.
  kCannotRun,        ///< The method does not apply to this item or scan.
  kFailed,           ///< The estimator threw (reason: its message).
  kUnavailable,      ///< No estimator for the method in this detector.
  kNotStarted,       ///< The item's time budget was spent before its turn.
};
const char* ToString(AttemptOutcome outcome);

/// What happened when one method was tried.
struct ChainAttempt {
  Method method = Method::kPpf;
  bool available = true;  ///< False when no estimator for the method was registered.
  std::size_t num_candidates = 0;
  std::optional<Detection> best;  ///< Best candidate, accepted or not.
  bool accepted = false;
  std::string error;  ///< Exception message, when the estimator threw.
  double duration_s = 0.0;
  AttemptOutcome outcome = AttemptOutcome::kNoCandidate;
  /// Why the method gave no accepted pose, in words a person can act on (empty if accepted).
  std::string reason;
};

struct ChainResult {
  std::optional<Detection> detection;  ///< The accepted detection, if any.
  std::vector<ChainAttempt> attempts;  ///< In the order tried.
};

/// Runs an item's methods in its configured order until one returns a detection that passes
/// that method's thresholds (the first such candidate in the estimator's ranking), or the
/// item's time budget is spent on EstimatorInput::clock (no further method started).
class DetectionChain final {
 public:
  /// Throws std::invalid_argument on a null estimator or two estimators for one method.
  DetectionChain(DetectorConfig config, std::vector<std::shared_ptr<Estimator>> estimators);

  /// Throws std::invalid_argument when input.scene is null.
  ChainResult Run(const EstimatorInput& input) const;

  const DetectorConfig& config() const { return config_; }

 private:
  DetectorConfig config_;
  std::map<Method, std::shared_ptr<Estimator>> estimators_;
};

}  // namespace picking::detector
