#include "services/planner/core/distance_grid.h"

#include <gtest/gtest.h>

#include <random>

namespace picking::planner {
namespace {

TEST(DistanceGridTest, ClearanceIsALowerBoundOfTheTrueDistance) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-0.3f, 0.3f);
  std::vector<Eigen::Vector3f> seeds;
  for (int i = 0; i < 300; ++i) seeds.emplace_back(u(rng), u(rng), u(rng) * 0.2f);
  DistanceGridOptions options;
  options.resolution_m = 0.01;
  options.margin_m = 0.1;
  const DistanceGrid grid = DistanceGrid::Build(seeds, options);
  double worst_gap = 0.0;
  std::uniform_real_distribution<float> q(-0.5f, 0.5f);
  for (int i = 0; i < 20000; ++i) {
    const Eigen::Vector3f p(q(rng), q(rng), q(rng));
    float truth = 1e9f;
    for (const auto& s : seeds) truth = std::min(truth, (s - p).norm());
    const float bound = grid.Clearance(p);
    ASSERT_LE(bound, truth) << "at " << p.transpose();
    if (truth < 0.1f) worst_gap = std::max<double>(worst_gap, truth - bound);
  }
  // The bound gives away at most the cell's diagonal plus rounding.
  EXPECT_LT(worst_gap, std::sqrt(3.0) * 0.01 * 1.5 + 1e-3);
}

TEST(DistanceGridTest, SeedAllowanceAndOutsideQueries) {
  const std::vector<Eigen::Vector3f> seeds = {Eigen::Vector3f(0.f, 0.f, 0.f)};
  DistanceGridOptions options;
  options.resolution_m = 0.02;
  options.margin_m = 0.1;
  options.seed_allowance_m = 0.005;
  const DistanceGrid grid = DistanceGrid::Build(seeds, options);
  EXPECT_LT(grid.Clearance(Eigen::Vector3f(0.f, 0.f, 0.f)), -0.005f);
  EXPECT_NEAR(grid.outside_clearance_m(), 0.095f, 1e-6f);
  EXPECT_FLOAT_EQ(grid.Clearance(Eigen::Vector3f(5.f, 0.f, 0.f)), grid.outside_clearance_m());
  EXPECT_TRUE(DistanceGrid().empty());
  EXPECT_GT(DistanceGrid().Clearance(Eigen::Vector3f::Zero()), 100.f);
}

TEST(DistanceGridTest, RejectsBadInput) {
  DistanceGridOptions options;
  options.resolution_m = 0.0;
  EXPECT_THROW(DistanceGrid::Build({Eigen::Vector3f::Zero()}, options), std::invalid_argument);
  options.resolution_m = 0.01;
  EXPECT_THROW(DistanceGrid::Build({Eigen::Vector3f(NAN, 0.f, 0.f)}, options),
               std::invalid_argument);
  EXPECT_THROW(DistanceGrid::Build({Eigen::Vector3f::Zero(), Eigen::Vector3f::Constant(100.f)},
                                   options, 1'000'000),
               std::invalid_argument);
}

TEST(DistanceGridTest, SurfaceSamplesLieWithinTheGapOfEverySurfacePoint) {
  const std::vector<Eigen::Vector3f> vertices = {
      {0.f, 0.f, 0.f}, {0.3f, 0.f, 0.f}, {0.0f, 0.05f, 0.f}};
  const std::vector<std::array<std::uint32_t, 3>> triangles = {{0, 1, 2}};
  std::vector<Eigen::Vector3f> samples;
  SampleSurface(vertices, triangles, Eigen::Isometry3d::Identity(), 0.004, &samples);
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  for (int i = 0; i < 2000; ++i) {
    float a = u(rng), b = u(rng);
    if (a + b > 1.f) {
      a = 1.f - a;
      b = 1.f - b;
    }
    const Eigen::Vector3f p =
        vertices[0] + a * (vertices[1] - vertices[0]) + b * (vertices[2] - vertices[0]);
    float best = 1e9f;
    for (const auto& s : samples) best = std::min(best, (s - p).norm());
    ASSERT_LE(best, 0.004f + 1e-6f);
  }
}

}  // namespace
}  // namespace picking::planner
