#include "libs/ur10/kinematics.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace picking::ur10 {
namespace {

constexpr double kPi = 3.14159265358979323846;

Ur10Model LoadModel() { return Ur10Model::Load(std::string(PICKING_DATA_DIR) + "/ur10"); }

JointVector RandomJoints(std::mt19937& rng) {
  std::uniform_real_distribution<double> angle(-kPi, kPi);
  JointVector q;
  for (int j = 0; j < kNumJoints; ++j) q[j] = angle(rng);
  return q;
}

// Largest of the position error (m) and the rotation error (rad).
double PoseError(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  const double dp = (a.translation() - b.translation()).norm();
  const double dr = Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle();
  return std::max(dp, dr);
}

// Largest joint difference modulo 2*pi.
double AngleDistance(const JointVector& a, const JointVector& b) {
  double d = 0.0;
  for (int j = 0; j < kNumJoints; ++j) d = std::max(d, std::abs(WrapToPi(a[j] - b[j])));
  return d;
}

const IkSolution* Find(const IkResult& result, const JointVector& q, double tol) {
  for (const auto& s : result.solutions) {
    if (AngleDistance(s.q_rad, q) < tol) return &s;
  }
  return nullptr;
}

bool Contains(const IkResult& result, const JointVector& q, double tol) {
  return Find(result, q, tol) != nullptr;
}

class KinematicsTest : public ::testing::Test {
 protected:
  KinematicsTest() : kin_(LoadModel()) {}
  // Every solution reproduces the pose, lies within the limits and carries its own branch.
  void ExpectAllSolutionsValid(const IkResult& result, const Eigen::Isometry3d& X, double tol) {
    for (const auto& s : result.solutions) {
      EXPECT_LT(PoseError(kin_.ForwardKinematics(s.q_rad), X), tol)
          << s.branch.ToString() << " q=" << s.q_rad.transpose();
      EXPECT_TRUE(kin_.model().WithinPositionLimits(s.q_rad));
      if (!s.wrist_singular && !s.elbow_singular && !s.shoulder_singular) {
        EXPECT_EQ(kin_.BranchOf(s.q_rad), s.branch) << s.q_rad.transpose();
      }
    }
  }
  Ur10Kinematics kin_;
};

TEST_F(KinematicsTest, ZeroConfigurationPose) {
  // At q = 0 the UR arm lies along -x: p = (a2 + a3, -(d4 + d6), d1 - d5), tool z along -y.
  const Eigen::Isometry3d X = kin_.ForwardKinematics(JointVector::Zero());
  EXPECT_NEAR(X.translation().x(), -0.612 - 0.5723, 1e-12);
  EXPECT_NEAR(X.translation().y(), -(0.163941 + 0.0922), 1e-12);
  EXPECT_NEAR(X.translation().z(), 0.1273 - 0.1157, 1e-12);
  EXPECT_TRUE(X.linear().col(2).isApprox(Eigen::Vector3d(0, -1, 0), 1e-12));
}

TEST_F(KinematicsTest, DhFramesEndAtTool) {
  std::mt19937 rng(1);
  const JointVector q = RandomJoints(rng);
  const auto frames = kin_.DhFrames(q);
  EXPECT_TRUE(frames[0].isApprox(Eigen::Isometry3d::Identity()));
  EXPECT_LT(PoseError(frames[6], kin_.ForwardKinematics(q)), 1e-12);
}

TEST_F(KinematicsTest, UrdfLinkChainAgreesWithDhChain) {
  std::mt19937 rng(2);
  for (int i = 0; i < 200; ++i) {
    const JointVector q = RandomJoints(rng);
    const auto links = kin_.LinkFrames(q);
    const Eigen::Isometry3d X_tool = links[6] * kin_.model().X_Wrist3Tool();
    ASSERT_LT(PoseError(X_tool, kin_.ForwardKinematics(q)), 1e-9) << q.transpose();
    // Joint axes coincide: link i's z axis is DH frame (i-1)'s z axis.
    const auto dh = kin_.DhFrames(q);
    for (int j = 1; j < kNumLinks; ++j) {
      ASSERT_LT((links[j].linear().col(2) - dh[j - 1].linear().col(2)).norm(), 1e-9);
    }
  }
}

TEST_F(KinematicsTest, RandomPosesRoundTripOnEveryBranch) {
  std::mt19937 rng(42);
  int total_solutions = 0;
  for (int i = 0; i < 5000; ++i) {
    const JointVector q = RandomJoints(rng);
    const Eigen::Isometry3d X = kin_.ForwardKinematics(q);
    const IkResult result = kin_.Solve(X);
    ASSERT_FALSE(result.empty()) << result.reason;
    ExpectAllSolutionsValid(result, X, 1e-9);
    ASSERT_TRUE(Contains(result, q, 1e-7)) << "q=" << q.transpose();
    for (const auto& s : result.solutions) {
      for (int j = 0; j < kNumJoints; ++j) {
        ASSERT_GT(s.q_rad[j], -kPi - 1e-12);
        ASSERT_LE(s.q_rad[j], kPi + 1e-12);
      }
    }
    total_solutions += static_cast<int>(result.solutions.size());
    if (HasFailure()) return;
  }
  // Generic poses have all 8 branches unless an elbow solution is cut by the reach.
  EXPECT_GT(total_solutions, 5000 * 4);
}

TEST_F(KinematicsTest, GeneratingBranchIsReported) {
  std::mt19937 rng(7);
  for (int i = 0; i < 500; ++i) {
    const JointVector q = RandomJoints(rng);
    const IkResult result = kin_.Solve(kin_.ForwardKinematics(q));
    const Branch b = kin_.BranchOf(q);
    bool found = false;
    for (const auto& s : result.solutions) {
      if (s.branch == b && AngleDistance(s.q_rad, q) < 1e-7) found = true;
    }
    ASSERT_TRUE(found) << b.ToString() << " q=" << q.transpose();
  }
}

TEST_F(KinematicsTest, TwoPiVariantsWithinLimits) {
  std::mt19937 rng(3);
  IkOptions options;
  options.include_2pi_variants = true;
  for (int i = 0; i < 50; ++i) {
    const JointVector q = RandomJoints(rng);
    const Eigen::Isometry3d X = kin_.ForwardKinematics(q);
    const IkResult plain = kin_.Solve(X);
    const IkResult all = kin_.Solve(X, options);
    // +-2*pi on joints 1, 2, 4, 5, 6 (limits +-2*pi), never on the elbow (+-pi).
    EXPECT_EQ(all.solutions.size(), plain.solutions.size() * 32);
    ExpectAllSolutionsValid(all, X, 1e-9);
    JointVector shifted = q;
    shifted[0] += q[0] > 0 ? -2 * kPi : 2 * kPi;
    shifted[5] += q[5] > 0 ? -2 * kPi : 2 * kPi;
    bool found = false;
    for (const auto& s : all.solutions) {
      if ((s.q_rad - shifted).cwiseAbs().maxCoeff() < 1e-7) found = true;
    }
    EXPECT_TRUE(found);
  }
}

TEST_F(KinematicsTest, NearestSolutionFollowsSeed) {
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0.0, 0.02);
  for (int i = 0; i < 300; ++i) {
    JointVector q = RandomJoints(rng);
    q[0] += q[0] < 0 ? 2 * kPi : 0.0;  // a variant beyond pi, within +-2*pi
    JointVector seed = q;
    for (int j = 0; j < kNumJoints; ++j) seed[j] += noise(rng);
    const auto sol = kin_.NearestSolution(kin_.ForwardKinematics(q), seed);
    ASSERT_TRUE(sol.has_value());
    EXPECT_LT((sol->q_rad - q).cwiseAbs().maxCoeff(), 1e-7)
        << "q=" << q.transpose() << " got " << sol->q_rad.transpose();
  }
}

TEST_F(KinematicsTest, NearestSolutionOnRequestedBranch) {
  std::mt19937 rng(9);
  const JointVector q = RandomJoints(rng);
  const Eigen::Isometry3d X = kin_.ForwardKinematics(q);
  const IkResult all = kin_.Solve(X);
  for (const auto& s : all.solutions) {
    const auto sol = kin_.NearestSolution(X, q, s.branch);
    ASSERT_TRUE(sol.has_value());
    EXPECT_EQ(sol->branch, s.branch);
    EXPECT_LT(PoseError(kin_.ForwardKinematics(sol->q_rad), X), 1e-9);
  }
}

TEST_F(KinematicsTest, IdentityLikeConfigurationIsWristSingular) {
  const JointVector q = JointVector::Zero();
  IkOptions options;
  options.seed_rad = q;
  const Eigen::Isometry3d X = kin_.ForwardKinematics(q);
  const IkResult result = kin_.Solve(X, options);
  ASSERT_FALSE(result.empty()) << result.reason;
  ExpectAllSolutionsValid(result, X, 1e-9);
  // q = 0 is also a stretched elbow: q3 is only determined to ~sqrt(machine epsilon).
  const IkSolution* found = Find(result, q, 1e-7);
  ASSERT_NE(found, nullptr);
  EXPECT_TRUE(found->wrist_singular);
  EXPECT_TRUE(found->elbow_singular);
}

TEST_F(KinematicsTest, WristSingularityTakesQ6FromSeed) {
  std::mt19937 rng(11);
  for (int i = 0; i < 200; ++i) {
    JointVector q = RandomJoints(rng);
    q[4] = (i % 2 == 0) ? 0.0 : kPi;  // q5 = 0 or pi: joints 4 and 6 aligned
    const Eigen::Isometry3d X = kin_.ForwardKinematics(q);
    IkOptions options;
    options.seed_rad = q;
    const IkResult result = kin_.Solve(X, options);
    ASSERT_FALSE(result.empty()) << result.reason;
    ExpectAllSolutionsValid(result, X, 1e-9);
    const IkSolution* found = Find(result, q, 1e-7);
    ASSERT_NE(found, nullptr) << q.transpose();
    EXPECT_TRUE(found->wrist_singular);
    EXPECT_EQ(found->q_rad[5], q[5]);  // the seed's q6 is kept where it is reachable
    // Without seed q6 is 0 or, where 0 cannot reach, a multiple of 5 degrees; the pose is
    // reproduced either way.
    const IkResult unseeded = kin_.Solve(X);
    ExpectAllSolutionsValid(unseeded, X, 1e-9);
    int singular = 0;
    for (const auto& s : unseeded.solutions) {
      if (!s.wrist_singular) continue;
      const double steps = s.q_rad[5] / (kPi / 36.0);
      EXPECT_NEAR(steps, std::round(steps), 1e-9);
      ++singular;
    }
    EXPECT_GT(singular, 0) << q.transpose() << " n=" << unseeded.solutions.size() << " "
                           << unseeded.reason;
  }
}

TEST_F(KinematicsTest, NearWristSingularityIsStillExact) {
  std::mt19937 rng(12);
  for (double q5 : {1e-4, 1e-6, 1e-8, -1e-7}) {
    for (int i = 0; i < 50; ++i) {
      JointVector q = RandomJoints(rng);
      q[4] = q5;
      const Eigen::Isometry3d X = kin_.ForwardKinematics(q);
      IkOptions options;
      options.seed_rad = q;
      const IkResult result = kin_.Solve(X, options);
      ExpectAllSolutionsValid(result, X, 1e-8);
      // Near the singularity a pose rounding error e moves q4/q6 by about e / |sin(q5)|.
      EXPECT_TRUE(Contains(result, q, std::max(1e-7, 1e-13 / std::abs(q5)))) << q.transpose();
    }
  }
}

TEST_F(KinematicsTest, ShoulderSingularityWristCentreOverBase) {
  // Wrist centre in the vertical plane through the base axis (p5 . x1 = 0): both shoulder
  // branches coincide.
  const auto& dh = kin_.model().dh();
  std::mt19937 rng(13);
  std::uniform_real_distribution<double> angle(-kPi, kPi);
  int tested = 0;
  while (tested < 100) {
    JointVector q = RandomJoints(rng);
    const double horizontal = dh.a2 * std::cos(q[1]) + dh.a3 * std::cos(q[1] + q[2]);
    const double s234 = -horizontal / dh.d5;
    if (std::abs(s234) > 1.0) continue;
    q[3] = WrapToPi(std::asin(s234) - q[1] - q[2]);
    const Eigen::Isometry3d X = kin_.ForwardKinematics(q);
    const Eigen::Vector3d p5 = X.translation() - dh.d6 * X.linear().col(2);
    ASSERT_NEAR(std::hypot(p5.x(), p5.y()), dh.d4, 1e-9);
    IkOptions options;
    options.seed_rad = q;
    const IkResult result = kin_.Solve(X, options);
    ASSERT_FALSE(result.empty()) << result.reason;
    ExpectAllSolutionsValid(result, X, 1e-6);
    EXPECT_TRUE(Contains(result, q, 1e-5)) << q.transpose();
    for (const auto& s : result.solutions) EXPECT_TRUE(s.shoulder_singular);
    ++tested;
  }
}

TEST_F(KinematicsTest, StretchedArm) {
  std::mt19937 rng(14);
  for (int i = 0; i < 100; ++i) {
    JointVector q = RandomJoints(rng);
    q[2] = 0.0;
    const Eigen::Isometry3d X = kin_.ForwardKinematics(q);
    const IkResult result = kin_.Solve(X);
    ASSERT_FALSE(result.empty()) << result.reason;
    ExpectAllSolutionsValid(result, X, 1e-6);
    const IkSolution* found = Find(result, q, 1e-6);
    ASSERT_NE(found, nullptr) << q.transpose();
    EXPECT_TRUE(found->elbow_singular);
  }
}

TEST_F(KinematicsTest, OutOfReachGivesReason) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(2.0, 0.3, 0.4);
  IkResult result = kin_.Solve(X);
  EXPECT_TRUE(result.empty());
  EXPECT_NE(result.reason.find("out of reach"), std::string::npos) << result.reason;

  // Wrist centre on the base axis: closer than the shoulder offset d4.
  X.translation() = Eigen::Vector3d(0.0, 0.0, 0.5 + kin_.model().dh().d6);
  result = kin_.Solve(X);
  EXPECT_TRUE(result.empty());
  EXPECT_NE(result.reason.find("shoulder offset"), std::string::npos) << result.reason;
}

TEST_F(KinematicsTest, InvalidInputIsRefused) {
  Eigen::Isometry3d X = kin_.ForwardKinematics(JointVector::Constant(0.5));
  X.translation().x() = std::nan("");
  EXPECT_TRUE(kin_.Solve(X).empty());
  EXPECT_NE(kin_.Solve(X).reason.find("invalid pose"), std::string::npos);
  Eigen::Isometry3d scaled = kin_.ForwardKinematics(JointVector::Constant(0.5));
  scaled.linear() *= 1.1;
  EXPECT_TRUE(kin_.Solve(scaled).empty());
  IkOptions options;
  options.seed_rad = JointVector::Constant(std::nan(""));
  EXPECT_TRUE(kin_.Solve(kin_.ForwardKinematics(JointVector::Constant(0.5)), options).empty());
}

TEST_F(KinematicsTest, TighterLimitsDropBranches) {
  Ur10Model model = LoadModel();
  auto limits = model.limits();
  limits[2].min_position_rad = 0.0;  // elbow up only
  model.set_limits(limits);
  const Ur10Kinematics kin(model);
  std::mt19937 rng(15);
  for (int i = 0; i < 100; ++i) {
    const IkResult result = kin.Solve(kin.ForwardKinematics(RandomJoints(rng)));
    for (const auto& s : result.solutions) {
      EXPECT_EQ(s.branch.elbow, Branch::Elbow::kUp);
      EXPECT_GE(s.q_rad[2], 0.0);
    }
  }
}

TEST_F(KinematicsTest, BranchIdRoundTrip) {
  for (int id = 0; id < 8; ++id) EXPECT_EQ(Branch::FromId(id).id(), id);
  EXPECT_EQ(Branch::FromId(5).ToString(), "shoulder_right/wrist_up/elbow_down");
}

TEST_F(KinematicsTest, JacobianMatchesFiniteDifferences) {
  std::mt19937 rng(16);
  const double h = 1e-6;
  for (int i = 0; i < 100; ++i) {
    const JointVector q = RandomJoints(rng);
    const Eigen::Matrix<double, 6, 6> J = kin_.Jacobian(q);
    const Eigen::Isometry3d X = kin_.ForwardKinematics(q);
    for (int j = 0; j < kNumJoints; ++j) {
      JointVector qp = q, qm = q;
      qp[j] += h;
      qm[j] -= h;
      const Eigen::Isometry3d Xp = kin_.ForwardKinematics(qp);
      const Eigen::Isometry3d Xm = kin_.ForwardKinematics(qm);
      const Eigen::Vector3d v = (Xp.translation() - Xm.translation()) / (2 * h);
      const Eigen::AngleAxisd dR(Xp.linear() * Xm.linear().transpose());
      const Eigen::Vector3d w = dR.axis() * dR.angle() / (2 * h);
      EXPECT_LT((J.block<3, 1>(0, j) - v).norm(), 1e-6);
      EXPECT_LT((J.block<3, 1>(3, j) - w).norm(), 1e-6);
    }
    (void)X;
  }
}

TEST_F(KinematicsTest, SingularityMeasure) {
  JointVector q;
  q << 0.3, -1.2, 1.5, -1.9, -1.57, 0.2;
  const double generic = kin_.SingularityMeasure(q);
  EXPECT_GT(generic, 0.05);
  q[4] = 0.0;  // wrist singularity
  EXPECT_LT(kin_.SingularityMeasure(q), 1e-9);
  q[4] = -1.57;
  q[2] = 0.0;  // stretched elbow
  EXPECT_LT(kin_.SingularityMeasure(q), 1e-9);
}

TEST_F(KinematicsTest, WrenchFromJointTorquesInvertsJacobianTranspose) {
  std::mt19937 rng(17);
  std::normal_distribution<double> n(0.0, 10.0);
  JointVector q;
  q << 0.3, -1.2, 1.5, -1.9, -1.57, 0.2;
  Eigen::Matrix<double, 6, 1> w;
  for (int i = 0; i < 6; ++i) w[i] = n(rng);
  const JointVector tau = kin_.Jacobian(q).transpose() * w;
  EXPECT_LT((kin_.WrenchFromJointTorques(q, tau) - w).norm(), 1e-8);
}

}  // namespace
}  // namespace picking::ur10
