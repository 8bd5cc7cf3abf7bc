#include "services/planner/core/motion_planner.h"
#include "services/planner/core/voxel_contacts.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <optional>
#include <sstream>

#include "libs/errors/errors.h"
#include "libs/world/shelf_bins.h"

namespace picking::planner {
namespace {

// Whether two joint vectors differ by whole turns only: the same arm pose, so the same
// collision answer and the same IK branch (IK's 2 pi variants).
bool SameArmPose(const JointVector& a_rad, const JointVector& b_rad) {
  for (int j = 0; j < 6; ++j) {
    if (std::abs(ur10::WrapToPi(a_rad[j] - b_rad[j])) > 1e-9) return false;
  }
  return true;
}

// Whether `q_rad` is a whole-turn variant of one of `tried`.
bool TriedAlready(const std::vector<JointVector>& tried, const JointVector& q_rad) {
  return std::any_of(tried.begin(), tried.end(),
                     [&](const JointVector& t) { return SameArmPose(t, q_rad); });
}

// A point of a container's opening plane (the centre of its opening face), base frame.
Eigen::Vector3d OpeningPoint(const GraspContainer& container) {
  const Eigen::Vector3d o = container.opening_direction_Base;
  return container.X_BaseContainer.translation() +
         0.5 * std::abs(o.dot(container.X_BaseContainer.linear() * container.inner_size_m)) * o;
}

std::string Fixed(double v, int digits) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.*f", digits, v);
  return buf;
}

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

void CheckDeadline(Deadline deadline, const std::string& stage) {
  if (std::chrono::steady_clock::now() > deadline) {
    throw TimeoutError("planning ran past the call's deadline during " + stage);
  }
}

bool IsRigid(const Eigen::Isometry3d& X) {
  if (!X.matrix().allFinite()) return false;
  const Eigen::Matrix3d R = X.linear();
  return (R.transpose() * R - Eigen::Matrix3d::Identity()).norm() < 1e-6 &&
         std::abs(R.determinant() - 1.0) < 1e-6;
}

PlanFailure FromSearch(FailureStage stage, const std::string& grasp,
                       const CartesianSearchResult& search) {
  PlanFailure f;
  f.stage = stage;
  f.kind = search.failure;
  f.grasp = grasp;
  f.node = search.failed_node;
  f.fraction_achieved = search.fraction_achieved;
  if (search.collision.in_collision) {
    f.body = BodyName(search.collision.body);
    f.obstacle = search.collision.obstacle;
  }
  f.message =
      std::string(FailureStageName(stage)) + " for grasp '" + grasp + "': " + search.Describe();
  return f;
}

// How far a pick's attempt got by the stage it failed at: the more advanced, the higher.
int StageRank(FailureStage stage) {
  switch (stage) {
    case FailureStage::kPreGrasp:
      return 1;
    case FailureStage::kDescend:
      return 2;
    case FailureStage::kRetreat:
      return 3;
    case FailureStage::kApproach:
      return 4;
    case FailureStage::kUnspecified:
    case FailureStage::kStart:
    case FailureStage::kGrasps:
    case FailureStage::kSearch:
    case FailureStage::kPlace:
    case FailureStage::kJointMotion:
      return 0;
  }
  return 0;
}

// `first` followed by `second`, which starts where `first` ends.
Trajectory Joined(const Trajectory& first, const Trajectory& second) {
  Trajectory joined = first;
  const double t0 = first.duration_s();
  for (std::size_t i = 1; i < second.samples.size(); ++i) {
    TrajectorySample s = second.samples[i];
    s.time_s += t0;
    joined.samples.push_back(s);
  }
  return joined;
}

// The camera at `p_Camera` looking at `p_Target`, its x axis horizontal (image rows level).
Eigen::Isometry3d LookAt(const Eigen::Vector3d& p_Camera, const Eigen::Vector3d& p_Target,
                         const Eigen::Vector3d& up) {
  const Eigen::Vector3d z = (p_Target - p_Camera).normalized();
  Eigen::Vector3d x = z.cross(up);
  if (x.norm() < 1e-6) x = z.unitOrthogonal();
  x.normalize();
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() << x, z.cross(x), z;
  X.translation() = p_Camera;
  return X;
}

// The tcp pointing straight down at `p`, its x axis along base +x.
Eigen::Isometry3d DownAt(const Eigen::Vector3d& p) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() << Eigen::Vector3d::UnitX(), -Eigen::Vector3d::UnitY(), -Eigen::Vector3d::UnitZ();
  X.translation() = p;
  return X;
}

}  // namespace

PlanFailedError::PlanFailedError(std::vector<PlanFailure> failures)
    : std::runtime_error(failures.empty() ? std::string("no plan found")
                                          : failures.front().message),
      failures_(std::move(failures)) {}

JointVector DefaultHomeJoints() {
  JointVector q;
  q << M_PI, -2.0, 2.0, -M_PI / 2, -M_PI / 2, 0.0;
  return q;
}

// ---------------------------------------------------------------------------------------
// Named poses

std::vector<NamedPoseChoices> ComputeNamedPoses(
    const RobotGeometry& robot, const StaticCell& cell, const FastChecker& checker,
    const ExactChecker& exact, const JointVector& home_rad, const Eigen::Isometry3d& X_ToolCamera,
    std::vector<std::string>* missing, std::size_t max_choices) {
  std::vector<NamedPoseChoices> poses;
  const ur10::Ur10Kinematics& kinematics = robot.kinematics();
  // Named poses are where motions start and end: they keep a margin from everything (and
  // the arm from itself), so that the continuous check of a motion leaving them, which grows
  // the spheres by half its state spacing, does not find them touching.
  constexpr float kNamedPoseMargin_m = 0.01f;
  auto free = [&](const JointVector& q) {
    return checker.IsFree(q, nullptr, kNamedPoseMargin_m) && !exact.Check(q).in_collision;
  };
  if (free(home_rad)) {
    poses.push_back({"home", {home_rad}});
  } else if (missing) {
    missing->push_back("home (" + checker.Check(home_rad).ToString() + ")");
  }
  // The free solutions (every branch, every 2 pi variant), nearest to home first.
  auto solve = [&](const Eigen::Isometry3d& X_BaseTool, std::vector<JointVector>* out) {
    ur10::IkOptions ik_options;
    ik_options.include_2pi_variants = true;
    ur10::IkResult ik = kinematics.Solve(X_BaseTool, ik_options);
    std::sort(ik.solutions.begin(), ik.solutions.end(), [&](const auto& a, const auto& b) {
      return (a.q_rad - home_rad).cwiseAbs().sum() < (b.q_rad - home_rad).cwiseAbs().sum();
    });
    for (const auto& s : ik.solutions) {
      if (out->size() >= max_choices) return;
      if (free(s.q_rad)) out->push_back(s.q_rad);
    }
  };
  // The candidate poses' solutions, in order of preference.
  auto add_first = [&](const std::string& name, const std::vector<Eigen::Isometry3d>& candidates) {
    NamedPoseChoices pose{name, {}};
    for (const Eigen::Isometry3d& X_BaseTool : candidates) {
      if (pose.q_rad.size() >= max_choices) break;  // no IK for choices never taken
      solve(X_BaseTool, &pose.q_rad);
    }
    if (!pose.q_rad.empty()) {
      poses.push_back(std::move(pose));
    } else if (missing) {
      missing->push_back(name);
    }
  };
  auto add = [&](const std::string& name, const Eigen::Isometry3d& X_BaseTool) {
    add_first(name, {X_BaseTool});
  };
  const Eigen::Isometry3d X_CameraTool = X_ToolCamera.inverse();
  const Eigen::Isometry3d& X_BaseShelf = cell.cell().config.X_BaseShelf;
  const Eigen::Vector3d up = Eigen::Vector3d::UnitZ();
  for (const world::BinGeometry& bin : cell.cell().bins) {
    const std::vector<world::BinScanView> views = world::CellBinScanViews();
    for (std::size_t k = 0; k < views.size(); ++k) {
      // Where the arm cannot hold the camera at the view's point (the wrist would pass the
      // base axis for the middle column), a little higher (seeing over the front items) or
      // lower, closer or farther.
      std::vector<Eigen::Isometry3d> candidates;
      for (const double standoff : {0.0, -0.05, -0.10, 0.05}) {
        for (const double raise : {0.0, 0.08, -0.08, -0.15, -0.22}) {
          world::BinScanView view = views[k];
          view.standoff_m += standoff;
          view.height_above_centre_m += raise;
          if (view.height_above_centre_m < 0.0) continue;
          candidates.push_back(LookAt(X_BaseShelf * world::BinScanEye_S(bin, view),
                                      X_BaseShelf * world::BinScanTarget_S(bin, view), up) *
                               X_CameraTool);
        }
      }
      add_first("scan/" + bin.name + "/" + std::to_string(k), candidates);
    }
  }
  const world::CellConfig& config = cell.cell().config;
  const Eigen::Vector3d tote_floor = config.X_BaseTote.translation();
  const Eigen::Vector3d tote_x = config.X_BaseTote.linear().col(0);
  for (int k = 0; k < 2; ++k) {
    const Eigen::Vector3d p_Camera =
        tote_floor + Eigen::Vector3d(0, 0, 0.95) + (k == 0 ? -0.08 : 0.08) * tote_x;
    const Eigen::Isometry3d X_BaseCamera =
        LookAt(p_Camera, tote_floor + (k == 0 ? -0.04 : 0.04) * tote_x, tote_x);
    add("scan/tote/" + std::to_string(k), X_BaseCamera * X_CameraTool);
  }
  const Eigen::Isometry3d X_TcpTool = robot.gripper().X_ToolTcp.inverse();
  add("above_tote", DownAt(tote_floor + Eigen::Vector3d(0, 0, 0.60)) * X_TcpTool);
  const Eigen::Vector3d table_top = config.X_BaseTable.translation();
  add("table", DownAt(table_top + Eigen::Vector3d(0, 0, 0.30)) * X_TcpTool);
  add("verify",
      LookAt(table_top + Eigen::Vector3d(0, 0, 0.60), table_top, Eigen::Vector3d::UnitX()) *
          X_CameraTool);
  return poses;
}

std::unique_ptr<Roadmap> ReachableRoadmap(const std::vector<NamedPoseChoices>& choices,
                                          const MotionChecker& checker,
                                          const RoadmapOptions& options,
                                          std::vector<std::string>* unreachable) {
  std::vector<std::size_t> pick(choices.size(), 0);
  auto chosen = [&] {
    std::vector<NamedPose> out;
    for (std::size_t i = 0; i < choices.size(); ++i) {
      out.push_back({choices[i].name, choices[i].q_rad[pick[i]]});
    }
    return out;
  };
  std::vector<bool> settled(choices.size(), false);
  if (!choices.empty()) settled[0] = true;  // the start of every check
  // Each round checks the unsettled poses against a roadmap over the current choices and
  // moves each that fails to its next choice; a pose with no choice left settles on its first.
  // The last round changes nothing: its roadmap holds the chosen poses, with the edges its
  // checks found free or blocked already known and the paths from home cached.
  for (;;) {
    bool changed = false;
    auto roadmap = std::make_unique<Roadmap>(checker, chosen(), options);
    for (std::size_t i = 1; i < choices.size(); ++i) {
      if (settled[i]) continue;
      if (roadmap->Plan(choices[0].q_rad[pick[0]], choices[i].q_rad[pick[i]]).ok) {
        settled[i] = true;
      } else if (pick[i] + 1 < choices[i].q_rad.size()) {
        ++pick[i];
        changed = true;
      } else {
        pick[i] = 0;
        changed = true;  // the roadmap is built again over its first choice
        settled[i] = true;
        if (unreachable) unreachable->push_back(choices[i].name);
      }
    }
    if (!changed) return roadmap;
  }
}

// ---------------------------------------------------------------------------------------
// Set-up

MotionPlanner::MotionPlanner(const ur10::Ur10Kinematics& kinematics, const world::CellModel& cell,
                             const GripperGeometry& gripper, const Eigen::Isometry3d& X_ToolCamera,
                             std::shared_ptr<const GraspTable> grasps,
                             std::shared_ptr<world::ItemModelLibrary> items,
                             const MotionPlannerOptions& options)
    : options_(options),
      cell_(std::make_unique<StaticCell>(cell, options.cell)),
      grasps_(std::move(grasps)),
      items_(std::move(items)),
      X_ToolCamera_(X_ToolCamera) {
  if (!grasps_ || !items_) throw std::invalid_argument("MotionPlanner needs grasps and items");
  if (!IsRigid(X_ToolCamera_)) throw std::invalid_argument("X_ToolCamera must be rigid");
  if (!(options_.head_angle_step_rad > 0.0) || !(options_.min_bent_hover_m >= 0.0) ||
      !(options_.bent_wrist_clearance_m >= 0.0)) {
    throw std::invalid_argument(
        "head_angle_step_rad must be > 0, min_bent_hover_m and bent_wrist_clearance_m >= 0");
  }
  ModelSeal::Validate(options_.seal);
  auto straight = std::make_unique<Head>();
  straight->angle_rad = gripper.head_angle_rad;
  straight->robot = std::make_unique<RobotGeometry>(kinematics, gripper);
  straight->fast = std::make_unique<FastChecker>(*straight->robot, *cell_, nullptr);
  straight->motion = std::make_unique<MotionChecker>(*straight->fast, options_.motion);
  straight->exact = std::make_unique<ExactChecker>(*straight->robot, *cell_, nullptr);
  robot_ = straight->robot.get();
  static_fast_ = straight->fast.get();
  static_motion_ = straight->motion.get();
  static_exact_ = straight->exact.get();
  straight_head_ = std::move(straight);
  heads_.emplace(straight_head_->angle_rad, straight_head_);
  // The servo's steps (BendHead's angles), built now rather than by the first pick that
  // needs one, so that no request pays for them.
  if (gripper.head_length_m > 0.0 && gripper.max_head_angle_rad > 0.0) {
    for (int k = 1; k * options_.head_angle_step_rad < gripper.max_head_angle_rad; ++k) {
      HeadAt(k * options_.head_angle_step_rad);
    }
    HeadAt(gripper.max_head_angle_rad);
  }
  std::vector<std::string> missing;
  const std::vector<NamedPoseChoices> choices = ComputeNamedPoses(
      *robot_, *cell_, *static_fast_, *static_exact_, DefaultHomeJoints(), X_ToolCamera_, &missing);
  if (!missing.empty()) {
    std::string list;
    for (const auto& m : missing) list += (list.empty() ? "" : ", ") + m;
    throw std::runtime_error("no collision-free IK solution for the named poses: " + list);
  }
  roadmap_ = ReachableRoadmap(choices, *static_motion_, options_.roadmap, &unreachable_poses_);
  // The paper's offline joint paths: every two named poses, planned once (0.3 s here).
  if (options_.cache_named_paths) roadmap_->CacheNamedPaths();
}

MotionPlanner::~MotionPlanner() = default;

struct MotionPlanner::RequestChecks {
  RequestChecks(std::shared_ptr<const Head> h, const StaticCell& cell, const ScanObstacles* scan,
                const MotionCheckOptions& options, double contact_margin_m)
      : head(std::move(h)),
        fast(*head->robot, cell, scan),
        motion(fast, options),
        exact(*head->robot, cell, scan) {
    if (scan && scan->voxel_m > 0.0) {
      contacts.emplace(scan->voxel_centres_Base, scan->voxel_m, contact_margin_m);
    }
  }
  std::shared_ptr<const Head> head;  // kept while the request runs; its exact check: the cell
  FastChecker fast;
  MotionChecker motion;
  ExactChecker exact;
  std::optional<VoxelContacts> contacts;  // the scan's voxels a carried item touches
};

std::shared_ptr<const MotionPlanner::Head> MotionPlanner::HeadAt(double angle_rad) const {
  if (!std::isfinite(angle_rad)) throw std::invalid_argument("the head angle must be finite");
  std::lock_guard<std::mutex> lock(heads_mutex_);
  auto it = heads_.find(angle_rad);
  if (it != heads_.end()) return it->second;
  if (heads_.size() > kMaxHeads) {
    // Many angles asked for: start again from the straight head (requests keep theirs).
    heads_.clear();
    heads_.emplace(straight_head_->angle_rad, straight_head_);
  }
  auto head = std::make_unique<Head>();
  head->angle_rad = angle_rad;
  head->robot = std::make_unique<RobotGeometry>(
      robot_->WithGripper(robot_->gripper().AtHeadAngle(angle_rad)));
  head->fast = std::make_unique<FastChecker>(*head->robot, *cell_, nullptr);
  head->motion = std::make_unique<MotionChecker>(*head->fast, options_.motion);
  head->exact = std::make_unique<ExactChecker>(*head->robot, *cell_, nullptr);
  std::shared_ptr<const Head> shared = std::move(head);
  heads_.emplace(angle_rad, shared);
  return shared;
}

GraspContainer MotionPlanner::Container(const std::string& name) const {
  if (name == "tote") return ToteContainer(cell_->cell());
  if (name == "table") return TableContainer(cell_->cell());
  for (const auto& bin : cell_->cell().bins) {
    if (bin.name == name) return ShelfBinContainer(cell_->cell(), name);
  }
  throw NotFoundError("unknown container '" + name.substr(0, 40) +
                      "': expected bin_A..bin_L, tote or table");
}

void MotionPlanner::ValidateStart(const JointVector& start_rad) const {
  if (!start_rad.allFinite()) throw std::invalid_argument("start joints must be finite");
  if (const std::string out = robot_->kinematics().model().PositionLimitViolation(start_rad);
      !out.empty()) {
    throw PreconditionError("the start joints are outside the UR10's limits: " + out);
  }
}

// ---------------------------------------------------------------------------------------
// Scenes and grasps

PlanningScene MotionPlanner::BuildScene(const std::string& container, const float* xyz_Base,
                                        std::size_t count, const std::string& item,
                                        const Eigen::Isometry3d& X_BaseItem,
                                        const PlanningScene* previous) const {
  const auto start = std::chrono::steady_clock::now();
  const GraspContainer box = Container(container);
  PlanningScene scene;
  scene.container = container;
  scene.item = item;
  scene.X_BaseItem = X_BaseItem;
  ScanSceneOptions scene_options;
  scene_options.resolution_m = options_.scene_resolution_m;
  // The container's box in base, grown by the margin (an axis-aligned box around it).
  Eigen::AlignedBox3d region;
  const Eigen::Vector3d half = 0.5 * box.inner_size_m;
  for (int i = 0; i < 8; ++i) {
    const Eigen::Vector3d corner((i & 1) ? half.x() : -half.x(), (i & 2) ? half.y() : -half.y(),
                                 (i & 4) ? half.z() : -half.z());
    region.extend(box.X_BaseContainer * corner);
  }
  region.min().array() -= options_.scene_region_margin_m;
  region.max().array() += options_.scene_region_margin_m;
  scene_options.region_Base = region;
  for (const auto& g : cell_->grids()) scene_options.known_surfaces.push_back(&g.grid);
  std::vector<SceneCutOut> cuts;
  if (!item.empty()) {
    if (!IsRigid(X_BaseItem)) throw std::invalid_argument("X_base_item must be a rigid pose");
    std::shared_ptr<const world::ItemModel> model;
    try {
      model = items_->Get(item);
    } catch (const apc::UnknownItemError&) {
      throw NotFoundError("unknown item '" + item.substr(0, 60) + "'");
    }
    ConvexHull hull_Item;
    {
      std::lock_guard<std::mutex> lock(hull_mutex_);
      auto it = hulls_Item_.find(item);
      if (it == hulls_Item_.end()) {
        it = hulls_Item_.emplace(item, ComputeConvexHull(model->mesh.vertices)).first;
      }
      hull_Item = it->second;
    }
    cuts.push_back({item, hull_Item.Transformed(X_BaseItem), options_.cut_margin_m});
    // The target's seal model (an Embree scene of its mesh, 1-8 ms once per item) is built
    // with its scene, as its hull is, not in the pick that follows.
    if (options_.check_seal) SealOf(item, *model);
  }
  if (previous && previous->container != container) {
    throw std::invalid_argument("the scene shows " + previous->container + ", not " + container);
  }
  auto scan = previous && previous->scan ? std::make_shared<ScanScene>(*previous->scan)
                                         : std::make_shared<ScanScene>(scene_options);
  scene.stats = scan->Insert(xyz_Base, count, cuts);
  scene.obstacles = scan->Snapshot();
  scene.scan = std::move(scan);
  scene.build_time_s = Seconds(start);
  return scene;
}

GraspResult MotionPlanner::ComputeGraspsFor(const std::string& item,
                                            const Eigen::Isometry3d& X_BaseItem,
                                            const std::string& container,
                                            const PlanningScene* scene) const {
  if (!grasps_->find(item)) throw NotFoundError("unknown item '" + item.substr(0, 60) + "'");
  if (!IsRigid(X_BaseItem)) throw std::invalid_argument("X_base_item must be a rigid pose");
  GraspOptions options = options_.grasp;
  const GripperGeometry& gripper = robot_->gripper();
  if (gripper.head_length_m > 0.0) {
    // A bent head takes faces up to its servo's range off the opening direction (a top
    // face lies at 90 degrees), and a little past it with the tube tipped.
    options.max_approach_angle_rad =
        std::max(options.max_approach_angle_rad,
                 gripper.max_head_angle_rad + options_.head_reach_past_servo_rad);
  }
  if (scene && scene->obstacles) {
    // Free distance behind the point: march back along -approach through the scan's and the
    // cell's grids (clearance bounds are conservative, so is the distance).
    const ScanObstacles* scan = scene->obstacles.get();
    const StaticCell* cell = cell_.get();
    const double radius = robot_->gripper().tube_radius_m;
    options.clearance = [scan, cell, radius](const Eigen::Vector3d& p,
                                             const Eigen::Vector3d& direction, double max_m) {
      for (double s = 0.02; s <= max_m; s += 0.01) {
        const Eigen::Vector3f q = (p + s * direction).cast<float>();
        float d = scan->grid.Clearance(q);
        for (const auto& g : cell->grids()) d = std::min(d, g.grid.Clearance(q));
        if (d < radius) return std::max(0.0, s - 0.01);
      }
      return max_m;
    };
  }
  return ComputeGrasps(*grasps_, item, X_BaseItem, Container(container), options);
}

// ---------------------------------------------------------------------------------------
// Timing and validation

namespace {

// The timed motion checked continuously where it may leave what is checked already: all of
// it, or (the path's segments checked) each run of sample steps that does not stay on one
// segment (blends, and steps across a corner, which cut it).
MotionCheckResult CheckTimedMotion(const MotionChecker& checker, const CarriedItem* carried,
                                   const std::vector<JointVector>& path_rad,
                                   const std::vector<TrajectorySample>& timed,
                                   const std::vector<JointVector>& samples, bool segments_checked) {
  if (!segments_checked) return checker.CheckPath(samples, carried);
  // Far below a sample step (the samples lie on a segment to rounding).
  constexpr double kOnSegmentRad = 1e-9;
  const std::vector<int> segment = PolylineSegmentOfSamples(timed, path_rad, kOnSegmentRad);
  std::size_t k = 0;
  while (k + 1 < samples.size()) {
    if (segment[k] >= 0 && segment[k] == segment[k + 1]) {
      ++k;
      continue;
    }
    std::size_t end = k + 1;  // the run of steps off a single segment
    while (end + 1 < samples.size() && !(segment[end] >= 0 && segment[end] == segment[end + 1])) {
      ++end;
    }
    const std::vector<JointVector> run(samples.begin() + k, samples.begin() + end + 1);
    MotionCheckResult check = checker.CheckPath(run, carried);
    if (!check.free) return check;
    k = end;
  }
  return MotionCheckResult{};
}

}  // namespace

Trajectory MotionPlanner::TimeAndValidate(const std::vector<JointVector>& path_rad,
                                          double speed_fraction, const MotionChecker& checker,
                                          const ExactChecker& exact, const CarriedItem* carried,
                                          FailureStage stage, PathChecked path_checked) const {
  if (!(speed_fraction > 0.0 && speed_fraction <= 1.0)) {
    throw std::invalid_argument("speed_fraction must be in (0, 1]");
  }
  const ur10::Ur10Model& model = robot_->kinematics().model();
  const RobotGeometry& robot = checker.checker().robot();  // the gripper's head as checked
  TimeOptimalOptions timing;
  timing.max_velocity_rad_s = model.max_velocity_rad_s() * speed_fraction;
  timing.max_acceleration_rad_s2 = model.max_acceleration_rad_s2() * speed_fraction;
  timing.sample_period_s = options_.sample_period_s;
  // The tcp's speed bound, met segment by segment: |dp/ds| by a forward difference of the
  // tcp's position along the path's tangent.
  timing.max_point_speed = 0.97 * options_.max_tcp_speed_m_s;
  timing.point_speed_rate = [&robot](const JointVector& q, const JointVector& dq_ds) {
    constexpr double kStepRad = 1e-6;
    return (robot.X_BaseTcp(q + kStepRad * dq_ds).translation() - robot.X_BaseTcp(q).translation())
               .norm() /
           kStepRad;
  };
  auto fail = [&](FailureKind kind, const std::string& message, const CollisionReport* report) {
    PlanFailure f;
    f.stage = stage;
    f.kind = kind;
    f.message = std::string(FailureStageName(stage)) + ": " + message;
    if (report && report->in_collision) {
      f.body = BodyName(report->body);
      f.obstacle = report->obstacle;
    }
    throw PlanFailedError({f});
  };
  // Blended corners leave the checked polyline; if the blended motion collides, time the
  // exact polyline instead (it stops at each corner).
  for (const double deviation : {options_.blend_deviation_rad, 0.0}) {
    timing.max_deviation_rad = deviation;
    timing.max_velocity_rad_s = model.max_velocity_rad_s() * speed_fraction;
    timing.max_acceleration_rad_s2 = model.max_acceleration_rad_s2() * speed_fraction;
    TimeOptimalResult timed = TimeParametrizeTimeOptimal(path_rad, timing);
    // The timing keeps the tcp within its bound at samples along the path; should it pass
    // the robot's limit between them, slow the whole motion down (speeds by k,
    // accelerations by k^2 keep the path and its timing law's shape) until it holds.
    for (int round = 0; round < 4; ++round) {
      if (timed.samples.empty()) break;
      double v_max = 0.0;
      Eigen::Vector3d p_last = robot.X_BaseTcp(timed.samples.front().q_rad).translation();
      for (std::size_t i = 1; i < timed.samples.size(); ++i) {
        const Eigen::Vector3d p = robot.X_BaseTcp(timed.samples[i].q_rad).translation();
        const double dt = timed.samples[i].time_s - timed.samples[i - 1].time_s;
        if (dt > 0.0) v_max = std::max(v_max, (p - p_last).norm() / dt);
        p_last = p;
      }
      if (v_max <= options_.max_tcp_speed_m_s) break;
      const double k = 0.95 * options_.max_tcp_speed_m_s / v_max;
      timing.max_velocity_rad_s *= k;
      timing.max_acceleration_rad_s2 *= k * k;
      timed = TimeParametrizeTimeOptimal(path_rad, timing);
    }
    if (!timed.ok) fail(FailureKind::kTiming, timed.reason, nullptr);
    std::vector<JointVector> samples;
    samples.reserve(timed.samples.size());
    for (const auto& s : timed.samples) samples.push_back(s.q_rad);
    const MotionCheckResult check = CheckTimedMotion(
        checker, carried, path_rad, timed.samples, samples, path_checked == PathChecked::kSegments);
    if (!check.free) {
      if (deviation > 0.0) continue;
      fail(FailureKind::kCollision, "the timed motion collides: " + check.report.ToString(),
           &check.report);
    }
    for (std::size_t i = 0; i < samples.size(); ++i) {
      if (i % options_.exact_sample_stride != 0 && i + 1 != samples.size()) continue;
      const CollisionReport report = exact.Check(samples[i], carried);
      if (report.in_collision) {
        fail(FailureKind::kCollision,
             "exact validation found a collision at t = " +
                 std::to_string(timed.samples[i].time_s) + " s: " + report.ToString(),
             &report);
      }
    }
    for (const JointVector& q : path_rad) {
      const CollisionReport report = exact.Check(q, carried);
      if (report.in_collision) {
        fail(FailureKind::kCollision,
             "exact validation found a collision at a path node: " + report.ToString(), &report);
      }
    }
    Trajectory trajectory;
    trajectory.samples = timed.samples;
    return trajectory;
  }
  fail(FailureKind::kCollision, "no collision-free timing", nullptr);
  return {};
}

namespace {

// Timed named motions kept (every ordered pair of 42 named poses at two speeds).
constexpr std::size_t kMotionCacheEntries = 4096;

// The bytes of a motion request between two configurations at a speed: a cache key.
std::string MotionKey(const JointVector& a, const JointVector& b, double speed_fraction) {
  std::string key(sizeof(double) * 13, '\0');
  std::memcpy(key.data(), a.data(), sizeof(double) * 6);
  std::memcpy(key.data() + sizeof(double) * 6, b.data(), sizeof(double) * 6);
  std::memcpy(key.data() + sizeof(double) * 12, &speed_fraction, sizeof(double));
  return key;
}

}  // namespace

JointMotionPlan MotionPlanner::PlanJointMotion(const JointVector& start_rad,
                                               const JointVector& goal_rad, double speed_fraction,
                                               Deadline deadline, double head_angle_rad) const {
  const auto started = std::chrono::steady_clock::now();
  ValidateStart(start_rad);
  const std::shared_ptr<const Head> head_ptr = HeadAt(head_angle_rad);  // throws out of range
  const Head& head = *head_ptr;
  const bool straight = head_ptr == straight_head_;
  if (!goal_rad.allFinite()) throw std::invalid_argument("goal joints must be finite");
  if (const std::string out = robot_->kinematics().model().PositionLimitViolation(goal_rad);
      !out.empty()) {
    throw std::invalid_argument("the goal joints are outside the UR10's limits: " + out);
  }
  if (const CollisionReport r = head.fast->Check(start_rad); r.in_collision) {
    throw PreconditionError("the start state collides: " + r.ToString());
  }
  if (const CollisionReport r = head.fast->Check(goal_rad); r.in_collision) {
    throw std::invalid_argument("the goal state collides: " + r.ToString());
  }
  // The roadmap's edges were checked with the straight head; a bent one checks the path too.
  const JointPathResult path =
      roadmap_->Plan(start_rad, goal_rad, straight ? nullptr : head.motion.get(), deadline);
  CheckDeadline(deadline, "the joint motion");
  if (!path.ok) {
    PlanFailure f;
    f.stage = FailureStage::kJointMotion;
    f.kind = FailureKind::kNoPath;
    f.message = "no collision-free joint motion: " + path.reason;
    throw PlanFailedError({f});
  }
  JointMotionPlan plan;
  plan.path_rad = path.path_rad;
  plan.cached = path.cached;
  // A cached path between named poses with the straight head is timed and validated once per
  // speed: the static cell it was validated in does not change.
  const bool keep = path.cached && straight;
  const std::string key = keep ? MotionKey(start_rad, goal_rad, speed_fraction) : "";
  if (keep) {
    std::lock_guard<std::mutex> lock(motion_cache_mutex_);
    if (const auto it = motion_cache_.find(key); it != motion_cache_.end()) {
      plan.trajectory = it->second;
      plan.planning_time_s = Seconds(started);
      return plan;
    }
  }
  plan.trajectory = TimeAndValidate(path.path_rad, speed_fraction, *head.motion, *head.exact,
                                    nullptr, FailureStage::kJointMotion);
  if (keep) {
    // Bounded: a caller asking for ever new speeds must not grow it without end.
    std::lock_guard<std::mutex> lock(motion_cache_mutex_);
    if (motion_cache_.size() < kMotionCacheEntries) motion_cache_.emplace(key, plan.trajectory);
  }
  plan.planning_time_s = Seconds(started);
  return plan;
}

// ---------------------------------------------------------------------------------------
// Pick

std::optional<JointVector> MotionPlanner::FreeIk(const Eigen::Isometry3d& X_BaseTcp,
                                                 const JointVector& seed,
                                                 const FastChecker& checker,
                                                 const CarriedItem* carried,
                                                 std::string* reason) const {
  // Each arm pose once, as its whole-turn variant nearest the seed (the others collide alike).
  ur10::IkOptions ik_options;
  ik_options.seed_rad = seed;
  ur10::IkResult ik = robot_->kinematics().Solve(
      X_BaseTcp * checker.robot().gripper().X_ToolTcp.inverse(), ik_options);
  if (ik.empty()) {
    *reason = "no IK solution: " + ik.reason;
    return std::nullopt;
  }
  std::sort(ik.solutions.begin(), ik.solutions.end(), [&](const auto& a, const auto& b) {
    return (a.q_rad - seed).cwiseAbs().sum() < (b.q_rad - seed).cwiseAbs().sum();
  });
  CollisionReport first;
  std::vector<JointVector> tried;  // a colliding pose collides in every whole-turn variant
  for (const auto& s : ik.solutions) {
    if (TriedAlready(tried, s.q_rad)) continue;
    tried.push_back(s.q_rad);
    if (checker.IsFree(s.q_rad, carried)) return s.q_rad;
    if (!first.in_collision) first = checker.Check(s.q_rad, carried);
  }
  *reason = "every IK solution collides (nearest: " + first.ToString() + ")";
  return std::nullopt;
}

std::optional<Eigen::Isometry3d> MotionPlanner::PreGraspPose(const GraspContainer& container,
                                                             const GraspCandidate& grasp,
                                                             double hover_m, bool bent,
                                                             std::string* reason) const {
  const bool tote = container.kind == GraspContainerKind::kOpenTop;
  const Eigen::Isometry3d& X_grasp = grasp.X_BaseTcp;
  const Eigen::Vector3d a = grasp.approach_Base;
  const Eigen::Vector3d o = container.opening_direction_Base;
  const Eigen::Vector3d p_opening = OpeningPoint(container);
  if (bent && !tote) {
    // The bent tube points out of the opening: hover over the grasp and draw straight back
    // out of the bin, the cup still facing the grasp.
    Eigen::Isometry3d X_pre = X_grasp;
    const double out_m =
        std::max(0.0, (p_opening - X_grasp.translation()).dot(o)) + options_.pregrasp_clearance_m;
    X_pre.translation() += -a * hover_m + o * out_m;
    return X_pre;
  }
  // Back along the approach line until outside the opening (or above the rim).
  const double back_per_m = (-a).dot(o);  // opening-normal distance per metre of back-off
  if (back_per_m < 0.1) {
    *reason = "the approach runs along the opening";
    return std::nullopt;
  }
  const double to_opening = std::max(0.0, (p_opening - X_grasp.translation()).dot(o)) / back_per_m;
  const double clearance = tote ? options_.tote_pregrasp_height_m : options_.pregrasp_clearance_m;
  const double back_m = to_opening + clearance / back_per_m;
  Eigen::Isometry3d X_pre = X_grasp;
  X_pre.translation() -= a * back_m;
  if (!tote && back_m > options_.max_pregrasp_back_m) {
    // Too oblique to come in along the approach line (a top face deep in a bin): start
    // straight in front of the opening, the cup pointing into the bin, at the grasp's side
    // position and a height the tube fits through; the descent turns the cup onto the face.
    const double half_height =
        0.5 * std::abs(Eigen::Vector3d::UnitZ().dot(container.X_BaseContainer.linear() *
                                                    container.inner_size_m));
    const double z_mid = container.X_BaseContainer.translation().z();
    Eigen::Vector3d p = X_grasp.translation();
    p += ((p_opening - p).dot(o) + clearance) * o;
    p.z() = std::clamp(X_grasp.translation().z() + 0.05, z_mid - half_height + 0.06,
                       z_mid + half_height - 0.06);
    X_pre.translation() = p;
    X_pre.linear() =
        Eigen::Quaterniond::FromTwoVectors(a, -o).toRotationMatrix() * X_grasp.linear();
  }
  return X_pre;
}

std::optional<std::pair<GraspCandidate, double>> MotionPlanner::BendHead(
    const GraspContainer& container, const GraspCandidate& grasp, PlanFailure* blocked) const {
  const GripperGeometry& gripper = robot_->gripper();
  if (gripper.head_length_m == 0.0 || gripper.max_head_angle_rad == 0.0) return std::nullopt;
  // The bent tube's direction -(sin t y_tcp + cos t z_tcp) lies nearest the opening direction
  // o when y_tcp is o's part across the approach, reversed, and t the angle from -a to o.
  const Eigen::Vector3d a = grasp.approach_Base;
  const Eigen::Vector3d o = container.opening_direction_Base;
  const Eigen::Vector3d across = o - o.dot(a) * a;
  if (across.norm() < 1e-6) return std::nullopt;  // straight out already
  const double ideal_rad = std::acos(std::clamp(-a.dot(o), -1.0, 1.0));
  const double step = options_.head_angle_step_rad;
  Eigen::Matrix3d R;
  R.col(2) = a;
  R.col(1) = -across.normalized();
  R.col(0) = R.col(1).cross(R.col(2));
  GraspCandidate bent = grasp;
  bent.X_BaseTcp.linear() = R;
  bent.X_BaseTcpPreGrasp.linear() = R;
  bent.roll_symmetric = false;  // the roll sets where the tube goes
  // The servo's steps on either side of the ideal angle tip the tube a little up or down:
  // take first the one that leaves the flange (and the wrist around it) nearer the middle
  // of the container's height, away from its ceiling and floor.
  std::vector<double> angles;
  for (const double k : {std::floor(ideal_rad / step), std::ceil(ideal_rad / step)}) {
    const double angle = std::min(k * step, gripper.max_head_angle_rad);
    if (angle > 0.0 && std::find(angles.begin(), angles.end(), angle) == angles.end()) {
      angles.push_back(angle);
    }
  }
  const double middle_z = container.X_BaseContainer.translation().z();
  auto flange_off_middle = [&](double angle) {
    const Eigen::Isometry3d X_BaseTool =
        bent.X_BaseTcp * gripper.AtHeadAngle(angle).X_ToolTcp.inverse();
    return std::abs(X_BaseTool.translation().z() - middle_z);
  };
  std::sort(angles.begin(), angles.end(),
            [&](double x, double y) { return flange_off_middle(x) < flange_off_middle(y); });
  for (const double angle : angles) {
    if (TubeReaches(container, bent, *HeadAt(angle)->robot, blocked)) {
      return std::make_pair(bent, angle);
    }
  }
  return std::nullopt;
}

double MotionPlanner::BentHover(const GraspContainer& container, const GraspCandidate& grasp,
                                const GripperGeometry& gripper) const {
  // The joint stands head_length_m behind the lip; the tube runs from it out of the opening
  // and the wrist around the flange must pass under the ceiling (the container box's top).
  const Eigen::Vector3d back = -grasp.approach_Base;
  if (back.z() < 0.3) return options_.guarded_distance_m;
  const double ceiling_z = container.X_BaseContainer.translation().z() +
                           0.5 * std::abs(Eigen::Vector3d::UnitZ().dot(
                                     container.X_BaseContainer.linear() * container.inner_size_m));
  const double joint_z = grasp.X_BaseTcp.translation().z() + gripper.head_length_m * back.z();
  const double room_m = (ceiling_z - options_.bent_wrist_clearance_m - joint_z) / back.z();
  return std::clamp(room_m, options_.min_bent_hover_m, options_.guarded_distance_m);
}

std::optional<GraspContainer> MotionPlanner::BinHoldingItem(const Eigen::Isometry3d& X_BaseItem,
                                                            const CarriedItem& carried) const {
  for (const auto& bin : cell_->cell().bins) {
    GraspContainer container = ShelfBinContainer(cell_->cell(), bin.name);
    // A corner of the item's box in the bin's inner box grown out of the opening by the
    // clearance: the item is in the bin or just before it.
    const Eigen::Vector3d half = 0.5 * container.inner_size_m;
    const Eigen::Vector3d o_Container =
        container.X_BaseContainer.linear().transpose() * container.opening_direction_Base;
    Eigen::AlignedBox3d region(-half, half);
    for (int axis = 0; axis < 3; ++axis) {
      if (o_Container[axis] > 0.5) region.max()[axis] += options_.item_exit_clearance_m;
      if (o_Container[axis] < -0.5) region.min()[axis] -= options_.item_exit_clearance_m;
    }
    const Eigen::AlignedBox3d& b = carried.box_Item;
    for (int i = 0; i < 8; ++i) {
      const Eigen::Vector3d corner((i & 1) ? b.max().x() : b.min().x(),
                                   (i & 2) ? b.max().y() : b.min().y(),
                                   (i & 4) ? b.max().z() : b.min().z());
      if (region.contains(container.X_BaseContainer.inverse() * (X_BaseItem * corner))) {
        return container;
      }
    }
  }
  return std::nullopt;
}

MotionPlanner::DrawOut MotionPlanner::DrawItemOut(const PlaceRequest& request,
                                                  const CarriedItem& carried, const Head& head,
                                                  Deadline deadline) const {
  DrawOut out;
  out.path_rad = {request.start_rad};
  const Eigen::Isometry3d X_BaseTcp = head.robot->X_BaseTcp(request.start_rad);
  const Eigen::Isometry3d X_BaseItem = X_BaseTcp * carried.X_TcpItem;
  const std::optional<GraspContainer> container = BinHoldingItem(X_BaseItem, carried);
  if (!container) return out;
  const double back_m = ItemDepthBehindOpening(*container, X_BaseItem, carried);
  const Eigen::Vector3d out_Base = container->opening_direction_Base;
  if (back_m <= 0.0) return out;
  // Drawn out by the full clearance first; where the arm cannot go that far back (a long
  // item drawn out of a middle bin brings the wrist to the base's axis), just out of the
  // opening, the rest of the way then the roadmap's or the trees' to find.
  const double inside_m = back_m - options_.item_exit_clearance_m;
  for (const double clearance_m :
       {options_.item_exit_clearance_m, options_.item_short_exit_clearance_m}) {
    if (auto path =
            DrawStraightBack(request.start_rad, X_BaseTcp, (inside_m + clearance_m) * out_Base,
                             carried, head, deadline)) {
      out.path_rad = std::move(*path);
      return out;
    }
  }
  return out;  // the roadmap tries from the start
}

std::optional<std::vector<JointVector>> MotionPlanner::DrawStraightBack(
    const JointVector& start_rad, const Eigen::Isometry3d& X_BaseTcp,
    const Eigen::Vector3d& shift_Base, const CarriedItem& carried, const Head& head,
    Deadline deadline) const {
  Eigen::Isometry3d X_goal = X_BaseTcp;
  X_goal.translation() += shift_Base;
  // A straight joint motion to the drawn-out pose on the start's branch moves the item
  // nearly straight out over such a distance: take it when it is free; else search the
  // cartesian line, with a small budget (wrist singularities often lie across it).
  const ur10::Ur10Kinematics& kinematics = robot_->kinematics();
  const auto q_out = kinematics.NearestSolution(X_goal * head.robot->gripper().X_ToolTcp.inverse(),
                                                start_rad, kinematics.BranchOf(start_rad));
  if (q_out && (q_out->q_rad - start_rad).cwiseAbs().maxCoeff() < 1.0 &&
      head.motion->CheckSegment(start_rad, q_out->q_rad, &carried).free) {
    return std::vector<JointVector>{start_rad, q_out->q_rad};
  }
  CartesianSearchOptions search = options_.search;
  search.deadline = deadline;
  search.node_budget = std::min(search.node_budget, 300);
  const CartesianSearchResult drawn =
      SearchCartesianPath(*head.motion, start_rad, X_goal, &carried, search);
  if (!drawn.ok) return std::nullopt;
  return drawn.path_rad;
}

double MotionPlanner::ItemDepthBehindOpening(const GraspContainer& container,
                                             const Eigen::Isometry3d& X_BaseItem,
                                             const CarriedItem& carried) const {
  const Eigen::Vector3d o = container.opening_direction_Base;
  const Eigen::Vector3d p_opening = OpeningPoint(container);
  double deepest = -std::numeric_limits<double>::infinity();
  const Eigen::AlignedBox3d& b = carried.box_Item;
  for (int i = 0; i < 8; ++i) {
    const Eigen::Vector3d corner((i & 1) ? b.max().x() : b.min().x(),
                                 (i & 2) ? b.max().y() : b.min().y(),
                                 (i & 4) ? b.max().z() : b.min().z());
    deepest = std::max(deepest, (p_opening - X_BaseItem * corner).dot(o));
  }
  return std::max(0.0, deepest + options_.item_exit_clearance_m);
}

bool MotionPlanner::TubeReaches(const GraspContainer& container, const GraspCandidate& grasp,
                                const RobotGeometry& robot, PlanFailure* failure) const {
  const GripperGeometry& gripper = robot.gripper();
  TubeReachOptions options;
  options.lip_to_flange_m = gripper.reach_m();
  options.cup_length_m = gripper.cup_length_m;
  options.tube_radius_m = gripper.tube_radius_m;
  options.head_length_m = gripper.head_length_m;
  options.head_angle_rad = gripper.head_angle_rad;
  const TubeReachResult reach = CheckTubeReach(container, grasp, options);
  if (reach.reaches) return true;
  failure->stage = FailureStage::kDescend;
  failure->kind = FailureKind::kTubeBlocked;
  failure->grasp = grasp.surface;
  failure->body = BodyName(kBodyTool);
  failure->obstacle = "shelf";
  if (container.kind == GraspContainerKind::kOpenTop) failure->obstacle = container.name;
  failure->message = "descend for grasp '" + grasp.surface + "': " + reach.message;
  return false;
}

std::optional<JointVector> MotionPlanner::DescentStart(const Eigen::Isometry3d& X_pre,
                                                       const Eigen::Isometry3d& X_descend_end,
                                                       const Eigen::Isometry3d& X_grasp,
                                                       const JointVector& seed,
                                                       const FastChecker& fast,
                                                       PlanFailure* failure) const {
  // The cartesian search keeps its start's IK branch, so a descent whose end pose collides
  // (or has no IK) on that branch is hopeless however long it searches: take the free
  // pre-grasp solution nearest to the start whose branch also holds both ends of the descent
  // and the guarded move free.
  const ur10::Ur10Kinematics& kinematics = robot_->kinematics();
  const Eigen::Isometry3d X_TcpTool = fast.robot().gripper().X_ToolTcp.inverse();
  // Each arm pose once, as its whole-turn variant nearest the seed (the others have the same
  // collisions and branch).
  ur10::IkOptions ik_options;
  ik_options.seed_rad = seed;
  ur10::IkResult ik = kinematics.Solve(X_pre * X_TcpTool, ik_options);
  if (ik.empty()) {
    failure->stage = FailureStage::kPreGrasp;
    failure->kind = FailureKind::kIkUnreachable;
    failure->message = "no IK solution: " + ik.reason;
    return std::nullopt;
  }
  std::sort(ik.solutions.begin(), ik.solutions.end(), [&](const auto& a, const auto& b) {
    return (a.q_rad - seed).cwiseAbs().sum() < (b.q_rad - seed).cwiseAbs().sum();
  });
  std::string first_reason;
  CollisionReport first_hit;
  bool any_free_pre = false;
  // A whole-turn variant of a solution tried has its arm pose and branch: the same answers.
  std::vector<JointVector> tried;
  for (const auto& s : ik.solutions) {
    if (TriedAlready(tried, s.q_rad)) continue;
    tried.push_back(s.q_rad);
    // IsFree stops at the first hit; Check, which says what hits what, only for the message.
    if (!fast.IsFree(s.q_rad)) {
      if (!first_hit.in_collision) first_hit = fast.Check(s.q_rad);
      continue;
    }
    any_free_pre = true;
    const ur10::Branch branch = kinematics.BranchOf(s.q_rad);
    bool ok = true;
    for (const auto& [X, what] : {std::pair{&X_descend_end, "the descent's end pose"},
                                  std::pair{&X_grasp, "the grasp pose"}}) {
      std::string reason;
      const auto q = kinematics.NearestSolution(*X * X_TcpTool, s.q_rad, branch, &reason);
      if (!q) {
        if (first_reason.empty()) {
          failure->kind = FailureKind::kIkUnreachable;
          first_reason = std::string(what) + " has no IK solution on branch " + branch.ToString() +
                         " of the free pre-grasp";
        }
        ok = false;
        break;
      }
      if (!fast.IsFree(q->q_rad)) {
        if (first_reason.empty()) {
          const CollisionReport r = fast.Check(q->q_rad);
          failure->kind = FailureKind::kCollision;
          failure->body = BodyName(r.body);
          failure->obstacle = r.obstacle;
          first_reason = std::string(what) + " itself collides on branch " + branch.ToString() +
                         " of the free pre-grasp: " + r.ToString();
        }
        ok = false;
        break;
      }
    }
    if (ok) return s.q_rad;
  }
  if (!any_free_pre) {
    failure->stage = FailureStage::kPreGrasp;
    failure->kind = FailureKind::kCollision;
    failure->body = BodyName(first_hit.body);
    failure->obstacle = first_hit.obstacle;
    failure->message = "every IK solution collides (nearest: " + first_hit.ToString() + ")";
    return std::nullopt;
  }
  failure->stage = FailureStage::kDescend;
  failure->message =
      first_reason + " (checked before the search; no free pre-grasp branch holds it)";
  return std::nullopt;
}

namespace {

// The nearest scan voxel beside the box (container frame) on each side of each horizontal
// axis, as the gap between the voxel's enclosing sphere and the box, metres: voxels whose
// cubes overlap the box's extent on the other horizontal axis and lie within the height the
// lift sweeps (above the support: from `above_support_m` over the box's bottom to `sweep_m`
// over its top). Gaps start at `far_m`.
void NeighbourGaps(const Eigen::AlignedBox3d& box_Container,
                   const Eigen::Isometry3d& X_ContainerBase, const VoxelContacts& voxels,
                   double voxel_m, double above_support_m, double sweep_m, double far_m,
                   Eigen::Vector3d* low_gap, Eigen::Vector3d* high_gap) {
  const double half = 0.5 * voxel_m;
  const double reach = 0.5 * std::sqrt(3.0) * voxel_m;
  for (std::size_t v = 0; v < voxels.size(); ++v) {
    const Eigen::Vector3d c = X_ContainerBase * voxels.centre(static_cast<int>(v)).cast<double>();
    if (c.z() + half < box_Container.min().z() + above_support_m ||
        c.z() - half > box_Container.max().z() + sweep_m) {
      continue;
    }
    for (int axis = 0; axis < 2; ++axis) {
      const int other = 1 - axis;
      if (c[other] + half < box_Container.min()[other] ||
          c[other] - half > box_Container.max()[other]) {
        continue;
      }
      // A voxel wholly beside the box; its gap from the sphere around it, as the fast check
      // sees it (a voxel's enclosing sphere reaches 3.7 mm past its cube at 1 cm).
      if (c[axis] + half <= box_Container.min()[axis]) {
        const double below = std::max(0.0, box_Container.min()[axis] - (c[axis] + reach));
        if (below < far_m) (*low_gap)[axis] = std::min((*low_gap)[axis], below);
      } else if (c[axis] - half >= box_Container.max()[axis]) {
        const double above = std::max(0.0, (c[axis] - reach) - box_Container.max()[axis]);
        if (above < far_m) (*high_gap)[axis] = std::min((*high_gap)[axis], above);
      }
    }
  }
}

}  // namespace

Eigen::Vector3d MotionPlanner::LiftRelease(const GraspContainer& container,
                                           const Eigen::Isometry3d& X_grasp,
                                           const CarriedItem& carried,
                                           const VoxelContacts* voxels) const {
  // The item's box in the container frame; a shelf bin's back and side walls near it, and
  // the neighbours beside it in the scan: where one side is close and the other has room,
  // the lift draws the item away from the close one (a box lifted straight up beside a
  // neighbour's curved flank runs into it). (Tote picks lift straight up, as in the paper.)
  if (container.kind != GraspContainerKind::kShelfBin) return Eigen::Vector3d::Zero();
  const Eigen::Isometry3d X_ContainerItem =
      container.X_BaseContainer.inverse() * X_grasp * carried.X_TcpItem;
  Eigen::AlignedBox3d box;
  for (int i = 0; i < 8; ++i) {
    const Eigen::AlignedBox3d& b = carried.box_Item;
    box.extend(X_ContainerItem * Eigen::Vector3d((i & 1) ? b.max().x() : b.min().x(),
                                                 (i & 2) ? b.max().y() : b.min().y(),
                                                 (i & 4) ? b.max().z() : b.min().z()));
  }
  const Eigen::Vector3d o_Container =
      container.X_BaseContainer.linear().transpose() * container.opening_direction_Base;
  const Eigen::Vector3d half = 0.5 * container.inner_size_m;
  const double need = options_.wall_release_m;
  // The opening side has no wall.
  Eigen::Vector3d low_gap = Eigen::Vector3d::Constant(1.0), high_gap = low_gap;
  for (int axis = 0; axis < 2; ++axis) {
    if (o_Container[axis] > -0.5) low_gap[axis] = box.min()[axis] + half[axis];
    if (o_Container[axis] < 0.5) high_gap[axis] = half[axis] - box.max()[axis];
  }
  if (voxels != nullptr) {
    NeighbourGaps(box, container.X_BaseContainer.inverse(), *voxels, options_.scene_resolution_m,
                  options_.lift_item_check_m, options_.lift_m, 1.0, &low_gap, &high_gap);
  }
  // The container's z is up (floor and ceiling are the lift's): across its x and y, a shift
  // off the near side that leaves the far side at least `need` too.
  Eigen::Vector3d shift = Eigen::Vector3d::Zero();
  for (int axis = 0; axis < 2; ++axis) {
    const double up = need - std::max(0.0, low_gap[axis]);
    const double down = need - std::max(0.0, high_gap[axis]);
    if (up > 0.0 && high_gap[axis] - up >= need) {
      shift[axis] += up;
    } else if (down > 0.0 && low_gap[axis] - down >= need) {
      shift[axis] -= down;
    }
  }
  return container.X_BaseContainer.linear() * shift;
}

namespace {

// The carried item's box with the face it rests on drawn in by `raise_m` (the face whose
// normal points most nearly down at X_BaseItem): it may slide on its support, which the
// exact check would otherwise call a collision, but not into anything higher.
CarriedItem RaisedOffSupport(const CarriedItem& carried, const Eigen::Isometry3d& X_BaseItem,
                             double raise_m) {
  const Eigen::Vector3d down_Item = X_BaseItem.linear().transpose() * -Eigen::Vector3d::UnitZ();
  int axis = 0;
  down_Item.cwiseAbs().maxCoeff(&axis);
  Eigen::AlignedBox3d box = carried.box_Item;
  const double room = box.sizes()[axis] - 1e-3;
  if (down_Item[axis] > 0.0) {
    box.max()[axis] -= std::min(raise_m, room);
  } else {
    box.min()[axis] += std::min(raise_m, room);
  }
  return MakeCarriedItem(carried.name, box, carried.X_TcpItem);
}

}  // namespace

std::vector<std::vector<Eigen::Vector3d>> MotionPlanner::LiftCandidates(
    const GraspContainer& container, const Eigen::Vector3d& release_Base) const {
  // Straight up off the support (the highest that works: a tall item has little room below
  // a bin's ceiling), then, for an item a neighbour overhangs or that lies against one,
  // slid out toward the opening just above its support and lifted there.
  const Eigen::Vector3d up = Eigen::Vector3d::UnitZ();
  std::vector<std::vector<Eigen::Vector3d>> candidates;
  for (const double fraction : {1.0, 0.8, 0.6}) {
    candidates.push_back({fraction * options_.lift_m * up + release_Base});
  }
  if (container.kind != GraspContainerKind::kShelfBin) return candidates;
  Eigen::Vector3d out = container.opening_direction_Base;
  out.z() = 0.0;
  if (out.norm() < 0.5) return candidates;
  out.normalize();
  // Just above the support first; then out, level or rising (by slide_rise per metre out:
  // level passes under an overhang, rising clears the lip at the bin's front edge); then up
  // to the full lift.
  const Eigen::Vector3d skim = options_.slide_height_m * up + release_Base;
  for (const double slide_m : options_.slide_out_m) {
    for (const double rise : options_.slide_rise) {
      const Eigen::Vector3d slid =
          skim + slide_m * out + std::min(rise * slide_m, options_.lift_m) * up;
      std::vector<Eigen::Vector3d> waypoints = {skim, slid};
      if (slid.z() < options_.lift_m) {
        waypoints.push_back(slid + (options_.lift_m - slid.z()) * up);
      }
      candidates.push_back(std::move(waypoints));
    }
  }
  return candidates;
}

namespace {

// How far the item's box at X_BaseItem reaches below the container's floor (0 if not): a
// detected pose a few millimetres off puts an item resting on a bin's board or the table's
// top partly inside it, which the item cannot be.
double DepthBelowFloor(const GraspContainer& container, const Eigen::AlignedBox3d& box_Item,
                       const Eigen::Isometry3d& X_BaseItem) {
  const Eigen::Isometry3d X_ContainerItem = container.X_BaseContainer.inverse() * X_BaseItem;
  double lowest_z = std::numeric_limits<double>::infinity();
  for (int i = 0; i < 8; ++i) {
    const auto corner = static_cast<Eigen::AlignedBox3d::CornerType>(i);
    lowest_z = std::min(lowest_z, (X_ContainerItem * box_Item.corner(corner)).z());
  }
  return std::max(0.0, -0.5 * container.inner_size_m.z() - lowest_z);
}

}  // namespace

MotionPlanner::LiftStart MotionPlanner::MakeLiftStart(const GraspContainer& container,
                                                      const Eigen::Isometry3d& X_grasp,
                                                      const JointVector& q_grasp,
                                                      const CarriedItem& carried,
                                                      const RequestChecks& checks) const {
  LiftStart start;
  start.X_grasp = X_grasp;
  start.q_grasp = q_grasp;
  start.carried = &carried;
  const Eigen::Isometry3d X_BaseItem = X_grasp * carried.X_TcpItem;
  start.skim_height_m =
      options_.lift_item_check_m + DepthBelowFloor(container, carried.box_Item, X_BaseItem);
  start.skimming = RaisedOffSupport(carried, X_BaseItem, start.skim_height_m);
  if (checks.contacts) start.touched = checks.contacts->Touching(X_BaseItem, carried.box_Item);
  return start;
}

bool MotionPlanner::CheckLiftPath(const LiftStart& start,
                                  const std::vector<Eigen::Vector3d>& waypoints_Base,
                                  const RequestChecks& checks, std::vector<JointVector>* path_rad,
                                  PlanFailure* failure, std::string* reason) const {
  const Eigen::Isometry3d& X_grasp = start.X_grasp;
  const CarriedItem& carried = *start.carried;
  const ur10::Branch branch = robot_->kinematics().BranchOf(start.q_grasp);
  const RobotGeometry& robot = checks.fast.robot();
  const Eigen::Isometry3d X_TcpTool = robot.gripper().X_ToolTcp.inverse();
  *path_rad = {start.q_grasp};
  for (const Eigen::Vector3d& d : waypoints_Base) {
    Eigen::Isometry3d X = X_grasp;
    X.translation() += d;
    const auto ik = robot_->kinematics().NearestSolution(X * X_TcpTool, path_rad->back(), branch);
    if (!ik) {
      *reason = "the lift pose has no IK solution";
      return false;
    }
    const JointVector q_from = path_rad->back();
    path_rad->push_back(ik->q_rad);
    // The arm and gripper: the continuous check (the cup is at the cut-out target).
    if (const MotionCheckResult m = checks.motion.CheckSegment(q_from, ik->q_rad); !m.free) {
      failure->body = BodyName(m.report.body);
      failure->obstacle = m.report.obstacle;
      *reason = "the lift collides: " + m.report.ToString();
      return false;
    }
    // The item's box every 2 mm: against the cell exactly (drawn in from its support until
    // it is lift_item_check_m up), against the scan by the contacts it did not have.
    const Eigen::Vector3d from = robot.X_BaseTcp(q_from).translation();
    const int steps =
        std::max(2, static_cast<int>(std::ceil((X.translation() - from).norm() / 0.002)));
    for (int k = 1; k <= steps; ++k) {
      const JointVector q = q_from + (ik->q_rad - q_from) * (double(k) / steps);
      const Eigen::Isometry3d X_BaseItem = robot.X_BaseTcp(q) * carried.X_TcpItem;
      const bool low =
          X_BaseItem.translation().z() - (X_grasp * carried.X_TcpItem).translation().z() <
          start.skim_height_m;
      if (const CollisionReport r = checks.head->exact->Check(q, low ? &start.skimming : &carried);
          r.in_collision) {
        failure->body = BodyName(r.body);
        failure->obstacle = r.obstacle;
        *reason = "lifting the item: " + r.ToString() + " (exact check of the item's box)";
        return false;
      }
      if (!checks.contacts) continue;
      if (const int v = checks.contacts->NewContact(X_BaseItem, carried.box_Item, start.touched);
          v >= 0) {
        const Eigen::Vector3f& c = checks.contacts->centre(v);
        failure->body = "item";
        failure->obstacle = "scan";
        *reason = "lifting the item: its box meets the scan at (" + Fixed(c.x(), 3) + ", " +
                  Fixed(c.y(), 3) + ", " + Fixed(c.z(), 3) +
                  ") m, which it did not touch at the grasp";
        return false;
      }
    }
  }
  return true;
}

bool MotionPlanner::LiftOff(const LiftStart& start,
                            const std::vector<Eigen::Vector3d>& waypoints_Base,
                            const RequestChecks& checks, std::vector<JointVector>* lift_rad,
                            PlanFailure* failure, std::string* reason) const {
  // The item rests on its support and may touch a wall or a neighbour, so the fast check
  // with the item takes over where the lift ends, and must see it free there by the motion
  // check's padding (else no move of the retreat could start). The item's spheres stand up
  // to 5.5 mm proud of its box, so an item within a few millimetres of a wall needs the lift
  // to draw it away (LiftRelease). Along the lift the item may keep touching what it touched
  // at the grasp, but meet nothing new (CheckLiftPath).
  if (!CheckLiftPath(start, waypoints_Base, checks, lift_rad, failure, reason)) return false;
  const float padding = static_cast<float>(0.5 * options_.motion.max_travel_m);
  if (const CollisionReport r = checks.fast.Check(lift_rad->back(), start.carried, padding);
      r.in_collision) {
    const Eigen::Vector3d& d = waypoints_Base.back();
    failure->body = BodyName(r.body);
    failure->obstacle = r.obstacle;
    *reason = "after a lift of " + Fixed(d.z(), 3) + " m (and " +
              Fixed(Eigen::Vector3d(d.x(), d.y(), 0.0).norm(), 3) + " m across) " + r.ToString() +
              " (clearance " + Fixed(r.clearance_m, 4) + " m, " + Fixed(padding, 4) +
              " m needed to move on): the item is wedged in";
    return false;
  }
  return true;
}

bool MotionPlanner::LiftAndRetreat(const GraspContainer& container, const GraspCandidate& grasp,
                                   const Eigen::Isometry3d& X_pre, double hover_m,
                                   const JointVector& q_grasp, const CarriedItem& carried,
                                   const RequestChecks& checks,
                                   const CartesianSearchOptions& search, PickPaths* paths,
                                   int* nodes_expanded, PlanFailure* failure) const {
  // Each lift in turn, with the retreat out of the container from where it ends: the first
  // pair that works. The failure kept is the straight lift's (or its retreat's), with the
  // furthest slide's reason added.
  const bool tote = container.kind == GraspContainerKind::kOpenTop;
  const bool bent = checks.fast.robot().gripper().bent();
  const Eigen::Isometry3d& X_grasp = grasp.X_BaseTcp;
  const Eigen::Vector3d release_Base =
      LiftRelease(container, X_grasp, carried, checks.contacts ? &*checks.contacts : nullptr);
  const LiftStart start = MakeLiftStart(container, X_grasp, q_grasp, carried, checks);
  bool first = true;
  std::string slide_reason;
  for (const auto& waypoints : LiftCandidates(container, release_Base)) {
    PlanFailure attempt;
    std::string why;
    std::vector<JointVector> lift_path;
    if (LiftOff(start, waypoints, checks, &lift_path, &attempt, &why)) {
      // Out at the lift's height: along the approach line back, or (bent) straight out.
      const Eigen::Vector3d& lift_Base = waypoints.back();
      Eigen::Isometry3d X_exit = X_pre;
      if (!tote)
        X_exit.translation() +=
            bent ? Eigen::Vector3d(lift_Base + grasp.approach_Base * hover_m) : lift_Base;
      const CartesianSearchResult retreat =
          SearchCartesianPath(checks.motion, lift_path.back(), X_exit, &carried, search);
      *nodes_expanded += retreat.nodes_expanded;
      if (retreat.ok) {
        paths->lift = std::move(lift_path);
        paths->retreat = retreat.path_rad;
        return true;
      }
      attempt = FromSearch(FailureStage::kRetreat, grasp.surface, retreat);
      why = attempt.message;
    } else {
      attempt.stage = FailureStage::kRetreat;
      attempt.kind = FailureKind::kCollision;
      attempt.grasp = grasp.surface;
      why = "retreat for grasp '" + grasp.surface + "': " + why;
    }
    if (first) {
      *failure = attempt;
      failure->message = why;
      first = false;
    } else if (waypoints.size() > 1) {
      slide_reason = why;  // the furthest slide's
    }
  }
  if (!slide_reason.empty()) failure->message += "; slid out first: " + slide_reason;
  return false;
}

double MotionPlanner::GuardedOvershoot(const Eigen::Isometry3d& X_grasp,
                                       const Eigen::Vector3d& approach_Base,
                                       const JointVector& q_grasp,
                                       const RequestChecks& checks) const {
  // The robot checks a guarded move's whole path against the cell before it moves, and a
  // thin item's face lies closer to the floor under it than the full overshoot: the longest
  // of the overshoot's fractions the arm can run without the cell (the item itself gives way
  // to the cup, its voxels cut out).
  const ur10::Branch branch = robot_->kinematics().BranchOf(q_grasp);
  const Eigen::Isometry3d X_TcpTool = checks.fast.robot().gripper().X_ToolTcp.inverse();
  for (const double fraction : {1.0, 0.75, 0.5, 0.25}) {
    const double overshoot_m = fraction * options_.guarded_overshoot_m;
    Eigen::Isometry3d X = X_grasp;
    X.translation() += overshoot_m * approach_Base;
    const auto ik = robot_->kinematics().NearestSolution(X * X_TcpTool, q_grasp, branch);
    if (ik && checks.head->motion->CheckSegment(q_grasp, ik->q_rad).free) return overshoot_m;
  }
  return 0.0;
}

void MotionPlanner::TimePickPaths(const PickPaths& paths, double speed_fraction,
                                  const CarriedItem& carried, const MotionChecker& motion,
                                  const ExactChecker& exact, PickPlan* plan) const {
  plan->approach = TimeAndValidate(paths.approach, speed_fraction, motion, exact, nullptr,
                                   FailureStage::kApproach);
  // The descent and the retreat are the cartesian search's, every segment checked.
  plan->descend = TimeAndValidate(paths.descend, speed_fraction, motion, exact, nullptr,
                                  FailureStage::kDescend, PathChecked::kSegments);
  // The lift is checked here without the item: LiftOff checked the item's box along it
  // exactly; the fast check takes the item from the lift's end on.
  const Trajectory lift = TimeAndValidate(paths.lift, speed_fraction, motion, exact, nullptr,
                                          FailureStage::kRetreat, PathChecked::kSegments);
  plan->retreat =
      Joined(lift, TimeAndValidate(paths.retreat, speed_fraction, motion, exact, &carried,
                                   FailureStage::kRetreat, PathChecked::kSegments));
}

namespace {

// Adds the seconds since `since` to `times[stage]` and restarts `since`.
void Lap(std::map<std::string, double>* times, const char* stage,
         std::chrono::steady_clock::time_point* since) {
  const auto now = std::chrono::steady_clock::now();
  (*times)[stage] += std::chrono::duration<double>(now - *since).count();
  *since = now;
}

}  // namespace

bool MotionPlanner::TryGrasp(const PickRequest& request, const GraspCandidate& grasp,
                             const std::shared_ptr<const world::ItemModel>& model,
                             const RequestChecks& checks, Deadline deadline, PickPlan* plan,
                             PlanFailure* failure) const {
  const FastChecker& fast = checks.fast;
  const MotionChecker& motion = checks.motion;
  const GraspContainer container = Container(request.container);
  const bool tote = container.kind == GraspContainerKind::kOpenTop;
  const Eigen::Isometry3d& X_grasp = grasp.X_BaseTcp;
  const Eigen::Vector3d a = grasp.approach_Base;
  auto translated = [](const Eigen::Isometry3d& X, const Eigen::Vector3d& d) {
    Eigen::Isometry3d Y = X;
    Y.translation() += d;
    return Y;
  };
  auto fail = [&](FailureStage stage, FailureKind kind, const std::string& message) {
    failure->stage = stage;
    failure->kind = kind;
    failure->grasp = grasp.surface;
    failure->message =
        std::string(FailureStageName(stage)) + " for grasp '" + grasp.surface + "': " + message;
    return false;
  };
  std::string reason;
  auto lap_start = std::chrono::steady_clock::now();
  std::map<std::string, double>* times = &plan->stage_times_s;
  const bool bent = fast.robot().gripper().bent();
  const double hover_m =
      bent ? BentHover(container, grasp, fast.robot().gripper()) : options_.guarded_distance_m;
  const std::optional<Eigen::Isometry3d> pre =
      PreGraspPose(container, grasp, hover_m, bent, &reason);
  if (!pre) {
    failure->before_search = true;
    return fail(FailureStage::kPreGrasp, FailureKind::kIkUnreachable, reason);
  }
  const Eigen::Isometry3d& X_pre = *pre;
  const Eigen::Isometry3d X_descend_end = translated(X_grasp, -a * hover_m);
  PlanFailure start_failure;
  const auto q_pre =
      DescentStart(X_pre, X_descend_end, X_grasp, request.start_rad, fast, &start_failure);
  Lap(times, "pre-grasp", &lap_start);
  if (!q_pre) {
    *failure = start_failure;  // body and obstacle
    failure->before_search = true;
    return fail(start_failure.stage, start_failure.kind, start_failure.message);
  }

  // Descend along the approach to guarded_distance short of the grasp.
  CartesianSearchOptions search = options_.search;
  search.deadline = deadline;
  if (tote) search.max_lateral_steps = search.max_tilt_steps = 0;  // tote picks go straight
  const CartesianSearchResult descend =
      SearchCartesianPath(motion, *q_pre, X_descend_end, nullptr, search);
  plan->nodes_expanded += descend.nodes_expanded;
  Lap(times, "descend", &lap_start);
  if (!descend.ok) {
    *failure = FromSearch(FailureStage::kDescend, grasp.surface, descend);
    return false;
  }
  // The guarded move and the lift: straight along the approach, the arm checked (the cup
  // touches the item, whose voxels are cut out).
  const ur10::Branch branch = robot_->kinematics().BranchOf(descend.path_rad.back());
  const Eigen::Isometry3d X_TcpTool = fast.robot().gripper().X_ToolTcp.inverse();
  const auto ik_grasp =
      robot_->kinematics().NearestSolution(X_grasp * X_TcpTool, descend.path_rad.back(), branch);
  if (!ik_grasp)
    return fail(FailureStage::kDescend, FailureKind::kIkUnreachable,
                "the grasp pose has no IK solution");
  const JointVector* q_grasp = &ik_grasp->q_rad;
  if (const MotionCheckResult m = motion.CheckSegment(descend.path_rad.back(), *q_grasp); !m.free) {
    failure->body = BodyName(m.report.body);
    failure->obstacle = m.report.obstacle;
    return fail(FailureStage::kDescend, FailureKind::kCollision,
                "the guarded move collides: " + m.report.ToString());
  }
  // The carried item hangs where it was detected relative to the cup.
  const CarriedItem carried =
      MakeCarriedItem(request.item, model->box_I, X_grasp.inverse() * request.X_BaseItem);
  PickPaths paths;
  const bool lifted = LiftAndRetreat(container, grasp, X_pre, hover_m, *q_grasp, carried, checks,
                                     search, &paths, &plan->nodes_expanded, failure);
  Lap(times, "retreat", &lap_start);
  if (!lifted) return false;
  // Approach: a joint motion from the start to the pre-grasp configuration.
  const JointPathResult approach = roadmap_->Plan(request.start_rad, *q_pre, &motion, deadline);
  Lap(times, "approach", &lap_start);
  if (!approach.ok) return fail(FailureStage::kApproach, FailureKind::kNoPath, approach.reason);
  CheckDeadline(deadline, "the pick's trajectories");

  plan->grasp = grasp;
  paths.approach = approach.path_rad;
  paths.descend = descend.path_rad;
  TimePickPaths(paths, request.speed_fraction, carried, motion, checks.exact, plan);
  plan->guarded_direction_Base = a;
  plan->guarded_distance_m = hover_m + GuardedOvershoot(X_grasp, a, *q_grasp, checks);
  Lap(times, "timing", &lap_start);
  plan->contact_distance_m = hover_m;
  plan->head_angle_rad = fast.robot().gripper().head_angle_rad;
  return true;
}

const MotionPlanner::RequestChecks* MotionPlanner::ChecksForGrasp(
    const PickRequest& request, const GraspContainer& container, const ScanObstacles* scan,
    const RequestChecks& straight, std::map<double, std::unique_ptr<RequestChecks>>* bent_checks,
    GraspCandidate* candidate, PlanFailure* refused) const {
  if (TubeReaches(container, *candidate, *robot_, refused)) return &straight;
  const GraspCandidate listed = *candidate;
  const auto bent = BendHead(container, listed, refused);
  if (!bent) return nullptr;
  *candidate = bent->first;
  auto& slot = (*bent_checks)[bent->second];
  if (!slot) {
    slot = std::make_unique<RequestChecks>(HeadAt(bent->second), *cell_, scan, options_.motion,
                                           options_.item_contact_margin_m);
  }
  // The head turns at the start, before the approach.
  if (const CollisionReport r = slot->fast.Check(request.start_rad); r.in_collision) {
    *refused = PlanFailure();
    refused->stage = FailureStage::kStart;
    refused->kind = FailureKind::kCollision;
    refused->grasp = listed.surface;
    refused->body = BodyName(r.body);
    refused->obstacle = r.obstacle;
    refused->message = "the head bent to " + Fixed(bent->second * 180.0 / M_PI, 0) +
                       " deg for grasp '" + listed.surface +
                       "' collides at the start: " + r.ToString();
    return nullptr;
  }
  return slot.get();
}

bool MotionPlanner::TryRolls(const PickRequest& request, const GraspCandidate& candidate,
                             const std::shared_ptr<const world::ItemModel>& model,
                             const RequestChecks& checks, bool bent, Deadline deadline,
                             PickPlan* plan, PlanFailure* best, bool* searched) const {
  // Suction is symmetric about the cup's axis: the wrist may take the grasp at another roll
  // where the first one runs into a joint limit, a wrist singularity or a wall. A bent head's
  // roll sets where the tube leaves the bin: a little to either side keeps the wrist off a
  // side wall or the tube off a neighbour.
  bool have_best = false;
  const auto rolls =
      bent ? std::array<double, 4>{0.0, options_.bent_roll_rad, -options_.bent_roll_rad, 0.0}
           : std::array<double, 4>{0.0, M_PI / 2, -M_PI / 2, M_PI};
  for (int k = 0; k < (bent ? 3 : 4); ++k) {
    const double roll = rolls[k];
    if (roll != 0.0 && !candidate.roll_symmetric && !bent) break;
    CheckDeadline(deadline, "the pick search");
    GraspCandidate rolled = candidate;
    const Eigen::Matrix3d R = Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    rolled.X_BaseTcp.linear() = candidate.X_BaseTcp.linear() * R;
    rolled.X_BaseTcpPreGrasp.linear() = candidate.X_BaseTcpPreGrasp.linear() * R;
    PlanFailure failure;
    try {
      if (TryGrasp(request, rolled, model, checks, deadline, plan, &failure)) {
        return true;
      }
    } catch (const PlanFailedError& e) {
      failure = e.failures().front();
      failure.grasp = candidate.surface;
    }
    if (!have_best || failure.fraction_achieved > best->fraction_achieved) *best = failure;
    have_best = true;
    if (!failure.before_search) *searched = true;
  }
  return false;
}

PlanFailure MotionPlanner::SearchBudgetSpent(const PickRequest& request,
                                             const GraspCandidate& grasp,
                                             int grasps_searched) const {
  PlanFailure f;
  f.stage = FailureStage::kSearch;
  f.kind = FailureKind::kSearchBudgetSpent;
  f.grasp = grasp.surface;
  char budget[32];
  std::snprintf(budget, sizeof(budget), "%.2f s", options_.search_time_budget_s);
  f.message = "the pick of '" + request.item + "' in " + request.container +
              " spent its search budget of " + budget + " over " + std::to_string(grasps_searched) +
              " searched grasps; the bin is too crowded around it for now";
  return f;
}

std::shared_ptr<const ModelSeal> MotionPlanner::SealOf(const std::string& item,
                                                       const world::ItemModel& model) const {
  std::lock_guard<std::mutex> lock(seal_mutex_);
  auto it = seals_.find(item);
  if (it == seals_.end()) {
    it = seals_.emplace(item, std::make_shared<const ModelSeal>(model.mesh, options_.seal)).first;
  }
  return it->second;
}

bool MotionPlanner::SealsOnModel(const PickRequest& request, const world::ItemModel& model,
                                 GraspCandidate* candidate, PlanFailure* refused) const {
  if (!options_.check_seal) return true;
  const ModelSealResult seal =
      SealOf(request.item, model)->Check(request.X_BaseItem, candidate->X_BaseTcp);
  if (seal.sealed) {
    candidate->X_BaseTcp.translation() += seal.shift_Base;
    candidate->X_BaseTcpPreGrasp.translation() += seal.shift_Base;
    candidate->p_BasePoint += seal.shift_Base;
    return true;
  }
  double farthest = 0.0;
  for (const double d : options_.seal.shift_m) farthest = std::max(farthest, d);
  *refused = PlanFailure();
  refused->stage = FailureStage::kGrasps;
  refused->kind = FailureKind::kNoSeal;
  refused->grasp = candidate->surface;
  refused->before_search = true;
  refused->message = "grasp '" + candidate->surface + "': the cup cannot seal on " + request.item +
                     "'s model there (" + seal.measure.reason + ") nor within " +
                     Fixed(100.0 * farthest, 0) + " cm of it";
  return false;
}

PickPlan MotionPlanner::PlanPick(const PickRequest& request, const PlanningScene* scene,
                                 Deadline deadline) const {
  const auto started = std::chrono::steady_clock::now();
  ValidateStart(request.start_rad);
  if (!IsRigid(request.X_BaseItem)) throw std::invalid_argument("X_base_item must be a rigid pose");
  if (!(request.speed_fraction > 0.0 && request.speed_fraction <= 1.0)) {
    throw std::invalid_argument("speed_fraction must be in (0, 1]");
  }
  std::shared_ptr<const world::ItemModel> model;
  try {
    model = items_->Get(request.item);
  } catch (const apc::UnknownItemError&) {
    throw NotFoundError("unknown item '" + request.item.substr(0, 60) + "'");
  }
  Container(request.container);  // throws NotFoundError
  CheckDeadline(deadline, "the pick's set-up");
  PickPlan plan;
  auto lap_start = started;
  const ScanObstacles* scan = scene ? scene->obstacles.get() : nullptr;
  RequestChecks straight(straight_head_, *cell_, scan, options_.motion,
                         options_.item_contact_margin_m);
  if (const CollisionReport r = straight.fast.Check(request.start_rad); r.in_collision) {
    throw PreconditionError("the start state collides: " + r.ToString());
  }
  // The checks with the head bent, per angle, built when a grasp first needs them.
  std::map<double, std::unique_ptr<RequestChecks>> bent_checks;
  Lap(&plan.stage_times_s, "set-up", &lap_start);
  const GraspResult grasps =
      ComputeGraspsFor(request.item, request.X_BaseItem, request.container, scene);
  Lap(&plan.stage_times_s, "grasps", &lap_start);
  if (grasps.empty()) {
    PlanFailure f;
    f.stage = FailureStage::kGrasps;
    f.kind = FailureKind::kNoGrasp;
    f.message =
        "no grasp for '" + request.item + "' in " + request.container + ": " + grasps.reason;
    throw PlanFailedError({f});
  }
  std::vector<PlanFailure> failures;
  const GraspContainer container = Container(request.container);
  const Deadline search_deadline =
      started + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                    std::chrono::duration<double>(options_.search_time_budget_s));
  for (const GraspCandidate& listed : grasps.candidates) {
    if (plan.grasps_tried >= options_.max_grasps_tried) break;
    // The tube's geometry at the grasp does not depend on the arm or the roll: a grasp it
    // rules out, straight and bent, is refused without IK or search and does not count.
    GraspCandidate candidate = listed;
    PlanFailure refused;
    lap_start = std::chrono::steady_clock::now();
    if (!SealsOnModel(request, *model, &candidate, &refused)) {
      Lap(&plan.stage_times_s, "seal", &lap_start);
      failures.push_back(refused);
      continue;
    }
    Lap(&plan.stage_times_s, "seal", &lap_start);
    const RequestChecks* checks =
        ChecksForGrasp(request, container, scan, straight, &bent_checks, &candidate, &refused);
    Lap(&plan.stage_times_s, "set-up", &lap_start);
    if (!checks) {
      failures.push_back(refused);
      continue;
    }
    PlanFailure best;
    bool searched = false;
    try {
      if (TryRolls(request, candidate, model, *checks, checks != &straight,
                   std::min(deadline, search_deadline), &plan, &best, &searched)) {
        ++plan.grasps_tried;
        plan.rejected = failures;
        plan.planning_time_s = Seconds(started);
        return plan;
      }
    } catch (const TimeoutError&) {
      if (std::chrono::steady_clock::now() > deadline) throw;
      failures.push_back(SearchBudgetSpent(request, candidate, plan.grasps_tried + 1));
      break;
    }
    if (searched) ++plan.grasps_tried;
    failures.push_back(best);
    if (std::chrono::steady_clock::now() > search_deadline) {
      failures.push_back(SearchBudgetSpent(request, candidate, plan.grasps_tried));
      break;
    }
  }
  // The most advanced attempt first.
  auto rank = [](const PlanFailure& f) { return StageRank(f.stage) + f.fraction_achieved; };
  std::stable_sort(failures.begin(), failures.end(),
                   [&](const auto& x, const auto& y) { return rank(x) > rank(y); });
  throw PlanFailedError(std::move(failures));
}

// ---------------------------------------------------------------------------------------
// Place

std::vector<Eigen::Vector2d> ToteReleaseSpots(const Eigen::Vector2d& inner_size_m,
                                              double margin_m) {
  // The cells' centres of a 3 x 2 grid, pulled in where a cell is narrower than the item.
  const Eigen::Vector2d reach = (0.5 * inner_size_m.array() - margin_m).max(0.0).matrix();
  const double cx = std::min(inner_size_m.x() / 3.0, reach.x());
  const double cy = std::min(inner_size_m.y() / 4.0, reach.y());
  return {{0.0, -cy}, {-cx, cy}, {cx, -cy}, {0.0, cy}, {-cx, -cy}, {cx, cy}};
}

namespace {

// Half the item's footprint when it hangs from the cup pointing down: its largest horizontal
// distance from the cup's axis.
double HalfFootprint(const Eigen::AlignedBox3d& box_I, const Eigen::Isometry3d& X_TcpItem) {
  double half = 0.0;
  for (int i = 0; i < 8; ++i) {
    const Eigen::Vector3d corner = box_I.corner(static_cast<Eigen::AlignedBox3d::CornerType>(i));
    half = std::max(half, (X_TcpItem * corner).head<2>().norm());
  }
  return half;
}

}  // namespace

std::vector<Eigen::Isometry3d> MotionPlanner::ReleasePoses(const GraspContainer& container,
                                                           const world::ItemModel& model,
                                                           const PlaceRequest& request,
                                                           double below_m) const {
  // Release over the tote (item 5 cm above the rim), on the table, or just inside a bin's
  // opening.
  std::vector<Eigen::Isometry3d> candidates;
  const Eigen::Vector3d centre = container.X_BaseContainer.translation();
  const double floor_z = centre.z() - 0.5 * container.inner_size_m.z();
  const double rim_z = centre.z() + 0.5 * container.inner_size_m.z();
  if (container.kind == GraspContainerKind::kOpenTop) {
    // The item's spot first (items let go one over the other stand and stack up above the
    // rim), then the others in turn, should the arm not reach it.
    const Eigen::Vector3d x = container.X_BaseContainer.linear().col(0);
    const Eigen::Vector3d y = container.X_BaseContainer.linear().col(1);
    const double half_footprint_m = HalfFootprint(model.box_I, request.X_TcpItem);
    std::vector<Eigen::Vector2d> spots =
        ToteReleaseSpots(container.inner_size_m.head<2>(), half_footprint_m);
    // Over the tote an item is let go 5 cm above the rim; on the table it is set down (2 cm
    // above the top), in the middle, where the verification view looks.
    const bool table = container.name == "table";
    const double release_z = table ? floor_z + 0.02 : rim_z + 0.05;
    if (table) spots.insert(spots.begin(), Eigen::Vector2d::Zero());
    for (std::size_t k = 0; k < spots.size(); ++k) {
      const std::size_t first = table ? 0 : static_cast<std::size_t>(request.placed_before);
      const Eigen::Vector2d& spot = spots[(first + k) % spots.size()];
      candidates.push_back(DownAt(centre + spot.x() * x + spot.y() * y +
                                  Eigen::Vector3d(0, 0, release_z - centre.z() + below_m)));
    }
  } else {
    // The cup points into the bin (horizontal); the item hanging from it is let go in the
    // bin's upper half, the tube clear of the ceiling, first half-way in, then just inside
    // the opening, each with the cup rolled so that the item's long side lies flat or stands.
    const Eigen::Vector3d z = -container.opening_direction_Base;
    const Eigen::Vector3d x = Eigen::Vector3d::UnitZ().cross(z).normalized();
    Eigen::Isometry3d X_flat = Eigen::Isometry3d::Identity();
    X_flat.linear().col(0) = x;
    X_flat.linear().col(1) = z.cross(x);
    X_flat.linear().col(2) = z;
    const double half_depth = 0.5 * container.inner_size_m.x();
    const double below_ceiling = robot_->gripper().tube_radius_m + 0.04;
    for (const double toward_opening_m : {0.0, half_depth - 0.08}) {
      for (const double down_m : {below_ceiling, 0.5 * container.inner_size_m.z()}) {
        for (const double roll_rad : {0.0, 0.5 * M_PI}) {
          Eigen::Isometry3d X = X_flat * Eigen::AngleAxisd(roll_rad, Eigen::Vector3d::UnitZ());
          X.translation() = centre + toward_opening_m * container.opening_direction_Base +
                            Eigen::Vector3d(0, 0, 0.5 * container.inner_size_m.z() - down_m);
          candidates.push_back(X);
        }
      }
    }
  }
  return candidates;
}

PlacePlan MotionPlanner::PlanPlace(const PlaceRequest& request, Deadline deadline) const {
  const auto started = std::chrono::steady_clock::now();
  ValidateStart(request.start_rad);
  std::shared_ptr<const world::ItemModel> model;
  try {
    model = items_->Get(request.item);
  } catch (const apc::UnknownItemError&) {
    throw NotFoundError("unknown item '" + request.item.substr(0, 60) + "'");
  }
  if (!IsRigid(request.X_TcpItem)) throw std::invalid_argument("X_tcp_item must be rigid");
  const GraspContainer container = Container(request.container);
  const std::shared_ptr<const Head> head_ptr = HeadAt(request.head_angle_rad);  // throws
  const Head& head = *head_ptr;
  const bool straight = head_ptr == straight_head_;
  const CarriedItem carried = MakeCarriedItem(request.item, model->box_I, request.X_TcpItem);
  // The item's lowest point below the tcp when the tcp points straight down.
  const Eigen::Isometry3d X_down = DownAt(Eigen::Vector3d::Zero());
  double below_m = 0.0;
  for (int i = 0; i < 8; ++i) {
    const Eigen::Vector3d corner((i & 1) ? model->box_I.max().x() : model->box_I.min().x(),
                                 (i & 2) ? model->box_I.max().y() : model->box_I.min().y(),
                                 (i & 4) ? model->box_I.max().z() : model->box_I.min().z());
    below_m = std::max(below_m, -(X_down * request.X_TcpItem * corner).z());
  }
  const double floor_z =
      container.X_BaseContainer.translation().z() - 0.5 * container.inner_size_m.z();
  PlacePlan plan;
  std::vector<PlanFailure> failures;
  const std::vector<Eigen::Isometry3d> candidates =
      ReleasePoses(container, *model, request, below_m);
  // A long item may still reach into the bin it came from: draw it straight out first, so
  // that the arm's first turn does not swing it into the shelf.
  const DrawOut draw_out = DrawItemOut(request, carried, head, deadline);
  const JointVector& start_rad = draw_out.path_rad.back();
  for (const Eigen::Isometry3d& X_release : candidates) {
    CheckDeadline(deadline, "the place");
    std::string reason;
    const auto q_release = FreeIk(X_release, start_rad, *head.fast, &carried, &reason);
    if (!q_release) {
      failures.push_back({FailureStage::kPlace, FailureKind::kIkUnreachable, "", -1, 0.0, "", "",
                          "release pose over " + request.container + ": " + reason});
      continue;
    }
    // Every motion of the search checked with the item on the cup.
    const JointPathResult path = roadmap_->Plan(
        start_rad, *q_release, straight ? nullptr : head.motion.get(), deadline, &carried);
    if (!path.ok) {
      failures.push_back({FailureStage::kPlace, FailureKind::kNoPath, "", -1, 0.0, "", "",
                          "no free motion to the release pose carrying the item: " + path.reason});
      continue;
    }
    std::vector<JointVector> joints = draw_out.path_rad;
    joints.insert(joints.end(), path.path_rad.begin() + 1, path.path_rad.end());
    plan.trajectory = TimeAndValidate(joints, request.speed_fraction, *head.motion, *head.exact,
                                      &carried, FailureStage::kPlace);
    plan.X_BaseTcp_release = X_release;
    plan.drop_height_m = X_release.translation().z() - below_m - floor_z;
    plan.planning_time_s = Seconds(started);
    return plan;
  }
  throw PlanFailedError(std::move(failures));
}

}  // namespace picking::planner
