#include "services/detector/core/ppf.h"

#include <gtest/gtest.h>

#include <cmath>
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
      const Eigen::Vector4f f =
          ComputePpf(box.points[i], box.normals[i], box.points[j], box.normals[j]);
      std::uint32_t key = 0;
      if (!q.Key(f, &key) || q.IsPlanar(f)) continue;
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
