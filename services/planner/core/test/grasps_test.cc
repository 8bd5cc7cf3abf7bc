#include "services/planner/core/grasps.h"
#include "libs/world/mesh_utils.h"
#include "services/planner/core/grasp_seal.h"

#include <gtest/gtest.h>

#include "services/planner/core/grasp_reach.h"

#include <cstdlib>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <limits>
#include <map>
#include <random>
#include <set>
#include <sstream>
#include <tuple>

#include "libs/world/cell_config.h"
#include "libs/world/item_shapes.h"

namespace picking::planner {
namespace {

const std::string kDataDir = PICKING_DATA_DIR;
constexpr double kDeg = EIGEN_PI / 180.0;

std::string GraspTablePath() { return kDataDir + "/planner/grasps.yaml"; }

// Everything loaded once: the catalogue, the shapes, the grasp table and the cell (measuring
// the bins casts rays through the shelf mesh).
struct Fixture {
  apc::Catalogue catalogue = apc::Catalogue::FromCsvFile(kDataDir + "/apc2016/items/item_data.csv");
  world::ShapeTable shapes =
      world::ShapeTable::FromYamlFile(kDataDir + "/items/shapes.yaml", catalogue);
  GraspTable table = GraspTable::FromYamlFile(GraspTablePath(), catalogue);
  world::CellModel cell =
      world::LoadCellModel(world::ReadCellConfig(world::DefaultCellConfigPath()));
};

const Fixture& F() {
  static const Fixture* fixture = new Fixture();
  return *fixture;
}

Eigen::Vector3d SizeOf(const std::string& item) {
  return world::ModelledSize(F().catalogue.at(item), F().shapes.at(item));
}

Eigen::Isometry3d Pose(const Eigen::Matrix3d& R, const Eigen::Vector3d& p) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = R;
  X.translation() = p;
  return X;
}

Eigen::Matrix3d RotZ(double angle_rad) {
  return Eigen::AngleAxisd(angle_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();
}

// An item resting on its -z face on the floor of a bin, a little behind the opening, its long
// side along the bin's width when it fits (else along the depth), turned by `yaw_jitter_rad`.
Eigen::Isometry3d PlaceInBin(const world::BinGeometry& bin, const Eigen::Vector3d& size,
                             double yaw_jitter_rad) {
  const bool across = size.x() <= bin.width_m() - 0.03;
  const double yaw = (across ? EIGEN_PI / 2.0 : 0.0) + yaw_jitter_rad;
  const Eigen::Matrix3d R_ShelfItem = RotZ(yaw);
  // Extent of the turned item along the shelf's x.
  const double extent_x = (R_ShelfItem.cwiseAbs() * size).x();
  const Eigen::Vector3d p_ShelfItem(bin.opening_x_m - 0.03 - extent_x / 2.0,
                                    bin.inner_S.center().y(),
                                    bin.floor_max_z_m + size.z() / 2.0 + 0.001);
  return F().cell.config.X_BaseShelf * Pose(R_ShelfItem, p_ShelfItem);
}

// An item resting on its -z face at the middle of the tote's floor.
Eigen::Isometry3d PlaceInTote(const GraspContainer& tote, const Eigen::Vector3d& size,
                              double yaw_rad) {
  const Eigen::Vector3d p_ContainerItem(0.0, 0.0,
                                        -tote.inner_size_m.z() / 2.0 + size.z() / 2.0 + 0.001);
  return tote.X_BaseContainer * Pose(RotZ(yaw_rad), p_ContainerItem);
}

// Checks of every candidate: the tcp frame, the pre-grasp, the contact point on the item and
// the sorting.
void ExpectConsistent(const GraspResult& result, const std::string& item,
                      const Eigen::Isometry3d& X_BaseItem, const GraspContainer& container,
                      const GraspOptions& options = {}) {
  const ItemGrasps& grasps = F().table.at(item);
  const double max_angle = container.kind == GraspContainerKind::kOpenTop
                               ? options.max_tote_approach_angle_rad
                               : options.max_approach_angle_rad;
  for (std::size_t i = 0; i < result.candidates.size(); ++i) {
    const GraspCandidate& c = result.candidates[i];
    SCOPED_TRACE(item + " in " + container.name + ", candidate " + std::to_string(i) + " '" +
                 c.surface + "'");
    ASSERT_GE(c.point_index, 0);
    ASSERT_LT(c.point_index, static_cast<int>(grasps.points.size()));
    const SuctionPoint& point = grasps.points[c.point_index];
    // The table's point, or (in a shelf bin) that point moved across its face toward the
    // opening: in the face's plane, the cup on the face.
    Eigen::Vector3d p_ItemPoint = point.p_ItemPoint;
    if (c.surface == point.name + ", toward the opening" ||
        c.surface.rfind(point.name + ", front corner ", 0) == 0) {
      EXPECT_EQ(container.kind, GraspContainerKind::kShelfBin);
      p_ItemPoint = X_BaseItem.inverse() * c.p_BasePoint;
      EXPECT_NEAR((p_ItemPoint - point.p_ItemPoint).dot(point.approach_Item), 0.0, 1e-9);
      const Eigen::Vector3d on_face =
          p_ItemPoint.cwiseAbs() + Eigen::Vector3d::Constant(F().table.cup_diameter_m() / 2.0);
      for (int axis = 0; axis < 3; ++axis) {
        if (std::abs(point.approach_Item[axis]) > 0.5) continue;
        EXPECT_LE(on_face[axis], grasps.size_m[axis] / 2.0 + 1e-9) << axis;
      }
    } else {
      EXPECT_EQ(c.surface, point.name);
    }
    // The tcp sits on the item's suction point, +z_tcp along the approach.
    const Eigen::Vector3d p_BasePoint = X_BaseItem * p_ItemPoint;
    EXPECT_LT((c.X_BaseTcp.translation() - p_BasePoint).norm(), 1e-9);
    EXPECT_LT((c.p_BasePoint - p_BasePoint).norm(), 1e-9);
    const Eigen::Matrix3d R = c.X_BaseTcp.linear();
    EXPECT_LT((R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff(), 1e-9);
    EXPECT_NEAR(R.determinant(), 1.0, 1e-9);
    EXPECT_LT((R.col(2) - c.approach_Base).norm(), 1e-9);
    EXPECT_NEAR(c.approach_Base.norm(), 1.0, 1e-9);
    // The surface approach is the table's, rotated with the item; the tilt is the angle between.
    EXPECT_LT((c.surface_approach_Base - X_BaseItem.linear() * point.approach_Item).norm(), 1e-9);
    EXPECT_NEAR(std::acos(std::clamp(c.approach_Base.dot(c.surface_approach_Base), -1.0, 1.0)),
                c.tilt_rad, 1e-6);
    EXPECT_LE(c.tilt_rad, options.max_tilt_rad + 1e-9);
    // Roll: x_tcp as close as possible to base -z (near-horizontal) or base +x (near-vertical).
    const Eigen::Vector3d z = c.approach_Base;
    const Eigen::Vector3d reference =
        std::abs(z.z()) > std::cos(options.vertical_roll_threshold_rad)
            ? Eigen::Vector3d(Eigen::Vector3d::UnitX())
            : Eigen::Vector3d(-Eigen::Vector3d::UnitZ());
    const Eigen::Vector3d x_expected = (reference - reference.dot(z) * z).normalized();
    EXPECT_LT((R.col(0) - x_expected).norm(), 1e-9);
    EXPECT_TRUE(c.roll_symmetric);
    // The pre-grasp is the grasp moved back along the approach by the standoff.
    EXPECT_LT((c.X_BaseTcpPreGrasp.linear() - R).cwiseAbs().maxCoeff(), 1e-12);
    EXPECT_LT((c.X_BaseTcpPreGrasp.translation() -
               (p_BasePoint - options.pregrasp_standoff_m * c.approach_Base))
                  .norm(),
              1e-9);
    // Approaches through the opening.
    const double angle =
        std::acos(std::clamp((-c.approach_Base).dot(container.opening_direction_Base), -1.0, 1.0));
    EXPECT_NEAR(c.approach_angle_rad, angle, 1e-9);
    EXPECT_LE(angle, max_angle + 1e-9);
    EXPECT_GE(c.clearance_m, options.min_clearance_m);
    EXPECT_LE(c.clearance_m, options.max_clearance_m);
    // Scores in [0, 1], the total the documented product, sorted best first.
    const GraspScore& s = c.score;
    for (double v :
         {s.total, s.quality, s.face_size, s.centrality, s.clearance, s.approach, s.tilt}) {
      EXPECT_GE(v, 0.0);
      EXPECT_LE(v, 1.0);
    }
    EXPECT_NEAR(s.total,
                s.quality * std::pow(s.face_size, options.face_size_weight) *
                    std::pow(s.centrality, options.centrality_weight) *
                    std::pow(s.clearance, options.clearance_weight) *
                    std::pow(s.approach, options.approach_weight) *
                    std::pow(s.tilt, options.tilt_weight),
                1e-12);
    EXPECT_NEAR(s.quality, grasps.quality * point.quality, 1e-12);
    if (i > 0) {
      EXPECT_GE(result.candidates[i - 1].score.total, s.total);
    }
  }
  EXPECT_EQ(result.rejected.size(),
            static_cast<std::size_t>(result.rejected_outside_container +
                                     result.rejected_approach_angle + result.rejected_blocked));
}

// ---------------------------------------------------------------------------------------------
// The table.

TEST(GraspTableTest, CoversExactlyTheCatalogue) {
  const Fixture& f = F();
  EXPECT_EQ(f.catalogue.size(), 39u);
  EXPECT_EQ(f.table.size(), f.catalogue.size());
  for (const apc::Item& item : f.catalogue.items()) {
    ASSERT_NE(f.table.find(item.name), nullptr) << item.name;
    EXPECT_FALSE(f.table.at(item.name).points.empty()) << item.name;
  }
  for (const auto& [name, grasps] : f.table.items()) {
    EXPECT_TRUE(f.catalogue.contains(name)) << name;
    EXPECT_EQ(grasps.item, name);
    EXPECT_GT(grasps.quality, 0.0);
    EXPECT_LE(grasps.quality, 1.0);
  }
  EXPECT_DOUBLE_EQ(f.table.cup_diameter_m(), 0.04);
  EXPECT_EQ(f.table.source(), GraspTablePath());
  EXPECT_TRUE(std::filesystem::is_regular_file(DefaultGraspTablePath()));
  EXPECT_THROW(f.table.at("no_such_item"), apc::UnknownItemError);
}

TEST(GraspTableTest, SizesAreTheModelledSizes) {
  for (const auto& [name, grasps] : F().table.items()) {
    EXPECT_LT((grasps.size_m - SizeOf(name)).cwiseAbs().maxCoeff(), 2e-4)
        << name << ": " << grasps.size_m.transpose() << " vs " << SizeOf(name).transpose();
  }
}

// Every point of a primitive item lies on its modelled surface and is approached along the
// inward normal; points of scanned items lie on their bounding box.
TEST(GraspTableTest, PointsLieOnTheModelledSurface) {
  constexpr double kTol = 1.5e-3;
  for (const auto& [name, grasps] : F().table.items()) {
    const world::ItemShape shape = F().shapes.at(name);
    const Eigen::Vector3d half = grasps.size_m / 2.0;
    for (const SuctionPoint& p : grasps.points) {
      SCOPED_TRACE(name + " '" + p.name + "'");
      EXPECT_NEAR(p.approach_Item.norm(), 1.0, 1e-9);
      EXPECT_GE(p.face_m[0], p.face_m[1]);
      EXPECT_GT(p.quality, 0.0);
      EXPECT_LE(p.quality, 1.0);
      const Eigen::Vector3d& q = p.p_ItemPoint;
      const Eigen::Vector3d& a = p.approach_Item;
      if (shape.kind == world::ShapeKind::kBox || shape.kind == world::ShapeKind::kScan) {
        int axis = -1;
        for (int i = 0; i < 3; ++i) {
          if (std::abs(std::abs(a[i]) - 1.0) < 1e-6) axis = i;
        }
        ASSERT_GE(axis, 0) << "approach not along a box axis: " << a.transpose();
        EXPECT_NEAR(q[axis], -a[axis] * half[axis], kTol);
        EXPECT_LE(((q.cwiseAbs() - half).array()).maxCoeff(), kTol);
      } else if (shape.kind == world::ShapeKind::kCylinder) {
        const int ax = shape.axis_along_long_side ? 0 : 2;
        const double radius =
            (ax == 0 ? std::min(half.y(), half.z()) : std::min(half.x(), half.y()));
        Eigen::Vector3d radial = q;
        radial[ax] = 0.0;
        if (std::abs(a[ax]) > 0.5) {  // A flat end.
          EXPECT_NEAR(std::abs(a[ax]), 1.0, 1e-6);
          EXPECT_NEAR(q[ax], -a[ax] * half[ax], kTol);
          EXPECT_LE(radial.norm(), radius + kTol);
        } else {  // The curved side.
          EXPECT_NEAR(radial.norm(), radius, kTol);
          EXPECT_LE(std::abs(q[ax]), half[ax] + kTol);
          EXPECT_LT((a + radial.normalized()).norm(), 1e-3);
        }
      } else {
        EXPECT_NEAR(q.norm(), half.minCoeff(), kTol);
        EXPECT_LT((a + q.normalized()).norm(), 1e-3);
      }
    }
  }
}

TEST(GraspTableTest, DefaultRule) {
  world::ItemShape box;
  // A book: only its two large faces are wide enough; 20 cm long, so their halves too.
  auto points = DefaultSuctionPoints({0.20, 0.167, 0.004}, box, 0.04);
  ASSERT_EQ(points.size(), 6u);
  EXPECT_EQ(points[0].name, "+z face");
  EXPECT_EQ(points[1].name, "+z face, -x half");
  EXPECT_TRUE(points[0].approach_Item.isApprox(-Eigen::Vector3d::UnitZ()));
  EXPECT_TRUE(points[0].p_ItemPoint.isApprox(Eigen::Vector3d(0, 0, 0.002)));
  EXPECT_TRUE(points[1].p_ItemPoint.isApprox(Eigen::Vector3d(-0.05, 0, 0.002)));
  EXPECT_TRUE(points[0].face_m.isApprox(Eigen::Vector2d(0.20, 0.167)));
  // A cube-ish box: all six faces, no halves.
  points = DefaultSuctionPoints({0.13, 0.115, 0.11}, box, 0.04);
  EXPECT_EQ(points.size(), 6u);
  // No face as wide as the cup (a toothbrush): the widest faces are kept.
  points = DefaultSuctionPoints({0.22, 0.025, 0.016}, box, 0.04);
  ASSERT_EQ(points.size(), 6u);
  for (const auto& p : points)
    EXPECT_EQ(p.name.substr(0, 7), p.name[0] == '+' ? "+z face" : "-z face");
  // A bottle: 8 points around the side (curved: quality < 1) and both ends.
  world::ItemShape cylinder;
  cylinder.kind = world::ShapeKind::kCylinder;
  points = DefaultSuctionPoints({0.195, 0.067, 0.067}, cylinder, 0.04);
  ASSERT_EQ(points.size(), 10u);
  EXPECT_EQ(points[0].name, "side +y");
  EXPECT_EQ(points[1].name, "side +y+z");
  EXPECT_EQ(points[8].name, "+x end");
  EXPECT_LT(points[0].quality, 0.8);
  EXPECT_GT(points[0].quality, 0.5);
  EXPECT_DOUBLE_EQ(points[8].quality, 1.0);
  // Larger radius, flatter side, better seal.
  EXPECT_GT(DefaultSuctionPoints({0.30, 0.15, 0.15}, cylinder, 0.04)[0].quality, points[0].quality);
  // Duct tape: axis along z.
  cylinder.axis_along_long_side = false;
  points = DefaultSuctionPoints({0.096, 0.096, 0.05}, cylinder, 0.04);
  ASSERT_EQ(points.size(), 10u);
  EXPECT_EQ(points[0].name, "side +x");
  EXPECT_EQ(points[8].name, "+z end");
  // A ball: 14 points toward the centre.
  world::ItemShape sphere;
  sphere.kind = world::ShapeKind::kSphere;
  points = DefaultSuctionPoints({0.068, 0.068, 0.068}, sphere, 0.04);
  ASSERT_EQ(points.size(), 14u);
  for (const auto& p : points) {
    EXPECT_NEAR(p.p_ItemPoint.norm(), 0.034, 1e-12);
    EXPECT_TRUE(p.approach_Item.isApprox(-p.p_ItemPoint.normalized()));
  }
  EXPECT_THROW(DefaultSuctionPoints({0.1, 0.0, 0.1}, box, 0.04), std::invalid_argument);
  EXPECT_THROW(DefaultSuctionPoints({0.1, 0.1, 0.1}, box, 0.0), std::invalid_argument);
}

// A two-item catalogue and a valid table for it, to break one field at a time.
apc::Catalogue SmallCatalogue() {
  apc::Item a;
  a.id = 1;
  a.name = "box_item";
  a.long_side_m = 0.2;
  a.middle_side_m = 0.1;
  a.short_side_m = 0.05;
  a.volume_cm3 = 1000.0;
  apc::Item b = a;
  b.id = 2;
  b.name = "other_item";
  return apc::Catalogue({a, b});
}

std::string SmallYaml() {
  return R"(version: 1
cup_diameter_m: 0.04
items:
  box_item:
    size_m: [0.2, 0.1, 0.05]
    quality: 0.5
    points:
      - {name: "+z face", p_ItemPoint: [0, 0, 0.025], approach_Item: [0, 0, -1], face_m: [0.2, 0.1]}
      - {name: "-z face", p_ItemPoint: [0, 0, -0.025], approach_Item: [0, 0, 1], face_m: [0.1, 0.2], quality: 0.9}
  other_item:
    size_m: [0.2, 0.1, 0.05]
    points:
      - {name: "+x face", p_ItemPoint: [0.1, 0, 0], approach_Item: [-1, 0, 0], face_m: [0.1, 0.05]}
)";
}

std::string Replace(std::string s, const std::string& from, const std::string& to) {
  const auto pos = s.find(from);
  EXPECT_NE(pos, std::string::npos) << from;
  return pos == std::string::npos ? s : s.replace(pos, from.size(), to);
}

// The error's item and field, checking that the message names the source.
std::string ErrorOf(const std::string& yaml) {
  try {
    GraspTable::FromYaml(yaml, "test_grasps.yaml", SmallCatalogue());
  } catch (const GraspTableError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("test_grasps.yaml"), std::string::npos) << what;
    if (!e.item().empty()) {
      EXPECT_NE(what.find(e.item()), std::string::npos) << what;
    }
    if (!e.field().empty()) {
      EXPECT_NE(what.find(e.field()), std::string::npos) << what;
    }
    EXPECT_EQ(e.source(), "test_grasps.yaml");
    return e.item() + ":" + e.field();
  }
  return "<no error>";
}

TEST(GraspTableTest, ParsesAValidTable) {
  const GraspTable t = GraspTable::FromYaml(SmallYaml(), "test_grasps.yaml", SmallCatalogue());
  ASSERT_EQ(t.size(), 2u);
  const ItemGrasps& g = t.at("box_item");
  EXPECT_DOUBLE_EQ(g.quality, 0.5);
  ASSERT_EQ(g.points.size(), 2u);
  EXPECT_EQ(g.points[1].name, "-z face");
  EXPECT_DOUBLE_EQ(g.points[1].quality, 0.9);
  EXPECT_DOUBLE_EQ(g.points[0].quality, 1.0);
  EXPECT_TRUE(g.points[1].face_m.isApprox(Eigen::Vector2d(0.2, 0.1)));  // Sorted.
  EXPECT_DOUBLE_EQ(t.at("other_item").quality, 1.0);
}

TEST(GraspTableTest, ErrorsNameTheFileItemAndField) {
  const std::string y = SmallYaml();
  // A missing item.
  EXPECT_EQ(ErrorOf(Replace(y,
                            "  other_item:\n    size_m: [0.2, 0.1, 0.05]\n    points:\n      "
                            "- {name: \"+x face\", p_ItemPoint: [0.1, 0, 0], approach_Item: "
                            "[-1, 0, 0], face_m: [0.1, 0.05]}\n",
                            "")),
            "other_item:items.other_item");
  // An item not in the catalogue.
  EXPECT_EQ(ErrorOf(y + "  mystery_item:\n    size_m: [1, 1, 1]\n    points: []\n"),
            "mystery_item:items.mystery_item");
  EXPECT_EQ(ErrorOf(Replace(y, "approach_Item: [0, 0, -1]", "approach_Item: [0, 0, -0.5]")),
            "box_item:points[0].approach_Item");
  EXPECT_EQ(ErrorOf(Replace(y, "approach_Item: [0, 0, -1]", "approach_Item: [0, 0, 1]")),
            "box_item:points[0].approach_Item");  // Points out of the item.
  EXPECT_EQ(ErrorOf(Replace(y, "p_ItemPoint: [0, 0, 0.025]", "p_ItemPoint: [0, .nan, 0.025]")),
            "box_item:points[0].p_ItemPoint[1]");
  EXPECT_EQ(ErrorOf(Replace(y, "p_ItemPoint: [0, 0, 0.025]", "p_ItemPoint: [0, 0, 0.04]")),
            "box_item:points[0].p_ItemPoint");  // Outside the item box.
  EXPECT_EQ(ErrorOf(Replace(y, "p_ItemPoint: [0, 0, 0.025]", "p_ItemPoint: [0, 0]")),
            "box_item:points[0].p_ItemPoint");
  EXPECT_EQ(ErrorOf(Replace(y, ", face_m: [0.2, 0.1]}", "}")), "box_item:points[0].face_m");
  EXPECT_EQ(ErrorOf(Replace(y, "face_m: [0.2, 0.1]", "face_m: [0.2, -0.1]")),
            "box_item:points[0].face_m");
  EXPECT_EQ(ErrorOf(Replace(y, "quality: 0.5", "quality: 0")), "box_item:quality");
  EXPECT_EQ(ErrorOf(Replace(y, "quality: 0.9", "quality: 1.5")), "box_item:points[1].quality");
  EXPECT_EQ(ErrorOf(Replace(y, "quality: 0.5", "qualty: 0.5")), "box_item:qualty");
  EXPECT_EQ(ErrorOf(Replace(y, "size_m: [0.2, 0.1, 0.05]", "size_m: [0.2, 0.1, x]")),
            "box_item:size_m[2]");
  EXPECT_EQ(ErrorOf(Replace(y, "{name: \"+z face\", ", "{")), "box_item:points[0].name");
  EXPECT_EQ(ErrorOf(Replace(y, "version: 1", "version: 2")), ":version");
  EXPECT_EQ(ErrorOf(Replace(y, "cup_diameter_m: 0.04", "cup_diameter_m: -1")), ":cup_diameter_m");
  EXPECT_EQ(ErrorOf(y + "  box_item:\n    size_m: [1, 1, 1]\n    points: []\n"),
            "box_item:items.box_item");  // Listed twice.
  EXPECT_EQ(ErrorOf(Replace(y, "p_ItemPoint: [0.1, 0, 0], ", "")),
            "other_item:points[0].p_ItemPoint");
  const std::string no_points =
      Replace(y, "    points:\n      - {name: \"+x face\"", "    points: []\n#");
  EXPECT_EQ(ErrorOf(no_points), "other_item:points");
  EXPECT_EQ(ErrorOf(Replace(y, "  other_item:", "  [other_item]:")), ":");  // Malformed key.
  EXPECT_EQ(ErrorOf("version: 1\nitems: [1, 2]\n"), ":items");
  EXPECT_EQ(ErrorOf("version: 1\nitems: {a: [}\n"), ":");
  EXPECT_THROW(GraspTable::FromYamlFile("/nonexistent/grasps.yaml", SmallCatalogue()),
               GraspTableError);
  // The error type is a runtime_error.
  EXPECT_THROW(GraspTable::FromYaml("version: 3", "x", SmallCatalogue()), std::runtime_error);
}

// ---------------------------------------------------------------------------------------------
// Grasps.

// For every item at a plausible pose in each of the 12 bins and in the tote: at least one
// candidate, the best one through the opening, every candidate consistent.
TEST(ComputeGraspsTest, EveryItemInEveryBinAndTheTote) {
  const Fixture& f = F();
  ASSERT_EQ(f.cell.bins.size(), 12u);
  std::mt19937 rng(2016);
  std::uniform_real_distribution<double> jitter(-10.0 * kDeg, 10.0 * kDeg);
  // Flat items show only their top face, which the seal tolerance's tilt brings no nearer
  // than 73 deg to the opening direction: the default 80 deg gives every item candidates.
  const GraspOptions options;
  for (const apc::Item& item : f.catalogue.items()) {
    const Eigen::Vector3d size = SizeOf(item.name);
    for (const world::BinGeometry& bin : f.cell.bins) {
      SCOPED_TRACE(item.name + " in " + bin.name);
      const GraspContainer container = ShelfBinContainer(f.cell, bin.name);
      EXPECT_EQ(container.kind, GraspContainerKind::kShelfBin);
      const Eigen::Isometry3d X_BaseItem = PlaceInBin(bin, size, jitter(rng));
      const GraspResult result = ComputeGrasps(f.table, item.name, X_BaseItem, container, options);
      ASSERT_FALSE(result.empty()) << result.reason;
      EXPECT_TRUE(result.reason.empty());
      EXPECT_EQ(result.rejected_outside_container, 0);
      EXPECT_LE(result.best().approach_angle_rad, options.max_approach_angle_rad);
      EXPECT_GT(result.best().score.total, 0.0);
      ExpectConsistent(result, item.name, X_BaseItem, container, options);
    }
    const GraspContainer tote = ToteContainer(f.cell);
    SCOPED_TRACE(item.name + " in the tote");
    const Eigen::Isometry3d X_BaseItem = PlaceInTote(tote, size, 4.0 * jitter(rng));
    const GraspResult result = ComputeGrasps(f.table, item.name, X_BaseItem, tote, options);
    ASSERT_FALSE(result.empty()) << result.reason;
    EXPECT_LE(result.best().approach_angle_rad, options.max_tote_approach_angle_rad);
    // From the tote the cup comes down: near vertical.
    EXPECT_LT(result.best().approach_Base.z(), -std::cos(options.max_tote_approach_angle_rad));
    ExpectConsistent(result, item.name, X_BaseItem, tote, options);
  }
}

TEST(ComputeGraspsTest, ContainersOfTheCell) {
  const Fixture& f = F();
  const GraspContainer bin = ShelfBinContainer(f.cell, "bin_E");
  EXPECT_EQ(bin.name, "bin_E");
  // The openings face the robot: -x of base.
  EXPECT_LT((bin.opening_direction_Base + Eigen::Vector3d::UnitX()).norm(), 1e-9);
  EXPECT_GT(bin.inner_size_m.minCoeff(), 0.2);
  EXPECT_THROW(ShelfBinContainer(f.cell, "bin_Z"), std::invalid_argument);
  const GraspContainer tote = ToteContainer(f.cell);
  EXPECT_EQ(tote.kind, GraspContainerKind::kOpenTop);
  EXPECT_LT((tote.opening_direction_Base - Eigen::Vector3d::UnitZ()).norm(), 1e-9);
  EXPECT_GT(tote.inner_size_m.x(), 0.3);
  EXPECT_THROW(ToteContainer(f.cell, -0.01), std::invalid_argument);
  EXPECT_THROW(ToteContainer(f.cell, 10.0), std::invalid_argument);
}

// A flat item lying on a bin floor: its top face can only be approached with the cup tilted
// toward the opening (straight down is 90 deg from the opening direction), and no further
// than the cup's seal tolerance allows.
TEST(ComputeGraspsTest, FlatItemInABinIsTakenFromAboveOnlyWithinTheSealTolerance) {
  const Fixture& f = F();
  const std::string item = "jane_eyre_dvd";
  const GraspContainer container = ShelfBinContainer(f.cell, "bin_E");
  const Eigen::Isometry3d X_BaseItem = PlaceInBin(f.cell.bin("bin_E"), SizeOf(item), 0.0);
  const GraspOptions defaults;
  EXPECT_LE(defaults.max_tilt_rad, kSealAngleToleranceRad - kSealAngleMarginRad);
  // Tilted by the largest tilt the planner takes, the top face is still 78 deg from the
  // opening direction: out with a 70 deg limit, ...
  GraspOptions narrow;
  narrow.max_approach_angle_rad = 70.0 * kDeg;
  const GraspResult steep = ComputeGrasps(f.table, item, X_BaseItem, container, narrow);
  for (const GraspCandidate& c : steep.candidates) EXPECT_NE(c.surface, "+z face");
  // ... in with the default 80 deg (the planner's tube test decides whether it can be
  // reached), tilted by max_tilt_rad.
  const GraspResult result = ComputeGrasps(f.table, item, X_BaseItem, container, defaults);
  ASSERT_FALSE(result.empty()) << result.reason;
  EXPECT_EQ(result.best().surface, "+z face");
  EXPECT_NEAR(result.best().tilt_rad, defaults.max_tilt_rad, 1e-9);
  EXPECT_NEAR(result.best().approach_angle_rad, 90.0 * kDeg - defaults.max_tilt_rad, 1e-9);
  EXPECT_GT(result.rejected_approach_angle, 0);  // Straight down, the bottom face, ...
  // A tilt beyond the seal tolerance is refused: the cup would not seal.
  GraspOptions too_far;
  too_far.max_tilt_rad = kSealAngleToleranceRad + 0.01;
  EXPECT_THROW(ComputeGrasps(f.table, item, X_BaseItem, container, too_far), std::invalid_argument);
  // Without tilting there is nothing, and the reason says what to change.
  GraspOptions no_tilt;
  no_tilt.max_tilt_rad = 0.0;
  const GraspResult none = ComputeGrasps(f.table, item, X_BaseItem, container, no_tilt);
  EXPECT_TRUE(none.empty());
  EXPECT_NE(none.reason.find("max_approach_angle_rad"), std::string::npos) << none.reason;
  EXPECT_NE(none.reason.find("jane_eyre_dvd"), std::string::npos) << none.reason;
  EXPECT_NE(none.reason.find("bin_E"), std::string::npos) << none.reason;
  EXPECT_EQ(none.rejected_approach_angle, static_cast<int>(none.rejected.size()));
  for (const RejectedGrasp& r : none.rejected) {
    EXPECT_EQ(r.reason, GraspRejection::kApproachAngle);
    EXPECT_FALSE(r.detail.empty());
  }
  // Allowing 90 deg accepts the straight approach from above, but the tilted one still wins.
  no_tilt.max_approach_angle_rad = 90.0 * kDeg;
  EXPECT_FALSE(ComputeGrasps(f.table, item, X_BaseItem, container, no_tilt).empty());
}

// A flat item lying deep in a bin is also offered its top face's point nearest the opening
// that keeps the whole cup (and the margin) on the face, and the front edge's corners; the
// centre still ranks first.
TEST(ComputeGraspsTest, ATopFaceIsAlsoOfferedNearTheOpening) {
  const Fixture& f = F();
  const std::string item = "cherokee_easy_tee_shirt";
  const GraspContainer container = ShelfBinContainer(f.cell, "bin_C");
  const Eigen::Vector3d size = SizeOf(item);
  const Eigen::Isometry3d X_BaseItem =
      PlaceInBin(f.cell.bin("bin_C"), size, 0.3) * Eigen::Translation3d(-0.12, 0.0, 0.0);
  const GraspOptions options;
  const GraspResult result = ComputeGrasps(f.table, item, X_BaseItem, container, options);
  const double cup_radius_m = f.table.cup_diameter_m() / 2.0;
  const Eigen::Vector3d o = container.opening_direction_Base;
  const GraspCandidate* centre = nullptr;
  const GraspCandidate* front = nullptr;
  for (const GraspCandidate& c : result.candidates) {  // each surface's best approach
    if (c.surface == "+z face" && !centre) centre = &c;
    if (c.surface == "+z face, toward the opening" && !front) front = &c;
  }
  ASSERT_NE(centre, nullptr);
  ASSERT_NE(front, nullptr) << "no point toward the opening";
  EXPECT_GT(centre->score.total, front->score.total);
  // Nearer the opening, on the same face, the cup's rim the margin inside one of its edges.
  const Eigen::Vector3d p_Item = X_BaseItem.inverse() * front->p_BasePoint;
  EXPECT_NEAR(p_Item.z(), size.z() / 2.0, 1e-9);
  const double to_edge_m =
      std::min(size.x() / 2.0 - std::abs(p_Item.x()), size.y() / 2.0 - std::abs(p_Item.y()));
  EXPECT_NEAR(to_edge_m, cup_radius_m + options.edge_margin_toward_opening_m, 1e-9);
  EXPECT_GT((front->p_BasePoint - centre->p_BasePoint).dot(o), 0.05);
  // Its shift lies in the face, along the opening direction's part across it.
  const Eigen::Vector3d shift = front->p_BasePoint - centre->p_BasePoint;
  const Eigen::Vector3d across =
      (o - o.dot(X_BaseItem.linear().col(2)) * X_BaseItem.linear().col(2)).normalized();
  EXPECT_NEAR(shift.normalized().dot(across), 1.0, 1e-9);
  // The front edge's two corners too, each the margin inside both edges, below the centre.
  std::set<std::string> corners;
  for (const GraspCandidate& c : result.candidates) {
    if (c.surface.rfind("+z face, front corner ", 0) != 0) continue;
    corners.insert(c.surface);
    EXPECT_LT(c.score.total, centre->score.total) << c.surface;
    const Eigen::Vector3d p_Corner = X_BaseItem.inverse() * c.p_BasePoint;
    EXPECT_NEAR(p_Corner.z(), size.z() / 2.0, 1e-9);
    for (int axis = 0; axis < 2; ++axis) {
      EXPECT_NEAR(size[axis] / 2.0 - std::abs(p_Corner[axis]),
                  cup_radius_m + options.edge_margin_toward_opening_m, 1e-9)
          << c.surface;
    }
    EXPECT_GT((c.p_BasePoint - centre->p_BasePoint).dot(o), 0.05) << c.surface;
  }
  // (Here the other corner lies outside the bin's free box.)
  EXPECT_EQ(corners.size(), 1u);
  // Off, or in the tote: none.
  GraspOptions off = options;
  off.edge_margin_toward_opening_m = -1.0;
  for (const GraspCandidate& c :
       ComputeGrasps(f.table, item, X_BaseItem, container, off).candidates) {
    EXPECT_EQ(c.surface.find("toward the opening"), std::string::npos);
    EXPECT_EQ(c.surface.find("front corner"), std::string::npos);
  }
  const GraspContainer tote = ToteContainer(f.cell);
  for (const GraspCandidate& c :
       ComputeGrasps(f.table, item, PlaceInTote(tote, size, 0.3), tote, options).candidates) {
    EXPECT_EQ(c.surface.find("toward the opening"), std::string::npos);
    EXPECT_EQ(c.surface.find("front corner"), std::string::npos);
  }
}

// A face toward the opening is also offered pitched down, the tube rising toward the
// opening over the floor's front lip, by the same tilts (within the seal tolerance).
TEST(ComputeGraspsTest, AFaceTowardTheOpeningIsAlsoPitchedDown) {
  const Fixture& f = F();
  const std::string item = "kleenex_tissue_box";
  const GraspContainer container = ShelfBinContainer(f.cell, "bin_E");
  const Eigen::Isometry3d X_BaseItem = PlaceInBin(f.cell.bin("bin_E"), SizeOf(item), 0.0);
  const GraspOptions options;
  const GraspResult result = ComputeGrasps(f.table, item, X_BaseItem, container, options);
  int straight = 0, pitched = 0;
  for (const GraspCandidate& c : result.candidates) {
    if (c.approach_angle_rad > 1e-6 &&
        c.surface_approach_Base.dot(Eigen::Vector3d::UnitX()) > 0.999) {
      ++pitched;
      EXPECT_LT(c.approach_Base.z(), 0.0) << c.surface;  // down into the bin
      EXPECT_LE(c.tilt_rad, options.max_tilt_rad + 1e-12);
      EXPECT_NEAR(c.approach_angle_rad, c.tilt_rad, 1e-9);
    } else if (c.approach_angle_rad < 1e-6) {
      ++straight;
    }
  }
  EXPECT_GE(straight, 1);
  EXPECT_EQ(pitched, options.tilt_steps * straight);
}

// An item standing with a big face toward the opening prefers that face, straight in.
TEST(ComputeGraspsTest, PrefersABigFaceTowardTheOpening) {
  const Fixture& f = F();
  const world::BinGeometry& bin = f.cell.bin("bin_H");
  const GraspContainer container = ShelfBinContainer(f.cell, "bin_H");
  for (const std::string item : {"jane_eyre_dvd", "i_am_a_bunny_book", "staples_index_cards",
                                 "kleenex_tissue_box", "crayola_24_ct"}) {
    SCOPED_TRACE(item);
    const Eigen::Vector3d size = SizeOf(item);
    // In the shelf frame: item z along shelf +x (out of the opening), item x along shelf y,
    // item y up: standing on its -y face.
    Eigen::Matrix3d R_ShelfItem;
    R_ShelfItem.col(0) = Eigen::Vector3d::UnitY();
    R_ShelfItem.col(1) = Eigen::Vector3d::UnitZ();
    R_ShelfItem.col(2) = Eigen::Vector3d::UnitX();
    const Eigen::Vector3d p_ShelfItem(bin.opening_x_m - 0.05 - size.z() / 2.0,
                                      bin.inner_S.center().y(),
                                      bin.floor_max_z_m + size.y() / 2.0 + 0.001);
    const Eigen::Isometry3d X_BaseItem = f.cell.config.X_BaseShelf * Pose(R_ShelfItem, p_ShelfItem);
    const GraspResult result = ComputeGrasps(f.table, item, X_BaseItem, container);
    ASSERT_FALSE(result.empty()) << result.reason;
    EXPECT_EQ(result.best().surface, "+z face");
    EXPECT_NEAR(result.best().tilt_rad, 0.0, 1e-12);
    EXPECT_NEAR(result.best().approach_angle_rad, 0.0, 1e-9);
    // Straight into the bin: +x of base.
    EXPECT_LT((result.best().approach_Base - Eigen::Vector3d::UnitX()).norm(), 1e-9);
    // It leaves through the opening: full clearance.
    EXPECT_DOUBLE_EQ(result.best().clearance_m, GraspOptions().max_clearance_m);
    ExpectConsistent(result, item, X_BaseItem, container);
  }
}

// Moving the item and its container together by a rigid motion moves every grasp with them
// (the roll reference is fixed in base, so only the approach axis is compared).
TEST(ComputeGraspsTest, MovingItemAndContainerMovesTheGrasps) {
  const Fixture& f = F();
  std::mt19937 rng(7);
  std::normal_distribution<double> normal(0.0, 1.0);
  for (const std::string item :
       {"kleenex_paper_towels", "rawlings_baseball", "i_am_a_bunny_book", "scotch_duct_tape"}) {
    const GraspContainer container = ShelfBinContainer(f.cell, "bin_B");
    const Eigen::Isometry3d X_BaseItem = PlaceInBin(f.cell.bin("bin_B"), SizeOf(item), 0.1);
    const GraspResult a = ComputeGrasps(f.table, item, X_BaseItem, container);
    for (int trial = 0; trial < 3; ++trial) {
      SCOPED_TRACE(item + ", trial " + std::to_string(trial));
      const Eigen::Quaterniond q =
          Eigen::Quaterniond(normal(rng), normal(rng), normal(rng), normal(rng)).normalized();
      const Eigen::Isometry3d T =
          Pose(q.toRotationMatrix(), Eigen::Vector3d(normal(rng), normal(rng), normal(rng)));
      GraspContainer moved = container;
      moved.X_BaseContainer = T * container.X_BaseContainer;
      moved.opening_direction_Base = T.linear() * container.opening_direction_Base;
      const GraspResult b = ComputeGrasps(f.table, item, T * X_BaseItem, moved);
      ASSERT_EQ(a.candidates.size(), b.candidates.size());
      EXPECT_EQ(a.rejected.size(), b.rejected.size());
      // A point's tilts toward the opening and its pitches down may share a tilt angle: the
      // approach's height in the container tells them apart.
      auto key = [](const GraspCandidate& c, const GraspContainer& box) {
        const double height = (box.X_BaseContainer.linear().transpose() * c.approach_Base).z();
        return std::tuple<std::string, long, long>{c.surface, std::lround(c.tilt_rad * 1e6),
                                                   std::lround(height * 1e4)};
      };
      std::map<std::tuple<std::string, long, long>, const GraspCandidate*> by_key;
      for (const GraspCandidate& c : b.candidates) by_key[key(c, moved)] = &c;
      for (const GraspCandidate& ca : a.candidates) {
        const auto it = by_key.find(key(ca, container));
        ASSERT_NE(it, by_key.end()) << ca.surface;
        const GraspCandidate& cb = *it->second;
        EXPECT_LT((cb.p_BasePoint - T * ca.p_BasePoint).norm(), 1e-9);
        EXPECT_LT((cb.approach_Base - T.linear() * ca.approach_Base).norm(), 1e-9);
        EXPECT_LT((cb.X_BaseTcp.linear().col(2) - T.linear() * ca.X_BaseTcp.linear().col(2)).norm(),
                  1e-9);
        EXPECT_LT(
            (cb.X_BaseTcpPreGrasp.translation() - T * ca.X_BaseTcpPreGrasp.translation()).norm(),
            1e-9);
        EXPECT_NEAR(cb.score.total, ca.score.total, 1e-9);
        EXPECT_NEAR(cb.clearance_m, ca.clearance_m, 1e-9);
      }
    }
  }
}

// Turning the item about the vertical in the tote turns the grasps with it.
TEST(ComputeGraspsTest, TurningTheItemTurnsTheGrasps) {
  const Fixture& f = F();
  const GraspContainer tote = ToteContainer(f.cell);
  const std::string item = "kleenex_tissue_box";
  const Eigen::Isometry3d X0 = PlaceInTote(tote, SizeOf(item), 0.0);
  const GraspResult a = ComputeGrasps(f.table, item, X0, tote);
  ASSERT_FALSE(a.empty());
  const Eigen::Isometry3d X1 = X0 * Pose(RotZ(0.7), Eigen::Vector3d::Zero());
  const GraspResult b = ComputeGrasps(f.table, item, X1, tote);
  ASSERT_EQ(a.candidates.size(), b.candidates.size());
  const Eigen::Isometry3d X_10 = X1 * X0.inverse();
  for (std::size_t i = 0; i < a.candidates.size(); ++i) {
    EXPECT_EQ(a.candidates[i].surface, b.candidates[i].surface);
    EXPECT_LT((b.candidates[i].p_BasePoint - X_10 * a.candidates[i].p_BasePoint).norm(), 1e-9);
    EXPECT_LT(
        (b.candidates[i].approach_Base - X_10.linear() * a.candidates[i].approach_Base).norm(),
        1e-9);
  }
  EXPECT_EQ(a.best().surface, "+z face");
  EXPECT_LT((a.best().approach_Base + Eigen::Vector3d::UnitZ()).norm(), 1e-9);
  // Near vertical: the roll reference is base +x.
  EXPECT_LT((a.best().X_BaseTcp.linear().col(0) - Eigen::Vector3d::UnitX()).norm(), 1e-9);
}

TEST(ComputeGraspsTest, ToteAcceptsOnlyNearVerticalApproaches) {
  const Fixture& f = F();
  const GraspContainer tote = ToteContainer(f.cell);
  const std::string item = "folgers_classic_roast_coffee";
  const GraspResult r = ComputeGrasps(f.table, item, PlaceInTote(tote, SizeOf(item), 0.3), tote);
  ASSERT_FALSE(r.empty());
  for (const GraspCandidate& c : r.candidates) {
    EXPECT_LE(c.approach_angle_rad, GraspOptions().max_tote_approach_angle_rad + 1e-12);
  }
  EXPECT_EQ(r.best().surface, "side +z");
  EXPECT_GT(r.rejected_approach_angle, 0);
}

TEST(ComputeGraspsTest, ClearanceCallbackAndGeometry) {
  const Fixture& f = F();
  const std::string item = "kleenex_tissue_box";
  const GraspContainer container = ShelfBinContainer(f.cell, "bin_E");
  const Eigen::Isometry3d X_BaseItem = PlaceInBin(f.cell.bin("bin_E"), SizeOf(item), 0.0);

  // The callback is asked from the point backwards along the approach, up to max_clearance_m.
  // 80 deg from the opening admits the tilted top face.
  GraspOptions wide;
  wide.max_approach_angle_rad = 80.0 * kDeg;
  GraspOptions options = wide;
  int calls = 0;
  options.clearance = [&](const Eigen::Vector3d& p, const Eigen::Vector3d& d, double max_m) {
    ++calls;
    EXPECT_NEAR(d.norm(), 1.0, 1e-12);
    EXPECT_DOUBLE_EQ(max_m, options.max_clearance_m);
    // Free only toward the robot (base -x).
    return d.x() < -0.99 ? 0.05 : 0.0;
  };
  GraspResult r = ComputeGrasps(f.table, item, X_BaseItem, container, options);
  EXPECT_GT(calls, 0);
  ASSERT_FALSE(r.empty()) << r.reason;
  for (const GraspCandidate& c : r.candidates) {
    EXPECT_DOUBLE_EQ(c.clearance_m, 0.05);
    EXPECT_DOUBLE_EQ(c.score.clearance, 0.5);
    EXPECT_LT((c.approach_Base - Eigen::Vector3d::UnitX()).norm(), 0.15);
  }
  EXPECT_GT(r.rejected_blocked, 0);

  // Everything blocked: no candidate, and the reason says so.
  options.clearance = [](const Eigen::Vector3d&, const Eigen::Vector3d&, double) { return 0.0; };
  r = ComputeGrasps(f.table, item, X_BaseItem, container, options);
  EXPECT_TRUE(r.empty());
  EXPECT_GT(r.rejected_blocked, 0);
  EXPECT_NE(r.reason.find("min_clearance_m"), std::string::npos) << r.reason;

  options.clearance = [](const Eigen::Vector3d&, const Eigen::Vector3d&, double) {
    return std::numeric_limits<double>::quiet_NaN();
  };
  EXPECT_THROW(ComputeGrasps(f.table, item, X_BaseItem, container, options), std::runtime_error);

  // Pure geometry: a tilted approach to the top face leaves the bin through its ceiling or its
  // opening; the face toward the opening leaves through the opening (full clearance).
  const GraspResult g = ComputeGrasps(f.table, item, X_BaseItem, container, wide);
  bool saw_top = false, saw_front = false;
  for (const GraspCandidate& c : g.candidates) {
    if (c.surface == "+z face") {
      saw_top = true;
      EXPECT_GT(c.tilt_rad, 0.0);
    }
    if (c.tilt_rad == 0.0 && c.approach_angle_rad < 0.3) {
      saw_front = true;
      EXPECT_DOUBLE_EQ(c.clearance_m, GraspOptions().max_clearance_m);
    }
  }
  EXPECT_TRUE(saw_top);
  EXPECT_TRUE(saw_front);

  // Pushed up under the bin's ceiling, the top face is blocked.
  const world::BinGeometry& bin = f.cell.bin("bin_E");
  Eigen::Isometry3d X_ShelfItem = f.cell.config.X_BaseShelf.inverse() * X_BaseItem;
  X_ShelfItem.translation().z() = bin.inner_S.max().z() - SizeOf(item).z() / 2.0 - 0.005;
  const GraspResult high =
      ComputeGrasps(f.table, item, f.cell.config.X_BaseShelf * X_ShelfItem, container, wide);
  ASSERT_FALSE(high.empty());
  for (const GraspCandidate& c : high.candidates) EXPECT_NE(c.surface, "+z face");
  EXPECT_GT(high.rejected_blocked, 0);
}

TEST(ComputeGraspsTest, PointsOutsideTheContainerAreRejected) {
  const Fixture& f = F();
  const std::string item = "kleenex_tissue_box";
  const GraspContainer container = ShelfBinContainer(f.cell, "bin_E");
  Eigen::Isometry3d X_BaseItem = PlaceInBin(f.cell.bin("bin_E"), SizeOf(item), 0.0);
  X_BaseItem.translation().y() += 1.0;  // In the next bin over, or beside the shelf.
  const GraspResult r = ComputeGrasps(f.table, item, X_BaseItem, container);
  EXPECT_TRUE(r.empty());
  // Every listed point (and every point moved toward the opening).
  EXPECT_EQ(r.rejected_outside_container, static_cast<int>(r.rejected.size()));
  EXPECT_GE(r.rejected_outside_container, static_cast<int>(F().table.at(item).points.size()));
  EXPECT_NE(r.reason.find("outside the container box"), std::string::npos) << r.reason;
}

TEST(ComputeGraspsTest, RejectsBadInputs) {
  const Fixture& f = F();
  const GraspContainer container = ShelfBinContainer(f.cell, "bin_E");
  const std::string item = "kleenex_tissue_box";
  const Eigen::Isometry3d X = PlaceInBin(f.cell.bin("bin_E"), SizeOf(item), 0.0);
  EXPECT_THROW(ComputeGrasps(f.table, "no_such_item", X, container), apc::UnknownItemError);
  Eigen::Isometry3d bad = X;
  bad.translation().x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(ComputeGrasps(f.table, item, bad, container), std::invalid_argument);
  bad = X;
  bad.linear() *= 1.1;  // Scaled.
  EXPECT_THROW(ComputeGrasps(f.table, item, bad, container), std::invalid_argument);
  bad = X;
  bad.linear().col(0) *= -1.0;  // A reflection.
  EXPECT_THROW(ComputeGrasps(f.table, item, bad, container), std::invalid_argument);
  bad = X;
  bad.linear()(0, 1) += 0.01;  // Sheared.
  EXPECT_THROW(ComputeGrasps(f.table, item, bad, container), std::invalid_argument);

  GraspContainer c = container;
  c.inner_size_m.y() = 0.0;
  EXPECT_THROW(ComputeGrasps(f.table, item, X, c), std::invalid_argument);
  c = container;
  c.opening_direction_Base *= 2.0;
  EXPECT_THROW(ComputeGrasps(f.table, item, X, c), std::invalid_argument);
  c = container;
  c.X_BaseContainer.linear() *= 2.0;
  EXPECT_THROW(ComputeGrasps(f.table, item, X, c), std::invalid_argument);

  GraspOptions o;
  o.pregrasp_standoff_m = -0.1;
  EXPECT_THROW(ComputeGrasps(f.table, item, X, container, o), std::invalid_argument);
  o = GraspOptions();
  o.max_approach_angle_rad = 0.0;
  EXPECT_THROW(ComputeGrasps(f.table, item, X, container, o), std::invalid_argument);
  o = GraspOptions();
  o.tilt_weight = -1.0;
  EXPECT_THROW(ComputeGrasps(f.table, item, X, container, o), std::invalid_argument);
  o = GraspOptions();
  o.max_tilt_rad = 2.0;
  EXPECT_THROW(ComputeGrasps(f.table, item, X, container, o), std::invalid_argument);
}

TEST(ComputeGraspsTest, IsDeterministicAndHonoursTheStandoff) {
  const Fixture& f = F();
  const GraspContainer container = ShelfBinContainer(f.cell, "bin_K");
  const std::string item = "dasani_water_bottle";
  const Eigen::Isometry3d X = PlaceInBin(f.cell.bin("bin_K"), SizeOf(item), 0.05);
  GraspOptions options;
  options.pregrasp_standoff_m = 0.05;
  const GraspResult a = ComputeGrasps(f.table, item, X, container, options);
  const GraspResult b = ComputeGrasps(f.table, item, X, container, options);
  ASSERT_FALSE(a.empty());
  ASSERT_EQ(a.candidates.size(), b.candidates.size());
  for (std::size_t i = 0; i < a.candidates.size(); ++i) {
    EXPECT_EQ(a.candidates[i].surface, b.candidates[i].surface);
    EXPECT_EQ(a.candidates[i].score.total, b.candidates[i].score.total);
    EXPECT_TRUE(a.candidates[i].X_BaseTcp.isApprox(b.candidates[i].X_BaseTcp, 0.0));
  }
  ExpectConsistent(a, item, X, container, options);
}

// ---------------------------------------------------------------------------------------------
// Generator of data/planner/grasps.yaml's defaults (the rule of DefaultSuctionPoints), to start
// an edit from:
//   test_planner_grasps --gtest_also_run_disabled_tests --gtest_filter='*PrintDefaultTable'

std::string Num(double v, int digits) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.*f", digits, v);
  std::string s = buf;
  if (s.find('.') != std::string::npos) {
    while (s.back() == '0') s.pop_back();
    if (s.back() == '.') s.pop_back();
  }
  if (s == "-0") s = "0";
  return s;
}

std::string Vec(const Eigen::VectorXd& v, int digits) {
  std::string s = "[";
  for (int i = 0; i < v.size(); ++i) s += (i ? ", " : "") + Num(v[i], digits);
  return s + "]";
}

// The rule that wrote data/planner/grasps.yaml still writes a table that loads for every
// item (print it with PICKING_PRINT_GRASP_TABLE=1 to start a new table from the defaults).
TEST(GraspTableGenerator, DefaultRuleWritesAValidTable) {
  const auto catalogue = apc::Catalogue::FromCsvFile(kDataDir + "/apc2016/items/item_data.csv");
  const auto shapes = world::ShapeTable::FromYamlFile(kDataDir + "/items/shapes.yaml", catalogue);
  std::ostringstream out;
  out << "items:\n";
  for (const apc::Item& item : catalogue.items()) {
    const world::ItemShape shape = shapes.at(item.name);
    const Eigen::Vector3d size = world::ModelledSize(item, shape);
    out << "  " << item.name << ":\n    size_m: " << Vec(size, 4) << "\n    points:\n";
    for (const SuctionPoint& p : DefaultSuctionPoints(size, shape, 0.04)) {
      out << "      - {name: \"" << p.name << "\", p_ItemPoint: " << Vec(p.p_ItemPoint, 4)
          << ", approach_Item: " << Vec(p.approach_Item, 7) << ", face_m: " << Vec(p.face_m, 4);
      if (p.quality < 1.0) out << ", quality: " << Num(p.quality, 2);
      out << "}\n";
    }
  }
  if (std::getenv("PICKING_PRINT_GRASP_TABLE")) std::cout << out.str();
  const GraspTable table = GraspTable::FromYaml("version: 1\ncup_diameter_m: 0.04\n" + out.str(),
                                                "generated", catalogue);
  EXPECT_EQ(table.size(), catalogue.size());
}

// ---------------------------------------------------------------------------------------------
// The straight tube through the opening.

// A 0.40 m deep, 0.30 m wide, 0.20 m high box with its opening toward +x, and a grasp at
// `p` whose approach is `angle_deg` from straight in (-x), tilted toward -z (down).
GraspCandidate GraspAt(const Eigen::Vector3d& p, double angle_deg) {
  GraspCandidate grasp;
  grasp.surface = "+z face";
  grasp.p_BasePoint = p;
  const double a = angle_deg * kDeg;
  grasp.approach_Base = Eigen::Vector3d(-std::cos(a), 0.0, -std::sin(a));
  return grasp;
}

GraspContainer TestBin() {
  GraspContainer bin;
  bin.name = "test bin";
  bin.inner_size_m = Eigen::Vector3d(0.40, 0.30, 0.20);
  bin.opening_direction_Base = Eigen::Vector3d::UnitX();
  return bin;
}

TEST(TubeReachTest, ATopFaceDeepInALowBinIsOutOfReach) {
  const GraspContainer bin = TestBin();
  // 60 deg from the opening, on the floor 0.30 m behind it: the tube rises 0.87 m per metre
  // and leaves the 0.20 m bin through the ceiling about 0.21 m from the cup.
  const TubeReachResult deep = CheckTubeReach(bin, GraspAt({-0.10, 0.0, -0.09}, 60.0));
  EXPECT_FALSE(deep.reaches);
  EXPECT_EQ(deep.wall, "ceiling");
  EXPECT_NEAR(deep.depth_m, 0.30, 1e-9);
  EXPECT_NEAR(deep.container_size_m, 0.20, 1e-9);
  EXPECT_NEAR(deep.angle_rad, 60.0 * kDeg, 1e-9);
  // The surface (0.01 m above the axis at 60 deg) meets the ceiling at z = 0.10.
  EXPECT_NEAR(deep.meets_at_m, (0.19 - 0.02 * std::cos(60.0 * kDeg)) / std::sin(60.0 * kDeg), 1e-9);
  EXPECT_GT(deep.penetration_m, 0.05);
  EXPECT_NE(deep.message.find("ceiling"), std::string::npos) << deep.message;
  EXPECT_NE(deep.message.find("0.30 m deep in a 0.20 m-high bin"), std::string::npos)
      << deep.message;
  // The same face 3 cm behind the opening: the tube is out of the bin before it rises.
  EXPECT_TRUE(CheckTubeReach(bin, GraspAt({0.17, 0.0, -0.09}, 60.0)).reaches);
  // Straight in at mid height reaches from the back wall.
  EXPECT_TRUE(CheckTubeReach(bin, GraspAt({-0.19, 0.0, 0.0}, 0.0)).reaches);
}

TEST(TubeReachTest, WallsFloorAndTolerance) {
  const GraspContainer bin = TestBin();
  // Coming up from below toward the opening: the floor.
  GraspCandidate up = GraspAt({-0.10, 0.0, 0.05}, -40.0);
  up.surface = "-z face";
  EXPECT_EQ(CheckTubeReach(bin, up).wall, "floor");
  // Sideways, 60 deg toward +y: a side wall.
  GraspCandidate side;
  side.surface = "side";
  side.p_BasePoint = Eigen::Vector3d(-0.10, 0.0, 0.0);
  side.approach_Base = Eigen::Vector3d(-0.5, -std::sqrt(0.75), 0.0);
  const TubeReachResult wall = CheckTubeReach(bin, side);
  EXPECT_EQ(wall.wall, "side wall");
  EXPECT_NE(wall.message.find("m-wide bin"), std::string::npos) << wall.message;
  // Straight in, the tube's surface 5 mm past the ceiling: within the tolerance; 15 mm: not.
  EXPECT_TRUE(CheckTubeReach(bin, GraspAt({-0.10, 0.0, 0.085}, 0.0)).reaches);
  EXPECT_FALSE(CheckTubeReach(bin, GraspAt({-0.10, 0.0, 0.095}, 0.0)).reaches);
  // A rotated, moved container gives the same answers.
  GraspContainer moved = bin;
  moved.X_BaseContainer =
      Eigen::Translation3d(1.2, -0.3, 0.5) * Eigen::AngleAxisd(EIGEN_PI, Eigen::Vector3d::UnitZ());
  moved.opening_direction_Base = -Eigen::Vector3d::UnitX();
  GraspCandidate deep = GraspAt({-0.10, 0.0, -0.09}, 60.0);
  deep.p_BasePoint = moved.X_BaseContainer * deep.p_BasePoint;
  deep.approach_Base = moved.X_BaseContainer.linear() * deep.approach_Base;
  const TubeReachResult turned = CheckTubeReach(moved, deep);
  EXPECT_FALSE(turned.reaches);
  EXPECT_EQ(turned.wall, "ceiling");
  EXPECT_NEAR(turned.depth_m, 0.30, 1e-9);
}

}  // namespace
}  // namespace picking::planner

namespace picking::planner {
namespace {

// The cup coming down (-z in base) onto the top of an item at X_BaseItem, its lip at
// `p_ItemContact` raised by 1 cm.
Eigen::Isometry3d CupDownOnto(const Eigen::Isometry3d& X_BaseItem,
                              const Eigen::Vector3d& p_ItemContact) {
  Eigen::Isometry3d X_BaseTcp = Eigen::Isometry3d::Identity();
  X_BaseTcp.linear() = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix();
  X_BaseTcp.translation() = X_BaseItem * p_ItemContact + Eigen::Vector3d(0.0, 0.0, 0.01);
  return X_BaseTcp;
}

Eigen::Isometry3d SomeItemPose() {
  Eigen::Isometry3d X_BaseItem(Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitZ()));
  X_BaseItem.translation() = Eigen::Vector3d(0.9, -0.2, 0.4);
  return X_BaseItem;
}

TEST(ModelSealTest, TheCupSealsOnAFlatFaceWhereItIsPlanned) {
  const ModelSeal seal(world::MakeBox({0.12, 0.08, 0.05}), ModelSealOptions{});
  const Eigen::Isometry3d X_BaseItem = SomeItemPose();
  const ModelSealResult r = seal.Check(X_BaseItem, CupDownOnto(X_BaseItem, {0.0, 0.0, 0.025}));
  EXPECT_TRUE(r.sealed) << r.measure.reason;
  EXPECT_TRUE(r.shift_Base.isZero());
}

// 5 mm from the face's edge the lip (1.5 cm radius) overhangs it; a contact moved inward
// seals.
TEST(ModelSealTest, AContactNearAnEdgeMovesInward) {
  const ModelSeal seal(world::MakeBox({0.12, 0.08, 0.05}), ModelSealOptions{});
  const Eigen::Isometry3d X_BaseItem = SomeItemPose();
  const ModelSealResult r = seal.Check(X_BaseItem, CupDownOnto(X_BaseItem, {0.055, 0.0, 0.025}));
  ASSERT_TRUE(r.sealed) << r.measure.reason;
  const Eigen::Vector3d shift_Item = X_BaseItem.linear().transpose() * r.shift_Base;
  EXPECT_LT(shift_Item.x(), -0.005);  // toward the face's middle
  EXPECT_NEAR(shift_Item.z(), 0.0, 1e-9);
  EXPECT_LE(r.shift_Base.norm(), 0.02 + 1e-9);
}

TEST(ModelSealTest, AFaceNarrowerThanTheLipAndABallAreRefused) {
  const Eigen::Isometry3d X_BaseItem = SomeItemPose();
  const ModelSeal bar(world::MakeBox({0.15, 0.02, 0.02}), ModelSealOptions{});
  const ModelSealResult on_bar = bar.Check(X_BaseItem, CupDownOnto(X_BaseItem, {0, 0, 0.01}));
  EXPECT_FALSE(on_bar.sealed);
  EXPECT_EQ(on_bar.measure.reason, "a lip point meets no surface");
  const ModelSeal ball(
      world::Transformed(world::MakeSphere(0.037, 48, 96),
                         Eigen::Isometry3d(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitX()))),
      ModelSealOptions{});
  const ModelSealResult on_ball = ball.Check(X_BaseItem, CupDownOnto(X_BaseItem, {0, 0, 0.037}));
  EXPECT_FALSE(on_ball.sealed);
  EXPECT_EQ(on_ball.measure.reason, "surface under the lip is not flat enough");
}

TEST(ModelSealTest, NothingAlongTheApproachIsNoSeal) {
  const ModelSeal seal(world::MakeBox({0.12, 0.08, 0.05}), ModelSealOptions{});
  const Eigen::Isometry3d X_BaseItem = SomeItemPose();
  const ModelSealResult r = seal.Check(X_BaseItem, CupDownOnto(X_BaseItem, {0.3, 0.0, 0.025}));
  EXPECT_FALSE(r.sealed);
  EXPECT_EQ(r.measure.reason, "the cup meets nothing of the item along its approach");
  ModelSealOptions bad;
  bad.shift_m = {0.0};
  EXPECT_THROW(ModelSeal(world::MakeBox({0.1, 0.1, 0.1}), bad), std::invalid_argument);
  EXPECT_THROW(ModelSeal(world::TriangleMesh{}, ModelSealOptions{}), std::invalid_argument);
  ModelSealOptions no_lip;
  no_lip.seal.cup_radius_m = 0.0;
  EXPECT_THROW(ModelSeal::Validate(no_lip), std::invalid_argument);
  EXPECT_THROW(ModelSeal(world::MakeBox({0.1, 0.1, 0.1}), no_lip), std::invalid_argument);
  EXPECT_NO_THROW(ModelSeal::Validate(ModelSealOptions{}));
}

}  // namespace
}  // namespace picking::planner
