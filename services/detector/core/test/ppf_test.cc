#include "services/detector/core/ppf.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <numeric>
#include <random>

#include "services/detector/core/test/ppf_test_util.h"

namespace picking::detector {
namespace {

constexpr float kPi = static_cast<float>(M_PI);

// A small closed box surface with outward normals: points on its six faces.
geometry::PointCloud BoxSurface(float sx, float sy, float sz, float step) {
  geometry::PointCloud c;
  const Eigen::Vector3f half(sx / 2, sy / 2, sz / 2);
  for (int axis = 0; axis < 3; ++axis) {
    const int u = (axis + 1) % 3, v = (axis + 2) % 3;
    for (float sign : {-1.0f, 1.0f}) {
      for (float a = -half[u]; a <= half[u] + 1e-6f; a += step) {
        for (float b = -half[v]; b <= half[v] + 1e-6f; b += step) {
          Eigen::Vector3f p;
          p[axis] = sign * half[axis];
          p[u] = a;
          p[v] = b;
          Eigen::Vector3f n = Eigen::Vector3f::Zero();
          n[axis] = sign;
          c.points.push_back(p);
          c.normals.push_back(n);
        }
      }
    }
  }
  c.width = static_cast<std::uint32_t>(c.size());
  return c;
}

TEST(PpfFeatureTest, InvariantUnderRigidMotion) {
  std::mt19937 rng(3);
  std::normal_distribution<float> g(0.0f, 1.0f);
  for (int i = 0; i < 100; ++i) {
    const Eigen::Vector3f p1(g(rng), g(rng), g(rng)), p2(g(rng), g(rng), g(rng));
    const Eigen::Vector3f n1 = Eigen::Vector3f(g(rng), g(rng), g(rng)).normalized();
    const Eigen::Vector3f n2 = Eigen::Vector3f(g(rng), g(rng), g(rng)).normalized();
    const Eigen::Isometry3f X = testing::RandomPose(&rng, 2.0).cast<float>();
    const Eigen::Vector4f f = ComputePpf(p1, n1, p2, n2);
    const Eigen::Vector4f g2 = ComputePpf(X * p1, X.linear() * n1, X * p2, X.linear() * n2);
    EXPECT_TRUE(f.isApprox(g2, 1e-4f)) << f.transpose() << " vs " << g2.transpose();
    EXPECT_GE(f.tail<3>().minCoeff(), 0.0f);
    EXPECT_LE(f.tail<3>().maxCoeff(), kPi);
  }
  EXPECT_FALSE(ComputePpf(Eigen::Vector3f::Ones(), Eigen::Vector3f::UnitX(),
                          Eigen::Vector3f::Ones(), Eigen::Vector3f::UnitX())
                   .allFinite());
}

TEST(PpfQuantizerTest, KeysAreDenseAndDistinct) {
  const PpfQuantizer q(0.01f, 0.2f, 30);
  EXPECT_NEAR(q.angle_step_rad(), 12.0f * kPi / 180.0f, 1e-6f);
  EXPECT_EQ(q.num_keys(), 21u * 15u * 15u * 15u);
  std::uint32_t key_a = 0, key_b = 0, key_max = 0;
  ASSERT_TRUE(q.Key(Eigen::Vector4f(0.0f, 0.0f, 0.0f, 0.0f), &key_a));
  EXPECT_EQ(key_a, 0u);
  ASSERT_TRUE(q.Key(Eigen::Vector4f(0.2f, kPi, kPi, kPi), &key_max));
  EXPECT_EQ(key_max, q.num_keys() - 1);
  // Values in one cell share a key; crossing a step changes it.
  ASSERT_TRUE(q.Key(Eigen::Vector4f(0.051f, 0.30f, 1.0f, 2.0f), &key_a));
  ASSERT_TRUE(q.Key(Eigen::Vector4f(0.059f, 0.40f, 1.0f, 2.0f), &key_b));
  EXPECT_EQ(key_a, key_b);
  ASSERT_TRUE(q.Key(Eigen::Vector4f(0.061f, 0.30f, 1.0f, 2.0f), &key_b));
  EXPECT_NE(key_a, key_b);
  EXPECT_FALSE(q.Key(Eigen::Vector4f(0.21f, 0.0f, 0.0f, 0.0f), &key_a));
  EXPECT_FALSE(q.Key(Eigen::Vector4f(std::nanf(""), 0.0f, 0.0f, 0.0f), &key_a));
  EXPECT_THROW(PpfQuantizer(0.0f, 0.2f, 30), std::invalid_argument);
  EXPECT_THROW(PpfQuantizer(1e-7f, 10.0f, 30), std::invalid_argument);
}

TEST(PpfQuantizerTest, AlphaBinsWrapAround) {
  const PpfQuantizer q(0.01f, 0.2f, 30);
  for (int b = 0; b < 30; ++b) {
    EXPECT_EQ(q.AlphaBin(q.AlphaBinCenter(b)), b);
    EXPECT_EQ(q.AlphaBin(q.AlphaBinCenter(b) + 2.0f * kPi), b);
  }
  EXPECT_EQ(q.AlphaBin(kPi - 1e-4f), 29);
  EXPECT_EQ(q.AlphaBin(-kPi + 1e-4f), 0);
}

TEST(PpfQuantizerTest, PlanarPairs) {
  const PpfQuantizer q(0.01f, 0.2f, 30);
  const Eigen::Vector3f n = Eigen::Vector3f::UnitZ();
  EXPECT_TRUE(q.IsPlanar(ComputePpf(Eigen::Vector3f::Zero(), n, Eigen::Vector3f(0.1f, 0, 0), n)));
  // Perpendicular faces of a box are not planar.
  EXPECT_FALSE(q.IsPlanar(ComputePpf(Eigen::Vector3f::Zero(), n, Eigen::Vector3f(0.1f, 0, -0.05f),
                                     Eigen::Vector3f::UnitX())));
}

// The cosine-based cells and keys agree with quantising the angles themselves, except within
// float rounding of a cell boundary.
TEST(PpfQuantizerTest, CosineCellsMatchAngleCells) {
  for (int bins : {30, 45, 360}) {
    const PpfQuantizer q(0.01f, 0.3f, bins);
    const int cells = (bins + 1) / 2;
    for (int k = 0; k <= 20000; ++k) {
      const double angle = M_PI * k / 20000.0;
      const double cell_real = angle / q.angle_step_rad();
      if (std::abs(cell_real - std::round(cell_real)) < 1e-4) continue;  // on a boundary
      const int expected = std::min(static_cast<int>(cell_real), cells - 1);
      ASSERT_EQ(q.CosineCell(static_cast<float>(std::cos(angle))), expected)
          << "bins " << bins << " angle " << angle;
    }
    EXPECT_EQ(q.CosineCell(1.5f), 0);
    EXPECT_EQ(q.CosineCell(-1.5f), cells - 1);
  }
  const PpfQuantizer q(0.01f, 0.3f, 30);
  std::mt19937 rng(17);
  std::normal_distribution<float> g(0.0f, 1.0f);
  int compared = 0;
  for (int i = 0; i < 20000; ++i) {
    const Eigen::Vector3f p1(0.1f * g(rng), 0.1f * g(rng), 0.1f * g(rng));
    const Eigen::Vector3f p2(0.1f * g(rng), 0.1f * g(rng), 0.1f * g(rng));
    const Eigen::Vector3f n1 = Eigen::Vector3f(g(rng), g(rng), g(rng)).normalized();
    const Eigen::Vector3f n2 = Eigen::Vector3f(g(rng), g(rng), g(rng)).normalized();
    const Eigen::Vector4f f = ComputePpf(p1, n1, p2, n2);
    std::uint32_t key = 0, expected = 0;
    bool planar = true;
    const bool ok = q.PairKey(p1, n1, p2, n2, &key, &planar);
    ASSERT_EQ(ok, q.Key(f, &expected));
    if (!ok) continue;
    const Eigen::Vector4f cells = f / q.angle_step_rad();
    const Eigen::Vector4f frac = (cells.array() - cells.array().round()).abs();
    if (frac.tail<3>().minCoeff() < 1e-3f) continue;  // on an angle boundary
    ++compared;
    EXPECT_EQ(key, expected) << f.transpose();
    EXPECT_EQ(planar, q.IsPlanar(f)) << f.transpose();
  }
  EXPECT_GT(compared, 5000);
  std::uint32_t key = 0;
  EXPECT_FALSE(q.PairKey(Eigen::Vector3f::Ones(), Eigen::Vector3f::UnitX(), Eigen::Vector3f::Ones(),
                         Eigen::Vector3f::UnitX(), &key));
  EXPECT_FALSE(q.PairKey(Eigen::Vector3f::Zero(), Eigen::Vector3f::UnitX(),
                         Eigen::Vector3f(0.31f, 0.0f, 0.0f), Eigen::Vector3f::UnitX(), &key));
}

TEST(PpfAlignTest, AlignToXAxisIsProperAndMapsNormal) {
  std::mt19937 rng(11);
  std::normal_distribution<float> g(0.0f, 1.0f);
  for (int i = 0; i < 50; ++i) {
    const Eigen::Vector3f p(g(rng), g(rng), g(rng));
    Eigen::Vector3f n = Eigen::Vector3f(g(rng), g(rng), g(rng)).normalized();
    if (i == 0) n = -Eigen::Vector3f::UnitX();  // the antiparallel case
    const Eigen::Isometry3f T = AlignToXAxis(p, n);
    EXPECT_NEAR(T.linear().determinant(), 1.0f, 1e-5f);
    EXPECT_TRUE((T.linear() * n).isApprox(Eigen::Vector3f::UnitX(), 1e-5f));
    EXPECT_LT((T * p).norm(), 1e-5f);
  }
}

TEST(PpfTableTest, StoresEveryNonPlanarPairOnce) {
  const geometry::PointCloud box = BoxSurface(0.1f, 0.06f, 0.04f, 0.02f);
  const float diameter = std::sqrt(0.1f * 0.1f + 0.06f * 0.06f + 0.04f * 0.04f) + 1e-4f;
  const PpfTable table(box, diameter, 0.01f);
  const PpfQuantizer& q = table.quantizer();
  std::size_t expected = 0;
  for (std::size_t i = 0; i < box.size(); ++i) {
    for (std::size_t j = 0; j < box.size(); ++j) {
      if (i == j) continue;
      std::uint32_t key = 0;
      bool planar = false;
      if (!q.PairKey(box.points[i], box.normals[i], box.points[j], box.normals[j], &key, &planar) ||
          planar) {
        continue;
      }
      ++expected;
      // The pair is stored under its key with its alpha.
      const float alpha = PairAngle(AlignToXAxis(box.points[i], box.normals[i]), box.points[j]);
      bool found = false;
      for (const auto* e = table.begin(key); e != table.end(key); ++e) {
        found |= e->model_reference == i && std::abs(e->alpha_m_rad - alpha) < 1e-6f;
      }
      EXPECT_TRUE(found) << i << " " << j;
    }
  }
  EXPECT_EQ(table.entries().size(), expected);
  EXPECT_EQ(table.offsets().size(), q.num_keys() + 1u);
  // The vote codes carry each entry's model point and its angle to 1/kAlphaSubsteps of a bin.
  ASSERT_EQ(table.vote_codes().size(), table.entries().size());
  const float unit = q.angle_step_rad() / PpfTable::kAlphaSubsteps;
  for (std::size_t k = 0; k < table.entries().size(); ++k) {
    const std::uint32_t code = table.vote_codes()[k];
    EXPECT_EQ(code >> 13, table.entries()[k].model_reference);
    const float decoded = -kPi + (static_cast<float>(code & 0x1FFFu) + 0.5f) * unit;
    EXPECT_LE(std::abs(decoded - table.entries()[k].alpha_m_rad), 0.5f * unit + 1e-5f);
  }
}

TEST(PpfTableTest, RejectsBadModels) {
  EXPECT_THROW(PpfTable(geometry::PointCloud{}, 0.1f, 0.01f), std::invalid_argument);
  geometry::PointCloud no_normals;
  no_normals.points = {Eigen::Vector3f::Zero(), Eigen::Vector3f::Ones()};
  EXPECT_THROW(PpfTable(no_normals, 2.0f, 0.1f), std::invalid_argument);
  geometry::PointCloud nan_normal = no_normals;
  nan_normal.normals = {Eigen::Vector3f::UnitX(), Eigen::Vector3f::Constant(std::nanf(""))};
  EXPECT_THROW(PpfTable(nan_normal, 2.0f, 0.1f), std::invalid_argument);
  geometry::PointCloud oversized;
  for (int i = 0; i < 9000; ++i) {
    oversized.points.emplace_back(0.001f * i, 0.0f, 0.0f);
    oversized.normals.push_back(Eigen::Vector3f::UnitZ());
  }
  EXPECT_THROW(PpfTable(oversized, 10.0f, 0.01f), std::invalid_argument);
}

// Voting on a copy of the model moved by a known transform recovers the transform.
TEST(PpfMatchTest, FindsMovedBox) {
  const geometry::PointCloud box = BoxSurface(0.12f, 0.07f, 0.04f, 0.005f);
  const float diameter = std::sqrt(0.12f * 0.12f + 0.07f * 0.07f + 0.04f * 0.04f) + 1e-3f;
  const PpfTable table(box, diameter, 0.005f);
  std::mt19937 rng(5);
  for (int trial = 0; trial < 3; ++trial) {
    const Eigen::Isometry3d X = testing::RandomPose(&rng, 0.3);
    const geometry::PointCloud scene = testing::Transformed(box, X);
    const KdTree tree(scene.points);
    PpfMatchOptions options;
    options.reference_step = 3;
    const PpfMatchResult result = MatchPpf(table, scene, tree, options);
    ASSERT_FALSE(result.hypotheses.empty());
    // A box has 4 proper symmetries; the best hypothesis maps the box onto itself.
    const Eigen::Isometry3d X_rel = X.inverse() * result.hypotheses.front().X_SceneModel;
    EXPECT_NEAR(X_rel.linear().determinant(), 1.0, 1e-9);
    double worst = 0.0;
    for (const auto& p : box.points) {
      float d2 = 0.0f;
      table.model_tree().Nearest((X_rel.cast<float>() * p), &d2);
      worst = std::max(worst, std::sqrt(static_cast<double>(d2)));
    }
    EXPECT_LT(worst, 0.012) << "trial " << trial;
  }
}

// Skipping duplicate scene pairs only removes look-ups (each skipped pair is counted), still
// finds the pose, and the result does not depend on the number of threads.
TEST(PpfMatchTest, DuplicateSkippingAndThreads) {
  const geometry::PointCloud box = BoxSurface(0.12f, 0.07f, 0.04f, 0.01f);
  const float diameter = std::sqrt(0.12f * 0.12f + 0.07f * 0.07f + 0.04f * 0.04f) + 1e-3f;
  const PpfTable table(box, diameter, 0.01f);
  std::mt19937 rng(23);
  const Eigen::Isometry3d X = testing::RandomPose(&rng, 0.3);
  const geometry::PointCloud scene = testing::Transformed(box, X);
  const KdTree tree(scene.points);
  PpfMatchOptions options;
  options.reference_step = 2;
  options.skip_duplicate_votes = false;
  const PpfMatchResult all = MatchPpf(table, scene, tree, options);
  options.skip_duplicate_votes = true;
  options.num_threads = 1;
  const PpfMatchResult one = MatchPpf(table, scene, tree, options);
  options.num_threads = 3;
  const PpfMatchResult three = MatchPpf(table, scene, tree, options);
  EXPECT_EQ(all.duplicate_pairs, 0);
  EXPECT_GT(one.duplicate_pairs, 0);
  EXPECT_EQ(one.pair_lookups + one.duplicate_pairs, all.pair_lookups);
  EXPECT_LT(one.votes_cast, all.votes_cast);
  ASSERT_EQ(one.hypotheses.size(), three.hypotheses.size());
  for (std::size_t h = 0; h < one.hypotheses.size(); ++h) {
    EXPECT_EQ(one.hypotheses[h].votes, three.hypotheses[h].votes);
    EXPECT_TRUE(one.hypotheses[h].X_SceneModel.isApprox(three.hypotheses[h].X_SceneModel, 1e-12));
  }
  for (const PpfMatchResult* r : {&all, &one}) {
    ASSERT_FALSE(r->hypotheses.empty());
    const Eigen::Isometry3d X_rel = X.inverse() * r->hypotheses.front().X_SceneModel;
    double worst = 0.0;
    for (const auto& p : box.points) {
      float d2 = 0.0f;
      table.model_tree().Nearest((X_rel.cast<float>() * p), &d2);
      worst = std::max(worst, std::sqrt(static_cast<double>(d2)));
    }
    EXPECT_LT(worst, 0.02);
  }
}

// With segments, every segment contributes its own best poses: the target box next to a
// larger, denser box still gets a hypothesis at its pose although the large box's poses
// collect more votes, and the hypotheses come in rounds over the segments.
TEST(PpfMatchTest, SegmentsEachContributeTheirBestPoses) {
  const geometry::PointCloud box = BoxSurface(0.12f, 0.07f, 0.04f, 0.008f);
  const float diameter = std::sqrt(0.12f * 0.12f + 0.07f * 0.07f + 0.04f * 0.04f) + 1e-3f;
  const PpfTable table(box, diameter, 0.008f);
  std::mt19937 rng(31);
  const Eigen::Isometry3d X_target = testing::RandomPose(&rng, 0.05);
  geometry::PointCloud scene = testing::Transformed(box, X_target);
  std::vector<std::int32_t> segments(scene.size(), 7);
  // The neighbour: a larger box 0.2 m away, sampled three times as densely.
  const geometry::PointCloud big = testing::Transformed(
      BoxSurface(0.2f, 0.15f, 0.1f, 0.004f),
      Eigen::Isometry3d(Eigen::Translation3d(0.2, 0.0, 0.0)) * testing::RandomPose(&rng, 0.0));
  scene.points.insert(scene.points.end(), big.points.begin(), big.points.end());
  scene.normals.insert(scene.normals.end(), big.normals.begin(), big.normals.end());
  scene.width = static_cast<std::uint32_t>(scene.size());
  segments.resize(scene.size(), -1);
  const KdTree tree(scene.points);
  PpfMatchOptions options;
  options.reference_step = 2;
  options.max_hypotheses = 4;
  options.segments = segments;
  options.hypotheses_per_segment = 2;
  const PpfMatchResult result = MatchPpf(table, scene, tree, options);
  // Two per segment at most (fewer when a segment's clusters merge as symmetric).
  ASSERT_GE(result.hypotheses.size(), 2u);
  ASSERT_LE(result.hypotheses.size(), 4u);
  EXPECT_FALSE(result.timed_out);
  EXPECT_EQ(result.voted_reference_points, result.reference_points);
  const auto fits_target = [&](const PpfHypothesis& h) {
    const Eigen::Isometry3d X_rel = X_target.inverse() * h.X_SceneModel;
    double worst = 0.0;
    for (const auto& p : box.points) {
      float d2 = 0.0f;
      table.model_tree().Nearest(X_rel.cast<float>() * p, &d2);
      worst = std::max(worst, std::sqrt(static_cast<double>(d2)));
    }
    return worst < 0.02;
  };
  // One of the first round's two hypotheses (one per segment) is the target's pose.
  EXPECT_TRUE(fits_target(result.hypotheses[0]) || fits_target(result.hypotheses[1]));
  EXPECT_NE((result.hypotheses[0].X_SceneModel.translation() -
             result.hypotheses[1].X_SceneModel.translation())
                .norm(),
            0.0);
  // Labels must cover the scene; at least one hypothesis per segment.
  PpfMatchOptions bad = options;
  bad.segments.pop_back();
  EXPECT_THROW(MatchPpf(table, scene, tree, bad), std::invalid_argument);
  bad = options;
  bad.hypotheses_per_segment = 0;
  EXPECT_THROW(MatchPpf(table, scene, tree, bad), std::invalid_argument);
}

// A deadline that has passed (on the options' clock, standing still here) stops the voting
// before any reference point: no hypothesis, and the result says so; without a deadline every
// reference point votes.
TEST(PpfMatchTest, DeadlineStopsTheVoting) {
  const geometry::PointCloud box = BoxSurface(0.12f, 0.07f, 0.04f, 0.01f);
  const float diameter = std::sqrt(0.12f * 0.12f + 0.07f * 0.07f + 0.04f * 0.04f) + 1e-3f;
  const PpfTable table(box, diameter, 0.01f);
  const KdTree tree(box.points);
  PpfMatchOptions options;
  const auto start = std::chrono::steady_clock::time_point(std::chrono::hours(1000));
  options.clock = BudgetClock::Frozen(start);
  options.deadline = start;
  const PpfMatchResult stopped = MatchPpf(table, box, tree, options);
  EXPECT_TRUE(stopped.timed_out);
  EXPECT_EQ(stopped.voted_reference_points, 0);
  EXPECT_GT(stopped.reference_points, 0);
  EXPECT_TRUE(stopped.hypotheses.empty());
  options.deadline = std::chrono::steady_clock::time_point::max();
  const PpfMatchResult full = MatchPpf(table, box, tree, options);
  EXPECT_FALSE(full.timed_out);
  EXPECT_EQ(full.voted_reference_points, full.reference_points);
  EXPECT_FALSE(full.hypotheses.empty());
}

// Planar pairs with a weight in (0, 1) need a table that stores them and still find the box.
TEST(PpfMatchTest, WeightedPlanarPairs) {
  const geometry::PointCloud box = BoxSurface(0.12f, 0.07f, 0.04f, 0.01f);
  const float diameter = std::sqrt(0.12f * 0.12f + 0.07f * 0.07f + 0.04f * 0.04f) + 1e-3f;
  PpfTableOptions table_options;
  table_options.store_planar_pairs = true;
  const PpfTable with_planar(box, diameter, 0.01f, table_options);
  const PpfTable without(box, diameter, 0.01f);
  EXPECT_GT(with_planar.entries().size(), without.entries().size());
  std::mt19937 rng(29);
  const Eigen::Isometry3d X = testing::RandomPose(&rng, 0.3);
  const geometry::PointCloud scene = testing::Transformed(box, X);
  const KdTree tree(scene.points);
  PpfMatchOptions options;
  options.reference_step = 2;
  options.planar_pair_weight = 0.25f;
  const PpfMatchResult r = MatchPpf(with_planar, scene, tree, options);
  ASSERT_FALSE(r.hypotheses.empty());
  const Eigen::Isometry3d X_rel = X.inverse() * r.hypotheses.front().X_SceneModel;
  double worst = 0.0;
  for (const auto& p : box.points) {
    float d2 = 0.0f;
    with_planar.model_tree().Nearest((X_rel.cast<float>() * p), &d2);
    worst = std::max(worst, std::sqrt(static_cast<double>(d2)));
  }
  EXPECT_LT(worst, 0.02);
  options.planar_pair_weight = 1.5f;
  EXPECT_THROW(MatchPpf(with_planar, scene, tree, options), std::invalid_argument);
}

// The grid-accelerated clustering equals the plain greedy scan over the clusters.
TEST(PpfClusterTest, MatchesLinearGreedyClustering) {
  std::mt19937 rng(31);
  std::uniform_int_distribution<int> pick(0, 19);
  std::uniform_real_distribution<double> vote(1.0, 10.0);
  std::vector<Eigen::Isometry3d> centres;
  for (int c = 0; c < 20; ++c) centres.push_back(testing::RandomPose(&rng, 0.2));
  std::vector<Eigen::Isometry3d> poses;
  std::vector<double> votes;
  for (int i = 0; i < 2000; ++i) {
    poses.push_back(centres[pick(rng)] *
                    testing::Perturbation(&rng, 0.3 * vote(rng) / 10.0, 0.03 * vote(rng) / 10.0));
    votes.push_back(std::round(vote(rng)));  // ties exercise the stable order
  }
  const double t_max = 0.02, r_max = 0.25;
  const auto clusters = ClusterPoses(poses, votes, t_max, r_max);
  // Reference: visit by decreasing votes (stable), join the first cluster in creation order.
  std::vector<std::size_t> order(poses.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t a, std::size_t b) { return votes[a] > votes[b]; });
  std::vector<Eigen::Isometry3d> firsts;
  std::vector<double> weights;
  for (std::size_t idx : order) {
    std::size_t c = 0;
    while (c < firsts.size() &&
           !((firsts[c].translation() - poses[idx].translation()).norm() < t_max &&
             RotationAngle(firsts[c].linear(), poses[idx].linear()) < r_max)) {
      ++c;
    }
    if (c == firsts.size()) {
      firsts.push_back(poses[idx]);
      weights.push_back(0.0);
    }
    weights[c] += votes[idx];
  }
  ASSERT_EQ(clusters.size(), firsts.size());
  std::vector<double> got, expected = weights;
  for (const auto& c : clusters) got.push_back(c.votes);
  std::sort(got.begin(), got.end());
  std::sort(expected.begin(), expected.end());
  for (std::size_t i = 0; i < got.size(); ++i) EXPECT_NEAR(got[i], expected[i], 1e-9);
  EXPECT_GT(clusters.size(), 20u);
}

TEST(PpfClusterTest, MergesNearbyPosesWithWeightedMean) {
  Eigen::Isometry3d a = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d b = a;
  b.translation() = Eigen::Vector3d(0.01, 0, 0);
  b.linear() = Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  Eigen::Isometry3d far = a;
  far.translation() = Eigen::Vector3d(1, 0, 0);
  const auto clusters = ClusterPoses({a, b, far}, {3.0, 1.0, 2.0}, 0.05, 0.3);
  ASSERT_EQ(clusters.size(), 2u);
  EXPECT_DOUBLE_EQ(clusters[0].votes, 4.0);
  EXPECT_EQ(clusters[0].num_poses, 2);
  EXPECT_NEAR(clusters[0].X_SceneModel.translation().x(), 0.0025, 1e-9);
  EXPECT_NEAR(Eigen::AngleAxisd(clusters[0].X_SceneModel.linear()).angle(), 0.025, 1e-3);
  EXPECT_NEAR(clusters[0].X_SceneModel.linear().determinant(), 1.0, 1e-12);
  EXPECT_DOUBLE_EQ(clusters[1].votes, 2.0);
}

}  // namespace
}  // namespace picking::detector
