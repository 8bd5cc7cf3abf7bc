#include "services/planner/core/distance_grid.h"

#include <gtest/gtest.h>

#include <limits>
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

// Two triangles of a tilted panel, sampled 3 mm apart, as the static cell's meshes are.
TEST(DistanceGridTest, TightenedCellsHoldTheExactDistanceNearTheSurface) {
  const std::vector<Eigen::Vector3f> vertices = {
      Eigen::Vector3f(0.f, 0.f, 0.f), Eigen::Vector3f(0.4f, 0.05f, 0.1f),
      Eigen::Vector3f(0.f, 0.3f, 0.2f), Eigen::Vector3f(0.4f, 0.35f, 0.3f)};
  const std::vector<std::array<std::uint32_t, 3>> indices = {{0, 1, 2}, {1, 3, 2}};
  std::vector<std::array<Eigen::Vector3f, 3>> triangles;
  for (const auto& t : indices)
    triangles.push_back({vertices[t[0]], vertices[t[1]], vertices[t[2]]});
  std::vector<Eigen::Vector3f> seeds;
  SampleSurface(vertices, indices, Eigen::Isometry3d::Identity(), 0.003, &seeds);
  DistanceGridOptions options;
  options.resolution_m = 0.005;
  options.margin_m = 0.1;
  options.seed_allowance_m = 0.003;
  const DistanceGrid seeded = DistanceGrid::Build(seeds, options);
  DistanceGrid tight = seeded;
  const float band_m = 0.04f;
  tight.Tighten(band_m, triangles);
  auto truth = [&](const Eigen::Vector3f& p) {
    float d2 = 1e9f;
    for (const auto& t : triangles) d2 = std::min(d2, PointTriangleDistance2(p, t[0], t[1], t[2]));
    return std::sqrt(d2);
  };
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  const float half_diagonal = 0.5f * std::sqrt(3.f) * 0.005f;
  float worst_seeded_gap = 0.f, worst_tight_gap = 0.f;
  double near_gap_sum = 0.0;
  int near_count = 0;
  for (int i = 0; i < 50000; ++i) {
    // Near the panel: a point of it moved off by up to 6 cm.
    const float a = u(rng), b = u(rng) * (1.f - a);
    const Eigen::Vector3f on = triangles[i % 2][0] +
                               a * (triangles[i % 2][1] - triangles[i % 2][0]) +
                               b * (triangles[i % 2][2] - triangles[i % 2][0]);
    const Eigen::Vector3f p =
        on + 0.06f * Eigen::Vector3f(u(rng) - 0.5f, u(rng) - 0.5f, u(rng) - 0.5f) * 2.f;
    const float d = truth(p);
    ASSERT_LE(tight.Clearance(p), d + 1e-5f) << "at " << p.transpose();
    ASSERT_GE(tight.Clearance(p), seeded.Clearance(p) - 1e-4f) << "at " << p.transpose();
    const DistanceGrid::Bounds near = tight.NearBounds(p);
    ASSERT_GE(near.upper_m, d - 1e-5f) << "at " << p.transpose();
    ASSERT_LE(near.lower_m, d + 1e-5f) << "at " << p.transpose();
    ASSERT_GE(near.lower_m, tight.Clearance(p) - 1e-5f) << "at " << p.transpose();
    ASSERT_EQ(seeded.NearBounds(p).upper_m, std::numeric_limits<float>::infinity());
    ASSERT_LE(seeded.NearBounds(p).lower_m, d + 1e-5f) << "at " << p.transpose();
    if (d < band_m) {
      // Loose only by twice the offset from the cell's centre (the distance there is exact, and
      // the true distance at p at most that offset farther) and the rounding to 0.1 mm.
      ASSERT_GE(tight.Clearance(p), d - 2.f * half_diagonal - 3e-4f) << "at " << p.transpose();
      worst_tight_gap = std::max(worst_tight_gap, d - tight.Clearance(p));
      // Within the band every cell is exact (the band is wider than the cells' diagonal).
      if (d < band_m - 2.f * half_diagonal) {
        ASSERT_LE(near.upper_m, d + 4.f * half_diagonal + 3e-4f);
        near_gap_sum += near.upper_m - near.lower_m;
        ++near_count;
      }
      worst_seeded_gap = std::max(worst_seeded_gap, d - seeded.Clearance(p));
    }
  }
  // The seeded bound alone gives away the seeds' spacing and another half diagonal as well.
  EXPECT_GT(worst_seeded_gap, worst_tight_gap + half_diagonal) << worst_tight_gap;
  // Eight centres pin the distance down to well under a cell diagonal on average.
  ASSERT_GT(near_count, 0);
  EXPECT_LT(near_gap_sum / near_count, 2.f * half_diagonal) << near_gap_sum / near_count;
  EXPECT_THROW(tight.Tighten(-1.f, triangles), std::invalid_argument);
}

TEST(DistanceGridTest, BlocksNeverBoundAboveTheGrid) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-0.2f, 0.2f);
  std::vector<Eigen::Vector3f> seeds;
  for (int i = 0; i < 200; ++i) seeds.emplace_back(u(rng), u(rng), u(rng));
  DistanceGridOptions options;
  options.resolution_m = 0.005;
  options.margin_m = 0.05;
  const DistanceGrid grid = DistanceGrid::Build(seeds, options);
  // Blocks over a box larger than the grid: the part outside answers the grid's outside bound.
  Eigen::AlignedBox3f box = grid.bounds_F();
  box.extend(box.max() + Eigen::Vector3f::Constant(0.1f));
  const BlockBound blocks = BlockBound::FromFunction(
      box, 0.02f, [&](const Eigen::AlignedBox3f& b) { return grid.LowerBoundIn(b); }, -1.f);
  std::uniform_real_distribution<float> q(-0.35f, 0.45f);
  int tight = 0;
  for (int i = 0; i < 50000; ++i) {
    const Eigen::Vector3f p(q(rng), q(rng), q(rng));
    const float fine = grid.Clearance(p);
    const float coarse = blocks.Clearance(p);
    // No distance is negative: the blocks store bounds below zero as zero.
    ASSERT_LE(coarse, std::max(fine, 0.f) + 1e-4f) << "at " << p.transpose();
    // The last blocks may reach up to a block beyond the box's far faces.
    Eigen::AlignedBox3f covered = box;
    covered.extend(box.max() + Eigen::Vector3f::Constant(0.02f));
    if (!covered.contains(p)) EXPECT_EQ(coarse, -1.f);
    // Within a block's diagonal and a cell's of the fine bound where anything is near.
    if (box.contains(p) && fine < 0.1f && coarse > fine - 0.04f) ++tight;
  }
  EXPECT_GT(tight, 1000);
  EXPECT_THROW(
      BlockBound::FromFunction(
          Eigen::AlignedBox3f(), 0.02f, [](const Eigen::AlignedBox3f&) { return 0.f; }, 0.f),
      std::invalid_argument);
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
