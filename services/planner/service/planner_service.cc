#include "services/planner/service/planner_service.h"

#include "libs/runtime/log.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>

#include "google/rpc/status.pb.h"
#include "libs/apc/catalogue.h"
#include "libs/errors/errors.h"
#include "libs/proto_convert/proto_convert.h"
#include "libs/runtime/status.h"
#include "libs/ur10/kinematics.h"
#include "libs/world/cell_config.h"
#include "libs/world/item_models.h"
#include "services/planner/core/motion_planner.h"
#include "services/planner/core/scene_store.h"

namespace picking::planner {
namespace {

namespace pb = ::picking::planner::v1;
namespace pc = ::picking::proto_convert;
namespace cpb = ::picking::common::v1;

ur10::JointVector ToJointVector(const std::array<double, 6>& q) {
  ur10::JointVector v;
  for (int i = 0; i < 6; ++i) v[i] = q[i];
  return v;
}

std::array<double, 6> ToArray(const ur10::JointVector& v) {
  std::array<double, 6> q{};
  for (int i = 0; i < 6; ++i) q[i] = v[i];
  return q;
}

ur10::JointVector JointsFrom(const cpb::JointPositions& joints, const char* field) {
  return ToJointVector(pc::JointsFromProto(joints, field));
}

void ToProto(const Trajectory& trajectory, cpb::JointTrajectory* out) {
  for (const TrajectorySample& s : trajectory.samples) {
    auto* point = out->add_points();
    point->set_time_from_start_s(s.time_s);
    for (int j = 0; j < 6; ++j) {
      point->add_positions_rad(s.q_rad[j]);
      point->add_velocities_rad_s(s.qd_rad_s[j]);
      point->add_accelerations_rad_s2(s.qdd_rad_s2[j]);
    }
  }
}

void ToProto(const GraspCandidate& g, pb::Grasp* out) {
  *out->mutable_x_base_tcp() = pc::PoseToProto(g.X_BaseTcp);
  *out->mutable_x_base_tcp_pregrasp() = pc::PoseToProto(g.X_BaseTcpPreGrasp);
  *out->mutable_approach_base() = pc::VectorToProto(g.approach_Base);
  out->set_score(g.score.total);
  out->set_surface(g.surface);
  out->set_face_size_score(g.score.face_size);
  out->set_centrality_score(g.score.centrality);
  out->set_clearance_score(g.score.clearance);
  out->set_approach_score(g.score.approach);
  out->set_clearance_m(g.clearance_m);
}

pb::PlanFailureStage ToProto(FailureStage stage) {
  switch (stage) {
    case FailureStage::kUnspecified:
      return pb::PLAN_FAILURE_STAGE_UNSPECIFIED;
    case FailureStage::kStart:
      return pb::PLAN_FAILURE_STAGE_START;
    case FailureStage::kGrasps:
      return pb::PLAN_FAILURE_STAGE_GRASPS;
    case FailureStage::kPreGrasp:
      return pb::PLAN_FAILURE_STAGE_PRE_GRASP;
    case FailureStage::kDescend:
      return pb::PLAN_FAILURE_STAGE_DESCEND;
    case FailureStage::kRetreat:
      return pb::PLAN_FAILURE_STAGE_RETREAT;
    case FailureStage::kApproach:
      return pb::PLAN_FAILURE_STAGE_APPROACH;
    case FailureStage::kPlace:
      return pb::PLAN_FAILURE_STAGE_PLACE;
    case FailureStage::kJointMotion:
      return pb::PLAN_FAILURE_STAGE_JOINT_MOTION;
    case FailureStage::kSearch:
      return pb::PLAN_FAILURE_STAGE_SEARCH;
  }
  return pb::PLAN_FAILURE_STAGE_UNSPECIFIED;
}

pb::PlanFailureKind ToProto(FailureKind kind) {
  switch (kind) {
    case FailureKind::kUnspecified:
      return pb::PLAN_FAILURE_KIND_UNSPECIFIED;
    case FailureKind::kCollision:
      return pb::PLAN_FAILURE_KIND_COLLISION;
    case FailureKind::kIkUnreachable:
      return pb::PLAN_FAILURE_KIND_IK_UNREACHABLE;
    case FailureKind::kJointJump:
      return pb::PLAN_FAILURE_KIND_JOINT_JUMP;
    case FailureKind::kNodeBudgetSpent:
      return pb::PLAN_FAILURE_KIND_NODE_BUDGET_SPENT;
    case FailureKind::kDeadline:
      return pb::PLAN_FAILURE_KIND_DEADLINE;
    case FailureKind::kNoGrasp:
      return pb::PLAN_FAILURE_KIND_NO_GRASP;
    case FailureKind::kNoPath:
      return pb::PLAN_FAILURE_KIND_NO_PATH;
    case FailureKind::kTiming:
      return pb::PLAN_FAILURE_KIND_TIMING;
    case FailureKind::kTubeBlocked:
      return pb::PLAN_FAILURE_KIND_TUBE_BLOCKED;
    case FailureKind::kSearchBudgetSpent:
      return pb::PLAN_FAILURE_KIND_SEARCH_BUDGET_SPENT;
    case FailureKind::kStartInCollision:
      return pb::PLAN_FAILURE_KIND_START_IN_COLLISION;
    case FailureKind::kNoSeal:
      return pb::PLAN_FAILURE_KIND_NO_SEAL;
  }
  return pb::PLAN_FAILURE_KIND_UNSPECIFIED;
}

// ABORTED with one PlanFailure per attempt in the rich error details, the most advanced
// first, as many as fit: the details travel in the trailing metadata, which clients cap (8 KiB
// by default, base64 taking a third more).
grpc::Status Aborted(const PlanFailedError& error) {
  constexpr std::size_t kMaxDetailBytes = 4096;
  google::rpc::Status details;
  details.set_code(grpc::StatusCode::ABORTED);
  details.set_message(runtime::CutMessage(error.what(), 1024));
  for (const PlanFailure& f : error.failures()) {
    if (details.details_size() > 0 &&
        details.ByteSizeLong() + std::min<std::size_t>(f.message.size(), 1024) + 256 >
            kMaxDetailBytes) {
      break;
    }
    pb::PlanFailure message;
    message.set_stage(ToProto(f.stage));
    message.set_kind(ToProto(f.kind));
    message.set_grasp(f.grasp);
    message.set_node(f.node);
    message.set_fraction_achieved(f.fraction_achieved);
    message.set_body(f.body);
    message.set_obstacle(f.obstacle);
    message.set_message(runtime::CutMessage(f.message, 1024));
    details.add_details()->PackFrom(message);
  }
  std::string message = runtime::CutMessage(error.what(), 1024);
  if (error.failures().size() > 1) {
    message += " (and " + std::to_string(error.failures().size() - 1) + " more attempts";
    const std::size_t listed = static_cast<std::size_t>(details.details_size());
    if (listed < error.failures().size()) {
      message += ", " + std::to_string(listed) + " in the details";
    }
    message += ")";
  }
  return grpc::Status(grpc::StatusCode::ABORTED, message, details.SerializeAsString());
}

// The call's deadline on the steady clock, at most `cap_s` away.
Deadline DeadlineOf(const grpc::ServerContext* ctx, double cap_s) {
  const auto now_system = std::chrono::system_clock::now();
  const auto now_steady = std::chrono::steady_clock::now();
  auto remaining =
      std::chrono::duration_cast<std::chrono::steady_clock::duration>(ctx->deadline() - now_system);
  const auto cap = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
      std::chrono::duration<double>(cap_s));
  if (ctx->deadline() == std::chrono::system_clock::time_point::max() || remaining > cap) {
    remaining = cap;
  }
  return now_steady + remaining;
}

Eigen::Isometry3d ReadHandEye(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot read the hand-eye calibration '" + path + "'");
  const nlohmann::json j = nlohmann::json::parse(in);
  const auto& v = j.at("values");
  if (v.at("parent_frame") != "tool" || v.at("child_frame") != "camera") {
    throw std::runtime_error(path + ": the hand-eye calibration must be camera in tool");
  }
  const auto t = v.at("translation_m").get<std::vector<double>>();
  const auto q = v.at("rotation_xyzw").get<std::vector<double>>();
  if (t.size() != 3 || q.size() != 4) throw std::runtime_error(path + ": malformed hand-eye");
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::Quaterniond(q[3], q[0], q[1], q[2]).normalized().toRotationMatrix();
  X.translation() = Eigen::Vector3d(t[0], t[1], t[2]);
  return X;
}

// Settings of the service, with their defaults.
struct Settings {
  double scene_ttl_s = 120.0;
  std::size_t max_scenes = 32;
  double max_plan_time_s = 30.0;
  std::uint64_t max_cloud_points = 20'000'000;
};

class PlannerServiceImpl final : public pb::PlannerService::Service {
 public:
  PlannerServiceImpl(std::shared_ptr<const MotionPlanner> planner, const Settings& settings)
      : planner_(std::move(planner)),
        settings_(settings),
        kinematics_(planner_->robot().kinematics()),
        X_ToolTcp_(planner_->robot().gripper().X_ToolTcp),
        scenes_(settings.max_scenes) {}

  grpc::Status ComputeFk(grpc::ServerContext*, const pb::ComputeFkRequest* request,
                         pb::ComputeFkResponse* response) override {
    return runtime::Guard([&] {
      const ur10::JointVector q = JointsFrom(request->joints(), "joints");
      if (const std::string out = kinematics_.model().PositionLimitViolation(q); !out.empty()) {
        return runtime::InvalidArgument("joints: " + out);
      }
      const Eigen::Isometry3d X_BaseTool = kinematics_.ForwardKinematics(q);
      *response->mutable_x_base_tool() = pc::PoseToProto(X_BaseTool);
      *response->mutable_x_base_tcp() = pc::PoseToProto(X_BaseTool * X_ToolTcp_);
      const auto links = kinematics_.LinkFrames(q);
      for (int i = 0; i < ur10::kNumLinks; ++i) {
        auto* link = response->add_links();
        link->set_parent_frame("base");
        link->set_child_frame(ur10::LinkName(static_cast<ur10::Link>(i)));
        *link->mutable_pose() = pc::PoseToProto(links[i]);
      }
      return grpc::Status::OK;
    });
  }

  grpc::Status ComputeIk(grpc::ServerContext*, const pb::ComputeIkRequest* request,
                         pb::ComputeIkResponse* response) override {
    return runtime::Guard([&] {
      const Eigen::Isometry3d X_BaseTcp = pc::PoseFromProto(request->x_base_tcp(), "X_base_tcp");
      ur10::IkOptions options;
      if (request->has_seed()) options.seed_rad = JointsFrom(request->seed(), "seed");
      const ur10::IkResult result = kinematics_.Solve(X_BaseTcp * X_ToolTcp_.inverse(), options);
      std::vector<ur10::IkSolution> solutions = result.solutions;
      if (options.seed_rad) {
        const ur10::JointVector seed = *options.seed_rad;
        auto distance = [&](const ur10::IkSolution& s) {
          const ur10::JointVector d = (s.q_rad - seed).cwiseAbs();
          return std::make_pair(d.maxCoeff(), d.squaredNorm());
        };
        std::stable_sort(solutions.begin(), solutions.end(),
                         [&](const auto& a, const auto& b) { return distance(a) < distance(b); });
      }
      for (const auto& s : solutions) {
        auto* out = response->add_solutions();
        *out->mutable_joints() = pc::JointsToProto(ToArray(s.q_rad));
        out->set_branch(static_cast<std::uint32_t>(s.branch.id()));
        out->set_branch_name(s.branch.ToString());
        out->set_wrist_singular(s.wrist_singular);
      }
      if (solutions.empty()) response->set_reason(result.reason);
      return grpc::Status::OK;
    });
  }

  grpc::Status ListNamedPoses(grpc::ServerContext*, const pb::ListNamedPosesRequest*,
                              pb::ListNamedPosesResponse* response) override {
    for (const NamedPose& pose : planner_->named_poses()) {
      auto* out = response->add_poses();
      out->set_name(pose.name);
      *out->mutable_joints() = pc::JointsToProto(ToArray(pose.q_rad));
    }
    return grpc::Status::OK;
  }

  grpc::Status PlanJointMotion(grpc::ServerContext* ctx, const pb::PlanJointMotionRequest* request,
                               pb::PlanJointMotionResponse* response) override {
    return Run([&] {
      const ur10::JointVector start = JointsFrom(request->start(), "start");
      ur10::JointVector goal;
      if (request->has_goal_joints()) {
        goal = JointsFrom(request->goal_joints(), "goal_joints");
      } else if (!request->goal_name().empty()) {
        goal = NamedJoints(request->goal_name());
      } else {
        throw std::invalid_argument("set goal_joints or goal_name");
      }
      const JointMotionPlan plan =
          planner_->PlanJointMotion(start, goal, SpeedFraction(request->speed_fraction()),
                                    CallDeadline(ctx), request->head_angle_rad());
      ToProto(plan.trajectory, response->mutable_trajectory());
      response->set_planning_time_s(plan.planning_time_s);
    });
  }

  grpc::Status ComputeGrasps(grpc::ServerContext*, const pb::ComputeGraspsRequest* request,
                             pb::ComputeGraspsResponse* response) override {
    return Run([&] {
      const Eigen::Isometry3d X_BaseItem = pc::PoseFromProto(request->x_base_item(), "X_base_item");
      const std::string container = pc::ContainerName(request->container());
      std::shared_ptr<const PlanningScene> scene;
      if (!request->scene_id().empty()) scene = scenes_.Get(request->scene_id());
      const GraspResult grasps =
          planner_->ComputeGraspsFor(request->item(), X_BaseItem, container, scene.get());
      for (const GraspCandidate& g : grasps.candidates) ToProto(g, response->add_grasps());
      response->set_reason(grasps.reason);
    });
  }

  grpc::Status UpdateScene(grpc::ServerContext*, grpc::ServerReader<pb::UpdateSceneRequest>* reader,
                           pb::UpdateSceneResponse* response) override {
    return Run([&] {
      pb::UpdateSceneRequest first;
      if (!reader->Read(&first) || !first.has_params()) {
        throw std::invalid_argument("the first message must carry params");
      }
      const pb::UpdateSceneParams& params = first.params();
      const double ttl_s = params.ttl_s() == 0.0 ? settings_.scene_ttl_s : params.ttl_s();
      if (!(ttl_s > 0.0 && ttl_s <= 3600.0))
        throw std::invalid_argument("ttl_s must be in (0, 3600]");
      std::shared_ptr<const PlanningScene> previous;
      if (!params.scene_id().empty()) previous = scenes_.Get(params.scene_id());
      const geometry::PointCloud cloud = ReadCloud(reader, nullptr);
      const PlanningScene scene =
          BuildScene(pc::ContainerName(params.container()), cloud, params.item(),
                     params.has_x_base_item(), params.x_base_item(), previous.get());
      const std::string id =
          scenes_.Put(std::make_shared<PlanningScene>(scene), ttl_s, params.scene_id());
      response->set_scene_id(id);
      response->set_points(scene.stats.points);
      response->set_points_invalid(scene.stats.points_invalid);
      response->set_points_outside(scene.stats.points_outside);
      response->set_points_cut(scene.stats.points_cut);
      response->set_occupied_voxels(scene.stats.voxels_total);
      response->set_voxels_cleared(scene.stats.voxels_cleared);
      response->set_build_time_s(scene.build_time_s);
    });
  }

  grpc::Status PlanPick(grpc::ServerContext* ctx, grpc::ServerReader<pb::PlanPickRequest>* reader,
                        pb::PlanPickResponse* response) override {
    return Run([&] {
      pb::PlanPickRequest first;
      if (!reader->Read(&first) || !first.has_params()) {
        throw std::invalid_argument("the first message must carry params");
      }
      const pb::PlanPickParams& params = first.params();
      if (params.octomap_resolution_m() != 0.0 &&
          std::abs(params.octomap_resolution_m() - planner_->options().scene_resolution_m) > 1e-9) {
        throw std::invalid_argument("this planner builds scenes at " +
                                    std::to_string(planner_->options().scene_resolution_m) +
                                    " m; octomap_resolution_m must be 0 or that");
      }
      if (params.cartesian_step_m() != 0.0 &&
          std::abs(params.cartesian_step_m() - planner_->options().search.step_m) > 1e-9) {
        throw std::invalid_argument("this planner searches in " +
                                    std::to_string(planner_->options().search.step_m) +
                                    " m steps; cartesian_step_m must be 0 or that");
      }
      PickRequest pick;
      pick.item = params.item();
      pick.X_BaseItem = pc::PoseFromProto(params.x_base_item(), "X_base_item");
      pick.container = pc::ContainerName(params.container());
      pick.start_rad = JointsFrom(params.start(), "start");
      pick.speed_fraction = SpeedFraction(params.speed_fraction());
      std::shared_ptr<const PlanningScene> scene;
      if (!params.scene_id().empty()) {
        scene = scenes_.Get(params.scene_id());
        pb::PlanPickRequest extra;
        if (reader->Read(&extra)) {
          throw std::invalid_argument("no cloud may follow params that name a scene_id");
        }
      } else {
        bool any = false;
        const geometry::PointCloud cloud = ReadCloud(reader, &any);
        if (any) {
          scene = std::make_shared<PlanningScene>(
              BuildScene(pick.container, cloud, pick.item, true, params.x_base_item(), nullptr));
        }
      }
      const PickPlan plan = planner_->PlanPick(pick, scene.get(), CallDeadline(ctx));
      ToProto(plan.grasp, response->mutable_grasp());
      ToProto(plan.approach, response->mutable_approach());
      ToProto(plan.descend, response->mutable_descend());
      ToProto(plan.retreat, response->mutable_retreat());
      *response->mutable_guarded_direction() = pc::VectorToProto(plan.guarded_direction_Base);
      response->set_guarded_distance_m(plan.guarded_distance_m);
      response->set_contact_distance_m(plan.contact_distance_m);
      response->set_planning_time_s(plan.planning_time_s);
      response->set_nodes_expanded(static_cast<std::uint32_t>(plan.nodes_expanded));
      response->set_head_angle_rad(plan.head_angle_rad);
    });
  }

  grpc::Status PlanPlace(grpc::ServerContext* ctx, const pb::PlanPlaceRequest* request,
                         pb::PlanPlaceResponse* response) override {
    return Run([&] {
      PlaceRequest place;
      place.item = request->item();
      place.container = pc::ContainerName(request->container());
      place.start_rad = JointsFrom(request->start(), "start");
      place.speed_fraction = SpeedFraction(request->speed_fraction());
      place.head_angle_rad = request->head_angle_rad();
      if (request->placed_before() > 1000) {
        throw std::invalid_argument("placed_before: at most 1000, got " +
                                    std::to_string(request->placed_before()));
      }
      place.placed_before = static_cast<int>(request->placed_before());
      if (request->has_x_tcp_item()) {
        place.X_TcpItem = pc::PoseFromProto(request->x_tcp_item(), "X_tcp_item");
      } else {
        place.X_TcpItem = DefaultHang(place.item);
      }
      const PlacePlan plan = planner_->PlanPlace(place, CallDeadline(ctx));
      ToProto(plan.trajectory, response->mutable_trajectory());
      *response->mutable_x_base_tcp_release() = pc::PoseToProto(plan.X_BaseTcp_release);
      response->set_drop_height_m(plan.drop_height_m);
    });
  }

 private:
  // Runs a handler body, mapping PlanFailedError to ABORTED and the rest as usual.
  template <class Fn>
  grpc::Status Run(Fn&& fn) {
    return runtime::Guard([&]() -> grpc::Status {
      try {
        fn();
        return grpc::Status::OK;
      } catch (const PlanFailedError& e) {
        return Aborted(e);
      } catch (const apc::UnknownItemError& e) {
        return runtime::NotFound(std::string(e.what()).substr(0, 200));
      }
    });
  }

  Deadline CallDeadline(const grpc::ServerContext* ctx) const {
    return DeadlineOf(ctx, settings_.max_plan_time_s);
  }

  static double SpeedFraction(double value) {
    if (value == 0.0) return 1.0;
    if (!(value > 0.0 && value <= 1.0))
      throw std::invalid_argument("speed_fraction must be in (0, 1]");
    return value;
  }

  ur10::JointVector NamedJoints(const std::string& name) const {
    for (const NamedPose& pose : planner_->named_poses()) {
      if (pose.name == name) return pose.q_rad;
    }
    throw std::invalid_argument("unknown named pose '" + name.substr(0, 60) +
                                "' (ListNamedPoses lists them)");
  }

  // The item centred below the cup, held by its +z face (its largest).
  Eigen::Isometry3d DefaultHang(const std::string& item) const {
    const apc::Item* entry = apc_catalogue().find(item);
    if (!entry) throw NotFoundError("unknown item '" + item.substr(0, 60) + "'");
    Eigen::Isometry3d X_TcpItem = Eigen::Isometry3d::Identity();
    X_TcpItem.linear() = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix();
    X_TcpItem.translation() = Eigen::Vector3d(0, 0, 0.5 * entry->short_side_m);
    return X_TcpItem;
  }

  const apc::Catalogue& apc_catalogue() const {
    static const apc::Catalogue catalogue =
        apc::Catalogue::FromCsvFile(apc::DefaultCataloguePath());
    return catalogue;
  }

  template <class Request>
  geometry::PointCloud ReadCloud(grpc::ServerReader<Request>* reader, bool* any) const {
    pc::CloudAssembler assembler(settings_.max_cloud_points);
    Request message;
    while (reader->Read(&message)) {
      if (!message.has_cloud()) throw std::invalid_argument("only cloud chunks may follow params");
      assembler.Add(message.cloud());
    }
    if (any) *any = assembler.started();
    if (!assembler.started()) return {};
    return assembler.Finish();
  }

  PlanningScene BuildScene(const std::string& container, const geometry::PointCloud& cloud,
                           const std::string& item, bool has_pose, const cpb::Pose& pose,
                           const PlanningScene* previous) const {
    Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();
    if (!item.empty()) {
      if (!has_pose)
        throw std::invalid_argument("X_base_item is needed to cut out '" + item.substr(0, 60) +
                                    "'");
      X_BaseItem = pc::PoseFromProto(pose, "X_base_item");
    }
    return planner_->BuildScene(container, reinterpret_cast<const float*>(cloud.points.data()),
                                cloud.points.size(), item, X_BaseItem, previous);
  }

  std::shared_ptr<const MotionPlanner> planner_;
  Settings settings_;
  const ur10::Ur10Kinematics& kinematics_;
  const Eigen::Isometry3d X_ToolTcp_;
  SceneStore scenes_;
};

}  // namespace

runtime::ServiceSet BuildPlannerServices(const runtime::Config& config) {
  const std::string data_dir = config.GetString("data_dir", apc::DefaultDataDir());
  ur10::Ur10ModelOptions model_options;
  model_options.max_acceleration_rad_s2 =
      config.GetDouble("ur10.max_acceleration_rad_s2", model_options.max_acceleration_rad_s2);
  const ur10::Ur10Kinematics kinematics(ur10::Ur10Model::Load(data_dir + "/ur10", model_options));
  // The tool centre point and the gripper's tube from the cell description every service
  // loads; the static cell from the same file.
  const std::string cell_path = config.GetPath("cell", world::DefaultCellConfigPath(data_dir));
  world::CellConfig cell_config;
  try {
    cell_config = world::ReadCellConfig(cell_path);
  } catch (const world::CellConfigError& e) {
    throw std::invalid_argument(std::string("setting 'cell': ") + e.what());
  }
  const GripperGeometry gripper = GripperGeometry::FromCell(cell_config.gripper);
  const world::CellModel cell = world::LoadCellModel(cell_config);
  const Eigen::Isometry3d X_ToolCamera =
      ReadHandEye(config.GetString("hand_eye", data_dir + "/scanner/sim_sensor/hand_eye.json"));
  apc::Catalogue catalogue = apc::Catalogue::FromCsvFile(apc::DefaultCataloguePath());
  auto grasps = std::make_shared<const GraspTable>(
      GraspTable::FromYamlFile(config.GetString("grasps", DefaultGraspTablePath()), catalogue));
  auto items = std::make_shared<world::ItemModelLibrary>(std::move(catalogue));

  MotionPlannerOptions options;
  options.search.node_budget =
      static_cast<int>(config.GetInt("search.node_budget", options.search.node_budget));
  options.search_time_budget_s =
      config.GetDouble("search.time_budget_s", options.search_time_budget_s);
  options.search.step_m = config.GetDouble("search.step_m", options.search.step_m);
  options.guarded_distance_m = config.GetDouble("guarded_distance_m", options.guarded_distance_m);
  options.cut_margin_m = config.GetDouble("scene.cut_margin_m", options.cut_margin_m);
  Settings settings;
  settings.scene_ttl_s = config.GetDouble("scene.ttl_s", settings.scene_ttl_s);
  settings.max_scenes = static_cast<std::size_t>(config.GetInt("scene.max_scenes", 32));
  settings.max_plan_time_s = config.GetDouble("max_plan_time_s", settings.max_plan_time_s);
  if (!(options.search.step_m >= 0.005 && options.search.step_m <= 0.1)) {
    throw std::invalid_argument("setting 'search.step_m' must be in [0.005, 0.1]");
  }
  if (options.search.node_budget < 10 || !(options.search_time_budget_s > 0) ||
      settings.max_scenes < 1 || !(settings.scene_ttl_s > 0)) {
    throw std::invalid_argument(
        "search.node_budget >= 10, search.time_budget_s > 0, scene.max_scenes >= 1, "
        "scene.ttl_s > 0");
  }
  auto planner = std::make_shared<const MotionPlanner>(kinematics, cell, gripper, X_ToolCamera,
                                                       grasps, items, options);
  for (const std::string& name : planner->unreachable_named_poses()) {
    runtime::LogWarning("named pose unreachable: no motion from home reaches it", {{"pose", name}});
  }
  runtime::ServiceSet set;
  set.Add(std::make_shared<PlannerServiceImpl>(std::move(planner), settings),
          pb::PlannerService::service_full_name());
  return set;
}

}  // namespace picking::planner
