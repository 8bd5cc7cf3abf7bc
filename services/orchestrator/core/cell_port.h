#pragma once

#include <Eigen/Geometry>

#include <array>
#include <future>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "libs/geometry/point_cloud.h"
#include "services/orchestrator/core/held_surface.h"

namespace picking::orchestrator {

/// A service of the cell did not answer as it should (it is down, timed out, or refused the
/// request for a reason that is not the item's). `retryable` failures (the service did not
/// answer: UNAVAILABLE, DEADLINE_EXCEEDED) are retried with backoff by the task.
class CellError : public std::runtime_error {
 public:
  CellError(std::string service, bool retryable, const std::string& what)
      : std::runtime_error(service + ": " + what),
        service_(std::move(service)),
        retryable_(retryable) {}
  const std::string& service() const { return service_; }
  bool retryable() const { return retryable_; }

 private:
  std::string service_;
  bool retryable_;
};

/// The robot refused a motion before it started (its own checks of the path): nothing
/// moved.
class MotionRefused final : public CellError {
 public:
  explicit MotionRefused(const std::string& what) : CellError("robot", false, what) {}
};

/// A physical step: ok, or why not, and the robot time it took (seconds).
struct StepOutcome {
  bool ok = true;
  std::string message;
  double robot_s = 0.0;
};

/// One view of a scan: an organised cloud in the base frame and where its camera was.
struct ScanView {
  std::shared_ptr<const geometry::PointCloud> cloud_Base;
  Eigen::Isometry3d X_BaseCamera = Eigen::Isometry3d::Identity();
  /// The suction cup's pose at the capture (a held item hangs from it there, wherever the
  /// arm has moved since).
  Eigen::Isometry3d X_BaseTcp = Eigen::Isometry3d::Identity();
  double capture_s = 0.0;  ///< Robot time the capture held the arm still.
};

/// One pose the detector found for an item, with its score.
struct PoseHypothesis {
  Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();
  double score = 0.0;
};

/// Where the detector put another item of the container, looked for beside the target: its
/// distinct poses above the item's threshold, best first.
struct OtherDetection {
  std::string item;
  std::vector<PoseHypothesis> poses;
};

struct Detection {
  bool found = false;
  Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();
  double score = 0.0;
  std::string method;
  std::string replica;  ///< Which detector answered.
  std::string message;  ///< Why not found, when not.
  /// The target's further distinct poses above its threshold, best first (asked for with
  /// `others`).
  std::vector<PoseHypothesis> alternatives;
  /// Each of the `others` asked for that the detector found.
  std::vector<OtherDetection> others;
};

/// A planned pick; `handle` lets the port find its trajectories again.
struct PlannedPick {
  bool ok = false;
  std::string message;  ///< Why there is no plan.
  std::string grasp;    ///< The grasp's surface.
  int handle = -1;
  double approach_s = 0.0, descend_s = 0.0, retreat_s = 0.0;
  /// The joint waypoints of the approach, descent and retreat, thinned (for a viewer).
  std::vector<std::array<double, 6>> path_q;
  double head_angle_rad = 0.0;
  /// How far along the guarded move the grasp's surface lies as detected (0: unknown).
  double contact_distance_m = 0.0;
  /// Unit direction of the guarded move, base frame (zero: unknown).
  Eigen::Vector3d guarded_direction_Base = Eigen::Vector3d::Zero();
  /// Without a plan: what stops it is the scan (another item: over the target, beside it,
  /// in the gripper's way), or no grasp has room behind it. Moving another item aside may
  /// make the pick possible.
  bool others_in_the_way = false;
};

struct TouchOutcome {
  bool contact = false;
  double distance_m = 0.0;
  double robot_s = 0.0;
  /// Why the robot refused the move before it started (its own check of the path), or "".
  std::string refused;
};

/// The gripper's reading: is the cup sealed on something.
struct SealReading {
  bool attached = false;
  double vacuum_kpa = 0.0;
};

struct PlaceOutcome {
  bool ok = true;
  std::string message;
  double drop_height_m = 0.0;
  double robot_s = 0.0;
  /// The robot stopped on the way (it touched something): the item was let go there.
  bool item_lost = false;
};

/// What a task needs from the cell: each operation one step of the paper's sequence, done by
/// the cell's services (scanner, detector pool, planner, robot, gripper). Operations throw
/// CellError when a service fails; an item-level "no" (not found, no plan, no contact) is an
/// outcome. Used from one task thread at a time.
class CellPort {
 public:
  virtual ~CellPort() = default;
  /// The named scan poses of a container ("scan/bin_A/0" ...), in capture order.
  virtual std::vector<std::string> ScanPoses(const std::string& container) = 0;
  /// Plans a joint motion from the current joints to a named pose and executes it.
  virtual StepOutcome MoveToNamed(const std::string& name) = 0;
  /// Captures one view at the current pose.
  virtual ScanView Scan() = 0;
  /// Captures one view at the current pose and returns once the capture is over, while the
  /// scanner still decodes it: the arm may move on. The future gives the view, or throws
  /// CellError for a scan that fails after its capture; a failure before it throws here. By
  /// default the whole scan, then a ready future.
  virtual std::shared_future<ScanView> StartScan() {
    std::promise<ScanView> done;
    done.set_value(Scan());
    return done.get_future().share();
  }
  /// Finds `item` in `container` from the views (merged by the detector), and in the same
  /// call the poses of each of `others` (other items of the container); with others, a few
  /// poses of the target too.
  virtual Detection Detect(const std::string& container, const std::string& item,
                           const std::vector<ScanView>& views,
                           const std::vector<std::string>& others = {}) = 0;
  /// Builds the planner's scene from the views with the item cut out and plans the pick from
  /// the current joints.
  virtual PlannedPick PlanPick(const std::string& container, const std::string& item,
                               const Eigen::Isometry3d& X_BaseItem,
                               const std::vector<ScanView>& views) = 0;
  /// Executes the approach and the descent to a few centimetres short of contact.
  virtual StepOutcome ExecuteApproach(const PlannedPick& pick) = 0;
  /// The guarded move along the approach until the force threshold.
  virtual TouchOutcome Touch(const PlannedPick& pick) = 0;
  /// Vacuum on; returns once sealed or after the seal wait.
  virtual SealReading VacuumOn() = 0;
  virtual SealReading ReadSeal() = 0;
  /// Back to the planned grasp joints and out of the container along the retreat.
  virtual StepOutcome ExecuteRetreat(const PlannedPick& pick) = 0;
  /// Plans from the current joints to the drop pose over `container` and moves there;
  /// `placed_before`: items already let go there by this task (each gets its own spot).
  virtual PlaceOutcome MoveToPlace(const std::string& item, const std::string& container,
                                   const PlannedPick& pick, int placed_before) = 0;
  virtual void VacuumOff() = 0;
  /// Puts a held item back where it was grasped (the retreat backwards), releases it and
  /// leaves the container again: the way out when no place can be planned.
  virtual StepOutcome PutBack(const PlannedPick& pick) = 0;
  /// Back along the last MoveToPlace's motion to where it started (the retreat's end), the
  /// item still held: the way back when the look back, finished while the arm carried the
  /// item on, finds the wrong item on the cup.
  virtual StepOutcome ReturnFromPlace() = 0;
  /// How well `item`, hanging from the cup as grasped, is supported by `view` (the detector's
  /// Verify score in [0, 1]); -1 when the view shows too little of it to tell.
  virtual double VerifyHeld(const std::string& item, const PlannedPick& pick,
                            const ScanView& view) = 0;
  /// What `view` (the look back out of `container`) shows of the space only the held item
  /// fills, against the box of `item` hanging from the cup as grasped (MeasureHeldSurface);
  /// nullopt where that cannot be told (by default).
  virtual std::optional<HeldSurface> MeasureHeld(const std::string& container,
                                                 const std::string& item, const PlannedPick& pick,
                                                 const ScanView& view) {
    (void)container, (void)item, (void)pick, (void)view;
    return std::nullopt;
  }
};

}  // namespace picking::orchestrator
