#include "services/orchestrator/service/grpc_cell.h"

#include <google/rpc/status.pb.h>
#include <grpcpp/channel.h>
#include <grpcpp/client_context.h>

#include <algorithm>
#include <future>

#include "libs/proto_convert/proto_convert.h"

namespace picking::orchestrator {
namespace pc = ::picking::proto_convert;
namespace sc = ::picking::scanner::v1;
namespace dt = ::picking::detector::v1;
namespace pl = ::picking::planner::v1;
namespace rb = ::picking::robot::v1;
namespace gr = ::picking::gripper::v1;
namespace cm = ::picking::common::v1;
namespace {

// The robot's answer when its own checks refuse a motion before it starts (nothing moved):
// the item's failure, not the cell's.
bool RefusedBeforeMoving(const grpc::Status& status) {
  return status.error_code() == grpc::StatusCode::FAILED_PRECONDITION ||
         status.error_code() == grpc::StatusCode::INVALID_ARGUMENT;
}

void SetDeadline(grpc::ClientContext& ctx, double seconds) {
  ctx.set_deadline(std::chrono::system_clock::now() +
                   std::chrono::microseconds(static_cast<long long>(seconds * 1e6)));
}

double Duration(const cm::JointTrajectory& t) {
  return t.points_size() == 0 ? 0.0 : t.points(t.points_size() - 1).time_from_start_s();
}

// A trajectory's joints thinned to at most `max_points` (its ends kept), for a viewer.
void AppendThinned(const cm::JointTrajectory& t, int max_points,
                   std::vector<std::array<double, 6>>& path_q) {
  const int n = t.points_size();
  if (n == 0) return;
  const int stride = std::max(1, (n + max_points - 1) / max_points);
  for (int i = 0; i < n; i += stride) {
    if (t.points(i).positions_rad_size() != 6) continue;
    std::array<double, 6> q{};
    std::copy(t.points(i).positions_rad().begin(), t.points(i).positions_rad().end(), q.begin());
    path_q.push_back(q);
  }
  if ((n - 1) % stride != 0 && t.points(n - 1).positions_rad_size() == 6) {
    std::array<double, 6> q{};
    const auto& last = t.points(n - 1).positions_rad();
    std::copy(last.begin(), last.end(), q.begin());
    path_q.push_back(q);
  }
}

// The planner's name of a failure's stage in its messages; null for one not known here.
const char* StageName(pl::PlanFailureStage stage) {
  switch (stage) {
    case pl::PLAN_FAILURE_STAGE_START:
      return "start";
    case pl::PLAN_FAILURE_STAGE_GRASPS:
      return "grasps";
    case pl::PLAN_FAILURE_STAGE_PRE_GRASP:
      return "pre-grasp";
    case pl::PLAN_FAILURE_STAGE_DESCEND:
      return "descend";
    case pl::PLAN_FAILURE_STAGE_RETREAT:
      return "retreat";
    case pl::PLAN_FAILURE_STAGE_APPROACH:
      return "approach";
    case pl::PLAN_FAILURE_STAGE_PLACE:
      return "place";
    case pl::PLAN_FAILURE_STAGE_JOINT_MOTION:
      return "joint motion";
    case pl::PLAN_FAILURE_STAGE_SEARCH:
      return "search";
    default:
      return nullptr;
  }
}

// The planner's typed failure from the status details, else the status message.
// Whether the planner's first (most advanced) failure is another item's doing: the scan is
// what it hits, or no grasp has room behind it (the rest of the scan over it).
bool OthersInTheWay(const grpc::Status& status) {
  google::rpc::Status details;
  if (status.error_details().empty() || !details.ParseFromString(status.error_details())) {
    return false;
  }
  for (const auto& any : details.details()) {
    pl::PlanFailure failure;
    if (!any.UnpackTo(&failure)) continue;
    return failure.obstacle() == "scan" ||
           (failure.kind() == pl::PLAN_FAILURE_KIND_NO_GRASP &&
            failure.message().find("free behind") != std::string::npos);
  }
  return false;
}

std::string PlanFailureMessage(const grpc::Status& status) {
  google::rpc::Status details;
  if (!status.error_details().empty() && details.ParseFromString(status.error_details())) {
    for (const auto& any : details.details()) {
      pl::PlanFailure failure;
      if (any.UnpackTo(&failure) && !failure.message().empty()) {
        const char* stage = StageName(failure.stage());
        return stage ? std::string(stage) + ": " + failure.message() : failure.message();
      }
    }
  }
  return status.error_message();
}

// The trajectory run backwards: the same path, each sample at T - t with its velocity
// negated (accelerations keep their sign), so it keeps the limits it was timed within.
cm::JointTrajectory Reversed(const cm::JointTrajectory& t) {
  cm::JointTrajectory out;
  const double total = Duration(t);
  for (int i = t.points_size() - 1; i >= 0; --i) {
    cm::TrajectoryPoint p = t.points(i);
    p.set_time_from_start_s(total - t.points(i).time_from_start_s());
    for (int j = 0; j < p.velocities_rad_s_size(); ++j) {
      p.set_velocities_rad_s(j, -p.velocities_rad_s(j));
    }
    *out.add_points() = p;
  }
  return out;
}

// The views' organised clouds stacked row-wise, as the detector takes several views.
geometry::PointCloud StackViews(const std::vector<ScanView>& views) {
  geometry::PointCloud out = *views.front().cloud_Base;
  for (std::size_t i = 1; i < views.size(); ++i) {
    const geometry::PointCloud& v = *views[i].cloud_Base;
    if (v.width != out.width || v.has_normals() != out.has_normals() ||
        v.has_intensities() != out.has_intensities() || v.has_colors() != out.has_colors()) {
      throw CellError("scanner", false, "the views of one scan differ in size or channels");
    }
    out.points.insert(out.points.end(), v.points.begin(), v.points.end());
    out.normals.insert(out.normals.end(), v.normals.begin(), v.normals.end());
    out.intensities.insert(out.intensities.end(), v.intensities.begin(), v.intensities.end());
    out.colors.insert(out.colors.end(), v.colors.begin(), v.colors.end());
    out.height += v.height;
  }
  return out;
}

}  // namespace

void ThrowIfFailed(const std::string& service, const std::string& what,
                   const grpc::Status& status) {
  if (status.ok()) return;
  const bool retryable = status.error_code() == grpc::StatusCode::UNAVAILABLE ||
                         status.error_code() == grpc::StatusCode::DEADLINE_EXCEEDED;
  throw CellError(service, retryable, what + ": " + status.error_message());
}

GrpcCell::GrpcCell(GrpcCellOptions options)
    : options_(std::move(options)),
      scanner_(sc::ScannerService::NewStub(options_.scanner)),
      planner_(pl::PlannerService::NewStub(options_.planner)),
      robot_(rb::RobotService::NewStub(options_.robot)),
      gripper_(gr::GripperService::NewStub(options_.gripper)) {}

std::vector<std::string> GrpcCell::ScanPoses(const std::string& container) {
  if (scan_poses_.empty()) {
    grpc::ClientContext ctx;
    SetDeadline(ctx, options_.plan_deadline_s);
    pl::ListNamedPosesResponse poses;
    ThrowIfFailed("planner", "ListNamedPoses", planner_->ListNamedPoses(&ctx, {}, &poses));
    for (const auto& p : poses.poses()) {
      const std::string& name = p.name();
      if (name.rfind("scan/", 0) != 0) continue;
      const std::size_t slash = name.find('/', 5);
      if (slash != std::string::npos) scan_poses_[name.substr(5, slash - 5)].push_back(name);
    }
    for (auto& [c, names] : scan_poses_) std::sort(names.begin(), names.end());
  }
  const auto it = scan_poses_.find(container);
  if (it == scan_poses_.end()) {
    throw CellError("planner", false, "no scan poses for '" + container + "'");
  }
  return it->second;
}

rb::GetStateResponse GrpcCell::RobotState() {
  grpc::ClientContext ctx;
  SetDeadline(ctx, 5.0);
  rb::GetStateResponse state;
  ThrowIfFailed("robot", "GetState", robot_->GetState(&ctx, {}, &state));
  return state;
}

double GrpcCell::Execute(const cm::JointTrajectory& trajectory) {
  grpc::ClientContext ctx;
  SetDeadline(ctx, options_.motion_deadline_s);
  rb::ExecuteTrajectoryRequest request;
  *request.mutable_trajectory() = trajectory;
  request.set_start_tolerance_rad(0.01);
  auto reader = robot_->ExecuteTrajectory(&ctx, request);
  rb::ExecuteTrajectoryResponse progress;
  bool done = false, moved = false;
  while (reader->Read(&progress)) {
    moved = true;
    done = done || progress.done();
  }
  const grpc::Status status = reader->Finish();
  // Refused by the robot's own checks before it moved: nothing happened.
  if (!moved && RefusedBeforeMoving(status)) {
    throw MotionRefused("ExecuteTrajectory: " + status.error_message());
  }
  ThrowIfFailed("robot", "ExecuteTrajectory", status);
  if (!done) throw CellError("robot", false, "the trajectory ended without reaching its end");
  return Duration(trajectory);
}

double GrpcCell::HeadAngle() {
  if (!head_angle_rad_) {
    grpc::ClientContext ctx;
    SetDeadline(ctx, 5.0);
    gr::GetStateResponse state;
    ThrowIfFailed("gripper", "GetState", gripper_->GetState(&ctx, {}, &state));
    head_angle_rad_ = state.joint_angle_rad();
  }
  return *head_angle_rad_;
}

bool GrpcCell::SetHead(double angle_rad, std::string* reason) {
  if (head_angle_rad_ && *head_angle_rad_ == angle_rad) return true;
  grpc::ClientContext ctx;
  SetDeadline(ctx, 5.0);
  gr::SetJointModeRequest request;
  request.set_mode(gr::JOINT_MODE_FIXED);
  request.set_angle_rad(angle_rad);
  gr::SetJointModeResponse response;
  const grpc::Status status = gripper_->SetJointMode(&ctx, request, &response);
  if (status.error_code() == grpc::StatusCode::FAILED_PRECONDITION) {
    *reason = "the gripper's head cannot turn to " + std::to_string(angle_rad) +
              " rad: " + status.error_message();
    head_angle_rad_.reset();  // read it again
    return false;
  }
  ThrowIfFailed("gripper", "SetJointMode", status);
  head_angle_rad_ = angle_rad;
  return true;
}

StepOutcome GrpcCell::MoveToNamed(const std::string& name) {
  // A head bent for the last pick is straightened first (the named poses' roadmap is the
  // straight gripper's); where it cannot turn, the motion is planned with it as it is.
  if (HeadAngle() != 0.0) {
    std::string ignored;
    SetHead(0.0, &ignored);
  }
  const rb::GetStateResponse state = RobotState();
  grpc::ClientContext ctx;
  SetDeadline(ctx, options_.plan_deadline_s);
  pl::PlanJointMotionRequest request;
  *request.mutable_start()->mutable_positions_rad() = state.joints().positions_rad();
  request.set_goal_name(name);
  request.set_head_angle_rad(HeadAngle());
  pl::PlanJointMotionResponse motion;
  const grpc::Status status = planner_->PlanJointMotion(&ctx, request, &motion);
  if (status.error_code() == grpc::StatusCode::ABORTED) {
    return {false, PlanFailureMessage(status), 0.0};
  }
  ThrowIfFailed("planner", "PlanJointMotion to " + name, status);
  return {true, "", Execute(motion.trajectory()) + motion.planning_time_s()};
}

ScanView GrpcCell::Scan() { return StartScan().get(); }

std::shared_future<ScanView> GrpcCell::StartScan() {
  const rb::GetStateResponse state = RobotState();
  sc::ScanRequest request;
  auto* view = request.add_views();
  *view->mutable_x_base_tool() = state.x_base_tool();
  *view->mutable_joints()->mutable_positions_rad() = state.joints().positions_rad();
  request.set_frame_id("base");
  request.set_with_normals(true);
  request.set_with_intensities(true);
  request.mutable_decode()->set_min_neighbours(3);
  auto captured = std::make_shared<std::promise<void>>();
  auto finished = std::make_shared<std::promise<ScanView>>();
  std::future<void> capture_over = captured->get_future();
  std::shared_future<ScanView> view_done = finished->get_future().share();
  {
    std::lock_guard<std::mutex> lock(scans_mutex_);
    // Scans already read to their end are let go; the rest are waited for by the destructor.
    scans_.erase(std::remove_if(scans_.begin(), scans_.end(),
                                [](const std::future<void>& f) {
                                  return f.wait_for(std::chrono::seconds(0)) ==
                                         std::future_status::ready;
                                }),
                 scans_.end());
    const Eigen::Isometry3d X_BaseTcp = pc::PoseFromProto(state.x_base_tcp(), "robot X_base_tcp");
    scans_.push_back(std::async(std::launch::async, [this, request, X_BaseTcp, captured, finished] {
      ReadScan(request, X_BaseTcp, captured.get(), finished.get());
    }));
  }
  capture_over.wait();
  // A scan that failed before its capture was over fails here (its error is set first).
  if (view_done.wait_for(std::chrono::seconds(0)) == std::future_status::ready) view_done.get();
  return view_done;
}

void GrpcCell::ReadScan(const sc::ScanRequest& request, const Eigen::Isometry3d& X_BaseTcp,
                        std::promise<void>* captured, std::promise<ScanView>* finished) const {
  bool told = false;
  auto tell = [&] {
    if (!told) captured->set_value();
    told = true;
  };
  try {
    grpc::ClientContext ctx;
    SetDeadline(ctx, options_.scan_deadline_s);
    auto reader = scanner_->Scan(&ctx, request);
    pc::CloudAssembler assembler;
    sc::ScanResponse response;
    sc::ScanSummary summary;
    while (reader->Read(&response)) {
      // The first stage after the capture: the images are taken, the arm may move.
      if (response.has_progress() && response.progress().stage() != sc::SCAN_STAGE_CAPTURE) {
        tell();
      }
      if (response.has_cloud()) assembler.Add(response.cloud());
      if (response.has_summary()) summary = response.summary();
    }
    ThrowIfFailed("scanner", "Scan", reader->Finish());
    ScanView out;
    out.cloud_Base = std::make_shared<geometry::PointCloud>(assembler.Finish());
    if (summary.x_frame_sensor_size() > 0) {
      out.X_BaseCamera = pc::PoseFromProto(summary.x_frame_sensor(0), "X_frame_sensor");
    }
    out.X_BaseTcp = X_BaseTcp;
    out.capture_s = summary.capture_time_s();
    finished->set_value(std::move(out));
  } catch (...) {
    finished->set_exception(std::current_exception());
  }
  tell();
}

GrpcCell::~GrpcCell() {
  std::lock_guard<std::mutex> lock(scans_mutex_);
  for (std::future<void>& scan : scans_) scan.wait();
}

GrpcCell::ContainerBox GrpcCell::InnerBox(const std::string& container) const {
  const world::CellConfig& config = options_.cell.config;
  if (container == "tote") {
    const Eigen::AlignedBox3d& inner = options_.cell.tote_inner_T();
    return {config.X_BaseTote * Eigen::Translation3d(inner.center()), inner.sizes()};
  }
  if (container == "table") {
    // The space over the table's top, as high as an item set down on it stands.
    constexpr double kHeightM = 0.3;
    return {config.X_BaseTable * Eigen::Translation3d(0.0, 0.0, 0.5 * kHeightM),
            Eigen::Vector3d(config.table_size_m.x(), config.table_size_m.y(), kHeightM)};
  }
  const world::BinGeometry& bin = options_.cell.bin(container);
  return {config.X_BaseShelf * Eigen::Translation3d(bin.inner_S.center()), bin.inner_S.sizes()};
}

Detection GrpcCell::Detect(const std::string& container, const std::string& item,
                           const std::vector<ScanView>& views,
                           const std::vector<std::string>& others) {
  if (views.empty()) throw CellError("scanner", false, "no views to detect in");
  dt::DetectParams params;
  // With other items to tell the target from, a few distinct poses of each.
  const int poses = others.empty() ? 1 : options_.poses_per_item;
  auto* target_query = params.add_queries();
  target_query->set_item(item);
  target_query->set_max_results(poses);
  for (const std::string& other : others) {
    auto* query = params.add_queries();
    query->set_item(other);
    query->set_max_results(poses);
  }
  // The region: the bin's or the tote's free inner box.
  const ContainerBox region = InnerBox(container);
  *params.mutable_region()->mutable_x_frame_region() = pc::PoseToProto(region.X_BaseBox);
  *params.mutable_region()->mutable_size_m() = pc::VectorToProto(region.size_m);
  params.mutable_region()->set_wall_margin_m(options_.wall_margin_m);
  if (views.size() > 1) {
    for (const ScanView& v : views) *params.add_x_frame_sensor() = pc::PoseToProto(v.X_BaseCamera);
  }
  std::vector<cm::PointCloudChunk> chunks = pc::CloudToChunks(StackViews(views));
  *chunks.front().mutable_header()->mutable_x_frame_sensor() =
      pc::PoseToProto(views[0].X_BaseCamera);
  dt::DetectResponse response;
  Detection out;
  ThrowIfFailed("detector", "Detect", options_.detect(params, chunks, &response, &out.replica));
  if (response.results_size() != params.queries_size()) {
    throw CellError("detector", false, "expected one result per query");
  }
  auto hypotheses = [](const dt::ItemResult& result, int from) {
    std::vector<PoseHypothesis> out;
    for (int k = from; k < result.detections_size(); ++k) {
      out.push_back({pc::PoseFromProto(result.detections(k).x_frame_item(), "X_frame_item"),
                     result.detections(k).score()});
    }
    return out;
  };
  for (int i = 1; i < response.results_size(); ++i) {
    const dt::ItemResult& other = response.results(i);
    if (other.status().code() != 0 || other.detections_size() == 0) continue;
    out.others.push_back({params.queries(i).item(), hypotheses(other, 0)});
  }
  const dt::ItemResult& result = response.results(0);
  if (result.status().code() != 0) {
    throw CellError("detector", false, item + ": " + result.status().message());
  }
  if (result.detections_size() == 0) {
    out.message = "no pose above the item's threshold (" +
                  std::to_string(result.methods_tried_size()) + " methods tried)";
    return out;
  }
  const dt::Detection& best = result.detections(0);
  out.found = true;
  out.X_BaseItem = pc::PoseFromProto(best.x_frame_item(), "X_frame_item");
  out.score = best.score();
  out.method = dt::Method_Name(best.method());
  out.alternatives = hypotheses(result, 1);
  return out;
}

std::string GrpcCell::UpdateScene(const std::string& container, const std::string& item,
                                  const Eigen::Isometry3d& X_BaseItem,
                                  const std::vector<ScanView>& views) {
  std::string scene_id;
  for (const ScanView& view : views) {
    grpc::ClientContext ctx;
    SetDeadline(ctx, options_.plan_deadline_s);
    pl::UpdateSceneResponse response;
    auto writer = planner_->UpdateScene(&ctx, &response);
    pl::UpdateSceneRequest first;
    auto* params = first.mutable_params();
    params->set_scene_id(scene_id);
    params->set_container(pc::ContainerFromName(container));
    params->set_item(item);
    *params->mutable_x_base_item() = pc::PoseToProto(X_BaseItem);
    writer->Write(first);
    for (const auto& chunk : pc::CloudToChunks(*view.cloud_Base)) {
      pl::UpdateSceneRequest message;
      *message.mutable_cloud() = chunk;
      if (!writer->Write(message)) break;
    }
    writer->WritesDone();
    ThrowIfFailed("planner", "UpdateScene", writer->Finish());
    scene_id = response.scene_id();
  }
  return scene_id;
}

PlannedPick GrpcCell::PlanPick(const std::string& container, const std::string& item,
                               const Eigen::Isometry3d& X_BaseItem,
                               const std::vector<ScanView>& views) {
  const std::string scene_id = UpdateScene(container, item, X_BaseItem, views);
  const rb::GetStateResponse state = RobotState();
  grpc::ClientContext ctx;
  SetDeadline(ctx, options_.plan_deadline_s);
  StoredPick stored;
  auto writer = planner_->PlanPick(&ctx, &stored.response);
  pl::PlanPickRequest request;
  auto* params = request.mutable_params();
  params->set_item(item);
  *params->mutable_x_base_item() = pc::PoseToProto(X_BaseItem);
  params->set_container(pc::ContainerFromName(container));
  *params->mutable_start()->mutable_positions_rad() = state.joints().positions_rad();
  params->set_scene_id(scene_id);
  writer->Write(request);
  writer->WritesDone();
  const grpc::Status status = writer->Finish();
  PlannedPick out;
  if (status.error_code() == grpc::StatusCode::ABORTED) {
    out.message = PlanFailureMessage(status);
    out.others_in_the_way = OthersInTheWay(status);
    return out;
  }
  ThrowIfFailed("planner", "PlanPick", status);
  const Eigen::Isometry3d X_BaseTcp =
      pc::PoseFromProto(stored.response.grasp().x_base_tcp(), "grasp.X_base_tcp");
  stored.X_TcpItem = X_BaseTcp.inverse() * X_BaseItem;
  out.ok = true;
  out.grasp = stored.response.grasp().surface();
  out.handle = next_handle_++;
  out.approach_s = Duration(stored.response.approach());
  out.descend_s = Duration(stored.response.descend());
  out.retreat_s = Duration(stored.response.retreat());
  out.head_angle_rad = stored.response.head_angle_rad();
  out.contact_distance_m = stored.response.contact_distance_m();
  if (stored.response.has_guarded_direction()) {
    out.guarded_direction_Base =
        pc::VectorFromProto(stored.response.guarded_direction(), "guarded_direction");
  }
  for (const cm::JointTrajectory* t :
       {&stored.response.approach(), &stored.response.descend(), &stored.response.retreat()}) {
    AppendThinned(*t, 40, out.path_q);
  }
  picks_[out.handle] = std::move(stored);
  return out;
}

const GrpcCell::StoredPick& GrpcCell::Stored(const PlannedPick& pick) const {
  const auto it = picks_.find(pick.handle);
  if (it == picks_.end()) throw CellError("orchestrator", false, "unknown pick plan");
  return it->second;
}

// A motion the robot stopped (a protective stop: it touched something the plan did not
// expect) is the item's failure, not the task's: the vacuum is let go, the stop reset, and the
// arm backs out of the container along the descent, so that the next target starts clear.
void GrpcCell::ReleaseAndResetStop() {
  // The item first: while it hangs from the cup in contact with the cell, the arm counts as
  // in collision and the stop cannot be reset.
  VacuumOff();
  grpc::ClientContext ctx;
  SetDeadline(ctx, 10.0);
  rb::ResetProtectiveStopResponse reset;
  const grpc::Status status = robot_->ResetProtectiveStop(&ctx, {}, &reset);
  // Not in a protective stop (the motion ended otherwise): nothing to reset.
  if (status.error_code() == grpc::StatusCode::FAILED_PRECONDITION) return;
  ThrowIfFailed("robot", "ResetProtectiveStop", status);
}

StepOutcome GrpcCell::Recover(const StoredPick& stored, const CellError& stopped) {
  ReleaseAndResetStop();
  const cm::JointTrajectory& descend = stored.response.descend();
  double backed_s = 0.0;
  if (descend.points_size() > 0) {
    grpc::ClientContext move_ctx;
    SetDeadline(move_ctx, options_.motion_deadline_s);
    rb::MoveJointsRequest request;
    *request.mutable_target()->mutable_positions_rad() =
        descend.points(descend.points_size() - 1).positions_rad();
    request.mutable_options()->set_speed_fraction(0.1);
    rb::MoveJointsResponse moved;
    ThrowIfFailed("robot", "MoveJoints out", robot_->MoveJoints(&move_ctx, request, &moved));
    backed_s = moved.duration_s() + Execute(Reversed(descend));
  }
  return {false, std::string(stopped.what()) + "; backed out", backed_s};
}

StepOutcome GrpcCell::ExecuteApproach(const PlannedPick& pick) {
  const StoredPick& stored = Stored(pick);
  // The head as the plan bent it, before the arm moves.
  if (std::string reason; !SetHead(stored.response.head_angle_rad(), &reason)) {
    return {false, reason, 0.0};
  }
  const double approach_s = Execute(stored.response.approach());
  try {
    return {true, "", approach_s + Execute(stored.response.descend())};
  } catch (const CellError& e) {
    if (e.retryable()) throw;
    return Recover(stored, e);
  }
}

TouchOutcome GrpcCell::Touch(const PlannedPick& pick) {
  const StoredPick& stored = Stored(pick);
  grpc::ClientContext ctx;
  SetDeadline(ctx, options_.motion_deadline_s);
  rb::GuardedMoveRequest request;
  *request.mutable_direction() = stored.response.guarded_direction();
  request.set_max_distance_m(stored.response.guarded_distance_m());
  request.set_force_threshold_n(options_.guarded_force_n);
  request.set_speed_m_s(options_.guarded_speed_m_s);
  rb::GuardedMoveResponse response;
  const grpc::Status status = robot_->GuardedMove(&ctx, request, &response);
  // Refused before anything moved (the robot's own check of the path): the item's failure.
  if (RefusedBeforeMoving(status)) {
    TouchOutcome refused;
    refused.refused = "the robot refused the guarded move: " + status.error_message();
    return refused;
  }
  ThrowIfFailed("robot", "GuardedMove", status);
  TouchOutcome out;
  out.contact = response.contact();
  out.distance_m = response.distance_travelled_m();
  out.robot_s = out.distance_m / options_.guarded_speed_m_s;
  return out;
}

SealReading GrpcCell::VacuumOn() {
  grpc::ClientContext ctx;
  SetDeadline(ctx, options_.seal_wait_s + 5.0);
  gr::SetVacuumRequest request;
  request.set_on(true);
  request.set_wait_for_seal_s(options_.seal_wait_s);
  gr::SetVacuumResponse response;
  const grpc::Status status = gripper_->SetVacuum(&ctx, request, &response);
  // DEADLINE_EXCEEDED from the gripper itself means "no seal in the wait": read the level.
  if (status.error_code() == grpc::StatusCode::DEADLINE_EXCEEDED) return ReadSeal();
  ThrowIfFailed("gripper", "SetVacuum", status);
  return {response.state().item_attached(), response.state().vacuum_kpa()};
}

SealReading GrpcCell::ReadSeal() {
  grpc::ClientContext ctx;
  SetDeadline(ctx, 5.0);
  gr::GetStateResponse state;
  ThrowIfFailed("gripper", "GetState", gripper_->GetState(&ctx, {}, &state));
  return {state.item_attached(), state.vacuum_kpa()};
}

void GrpcCell::VacuumOff() {
  grpc::ClientContext ctx;
  SetDeadline(ctx, 5.0);
  gr::SetVacuumRequest request;
  request.set_on(false);
  gr::SetVacuumResponse response;
  ThrowIfFailed("gripper", "SetVacuum off", gripper_->SetVacuum(&ctx, request, &response));
}

StepOutcome GrpcCell::ExecuteRetreat(const PlannedPick& pick) {
  const StoredPick& stored = Stored(pick);
  const cm::JointTrajectory& retreat = stored.response.retreat();
  if (retreat.points_size() == 0) return {false, "empty retreat", 0.0};
  // The guarded move stopped where the cup met the item, a little before or after the
  // planned grasp: join the retreat at its start with a short joint move.
  try {
    grpc::ClientContext ctx;
    SetDeadline(ctx, options_.motion_deadline_s);
    rb::MoveJointsRequest request;
    *request.mutable_target()->mutable_positions_rad() = retreat.points(0).positions_rad();
    request.mutable_options()->set_speed_fraction(0.1);
    rb::MoveJointsResponse moved;
    ThrowIfFailed("robot", "MoveJoints to the retreat", robot_->MoveJoints(&ctx, request, &moved));
    return {true, "", moved.duration_s() + Execute(retreat)};
  } catch (const CellError& e) {
    if (e.retryable()) throw;
    return Recover(stored, e);
  }
}

double GrpcCell::VerifyHeld(const std::string& item, const PlannedPick& pick,
                            const ScanView& view) {
  // The item hangs from the cup where the cup was at the capture.
  dt::VerifyParams params;
  params.set_item(item);
  *params.mutable_x_frame_item() = pc::PoseToProto(view.X_BaseTcp * Stored(pick).X_TcpItem);
  *params.mutable_x_frame_sensor() = pc::PoseToProto(view.X_BaseCamera);
  std::vector<cm::PointCloudChunk> chunks = pc::CloudToChunks(*view.cloud_Base);
  dt::VerifyResponse response;
  ThrowIfFailed("detector", "Verify", options_.verify(params, chunks, &response));
  if (static_cast<int>(response.visible_model_points()) < options_.min_visible_points_to_verify) {
    return -1.0;
  }
  return response.score();
}

std::optional<HeldSurface> GrpcCell::MeasureHeld(const std::string& container,
                                                 const std::string& item, const PlannedPick& pick,
                                                 const ScanView& view) {
  const auto size = options_.item_size_m.find(item);
  if (size == options_.item_size_m.end() || !view.cloud_Base || pick.handle < 0) {
    return std::nullopt;
  }
  // The container's opening plane, its normal pointing out: the face of its inner box at a
  // shelf bin's front (the box's +x) or the tote's rim (+z).
  if (container != "tote" && container.rfind("bin_", 0) != 0) return std::nullopt;
  const int out_axis = container == "tote" ? 2 : 0;
  const ContainerBox box = InnerBox(container);
  const Eigen::Vector3d p_BaseOpening =
      box.X_BaseBox * (0.5 * box.size_m[out_axis] * Eigen::Vector3d::Unit(out_axis));
  const Eigen::Vector3d n_BaseOpening = box.X_BaseBox.linear().col(out_axis);
  return MeasureHeldSurface(*view.cloud_Base, view.X_BaseTcp, Stored(pick).X_TcpItem, size->second,
                            p_BaseOpening, n_BaseOpening);
}

StepOutcome GrpcCell::PutBack(const PlannedPick& pick) {
  const StoredPick& stored = Stored(pick);
  // The arm is at the retreat's end (the place was not planned, so it has not moved since).
  const double back_s = Execute(Reversed(stored.response.retreat()));
  VacuumOff();
  return {true, "", back_s + Execute(stored.response.retreat())};
}

StepOutcome GrpcCell::ReturnFromPlace() {
  if (last_place_.points().empty()) {
    throw CellError("orchestrator", false, "no place motion to return along");
  }
  return {true, "", Execute(Reversed(last_place_))};
}

PlaceOutcome GrpcCell::MoveToPlace(const std::string& item, const std::string& container,
                                   const PlannedPick& pick, int placed_before) {
  const rb::GetStateResponse state = RobotState();
  grpc::ClientContext ctx;
  SetDeadline(ctx, options_.plan_deadline_s);
  pl::PlanPlaceRequest request;
  request.set_item(item);
  request.set_container(pc::ContainerFromName(container));
  *request.mutable_start()->mutable_positions_rad() = state.joints().positions_rad();
  if (pick.handle >= 0) *request.mutable_x_tcp_item() = pc::PoseToProto(Stored(pick).X_TcpItem);
  request.set_head_angle_rad(HeadAngle());
  request.set_placed_before(static_cast<std::uint32_t>(std::clamp(placed_before, 0, 1000)));
  pl::PlanPlaceResponse response;
  const grpc::Status status = planner_->PlanPlace(&ctx, request, &response);
  if (status.error_code() == grpc::StatusCode::ABORTED) {
    return {false, PlanFailureMessage(status), 0.0, 0.0};
  }
  // A planner that finds no motion within the deadline has none to offer for this item: the
  // item is put back rather than the task given up (a planner that is down answers
  // UNAVAILABLE, which is retried).
  if (status.error_code() == grpc::StatusCode::DEADLINE_EXCEEDED) {
    return {false,
            "the planner found no motion to " + container + " within " +
                std::to_string(static_cast<int>(options_.plan_deadline_s)) + " s",
            0.0, 0.0};
  }
  ThrowIfFailed("planner", "PlanPlace", status);
  try {
    last_place_ = response.trajectory();
    return {true, "", response.drop_height_m(), Execute(response.trajectory())};
  } catch (const MotionRefused& e) {
    return {false, e.what(), 0.0, 0.0};  // still held where it was: put back or elsewhere
  } catch (const CellError& e) {
    if (e.retryable()) throw;
    // Stopped with the item on the cup: it is let go where the arm stopped.
    ReleaseAndResetStop();
    return {false, e.what(), 0.0, 0.0, true};
  }
}

}  // namespace picking::orchestrator
