#include "libs/world/cell_config.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <limits>

#include "libs/world/mesh_utils.h"
#include "libs/world/ray_scene.h"

namespace picking::world {
namespace {

const std::string kDataDir = PICKING_DATA_DIR;

std::string Replace(std::string s, const std::string& from, const std::string& to) {
  const auto pos = s.find(from);
  EXPECT_NE(pos, std::string::npos) << from;
  return s.replace(pos, from.size(), to);
}

std::string ValidYaml() {
  return R"(version: 1
robot_base:
  X_WorldBase: {position: [0, 0, 0.7], orientation: [1, 0, 0, 0]}
shelf:
  X_BaseShelf: {position: [1.25, 0, -0.7], orientation: [0, 0, 0, 1]}
  mesh: apc2016/shelf/pod_lowres.stl
tote:
  X_BaseTote: {position: [0.2, -0.75, -0.7], orientation: [1, 0, 0, 0]}
  mesh: apc2016/shelf/tote_delft.stl
table:
  X_BaseTable: {position: [0.2, 0.8, -0.2], orientation: [1, 0, 0, 0]}
  size_m: [0.6, 0.6, 0.5]
gripper:
  X_ToolTcp: {position: [0, 0, 0.35], orientation: [1, 0, 0, 0]}
  tube_radius_m: 0.02
  cup_length_m: 0.02
)";
}

// ValidYaml() with the gripper section's three entries replaced.
std::string WithGripper(const std::string& pose, const std::string& radius,
                        const std::string& cup) {
  std::string yaml =
      Replace(ValidYaml(), "{position: [0, 0, 0.35], orientation: [1, 0, 0, 0]}", pose);
  yaml = Replace(yaml, "tube_radius_m: 0.02", "tube_radius_m: " + radius);
  return Replace(yaml, "cup_length_m: 0.02", "cup_length_m: " + cup);
}

std::string FieldOfError(const std::string& yaml) {
  try {
    ParseCellConfig(yaml, "test.yaml", kDataDir);
  } catch (const CellConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("test.yaml"), std::string::npos) << e.what();
    return e.field();
  }
  return "<no error>";
}

TEST(CellConfigTest, ParsesPosesAndResolvesPaths) {
  const CellConfig c = ParseCellConfig(ValidYaml(), "test.yaml", kDataDir);
  EXPECT_NEAR(c.floor_z_m(), -0.7, 1e-12);
  EXPECT_TRUE(c.X_BaseShelf.translation().isApprox(Eigen::Vector3d(1.25, 0, -0.7)));
  // Turned by 180 degrees about z: the shelf's +x (bin openings) faces the robot.
  EXPECT_TRUE(
      (c.X_BaseShelf.linear() * Eigen::Vector3d::UnitX()).isApprox(-Eigen::Vector3d::UnitX()));
  EXPECT_TRUE(std::filesystem::exists(c.shelf_mesh_path));
  EXPECT_TRUE(c.table_size_m.isApprox(Eigen::Vector3d(0.6, 0.6, 0.5)));
}

TEST(CellConfigTest, ErrorsNameTheField) {
  EXPECT_EQ(
      FieldOfError(Replace(ValidYaml(), "orientation: [0, 0, 0, 1]", "orientation: [0, 0, 0, 2]")),
      "shelf.X_BaseShelf.orientation");
  EXPECT_EQ(FieldOfError(Replace(ValidYaml(), "[0.2, -0.75, -0.7]", "[0.2, -0.75]")),
            "tote.X_BaseTote.position");
  EXPECT_EQ(FieldOfError(Replace(ValidYaml(), "[0.6, 0.6, 0.5]", "[0.6, -0.6, 0.5]")),
            "table.size_m[1]");
  EXPECT_EQ(FieldOfError(Replace(ValidYaml(), "[0.6, 0.6, 0.5]", "[0.6, abc, 0.5]")),
            "table.size_m[1]");
  EXPECT_EQ(FieldOfError(Replace(ValidYaml(), "tote_delft.stl", "missing.stl")), "tote.mesh");
  EXPECT_EQ(FieldOfError(Replace(ValidYaml(), "  size_m:", "  colour: red\n  size_m:")),
            "table.colour");
  EXPECT_EQ(FieldOfError(Replace(ValidYaml(), "version: 1", "version: 2")), "version");
  EXPECT_EQ(
      FieldOfError(Replace(
          ValidYaml(),
          "robot_base:\n  X_WorldBase: {position: [0, 0, 0.7], orientation: [1, 0, 0, 0]}\n", "")),
      "robot_base");
  EXPECT_EQ(FieldOfError("version: 1\n  bad: [indent\n"), "");
  EXPECT_THROW(ReadCellConfig(kDataDir + "/cell/no_such_file.yaml"), CellConfigError);
}

TEST(CellConfigTest, ParsesTheGripper) {
  const CellConfig c = ParseCellConfig(
      WithGripper("{position: [0.01, 0, 0.3], orientation: [0.7071068, 0.7071068, 0, 0]}", "0.025",
                  "0"),
      "test.yaml", kDataDir);
  EXPECT_TRUE(c.gripper.X_ToolTcp.translation().isApprox(Eigen::Vector3d(0.01, 0.0, 0.3)));
  // A quarter turn about x: the TCP's z axis along -y of the flange; normalised on reading.
  EXPECT_TRUE((c.gripper.X_ToolTcp.linear() * Eigen::Vector3d::UnitZ())
                  .isApprox(-Eigen::Vector3d::UnitY(), 1e-6));
  EXPECT_NEAR(c.gripper.X_ToolTcp.linear().determinant(), 1.0, 1e-12);
  EXPECT_EQ(c.gripper.tube_radius_m, 0.025);
  EXPECT_EQ(c.gripper.cup_length_m, 0.0);
}

TEST(CellConfigTest, GripperErrorsNameTheField) {
  const std::string pose = "{position: [0, 0, 0.35], orientation: [1, 0, 0, 0]}";
  const std::string section =
      "gripper:\n  X_ToolTcp: " + pose + "\n  tube_radius_m: 0.02\n  cup_length_m: 0.02\n";
  EXPECT_EQ(FieldOfError(Replace(ValidYaml(), section, "")), "gripper");
  EXPECT_EQ(FieldOfError(Replace(ValidYaml(), section, "gripper: 0.35\n")), "gripper");
  EXPECT_EQ(FieldOfError(WithGripper("{position: [0, 0, 0.35], orientation: [1, 0, 0, 0.5]}",
                                     "0.02", "0.02")),
            "gripper.X_ToolTcp.orientation");
  EXPECT_EQ(
      FieldOfError(WithGripper("{position: [0, 0.35], orientation: [1, 0, 0, 0]}", "0.02", "0.02")),
      "gripper.X_ToolTcp.position");
  EXPECT_EQ(FieldOfError(
                WithGripper("{position: [0, 0, .nan], orientation: [1, 0, 0, 0]}", "0.02", "0.02")),
            "gripper.X_ToolTcp.position[2]");
  EXPECT_EQ(FieldOfError(WithGripper("[0, 0, 0.35]", "0.02", "0.02")), "gripper.X_ToolTcp");
  EXPECT_EQ(FieldOfError(WithGripper(pose, "0", "0.02")), "gripper.tube_radius_m");
  EXPECT_EQ(FieldOfError(WithGripper(pose, "-0.02", "0.02")), "gripper.tube_radius_m");
  EXPECT_EQ(FieldOfError(WithGripper(pose, "wide", "0.02")), "gripper.tube_radius_m");
  EXPECT_EQ(FieldOfError(WithGripper(pose, "[0.02]", "0.02")), "gripper.tube_radius_m");
  EXPECT_EQ(FieldOfError(WithGripper(pose, "0.02", "-0.01")), "gripper.cup_length_m");
  // The cup cannot be as long as the whole tube (0.35 m from the flange to the TCP).
  EXPECT_EQ(FieldOfError(WithGripper(pose, "0.02", "0.35")), "gripper.cup_length_m");
  EXPECT_EQ(FieldOfError(Replace(ValidYaml(), "  cup_length_m: 0.02\n", "")),
            "gripper.cup_length_m");
  EXPECT_EQ(FieldOfError(
                Replace(ValidYaml(), "  cup_length_m:", "  tube_length_m: 0.35\n  cup_length_m:")),
            "gripper.tube_length_m");
  EXPECT_EQ(FieldOfError(ValidYaml() + "X_ToolTcp: {position: [0, 0, 0.35]}\n"), "X_ToolTcp");
  // The message names the file and the field.
  try {
    ParseCellConfig(WithGripper(pose, "0", "0.02"), "my_cell.yaml", kDataDir);
    ADD_FAILURE() << "no error";
  } catch (const CellConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("my_cell.yaml"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("gripper.tube_radius_m"), std::string::npos) << e.what();
  }
}

TEST(CellConfigTest, DefaultCellLoadsAndItsBinsAreReachable) {
  const CellConfig config = ReadCellConfig(DefaultCellConfigPath());
  // The suction cup's lip 0.35 m along the flange's z axis, turned as the flange.
  EXPECT_TRUE(config.gripper.X_ToolTcp.translation().isApprox(Eigen::Vector3d(0.0, 0.0, 0.35)));
  EXPECT_TRUE(config.gripper.X_ToolTcp.linear().isIdentity());
  EXPECT_EQ(config.gripper.tube_radius_m, 0.02);
  EXPECT_EQ(config.gripper.cup_length_m, 0.02);
  const CellModel cell = LoadCellModel(config);
  ASSERT_EQ(cell.bins.size(), 12u);
  EXPECT_EQ(cell.bin("bin_E").name, "bin_E");
  EXPECT_THROW(cell.bin("bin_Z"), std::invalid_argument);
  // UR10 reach is about 1.3 m from the shoulder (0.1273 m above the base): every bin's opening
  // centre must be within reach, and the shelf must not overlap the robot's base.
  const Eigen::Vector3d p_BaseShoulder(0, 0, 0.1273);
  for (const auto& bin : cell.bins) {
    const Eigen::Vector3d p_ShelfOpening(bin.opening_x_m, bin.inner_S.center().y(),
                                         bin.inner_S.center().z());
    const Eigen::Vector3d p_BaseOpening = config.X_BaseShelf * p_ShelfOpening;
    EXPECT_LT((p_BaseOpening - p_BaseShoulder).norm(), 1.2) << bin.name;
    EXPECT_GT(p_BaseOpening.x(), 0.5) << bin.name;
  }
  // Bin A is the robot's top left: +y and highest.
  const Eigen::Vector3d a = config.X_BaseShelf * cell.bin("bin_A").inner_S.center();
  const Eigen::Vector3d c = config.X_BaseShelf * cell.bin("bin_C").inner_S.center();
  const Eigen::Vector3d l = config.X_BaseShelf * cell.bin("bin_L").inner_S.center();
  EXPECT_GT(a.y(), c.y());
  EXPECT_GT(a.z(), l.z());
  // Tote and table stand on the floor / above it and apart from the shelf.
  const auto tote = Bounds(cell.tote, config.X_BaseTote);
  EXPECT_NEAR(tote.min().z(), config.floor_z_m(), 1e-6);
  const auto shelf = Bounds(cell.shelf, config.X_BaseShelf);
  EXPECT_FALSE(shelf.intersects(tote));
  EXPECT_FALSE(shelf.intersects(Bounds(cell.table, config.X_BaseTable)));
  EXPECT_NEAR(Bounds(cell.table, config.X_BaseTable).min().z(), config.floor_z_m(), 1e-6);
}

// The tote's inner box is where its mesh is: rays from inside the box, over a grid of each
// wall and the floor (6 cm in from the edges, clear of the tote's rounded corners), hit the
// mesh where the box's face is, and the box is open above (nothing between it and the rim).
TEST(CellConfigTest, TheToteBoxIsMeasuredFromItsMesh) {
  const CellModel cell = LoadCellModel(ReadCellConfig(DefaultCellConfigPath()));
  const Eigen::AlignedBox3d& box_T = cell.tote_inner_T();
  ASSERT_FALSE(box_T.isEmpty());
  const Eigen::AlignedBox3d bounds_T = Bounds(cell.tote);
  EXPECT_TRUE(bounds_T.contains(box_T));
  EXPECT_NEAR(box_T.max().z(), bounds_T.max().z(), 1e-9);  // up to the rim
  EXPECT_GT(box_T.sizes().minCoeff(), 0.1);
  RayScene scene;
  scene.Add(0, cell.tote, Eigen::Isometry3d::Identity());
  scene.Commit();
  constexpr double kInf = std::numeric_limits<double>::infinity();
  constexpr double kInset = 0.06;
  int rays = 0;
  for (int axis = 0; axis < 3; ++axis) {
    for (const double sign : {-1.0, 1.0}) {
      if (axis == 2 && sign > 0) continue;  // open at the top
      Eigen::Vector3d direction = Eigen::Vector3d::Zero();
      direction[axis] = sign;
      const int u = (axis + 1) % 3, v = (axis + 2) % 3;
      for (int i = 0; i < 5; ++i) {
        for (int j = 0; j < 5; ++j) {
          Eigen::Vector3d p_T = box_T.center();
          p_T[u] = box_T.min()[u] + kInset + (box_T.sizes()[u] - 2 * kInset) * i / 4.0;
          p_T[v] = box_T.min()[v] + kInset + (box_T.sizes()[v] - 2 * kInset) * j / 4.0;
          const double face = sign > 0 ? box_T.max()[axis] : box_T.min()[axis];
          const auto hit = scene.Cast(p_T, direction, kInf);
          ASSERT_TRUE(hit) << axis << " " << sign << " " << p_T.transpose();
          EXPECT_NEAR(hit->distance_m, std::abs(face - p_T[axis]), 1e-3)
              << "axis " << axis << " sign " << sign << " at " << p_T.transpose();
          ++rays;
        }
      }
    }
  }
  EXPECT_EQ(rays, 125);
  for (int i = 0; i < 5; ++i) {
    Eigen::Vector3d p_T = box_T.center();
    p_T.x() = box_T.min().x() + kInset + (box_T.sizes().x() - 2 * kInset) * i / 4.0;
    EXPECT_FALSE(scene.Cast(p_T, Eigen::Vector3d::UnitZ(), kInf)) << p_T.transpose();
  }
  // A tote mesh without a floor is refused.
  TriangleMesh open;
  open.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  open.triangles = {{0, 1, 2}};
  EXPECT_THROW(MeasureToteInner(open), std::runtime_error);
}

TEST(CellConfigTest, AHeadOnItsJointTurnsTheTcpAboutTheJoint) {
  const std::string head =
      "  cup_length_m: 0.02\n  head_length_m: 0.09\n  max_head_angle_deg: 90\n";
  const CellConfig c =
      ParseCellConfig(Replace(ValidYaml(), "  cup_length_m: 0.02\n", head), "test.yaml", kDataDir);
  const GripperConfig& g = c.gripper;
  EXPECT_EQ(g.head_length_m, 0.09);
  EXPECT_NEAR(g.max_head_angle_rad, M_PI / 2, 1e-12);
  EXPECT_TRUE(g.p_ToolJoint().isApprox(Eigen::Vector3d(0.0, 0.0, 0.26)));
  EXPECT_TRUE(g.X_ToolTcpAt(0.0).isApprox(g.X_ToolTcp));
  // A quarter turn: the lip 0.09 m from the joint along the flange's -y, the cup facing it.
  const Eigen::Isometry3d X_ToolTcp = g.X_ToolTcpAt(M_PI / 2);
  EXPECT_TRUE(X_ToolTcp.translation().isApprox(Eigen::Vector3d(0.0, -0.09, 0.26), 1e-9));
  EXPECT_TRUE((X_ToolTcp.linear() * Eigen::Vector3d::UnitZ()).isApprox(-Eigen::Vector3d::UnitY()));
  // Every angle keeps the lip head_length_m from the joint.
  for (const double a : {-1.2, -0.3, 0.4, 1.5}) {
    EXPECT_NEAR((g.X_ToolTcpAt(a).translation() - g.p_ToolJoint()).norm(), 0.09, 1e-12);
  }
  // A straight gripper has no joint: every angle is the straight tcp.
  const CellConfig straight = ParseCellConfig(ValidYaml(), "test.yaml", kDataDir);
  EXPECT_EQ(straight.gripper.head_length_m, 0.0);
  EXPECT_TRUE(straight.gripper.X_ToolTcpAt(1.0).isApprox(straight.gripper.X_ToolTcp));

  auto with_head = [&](const std::string& length, const std::string& angle) {
    return Replace(ValidYaml(), "  cup_length_m: 0.02\n",
                   "  cup_length_m: 0.02\n  head_length_m: " + length +
                       "\n  max_head_angle_deg: " + angle + "\n");
  };
  EXPECT_EQ(FieldOfError(with_head("0.01", "90")), "gripper.head_length_m");  // inside the cup
  EXPECT_EQ(FieldOfError(with_head("0.4", "90")), "gripper.head_length_m");   // past the flange
  EXPECT_EQ(FieldOfError(with_head("0.09", "-5")), "gripper.max_head_angle_deg");
  EXPECT_EQ(FieldOfError(with_head("0.09", "wide")), "gripper.max_head_angle_deg");
  EXPECT_EQ(FieldOfError(Replace(ValidYaml(), "  cup_length_m: 0.02\n",
                                 "  cup_length_m: 0.02\n  max_head_angle_deg: 90\n")),
            "gripper.max_head_angle_deg");
}

}  // namespace
}  // namespace picking::world
