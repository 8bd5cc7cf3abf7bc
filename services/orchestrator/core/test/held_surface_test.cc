#include "services/orchestrator/core/held_surface.h"

#include <gtest/gtest.h>

#include <limits>

namespace picking::orchestrator {
namespace {

// Points over the faces of a box of `size_m` centred at X_BaseBox, 5 mm apart.
void AddBoxSurface(const Eigen::Isometry3d& X_BaseBox, const Eigen::Vector3d& size_m,
                   geometry::PointCloud* cloud) {
  const double step = 0.005;
  const Eigen::Vector3d half = 0.5 * size_m;
  for (int axis = 0; axis < 3; ++axis) {
    const int u = (axis + 1) % 3, v = (axis + 2) % 3;
    for (const double side : {-1.0, 1.0}) {
      for (double a = -half[u]; a <= half[u]; a += step) {
        for (double b = -half[v]; b <= half[v]; b += step) {
          Eigen::Vector3d p = Eigen::Vector3d::Zero();
          p[axis] = side * half[axis];
          p[u] = a;
          p[v] = b;
          cloud->points.push_back((X_BaseBox * p).cast<float>());
        }
      }
    }
  }
}

// The cup 0.2 m in front of a shelf opening at x = 1 (outward normal -x), pointing at the
// shelf (+x): a held item hangs on the lip's +z side.
struct Scene {
  Eigen::Isometry3d X_BaseTcp = Eigen::Isometry3d::Identity();
  Eigen::Vector3d p_BaseOpening{1.0, 0.0, 0.8};
  Eigen::Vector3d n_BaseOpening{-1.0, 0.0, 0.0};
  Scene() {
    X_BaseTcp.linear() = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitY()).toRotationMatrix();
    X_BaseTcp.translation() = Eigen::Vector3d(0.75, 0.0, 0.8);
  }
  // The item's face centre on the lip: its frame half its short side further along z_tcp.
  static Eigen::Isometry3d X_TcpItem(const Eigen::Vector3d& size_m) {
    return Eigen::Isometry3d(Eigen::Translation3d(0.0, 0.0, 0.5 * size_m.z()));
  }
};

TEST(HeldSurfaceTest, TheBelievedItemFillsItsBoxAndALargerOneSpillsOut) {
  const Scene s;
  const Eigen::Vector3d tape_m(0.096, 0.096, 0.05);
  const Eigen::Vector3d cup_holder_m(0.136, 0.111, 0.111);
  geometry::PointCloud right;
  AddBoxSurface(s.X_BaseTcp * Scene::X_TcpItem(tape_m), tape_m, &right);
  const HeldSurface as_believed = MeasureHeldSurface(right, s.X_BaseTcp, Scene::X_TcpItem(tape_m),
                                                     tape_m, s.p_BaseOpening, s.n_BaseOpening);
  EXPECT_GT(as_believed.on_item, 1000);
  EXPECT_EQ(as_believed.beyond, 0);

  geometry::PointCloud wrong;
  AddBoxSurface(s.X_BaseTcp * Scene::X_TcpItem(cup_holder_m), cup_holder_m, &wrong);
  const HeldSurface larger = MeasureHeldSurface(wrong, s.X_BaseTcp, Scene::X_TcpItem(tape_m),
                                                tape_m, s.p_BaseOpening, s.n_BaseOpening);
  EXPECT_GT(larger.BeyondFraction(), 0.3);
  // The other way round, the smaller item lies within the larger box.
  EXPECT_EQ(MeasureHeldSurface(right, s.X_BaseTcp, Scene::X_TcpItem(cup_holder_m), cup_holder_m,
                               s.p_BaseOpening, s.n_BaseOpening)
                .beyond,
            0);
}

TEST(HeldSurfaceTest, TheBinsContentsTheTubeAndHolesAreNotCounted) {
  const Scene s;
  const Eigen::Vector3d size_m(0.1, 0.08, 0.04);
  geometry::PointCloud cloud;
  // Items behind the opening plane (in the bin), one right behind the held item.
  AddBoxSurface(Eigen::Isometry3d(Eigen::Translation3d(1.1, 0.0, 0.8)),
                Eigen::Vector3d::Constant(0.1), &cloud);
  // The tube behind the lip, and points far from the cup.
  for (double t = 0.01; t < 0.35; t += 0.005) {
    cloud.points.push_back((s.X_BaseTcp * Eigen::Vector3d(0.0, 0.0, -t)).cast<float>());
  }
  cloud.points.push_back(Eigen::Vector3f(0.3, 0.0, 0.8));
  const float nan = std::numeric_limits<float>::quiet_NaN();
  cloud.points.push_back(Eigen::Vector3f(nan, nan, nan));
  const HeldSurface nothing = MeasureHeldSurface(cloud, s.X_BaseTcp, Scene::X_TcpItem(size_m),
                                                 size_m, s.p_BaseOpening, s.n_BaseOpening);
  EXPECT_EQ(nothing.total(), 0);
  EXPECT_EQ(nothing.BeyondFraction(), 0.0);
}

}  // namespace
}  // namespace picking::orchestrator
