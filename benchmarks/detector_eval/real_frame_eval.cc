// The detector on real RGB-D frames: YCB-Video video 0000, frames 1-10 (Asus Xtion, 640 x 480,
// tests/data/real/ycb_video_0000), three objects with ground-truth poses. Each object is looked
// for in each frame through the detector's own workflow (PrepareScene, DetectItem) on the
// organised depth cloud in the camera frame, and held against the truth:
//
// - correct: the silhouette of the model drawn at the estimated pose overlaps the one at the
//   true pose by an IoU of at least 0.5; the stricter ADD (ADD-S for the two boxes) under a
//   tenth of the model's diameter, as PoseCNN judges YCB-Video, is counted beside it;
// - the region: the box (camera frame) around the three objects at their true poses, grown by
//   10 cm on every side, as a shelf bin's region holds its items (--region=none: the whole
//   frame, table, floor and walls included);
// - recall: targets whose accepted pose is correct; precision: accepted poses that are;
// - the score's ROC: every candidate pose above a minimal score (up to five per target),
//   correct or not, ranked by score (area under the curve by the rank-sum statistic);
// - each method alone (PPF, range templates) with what it says when it finds nothing.
//
// Usage: real_frame_eval [--data=DIR] [--frames=1,2,...] [--region=objects|none]
//                        [--markdown=FILE] [--cache_dir=DIR] [--candidates_csv=FILE]
// Exit status: 0 after a complete evaluation (the figures are reported, not asserted), 1 on
// unreadable data or a failed detection call, 2 on bad arguments.

#include <pthread.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "benchmarks/detector_eval/pose_check.h"
#include "libs/camera/pinhole_camera.h"
#include "services/detector/core/detect_in_region.h"
#include "services/detector/core/model_library.h"
#include "services/detector/core/verify.h"

namespace picking::detector_eval {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

struct Args {
  std::string data_dir = std::string(PICKING_SOURCE_DIR) + "/tests/data/real/ycb_video_0000";
  std::vector<int> frames = {1, 2, 3, 4, 5, 6, 7, 8, 9, 10};
  bool region = true;
  std::string markdown;
  std::string cache_dir;
  std::string candidates_csv;
};

Args ParseArgs(int argc, char** argv) {
  Args args;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    auto value = [&](const std::string& key) -> std::optional<std::string> {
      if (arg.rfind(key + "=", 0) == 0) return arg.substr(key.size() + 1);
      return std::nullopt;
    };
    if (auto v = value("--data")) {
      args.data_dir = *v;
    } else if (auto v = value("--frames")) {
      args.frames.clear();
      std::stringstream list(*v);
      for (std::string item; std::getline(list, item, ',');) {
        const int frame = std::stoi(item);
        if (frame < 1 || frame > 999999) throw std::invalid_argument("--frames: bad frame number");
        args.frames.push_back(frame);
      }
      if (args.frames.empty()) throw std::invalid_argument("--frames: empty list");
    } else if (auto v = value("--region")) {
      if (*v != "objects" && *v != "none") throw std::invalid_argument("--region: objects or none");
      args.region = *v == "objects";
    } else if (auto v = value("--markdown")) {
      args.markdown = *v;
    } else if (auto v = value("--cache_dir")) {
      args.cache_dir = *v;
    } else if (auto v = value("--candidates_csv")) {
      args.candidates_csv = *v;
    } else {
      throw std::invalid_argument("unknown argument '" + arg + "'");
    }
  }
  return args;
}

struct TrueObject {
  std::string name;
  int class_index = 0;
  Eigen::Isometry3d X_CameraObject = Eigen::Isometry3d::Identity();
};

struct Frame {
  int index = 0;
  cv::Mat depth;  // CV_16U
  double depth_factor = 10000.0;
  camera::PinholeCamera camera;  // K from the frame's metadata
  std::vector<TrueObject> objects;
};

Frame ReadFrame(const std::string& data_dir, int index) {
  std::ostringstream stem;
  stem << data_dir << "/frames/" << std::setw(6) << std::setfill('0') << index;
  Frame frame{index, cv::Mat(), 10000.0, camera::PinholeCamera(1, 1, 1.0, 1.0, 0.0, 0.0), {}};
  frame.depth = cv::imread(stem.str() + "-depth.png", cv::IMREAD_ANYDEPTH);
  if (frame.depth.empty() || frame.depth.type() != CV_16U) {
    throw std::runtime_error("cannot read a 16-bit depth image '" + stem.str() + "-depth.png'");
  }
  std::ifstream meta_file(stem.str() + "-meta.json");
  if (!meta_file) throw std::runtime_error("cannot read '" + stem.str() + "-meta.json'");
  const nlohmann::json meta = nlohmann::json::parse(meta_file);
  frame.depth_factor = meta.at("depth_factor").get<double>();
  const auto& K = meta.at("K");
  frame.camera =
      camera::PinholeCamera(frame.depth.cols, frame.depth.rows, K[0][0], K[1][1], K[0][2], K[1][2]);
  for (const auto& o : meta.at("objects")) {
    TrueObject object;
    object.name = o.at("name").get<std::string>();
    object.class_index = o.at("class_index").get<int>();
    for (int r = 0; r < 4; ++r) {
      for (int c = 0; c < 4; ++c) object.X_CameraObject.matrix()(r, c) = o["X_camera_object"][r][c];
    }
    frame.objects.push_back(object);
  }
  return frame;
}

// The depth image as an organised cloud in the camera frame (NaN where the sensor saw nothing).
geometry::PointCloud DepthToCloud(const Frame& frame) {
  geometry::PointCloud cloud;
  cloud.width = static_cast<std::uint32_t>(frame.depth.cols);
  cloud.height = static_cast<std::uint32_t>(frame.depth.rows);
  cloud.points.reserve(static_cast<std::size_t>(cloud.width) * cloud.height);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int v = 0; v < frame.depth.rows; ++v) {
    for (int u = 0; u < frame.depth.cols; ++u) {
      const std::uint16_t raw = frame.depth.at<std::uint16_t>(v, u);
      if (raw == 0) {
        cloud.points.emplace_back(nan, nan, nan);
        continue;
      }
      const double z = raw / frame.depth_factor;
      cloud.points.push_back((frame.camera.Unproject(Eigen::Vector2d(u, v)) * z).cast<float>());
    }
  }
  return cloud;
}

// The model drawn at a pose: each point a disc as wide as the model's point spacing seen from
// there, so the silhouette closes.
cv::Mat Silhouette(const geometry::PointCloud& model, const Eigen::Isometry3d& X_CameraObject,
                   const camera::PinholeCamera& camera, double spacing_m) {
  cv::Mat mask = cv::Mat::zeros(camera.height(), camera.width(), CV_8U);
  for (const Eigen::Vector3f& p : model.points) {
    const Eigen::Vector3d p_Camera = X_CameraObject * p.cast<double>();
    if (!(p_Camera.z() > 0.05)) continue;
    const std::optional<Eigen::Vector2d> projected = camera.Project(p_Camera);
    if (!projected) continue;
    const Eigen::Vector2d& uv = *projected;
    const int radius =
        std::max(1, static_cast<int>(std::ceil(camera.fx() * spacing_m / p_Camera.z())));
    cv::circle(
        mask,
        cv::Point(static_cast<int>(std::lround(uv.x())), static_cast<int>(std::lround(uv.y()))),
        radius, cv::Scalar(255), cv::FILLED);
  }
  return mask;
}

double Iou(const cv::Mat& a, const cv::Mat& b) {
  cv::Mat both, either;
  cv::bitwise_and(a, b, both);
  cv::bitwise_or(a, b, either);
  const int u = cv::countNonZero(either);
  return u == 0 ? 0.0 : static_cast<double>(cv::countNonZero(both)) / u;
}

// A candidate pose held against the truth.
struct Judged {
  bool correct = false;  // silhouette IoU >= 0.5
  bool add_correct = false;
  double add_m = 0.0;
  double iou = 0.0;
  double score = 0.0;
};

class Judge {
 public:
  Judge(const detector::LoadedModel& model, const camera::PinholeCamera& camera)
      : model_(model), camera_(camera) {
    const auto& points = model.object->icp_cloud().points;
    Eigen::AlignedBox3f box;
    for (const auto& p : points) box.extend(p);
    diameter_m_ = box.diagonal().norm();
    spacing_m_ = 0.004;
  }
  Judged operator()(const detector::Detection& d, const Eigen::Isometry3d& X_true) const {
    Judged j;
    j.score = d.score;
    j.add_m =
        PoseError(model_.object->icp_cloud(), model_.spec.symmetry, d.X_BaseItem, X_true).add_m;
    j.add_correct = j.add_m < 0.1 * diameter_m_;
    j.iou = Iou(Silhouette(model_.object->icp_cloud(), d.X_BaseItem, camera_, spacing_m_),
                Silhouette(model_.object->icp_cloud(), X_true, camera_, spacing_m_));
    j.correct = j.iou >= 0.5;
    return j;
  }

 private:
  const detector::LoadedModel& model_;
  const camera::PinholeCamera& camera_;
  double diameter_m_ = 0.0;
  double spacing_m_ = 0.0;
};

// Area under the ROC curve of scores for correct (positive) against wrong poses: the chance
// that a correct pose outscores a wrong one (ties count half). NaN without both kinds.
double RocArea(const std::vector<Judged>& candidates) {
  std::vector<double> right, wrong;
  for (const Judged& j : candidates) (j.correct ? right : wrong).push_back(j.score);
  if (right.empty() || wrong.empty()) return std::numeric_limits<double>::quiet_NaN();
  double wins = 0.0;
  for (double r : right) {
    for (double w : wrong) wins += r > w ? 1.0 : (r == w ? 0.5 : 0.0);
  }
  return wins / (static_cast<double>(right.size()) * wrong.size());
}

// Per object (and in total): what was accepted, how it held, and every candidate for the ROC.
struct Tally {
  int targets = 0, accepted = 0, correct_accepted = 0, add_correct_accepted = 0;
  double total_s = 0.0, max_s = 0.0;
  std::vector<Judged> candidates;
  std::map<std::string, int> method_found;           // a pose from the method alone
  std::map<std::string, int> method_correct;         // ... that was correct
  std::map<std::string, std::string> method_silent;  // why the method last found nothing
};

std::string Percent(int n, int d) {
  std::ostringstream s;
  s << n << "/" << d;
  if (d > 0) s << " (" << std::lround(100.0 * n / d) << " %)";
  return s.str();
}

// The chain's answer for one target (accepted pose, time) and its candidates down to a minimal
// score for the ROC.
void EvaluateTarget(const std::shared_ptr<const detector::ModelLibrary>& library,
                    const detector::PreparedScene& scene, const TrueObject& truth, Tally* tally,
                    std::ostream& rows, int frame, CandidateLog* log) {
  const auto model = library->Get(truth.name);
  const Judge judge(*model, *scene.camera);
  detector::ItemQuery query;
  query.item = truth.name;
  // The budget runs on this thread's CPU time, as the detector service judges it.
  query.budget_clock = detector::BudgetClock::ThreadCpu(pthread_self());
  // One scene context per target, made inside the timed call as the service makes it; the
  // evidence and the candidates for the ROC reuse it.
  const auto started = Clock::now();
  const auto budget_start = query.budget_clock.Now();
  const auto context = detector::MakeSceneContext(scene);
  const detector::ItemDetections found =
      detector::DetectItem(library, scene, context, query, budget_start);
  const double seconds = std::chrono::duration<double>(Clock::now() - started).count();
  tally->total_s += seconds;
  tally->max_s = std::max(tally->max_s, seconds);
  ++tally->targets;
  rows << "| " << frame << " | " << truth.name << " | ";
  if (found.chain.detection) {
    const Judged j = judge(*found.chain.detection, truth.X_CameraObject);
    // The evidence under the score: the model's points facing the sensor, hidden behind other
    // surfaces, supported by the scan, and in space the sensor saw through.
    const detector::VerifyResult v = detector::Verify(
        *context->Verification(), model->object->icp_cloud(), found.chain.detection->X_BaseItem);
    // The same measure at the true pose: a search that missed it, or a score that prefers
    // the wrong one.
    const detector::VerifyResult at_truth = detector::Verify(
        *context->Verification(), model->object->icp_cloud(), truth.X_CameraObject);
    ++tally->accepted;
    tally->correct_accepted += j.correct;
    tally->add_correct_accepted += j.add_correct;
    rows << (j.correct ? "ok" : "WRONG") << " " << std::fixed << std::setprecision(1)
         << 1e3 * j.add_m << " mm, IoU " << std::setprecision(2) << j.iou << ", score " << j.score
         << " (" << found.chain.detection->method << "; visible " << v.num_visible << ", occluded "
         << v.num_occluded << ", supported " << v.num_supported << ", conflicts " << v.num_conflicts
         << " of " << v.num_model_points << "; true pose: score " << at_truth.score << ", visible "
         << at_truth.num_visible << ", occluded " << at_truth.num_occluded << ", supported "
         << at_truth.num_supported << ", conflicts " << at_truth.num_conflicts << ")";
  } else {
    rows << "none";
  }
  rows << " | " << std::setprecision(2) << seconds << " s |";
  // Every candidate down to a minimal score, for the ROC.
  query.min_score = 0.01;
  query.max_results = 5;
  const detector::ItemDetections all =
      detector::DetectItem(library, scene, context, query, query.budget_clock.Now());
  int right = 0;
  for (const detector::Detection& d : all.poses) {
    tally->candidates.push_back(judge(d, truth.X_CameraObject));
    right += tally->candidates.back().correct;
    log->Add("real", "frame" + std::to_string(frame), static_cast<int>(&d - all.poses.data()),
             tally->candidates.back().correct, d);
  }
  rows << " " << right << " of " << all.poses.size() << " |";
}

// Each method alone on the same scene: whether it gives a pose, and what it says if not.
void EvaluateMethods(const std::shared_ptr<const detector::ModelLibrary>& library,
                     const detector::PreparedScene& scene, const TrueObject& truth, Tally* tally,
                     std::ostream& rows) {
  const auto model = library->Get(truth.name);
  const Judge judge(*model, *scene.camera);
  for (const detector::Method m : {detector::Method::kPpf, detector::Method::kRangeTemplates}) {
    const std::string name = detector::ToString(m);
    detector::ItemQuery query;
    query.item = truth.name;
    query.method = m;
    query.budget_clock = detector::BudgetClock::ThreadCpu(pthread_self());
    const detector::ItemDetections found = detector::DetectItem(
        library, scene, detector::MakeSceneContext(scene), query, query.budget_clock.Now());
    if (found.chain.detection) {
      const bool correct = judge(*found.chain.detection, truth.X_CameraObject).correct;
      ++tally->method_found[name];
      tally->method_correct[name] += correct;
      rows << " " << (correct ? "ok" : "WRONG") << " |";
    } else {
      std::string why = "no pose";
      for (const auto& attempt : found.chain.attempts) {
        if (!attempt.reason.empty()) why = attempt.reason;
      }
      tally->method_silent[name] = why;
      rows << " none |";
    }
  }
  rows << "\n";
}

std::string Summary(const std::map<std::string, Tally>& per_object, const Tally& total) {
  std::ostringstream s;
  s << "| object | recall (IoU >= 0.5) | precision (correct / accepted) | recall (ADD < 10 % "
       "diameter) | ROC area | mean s | max s | ppf alone | range templates alone |\n"
       "|---|---|---|---|---|---|---|---|---|\n";
  auto line = [&](const std::string& name, const Tally& t) {
    s << "| " << name << " | " << Percent(t.correct_accepted, t.targets) << " | "
      << Percent(t.correct_accepted, t.accepted) << " | "
      << Percent(t.add_correct_accepted, t.targets) << " | " << std::fixed << std::setprecision(2)
      << RocArea(t.candidates) << " | " << (t.targets ? t.total_s / t.targets : 0.0) << " | "
      << t.max_s << " |";
    for (const char* m : {"ppf", "range_templates"}) {
      const auto found = t.method_found.find(m);
      const int n = found == t.method_found.end() ? 0 : found->second;
      const auto correct = t.method_correct.find(m);
      s << " " << (correct == t.method_correct.end() ? 0 : correct->second) << " correct of " << n
        << " found |";
    }
    s << "\n";
  };
  for (const auto& [name, t] : per_object) line(name, t);
  line("all", total);
  for (const auto& [name, t] : per_object) {
    for (const auto& [method, why] : t.method_silent) {
      s << "\n" << name << ", " << method << " alone, last time it found nothing: " << why;
    }
  }
  s << "\n";
  return s.str();
}

// The box around the frame's objects at their true poses, grown by 10 cm: the region a bin
// would give.
detector::OrientedBox ObjectsRegion(const detector::ModelLibrary& library, const Frame& frame) {
  Eigen::AlignedBox3d box;
  for (const TrueObject& object : frame.objects) {
    for (const Eigen::Vector3f& p : library.Get(object.name)->object->icp_cloud().points) {
      box.extend(object.X_CameraObject * p.cast<double>());
    }
  }
  detector::OrientedBox region;
  region.size_m = box.sizes() + Eigen::Vector3d::Constant(0.2);
  region.X_BaseBox = Eigen::Translation3d(box.center()) * Eigen::Isometry3d::Identity();
  return region;
}

int Run(const Args& args) {
  detector::ModelLibraryOptions library_options;
  library_options.cache_dir = args.cache_dir.empty()
                                  ? (fs::temp_directory_path() / "picking-real-frame-eval").string()
                                  : args.cache_dir;
  const auto library = std::make_shared<const detector::ModelLibrary>(
      detector::ModelManifest::LoadFile(args.data_dir + "/models.json", args.data_dir),
      library_options);
  std::map<std::string, Tally> per_object;
  Tally total;
  std::ostringstream rows;
  CandidateLog log(args.candidates_csv);
  rows << "| frame | object | chain | s | candidates correct | ppf alone | range templates alone "
          "|\n|---|---|---|---|---|---|---|\n";
  for (const int index : args.frames) {
    const Frame frame = ReadFrame(args.data_dir, index);
    detector::SceneOptions options;
    options.fallback_camera = frame.camera;
    if (args.region) options.region = ObjectsRegion(*library, frame);
    const detector::PreparedScene scene =
        detector::PrepareScene(DepthToCloud(frame), Eigen::Isometry3d::Identity(), options);
    for (const TrueObject& truth : frame.objects) {
      Tally& tally = per_object[truth.name];
      EvaluateTarget(library, scene, truth, &tally, rows, index, &log);
      EvaluateMethods(library, scene, truth, &tally, rows);
      std::cout << "frame " << index << " " << truth.name << " done" << std::endl;
    }
  }
  for (const auto& [name, t] : per_object) {
    total.targets += t.targets;
    total.accepted += t.accepted;
    total.correct_accepted += t.correct_accepted;
    total.add_correct_accepted += t.add_correct_accepted;
    total.total_s += t.total_s;
    total.max_s = std::max(total.max_s, t.max_s);
    total.candidates.insert(total.candidates.end(), t.candidates.begin(), t.candidates.end());
    for (const auto& [m, n] : t.method_found) total.method_found[m] += n;
    for (const auto& [m, n] : t.method_correct) total.method_correct[m] += n;
  }
  const std::string summary = Summary(per_object, total);
  std::cout << "\n" << summary << "\n" << rows.str();
  if (!args.markdown.empty()) {
    std::ofstream out(args.markdown);
    out << summary << "\n" << rows.str();
    if (!out) throw std::runtime_error("cannot write '" + args.markdown + "'");
  }
  return 0;
}

}  // namespace
}  // namespace picking::detector_eval

int main(int argc, char** argv) {
  picking::detector_eval::Args args;
  try {
    args = picking::detector_eval::ParseArgs(argc, argv);
  } catch (const std::exception& e) {
    std::cerr << "real_frame_eval: " << e.what() << "\n";
    return 2;
  }
  try {
    return picking::detector_eval::Run(args);
  } catch (const std::exception& e) {
    std::cerr << "real_frame_eval: " << e.what() << "\n";
    return 1;
  }
}
