#include "libs/ur10/ur10_model.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace picking::ur10 {
namespace {

constexpr double kPi = 3.14159265358979323846;
const std::string kDataDir = std::string(PICKING_DATA_DIR) + "/ur10";

TEST(Ur10ModelTest, LoadsFactoryDhParameters) {
  const Ur10Model model = Ur10Model::Load(kDataDir);
  EXPECT_DOUBLE_EQ(model.dh().d1, 0.1273);
  EXPECT_DOUBLE_EQ(model.dh().a2, -0.612);
  EXPECT_DOUBLE_EQ(model.dh().a3, -0.5723);
  EXPECT_DOUBLE_EQ(model.dh().d4, 0.163941);
  EXPECT_DOUBLE_EQ(model.dh().d5, 0.1157);
  EXPECT_DOUBLE_EQ(model.dh().d6, 0.0922);
}

TEST(Ur10ModelTest, LoadsLimitsWithDegreesTag) {
  const Ur10Model model = Ur10Model::Load(kDataDir);
  // shoulder_pan: +-360 deg, 120 deg/s; elbow: +-180 deg, 180 deg/s.
  EXPECT_NEAR(model.limits()[0].min_position_rad, -2 * kPi, 1e-12);
  EXPECT_NEAR(model.limits()[0].max_position_rad, 2 * kPi, 1e-12);
  EXPECT_NEAR(model.limits()[0].max_velocity_rad_s, 120.0 * kPi / 180.0, 1e-12);
  EXPECT_NEAR(model.limits()[1].max_velocity_rad_s, 120.0 * kPi / 180.0, 1e-12);
  EXPECT_NEAR(model.limits()[2].min_position_rad, -kPi, 1e-12);
  EXPECT_NEAR(model.limits()[2].max_position_rad, kPi, 1e-12);
  for (int j = 2; j < kNumJoints; ++j) {
    EXPECT_NEAR(model.limits()[j].max_velocity_rad_s, kPi, 1e-12) << kJointNames[j];
  }
  EXPECT_DOUBLE_EQ(model.limits()[0].max_effort_nm, 330.0);
  EXPECT_DOUBLE_EQ(model.limits()[5].max_effort_nm, 56.0);
  for (int j = 0; j < kNumJoints; ++j) {
    EXPECT_DOUBLE_EQ(model.limits()[j].max_acceleration_rad_s2, 2.5);
  }
  Ur10ModelOptions options;
  options.max_acceleration_rad_s2 = 1.2;
  EXPECT_DOUBLE_EQ(Ur10Model::Load(kDataDir, options).max_acceleration_rad_s2()[3], 1.2);
}

TEST(Ur10ModelTest, YamlChainMatchesDhDerivedChain) {
  const Ur10Model loaded = Ur10Model::Load(kDataDir);
  const Ur10Model from_dh(loaded.dh(), loaded.limits());
  for (int i = 0; i < kNumLinks; ++i) {
    const Link link = static_cast<Link>(i);
    EXPECT_TRUE(loaded.X_ParentLink(link).isApprox(from_dh.X_ParentLink(link), 1e-9))
        << LinkName(link);
  }
}

TEST(Ur10ModelTest, LoadsEveryCollisionMesh) {
  const Ur10Model model = Ur10Model::Load(kDataDir);
  for (int i = 0; i < kNumLinks; ++i) {
    const Link link = static_cast<Link>(i);
    const world::TriangleMesh mesh = model.LoadCollisionMesh(link);
    EXPECT_EQ(mesh.name, LinkName(link));
    ASSERT_GT(mesh.num_triangles(), 100u) << LinkName(link);
    Eigen::Vector3f lo = mesh.vertices[0], hi = mesh.vertices[0];
    for (const auto& v : mesh.vertices) {
      lo = lo.cwiseMin(v);
      hi = hi.cwiseMax(v);
    }
    for (const auto& t : mesh.triangles) {
      for (auto index : t) ASSERT_LT(index, mesh.vertices.size());
    }
    // Metres: every UR10 link fits in a 0.8 m cube and is thicker than 3 cm.
    const Eigen::Vector3f size = hi - lo;
    EXPECT_LT(size.maxCoeff(), 0.8f) << LinkName(link);
    EXPECT_GT(size.maxCoeff(), 0.03f) << LinkName(link);
  }
  // The upper arm is the longest link (0.612 m between the joint axes).
  const world::TriangleMesh upper = model.LoadCollisionMesh(Link::kUpperArm);
  Eigen::Vector3f lo = upper.vertices[0], hi = upper.vertices[0];
  for (const auto& v : upper.vertices) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  EXPECT_GT((hi - lo).maxCoeff(), 0.6f);
}

class TempDir {
 public:
  TempDir() {
    path_ =
        std::filesystem::temp_directory_path() /
        ("ur10_model_test_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) +
         "_" + ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::remove_all(path_);
    std::filesystem::create_directories(path_);
    for (const char* f : {"default_kinematics.yaml", "physical_parameters.yaml",
                          "joint_limits.yaml", "visual_parameters.yaml"}) {
      std::filesystem::copy_file(kDataDir + "/" + f, path_ / f);
    }
  }
  ~TempDir() { std::filesystem::remove_all(path_); }
  std::string path() const { return path_.string(); }
  void Replace(const std::string& file, const std::string& from, const std::string& to) {
    std::ifstream in(path_ / file);
    std::stringstream ss;
    ss << in.rdbuf();
    std::string text = ss.str();
    const auto pos = text.find(from);
    ASSERT_NE(pos, std::string::npos);
    text.replace(pos, from.size(), to);
    std::ofstream(path_ / file) << text;
  }

 private:
  std::filesystem::path path_;
};

std::string LoadError(const std::string& dir) {
  try {
    Ur10Model::Load(dir);
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "";
}

TEST(Ur10ModelTest, MissingFieldNamesFileAndField) {
  TempDir dir;
  dir.Replace("physical_parameters.yaml", "a3: -0.5723", "a7: -0.5723");
  const std::string error = LoadError(dir.path());
  EXPECT_NE(error.find("physical_parameters.yaml"), std::string::npos) << error;
  EXPECT_NE(error.find("dh_parameters.a3"), std::string::npos) << error;
}

TEST(Ur10ModelTest, UnknownTagIsRejected) {
  TempDir dir;
  dir.Replace("joint_limits.yaml", "max_velocity: !degrees  120.0", "max_velocity: !grads 120.0");
  const std::string error = LoadError(dir.path());
  EXPECT_NE(error.find("joint_limits.yaml"), std::string::npos) << error;
  EXPECT_NE(error.find("!grads"), std::string::npos) << error;
}

TEST(Ur10ModelTest, NonNumberIsRejectedWithLine) {
  TempDir dir;
  dir.Replace("physical_parameters.yaml", "d1: 0.1273", "d1: tall");
  const std::string error = LoadError(dir.path());
  EXPECT_NE(error.find("physical_parameters.yaml:4"), std::string::npos) << error;
  EXPECT_NE(error.find("tall"), std::string::npos) << error;
}

TEST(Ur10ModelTest, MissingDirectoryIsAnError) {
  EXPECT_NE(LoadError("/nonexistent/ur10").find("cannot read"), std::string::npos);
}

TEST(Ur10ModelTest, ConstructorValidates) {
  const Ur10Model model = Ur10Model::Load(kDataDir);
  auto limits = model.limits();
  limits[3].max_velocity_rad_s = 0.0;
  EXPECT_THROW(Ur10Model(model.dh(), limits), std::invalid_argument);
  limits = model.limits();
  limits[1].min_position_rad = limits[1].max_position_rad;
  EXPECT_THROW(Ur10Model(model.dh(), limits), std::invalid_argument);
  DhParameters dh = model.dh();
  dh.d4 = std::nan("");
  EXPECT_THROW(Ur10Model(dh, model.limits()), std::invalid_argument);
  Ur10Model copy = model;
  limits = model.limits();
  limits[0].max_acceleration_rad_s2 = -1.0;
  EXPECT_THROW(copy.set_limits(limits), std::invalid_argument);
  EXPECT_DOUBLE_EQ(copy.limits()[0].max_acceleration_rad_s2, 2.5);  // unchanged
}

TEST(Ur10ModelTest, WithinPositionLimits) {
  const Ur10Model model = Ur10Model::Load(kDataDir);
  JointVector q = JointVector::Zero();
  EXPECT_TRUE(model.WithinPositionLimits(q));
  q[2] = 3.2;  // elbow beyond pi
  EXPECT_FALSE(model.WithinPositionLimits(q));
  EXPECT_NE(model.PositionLimitViolation(q).find("joint elbow_joint at 3.2 rad"), std::string::npos)
      << model.PositionLimitViolation(q);
  q[2] = 0.0;
  q[0] = std::nan("");
  EXPECT_FALSE(model.WithinPositionLimits(q));
  EXPECT_NE(model.PositionLimitViolation(q).find("shoulder_pan"), std::string::npos);
  EXPECT_EQ(model.PositionLimitViolation(JointVector::Zero()), "");
}

TEST(StlTest, ReadsAsciiStl) {
  const auto path = std::filesystem::temp_directory_path() / "ur10_ascii_test.stl";
  std::ofstream(path) << "solid t\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n"
                         "   vertex 1 0 0\n   vertex 0 1 0\n  endloop\n endfacet\n"
                         " facet normal 0 0 1\n  outer loop\n   vertex 1 0 0\n"
                         "   vertex 1 1 0\n   vertex 0 1 0\n  endloop\n endfacet\nendsolid t\n";
  const world::TriangleMesh mesh = ReadStl(path.string());
  EXPECT_EQ(mesh.num_triangles(), 2u);
  EXPECT_EQ(mesh.vertices.size(), 4u);  // shared vertices merged
  std::filesystem::remove(path);
}

TEST(StlTest, RejectsGarbage) {
  const auto path = std::filesystem::temp_directory_path() / "ur10_garbage_test.stl";
  std::ofstream(path) << "not an stl";
  EXPECT_THROW(ReadStl(path.string()), std::runtime_error);
  std::filesystem::remove(path);
  EXPECT_THROW(ReadStl("/nonexistent.stl"), std::runtime_error);
}

}  // namespace
}  // namespace picking::ur10
