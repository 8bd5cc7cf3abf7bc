#include "services/detector/core/verify.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "services/detector/core/templates.h"

namespace picking::detector {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

world::TriangleMesh BoxMesh(const Eigen::Vector3f& size) {
  world::TriangleMesh mesh;
  const Eigen::Vector3f h = 0.5f * size;
  for (int i = 0; i < 8; ++i)
    mesh.vertices.emplace_back((i & 1) ? h.x() : -h.x(), (i & 2) ? h.y() : -h.y(),
                               (i & 4) ? h.z() : -h.z());
  mesh.triangles = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                    {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
  return mesh;
}

class VerifyTest : public ::testing::Test {
 protected:
  void SetUp() override {
    model_ = SampleMeshSurface(BoxMesh({0.1f, 0.06f, 0.03f}), 0.0015, 3);
    X_BaseSensor_ = Eigen::Translation3d(0.0, 0.0, 0.7) *
                    Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()) *
                    Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitY());
    X_BaseItem_ =
        Eigen::Translation3d(0.02, 0.01, 0.015) * Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitZ());
    scene_ = Scan(X_BaseSensor_, 1);
  }

  // Floor z = 0 and the box as a sensor at X_BaseSensor sees them, ray cast through a dense
  // splat render of the model; organised, NaN where a ray meets nothing.
  geometry::PointCloud Scan(const Eigen::Isometry3d& X_BaseSensor, unsigned seed) const {
    const RangeImage object =
        RenderRangeImage(model_, X_BaseSensor.inverse() * X_BaseItem_, camera_, 0.0015);
    std::mt19937 rng(seed);
    std::normal_distribution<float> noise(0.0f, 0.0005f);
    geometry::PointCloud scan;
    scan.width = camera_.width();
    scan.height = camera_.height();
    for (int v = 0; v < camera_.height(); ++v) {
      for (int u = 0; u < camera_.width(); ++u) {
        const Eigen::Vector3d d((u - camera_.cx()) / camera_.fx(),
                                (v - camera_.cy()) / camera_.fy(), 1.0);
        const Eigen::Vector3d d_Base = X_BaseSensor.linear() * d;
        double z = d_Base.z() < 0 ? -X_BaseSensor.translation().z() / d_Base.z()
                                  : std::numeric_limits<double>::infinity();
        if (std::isfinite(object.at(u, v))) z = std::min<double>(z, object.at(u, v));
        const Eigen::Vector3f p = (X_BaseSensor * (d * (z + noise(rng)))).cast<float>();
        scan.points.push_back(std::isfinite(z) ? p : Eigen::Vector3f::Constant(kNaN));
      }
    }
    return scan;
  }

  geometry::PointCloud model_, scene_;
  PinholeCamera camera_{320, 240, 300.0, 300.0, 159.5, 119.5};
  Eigen::Isometry3d X_BaseSensor_, X_BaseItem_;
};

TEST_F(VerifyTest, TruePoseScoresHigh) {
  const VerificationScene scene(scene_, X_BaseSensor_, camera_);
  const VerifyResult r = Verify(scene, model_, X_BaseItem_);
  EXPECT_GT(r.score, 0.8);
  EXPECT_GT(r.num_visible, 100u);
  EXPECT_LT(r.num_visible, r.num_model_points);  // the back faces are culled
  EXPECT_LT(r.conflict_fraction, 0.05);
  EXPECT_LT(r.inlier_rmse_m, 0.003);
}

TEST_F(VerifyTest, ShiftedPoseScoresLow) {
  const VerificationScene scene(scene_, X_BaseSensor_, camera_);
  const double true_score = Verify(scene, model_, X_BaseItem_).score;
  for (const Eigen::Vector3d& shift :
       {Eigen::Vector3d(0.02, 0, 0), Eigen::Vector3d(0, 0.02, 0), Eigen::Vector3d(0, 0, 0.02)}) {
    Eigen::Isometry3d X = X_BaseItem_;
    X.translation() += shift;
    const VerifyResult r = Verify(scene, model_, X);
    EXPECT_LT(r.score, 0.6) << shift.transpose();
    EXPECT_LT(r.score, true_score - 0.3) << shift.transpose();
  }
  // Lifted 2 cm: the model floats where the sensor saw through to the box top and floor.
  Eigen::Isometry3d lifted = X_BaseItem_;
  lifted.translation().z() += 0.02;
  EXPECT_GT(Verify(scene, model_, lifted).num_conflicts, 50u);
}

TEST_F(VerifyTest, AbsentObjectScoresNearZero) {
  Eigen::Isometry3d elsewhere = X_BaseItem_;
  elsewhere.translation() += Eigen::Vector3d(-0.15, 0.1, 0.0);  // empty floor
  const VerificationScene scene(scene_, X_BaseSensor_, camera_);
  const VerifyResult r = Verify(scene, model_, elsewhere);
  EXPECT_LT(r.score, 0.1);
  EXPECT_GT(r.num_conflicts, 0u);
  // Below the floor: hidden behind measured surface, nothing to confirm.
  Eigen::Isometry3d below = X_BaseItem_;
  below.translation().z() -= 0.1;
  const VerifyResult hidden = Verify(scene, model_, below);
  EXPECT_EQ(hidden.score, 0.0);
  EXPECT_GT(hidden.num_occluded, 0u);
}

// A thin card posed flush with the floor, where no card is: the floor supports every point of
// its face, but the floor's surface runs on past its outline all round, as it does not past
// the real box's (which drops 3 cm to the floor). The outline scales the card's score down.
TEST_F(VerifyTest, APoseLaidIntoALargerSurfaceIsScaledDownByItsOutline) {
  const VerificationScene scene(scene_, X_BaseSensor_, camera_);
  const VerifyResult real = Verify(scene, model_, X_BaseItem_);
  EXPECT_GT(real.num_outline, 20u);
  EXPECT_LT(real.num_outline_continued, real.num_outline / 4);
  EXPECT_DOUBLE_EQ(real.outline_factor, 1.0);
  EXPECT_DOUBLE_EQ(real.score, real.support_score);

  const geometry::PointCloud card = SampleMeshSurface(BoxMesh({0.06f, 0.04f, 0.004f}), 0.0015, 5);
  const Eigen::Isometry3d X_BaseCard(Eigen::Translation3d(-0.12, 0.08, -0.002));
  const VerifyResult laid = Verify(scene, card, X_BaseCard);
  EXPECT_GT(laid.support_score, 0.8);  // every visible point lies on the floor
  EXPECT_GT(laid.num_outline, 20u);
  EXPECT_GT(laid.num_outline_continued, laid.num_outline * 9 / 10);
  EXPECT_LT(laid.outline_factor, 0.3);
  EXPECT_LT(laid.score, 0.3);

  // Switched off, the outline is still measured but leaves the score as it is.
  VerifyOptions unchecked;
  unchecked.outline_check = false;
  const VerifyResult kept = Verify(scene, card, X_BaseCard, unchecked);
  EXPECT_EQ(kept.num_outline, laid.num_outline);
  EXPECT_DOUBLE_EQ(kept.outline_factor, 1.0);
  EXPECT_DOUBLE_EQ(kept.score, laid.support_score);
}

// A pose whose outline the sensor did not measure (a cropped region: nothing around it) keeps
// its score: the outline's prior alone leaves the factor at 1.
TEST_F(VerifyTest, AnOutlineWithoutMeasurementsLeavesTheScore) {
  geometry::PointCloud cropped = scene_;
  for (auto& p : cropped.points) {
    if (p.allFinite() && p.z() < 0.003f) p.setConstant(kNaN);  // the floor cut away
  }
  const VerificationScene scene(cropped, X_BaseSensor_, camera_);
  const VerifyResult r = Verify(scene, model_, X_BaseItem_);
  EXPECT_EQ(r.num_outline, 0u);
  EXPECT_DOUBLE_EQ(r.outline_factor, 1.0);
  EXPECT_GT(r.score, 0.8);
}

TEST_F(VerifyTest, RejectsBadInput) {
  geometry::PointCloud all_nan = scene_;
  for (auto& p : all_nan.points) p.setConstant(kNaN);
  EXPECT_THROW(VerificationScene(all_nan, X_BaseSensor_, camera_), std::invalid_argument);
  const VerificationScene scene(scene_, X_BaseSensor_, camera_);
  geometry::PointCloud no_normals = model_;
  no_normals.normals.clear();
  EXPECT_THROW(Verify(scene, no_normals, X_BaseItem_), std::invalid_argument);
  VerifyOptions bad;
  bad.outline_distance_m = 0.0;
  EXPECT_THROW(Verify(scene, model_, X_BaseItem_, bad), std::invalid_argument);
  bad = VerifyOptions();
  bad.outline_free_fraction = 1.0;
  EXPECT_THROW(Verify(scene, model_, X_BaseItem_, bad), std::invalid_argument);
  bad = VerifyOptions();
  bad.outline_prior = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(Verify(scene, model_, X_BaseItem_, bad), std::invalid_argument);
}

// The same box scanned from a second sensor position on its other side (0.4 m along x,
// looking back at it) and the two scans merged: the faces the first sensor does not
// see are verified from the second.
TEST_F(VerifyTest, SeveralSensorsJudgeVisibilityFromEach) {
  const Eigen::Isometry3d X_BaseOther = Eigen::Translation3d(0.4, 0.0, 0.7) *
                                        Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()) *
                                        Eigen::AngleAxisd(-0.5, Eigen::Vector3d::UnitY());
  const geometry::PointCloud other = Scan(X_BaseOther, 2);
  geometry::PointCloud merged;
  for (const geometry::PointCloud* scan :
       {static_cast<const geometry::PointCloud*>(&scene_), &other}) {
    for (const Eigen::Vector3f& p : scan->points) {
      if (p.allFinite()) merged.points.push_back(p);
    }
  }
  merged.width = static_cast<std::uint32_t>(merged.points.size());
  const std::vector<SensorView> both = {{X_BaseSensor_, camera_}, {X_BaseOther, camera_}};
  const VerificationScene one(scene_, X_BaseSensor_, camera_);
  const VerificationScene two(merged, both);
  ASSERT_EQ(two.sensors().size(), 2u);

  const VerifyResult single = Verify(one, model_, X_BaseItem_);
  const VerifyResult r = Verify(two, model_, X_BaseItem_);
  EXPECT_GT(r.num_visible, single.num_visible + 50);  // a face only the second sensor sees
  EXPECT_GT(r.score, 0.8);
  EXPECT_LT(r.conflict_fraction, 0.05);
  // Shifted 2 cm along x: both sensors see it off the box.
  Eigen::Isometry3d shifted = X_BaseItem_;
  shifted.translation().x() += 0.02;
  EXPECT_LT(Verify(two, model_, shifted).score, r.score - 0.3);
  // Lifted 2 cm: in the free space the first sensor saw.
  Eigen::Isometry3d lifted = X_BaseItem_;
  lifted.translation().z() += 0.02;
  EXPECT_GT(Verify(two, model_, lifted).conflict_fraction, 0.3);

  EXPECT_THROW(VerificationScene(merged, std::vector<SensorView>{}), std::invalid_argument);
  Eigen::Isometry3d bad = X_BaseOther;
  bad.translation().x() = std::nan("");
  EXPECT_THROW(VerificationScene(merged, {{X_BaseSensor_, camera_}, {bad, camera_}}),
               std::invalid_argument);
}

}  // namespace
}  // namespace picking::detector
