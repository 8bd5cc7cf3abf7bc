#include "services/detector/core/kdtree.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <random>

namespace picking::detector {
namespace {

std::vector<Eigen::Vector3f> RandomPoints(std::mt19937* rng, int n) {
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::vector<Eigen::Vector3f> pts(n);
  for (auto& p : pts) p = Eigen::Vector3f(u(*rng), u(*rng), 0.2f * u(*rng));
  return pts;
}

TEST(KdTreeTest, NearestAndRadiusMatchBruteForce) {
  std::mt19937 rng(7);
  const auto pts = RandomPoints(&rng, 3000);
  const KdTree tree(pts, 8);
  const auto queries = RandomPoints(&rng, 200);
  std::vector<std::int32_t> found;
  for (const auto& q : queries) {
    std::int32_t best = 0;
    for (std::int32_t i = 1; i < static_cast<std::int32_t>(pts.size()); ++i) {
      if ((pts[i] - q).squaredNorm() < (pts[best] - q).squaredNorm()) best = i;
    }
    float d2 = -1.0f;
    EXPECT_EQ(tree.Nearest(q, &d2), best);
    EXPECT_FLOAT_EQ(d2, (pts[best] - q).squaredNorm());

    tree.RadiusSearch(q, 0.15f, &found);
    std::vector<std::int32_t> expected;
    for (std::int32_t i = 0; i < static_cast<std::int32_t>(pts.size()); ++i) {
      if ((pts[i] - q).norm() <= 0.15f) expected.push_back(i);
    }
    std::sort(found.begin(), found.end());
    EXPECT_EQ(found, expected);
  }
}

TEST(KdTreeTest, MaxDistanceLimitsNearest) {
  const KdTree tree({Eigen::Vector3f(1, 0, 0), Eigen::Vector3f(0, 2, 0)});
  EXPECT_EQ(tree.Nearest(Eigen::Vector3f::Zero(), nullptr, 0.5f), KdTree::kNone);
  EXPECT_EQ(tree.Nearest(Eigen::Vector3f::Zero(), nullptr, 1.5f), 0);
}

TEST(KdTreeTest, DuplicatePointsAndEmptyTree) {
  const KdTree tree(std::vector<Eigen::Vector3f>(100, Eigen::Vector3f(1, 1, 1)), 4);
  std::vector<std::int32_t> found;
  tree.RadiusSearch(Eigen::Vector3f(1, 1, 1), 0.0f, &found);
  EXPECT_EQ(found.size(), 100u);
  const KdTree empty;
  EXPECT_EQ(empty.Nearest(Eigen::Vector3f::Zero()), KdTree::kNone);
}

TEST(KdTreeTest, RejectsNonFinitePoints) {
  std::vector<Eigen::Vector3f> pts = {
      Eigen::Vector3f::Zero(), Eigen::Vector3f(std::numeric_limits<float>::quiet_NaN(), 0, 0)};
  EXPECT_THROW(KdTree{pts}, std::invalid_argument);
}

}  // namespace
}  // namespace picking::detector
