#include "libs/world/mesh_utils.h"

#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <set>

namespace picking::world {
namespace {

// Every edge of a closed, consistently wound mesh appears once in each direction (after
// welding coincident vertices).
bool IsClosedAndConsistent(const TriangleMesh& mesh) {
  std::map<std::array<float, 3>, std::uint32_t> weld;
  std::vector<std::uint32_t> id(mesh.vertices.size());
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    const auto& v = mesh.vertices[i];
    const std::array<float, 3> key = {std::round(v.x() * 1e5f) / 1e5f,
                                      std::round(v.y() * 1e5f) / 1e5f,
                                      std::round(v.z() * 1e5f) / 1e5f};
    id[i] = weld.emplace(key, static_cast<std::uint32_t>(weld.size())).first->second;
  }
  std::map<std::pair<std::uint32_t, std::uint32_t>, int> edges;
  for (const auto& t : mesh.triangles) {
    for (int k = 0; k < 3; ++k) {
      const auto a = id[t[k]], b = id[t[(k + 1) % 3]];
      if (a != b) ++edges[{a, b}];
    }
  }
  for (const auto& [e, n] : edges) {
    if (n != 1) return false;
    const auto it = edges.find({e.second, e.first});
    if (it == edges.end() || it->second != 1) return false;
  }
  return true;
}

TEST(MeshUtilsTest, BoxIsClosedOutwardAndHasTheRightVolume) {
  const TriangleMesh box = MakeBox({0.3, 0.2, 0.1});
  EXPECT_EQ(box.num_triangles(), 12u);
  EXPECT_NEAR(SignedVolume(box), 0.006, 1e-9);
  EXPECT_NEAR(SurfaceArea(box), 2 * (0.06 + 0.03 + 0.02), 1e-7);
  EXPECT_TRUE(IsClosedAndConsistent(box));
  // Each face normal points away from the centre.
  for (std::size_t t = 0; t < box.num_triangles(); ++t) {
    const Eigen::Vector3f c = box.vertices[box.triangles[t][0]];
    EXPECT_GT(FaceNormal(box, t).dot(c), 0.0f);
  }
  const auto b = Bounds(box);
  EXPECT_TRUE(b.min().isApprox(Eigen::Vector3d(-0.15, -0.1, -0.05), 1e-6));
  EXPECT_TRUE(b.max().isApprox(Eigen::Vector3d(0.15, 0.1, 0.05), 1e-6));
}

TEST(MeshUtilsTest, CylinderAndSphereVolumesConvergeToTheFormulas) {
  const double r = 0.05, h = 0.2;
  const TriangleMesh cyl = MakeCylinder(r, h, 128);
  EXPECT_TRUE(IsClosedAndConsistent(cyl));
  EXPECT_NEAR(SignedVolume(cyl), M_PI * r * r * h, 0.002 * M_PI * r * r * h);
  const TriangleMesh sphere = MakeSphere(r, 64, 128);
  EXPECT_TRUE(IsClosedAndConsistent(sphere));
  EXPECT_NEAR(SignedVolume(sphere), 4.0 / 3.0 * M_PI * r * r * r,
              0.005 * 4.0 / 3.0 * M_PI * r * r * r);
  for (const auto& v : sphere.vertices) EXPECT_NEAR(v.norm(), r, 1e-6);
}

TEST(MeshUtilsTest, TransformKeepsVolumeAndMovesBounds) {
  const TriangleMesh box = MakeBox({0.1, 0.1, 0.1});
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translate(Eigen::Vector3d(1.0, 2.0, 3.0));
  X.rotate(Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()));
  const TriangleMesh moved = Transformed(box, X);
  EXPECT_NEAR(SignedVolume(moved), 0.001, 1e-8);
  EXPECT_TRUE(Bounds(moved).center().isApprox(Eigen::Vector3d(1, 2, 3), 1e-6));
  const auto b1 = Bounds(moved);
  const auto b2 = Bounds(box, X);
  EXPECT_TRUE(b1.min().isApprox(b2.min(), 1e-5));
  EXPECT_TRUE(b1.max().isApprox(b2.max(), 1e-5));
}

TEST(MeshUtilsTest, MergeOffsetsIndicesAndFillsAlbedo) {
  TriangleMesh a = MakeBox({0.1, 0.1, 0.1});
  a.albedo = 0.2f;
  TriangleMesh b = MakeSphere(0.05, 4, 8);
  b.vertex_albedo.assign(b.vertices.size(), 0.9f);
  const TriangleMesh m = Merge({a, b});
  EXPECT_EQ(m.vertices.size(), a.vertices.size() + b.vertices.size());
  EXPECT_EQ(m.num_triangles(), a.num_triangles() + b.num_triangles());
  ASSERT_EQ(m.vertex_albedo.size(), m.vertices.size());
  EXPECT_FLOAT_EQ(m.vertex_albedo.front(), 0.2f);
  EXPECT_FLOAT_EQ(m.vertex_albedo.back(), 0.9f);
  EXPECT_NO_THROW(Validate(m));
  EXPECT_EQ(m.triangles.back()[0] >= a.vertices.size(), true);
}

TEST(MeshUtilsTest, BadInputIsRejectedWithAClearMessage) {
  EXPECT_THROW(MakeBox({0.1, -0.1, 0.1}), std::invalid_argument);
  EXPECT_THROW(MakeBox({0.1, NAN, 0.1}), std::invalid_argument);
  EXPECT_THROW(MakeCylinder(0.1, 0.1, 2), std::invalid_argument);
  EXPECT_THROW(MakeSphere(0.0), std::invalid_argument);
  TriangleMesh bad = MakeBox({0.1, 0.1, 0.1});
  bad.name = "broken";
  bad.triangles.push_back({0, 1, 99});
  try {
    Validate(bad);
    FAIL() << "no throw";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("broken"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("99"), std::string::npos);
  }
}

}  // namespace
}  // namespace picking::world
