// Speed of the UR10 kinematics: forward kinematics, all-branch inverse kinematics and the
// nearest-to-seed solution, over a fixed set of random reachable poses.
#include <benchmark/benchmark.h>

#include <random>
#include <string>
#include <vector>

#include "libs/ur10/kinematics.h"

namespace {

using picking::ur10::JointVector;
using picking::ur10::Ur10Kinematics;
using picking::ur10::Ur10Model;

constexpr int kNumSamples = 1024;

const Ur10Kinematics& Kinematics() {
  static const Ur10Kinematics kin(Ur10Model::Load(std::string(PICKING_DATA_DIR) + "/ur10"));
  return kin;
}

std::vector<JointVector> RandomJoints() {
  std::mt19937 rng(123);
  std::uniform_real_distribution<double> angle(-3.14159, 3.14159);
  std::vector<JointVector> qs(kNumSamples);
  for (auto& q : qs) {
    for (int j = 0; j < 6; ++j) q[j] = angle(rng);
  }
  return qs;
}

std::vector<Eigen::Isometry3d> RandomPoses(const std::vector<JointVector>& qs) {
  std::vector<Eigen::Isometry3d> poses;
  for (const auto& q : qs) poses.push_back(Kinematics().ForwardKinematics(q));
  return poses;
}

void BM_ForwardKinematics(benchmark::State& state) {
  const auto qs = RandomJoints();
  std::size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(Kinematics().ForwardKinematics(qs[i++ % qs.size()]));
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_ForwardKinematics);

void BM_InverseKinematicsAllBranches(benchmark::State& state) {
  const auto poses = RandomPoses(RandomJoints());
  std::size_t i = 0;
  std::size_t solutions = 0;
  for (auto _ : state) {
    const auto result = Kinematics().Solve(poses[i++ % poses.size()]);
    solutions += result.solutions.size();
    benchmark::DoNotOptimize(result);
  }
  state.SetItemsProcessed(state.iterations());
  state.counters["solutions_per_s"] =
      benchmark::Counter(static_cast<double>(solutions), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_InverseKinematicsAllBranches);

void BM_InverseKinematicsNearestToSeed(benchmark::State& state) {
  const auto qs = RandomJoints();
  const auto poses = RandomPoses(qs);
  std::size_t i = 0;
  for (auto _ : state) {
    const std::size_t k = i++ % poses.size();
    benchmark::DoNotOptimize(Kinematics().NearestSolution(poses[k], qs[k]));
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_InverseKinematicsNearestToSeed);

void BM_Jacobian(benchmark::State& state) {
  const auto qs = RandomJoints();
  std::size_t i = 0;
  for (auto _ : state) benchmark::DoNotOptimize(Kinematics().Jacobian(qs[i++ % qs.size()]));
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Jacobian);

}  // namespace

BENCHMARK_MAIN();
