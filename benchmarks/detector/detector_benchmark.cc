// Detector benchmarks: PPF training / matching against OpenCV's PPF3DDetector on its own
// sample data, recovery of the PCL milk carton pose from seeded random starts (ours, OpenCV,
// PCL's PPFRegistration under a wall-clock cap) and ICP refinement of one pose.
//
// The accuracy reports run first and print a table; Google Benchmark timings follow.
//   bench_detector [--milk_starts=100] [--opencv_starts=100] [--pcl_starts=3] [--pcl_cap_s=180]
//                  [--milk_sampling_permille=50] [--reference_step=5] [--absent] [--skip_pcl]
//                  [--skip_rs1] [--skip_reports] [--benchmark_filter=...]

#include <benchmark/benchmark.h>
#include <pcl/features/ppf.h>
#include <pcl/io/pcd_io.h>
#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/point_types.h>
#include <pcl/registration/ppf_registration.h>
#include <sys/wait.h>
#include <unistd.h>

#include <opencv2/core.hpp>
#include <opencv2/surface_matching.hpp>
#include <opencv2/surface_matching/ppf_helpers.hpp>

#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <iostream>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "services/detector/core/icp.h"
#include "services/detector/core/kdtree.h"
#include "services/detector/core/model.h"
#include "services/detector/core/ppf.h"
#include "services/detector/core/ppf_detector.h"

namespace pd = picking::detector;
using picking::geometry::PointCloud;

namespace {

constexpr double kDeg = M_PI / 180.0;
const std::string kOpenCvData = "/usr/share/doc/opencv-doc/examples/surface_matching/data/";

double Now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

std::string DataPath(const std::string& name) {
  return std::string(PICKING_TEST_DATA_DIR) + "/pointclouds/" + name;
}

PointCloud LoadPcd(const std::string& path) {
  pcl::PointCloud<pcl::PointXYZ> in;
  if (pcl::io::loadPCDFile(path, in) != 0) throw std::runtime_error("cannot read " + path);
  PointCloud out;
  for (const auto& p : in) out.points.emplace_back(p.x, p.y, p.z);
  out.width = in.width;
  out.height = in.height;
  return out;
}

// OpenCV's sample PLY files (millimetres, with normals) as a cloud in metres.
PointCloud FromOpenCvMat(const cv::Mat& m, float scale) {
  PointCloud out;
  for (int i = 0; i < m.rows; ++i) {
    const float* r = m.ptr<float>(i);
    Eigen::Vector3f n(r[3], r[4], r[5]);
    if (!(n.norm() > 0.0f)) continue;
    out.points.emplace_back(scale * r[0], scale * r[1], scale * r[2]);
    out.normals.push_back(n.normalized());
  }
  out.width = static_cast<std::uint32_t>(out.size());
  return out;
}

cv::Mat ToOpenCvMat(const PointCloud& c) {
  cv::Mat m(static_cast<int>(c.size()), 6, CV_32F);
  for (int i = 0; i < m.rows; ++i) {
    float* r = m.ptr<float>(i);
    for (int k = 0; k < 3; ++k) {
      r[k] = c.points[i][k];
      r[3 + k] = c.normals[i][k];
    }
  }
  return m;
}

Eigen::Isometry3d FromMatx(const cv::Matx44d& m, double scale) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) X.linear()(r, c) = m(r, c);
    X.translation()[r] = scale * m(r, 3);
  }
  X.linear() = Eigen::Quaterniond(X.linear()).normalized().toRotationMatrix();
  return X;
}

PointCloud Transformed(const PointCloud& cloud, const Eigen::Isometry3d& X) {
  PointCloud out = cloud;
  const Eigen::Isometry3f Xf = X.cast<float>();
  for (auto& p : out.points) p = Xf * p;
  for (auto& n : out.normals) n = Xf.linear() * n;
  return out;
}

Eigen::Isometry3d RandomPose(std::mt19937* rng, double max_translation_m) {
  std::normal_distribution<double> normal(0.0, 1.0);
  std::uniform_real_distribution<double> uniform(-max_translation_m, max_translation_m);
  Eigen::Quaterniond q(normal(*rng), normal(*rng), normal(*rng), normal(*rng));
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = q.normalized().toRotationMatrix();
  X.translation() = Eigen::Vector3d(uniform(*rng), uniform(*rng), uniform(*rng));
  return X;
}

double TransErr(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return (a.translation() - b.translation()).norm();
}
double RotErr(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return pd::RotationAngle(a.linear(), b.linear());
}

// ---------------------------------------------------------------------------------------
// Shared fixtures (loaded once).

struct OpenCvSample {
  cv::Mat model_mat;  // millimetres, as OpenCV's sample uses it
  cv::Mat scene_mat;
  PointCloud model;  // metres
  PointCloud scene;
};

const OpenCvSample& Sample() {
  static const OpenCvSample* s = [] {
    auto* out = new OpenCvSample;
    out->model_mat =
        cv::ppf_match_3d::loadPLYSimple((kOpenCvData + "parasaurolophus_6700.ply").c_str(), 1);
    out->scene_mat = cv::ppf_match_3d::loadPLYSimple((kOpenCvData + "rs1_normals.ply").c_str(), 1);
    out->model = FromOpenCvMat(out->model_mat, 1e-3f);
    out->scene = FromOpenCvMat(out->scene_mat, 1e-3f);
    return out;
  }();
  return *s;
}

pd::ObjectModelOptions Rs1ModelOptions() {
  pd::ObjectModelOptions o;
  o.sampling_distance_rel = 0.025f;  // OpenCV's sample trains at 0.025
  o.use_input_normals = true;
  o.fine_voxel_rel = 0.01f;
  o.icp_voxel_rel = 0.015f;
  return o;
}

pd::PpfDetectorOptions Rs1DetectorOptions() {
  pd::PpfDetectorOptions o;
  o.match.reference_step = 10;
  o.hypotheses_to_verify = 3;
  return o;
}

struct MilkData {
  PointCloud model;
  PointCloud scene;
};

const MilkData& Milk() {
  static const MilkData* m = [] {
    auto* out = new MilkData;
    out->model = LoadPcd(DataPath("milk.pcd"));
    out->scene = LoadPcd(DataPath("milk_cartoon_all_small_clorox.pcd"));
    return out;
  }();
  return *m;
}

// ---------------------------------------------------------------------------------------
// Reports.

void ReportRs1() {
  const OpenCvSample& s = Sample();
  std::printf("\n== OpenCV sample: parasaurolophus_6700 (%zu pts) in rs1_normals (%zu pts) ==\n",
              s.model.size(), s.scene.size());
  double t0 = Now();
  cv::ppf_match_3d::PPF3DDetector cv_detector(0.025, 0.05);
  cv_detector.trainModel(s.model_mat);
  const double cv_train_s = Now() - t0;
  std::vector<cv::ppf_match_3d::Pose3DPtr> cv_results;
  t0 = Now();
  cv_detector.match(s.scene_mat, cv_results, 1.0 / 40.0, 0.05);
  const double cv_match_s = Now() - t0;
  std::vector<cv::ppf_match_3d::Pose3DPtr> cv_top(
      cv_results.begin(), cv_results.begin() + std::min<std::size_t>(2, cv_results.size()));
  cv::ppf_match_3d::ICP cv_icp(100, 0.005f, 2.5f, 8);
  t0 = Now();
  cv_icp.registerModelToScene(s.model_mat, s.scene_mat, cv_top);
  const double cv_icp_s = Now() - t0;
  const Eigen::Isometry3d X_cv = FromMatx(cv_top.front()->pose, 1e-3);

  t0 = Now();
  const pd::ObjectModel model(s.model, Rs1ModelOptions());
  const double train_s = Now() - t0;
  pd::PpfSceneOptions scene_options;
  scene_options.use_input_normals = true;
  t0 = Now();
  const pd::PpfScene scene = pd::PreparePpfScene(s.scene, model, scene_options);
  const double prepare_s = Now() - t0;
  t0 = Now();
  const pd::PpfDetectionResult ours = pd::DetectPpf(model, scene, Rs1DetectorOptions());
  const double detect_s = Now() - t0;
  const pd::PpfDetection& best = ours.best;

  int visible = 0;
  const float step = model.sampling_distance_m();
  const double cv_support = pd::SceneSupport(model, scene, X_cv, 0.5f * step, 0.5f, &visible);
  std::printf(
      "OpenCV: train %.3f s, match %.3f s (%zu poses), ICP of 2 poses %.3f s; "
      "support of its best pose after ICP %.3f\n",
      cv_train_s, cv_match_s, cv_results.size(), cv_icp_s, cv_support);
  std::printf(
      "ours:   train %.3f s (%zu sampled pts, %zu pairs), scene sampling %.3f s, "
      "match %.3f s + ICP/verify %.3f s = %.3f s; support %.3f, ICP rmse %.2f mm\n",
      train_s, model.table().sampled_model().size(), model.table().entries().size(), prepare_s,
      ours.match_s, ours.refine_s, detect_s, best.support, 1e3 * best.icp.inlier_rmse_m);
  std::printf("difference ours vs OpenCV+ICP: %.2f mm, %.2f deg\n",
              1e3 * TransErr(best.X_SceneModel, X_cv), RotErr(best.X_SceneModel, X_cv) / kDeg);
  std::printf("speed-up: training %.1fx, matching (sampling+match+ICP/verify vs match) %.1fx\n",
              cv_train_s / train_s, cv_match_s / (prepare_s + detect_s));
}

struct Outcome {
  int ok = 0;
  int total = 0;
  double time_s = 0.0;
  double worst_ok_trans_m = 0.0;
  double worst_ok_rot_rad = 0.0;
};

void PrintOutcome(const char* name, const Outcome& o) {
  std::printf(
      "%-10s %3d / %3d within 5 mm and 2 deg (%.0f %%), mean %.3f s per start; "
      "worst successful error %.2f mm %.2f deg\n",
      name, o.ok, o.total, 100.0 * o.ok / std::max(1, o.total), o.time_s / std::max(1, o.total),
      1e3 * o.worst_ok_trans_m, o.worst_ok_rot_rad / kDeg);
}

void Score(Outcome* o, const Eigen::Isometry3d& X, const Eigen::Isometry3d& expected) {
  const double te = TransErr(X, expected), re = RotErr(X, expected);
  ++o->total;
  if (te < 0.005 && re < 2.0 * kDeg) {
    ++o->ok;
    o->worst_ok_trans_m = std::max(o->worst_ok_trans_m, te);
    o->worst_ok_rot_rad = std::max(o->worst_ok_rot_rad, re);
  }
}

// Knobs of the milk report (command-line flags), defaults = the library defaults.
// Model sampling 0.05 of the diameter is Drost et al.'s tau_d (the library default is 0.03).
struct MilkKnobs {
  float sampling_rel = 0.05f;
  int reference_step = pd::PpfMatchOptions{}.reference_step;
};

std::vector<Eigen::Isometry3d> MilkMoves(int count) {
  std::mt19937 rng(2016);
  std::vector<Eigen::Isometry3d> moves;
  for (int i = 0; i < count; ++i) moves.push_back(RandomPose(&rng, 0.5));
  return moves;
}

double CpuNow() { return static_cast<double>(std::clock()) / CLOCKS_PER_SEC; }

void ReportMilk(int starts, int opencv_starts, const MilkKnobs& knobs) {
  const MilkData& m = Milk();
  std::printf("\n== PCL milk scene: %d seeded random starts (model moved by X, expect X^-1) ==\n",
              starts);
  Outcome ours, opencv;
  const std::vector<Eigen::Isometry3d> moves = MilkMoves(std::max(starts, opencv_starts));
  double train_sum = 0, prep_sum = 0, match_sum = 0, refine_sum = 0;
  double refs = 0, lookups = 0, votes = 0, scene_points = 0;
  pd::ObjectModelOptions model_options;
  model_options.sampling_distance_rel = knobs.sampling_rel;
  pd::PpfDetectorOptions detector_options;
  detector_options.match.reference_step = knobs.reference_step;
  double match_cpu = 0.0;
  for (int i = 0; i < starts; ++i) {
    double t0 = Now();
    const pd::ObjectModel model(Transformed(m.model, moves[i]), model_options);
    const double t1 = Now();
    const pd::PpfScene scene = pd::PreparePpfScene(m.scene, model);
    const double t2 = Now();
    const double c2 = CpuNow();
    const pd::PpfDetectionResult r = pd::DetectPpf(model, scene, detector_options);
    match_cpu += CpuNow() - c2;
    const double t3 = Now();
    train_sum += t1 - t0;
    prep_sum += t2 - t1;
    match_sum += r.match_s;
    refine_sum += r.refine_s;
    refs += r.match.reference_points;
    lookups += static_cast<double>(r.match.pair_lookups);
    votes += static_cast<double>(r.match.votes_cast);
    scene_points += static_cast<double>(scene.sampled.size());
    ours.time_s += t3 - t0;
    const Eigen::Isometry3d X =
        r.detections.empty() ? r.best.X_SceneModel : r.detections.front().X_SceneModel;
    Score(&ours, X, moves[i].inverse());
  }
  PrintOutcome("ours", ours);
  std::printf(
      "  per start: train %.3f s, scene sampling + normals %.3f s, match %.3f s, "
      "ICP + verification %.3f s\n",
      train_sum / starts, prep_sum / starts, match_sum / starts, refine_sum / starts);
  std::printf(
      "  per start: %.0f sampled scene points, %.0f reference points, %.2e pair "
      "look-ups, %.2e votes\n",
      scene_points / starts, refs / starts, lookups / starts, votes / starts);
  std::printf("  per start: match + ICP/verify CPU time %.3f s (both threads)\n",
              match_cpu / starts);

  if (opencv_starts <= 0) return;
  // OpenCV is trained once on the model with our normals; the scene is moved by X^-1
  // instead of the model by X (the same relative placement), to avoid retraining per start.
  const pd::ObjectModel model(m.model, model_options);
  const pd::PpfScene scene = pd::PreparePpfScene(m.scene, model);
  const cv::Mat model_mat = ToOpenCvMat(model.fine_cloud());
  double t0 = Now();
  cv::ppf_match_3d::PPF3DDetector cv_detector(knobs.sampling_rel, 0.05);
  cv_detector.trainModel(model_mat);
  const double cv_train_s = Now() - t0;
  for (int i = 0; i < opencv_starts; ++i) {
    const Eigen::Isometry3d X_moved = moves[i].inverse();
    const cv::Mat scene_mat = ToOpenCvMat(Transformed(scene.fine, X_moved));
    t0 = Now();
    std::vector<cv::ppf_match_3d::Pose3DPtr> results;
    cv_detector.match(scene_mat, results, 1.0 / knobs.reference_step, knobs.sampling_rel);
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    if (!results.empty()) {
      std::vector<cv::ppf_match_3d::Pose3DPtr> top(
          results.begin(), results.begin() + std::min<std::size_t>(2, results.size()));
      cv::ppf_match_3d::ICP icp(100, 0.005f, 2.5f, 8);
      icp.registerModelToScene(model_mat, scene_mat, top);
      X = FromMatx(top.front()->pose, 1.0);
    }
    opencv.time_s += Now() - t0;
    Score(&opencv, X, X_moved);
  }
  PrintOutcome("OpenCV", opencv);
  std::printf(
      "  OpenCV trained once in %.2f s (relative sampling %.3f, scene step 1/%d); time per start "
      "is match + ICP of its 2 best poses\n",
      cv_train_s, knobs.sampling_rel, knobs.reference_step);
}

// An object that is not in the scene (the Stanford bunny) must not be detected in the milk
// scene: prints the best support any of its hypotheses reaches after ICP.
void ReportAbsentObject(const MilkKnobs& knobs) {
  const MilkData& m = Milk();
  pd::ObjectModelOptions model_options;
  model_options.sampling_distance_rel = knobs.sampling_rel;
  pd::PpfDetectorOptions options;
  options.match.reference_step = knobs.reference_step;
  for (const char* name : {"bun0.pcd", "milk.pcd"}) {
    // bun0 has 397 points: normals need a wider neighbourhood than the default.
    pd::ObjectModelOptions o = model_options;
    if (std::string(name) == "bun0.pcd") o.normal_radius_rel = 0.1f;
    const pd::ObjectModel model(LoadPcd(DataPath(name)), o);
    const pd::PpfScene scene = pd::PreparePpfScene(m.scene, model);
    for (bool skip : {true, false}) {
      options.match.skip_duplicate_votes = skip;
      const pd::PpfDetectionResult r = pd::DetectPpf(model, scene, options);
      std::printf(
          "%s in the milk scene (skip_duplicate_votes %d): %zu detections; best hypothesis: "
          "support %.3f, conflicts %.3f, %d of %zu model points visible\n",
          name, skip ? 1 : 0, r.detections.size(), r.best.support, r.best.conflict_fraction,
          r.best.visible_points, model.icp_cloud().size());
    }
  }
}

// PCL's PPFRegistration on the first `starts` milk starts, each in a child process stopped
// after cap_s seconds; it gets the same sampled model and scene (with our normals) as ours.
void ReportPcl(int starts, int cap_s, const MilkKnobs& knobs) {
  const MilkData& m = Milk();
  std::printf(
      "\n== PCL PPFRegistration (PPFEstimation + PPFHashMapSearch, 12 deg, %.3f of the "
      "diameter, scene step %d), %d starts, cap %d s each ==\n",
      knobs.sampling_rel, knobs.reference_step, starts, cap_s);
  std::fflush(stdout);
  const std::vector<Eigen::Isometry3d> moves = MilkMoves(starts);
  Outcome pcl;
  int capped = 0;
  double finished_time = 0.0;
  for (int i = 0; i < starts; ++i) {
    int fds[2];
    if (pipe(fds) != 0) return;
    const double t0 = Now();
    const pid_t child = fork();
    if (child == 0) {
      close(fds[0]);
      alarm(static_cast<unsigned>(cap_s));  // SIGALRM ends the child at the cap
      pd::ObjectModelOptions options;
      options.sampling_distance_rel = knobs.sampling_rel;
      const pd::ObjectModel model(Transformed(m.model, moves[i]), options);
      const pd::PpfScene scene = pd::PreparePpfScene(m.scene, model);
      auto to_pcl = [](const PointCloud& c) {
        auto out = std::make_shared<pcl::PointCloud<pcl::PointNormal>>();
        for (std::size_t k = 0; k < c.size(); ++k) {
          pcl::PointNormal p;
          p.getVector3fMap() = c.points[k];
          p.getNormalVector3fMap() = c.normals[k];
          out->push_back(p);
        }
        return out;
      };
      auto model_pcl = to_pcl(model.table().sampled_model());
      auto scene_pcl = to_pcl(scene.sampled);
      const double t_start = Now();
      auto features = std::make_shared<pcl::PointCloud<pcl::PPFSignature>>();
      pcl::PPFEstimation<pcl::PointNormal, pcl::PointNormal, pcl::PPFSignature> estimation;
      estimation.setInputCloud(model_pcl);
      estimation.setInputNormals(model_pcl);
      estimation.compute(*features);
      auto search = std::make_shared<pcl::PPFHashMapSearch>(
          12.0f * static_cast<float>(kDeg), knobs.sampling_rel * model.diameter_m());
      search->setInputFeatureCloud(features);
      pcl::PPFRegistration<pcl::PointNormal, pcl::PointNormal> registration;
      registration.setSceneReferencePointSamplingRate(knobs.reference_step);
      registration.setPositionClusteringThreshold(0.1f * model.diameter_m());
      registration.setRotationClusteringThreshold(30.0f * static_cast<float>(kDeg));
      registration.setSearchMethod(search);
      registration.setInputSource(model_pcl);
      registration.setInputTarget(scene_pcl);
      pcl::PointCloud<pcl::PointNormal> aligned;
      registration.align(aligned);
      Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
      X.matrix() = registration.getFinalTransformation().cast<double>();
      X.linear() = Eigen::Quaterniond(X.linear()).normalized().toRotationMatrix();
      double out[9] = {Now() - t_start};
      const Eigen::Quaterniond q(X.linear());
      out[1] = X.translation().x();
      out[2] = X.translation().y();
      out[3] = X.translation().z();
      out[4] = q.w();
      out[5] = q.x();
      out[6] = q.y();
      out[7] = q.z();
      if (write(fds[1], out, sizeof(out)) != sizeof(out)) _exit(2);
      _exit(0);
    }
    close(fds[1]);
    int status = 0;
    waitpid(child, &status, 0);
    const double elapsed = Now() - t0;
    double out[9] = {};
    const bool finished = read(fds[0], out, sizeof(out)) == sizeof(out);
    close(fds[0]);
    if (!finished) {
      ++capped;
      ++pcl.total;  // a start stopped at the cap counts as a failure
      std::printf("  start %d: stopped at the cap (%.1f s wall)\n", i, elapsed);
      continue;
    }
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.translation() = Eigen::Vector3d(out[1], out[2], out[3]);
    X.linear() = Eigen::Quaterniond(out[4], out[5], out[6], out[7]).toRotationMatrix();
    const Eigen::Isometry3d expected = moves[i].inverse();
    Score(&pcl, X, expected);
    finished_time += out[0];
    std::printf("  start %d: registration %.1f s (process %.1f s wall), error %.2f mm, %.2f deg\n",
                i, out[0], elapsed, 1e3 * TransErr(X, expected), RotErr(X, expected) / kDeg);
  }
  std::printf(
      "PCL        %3d / %3d within 5 mm and 2 deg; %d stopped at the %d s cap; mean registration "
      "time of the finished starts %.1f s\n",
      pcl.ok, pcl.total, capped, cap_s,
      pcl.total > capped ? finished_time / (pcl.total - capped) : 0.0);
  std::fflush(stdout);
}

// ---------------------------------------------------------------------------------------
// Google Benchmark timings.

void BM_PpfTrainParasaurolophus(benchmark::State& state) {
  const OpenCvSample& s = Sample();
  for (auto _ : state) {
    pd::ObjectModel model(s.model, Rs1ModelOptions());
    benchmark::DoNotOptimize(model.table().entries().data());
  }
}
BENCHMARK(BM_PpfTrainParasaurolophus)->Unit(benchmark::kMillisecond);

void BM_PpfDetectRs1(benchmark::State& state) {
  const OpenCvSample& s = Sample();
  const pd::ObjectModel model(s.model, Rs1ModelOptions());
  pd::PpfSceneOptions scene_options;
  scene_options.use_input_normals = true;
  for (auto _ : state) {
    const pd::PpfScene scene = pd::PreparePpfScene(s.scene, model, scene_options);
    benchmark::DoNotOptimize(pd::DetectPpf(model, scene, Rs1DetectorOptions()).best.support);
  }
}
BENCHMARK(BM_PpfDetectRs1)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_OpenCvMatchRs1(benchmark::State& state) {
  const OpenCvSample& s = Sample();
  static cv::ppf_match_3d::PPF3DDetector* detector = [&] {
    auto* d = new cv::ppf_match_3d::PPF3DDetector(0.025, 0.05);
    d->trainModel(s.model_mat);
    return d;
  }();
  for (auto _ : state) {
    std::vector<cv::ppf_match_3d::Pose3DPtr> results;
    detector->match(s.scene_mat, results, 1.0 / 40.0, 0.05);
    benchmark::DoNotOptimize(results.data());
  }
}
BENCHMARK(BM_OpenCvMatchRs1)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(5);

// ICP refinement of one pose on the milk scene from a 3 degree / 5 mm perturbation.
void BM_IcpRefineMilk(benchmark::State& state) {
  const MilkData& m = Milk();
  const pd::ObjectModel model(m.model, pd::ObjectModelOptions{});
  const pd::PpfScene scene = pd::PreparePpfScene(m.scene, model);
  pd::IcpOptions options;
  options.max_correspondence_distance_m = 2.5f * model.sampling_distance_m();
  options.loss_scale_m = 0.5f * model.sampling_distance_m();
  Eigen::Isometry3d start = Eigen::Isometry3d::Identity();
  start.linear() = Eigen::AngleAxisd(3.0 * kDeg, Eigen::Vector3d(1, 2, 3).normalized()).matrix();
  start.translation() = Eigen::Vector3d(0.003, -0.004, 0.0);
  double err = 0.0;
  int iterations = 0;
  for (auto _ : state) {
    const pd::IcpResult r =
        pd::RunIcp(model.icp_cloud(), scene.fine, scene.fine_tree, start, options);
    err = r.X_TargetSource.translation().norm();
    iterations = r.iterations;
  }
  state.counters["final_error_mm"] = 1e3 * err;
  state.counters["iterations"] = iterations;
  state.counters["model_points"] = static_cast<double>(model.icp_cloud().size());
  state.counters["scene_points"] = static_cast<double>(scene.fine.size());
}
BENCHMARK(BM_IcpRefineMilk)->Unit(benchmark::kMillisecond);

void BM_OpenCvIcpRs1(benchmark::State& state) {
  const OpenCvSample& s = Sample();
  cv::ppf_match_3d::PPF3DDetector detector(0.025, 0.05);
  static std::vector<cv::ppf_match_3d::Pose3DPtr> results;
  static bool trained = false;
  static cv::ppf_match_3d::PPF3DDetector* d = nullptr;
  if (!trained) {
    d = new cv::ppf_match_3d::PPF3DDetector(0.025, 0.05);
    d->trainModel(s.model_mat);
    d->match(s.scene_mat, results, 1.0 / 40.0, 0.05);
    trained = true;
  }
  for (auto _ : state) {
    std::vector<cv::ppf_match_3d::Pose3DPtr> one(results.begin(), results.begin() + 1);
    cv::ppf_match_3d::ICP icp(100, 0.005f, 2.5f, 8);
    icp.registerModelToScene(s.model_mat, s.scene_mat, one);
  }
}
BENCHMARK(BM_OpenCvIcpRs1)->Unit(benchmark::kMillisecond)->Iterations(3);

// Search-tree build over a scan-sized cloud (550 k points, the largest bin regions of the
// shelf scans): ours against PCL's KdTreeFLANN. The points are a seeded, gently curved
// surface in shuffled order.
const std::vector<Eigen::Vector3f>& ScanSizedCloud() {
  static const std::vector<Eigen::Vector3f> points = [] {
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> u(0.0f, 0.3f);
    std::vector<Eigen::Vector3f> out;
    for (int i = 0; i < 550000; ++i) {
      const float x = u(rng), y = u(rng);
      out.emplace_back(x, y, 0.05f * std::sin(20.0f * x) + 0.003f * static_cast<float>(i % 3));
    }
    return out;
  }();
  return points;
}

void BM_KdTreeBuild550k(benchmark::State& state) {
  const std::vector<Eigen::Vector3f>& points = ScanSizedCloud();
  for (auto _ : state) {
    pd::KdTree tree(points);
    benchmark::DoNotOptimize(tree.size());
  }
}
BENCHMARK(BM_KdTreeBuild550k)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_PclKdTreeFlannBuild550k(benchmark::State& state) {
  auto cloud = pcl::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  for (const auto& p : ScanSizedCloud()) cloud->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
  for (auto _ : state) {
    pcl::KdTreeFLANN<pcl::PointXYZ> tree;
    tree.setInputCloud(cloud);
    benchmark::DoNotOptimize(tree.getInputCloud());
  }
}
BENCHMARK(BM_PclKdTreeFlannBuild550k)->Unit(benchmark::kMillisecond)->UseRealTime();

bool Flag(const std::string& arg, const std::string& name, int* value) {
  const std::string prefix = "--" + name + "=";
  if (arg.rfind(prefix, 0) != 0) return false;
  *value = std::stoi(arg.substr(prefix.size()));
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  int milk_starts = 100, opencv_starts = 100, pcl_cap_s = 180, pcl_starts = 3, skip_pcl = 0,
      skip_reports = 0, skip_rs1 = 0, absent = 0;
  MilkKnobs knobs;
  int sampling_permille = static_cast<int>(std::lround(1000 * knobs.sampling_rel));
  std::vector<char*> rest = {argv[0]};
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (Flag(a, "milk_sampling_permille", &sampling_permille) ||
        Flag(a, "reference_step", &knobs.reference_step)) {
      knobs.sampling_rel = 1e-3f * static_cast<float>(sampling_permille);
      continue;
    }
    if (Flag(a, "milk_starts", &milk_starts) || Flag(a, "opencv_starts", &opencv_starts) ||
        Flag(a, "pcl_cap_s", &pcl_cap_s) || Flag(a, "pcl_starts", &pcl_starts)) {
      continue;
    }
    if (a == "--skip_pcl") {
      skip_pcl = 1;
      continue;
    }
    if (a == "--skip_reports") {
      skip_reports = 1;
      continue;
    }
    if (a == "--absent") {
      absent = 1;
      continue;
    }
    if (a == "--skip_rs1") {
      skip_rs1 = 1;
      continue;
    }
    rest.push_back(argv[i]);
  }
  if (!skip_reports) {
    if (!skip_pcl && pcl_starts > 0) {
      ReportPcl(pcl_starts, pcl_cap_s, knobs);  // first, before any thread exists (fork)
    }
    if (!skip_rs1) ReportRs1();
    if (absent) ReportAbsentObject(knobs);
    if (milk_starts > 0) ReportMilk(milk_starts, opencv_starts, knobs);
    std::fflush(stdout);
  }
  int n = static_cast<int>(rest.size());
  benchmark::Initialize(&n, rest.data());
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
