#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <optional>
#include <string>
#include <vector>

#include "libs/ur10/ur10_model.h"

namespace picking::ur10 {

/// One of the 8 analytic inverse kinematics branches.
///
/// - shoulder: kLeft when the wrist centre lies on the negative x side of frame 1 (the
///   "+acos" solution of the base joint), kRight otherwise;
/// - wrist: kUp when sin(q5) >= 0 (q5 in (-pi, pi]), kDown otherwise;
/// - elbow: kUp when sin(q3) >= 0 (q3 in (-pi, pi]), kDown otherwise.
///
/// The id is 4 * shoulder + 2 * wrist + elbow, in [0, 8).
struct Branch {
  enum class Shoulder { kLeft = 0, kRight = 1 };
  enum class Wrist { kUp = 0, kDown = 1 };
  enum class Elbow { kUp = 0, kDown = 1 };
  Shoulder shoulder = Shoulder::kLeft;
  Wrist wrist = Wrist::kUp;
  Elbow elbow = Elbow::kUp;

  int id() const {
    return 4 * static_cast<int>(shoulder) + 2 * static_cast<int>(wrist) + static_cast<int>(elbow);
  }
  static Branch FromId(int id);
  bool operator==(const Branch& o) const { return id() == o.id(); }
  bool operator!=(const Branch& o) const { return id() != o.id(); }
  /// E.g. "shoulder_left/wrist_up/elbow_down".
  std::string ToString() const;
};

/// One inverse kinematics solution.
struct IkSolution {
  JointVector q_rad = JointVector::Zero();
  Branch branch;
  /// |sin(q5)| below IkOptions::singularity_tolerance: joints 2, 3, 4 and 6 are parallel and
  /// q6 is not determined by the pose. q6 is the seed's (0 without seed) or, if the arm cannot
  /// reach the pose with that value, the closest value in 5 degree steps with which it can.
  bool wrist_singular = false;
  /// The wrist centre is at the shoulder offset distance from the base axis: both shoulder
  /// branches coincide.
  bool shoulder_singular = false;
  /// The arm is (nearly) stretched or folded (|sin(q3)| tiny): both elbow branches coincide.
  bool elbow_singular = false;
};

/// Options of Ur10Kinematics::Solve.
struct IkOptions {
  /// Seed joint vector: its q6 is used at a wrist singularity, and NearestSolution measures
  /// the distance to it. Without seed, q6 = 0 at a wrist singularity.
  std::optional<JointVector> seed_rad;
  /// Also return every +-2*pi variant of each solution that lies within the joint limits
  /// (the UR joints allow +-2*pi). Default: one variant per branch, each angle wrapped into
  /// (-pi, pi] (or moved by 2*pi into the limits if that range is not allowed), or, with a
  /// seed, each angle's variant closest to the seed.
  bool include_2pi_variants = false;
  /// |sin(q5)| below which the wrist is treated as singular.
  double singularity_tolerance = 1e-10;
  /// Slack for reach tests (cosines slightly beyond +-1 from rounding are clamped), unitless.
  double reach_tolerance = 1e-9;
};

/// Result of Ur10Kinematics::Solve.
struct IkResult {
  /// All solutions within the joint limits, unique, sorted by branch id (and, with 2*pi
  /// variants, by joint vector). Empty when the pose is not reachable.
  std::vector<IkSolution> solutions;
  /// Why `solutions` is empty (or which branches were dropped), for logs and errors.
  std::string reason;
  bool empty() const { return solutions.empty(); }
};

/// Forward and analytic inverse kinematics and the geometric Jacobian of the UR10 DH chain.
/// Frames: Base and Tool (flange, zero TCP) as in Ur10Model. Thread-safe (const).
class Ur10Kinematics final {
 public:
  explicit Ur10Kinematics(const Ur10Model& model);

  const Ur10Model& model() const { return model_; }

  /// Pose of the tool flange in the base frame, X_BaseTool(q). q in rad; no limit check.
  Eigen::Isometry3d ForwardKinematics(const JointVector& q_rad) const;

  /// Poses of the DH frames 0..6 in the base frame (frame 0 = Base, frame 6 = Tool).
  std::array<Eigen::Isometry3d, kNumJoints + 1> DhFrames(const JointVector& q_rad) const;

  /// Poses of the URDF link frames (base, shoulder, upper_arm, forearm, wrist_1, wrist_2,
  /// wrist_3) in the base frame, for placing the collision meshes
  /// (X_BaseMesh = X_BaseLink * model().X_LinkMesh(link)).
  std::array<Eigen::Isometry3d, kNumLinks> LinkFrames(const JointVector& q_rad) const;

  /// All inverse kinematics solutions of X_BaseTool within the joint limits.
  /// Returns an empty result with a reason for non-finite or non-rigid input or an
  /// unreachable pose.
  IkResult Solve(const Eigen::Isometry3d& X_BaseTool, const IkOptions& options = {}) const;

  /// The solution closest to `seed_rad` (largest joint difference first, then the sum of
  /// squares), considering every 2*pi variant; nullopt if the pose is unreachable.
  /// `branch`, if given, restricts the answer to that branch.
  std::optional<IkSolution> NearestSolution(const Eigen::Isometry3d& X_BaseTool,
                                            const JointVector& seed_rad,
                                            std::optional<Branch> branch = std::nullopt,
                                            std::string* reason = nullptr) const;

  /// The branch of a joint vector (see Branch).
  Branch BranchOf(const JointVector& q_rad) const;

  /// Geometric Jacobian at the tool flange origin in the base frame: rows 0-2 map joint
  /// speeds (rad/s) to the flange's linear velocity (m/s), rows 3-5 to its angular velocity
  /// (rad/s).
  Eigen::Matrix<double, 6, 6> Jacobian(const JointVector& q_rad) const;

  /// Smallest singular value of the Jacobian with its linear rows scaled by 1/reach (so both
  /// halves are unitless); near 0 at a singularity.
  double SingularityMeasure(const JointVector& q_rad) const;

  /// Wrench at the tool flange in the base frame [force (N); torque (Nm)] that balances the
  /// joint torques `tau_nm` (tau = J^T w), least squares via the pseudo-inverse.
  Eigen::Matrix<double, 6, 1> WrenchFromJointTorques(const JointVector& q_rad,
                                                     const JointVector& tau_nm) const;

 private:
  // Solutions of the 8 branches with angles in (-pi, pi] (not limit-checked).
  std::vector<IkSolution> SolveRaw(const Eigen::Isometry3d& X_BaseTool, const IkOptions& options,
                                   std::string* reason) const;

  Ur10Model model_;
};

/// Wraps an angle into (-pi, pi].
double WrapToPi(double angle_rad);

}  // namespace picking::ur10
