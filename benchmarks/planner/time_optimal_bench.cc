// Speed of the time-optimal trajectory generation (Kunz & Stilman TOTG with blends of at most
// 0.01 rad) against the robot's rest-to-rest parametrisation (robot::TimeParametrizePath,
// which stops at every corner), on 100-waypoint joint paths with the real UR10 limits,
// sampled at 125 Hz. path:0 the IK samples of straight tool moves, path:1 a tight random walk
// in joint space, path:2 waypoints uniform in the joint range. Counter trajectory_s: the mean
// duration of the trajectories produced.
#include <benchmark/benchmark.h>

#include <random>
#include <string>
#include <vector>

#include "libs/ur10/kinematics.h"
#include "libs/ur10/ur10_model.h"
#include "services/planner/core/time_optimal.h"
#include "services/robot/core/trajectory.h"

namespace {

using picking::ur10::JointVector;

constexpr int kNumWaypoints = 100;
constexpr int kNumPaths = 16;

const picking::ur10::Ur10Model& Model() {
  static const picking::ur10::Ur10Model model =
      picking::ur10::Ur10Model::Load(std::string(PICKING_DATA_DIR) + "/ur10");
  return model;
}

const picking::ur10::Ur10Kinematics& Kinematics() {
  static const picking::ur10::Ur10Kinematics kinematics(Model());
  return kinematics;
}

// The IK samples of straight tool moves (robot::SampleLinearPath, 100 waypoints each): 0.3 to
// 0.8 m lines with a turn of the tool of up to 0.5 rad, from seeded random start poses.
std::vector<std::vector<JointVector>> CartesianPaths() {
  std::mt19937 rng(2016);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  picking::robot::LinearMoveOptions options;
  options.max_joint_step_rad = 0.2;
  const JointVector home = (JointVector() << 0.0, -1.9, 1.9, -1.57, -1.57, 0.0).finished();
  std::vector<std::vector<JointVector>> paths;
  while (static_cast<int>(paths.size()) < kNumPaths) {
    const JointVector q0 = home + 0.5 * JointVector::NullaryExpr([&] { return unit(rng); });
    const Eigen::Isometry3d X_start = Kinematics().ForwardKinematics(q0);
    Eigen::Vector3d move(unit(rng), unit(rng), 0.5 * unit(rng));
    move *= (0.55 + 0.25 * unit(rng)) / move.norm();
    Eigen::Isometry3d X_goal = X_start;
    X_goal.translation() += move;
    X_goal.linear() =
        X_start.linear() *
        Eigen::AngleAxisd(0.5 * unit(rng), Eigen::Vector3d::UnitZ()).toRotationMatrix();
    const auto line = picking::robot::SampleLinearPath(Kinematics(), q0, X_goal, options,
                                                       move.norm() / (kNumWaypoints - 1), 1.0);
    if (!line.ok || static_cast<int>(line.trajectory.points.size()) != kNumWaypoints) continue;
    std::vector<JointVector> path;
    for (const auto& p : line.trajectory.points) path.push_back(p.q_rad);
    paths.push_back(path);
  }
  return paths;
}

// A random walk in joint space in steps of 0.02 rad whose direction turns by about 20 degrees
// at every waypoint (tight, shallow corners), about 2 rad in all.
std::vector<std::vector<JointVector>> WalkPaths() {
  std::mt19937 rng(2016);
  std::normal_distribution<double> normal(0.0, 1.0);
  std::vector<std::vector<JointVector>> paths(kNumPaths);
  for (auto& path : paths) {
    path = {JointVector::Zero()};
    JointVector direction = JointVector::NullaryExpr([&] { return normal(rng); }).normalized();
    for (int i = 1; i < kNumWaypoints; ++i) {
      const JointVector turn = JointVector::NullaryExpr([&] { return normal(rng); });
      direction = (direction + 0.15 * turn).normalized();
      path.push_back(path.back() + 0.02 * direction);
    }
  }
  return paths;
}

// Waypoints uniform in the UR10's joint range (long moves, corners of any angle).
std::vector<std::vector<JointVector>> RandomPaths() {
  std::mt19937 rng(2012);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const JointVector lo = Model().min_position_rad();
  const JointVector hi = Model().max_position_rad();
  std::vector<std::vector<JointVector>> paths(kNumPaths, std::vector<JointVector>(kNumWaypoints));
  for (auto& path : paths) {
    for (auto& q : path) {
      for (int j = 0; j < 6; ++j) q[j] = lo[j] + (hi[j] - lo[j]) * unit(rng);
    }
  }
  return paths;
}

// Path kinds: 0 cartesian, 1 walk, 2 random.
const std::vector<std::vector<JointVector>>& Paths(int kind) {
  static const auto cartesian = CartesianPaths();
  static const auto walk = WalkPaths();
  static const auto random = RandomPaths();
  return kind == 0 ? cartesian : kind == 1 ? walk : random;
}

void BM_TimeOptimal(benchmark::State& state) {
  const auto& paths = Paths(static_cast<int>(state.range(0)));
  picking::planner::TimeOptimalOptions options;
  options.max_velocity_rad_s = Model().max_velocity_rad_s();
  options.max_acceleration_rad_s2 = Model().max_acceleration_rad_s2();
  options.max_deviation_rad = 0.01;
  options.sample_period_s = 0.008;
  double duration = 0.0;
  for (const auto& path : paths) {
    duration += picking::planner::TimeParametrizeTimeOptimal(path, options).duration_s;
  }
  std::size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(
        picking::planner::TimeParametrizeTimeOptimal(paths[i++ % paths.size()], options));
  }
  state.counters["trajectory_s"] = duration / static_cast<double>(paths.size());
}
BENCHMARK(BM_TimeOptimal)->ArgName("path")->DenseRange(0, 2)->Unit(benchmark::kMicrosecond);

// The time law alone on the random waypoints (path:2): the same solution sampled once a
// second, so that the figure leaves out writing the 51,000 samples at 125 Hz.
void BM_TimeOptimalLawOnly(benchmark::State& state) {
  const auto& paths = Paths(2);
  picking::planner::TimeOptimalOptions options;
  options.max_velocity_rad_s = Model().max_velocity_rad_s();
  options.max_acceleration_rad_s2 = Model().max_acceleration_rad_s2();
  options.max_deviation_rad = 0.01;
  options.sample_period_s = 1.0;
  std::size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(
        picking::planner::TimeParametrizeTimeOptimal(paths[i++ % paths.size()], options));
  }
}
BENCHMARK(BM_TimeOptimalLawOnly)->Unit(benchmark::kMicrosecond);

// The floor under path:2's sampling: a vector of as many samples as its trajectories hold
// (412 s at 125 Hz), filled with one sample's values and nothing computed; what allocating
// and writing the output costs on this machine.
void BM_WriteSamplesOnly(benchmark::State& state) {
  const std::size_t n = static_cast<std::size_t>(412.4 / 0.008) + 2;
  picking::planner::TrajectorySample sample;
  sample.q_rad.setConstant(0.5);
  for (auto _ : state) {
    std::vector<picking::planner::TrajectorySample> samples;
    samples.reserve(n);
    for (std::size_t k = 0; k < n; ++k) {
      sample.time_s = 0.008 * static_cast<double>(k);
      samples.push_back(sample);
    }
    benchmark::DoNotOptimize(samples.data());
    benchmark::ClobberMemory();
  }
}
BENCHMARK(BM_WriteSamplesOnly)->Unit(benchmark::kMicrosecond);

void BM_RobotRestToRest(benchmark::State& state) {
  const auto& paths = Paths(static_cast<int>(state.range(0)));
  picking::robot::TimeParametrizationOptions options;
  options.max_velocity_rad_s = Model().max_velocity_rad_s();
  options.max_acceleration_rad_s2 = Model().max_acceleration_rad_s2();
  options.sample_rate_hz = 125.0;
  double duration = 0.0;
  for (const auto& path : paths) {
    duration += picking::robot::TimeParametrizePath(path, options).duration_s();
  }
  std::size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(
        picking::robot::TimeParametrizePath(paths[i++ % paths.size()], options));
  }
  state.counters["trajectory_s"] = duration / static_cast<double>(paths.size());
}
BENCHMARK(BM_RobotRestToRest)->ArgName("path")->DenseRange(0, 2)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
