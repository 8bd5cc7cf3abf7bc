#include <gtest/gtest.h>

#include <cstring>

#include "libs/world/stl_io.h"
#include "services/viewer/core/test/viewer_fixture.h"

namespace picking::viewer {
namespace {

Eigen::Matrix4d MatrixFromJson(const nlohmann::json& j) {
  Eigen::Matrix4d m;
  for (int c = 0; c < 4; ++c) {
    for (int r = 0; r < 4; ++r) m(r, c) = j.at(4 * c + r).get<double>();
  }
  return m;
}

TEST(ViewerModelTest, PosesAreColumnMajorMatrices) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(1, 2, 3);
  X.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  const nlohmann::json j = PoseJson(X);
  ASSERT_EQ(j.size(), 16u);
  EXPECT_DOUBLE_EQ(j[12].get<double>(), 1.0);  // translation in the last column
  EXPECT_DOUBLE_EQ(j[14].get<double>(), 3.0);
  EXPECT_TRUE(MatrixFromJson(j).isApprox(X.matrix()));
}

TEST(ViewerModelTest, TheCellListsEveryBinAndLinkWithServedMeshes) {
  const ViewerModel& model = BundledModel();
  const nlohmann::json cell = model.CellJson();
  ASSERT_EQ(cell["bins"].size(), 12u);
  EXPECT_EQ(cell["bins"][0]["name"], "bin_A");
  ASSERT_EQ(cell["arm"]["links"].size(), 7u);
  for (const nlohmann::json& link : cell["arm"]["links"]) {
    const auto file = model.File(link["mesh"].get<std::string>());
    ASSERT_TRUE(file.has_value()) << link["mesh"];
    EXPECT_GT(file->bytes.size(), 84u);
  }
  EXPECT_TRUE(model.File(cell["shelf"]["mesh"].get<std::string>()).has_value());
  // A bin's centre lies in the shelf's bounds: in front of the robot, within reach.
  const Eigen::Matrix4d X_BaseBin = MatrixFromJson(cell["bins"][4]["X"]);
  const Eigen::Vector3d p_BaseBin = X_BaseBin.col(3).head<3>();
  EXPECT_LT(p_BaseBin.head<2>().norm(), 2.0);
}

TEST(ViewerModelTest, OnlyTheCellsArmsAndItemsFilesAreServed) {
  const ViewerModel& model = BundledModel();
  EXPECT_FALSE(model.File("/files/../../etc/passwd").has_value());
  EXPECT_FALSE(model.File("/files/cell/default_cell.yaml").has_value());
  EXPECT_FALSE(model.File("/files/items/no_such_item.stl").has_value());
  EXPECT_FALSE(model.File("/files/items/.stl").has_value());
  const auto item = model.File("/files/items/kleenex_tissue_box.stl");
  ASSERT_TRUE(item.has_value());
  // A binary STL: 80-byte header, the count, 50 bytes a triangle.
  std::uint32_t count = 0;
  std::memcpy(&count, item->bytes.data() + 80, 4);
  EXPECT_GT(count, 0u);
  EXPECT_EQ(item->bytes.size(), 84u + 50u * count);
}

TEST(ViewerModelTest, TheArmEndsWhereTheRobotSaysItsToolCentrePointIs) {
  const ViewerModel& model = BundledModel();
  ur10::JointVector q;
  q << 0.1, -1.2, 1.4, -1.8, -1.57, 0.3;
  const std::vector<Eigen::Vector3d> path =
      model.TcpPath({{0.1, -1.2, 1.4, -1.8, -1.57, 0.3}}, 0.0);
  ASSERT_EQ(path.size(), 1u);
  const nlohmann::json arm = model.ArmJson(q, path[0]);
  ASSERT_EQ(arm["links"].size(), 7u);
  const nlohmann::json& last = arm["gripper"].back()["to"];
  EXPECT_NEAR((Eigen::Vector3d(last[0], last[1], last[2]) - path[0]).norm(), 0.0, 1e-9);
  // The tube starts at the flange: wrist 3's frame origin region, not at the base.
  const nlohmann::json& first = arm["gripper"][0]["from"];
  EXPECT_GT(Eigen::Vector3d(first[0], first[1], first[2]).norm(), 0.3);
}

TEST(ViewerModelTest, ABentHeadMovesTheToolCentrePointOfAPath) {
  const ViewerModel& model = BundledModel();
  const std::array<double, 6> q = {0.1, -1.2, 1.4, -1.8, -1.57, 0.3};
  const Eigen::Vector3d straight = model.TcpPath({q}, 0.0)[0];
  const Eigen::Vector3d bent = model.TcpPath({q}, 1.2)[0];
  EXPECT_GT((straight - bent).norm(), 0.03);  // a 9 cm head turned by 69 degrees
}

TEST(ViewerModelTest, ADetectionCarriesItsModelAndBounds) {
  const ViewerModel& model = BundledModel();
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(1.0, 0.1, 0.8);
  const nlohmann::json d = model.DetectionJson("kleenex_tissue_box", X, 0.7, "ppf");
  EXPECT_EQ(d["model"], "/files/items/kleenex_tissue_box.stl");
  EXPECT_GT(d["box_m"][0].get<double>(), 0.1);  // a tissue box is over 10 cm long
  EXPECT_EQ(d["method"], "ppf");
  const nlohmann::json unknown = model.DetectionJson("not_an_item", X, 0.1, "sift");
  EXPECT_TRUE(unknown["model"].is_null());
}

}  // namespace
}  // namespace picking::viewer
