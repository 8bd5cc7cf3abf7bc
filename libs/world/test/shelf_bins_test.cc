#include "libs/world/shelf_bins.h"

#include <gtest/gtest.h>

#include "libs/world/mesh_utils.h"
#include "libs/world/stl_io.h"

namespace picking::world {
namespace {

TriangleMesh BoxAt(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  return Transformed(MakeBox(hi - lo), Eigen::Isometry3d(Eigen::Translation3d(0.5 * (lo + hi))));
}

// A shelf built from boxes with known bins: columns 0.26 / 0.30 / 0.26 m, rows (top first)
// 0.26 / 0.22 / 0.22 / 0.26 m, 0.43 m deep, 2 cm boards, a 0.6 m tall base below.
struct SyntheticShelf {
  TriangleMesh mesh;
  std::vector<Eigen::AlignedBox3d> bins;  // A..L
};

SyntheticShelf MakeSyntheticShelf() {
  const double t = 0.02, back = 0.01, depth = 0.43;
  const std::vector<double> widths = {0.26, 0.30, 0.26};
  const std::vector<double> heights_top_first = {0.26, 0.22, 0.22, 0.26};
  const double total_w = 0.26 + 0.30 + 0.26 + 4 * t;
  std::vector<TriangleMesh> parts;
  const double y0 = -0.5 * total_w;
  const double z_base = 0.6;
  double total_h = z_base;
  for (double h : heights_top_first) total_h += h + t;
  total_h += t;
  const double x1 = back + depth;
  parts.push_back(BoxAt({0, y0, 0}, {back, -y0, total_h}));  // back wall
  double y = y0;
  for (int c = 0; c <= 3; ++c) {  // dividers and side walls
    parts.push_back(BoxAt({back, y, z_base}, {x1, y + t, total_h}));
    if (c < 3) y += t + widths[c];
  }
  parts.push_back(BoxAt({back, y0, 0}, {x1, -y0, 0.02}));  // base plate
  SyntheticShelf shelf;
  // Boards from the bottom up; bins from the top down.
  double z = z_base;
  std::vector<double> floors;
  for (int r = 3; r >= 0; --r) {
    parts.push_back(BoxAt({back, y0, z}, {x1, -y0, z + t}));
    floors.push_back(z + t);
    z += t + heights_top_first[r];
  }
  parts.push_back(BoxAt({back, y0, z}, {x1, -y0, z + t}));  // top board
  for (int r = 0; r < 4; ++r) {
    const double floor = floors[3 - r];
    double yy = y0 + t;
    for (int c = 0; c < 3; ++c) {
      shelf.bins.emplace_back(Eigen::Vector3d(back, yy, floor),
                              Eigen::Vector3d(x1, yy + widths[c], floor + heights_top_first[r]));
      yy += widths[c] + t;
    }
  }
  shelf.mesh = Merge(parts);
  return shelf;
}

TEST(ShelfBinsTest, RecoversTheBinsOfAShelfOfKnownDimensions) {
  const SyntheticShelf shelf = MakeSyntheticShelf();
  const auto bins = MeasureBins(shelf.mesh);
  ASSERT_EQ(bins.size(), 12u);
  for (int i = 0; i < 12; ++i) {
    SCOPED_TRACE(bins[i].name);
    EXPECT_EQ(bins[i].name, std::string("bin_") + static_cast<char>('A' + i));
    EXPECT_EQ(bins[i].row, i / 3);
    EXPECT_EQ(bins[i].column, i % 3);
    EXPECT_TRUE(bins[i].inner_S.min().isApprox(shelf.bins[i].min(), 1e-3))
        << bins[i].inner_S.min().transpose() << " vs " << shelf.bins[i].min().transpose();
    EXPECT_TRUE(bins[i].inner_S.max().isApprox(shelf.bins[i].max(), 1e-3))
        << bins[i].inner_S.max().transpose() << " vs " << shelf.bins[i].max().transpose();
    EXPECT_NEAR(bins[i].floor_max_z_m, shelf.bins[i].min().z(), 1e-6);
  }
}

TEST(ShelfBinsTest, AShelfWithoutTwelveBinsIsReported) {
  const TriangleMesh cube = MakeBox({1, 1, 1});
  EXPECT_THROW(MeasureBins(cube), std::runtime_error);
  MeasureBinsOptions options;
  options.columns = 4;
  try {
    MeasureBins(MakeSyntheticShelf().mesh, options);
    FAIL() << "no throw";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("expected 4"), std::string::npos) << e.what();
  }
}

TEST(ShelfBinsTest, KivaPodHasTwelvePlausibleBinsInOrder) {
  const TriangleMesh pod = ReadStl(std::string(PICKING_DATA_DIR) + "/apc2016/shelf/pod_lowres.stl");
  const auto bins = MeasureBins(pod);
  ASSERT_EQ(bins.size(), 12u);
  for (int i = 0; i < 12; ++i) {
    const BinGeometry& b = bins[i];
    SCOPED_TRACE(b.name + " " + std::to_string(b.width_m()) + " x " + std::to_string(b.height_m()) +
                 " x " + std::to_string(b.depth_m()));
    EXPECT_EQ(b.name, std::string("bin_") + static_cast<char>('A' + i));
    EXPECT_GE(b.width_m(), 0.25);
    EXPECT_LE(b.width_m(), 0.30);
    EXPECT_GE(b.height_m(), 0.22);
    EXPECT_LE(b.height_m(), 0.27);
    EXPECT_NEAR(b.depth_m(), 0.43, 0.015);
    EXPECT_GE(b.floor_max_z_m, b.inner_S.min().z());
    EXPECT_LT(b.floor_max_z_m - b.inner_S.min().z(), 0.03);  // the slight rise to the lip
    EXPECT_NEAR(b.opening_x_m, b.inner_S.max().x(), 1e-9);
  }
  for (int i = 0; i < 12; ++i) {
    const auto& b = bins[i];
    // Left to right seen from the front is -y to +y; rows go down.
    if (b.column > 0) EXPECT_GT(b.inner_S.min().y(), bins[i - 1].inner_S.max().y());
    if (b.row > 0) EXPECT_LT(b.inner_S.max().z(), bins[i - 3].inner_S.min().z());
    // Neighbours are separated by a divider or board of 5-25 mm.
    if (b.column > 0) {
      EXPECT_LT(b.inner_S.min().y() - bins[i - 1].inner_S.max().y(), 0.025);
    }
  }
  // The middle column is the wider one on the Kiva pod.
  EXPECT_GT(bins[1].width_m(), bins[0].width_m() + 0.01);
  // Top and bottom rows are taller than the middle rows.
  EXPECT_GT(bins[0].height_m(), bins[3].height_m() + 0.02);
  EXPECT_GT(bins[9].height_m(), bins[6].height_m() + 0.02);
}

TEST(ShelfBinsTest, TheScanViewsLookIntoTheBinFromInFrontTheSideViewsFromAbove) {
  BinGeometry bin;
  bin.inner_S =
      Eigen::AlignedBox3d(Eigen::Vector3d(0.0, -0.15, 1.0), Eigen::Vector3d(0.43, 0.15, 1.25));
  bin.opening_x_m = 0.43;
  const std::vector<BinScanView> views = CellBinScanViews();
  ASSERT_EQ(views.size(), 3u);
  const Eigen::Vector3d p_Target = BinScanTarget_S(bin, views[0]);
  EXPECT_TRUE(p_Target.isApprox(Eigen::Vector3d(0.215, 0.0, 1.03)));
  const Eigen::Vector3d p_Middle = BinScanEye_S(bin, views[0]);
  EXPECT_GT(p_Middle.x(), bin.opening_x_m + 0.4);
  EXPECT_NEAR(p_Middle.y(), 0.0, 1e-12);
  for (int k : {1, 2}) {
    const Eigen::Vector3d p_Side = BinScanEye_S(bin, views[k]);
    EXPECT_GT(p_Side.z(), p_Middle.z() + 0.1) << k;  // sees over the items at the front
    EXPECT_GT(std::abs(p_Side.y()), 0.1) << k;
    EXPECT_TRUE(BinScanTarget_S(bin, views[k]).isApprox(p_Target)) << k;
  }
  EXPECT_LT(BinScanEye_S(bin, views[1]).y() * BinScanEye_S(bin, views[2]).y(), 0.0);
}

}  // namespace
}  // namespace picking::world
