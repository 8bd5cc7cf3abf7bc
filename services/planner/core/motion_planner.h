#pragma once

#include <Eigen/Geometry>

#include <chrono>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "libs/world/cell_config.h"
#include "libs/world/item_models.h"
#include "services/planner/core/cartesian_search.h"
#include "services/planner/core/collision_world.h"
#include "services/planner/core/grasp_reach.h"
#include "services/planner/core/grasp_seal.h"
#include "services/planner/core/grasps.h"
#include "services/planner/core/plan_failure.h"
#include "services/planner/core/roadmap.h"
#include "services/planner/core/scene.h"
#include "services/planner/core/time_optimal.h"

namespace picking::planner {

class VoxelContacts;

using Deadline = std::chrono::steady_clock::time_point;

/// Settings of the planner's request-level workflows. Lengths in metres, angles in radians.
struct MotionPlannerOptions {
  CartesianSearchOptions search;
  MotionCheckOptions motion;
  RoadmapOptions roadmap;
  /// Plan the paths between every two named poses at start-up (Roadmap::CacheNamedPaths).
  bool cache_named_paths = true;
  GraspOptions grasp;
  /// A grasp whose cup cannot seal on the item's model (nor a little beside it) is refused
  /// before any search (ModelSeal); one that seals a little beside is moved there.
  ModelSealOptions seal;
  bool check_seal = true;
  StaticCellOptions cell;
  /// OctoMap resolution of scans and how far around the target container scan points are
  /// kept (the rest of the cell is the static cell's).
  double scene_resolution_m = 0.01;
  double scene_region_margin_m = 0.15;
  /// The target's convex hull is grown by this before its points and voxels are cut out.
  double cut_margin_m = 0.02;
  /// The descent ends this far short of the grasp; the robot's guarded move covers it and
  /// may go `guarded_overshoot_m` beyond (the item may sit a little deeper than detected),
  /// less where the arm would meet the cell (a thin item on a bin's floor).
  double guarded_distance_m = 0.05;
  double guarded_overshoot_m = 0.04;
  /// The retreat's first straight lift, upward; the carried item is checked against the scene
  /// by the fast check from the lift's end on (it rests on its support before), exactly (its
  /// box, FCL) from `lift_item_check_m` of lift on, plus however far the detected pose puts
  /// the box below the container's floor (the item rests on it, so it is not inside it).
  double lift_m = 0.05;
  double lift_item_check_m = 0.01;
  /// Where the straight lift meets something, the item is raised slide_height_m off its
  /// support, slid out toward the opening by each of slide_out_m in turn, level or rising by
  /// each of slide_rise (metres up per metre out), then lifted to lift_m. Level, it passes
  /// under an overhanging neighbour; rising, it clears the voxels of an item it rests on (a
  /// voxel says only that a surface lies somewhere in it) and a bin's front lip.
  std::vector<double> slide_out_m = {0.04, 0.08};
  std::vector<double> slide_rise = {0.0, 0.5, 1.0};
  double slide_height_m = 0.004;
  /// A scan voxel within this of the carried item's box (beyond the voxel's half diagonal)
  /// touches it: the lift may keep the contacts of the grasp but make no new one (metres).
  double item_contact_margin_m = 0.002;
  /// An item within this of a bin's back or side wall, or of a neighbour beside it in the
  /// scan, is drawn away from it during the lift (where the other side has twice the room),
  /// to this distance: the fast check's spheres stand up to 5.5 mm proud of the item's box
  /// and the motion check pads them by max_travel_m / 2, so nearer than that to a wall no
  /// move with the item could start.
  double wall_release_m = 0.015;
  /// The pre-grasp pose lies on the approach line this far outside the bin's opening plane,
  /// or this far above the tote's rim.
  double pregrasp_clearance_m = 0.10;
  /// The place starts by drawing a carried item that still reaches into its bin, or lies
  /// less than this in front of it, straight out until its box is this far out of the
  /// opening plane: the arm's first turn toward the roadmap then cannot swing it into the
  /// shelf.
  double item_exit_clearance_m = 0.25;
  /// ... or, where the arm cannot draw it back that far (the wrist would pass the base's
  /// axis), this far: the rest of the way out is the roadmap's or the trees' to find.
  double item_short_exit_clearance_m = 0.04;
  double tote_pregrasp_height_m = 0.20;
  /// When the approach line leaves the bin further than this from the grasp, the pre-grasp
  /// is straight in front of the opening instead, the cup pointing in (metres).
  double max_pregrasp_back_m = 0.45;
  /// A gripper with a head on a joint bends it for a grasp the straight tube cannot stand
  /// at: to the multiple of this step (up to the servo's range) nearest the angle between
  /// the reversed approach and the opening direction, the rest of the tube then pointing out
  /// of the opening (radians, > 0).
  double head_angle_step_rad = 30.0 * M_PI / 180.0;
  /// With a head, grasps are taken up to the servo's range plus this from the opening
  /// direction (the tube then tipped a little off level), radians.
  double head_reach_past_servo_rad = 10.0 * M_PI / 180.0;
  /// With the head bent, the descent ends at most guarded_distance_m above the grasp and at
  /// least min_bent_hover_m, lower where the tube, level from the joint to the flange,
  /// would bring the wrist within bent_wrist_clearance_m of the bin's ceiling (the UR10's
  /// wrist housings reach about 6 cm around the flange's axis; metres).
  double min_bent_hover_m = 0.015;
  /// A bent grasp is also tried rolled by +- this about the approach (the tube leaving the
  /// bin turned that much to a side), radians.
  double bent_roll_rad = 20.0 * M_PI / 180.0;
  double bent_wrist_clearance_m = 0.08;
  /// Grasps searched, best first, before the pick is given up. Grasps refused by the checks
  /// before the search (the tube through the opening, the descent's end pose) cost
  /// microseconds and are not counted.
  int max_grasps_tried = 8;
  /// Seconds of search a PlanPick may spend over all its grasps. When it is spent the call
  /// answers with the typed failures so far and a "search budget spent" one, not with the
  /// call's deadline: a dense bin whose every grasp spends its node budget is a "no plan" the
  /// caller can act on within its own time, not a timeout it retries.
  double search_time_budget_s = 1.0;
  /// Trajectory timing: the blend tolerance at corners and the output sample period.
  double blend_deviation_rad = 0.02;
  double sample_period_s = 0.008;
  /// The tcp's speed limit of the robot service's safety settings, m/s.
  double max_tcp_speed_m_s = 0.45;
  /// Exact (FCL) validation: every path node, and trajectory samples at this spacing.
  int exact_sample_stride = 8;
};

/// A time-parametrised joint trajectory.
struct Trajectory {
  std::vector<TrajectorySample> samples;
  double duration_s() const { return samples.empty() ? 0.0 : samples.back().time_s; }
};

/// Where and why a plan failed, typed for the caller.
struct PlanFailure {
  FailureStage stage = FailureStage::kUnspecified;  ///< Where (plan_failure.h).
  FailureKind kind = FailureKind::kUnspecified;     ///< Why.
  std::string grasp;  ///< The grasp's surface, when one was being tried.
  int node = -1;      ///< Search node where it stopped.
  double fraction_achieved = 0.0;
  std::string body;      ///< Colliding body, if any.
  std::string obstacle;  ///< What it hit.
  std::string message;   ///< One line a person can act on.
  /// Refused by the checks before any search (the pre-grasp's and the descent's end poses'
  /// IK and collisions), which cost microseconds.
  bool before_search = false;
};

/// Thrown when no plan exists (mapped to ABORTED); carries every attempt's failure, the most
/// advanced first.
class PlanFailedError final : public std::runtime_error {
 public:
  explicit PlanFailedError(std::vector<PlanFailure> failures);
  const std::vector<PlanFailure>& failures() const { return failures_; }

 private:
  std::vector<PlanFailure> failures_;
};

/// A planning scene: the scan of one container with the target item cut out.
struct PlanningScene {
  std::string container;  ///< "bin_A".."bin_L" or "tote".
  std::string item;       ///< The cut-out target ("" if none).
  Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();
  std::shared_ptr<const ScanScene> scan;  ///< The voxels, for later updates.
  std::shared_ptr<const ScanObstacles> obstacles;
  SceneUpdateStats stats;
  double build_time_s = 0.0;
};

/// What a pick needs to know.
struct PickRequest {
  std::string item;
  // (The gripper's head is straight at the start; the plan says how to bend it.)
  Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();
  std::string container;  ///< "bin_A".."bin_L" or "tote".
  JointVector start_rad = JointVector::Zero();
  double speed_fraction = 1.0;  ///< (0, 1]
};

struct PickPlan {
  GraspCandidate grasp;
  /// The gripper's head angle for the whole pick (radians; 0: straight): set it at the
  /// start, before the approach, and keep it through the place.
  double head_angle_rad = 0.0;
  Trajectory approach;  ///< start -> pre-grasp
  Trajectory descend;   ///< pre-grasp -> guarded_distance short of the grasp
  Trajectory retreat;   ///< grasp -> pre-grasp, carrying the item
  Eigen::Vector3d guarded_direction_Base = Eigen::Vector3d::Zero();
  double guarded_distance_m = 0.0;
  /// How far along the guarded move the grasp's surface lies, as detected (the cup meeting
  /// something much sooner has met something else).
  double contact_distance_m = 0.0;
  int nodes_expanded = 0;
  int grasps_tried = 0;
  double planning_time_s = 0.0;
  /// Where planning_time_s went, summed over the grasps tried: "set-up" (the request's
  /// checkers), "grasps", "pre-grasp" (the pre-grasp and the descent's end: IK and checks),
  /// "descend" (the search), "retreat" (lift and retreat), "approach" (the roadmap),
  /// "timing" (time parametrisation and exact validation). Seconds.
  std::map<std::string, double> stage_times_s;
  std::vector<PlanFailure> rejected;  ///< Grasps tried before the one returned.
};

struct PlaceRequest {
  std::string item;                                             ///< The carried item.
  Eigen::Isometry3d X_TcpItem = Eigen::Isometry3d::Identity();  ///< Where it hangs.
  std::string container;  ///< "tote" (pick task) or a bin (stow).
  JointVector start_rad = JointVector::Zero();
  double speed_fraction = 1.0;
  double head_angle_rad = 0.0;  ///< The gripper's head as the pick left it.
  /// Items already let go in the tote: the release spot is the next of ToteReleaseSpots.
  int placed_before = 0;
};

/// Where items are let go over the tote, in turn: the centres of a 3 x 2 grid over the tote
/// floor (tote frame, metres), each kept `margin_m` inside the walls (the item's half
/// footprint), the middle first, then the corners, then the last two.
std::vector<Eigen::Vector2d> ToteReleaseSpots(const Eigen::Vector2d& inner_size_m, double margin_m);

struct PlacePlan {
  Trajectory trajectory;
  Eigen::Isometry3d X_BaseTcp_release = Eigen::Isometry3d::Identity();
  double drop_height_m = 0.0;  ///< From the item's lowest point to the container floor.
  double planning_time_s = 0.0;
};

struct JointMotionPlan {
  Trajectory trajectory;
  std::vector<JointVector> path_rad;
  bool cached = false;
  double planning_time_s = 0.0;
};

/// The planner's workflows over one cell: the collision world, the named poses and their
/// roadmap, grasps, scenes from scans, pick, place and joint motions. Every plan it returns
/// is collision-free for the fast check along its whole sampled motion, exactly validated
/// (FCL) at its nodes and samples, and within the joint speed and acceleration limits.
/// Thread-safe: plans run concurrently.
class MotionPlanner final {
 public:
  /// Builds the static cell's grids, the named poses (IK at start-up) and the roadmap.
  /// Throws std::runtime_error if the cell or a model cannot be loaded, std::invalid_argument
  /// for bad options.
  MotionPlanner(const ur10::Ur10Kinematics& kinematics, const world::CellModel& cell,
                const GripperGeometry& gripper, const Eigen::Isometry3d& X_ToolCamera,
                std::shared_ptr<const GraspTable> grasps,
                std::shared_ptr<world::ItemModelLibrary> items,
                const MotionPlannerOptions& options = {});
  ~MotionPlanner();

  const RobotGeometry& robot() const { return *robot_; }
  const StaticCell& cell() const { return *cell_; }
  const std::vector<NamedPose>& named_poses() const { return roadmap_->named(); }
  /// Named poses the roadmap joins to "home" by none of their configurations
  /// (ReachableRoadmap): motions to them fail.
  const std::vector<std::string>& unreachable_named_poses() const { return unreachable_poses_; }
  const MotionPlannerOptions& options() const { return options_; }

  /// A scene from a scan (x, y, z floats in base) of `container`, with `item` at X_BaseItem
  /// cut out (item may be empty); with `previous`, that scene's voxels plus this scan's (the
  /// cut-out applies to both). Throws NotFoundError for an unknown item or container,
  /// std::invalid_argument for a previous scene of another container.
  PlanningScene BuildScene(const std::string& container, const float* xyz_Base, std::size_t count,
                           const std::string& item, const Eigen::Isometry3d& X_BaseItem,
                           const PlanningScene* previous = nullptr) const;

  /// Grasps for `item` at X_BaseItem in `container`, best first (scene optional, for the
  /// clearance along each approach).
  GraspResult ComputeGraspsFor(const std::string& item, const Eigen::Isometry3d& X_BaseItem,
                               const std::string& container,
                               const PlanningScene* scene = nullptr) const;

  /// A collision-free trajectory from start to goal (joint values, or a named pose).
  /// `head_angle_rad`: the gripper's head during the motion (within the servo's range).
  JointMotionPlan PlanJointMotion(const JointVector& start_rad, const JointVector& goal_rad,
                                  double speed_fraction, Deadline deadline,
                                  double head_angle_rad = 0.0) const;

  /// Approach, descent and retreat for picking `request.item`, with the gripper's head straight
  /// or, where the straight tube cannot stand at a grasp, bent (PickPlan::head_angle_rad).
  /// Throws PlanFailedError when no
  /// grasp can be planned, NotFoundError / std::invalid_argument / PreconditionError for bad
  /// requests, TimeoutError when the deadline passes.
  PickPlan PlanPick(const PickRequest& request, const PlanningScene* scene,
                    Deadline deadline) const;

  /// From the retreat's end, carrying the item, to its release pose over the container.
  PlacePlan PlanPlace(const PlaceRequest& request, Deadline deadline) const;

  /// Whether the caller has checked the path's own segments with the same checker and
  /// carried item (CheckSegment on each, as the cartesian search does).
  enum class PathChecked { kNo, kSegments };
  /// Times a joint path within the limits (scaled by speed_fraction) and checks the timed
  /// motion: continuous fast check (only where it leaves the path's segments, if they are
  /// checked), then FCL at nodes and samples. Throws PlanFailedError.
  Trajectory TimeAndValidate(const std::vector<JointVector>& path_rad, double speed_fraction,
                             const MotionChecker& checker, const ExactChecker& exact,
                             const CarriedItem* carried, FailureStage stage,
                             PathChecked path_checked = PathChecked::kNo) const;

 private:
  struct Attempt;
  // The static cell's checks with the gripper's head at one angle.
  struct Head {
    double angle_rad = 0.0;
    std::unique_ptr<RobotGeometry> robot;
    std::unique_ptr<FastChecker> fast;
    std::unique_ptr<MotionChecker> motion;
    std::unique_ptr<ExactChecker> exact;
  };
  // The checks of one request (its scan) with the head at one angle.
  struct RequestChecks;
  // The head at `angle_rad`, its checks built the first time it is asked for and kept
  // (at most kMaxHeads angles besides the straight head: a request holds on to its own).
  // Throws std::invalid_argument outside the servo's range.
  std::shared_ptr<const Head> HeadAt(double angle_rad) const;
  static constexpr std::size_t kMaxHeads = 16;
  // For a grasp the straight tube cannot stand at: the grasp turned so that the bent tube
  // points out of the opening, and the head angle; nullopt (and `blocked` saying why) if
  // the gripper has no joint or the bent tube does not fit either.
  std::optional<std::pair<GraspCandidate, double>> BendHead(const GraspContainer& container,
                                                            const GraspCandidate& grasp,
                                                            PlanFailure* blocked) const;
  // The carried item drawn straight out of the bin it still reaches into, as a joint path
  // from the place's start (just the start when it is out, or the way out is blocked).
  struct DrawOut {
    std::vector<JointVector> path_rad;
  };
  // The shelf bin the carried item is in, or just before (within the exit clearance).
  std::optional<GraspContainer> BinHoldingItem(const Eigen::Isometry3d& X_BaseItem,
                                               const CarriedItem& carried) const;
  /// Where the carried item may be let go in `container`, best first: over the tote's spots
  /// (from the request's placed_before on), set down in the middle of the table, or inside a
  /// bin's opening; `below_m`: the item's lowest point below the tcp pointing down.
  std::vector<Eigen::Isometry3d> ReleasePoses(const GraspContainer& container,
                                              const world::ItemModel& model,
                                              const PlaceRequest& request, double below_m) const;
  DrawOut DrawItemOut(const PlaceRequest& request, const CarriedItem& carried, const Head& head,
                      Deadline deadline) const;
  // How far the item's box at X_BaseItem must still move out along the opening direction to
  // be item_exit_clearance_m out of the container (0 if it is already).
  /// The path that moves the tcp from X_BaseTcp (at `start_rad`) by `shift_Base`, carrying
  /// the item: a straight joint motion if free, else a short cartesian search; nullopt if
  /// neither.
  std::optional<std::vector<JointVector>> DrawStraightBack(const JointVector& start_rad,
                                                           const Eigen::Isometry3d& X_BaseTcp,
                                                           const Eigen::Vector3d& shift_Base,
                                                           const CarriedItem& carried,
                                                           const Head& head,
                                                           Deadline deadline) const;
  double ItemDepthBehindOpening(const GraspContainer& container,
                                const Eigen::Isometry3d& X_BaseItem,
                                const CarriedItem& carried) const;
  // How far above a bent grasp the descent ends (see min_bent_hover_m).
  double BentHover(const GraspContainer& container, const GraspCandidate& grasp,
                   const GripperGeometry& gripper) const;
  void ValidateStart(const JointVector& start_rad) const;
  GraspContainer Container(const std::string& name) const;
  std::optional<JointVector> FreeIk(const Eigen::Isometry3d& X_BaseTcp, const JointVector& seed,
                                    const FastChecker& checker, const CarriedItem* carried,
                                    std::string* reason) const;
  std::optional<Eigen::Isometry3d> PreGraspPose(const GraspContainer& container,
                                                const GraspCandidate& grasp, double hover_m,
                                                bool bent, std::string* reason) const;
  bool TubeReaches(const GraspContainer& container, const GraspCandidate& grasp,
                   const RobotGeometry& robot, PlanFailure* failure) const;
  std::optional<JointVector> DescentStart(const Eigen::Isometry3d& X_pre,
                                          const Eigen::Isometry3d& X_descend_end,
                                          const Eigen::Isometry3d& X_grasp, const JointVector& seed,
                                          const FastChecker& fast, PlanFailure* failure) const;
  // The horizontal shift that draws the item off a bin's wall or a neighbour close beside it
  // during the lift (`voxels`: the scan's, or null).
  Eigen::Vector3d LiftRelease(const GraspContainer& container, const Eigen::Isometry3d& X_grasp,
                              const CarriedItem& carried, const VoxelContacts* voxels) const;
  // The lifts LiftOff tries, each as waypoints (displacements of the cup from the grasp).
  std::vector<std::vector<Eigen::Vector3d>> LiftCandidates(
      const GraspContainer& container, const Eigen::Vector3d& release_Base) const;
  // What every lift of one grasp starts from, worked out once for all of them.
  struct LiftStart {
    Eigen::Isometry3d X_grasp = Eigen::Isometry3d::Identity();
    JointVector q_grasp = JointVector::Zero();
    const CarriedItem* carried = nullptr;
    CarriedItem skimming;      // the item with its resting face drawn in (RaisedOffSupport)
    double skim_height_m = 0;  // by this much, checked so until lifted by as much
    std::vector<int> touched;  // the scan voxels its box touches at the grasp
  };
  LiftStart MakeLiftStart(const GraspContainer& container, const Eigen::Isometry3d& X_grasp,
                          const JointVector& q_grasp, const CarriedItem& carried,
                          const RequestChecks& checks) const;
  // One lift: IK at each waypoint, the arm's motion, the item's box against the cell and
  // against scan voxels it did not touch at the grasp. The joint path in `path_rad`.
  bool CheckLiftPath(const LiftStart& start, const std::vector<Eigen::Vector3d>& waypoints_Base,
                     const RequestChecks& checks, std::vector<JointVector>* path_rad,
                     PlanFailure* failure, std::string* reason) const;
  // One lift (CheckLiftPath) that ends where the item is free for the retreat.
  bool LiftOff(const LiftStart& start, const std::vector<Eigen::Vector3d>& waypoints_Base,
               const RequestChecks& checks, std::vector<JointVector>* lift_rad,
               PlanFailure* failure, std::string* reason) const;
  // The checks a grasp is tried with: the straight head's, or (the grasp turned in
  // `candidate`) a bent head's, built once per angle in `bent_checks`; nullptr, with the
  // reason in `refused`, when neither tube fits or the bent head collides at the start.
  const RequestChecks* ChecksForGrasp(const PickRequest& request, const GraspContainer& container,
                                      const ScanObstacles* scan, const RequestChecks& straight,
                                      std::map<double, std::unique_ptr<RequestChecks>>* bent_checks,
                                      GraspCandidate* candidate, PlanFailure* refused) const;
  // TryGrasp at the grasp's rolls; the most advanced failure in `best` when none works, and
  // in `searched` whether any roll got past the checks before the search.
  /// The failure that ends a PlanPick whose search budget is spent.
  PlanFailure SearchBudgetSpent(const PickRequest& request, const GraspCandidate& grasp,
                                int grasps_searched) const;
  // The item's ModelSeal, built on first use.
  std::shared_ptr<const ModelSeal> SealOf(const std::string& item,
                                          const world::ItemModel& model) const;
  // Whether the cup seals on the item's model at the candidate's contact, or a little beside
  // it (the candidate is then moved there); false with the failure typed when not.
  bool SealsOnModel(const PickRequest& request, const world::ItemModel& model,
                    GraspCandidate* candidate, PlanFailure* refused) const;
  bool TryRolls(const PickRequest& request, const GraspCandidate& candidate,
                const std::shared_ptr<const world::ItemModel>& model, const RequestChecks& checks,
                bool bent, Deadline deadline, PickPlan* plan, PlanFailure* best,
                bool* searched) const;
  /// The joint paths of a pick, in the order the arm runs them.
  struct PickPaths {
    std::vector<JointVector> approach, descend, lift, retreat;
  };
  /// Times each path and validates it exactly (the retreat with the item on the cup) into
  /// `plan`'s trajectories, the lift and the retreat joined.
  void TimePickPaths(const PickPaths& paths, double speed_fraction, const CarriedItem& carried,
                     const MotionChecker& motion, const ExactChecker& exact, PickPlan* plan) const;
  bool TryGrasp(const PickRequest& request, const GraspCandidate& grasp,
                const std::shared_ptr<const world::ItemModel>& model, const RequestChecks& checks,
                Deadline deadline, PickPlan* plan, PlanFailure* failure) const;
  // How far past the grasp the guarded move may go without the arm meeting the cell.
  double GuardedOvershoot(const Eigen::Isometry3d& X_grasp, const Eigen::Vector3d& approach_Base,
                          const JointVector& q_grasp, const RequestChecks& checks) const;
  // The first lift whose end a retreat out of the container starts from (the lift and the
  // retreat into `paths`).
  bool LiftAndRetreat(const GraspContainer& container, const GraspCandidate& grasp,
                      const Eigen::Isometry3d& X_pre, double hover_m, const JointVector& q_grasp,
                      const CarriedItem& carried, const RequestChecks& checks,
                      const CartesianSearchOptions& search, PickPaths* paths, int* nodes_expanded,
                      PlanFailure* failure) const;

  MotionPlannerOptions options_;
  std::unique_ptr<StaticCell> cell_;
  mutable std::mutex heads_mutex_;
  // The head's checks by angle; the straight head's (at 0) built first, its parts named below.
  mutable std::map<double, std::shared_ptr<const Head>> heads_;
  std::shared_ptr<const Head> straight_head_;
  const RobotGeometry* robot_ = nullptr;
  const FastChecker* static_fast_ = nullptr;
  const MotionChecker* static_motion_ = nullptr;
  const ExactChecker* static_exact_ = nullptr;
  std::unique_ptr<Roadmap> roadmap_;
  std::shared_ptr<const GraspTable> grasps_;
  std::shared_ptr<world::ItemModelLibrary> items_;
  Eigen::Isometry3d X_ToolCamera_;
  std::vector<std::string> unreachable_poses_;
  mutable std::mutex hull_mutex_;
  mutable std::map<std::string, ConvexHull> hulls_Item_;
  mutable std::mutex motion_cache_mutex_;
  mutable std::map<std::string, Trajectory> motion_cache_;  // named-pose motions, timed
  mutable std::mutex seal_mutex_;
  mutable std::map<std::string, std::shared_ptr<const ModelSeal>> seals_;
};

/// The named poses of the cell: "home", "scan/<bin>/<k>" (three views per bin,
/// world::CellBinScanViews: the camera in front of the opening looking at the floor's
/// middle), "scan/tote/<k>" (two views from above), "above_tote", "table", "verify" (the camera
/// above the table). Each from IK: the collision-free solutions, nearest to `home` first, of
/// the pose and then of its fall-backs (a scan view a little lower, higher, closer or
/// farther), at most `max_choices`. Poses with no such solution are left out and named in
/// `missing`.
std::vector<NamedPoseChoices> ComputeNamedPoses(
    const RobotGeometry& robot, const StaticCell& cell, const FastChecker& checker,
    const ExactChecker& exact, const JointVector& home_rad, const Eigen::Isometry3d& X_ToolCamera,
    std::vector<std::string>* missing, std::size_t max_choices = 8);

/// The roadmap over one configuration per named pose, each one the roadmap joins to the first
/// pose ("home"): a configuration can be free and still sit in a pocket of the joint space
/// that no motion reaches (an arm stretched up into a top bin's view, its wrist turned the
/// far way round). Each pose takes its first choice that a Roadmap over the chosen poses
/// plans to from the first; one with no such choice keeps its first (motions to it then fail
/// with the roadmap's reason) and is named in `unreachable`. The roadmap returned is the one
/// the last checks ran on: the edges they checked are known, their paths from home cached.
std::unique_ptr<Roadmap> ReachableRoadmap(const std::vector<NamedPoseChoices>& choices,
                                          const MotionChecker& checker,
                                          const RoadmapOptions& options,
                                          std::vector<std::string>* unreachable);

/// The UR10 facing the shelf, elbow up, the tool pointing at the shelf: the default home.
JointVector DefaultHomeJoints();

}  // namespace picking::planner
