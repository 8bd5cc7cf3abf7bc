#include "services/robot/core/trajectory.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "services/robot/core/safety.h"

namespace picking::robot {
namespace {

ur10::Ur10Model Model() { return ur10::Ur10Model::Load(std::string(PICKING_DATA_DIR) + "/ur10"); }

TEST(TrapezoidProfileTest, ReachesOneAtRest) {
  for (auto [v, a] : {std::pair{0.5, 1.0}, std::pair{5.0, 1.0}, std::pair{0.1, 10.0}}) {
    const TrapezoidProfile profile(v, a);
    double s, sd, sdd;
    profile.Evaluate(profile.duration_s(), &s, &sd, &sdd);
    EXPECT_DOUBLE_EQ(s, 1.0);
    EXPECT_DOUBLE_EQ(sd, 0.0);
    profile.Evaluate(0.0, &s, &sd, &sdd);
    EXPECT_DOUBLE_EQ(s, 0.0);
    for (double t = 0; t < profile.duration_s(); t += 0.001) {
      profile.Evaluate(t, &s, &sd, &sdd);
      EXPECT_LE(sd, v + 1e-12);
      EXPECT_LE(std::abs(sdd), a + 1e-12);
    }
  }
  // Triangle: 1 = a t^2 -> t = 1 s each way for a = 1 and an unreachable v.
  EXPECT_NEAR(TrapezoidProfile(5.0, 1.0).duration_s(), 2.0, 1e-12);
  // Trapezoid: t_acc = 0.5, duration = 0.5 + 1/0.5 = 2.5.
  EXPECT_NEAR(TrapezoidProfile(0.5, 1.0).duration_s(), 2.5, 1e-12);
  EXPECT_THROW(TrapezoidProfile(0.0, 1.0), std::invalid_argument);
}

TEST(TimeParametrizePathTest, SingleSegmentIsTimeOptimal) {
  TimeParametrizationOptions options;
  options.max_velocity_rad_s = JointVector::Constant(1.0);
  options.max_acceleration_rad_s2 = JointVector::Constant(2.0);
  JointVector a = JointVector::Zero(), b = JointVector::Zero();
  b[0] = 2.0;  // joint 0 limited: t_acc = 0.5 s, cruise 1.5 s, total 2.5 s
  b[1] = -1.0;
  const JointTrajectory t = TimeParametrizePath({a, b}, options);
  EXPECT_NEAR(t.duration_s(), 2.5, 1e-9);
  EXPECT_TRUE(t.points.back().q_rad.isApprox(b));
  EXPECT_EQ(t.points.size(), 314u);  // k / 125 s for k = 0..312, plus the end at 2.5 s
  for (const auto& p : t.points) {
    EXPECT_LE(p.qd_rad_s.cwiseAbs().maxCoeff(), 1.0 + 1e-12);
    EXPECT_LE(p.qdd_rad_s2.cwiseAbs().maxCoeff(), 2.0 + 1e-12);
    // Straight line in joint space: joint 1 moves at -1/2 of joint 0.
    EXPECT_NEAR(p.q_rad[1], -0.5 * p.q_rad[0], 1e-12);
  }
}

TEST(TimeParametrizePathTest, StopsAtCornersMergesCollinearAndPassesSafety) {
  const ur10::Ur10Model model = Model();
  TimeParametrizationOptions options;
  options.max_velocity_rad_s = model.max_velocity_rad_s();
  options.max_acceleration_rad_s2 = model.max_acceleration_rad_s2();
  JointVector q0, q1, q2, q3;
  q0 << 0, -1.5, 1.5, -1.5, -1.5, 0;
  q1 = q0;
  q1[0] = 0.5;
  q2 = q0;
  q2[0] = 1.0;  // collinear with q0 -> q1
  q3 = q2;
  q3[1] = -1.0;
  const JointTrajectory merged = TimeParametrizePath({q0, q1, q1, q2, q3}, options);
  const JointTrajectory direct = TimeParametrizePath({q0, q2, q3}, options);
  EXPECT_NEAR(merged.duration_s(), direct.duration_s(), 1e-9);
  // Rest at the corner q2: the sample closest to it is within one sample period of the stop.
  const TrajectoryPoint* closest = &merged.points.front();
  for (const auto& p : merged.points) {
    if ((p.q_rad - q2).norm() < (closest->q_rad - q2).norm()) closest = &p;
  }
  const double dt = 1.0 / options.sample_rate_hz;
  for (int j = 0; j < ur10::kNumJoints; ++j) {
    EXPECT_LE(std::abs(closest->qd_rad_s[j]), options.max_acceleration_rad_s2[j] * dt + 1e-12);
  }
  ur10::Ur10Kinematics kin(model);
  const SafetyChecker checker(
      kin, SafetyLimits::FromModel(model, {"cell", {-2, -2, -2}, {2, 2, 2}}, 5.0));
  const SafetyCheck check = checker.CheckTrajectory(merged);
  EXPECT_TRUE(check.ok) << check.reason;
}

TEST(TimeParametrizePathTest, RejectsBadInput) {
  TimeParametrizationOptions options;
  EXPECT_THROW(TimeParametrizePath({}, options), std::invalid_argument);
  EXPECT_THROW(TimeParametrizePath({JointVector::Constant(std::nan(""))}, options),
               std::invalid_argument);
  options.max_velocity_rad_s[2] = 0.0;
  EXPECT_THROW(TimeParametrizePath({JointVector::Zero(), JointVector::Ones()}, options),
               std::invalid_argument);
  EXPECT_EQ(
      TimeParametrizePath({JointVector::Zero(), JointVector::Zero()}, TimeParametrizationOptions{})
          .points.size(),
      1u);
}

TEST(TimeParametrizePathTest, RefusesTooLongOrTooDenseProfilesBeforeSampling) {
  // 1e-6 rad/s over 1 rad is ~11.6 days: millions of samples, refused up front.
  TimeParametrizationOptions options;
  options.max_velocity_rad_s = JointVector::Constant(1e-6);
  try {
    TimeParametrizePath({JointVector::Zero(), JointVector::Ones()}, options);
    ADD_FAILURE() << "a 1e6 s profile was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("600 s limit"), std::string::npos) << e.what();
  }
  options = TimeParametrizationOptions{};
  options.sample_rate_hz = 1e9;  // a 2 s profile at 1 GHz
  EXPECT_THROW(TimeParametrizePath({JointVector::Zero(), JointVector::Ones()}, options),
               std::invalid_argument);
  // Just inside the limit is fine.
  options = TimeParametrizationOptions{};
  options.max_velocity_rad_s = JointVector::Constant(1.0 / 500.0);
  EXPECT_LT(TimeParametrizePath({JointVector::Zero(), JointVector::Ones()}, options).duration_s(),
            kMaxTrajectoryDuration_s);
}

class LinearMoveTest : public ::testing::Test {
 protected:
  LinearMoveTest() : model_(Model()), kin_(model_) {
    q_start_ << 0.2, -1.6, 1.8, -1.8, -1.57, 0.3;
    options_.max_velocity_rad_s = model_.max_velocity_rad_s();
    options_.max_acceleration_rad_s2 = model_.max_acceleration_rad_s2();
  }
  ur10::Ur10Model model_;
  ur10::Ur10Kinematics kin_;
  JointVector q_start_;
  LinearMoveOptions options_;
};

TEST_F(LinearMoveTest, TcpFollowsTheLine) {
  options_.X_ToolTcp.translation() = Eigen::Vector3d(0, 0, 0.2);
  const Eigen::Isometry3d X_start = kin_.ForwardKinematics(q_start_) * options_.X_ToolTcp;
  Eigen::Isometry3d X_goal = X_start;
  X_goal.translation() += Eigen::Vector3d(0.1, -0.2, -0.15);
  X_goal.linear() = X_goal.linear() * Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ());
  const LinearMoveResult r = PlanLinearMove(kin_, q_start_, X_goal, options_);
  ASSERT_TRUE(r.ok) << r.reason;
  const auto& p = r.trajectory.points;
  ASSERT_GT(p.size(), 10u);
  EXPECT_LT((p.front().q_rad - q_start_).norm(), 1e-9);
  const Eigen::Vector3d a = X_start.translation(), b = X_goal.translation();
  for (const auto& point : p) {
    const Eigen::Vector3d tcp =
        (kin_.ForwardKinematics(point.q_rad) * options_.X_ToolTcp).translation();
    // Distance from the segment a-b.
    const double u = std::clamp((tcp - a).dot(b - a) / (b - a).squaredNorm(), 0.0, 1.0);
    EXPECT_LT((tcp - (a + u * (b - a))).norm(), 1e-9);
    EXPECT_EQ(kin_.BranchOf(point.q_rad), r.branch);
  }
  const Eigen::Isometry3d X_end = kin_.ForwardKinematics(p.back().q_rad) * options_.X_ToolTcp;
  EXPECT_TRUE(X_end.isApprox(X_goal, 1e-9));
  // Within joint and tool limits.
  SafetyLimits limits = SafetyLimits::FromModel(model_, {"cell", {-2, -2, -2}, {2, 2, 2}},
                                                options_.max_tool_speed_m_s);
  const SafetyChecker checker(kin_, limits, options_.X_ToolTcp);
  const SafetyCheck check = checker.CheckTrajectory(r.trajectory);
  EXPECT_TRUE(check.ok) << check.reason;
}

TEST_F(LinearMoveTest, SlowsDownForJointLimits) {
  const Eigen::Isometry3d X_start = kin_.ForwardKinematics(q_start_);
  Eigen::Isometry3d X_goal = X_start;
  X_goal.translation() += Eigen::Vector3d(0.0, 0.0, -0.3);
  options_.max_velocity_rad_s = JointVector::Constant(0.05);
  const LinearMoveResult slow = PlanLinearMove(kin_, q_start_, X_goal, options_);
  ASSERT_TRUE(slow.ok) << slow.reason;
  options_.max_velocity_rad_s = model_.max_velocity_rad_s();
  const LinearMoveResult fast = PlanLinearMove(kin_, q_start_, X_goal, options_);
  ASSERT_TRUE(fast.ok) << fast.reason;
  EXPECT_GT(slow.trajectory.duration_s(), 1.5 * fast.trajectory.duration_s());
  const auto& p = slow.trajectory.points;
  for (std::size_t i = 1; i < p.size(); ++i) {
    const JointVector v = (p[i].q_rad - p[i - 1].q_rad) / (p[i].time_s - p[i - 1].time_s);
    ASSERT_LE(v.cwiseAbs().maxCoeff(), 0.05 * (1 + 1e-9));
  }
}

TEST_F(LinearMoveTest, RefusesATinyToolSpeed) {
  Eigen::Isometry3d X_goal = kin_.ForwardKinematics(q_start_);
  X_goal.translation() += Eigen::Vector3d(0.0, 0.0, -0.1);
  options_.max_tool_speed_m_s = 1e-300;
  const LinearMoveResult r = PlanLinearMove(kin_, q_start_, X_goal, options_);
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.reason.find("600 s limit"), std::string::npos) << r.reason;
  EXPECT_TRUE(r.trajectory.points.empty());
}

TEST_F(LinearMoveTest, UnreachableLineFailsWithSample) {
  const Eigen::Isometry3d X_start = kin_.ForwardKinematics(q_start_);
  Eigen::Isometry3d X_goal = X_start;
  X_goal.translation() = Eigen::Vector3d(2.5, 0.0, 0.5);
  const LinearMoveResult r = PlanLinearMove(kin_, q_start_, X_goal, options_);
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.reason.find("sample"), std::string::npos) << r.reason;
  EXPECT_NE(r.reason.find("not reachable"), std::string::npos) << r.reason;
}

TEST_F(LinearMoveTest, LineThroughWristSingularityIsRefused) {
  // Start near q5 = 0 and move so that q5 must change sign: the branch (wrist up) is lost.
  JointVector q = q_start_;
  q[4] = 0.05;
  const Eigen::Isometry3d X_start = kin_.ForwardKinematics(q);
  JointVector q_other = q;
  q_other[4] = -0.05;
  const Eigen::Isometry3d X_goal = kin_.ForwardKinematics(q_other);
  const LinearMoveResult r = SampleLinearPath(kin_, q, X_goal, options_);
  EXPECT_FALSE(r.ok);
  EXPECT_FALSE(r.reason.empty());
  (void)X_start;
}

}  // namespace
}  // namespace picking::robot
