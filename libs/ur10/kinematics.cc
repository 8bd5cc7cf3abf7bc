#include "libs/ur10/kinematics.h"

#include <Eigen/QR>
#include <Eigen/SVD>

#include <algorithm>
#include <cmath>
#include <sstream>

#include "libs/geometry/pose.h"

namespace picking::ur10 {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kTwoPi = 2.0 * kPi;

// alpha = [pi/2, 0, 0, pi/2, -pi/2, 0] of the UR.
constexpr double kCosAlpha[kNumJoints] = {0.0, 1.0, 1.0, 0.0, 0.0, 1.0};
constexpr double kSinAlpha[kNumJoints] = {1.0, 0.0, 0.0, 1.0, -1.0, 0.0};

// X = X * (joint i's standard DH transform Rz(theta) Tz(d) Tx(a) Rx(alpha)): the turn rotates
// the frame's x and y columns, and alpha of +-pi/2 or 0 swaps and negates columns, so a joint
// costs a few multiplications instead of a matrix product (the planner's forward kinematics
// run for every state and sample).
void ApplyJoint(const DhParameters& dh, int i, double theta, Eigen::Isometry3d* X) {
  const double d[kNumJoints] = {dh.d1, 0.0, 0.0, dh.d4, dh.d5, dh.d6};
  const double a[kNumJoints] = {0.0, dh.a2, dh.a3, 0.0, 0.0, 0.0};
  const double c = std::cos(theta);
  const double s = std::sin(theta);
  auto R = X->linear();
  const Eigen::Vector3d x = c * R.col(0) + s * R.col(1);  // Rz(theta)
  const Eigen::Vector3d y = c * R.col(1) - s * R.col(0);
  const Eigen::Vector3d z = R.col(2);
  X->translation() += d[i] * z + a[i] * x;  // Tz(d) Tx(a)
  // Rx(alpha): y' = cos(alpha) y + sin(alpha) z, z' = -sin(alpha) y + cos(alpha) z.
  R.col(0) = x;
  R.col(1) = kCosAlpha[i] * y + kSinAlpha[i] * z;
  R.col(2) = kCosAlpha[i] * z - kSinAlpha[i] * y;
}

// Joint i's DH transform alone.
Eigen::Isometry3d Joint(const DhParameters& dh, int i, double theta) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  ApplyJoint(dh, i, theta, &X);
  return X;
}

// Orders joint vectors by (max |difference|, sum of squared differences) to `seed`.
std::pair<double, double> Distance(const JointVector& q, const JointVector& seed) {
  const JointVector diff = (q - seed).cwiseAbs();
  return {diff.maxCoeff(), diff.squaredNorm()};
}

}  // namespace

double WrapToPi(double angle_rad) {
  double a = std::fmod(angle_rad, kTwoPi);
  if (a <= -kPi) a += kTwoPi;
  if (a > kPi) a -= kTwoPi;
  return a;
}

Branch Branch::FromId(int id) {
  Branch b;
  b.shoulder = (id & 4) ? Shoulder::kRight : Shoulder::kLeft;
  b.wrist = (id & 2) ? Wrist::kDown : Wrist::kUp;
  b.elbow = (id & 1) ? Elbow::kDown : Elbow::kUp;
  return b;
}

std::string Branch::ToString() const {
  std::string s = shoulder == Shoulder::kLeft ? "shoulder_left" : "shoulder_right";
  s += wrist == Wrist::kUp ? "/wrist_up" : "/wrist_down";
  s += elbow == Elbow::kUp ? "/elbow_up" : "/elbow_down";
  return s;
}

Ur10Kinematics::Ur10Kinematics(const Ur10Model& model) : model_(model) {}

std::array<Eigen::Isometry3d, kNumJoints + 1> Ur10Kinematics::DhFrames(
    const JointVector& q_rad) const {
  std::array<Eigen::Isometry3d, kNumJoints + 1> X;
  X[0] = Eigen::Isometry3d::Identity();
  for (int i = 0; i < kNumJoints; ++i) {
    X[i + 1] = X[i];
    ApplyJoint(model_.dh(), i, q_rad[i], &X[i + 1]);
  }
  return X;
}

Eigen::Isometry3d Ur10Kinematics::ForwardKinematics(const JointVector& q_rad) const {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  for (int i = 0; i < kNumJoints; ++i) ApplyJoint(model_.dh(), i, q_rad[i], &X);
  return X;
}

std::array<Eigen::Isometry3d, kNumLinks> Ur10Kinematics::LinkFrames(
    const JointVector& q_rad) const {
  std::array<Eigen::Isometry3d, kNumLinks> X;
  X[0] = model_.X_ParentLink(Link::kBase);
  for (int i = 1; i < kNumLinks; ++i) {
    X[i] = X[i - 1] * model_.X_ParentLink(static_cast<Link>(i));
    // The joint turns the link about its own z axis: a rotation of the frame's x and y
    // columns, cheaper than composing a rotation matrix (the planner's checks call this
    // for every state).
    const double c = std::cos(q_rad[i - 1]);
    const double s = std::sin(q_rad[i - 1]);
    auto R = X[i].linear();
    const Eigen::Vector3d x = R.col(0);
    const Eigen::Vector3d y = R.col(1);
    R.col(0) = c * x + s * y;
    R.col(1) = c * y - s * x;
  }
  return X;
}

Branch Ur10Kinematics::BranchOf(const JointVector& q_rad) const {
  const Eigen::Isometry3d X = ForwardKinematics(q_rad);
  const Eigen::Vector3d p5 = X.translation() - model_.dh().d6 * X.linear().col(2);
  const double c1 = std::cos(q_rad[0]);
  const double s1 = std::sin(q_rad[0]);
  Branch b;
  b.shoulder =
      (p5.x() * c1 + p5.y() * s1 <= 0.0) ? Branch::Shoulder::kLeft : Branch::Shoulder::kRight;
  b.wrist = std::sin(q_rad[4]) >= 0.0 ? Branch::Wrist::kUp : Branch::Wrist::kDown;
  b.elbow = std::sin(q_rad[2]) >= 0.0 ? Branch::Elbow::kUp : Branch::Elbow::kDown;
  return b;
}

std::vector<IkSolution> Ur10Kinematics::SolveRaw(const Eigen::Isometry3d& X_BaseTool,
                                                 const IkOptions& options,
                                                 std::string* reason) const {
  const DhParameters& dh = model_.dh();
  const Eigen::Matrix3d R = X_BaseTool.linear();
  const Eigen::Vector3d p = X_BaseTool.translation();
  const double tol = options.reach_tolerance;
  std::vector<IkSolution> out;

  // Base joint: the wrist centre p5 lies in the plane at distance d4 from the base axis.
  const Eigen::Vector3d p5 = p - dh.d6 * R.col(2);
  const double r = std::hypot(p5.x(), p5.y());
  if (r < dh.d4 * (1.0 - tol)) {
    std::ostringstream os;
    os << "unreachable: the wrist centre is " << r
       << " m from the base axis, closer than the shoulder offset d4 = " << dh.d4 << " m";
    *reason = os.str();
    return out;
  }
  const double cos_phi = std::clamp(dh.d4 / std::max(r, 1e-300), -1.0, 1.0);
  const double phi = std::acos(cos_phi);
  const double psi = std::atan2(p5.y(), p5.x());
  // Rounding leaves ~1e-8 m of in-plane distance at an exact singularity.
  const bool shoulder_singular = r * std::sin(phi) < 1e-6;

  std::ostringstream why;
  for (int shoulder = 0; shoulder < 2; ++shoulder) {
    const double q1 = psi + (shoulder == 0 ? phi : -phi) + kPi / 2.0;
    const double c1 = std::cos(q1);
    const double s1 = std::sin(q1);
    const Eigen::Vector3d z1(s1, -c1, 0.0);
    // In the tool frame, z1 = (s5 c6, -s5 s6, c5).
    const double c5 = R.col(2).dot(z1);
    const double s5c6 = R.col(0).dot(z1);
    const double ms5s6 = R.col(1).dot(z1);
    const double abs_s5 = std::hypot(s5c6, ms5s6);
    const bool wrist_singular = abs_s5 < options.singularity_tolerance;

    for (int wrist = 0; wrist < 2; ++wrist) {
      const double s5 = wrist == 0 ? abs_s5 : -abs_s5;
      const double q5 = std::atan2(s5, c5);
      // The planar 2R problem of joints 2 and 3 for a given q6; false if out of reach.
      auto solve_planar = [&](double q6, bool report) {
        const Eigen::Isometry3d X_01 = Joint(dh, 0, q1);
        const Eigen::Isometry3d X_46 = Joint(dh, 4, q5) * Joint(dh, 5, q6);
        const Eigen::Isometry3d X_14 = X_01.inverse() * X_BaseTool * X_46.inverse();
        const double x = X_14.translation().x();
        const double y = X_14.translation().y();
        const double c3 = (x * x + y * y - dh.a2 * dh.a2 - dh.a3 * dh.a3) / (2.0 * dh.a2 * dh.a3);
        if (std::abs(c3) > 1.0 + tol) {
          if (report) {
            why << "branch shoulder " << (shoulder == 0 ? "left" : "right") << " wrist "
                << (wrist == 0 ? "up" : "down") << ": out of reach (elbow cosine " << c3 << "); ";
          }
          return false;
        }
        const double acos3 = std::acos(std::clamp(c3, -1.0, 1.0));
        const double q234 = std::atan2(X_14.linear()(1, 0), X_14.linear()(0, 0));
        for (int elbow = 0; elbow < 2; ++elbow) {
          const double q3 = elbow == 0 ? acos3 : -acos3;
          const double q2 =
              std::atan2(y, x) - std::atan2(dh.a3 * std::sin(q3), dh.a2 + dh.a3 * std::cos(q3));
          const double q4 = q234 - q2 - q3;
          IkSolution sol;
          sol.q_rad << WrapToPi(q1), WrapToPi(q2), WrapToPi(q3), WrapToPi(q4), WrapToPi(q5),
              WrapToPi(q6);
          sol.branch.shoulder = shoulder == 0 ? Branch::Shoulder::kLeft : Branch::Shoulder::kRight;
          sol.branch.wrist = wrist == 0 ? Branch::Wrist::kUp : Branch::Wrist::kDown;
          sol.branch.elbow = elbow == 0 ? Branch::Elbow::kUp : Branch::Elbow::kDown;
          sol.wrist_singular = wrist_singular;
          sol.shoulder_singular = shoulder_singular;
          sol.elbow_singular = std::abs(std::sin(acos3)) < 1e-6;
          out.push_back(sol);
        }
        return true;
      };
      if (!wrist_singular) {
        solve_planar(std::atan2(-ms5s6 / s5, s5c6 / s5), true);
        continue;
      }
      // Wrist singularity: joints 2, 3, 4 and 6 are parallel and q6 is free. Take the seed's
      // q6 (0 without seed); if the arm cannot reach the pose with it, the closest value in
      // 5 degree steps for which it can.
      const double preferred = options.seed_rad ? (*options.seed_rad)[5] : 0.0;
      constexpr int kSteps = 72;
      for (int k = 0; k <= kSteps; ++k) {
        const double step = kPi / 36.0 * ((k + 1) / 2) * (k % 2 == 0 ? 1.0 : -1.0);
        if (solve_planar(preferred + step, k == kSteps)) break;
      }
    }
  }
  if (out.empty()) *reason = "unreachable: " + why.str();
  return out;
}

IkResult Ur10Kinematics::Solve(const Eigen::Isometry3d& X_BaseTool,
                               const IkOptions& options) const {
  IkResult result;
  if (!geometry::IsValidPose(X_BaseTool)) {
    result.reason = "invalid pose: not finite or its rotation is not orthonormal";
    return result;
  }
  if (options.seed_rad && !options.seed_rad->allFinite()) {
    result.reason = "invalid seed: not finite";
    return result;
  }
  std::string reason;
  const std::vector<IkSolution> raw = SolveRaw(X_BaseTool, options, &reason);
  if (raw.empty()) {
    result.reason = reason;
    return result;
  }
  const JointVector lo = model_.min_position_rad();
  const JointVector hi = model_.max_position_rad();
  const JointVector reference = options.seed_rad ? *options.seed_rad : JointVector::Zero();
  std::ostringstream dropped;
  for (const IkSolution& sol : raw) {
    // Candidate values of each joint: every 2*pi shift within the limits.
    std::array<std::vector<double>, kNumJoints> candidates;
    int missing_joint = -1;
    for (int j = 0; j < kNumJoints; ++j) {
      for (int k = -2; k <= 2; ++k) {
        const double v = sol.q_rad[j] + k * kTwoPi;
        if (v >= lo[j] && v <= hi[j]) candidates[j].push_back(v);
      }
      if (candidates[j].empty()) {
        missing_joint = j;
        break;
      }
      if (!options.include_2pi_variants) {
        const double best =
            *std::min_element(candidates[j].begin(), candidates[j].end(), [&](double a, double b) {
              return std::abs(a - reference[j]) < std::abs(b - reference[j]);
            });
        candidates[j] = {best};
      }
    }
    if (missing_joint >= 0) {
      dropped << sol.branch.ToString() << ": joint " << kJointNames[missing_joint] << " = "
              << sol.q_rad[missing_joint] << " rad outside its limits; ";
      continue;
    }
    // Cartesian product of the candidates.
    std::array<std::size_t, kNumJoints> idx{};
    while (true) {
      IkSolution variant = sol;
      for (int j = 0; j < kNumJoints; ++j) variant.q_rad[j] = candidates[j][idx[j]];
      const bool duplicate =
          std::any_of(result.solutions.begin(), result.solutions.end(), [&](const IkSolution& s) {
            return (s.q_rad - variant.q_rad).cwiseAbs().maxCoeff() < 1e-9;
          });
      if (!duplicate) result.solutions.push_back(variant);
      int j = 0;
      while (j < kNumJoints && ++idx[j] == candidates[j].size()) idx[j++] = 0;
      if (j == kNumJoints) break;
    }
  }
  std::stable_sort(result.solutions.begin(), result.solutions.end(),
                   [](const IkSolution& a, const IkSolution& b) {
                     if (a.branch.id() != b.branch.id()) return a.branch.id() < b.branch.id();
                     return std::lexicographical_compare(a.q_rad.data(), a.q_rad.data() + 6,
                                                         b.q_rad.data(), b.q_rad.data() + 6);
                   });
  result.reason = dropped.str();
  if (result.solutions.empty()) {
    result.reason = "no solution within the joint limits: " + result.reason;
  }
  return result;
}

std::optional<IkSolution> Ur10Kinematics::NearestSolution(const Eigen::Isometry3d& X_BaseTool,
                                                          const JointVector& seed_rad,
                                                          std::optional<Branch> branch,
                                                          std::string* reason) const {
  IkOptions options;
  options.seed_rad = seed_rad;
  const IkResult result = Solve(X_BaseTool, options);
  std::optional<IkSolution> best;
  std::pair<double, double> best_distance;
  for (const IkSolution& sol : result.solutions) {
    if (branch && sol.branch != *branch) continue;
    const auto d = Distance(sol.q_rad, seed_rad);
    if (!best || d < best_distance) {
      best = sol;
      best_distance = d;
    }
  }
  if (!best && reason) {
    *reason = result.empty() ? result.reason
                             : "no solution on branch " + branch->ToString() + "; " + result.reason;
  }
  return best;
}

Eigen::Matrix<double, 6, 6> Ur10Kinematics::Jacobian(const JointVector& q_rad) const {
  const auto X = DhFrames(q_rad);
  const Eigen::Vector3d p_tool = X[kNumJoints].translation();
  Eigen::Matrix<double, 6, 6> J;
  for (int i = 0; i < kNumJoints; ++i) {
    const Eigen::Vector3d z = X[i].linear().col(2);
    J.block<3, 1>(0, i) = z.cross(p_tool - X[i].translation());
    J.block<3, 1>(3, i) = z;
  }
  return J;
}

double Ur10Kinematics::SingularityMeasure(const JointVector& q_rad) const {
  const DhParameters& dh = model_.dh();
  const double reach = std::abs(dh.a2) + std::abs(dh.a3) + dh.d4 + dh.d5 + dh.d6;
  Eigen::MatrixXd J = Jacobian(q_rad);
  J.topRows(3) /= reach;
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(J);
  return svd.singularValues().minCoeff();
}

Eigen::Matrix<double, 6, 1> Ur10Kinematics::WrenchFromJointTorques(
    const JointVector& q_rad, const JointVector& tau_nm) const {
  const Eigen::Matrix<double, 6, 6> Jt = Jacobian(q_rad).transpose();
  return Jt.completeOrthogonalDecomposition().solve(tau_nm);
}

}  // namespace picking::ur10
