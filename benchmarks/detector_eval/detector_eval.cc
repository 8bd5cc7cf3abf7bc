// detector_eval: the detector on simulated scans of the APC shelf bins.
//
// For each pick layout and each of its work-order entries (one target item per bin), the bin
// is laid out by the simulator, scanned in process (Embree structured-light rendering with
// camera noise, Gray-code decoding, sub-pixel refinement, triangulation into the base frame)
// and the detector runs its full method chain for the target with the bin as region, then
// each method on its own. A detection counts as correct when its ADD error against the
// closest true instance of the item, judged by the closest symmetric pose, is below 10 % of
// the model's diameter.
//
// Usage: detector_eval [--layouts=1,2,3] [--seed=N] [--per_method=true|false]
//                      [--bins=A,B,...] [--markdown=FILE] [--budget_scale=F]
//                      [--ppf_segments=true|false] [--sphere_fit=true|false]
//                      [--floor_band=true|false] [--multi_sensor=true|false]
//                      [--views=1|3] [--view_offset_m=0.15] [--side_height_m=0.25]
//                      [--appearance=true|false|rank] [--appearance_search=true|false]
//                      [--patch_contrast=true|false] [--min_print=F]
//                      [--search_step_m=F] [--search_levels=N] [--cache_dir=DIR]
//                      [--box_faces=true|false] [--box_continuation=true|false]
//                      [--box_polish_contradicted=true|false]
//                      [--hypotheses=N] [--reference_step=N] [--layout_mode=tidy|settled]
//                      [--only=LAYOUT:BIN,...] [--candidates=N] [--candidates_csv=FILE]
//                      [--sensor=structured_light|rgbd] [--outline=true|false]
//
// --outline=false measures the scene past each pose's silhouette but leaves its score as it is
// (VerifyOptions::outline_check).
// --sensor=rgbd scans each view with a simulated commodity RGB-D camera (Xtion-like:
// simulator::RenderRgbd, holes, noise growing with the square of the distance, a colour image
// under room light) instead of the cell's structured-light scanner.
//
// --only=2:H,3:G runs those targets only (layout 2 bin H, layout 3 bin G): one bin in seconds
// instead of the whole set, for looking into a failure. --candidates=N also prints up to N
// distinct poses the accepting method found above its thresholds, each with its error against
// the truth and its evidence (what ranked a wrong pose first); --candidates_csv=FILE writes
// each of them, judged and with its evidence, as a CSV row (detector_eval::CandidateLog).
// --layout_mode=settled drops the items and lets them settle by physics (stacked, leaning,
// standing on end: simulator::PhysicsLayout) instead of laying them side by side.
// --budget_scale multiplies every item's time budget (on a machine busy with other work,
// the load factor); --ppf_segments and --sphere_fit switch PPF's per-cluster hypotheses and
// the sphere fit of ball models (detector::PpfSearchOptions) for comparisons; --box_faces
// the box models' face poses on the scene's planar patches (PpfSearchOptions::fit_boxes) and
// --box_continuation the penalty of box poses the scene's surface runs on past
// (RefineVerifyOptions::box_continuation_weight); --box_polish_contradicted=false polishes
// only the best box candidate and its best quarter-turn, not also the best shape fit the
// print contradicts (PpfSearchOptions::box_polish_contradicted). --views=3 scans
// each bin from the cell's three camera positions (world::CellBinScanViews, the planner's
// scan poses: the middle one and view_offset_m to either side, all aimed at the bin floor's
// middle; side_height_m above the bin's middle where they see over the front items, the
// middle view 0.1 m),
// and detects in the views stacked as the scanner stacks them (MergeViews), through the
// detector service's own workflow with the views' poses (DetectParams.X_frame_sensor,
// detector::SceneOptions::view_poses): each view's print compensated and screened
// by its own sensor, poses verified from every view's sensor (--multi_sensor=false: from the
// first view's alone). --appearance=false ranks and accepts poses
// without the printed texture's appearance (RefineVerifyOptions), =rank only ranks by it.
// --appearance_search=false leaves out PPF's print-guided pose search (SearchAppearancePose);
// --search_step_m and --search_levels set its first step and number of step halvings.
// --hypotheses sets how many of PPF's vote clusters are kept and refined, --reference_step
// which sampled scene points vote (every n-th).
// --patch_contrast=false compares the print as one correlation over all faces instead of
// per surface patch (AppearanceOptions::patch_contrast); --min_print sets the correlation
// below which verification takes a print as contradicting the pose (halving its score).
// Models are built from the current code into --cache_dir, by default a new temporary folder
// removed at the end: a cache left by other code would measure that code's models.
#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "benchmarks/detector_eval/bin_detection.h"
#include "benchmarks/detector_eval/bin_scan_sim.h"
#include "benchmarks/detector_eval/pose_check.h"
#include "libs/apc/catalogue.h"
#include "services/detector/core/model_library.h"

namespace picking::detector_eval {
namespace {

std::vector<std::string> Split(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream in(s);
  std::string part;
  while (std::getline(in, part, ',')) {
    if (!part.empty()) out.push_back(part);
  }
  return out;
}

struct Args {
  std::vector<std::string> layouts = {"1", "2", "3"};
  std::vector<std::string> bins;  // Empty: every bin of the work order.
  // --only: "layout:bin_X" targets; empty: every target the other filters leave.
  std::vector<std::string> only;
  std::uint32_t seed = 1;
  BinSensor sensor = BinSensor::kStructuredLight;
  bool per_method = true;
  std::string markdown;
  BinDetectionOptions detection;
  int views = 1;
  std::string cache_dir;       // empty: a fresh temporary folder
  std::string candidates_csv;  // --candidates_csv: every candidate's evidence, one row each
  // The views of --views=3 (the first alone with --views=1); --view_offset_m and
  // --side_height_m move the side ones.
  std::vector<world::BinScanView> bin_views = world::CellBinScanViews();
  simulator::LayoutMode layout_mode = simulator::LayoutMode::kTidy;
};

bool ParseBool(const std::string& key, const std::string& v) {
  if (v == "true" || v == "1") return true;
  if (v == "false" || v == "0") return false;
  throw std::invalid_argument(key + " must be true or false, got '" + v + "'");
}

// The detector's search and verification settings among the arguments: true when `a` is one
// of them (set in `detection`).
bool ParseDetectionFlag(const std::string& a, BinDetectionOptions* detection) {
  const auto value = [&](const std::string& key) -> std::optional<std::string> {
    if (a.rfind(key + "=", 0) == 0) return a.substr(key.size() + 1);
    return std::nullopt;
  };
  if (auto v = value("--budget_scale")) {
    detection->budget_scale = std::stod(*v);
    if (!(detection->budget_scale > 0.0)) {
      throw std::invalid_argument("--budget_scale must be positive");
    }
  } else if (auto v = value("--ppf_segments")) {
    detection->estimators.ppf_search.per_segment_hypotheses = ParseBool("--ppf_segments", *v);
  } else if (auto v = value("--appearance")) {
    // false: the chain neither ranks by nor penalises the printed texture's appearance;
    // rank: it ranks candidates by it but does not penalise a contradiction.
    auto& refine = detection->estimators.refine;
    auto& ppf = detection->estimators.ppf;
    if (*v == "rank") {
      refine.verify.appearance_contradiction_scale = 1.0;
      ppf.min_appearance_correlation = -1.0f;
    } else if (!ParseBool("--appearance", *v)) {
      refine.verify.appearance_contradiction_scale = 1.0;
      refine.appearance_rank_weight = 0.0;
      ppf.min_appearance_correlation = -1.0f;
      ppf.appearance_weight = 0.0f;
    }
  } else if (auto v = value("--search_step_m")) {
    detection->estimators.ppf.appearance_search.start_step_m = std::stod(*v);
  } else if (auto v = value("--search_levels")) {
    detection->estimators.ppf.appearance_search.levels = std::stoi(*v);
  } else if (auto v = value("--min_print")) {
    // Verification: a print correlating below this contradicts the pose (halves its score).
    detection->estimators.refine.verify.min_appearance_correlation = std::stod(*v);
  } else if (auto v = value("--patch_contrast")) {
    const bool on = ParseBool("--patch_contrast", *v);
    detection->estimators.ppf.appearance.patch_contrast = on;
    detection->estimators.refine.verify.appearance.patch_contrast = on;
  } else if (auto v = value("--appearance_search")) {
    if (!ParseBool("--appearance_search", *v)) {
      detection->estimators.ppf.appearance_search.levels = 0;
    }
  } else if (auto v = value("--hypotheses")) {
    // PPF's vote clusters kept and refined (PpfMatchOptions::max_hypotheses and
    // PpfDetectorOptions::hypotheses_to_verify together).
    const int n = std::stoi(*v);
    if (n < 1) throw std::invalid_argument("--hypotheses must be >= 1");
    detection->estimators.ppf.match.max_hypotheses = n;
    detection->estimators.ppf.hypotheses_to_verify = n;
  } else if (auto v = value("--reference_step")) {
    const int n = std::stoi(*v);
    if (n < 1) throw std::invalid_argument("--reference_step must be >= 1");
    detection->estimators.ppf.match.reference_step = n;
  } else if (auto v = value("--outline")) {
    detection->estimators.refine.verify.outline_check = ParseBool("--outline", *v);
  } else if (auto v = value("--multi_sensor")) {
    detection->multi_sensor_verification = ParseBool("--multi_sensor", *v);
  } else if (auto v = value("--floor_band")) {
    // false: the wall margin spares the bin's bottom face; only the measured floor goes.
    if (!ParseBool("--floor_band", *v)) detection->wall_faces &= ~detector::kFaceMinZ;
  } else if (auto v = value("--sphere_fit")) {
    detection->estimators.ppf_search.fit_spheres = ParseBool("--sphere_fit", *v);
  } else if (auto v = value("--box_faces")) {
    detection->estimators.ppf_search.fit_boxes = ParseBool("--box_faces", *v);
  } else if (auto v = value("--box_polish_contradicted")) {
    detection->estimators.ppf_search.box_polish_contradicted =
        ParseBool("--box_polish_contradicted", *v);
  } else if (auto v = value("--box_continuation")) {
    detection->estimators.refine.box_continuation_weight =
        ParseBool("--box_continuation", *v) ? 1.0 : 0.0;
  } else {
    return false;
  }
  return true;
}

Args Parse(int argc, char** argv) {
  Args args;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const auto value = [&](const std::string& key) -> std::optional<std::string> {
      if (a.rfind(key + "=", 0) == 0) return a.substr(key.size() + 1);
      return std::nullopt;
    };
    if (auto v = value("--layouts")) {
      args.layouts = Split(*v);
    } else if (auto v = value("--bins")) {
      for (const std::string& b : Split(*v)) args.bins.push_back("bin_" + b);
    } else if (auto v = value("--only")) {
      for (const std::string& target : Split(*v)) {
        const auto colon = target.find(':');
        if (colon == std::string::npos || colon == 0 || colon + 1 == target.size()) {
          throw std::invalid_argument("--only takes LAYOUT:BIN pairs, got '" + target + "'");
        }
        args.only.push_back(target.substr(0, colon) + ":bin_" + target.substr(colon + 1));
      }
    } else if (auto v = value("--candidates")) {
      const int n = std::stoi(*v);
      if (n < 1) throw std::invalid_argument("--candidates must be >= 1");
      args.detection.max_results = static_cast<std::size_t>(n);
    } else if (auto v = value("--candidates_csv")) {
      args.candidates_csv = *v;
    } else if (auto v = value("--sensor")) {
      if (*v != "structured_light" && *v != "rgbd") {
        throw std::invalid_argument("--sensor is structured_light or rgbd, got '" + *v + "'");
      }
      args.sensor = *v == "rgbd" ? BinSensor::kRgbd : BinSensor::kStructuredLight;
    } else if (auto v = value("--seed")) {
      args.seed = static_cast<std::uint32_t>(std::stoul(*v));
    } else if (auto v = value("--per_method")) {
      args.per_method = *v == "true" || *v == "1";
    } else if (auto v = value("--markdown")) {
      args.markdown = *v;
    } else if (auto v = value("--views")) {
      args.views = std::stoi(*v);
      if (args.views != 1 && args.views != 3) throw std::invalid_argument("--views must be 1 or 3");
    } else if (auto v = value("--layout_mode")) {
      args.layout_mode = simulator::LayoutModeFromString(*v);
    } else if (auto v = value("--view_offset_m")) {
      args.bin_views[1].lateral_offset_m = -std::stod(*v);
      args.bin_views[2].lateral_offset_m = std::stod(*v);
    } else if (auto v = value("--side_height_m")) {
      const double height_m = std::stod(*v);
      if (!(std::abs(height_m) < 0.5)) {
        throw std::invalid_argument("--side_height_m must be within 0.5 m of the bin's middle");
      }
      args.bin_views[1].height_above_centre_m = args.bin_views[2].height_above_centre_m = height_m;
    } else if (auto v = value("--cache_dir")) {
      args.cache_dir = *v;
    } else if (ParseDetectionFlag(a, &args.detection)) {
      continue;
    } else {
      throw std::invalid_argument("unknown argument '" + a +
                                  "' (see the header of detector_eval.cc)");
    }
  }
  return args;
}

// Outcome of one detection call.
struct Outcome {
  bool applicable = true;  // False: the method has no model for the item (e.g. no texture).
  bool detected = false;   // A detection was accepted.
  bool correct = false;    // ... within 10 % of the diameter of a true instance.
  double add_m = 0.0;
  double rotation_rad = 0.0;
  double total_s = 0.0;
  std::string method;  // Accepting method.
  double score = 0.0;
  double appearance = std::numeric_limits<double>::quiet_NaN();
  // The accepted pose's evidence (Detection's visible / occluded / supported / conflict
  // model points), for telling thin evidence from a well-seen wrong pose.
  std::string evidence;
  std::string error;
  std::string
      attempts;  // Methods tried and their durations, e.g. "ppf 0.41s range_templates 0.6s".
};

// "visible V occluded O supported S conflicts C" of a verified detection.
std::string Evidence(const detector::Detection& d) {
  std::ostringstream s;
  s << "visible " << d.visible_points << " occluded " << d.occluded_points << " supported "
    << d.supported_points << " conflicts " << d.conflict_points;
  return s.str();
}

Outcome Judge(const BinDetectionResult& r, const detector::LoadedModel& model,
              const std::vector<TrueItem>& truth, const std::string& item) {
  Outcome o;
  o.total_s = r.total_s;
  for (const auto& a : r.chain.attempts) {
    if (!a.error.empty()) o.error = a.error;
    if (!a.available) continue;
    std::ostringstream s;
    s << (o.attempts.empty() ? "" : " ") << detector::ToString(a.method) << " " << std::fixed
      << std::setprecision(2) << a.duration_s << "s";
    o.attempts += s.str();
  }
  if (!r.chain.detection) return o;
  o.detected = true;
  o.method = r.chain.detection->method;
  o.score = r.chain.detection->score;
  o.appearance = r.chain.detection->appearance;
  o.evidence = Evidence(*r.chain.detection);
  o.add_m = std::numeric_limits<double>::infinity();
  for (const TrueItem& t : truth) {
    if (t.name != item) continue;
    const PoseErrorResult e = PoseError(model.object->icp_cloud(), model.spec.symmetry,
                                        r.chain.detection->X_BaseItem, t.X_BaseItem);
    if (e.add_m < o.add_m) {
      o.add_m = e.add_m;
      o.rotation_rad = e.rotation_rad;
    }
  }
  o.correct = o.add_m < 0.1 * model.object->diameter_m();
  return o;
}

struct Tally {
  int runs = 0;
  int correct = 0;
  int wrong = 0;  // Accepted but wrong pose.
  double total_s = 0.0;
  double max_s = 0.0;
  std::vector<std::pair<double, bool>> accepted;  // (score, correct) of each accepted pose
  void Add(const Outcome& o) {
    ++runs;
    correct += o.correct ? 1 : 0;
    wrong += o.detected && !o.correct ? 1 : 0;
    total_s += o.total_s;
    max_s = std::max(max_s, o.total_s);
    if (o.detected) accepted.emplace_back(o.score, o.correct);
  }
  // Of the accepted poses, the fraction that are right.
  std::string Precision() const {
    std::ostringstream s;
    s << correct << "/" << accepted.size();
    return s.str();
  }
  // Area under the ROC curve of the accepted poses' scores: the chance that a right pose
  // scores above a wrong one (ties count half); "-" without both kinds.
  std::string RocArea() const {
    double above = 0.0;
    int pairs = 0;
    for (const auto& [right_score, right] : accepted) {
      if (!right) continue;
      for (const auto& [wrong_score, also_right] : accepted) {
        if (also_right) continue;
        above += right_score > wrong_score ? 1.0 : right_score == wrong_score ? 0.5 : 0.0;
        ++pairs;
      }
    }
    if (pairs == 0) return "-";
    std::ostringstream s;
    s << std::fixed << std::setprecision(2) << above / pairs;
    return s.str();
  }
  std::string Rate() const {
    std::ostringstream s;
    s << correct << "/" << runs;
    if (runs > 0)
      s << " (" << std::fixed << std::setprecision(0) << 100.0 * correct / runs << " %)";
    return s.str();
  }
  std::string MeanTime() const {
    std::ostringstream s;
    s << std::fixed << std::setprecision(3) << (runs > 0 ? total_s / runs : 0.0);
    return s.str();
  }
};

std::string Cell(const Outcome& o) {
  if (!o.applicable) return "n/a";
  std::ostringstream s;
  s << std::fixed << std::setprecision(3);
  if (!o.detected) {
    s << "none";
  } else {
    s << (o.correct ? "ok" : "WRONG") << " " << std::setprecision(1) << o.add_m * 1000 << "mm";
  }
  s << std::setprecision(2) << " " << o.total_s << "s";
  return s.str();
}

// A new folder under the system's temporary directory, removed with its contents.
class TemporaryFolder {
 public:
  TemporaryFolder() {
    std::string pattern =
        (std::filesystem::temp_directory_path() / "detector_eval_models_XXXXXX").string();
    if (mkdtemp(pattern.data()) == nullptr) {
      throw std::runtime_error("cannot create a temporary model cache folder: " + pattern);
    }
    path_ = pattern;
  }
  ~TemporaryFolder() {
    std::error_code ignored;
    std::filesystem::remove_all(path_, ignored);
  }
  TemporaryFolder(const TemporaryFolder&) = delete;
  TemporaryFolder& operator=(const TemporaryFolder&) = delete;
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

// The figures gathered over every target.
struct Evaluation {
  Tally chain_total;
  std::map<std::string, Tally> per_method_total;
  std::map<std::string, Tally> per_item;
  std::map<std::string, std::map<std::string, Tally>> per_item_method;
  std::ostringstream rows;  // one markdown row per target
  double scan_s = 0.0;
  int scans = 0;
  std::unique_ptr<CandidateLog> candidates;  // --candidates_csv
};

// The detector's models, cached in args.cache_dir or in a fresh folder kept by `fresh_cache`.
std::shared_ptr<const detector::ModelLibrary> MakeLibrary(
    const Args& args, const std::string& data_dir, std::optional<TemporaryFolder>* fresh_cache) {
  detector::ModelLibraryOptions library_options;
  if (args.cache_dir.empty()) {
    fresh_cache->emplace();
    library_options.cache_dir = (*fresh_cache)->path();
  } else {
    library_options.cache_dir = args.cache_dir;
  }
  library_options.catalogue_path = data_dir + "/apc2016/items/item_data.csv";
  return std::make_shared<const detector::ModelLibrary>(
      detector::ModelManifest::LoadFile(data_dir + "/detector/models.json", data_dir),
      library_options);
}

// The bin seen from the cell's middle view and, with three views, from either side, merged.
BinScan ScanBin(SimulatedBinScanner& scanner, const std::string& bin, const Args& args) {
  BinScanOptions options;
  options.sensor = args.sensor;
  const std::vector<world::BinScanView> views(args.bin_views.begin(),
                                              args.bin_views.begin() + args.views);
  return ScanViews(scanner, bin, options, views);
}

// Each method alone on the same scan (not applicable where the item has no model for it).
std::map<std::string, Outcome> JudgeEachMethod(
    const std::shared_ptr<const detector::ModelLibrary>& library, const BinScan& scan,
    const std::string& item, const detector::LoadedModel& model, const Args& args,
    Evaluation* evaluation) {
  std::map<std::string, Outcome> by_method;
  for (detector::Method m :
       {detector::Method::kPpf, detector::Method::kSift, detector::Method::kRangeTemplates}) {
    Outcome o;
    const bool has_model = m == detector::Method::kPpf ||
                           (m == detector::Method::kSift && model.sift) ||
                           (m == detector::Method::kRangeTemplates && model.templates);
    if (has_model) {
      o = Judge(DetectInBin(library, scan, item, m, args.detection), model, scan.items, item);
      evaluation->per_method_total[detector::ToString(m)].Add(o);
      evaluation->per_item_method[item][detector::ToString(m)].Add(o);
    } else {
      o.applicable = false;
    }
    by_method[detector::ToString(m)] = o;
  }
  return by_method;
}

// What the detector makes of the item's true pose: its score and the scene's agreement.
void PrintTruePoses(const std::shared_ptr<const detector::ModelLibrary>& library,
                    const BinScan& scan, const std::string& item, const Args& args) {
  for (const TrueItem& t : scan.items) {
    if (t.name != item) continue;
    const detector::Detection truth =
        ScoreTruePose(library, scan, item, t.X_BaseItem, args.detection);
    const detector::SceneAgreement agreement =
        TruePoseAgreement(library, scan, item, t.X_BaseItem, args.detection);
    std::cout << "; true pose at " << t.X_BaseItem.translation().transpose() << " x "
              << t.X_BaseItem.linear().col(0).transpose() << " score " << truth.score << " fitness "
              << truth.fitness << " print " << truth.appearance << " (" << Evidence(truth)
              << ") ppf support " << agreement.support << " conflicts "
              << agreement.conflict_fraction << " visible " << agreement.visible_points
              << " occluded " << agreement.occluded_points;
  }
}

// The poses the accepting method found, each judged against the truth.
void PrintCandidates(const BinDetectionResult& r, const detector::LoadedModel& model,
                     const std::vector<TrueItem>& truth, const std::string& item) {
  for (std::size_t k = 0; k < r.poses.size(); ++k) {
    BinDetectionResult one;
    one.chain.detection = r.poses[k];
    const Outcome o = Judge(one, model, truth, item);
    std::cout << "\n    candidate " << k << ": " << (o.correct ? "ok" : "WRONG") << " "
              << std::setprecision(1) << std::fixed << o.add_m * 1000 << "mm score "
              << std::setprecision(3) << o.score << " print " << o.appearance << " (" << o.evidence
              << ")" << std::defaultfloat;
    // Where it lies in the frame of the nearest true instance: a slide along a box's side
    // shows as one large coordinate.
    double nearest_m = std::numeric_limits<double>::infinity();
    Eigen::Vector3d p_TrueFound = Eigen::Vector3d::Zero();
    for (const TrueItem& t : truth) {
      if (t.name != item) continue;
      const Eigen::Vector3d p = t.X_BaseItem.inverse() * r.poses[k].X_BaseItem.translation();
      if (p.norm() < nearest_m) {
        nearest_m = p.norm();
        p_TrueFound = p;
      }
    }
    std::cout << " at " << p_TrueFound.transpose() << " in the true item's frame";
  }
}

// One target of a layout: scanned, detected by the chain (and each method alone), judged
// against the truth, printed and tallied.
void EvaluateTarget(const std::shared_ptr<const detector::ModelLibrary>& library,
                    SimulatedBinScanner& scanner, const std::string& layout,
                    const apc::WorkOrderEntry& entry, const Args& args, Evaluation* evaluation) {
  const BinScan scan = ScanBin(scanner, entry.bin, args);
  evaluation->scan_s += scan.render_s + scan.process_s;
  ++evaluation->scans;
  const auto model_start = std::chrono::steady_clock::now();
  const auto model = library->Get(entry.item);  // Built or loaded outside the timed call.
  const double model_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - model_start).count();
  const BinDetectionResult chain_result =
      DetectInBin(library, scan, entry.item, std::nullopt, args.detection);
  const Outcome chain = Judge(chain_result, *model, scan.items, entry.item);
  evaluation->chain_total.Add(chain);
  evaluation->per_item[entry.item].Add(chain);
  std::map<std::string, Outcome> by_method;
  if (args.per_method) {
    by_method = JudgeEachMethod(library, scan, entry.item, *model, args, evaluation);
  }

  evaluation->rows << "| " << layout << " | " << entry.bin.substr(4) << " | " << entry.item << " | "
                   << scan.items.size() << " | " << chain_result.points_in_region << " | "
                   << Cell(chain) << (chain.detected ? " (" + chain.method + ")" : "") << " | "
                   << (args.per_method ? Cell(by_method["ppf"]) : "-") << " | "
                   << (args.per_method ? Cell(by_method["sift"]) : "-") << " | "
                   << (args.per_method ? Cell(by_method["range_templates"]) : "-") << " |\n";
  std::cout << "layout " << layout << " " << entry.bin << " " << entry.item << ": " << Cell(chain)
            << (chain.detected ? " by " + chain.method : "") << " score " << std::setprecision(3)
            << chain.score << " print " << chain.appearance
            << (chain.detected ? " (" + chain.evidence + ")" : "") << ", rot "
            << chain.rotation_rad * 180.0 / M_PI << " deg, " << scan.items.size() << " items, "
            << chain_result.points_in_region << " region points, intrinsics "
            << (chain_result.intrinsics_fitted ? "fitted" : "NOT fitted") << ", scan "
            << scan.render_s << " + " << scan.process_s << " s, model " << model_s << " s";
  std::cout << ", tried: " << chain.attempts;
  if (!chain.error.empty()) std::cout << ", error: " << chain.error;
  PrintTruePoses(library, scan, entry.item, args);
  if (args.detection.max_results > 1) PrintCandidates(chain_result, *model, scan.items, entry.item);
  for (std::size_t k = 0; k < chain_result.poses.size(); ++k) {
    BinDetectionResult one;
    one.chain.detection = chain_result.poses[k];
    evaluation->candidates->Add(
        std::string(args.sensor == BinSensor::kRgbd ? "rgbd" : "structured_light") + "_seed" +
            std::to_string(args.seed),
        "layout" + layout + ":" + entry.bin, static_cast<int>(k),
        Judge(one, *model, scan.items, entry.item).correct, chain_result.poses[k]);
  }
  for (const auto& [name, o] : by_method) std::cout << "; " << name << " " << Cell(o);
  std::cout << std::endl;
}

// The tables: per method, per item, and the scans' time.
std::string Summary(const Evaluation& evaluation, const Args& args) {
  const Tally& chain_total = evaluation.chain_total;
  std::ostringstream summary;
  summary << "\nChain (configured order): " << chain_total.Rate() << " correct, "
          << chain_total.wrong << " wrong poses accepted (precision " << chain_total.Precision()
          << ", ROC area of the accepted poses' scores " << chain_total.RocArea() << "), mean "
          << chain_total.MeanTime() << " s, max " << std::setprecision(3) << chain_total.max_s
          << " s per call\n";
  summary << "\n| method | correct | wrong accepted | mean s per call | max s "
             "|\n|---|---|---|---|---|\n";
  summary << "| chain | " << chain_total.Rate() << " | " << chain_total.wrong << " | "
          << chain_total.MeanTime() << " | " << chain_total.max_s << " |\n";
  for (const auto& [name, t] : evaluation.per_method_total) {
    summary << "| " << name << " | " << t.Rate() << " | " << t.wrong << " | " << t.MeanTime()
            << " | " << t.max_s << " |\n";
  }
  summary << "\n| item | chain | ppf | sift | range_templates |\n|---|---|---|---|---|\n";
  for (const auto& [item, t] : evaluation.per_item) {
    summary << "| " << item << " | " << t.Rate();
    const auto methods = evaluation.per_item_method.find(item);
    for (const char* m : {"ppf", "sift", "range_templates"}) {
      const bool known = methods != evaluation.per_item_method.end() && methods->second.count(m);
      summary << " | " << (known ? methods->second.at(m).Rate() : "n/a");
    }
    summary << " |\n";
  }
  summary << "\nScans: " << evaluation.scans << " (" << args.views << " view"
          << (args.views > 1 ? "s" : "") << " each), mean " << std::setprecision(3)
          << (evaluation.scans > 0 ? evaluation.scan_s / evaluation.scans : 0.0)
          << " s to render and process one.\n";
  return summary.str();
}

int Run(const Args& args) {
  const std::string data_dir = apc::DefaultDataDir();
  SimulatedBinScanner scanner(data_dir);
  std::optional<TemporaryFolder> fresh_cache;
  const auto library = MakeLibrary(args, data_dir, &fresh_cache);
  Evaluation evaluation;
  evaluation.candidates = std::make_unique<CandidateLog>(args.candidates_csv);
  evaluation.rows << "| layout | bin | item | items in bin | region points | chain | ppf | sift | "
                     "range_templates |\n|---|---|---|---|---|---|---|---|---|\n";
  for (const std::string& layout : args.layouts) {
    const bool has_target = std::any_of(args.only.begin(), args.only.end(), [&](const auto& t) {
      return t.rfind(layout + ":", 0) == 0;
    });
    if (!args.only.empty() && !has_target) continue;  // Not laid out: --only leaves no bin.
    const apc::Task task =
        scanner.ReadTask(data_dir + "/apc2016/tasks/pick_layout_" + layout + ".json");
    scanner.LoadTask(task, args.seed, args.layout_mode);
    for (const apc::WorkOrderEntry& entry : task.work_order) {
      if (!args.bins.empty() &&
          std::find(args.bins.begin(), args.bins.end(), entry.bin) == args.bins.end()) {
        continue;
      }
      if (!args.only.empty() && std::find(args.only.begin(), args.only.end(),
                                          layout + ":" + entry.bin) == args.only.end()) {
        continue;
      }
      EvaluateTarget(library, scanner, layout, entry, args, &evaluation);
    }
  }
  const std::string summary = Summary(evaluation, args);
  std::cout << summary << "\n" << evaluation.rows.str();
  if (!args.markdown.empty()) {
    std::ofstream out(args.markdown);
    out << summary << "\n" << evaluation.rows.str();
    if (!out) throw std::runtime_error("cannot write '" + args.markdown + "'");
  }
  const Tally& chain_total = evaluation.chain_total;
  const bool goal = chain_total.runs > 0 && chain_total.correct >= 0.9 * chain_total.runs;
  return goal ? 0 : 1;
}

}  // namespace
}  // namespace picking::detector_eval

int main(int argc, char** argv) {
  try {
    return picking::detector_eval::Run(picking::detector_eval::Parse(argc, argv));
  } catch (const std::exception& e) {
    std::cerr << "detector_eval: " << e.what() << "\n";
    return 2;
  }
}
