// The planner through its server binary on the simulated cell: for every target of
// pick_layout_1..3, three simulated scans of its bin (the simulator's ground-truth depth from
// the planner's scan poses), UpdateScene with the target cut out at its true pose, PlanPick
// from the bin's scan pose. Every returned trajectory is checked against the simulator's
// ground truth (the cell's meshes and every other item's mesh at its true pose) at 1 ms
// and against the joint limits; one pick is executed on the simulated robot up to the
// guarded move, which must touch the target.
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <cmath>
#include <cstring>
#include <fstream>
#include <map>
#include <sstream>

#include "google/rpc/status.pb.h"
#include "libs/apc/task.h"
#include "libs/proto_convert/proto_convert.h"
#include "libs/world/cell_config.h"
#include "libs/world/item_models.h"
#include "libs/world/mesh_utils.h"
#include "picking/planner/v1/planner.grpc.pb.h"
#include "picking/robot/v1/robot.grpc.pb.h"
#include "picking/simulator/v1/simulator.grpc.pb.h"
#include "services/planner/core/collision_world.h"
#include "services/planner/core/grasp_seal.h"
#include "services/planner/core/grasps.h"
#include "services/simulator/core/sim_world.h"
#include "tests/harness/server_process.h"

namespace picking::testing {
namespace {

namespace sim = ::picking::simulator::v1;
namespace pl = ::picking::planner::v1;
namespace rb = ::picking::robot::v1;
namespace common = ::picking::common::v1;
namespace pc = ::picking::proto_convert;
using planner::JointVector;

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

JointVector Joints(const google::protobuf::RepeatedField<double>& v) {
  JointVector q;
  for (int i = 0; i < 6; ++i) q[i] = v.Get(i);
  return q;
}

common::JointPositions ToProto(const JointVector& q) {
  common::JointPositions out;
  for (int i = 0; i < 6; ++i) out.add_positions_rad(q[i]);
  return out;
}

// Position of a trajectory at time t: cubic Hermite between the samples around it.
JointVector At(const common::JointTrajectory& t, double time_s) {
  int i = 0;
  while (i + 2 < t.points_size() && t.points(i + 1).time_from_start_s() < time_s) ++i;
  const auto& a = t.points(i);
  const auto& b = t.points(std::min(i + 1, t.points_size() - 1));
  const double h = b.time_from_start_s() - a.time_from_start_s();
  if (h <= 0.0) return Joints(b.positions_rad());
  const double s = std::clamp((time_s - a.time_from_start_s()) / h, 0.0, 1.0);
  const double h00 = 2 * s * s * s - 3 * s * s + 1, h10 = s * s * s - 2 * s * s + s,
               h01 = -2 * s * s * s + 3 * s * s, h11 = s * s * s - s * s;
  return h00 * Joints(a.positions_rad()) + h10 * h * Joints(a.velocities_rad_s()) +
         h01 * Joints(b.positions_rad()) + h11 * h * Joints(b.velocities_rad_s());
}

class PlannerPickTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    simulator_ = new ServerProcess(ServerBinary("picking-simulator"), {});
    planner_ = new ServerProcess(ServerBinary("picking-planner"), {});
    robot_ = new ServerProcess(
        ServerBinary("picking-robot"),
        {"--backend=sim", "--sim.address=" + simulator_->address(), "--sim.time_scale=20"});
    sim_ = sim::SimulatorService::NewStub(simulator_->Channel()).release();
    plan_ = pl::PlannerService::NewStub(planner_->Channel()).release();
    robot_stub_ = rb::RobotService::NewStub(robot_->Channel()).release();
    kinematics_ = new ur10::Ur10Kinematics(ur10::Ur10Model::Load(PICKING_DATA_DIR "/ur10"));
    const world::CellConfig config =
        world::ReadCellConfig(PICKING_DATA_DIR "/cell/default_cell.yaml");
    cell_ = new world::CellModel(world::LoadCellModel(config));
    const planner::GripperGeometry gripper = planner::GripperGeometry::FromCell(config.gripper);
    robot_geometry_ = new planner::RobotGeometry(*kinematics_, gripper);
    catalogue_ = new apc::Catalogue(apc::Catalogue::FromCsvFile(apc::DefaultCataloguePath()));
    items_ = new world::ItemModelLibrary(*catalogue_);
    X_ToolCamera_ = new Eigen::Isometry3d(Eigen::Translation3d(-0.075, 0.06, 0.04));
    grpc::ClientContext ctx;
    pl::ListNamedPosesResponse named;
    ASSERT_TRUE(plan_->ListNamedPoses(&ctx, {}, &named).ok());
    named_ = new std::map<std::string, JointVector>();
    for (const auto& p : named.poses()) (*named_)[p.name()] = Joints(p.joints().positions_rad());
  }
  static void TearDownTestSuite() {
    EXPECT_EQ(robot_->Stop(), 0);
    EXPECT_EQ(planner_->Stop(), 0);
    EXPECT_EQ(simulator_->Stop(), 0);
  }

  static sim::GetGroundTruthResponse LoadLayout(int layout) {
    grpc::ClientContext ctx;
    sim::LoadLayoutRequest request;
    request.set_task_json(ReadText(std::string(PICKING_DATA_DIR) + "/apc2016/tasks/pick_layout_" +
                                   std::to_string(layout) + ".json"));
    request.set_seed(7);
    sim::LoadLayoutResponse loaded;
    const grpc::Status status = sim_->LoadLayout(&ctx, request, &loaded);
    EXPECT_TRUE(status.ok()) << status.error_message();
    grpc::ClientContext truth_ctx;
    sim::GetGroundTruthResponse truth;
    EXPECT_TRUE(sim_->GetGroundTruth(&truth_ctx, {}, &truth).ok());
    return truth;
  }

  // The simulator's depth from the camera of scan pose `name`, as points in base.
  static std::vector<Eigen::Vector3f> ScanView(const std::string& name) {
    const Eigen::Isometry3d X_BaseCamera =
        kinematics_->ForwardKinematics(named_->at(name)) * *X_ToolCamera_;
    grpc::ClientContext ctx;
    sim::RenderDepthRequest request;
    auto* camera = request.mutable_camera();
    const int width = 480, height = 384;
    camera->set_width(width), camera->set_height(height), camera->set_fx(460.0),
        camera->set_fy(460.0), camera->set_cx(240.0), camera->set_cy(192.0);
    *request.mutable_x_base_camera() = pc::PoseToProto(X_BaseCamera);
    auto reader = sim_->RenderDepth(&ctx, request);
    sim::RenderDepthResponse response;
    std::string bytes;
    while (reader->Read(&response)) bytes += response.chunk().data();
    EXPECT_TRUE(reader->Finish().ok());
    std::vector<float> depth(bytes.size() / 4);
    std::memcpy(depth.data(), bytes.data(), depth.size() * 4);
    std::vector<Eigen::Vector3f> points;
    for (int v = 0; v < height; ++v) {
      for (int u = 0; u < width; ++u) {
        const float d = depth[static_cast<std::size_t>(v) * width + u];
        if (!std::isfinite(d) || d <= 0.f) continue;
        const Eigen::Vector3d ray((u + 0.5 - 240.0) / 460.0, (v + 0.5 - 192.0) / 460.0, 1.0);
        points.push_back((X_BaseCamera * (ray * d)).cast<float>());
      }
    }
    return points;
  }

  // UpdateScene with the bin's three views, the target cut out at its true pose.
  static std::string BuildScene(const std::string& bin, const std::string& item,
                                const Eigen::Isometry3d& X_BaseItem) {
    std::string id;
    for (int k = 0; k < 3; ++k) {
      geometry::PointCloud cloud;
      cloud.points = ScanView("scan/" + bin + "/" + std::to_string(k));
      grpc::ClientContext ctx;
      pl::UpdateSceneResponse response;
      auto writer = plan_->UpdateScene(&ctx, &response);
      pl::UpdateSceneRequest first;
      auto* params = first.mutable_params();
      params->set_scene_id(id);
      params->set_container(pc::ContainerFromName(bin));
      params->set_item(item);
      *params->mutable_x_base_item() = pc::PoseToProto(X_BaseItem);
      writer->Write(first);
      for (const auto& c : pc::CloudToChunks(cloud)) {
        pl::UpdateSceneRequest message;
        *message.mutable_cloud() = c;
        writer->Write(message);
      }
      writer->WritesDone();
      const grpc::Status status = writer->Finish();
      EXPECT_TRUE(status.ok()) << status.error_message();
      EXPECT_GT(response.occupied_voxels(), 0u);
      id = response.scene_id();
    }
    return id;
  }

  // An exact checker over the ground truth: the cell and every item but the target.
  static std::unique_ptr<planner::StaticCell> TruthCell(const sim::GetGroundTruthResponse& truth,
                                                        int target_index) {
    world::CellModel cell = *cell_;
    std::vector<world::TriangleMesh> parts = {
        world::Transformed(cell.table, cell.config.X_BaseTable)};
    for (int i = 0; i < truth.items_size(); ++i) {
      if (i == target_index) continue;
      const auto model = items_->Get(truth.items(i).item().name());
      parts.push_back(world::Transformed(
          model->mesh, pc::PoseFromProto(truth.items(i).x_base_item(), "X_base_item")));
    }
    cell.table = world::Merge(parts);
    cell.config.X_BaseTable = Eigen::Isometry3d::Identity();
    planner::StaticCellOptions options;
    options.grid_resolution_m = 0.05;  // only the exact (FCL) check is used
    return std::make_unique<planner::StaticCell>(cell, options);
  }

  // Stages of PlansEveryTargetOfTheThreeLayoutsOrSaysWhyNot, defined below it.
  // The target's index among the truth's items, -1 if it is not there.
  static int TargetIndex(const sim::GetGroundTruthResponse& truth,
                         const apc::WorkOrderEntry& entry);
  // PlanPick for the target at X_BaseItem in `scene`, from its bin's first scan pose.
  static grpc::Status RequestPick(const apc::WorkOrderEntry& entry,
                                  const Eigen::Isometry3d& X_BaseItem, const std::string& scene,
                                  pl::PlanPickResponse* response);
  // A refusal is ABORTED with a typed PlanFailure: a stage and a kind the contract knows (not
  // UNSPECIFIED) and a message; *kind receives its kind.
  static void ExpectTypedRefusal(const grpc::Status& status, const std::string& what,
                                 pl::PlanFailureKind* kind);
  // Every trajectory of a plan is free against the simulator's true geometry and within the
  // limits; the retreat, from a centimetre up, also with the item on the cup.
  static void CheckPlannedPick(const sim::GetGroundTruthResponse& truth, int index,
                               const apc::WorkOrderEntry& entry,
                               const Eigen::Isometry3d& X_BaseItem,
                               const pl::PlanPickResponse& response, const std::string& what);

  static ServerProcess* simulator_;
  static ServerProcess* planner_;
  static ServerProcess* robot_;
  static sim::SimulatorService::Stub* sim_;
  static pl::PlannerService::Stub* plan_;
  static rb::RobotService::Stub* robot_stub_;
  static ur10::Ur10Kinematics* kinematics_;
  static world::CellModel* cell_;
  static planner::RobotGeometry* robot_geometry_;
  static apc::Catalogue* catalogue_;
  static world::ItemModelLibrary* items_;
  static Eigen::Isometry3d* X_ToolCamera_;
  static std::map<std::string, JointVector>* named_;
};
ServerProcess* PlannerPickTest::simulator_ = nullptr;
ServerProcess* PlannerPickTest::planner_ = nullptr;
ServerProcess* PlannerPickTest::robot_ = nullptr;
sim::SimulatorService::Stub* PlannerPickTest::sim_ = nullptr;
pl::PlannerService::Stub* PlannerPickTest::plan_ = nullptr;
rb::RobotService::Stub* PlannerPickTest::robot_stub_ = nullptr;
ur10::Ur10Kinematics* PlannerPickTest::kinematics_ = nullptr;
world::CellModel* PlannerPickTest::cell_ = nullptr;
planner::RobotGeometry* PlannerPickTest::robot_geometry_ = nullptr;
apc::Catalogue* PlannerPickTest::catalogue_ = nullptr;
world::ItemModelLibrary* PlannerPickTest::items_ = nullptr;
Eigen::Isometry3d* PlannerPickTest::X_ToolCamera_ = nullptr;
std::map<std::string, JointVector>* PlannerPickTest::named_ = nullptr;

// Checks a trajectory's samples against the joint limits and its motion, sampled every
// `period_s`, against the ground truth.
void CheckTrajectory(const common::JointTrajectory& t, const ur10::Ur10Model& model,
                     const planner::ExactChecker& truth, const planner::CarriedItem* carried,
                     double period_s, const std::string& what) {
  ASSERT_GE(t.points_size(), 2) << what;
  for (const auto& p : t.points()) {
    const JointVector q = Joints(p.positions_rad()), qd = Joints(p.velocities_rad_s()),
                      qdd = Joints(p.accelerations_rad_s2());
    ASSERT_TRUE(model.WithinPositionLimits(q)) << what;
    for (int j = 0; j < 6; ++j) {
      ASSERT_LE(std::abs(qd[j]), model.max_velocity_rad_s()[j] * (1 + 1e-6)) << what;
      ASSERT_LE(std::abs(qdd[j]), model.max_acceleration_rad_s2()[j] * (1 + 1e-6)) << what;
    }
  }
  const double duration = t.points(t.points_size() - 1).time_from_start_s();
  for (double time = 0.0; time <= duration + 1e-9; time += period_s) {
    const planner::CollisionReport r = truth.Check(At(t, time), carried);
    ASSERT_FALSE(r.in_collision) << what << " at t = " << time << " s: " << r.ToString();
  }
}

// The planner tilts the cup off a surface's normal only as far as the cell's cup seals: its
// constant is the simulator's seal tolerance, and its default tilt stays within it.
TEST(PlannerSealTolerance, IsTheSimulatorsAndBoundsTheGraspTilt) {
  const simulator::SimOptions sim;
  EXPECT_DOUBLE_EQ(planner::kSealAngleToleranceRad, sim.seal_angle_tolerance_rad);
  EXPECT_LE(planner::GraspOptions{}.max_tilt_rad, sim.seal_angle_tolerance_rad);
}

// The planner refuses a grasp whose cup cannot seal on the item's model by the simulator's
// own seal rule and cup: the two must not drift apart.
TEST(PlannerSealRule, IsTheSimulators) {
  const world::SealOptions sim = simulator::SimWorld::SealOptionsOf(simulator::SimOptions{});
  const world::SealOptions planned = planner::ModelSealOptions{}.seal;
  EXPECT_DOUBLE_EQ(planned.cup_radius_m, sim.cup_radius_m);
  EXPECT_EQ(planned.rim_samples, sim.rim_samples);
  EXPECT_DOUBLE_EQ(planned.flatness_tolerance_m, sim.flatness_tolerance_m);
  EXPECT_DOUBLE_EQ(planned.angle_tolerance_rad, sim.angle_tolerance_rad);
  EXPECT_DOUBLE_EQ(planned.max_gap_m, sim.max_gap_m);
  EXPECT_DOUBLE_EQ(planned.lookback_m, sim.lookback_m);
  // The cup presses on by the force threshold over its stiffness.
  const simulator::SimOptions options;
  EXPECT_NEAR(planner::ModelSealOptions{}.press_m,
              options.contact_force_threshold_n / options.contact_stiffness_n_per_m, 1e-9);
}

int PlannerPickTest::TargetIndex(const sim::GetGroundTruthResponse& truth,
                                 const apc::WorkOrderEntry& entry) {
  for (int i = 0; i < truth.items_size(); ++i) {
    if (truth.items(i).item().name() == entry.item &&
        pc::ContainerName(truth.items(i).container()) == entry.bin) {
      return i;
    }
  }
  return -1;
}

grpc::Status PlannerPickTest::RequestPick(const apc::WorkOrderEntry& entry,
                                          const Eigen::Isometry3d& X_BaseItem,
                                          const std::string& scene,
                                          pl::PlanPickResponse* response) {
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(20));
  auto writer = plan_->PlanPick(&ctx, response);
  pl::PlanPickRequest request;
  auto* params = request.mutable_params();
  params->set_item(entry.item);
  *params->mutable_x_base_item() = pc::PoseToProto(X_BaseItem);
  params->set_container(pc::ContainerFromName(entry.bin));
  *params->mutable_start() = ToProto(named_->at("scan/" + entry.bin + "/0"));
  params->set_scene_id(scene);
  writer->Write(request);
  writer->WritesDone();
  return writer->Finish();
}

void PlannerPickTest::ExpectTypedRefusal(const grpc::Status& status, const std::string& what,
                                         pl::PlanFailureKind* kind) {
  ASSERT_EQ(status.error_code(), grpc::StatusCode::ABORTED)
      << what << ": " << status.error_message();
  google::rpc::Status details;
  ASSERT_TRUE(details.ParseFromString(status.error_details())) << what;
  ASSERT_GT(details.details_size(), 0) << what;
  pl::PlanFailure failure;
  ASSERT_TRUE(details.details(0).UnpackTo(&failure)) << what;
  EXPECT_TRUE(pl::PlanFailureStage_IsValid(failure.stage()) &&
              failure.stage() != pl::PLAN_FAILURE_STAGE_UNSPECIFIED)
      << what << ": stage " << failure.stage();
  EXPECT_TRUE(pl::PlanFailureKind_IsValid(failure.kind()) &&
              failure.kind() != pl::PLAN_FAILURE_KIND_UNSPECIFIED)
      << what << ": kind " << failure.kind();
  EXPECT_FALSE(failure.message().empty());
  *kind = failure.kind();
  std::printf("%s: no plan: %s\n", what.c_str(), failure.message().c_str());
}

void PlannerPickTest::CheckPlannedPick(const sim::GetGroundTruthResponse& truth, int index,
                                       const apc::WorkOrderEntry& entry,
                                       const Eigen::Isometry3d& X_BaseItem,
                                       const pl::PlanPickResponse& response,
                                       const std::string& what) {
  const ur10::Ur10Model& model = kinematics_->model();
  const auto truth_cell = TruthCell(truth, index);
  // The arm with the gripper's head as the plan bends it.
  const planner::RobotGeometry robot = robot_geometry_->WithGripper(
      robot_geometry_->gripper().AtHeadAngle(response.head_angle_rad()));
  const planner::ExactChecker exact(robot, *truth_cell, nullptr);
  const Eigen::Isometry3d X_BaseTcp = pc::PoseFromProto(response.grasp().x_base_tcp(), "grasp");
  const planner::CarriedItem carried = planner::MakeCarriedItem(
      entry.item, items_->Get(entry.item)->box_I, X_BaseTcp.inverse() * X_BaseItem);
  CheckTrajectory(response.approach(), model, exact, nullptr, 0.008, what + " approach");
  CheckTrajectory(response.descend(), model, exact, nullptr, 0.001, what + " descend");
  // The retreat's first samples lift the item off its support; from a centimetre up it
  // must be free with the item too.
  CheckTrajectory(response.retreat(), model, exact, nullptr, 0.001, what + " retreat");
  const auto& retreat = response.retreat();
  const double end = retreat.points(retreat.points_size() - 1).time_from_start_s();
  for (double time = 0.0; time <= end; time += 0.001) {
    const JointVector q = At(retreat, time);
    const double lifted =
        (kinematics_->ForwardKinematics(q) * robot.gripper().X_ToolTcp).translation().z() -
        X_BaseTcp.translation().z();
    if (lifted < 0.01) continue;
    const planner::CollisionReport r = exact.Check(q, &carried);
    ASSERT_FALSE(r.in_collision) << what << " retreat with the item at t = " << time
                                 << " s: " << r.ToString();
  }
}

TEST_F(PlannerPickTest, PlansEveryTargetOfTheThreeLayoutsOrSaysWhyNot) {
  int targets = 0, planned = 0, bent = 0;
  std::map<int, int> planned_in_layout;
  std::map<pl::PlanFailureKind, int> refusals_by_kind;
  for (int layout = 1; layout <= 3; ++layout) {
    const sim::GetGroundTruthResponse truth = LoadLayout(layout);
    const apc::Task task =
        apc::ReadTaskFile(std::string(PICKING_DATA_DIR) + "/apc2016/tasks/pick_layout_" +
                              std::to_string(layout) + ".json",
                          *catalogue_);
    for (const apc::WorkOrderEntry& entry : task.work_order) {
      const int index = TargetIndex(truth, entry);
      ASSERT_GE(index, 0) << entry.item << " in " << entry.bin;
      ++targets;
      const Eigen::Isometry3d X_BaseItem =
          pc::PoseFromProto(truth.items(index).x_base_item(), "X_base_item");
      const std::string scene = BuildScene(entry.bin, entry.item, X_BaseItem);
      pl::PlanPickResponse response;
      const grpc::Status status = RequestPick(entry, X_BaseItem, scene, &response);
      const std::string what =
          "layout " + std::to_string(layout) + " " + entry.bin + " " + entry.item;
      if (!status.ok()) {
        pl::PlanFailureKind kind = pl::PLAN_FAILURE_KIND_UNSPECIFIED;
        ASSERT_NO_FATAL_FAILURE(ExpectTypedRefusal(status, what, &kind));
        ++refusals_by_kind[kind];
        continue;
      }
      ++planned;
      ++planned_in_layout[layout];
      std::printf("%s: planned in %.1f ms (%u nodes), grasp '%s'\n", what.c_str(),
                  1e3 * response.planning_time_s(), response.nodes_expanded(),
                  response.grasp().surface().c_str());
      if (response.head_angle_rad() != 0.0) ++bent;
      ASSERT_NO_FATAL_FAILURE(CheckPlannedPick(truth, index, entry, X_BaseItem, response, what));
    }
  }
  std::printf(
      "planned %d of %d targets (layout 1: %d, 2: %d, 3 held out: %d), %d with the head bent\n",
      planned, targets, planned_in_layout[1], planned_in_layout[2], planned_in_layout[3], bent);
  for (const auto& [kind, n] : refusals_by_kind)
    std::printf("  refused, %s: %d\n", pl::PlanFailureKind_Name(kind).c_str(), n);
  RecordProperty("targets", targets);
  RecordProperty("planned", planned);
  // Many of the others lie flat in their bins: their top faces lie too deep for the bent
  // head's 26 cm of tube (the wrist meets the bin's ceiling), or a neighbour stands too near
  // ("wedged in"); benchmarks/RESULTS.md lists the reasons, and every target without a plan
  // says why above. Items the cup cannot seal on (a ball, a toothbrush narrower than the lip)
  // are refused as such. Layouts 1 and 2 were used while developing the planner, layout 3 was
  // held out.
  EXPECT_EQ(targets, 36);
  EXPECT_GE(planned, 13);
  EXPECT_GE(planned_in_layout[1], 4);
  EXPECT_GE(planned_in_layout[2], 5);
  EXPECT_GE(planned_in_layout[3], 3);
  EXPECT_GE(bent, 1);
  // Hopeless grasps are refused before any search, with the geometric reason.
  EXPECT_GT(refusals_by_kind[pl::PLAN_FAILURE_KIND_NO_GRASP] +
                refusals_by_kind[pl::PLAN_FAILURE_KIND_TUBE_BLOCKED],
            0);
  EXPECT_GT(refusals_by_kind[pl::PLAN_FAILURE_KIND_NO_SEAL], 0);  // the baseball at least
}

TEST_F(PlannerPickTest, ThePickExecutesOnTheSimRobotAndTheGuardedMoveTouchesTheItem) {
  const sim::GetGroundTruthResponse truth = LoadLayout(1);
  // The first item of the layout, bin by bin, that the planner can pick.
  int index = -1;
  std::string bin, item, scene;
  Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();
  pl::PlanPickResponse pick;
  for (int i = 0; i < truth.items_size() && index < 0; ++i) {
    const std::string container = pc::ContainerName(truth.items(i).container());
    if (container == "tote") continue;
    const Eigen::Isometry3d X = pc::PoseFromProto(truth.items(i).x_base_item(), "X_base_item");
    const std::string id = BuildScene(container, truth.items(i).item().name(), X);
    grpc::ClientContext pick_ctx;
    auto writer = plan_->PlanPick(&pick_ctx, &pick);
    pl::PlanPickRequest request;
    request.mutable_params()->set_item(truth.items(i).item().name());
    *request.mutable_params()->mutable_x_base_item() = pc::PoseToProto(X);
    request.mutable_params()->set_container(truth.items(i).container());
    *request.mutable_params()->mutable_start() = ToProto(named_->at("scan/" + container + "/0"));
    request.mutable_params()->set_scene_id(id);
    writer->Write(request);
    writer->WritesDone();
    if (writer->Finish().ok()) {
      index = i, bin = container, item = truth.items(i).item().name(), X_BaseItem = X, scene = id;
    }
  }
  ASSERT_GE(index, 0) << "no item of pick_layout_1 could be planned";
  auto execute = [&](const common::JointTrajectory& t) {
    grpc::ClientContext ctx;
    rb::ExecuteTrajectoryRequest request;
    *request.mutable_trajectory() = t;
    request.set_start_tolerance_rad(0.01);
    auto reader = robot_stub_->ExecuteTrajectory(&ctx, request);
    rb::ExecuteTrajectoryResponse progress;
    bool done = false;
    while (reader->Read(&progress)) done = done || progress.done();
    const grpc::Status status = reader->Finish();
    ASSERT_TRUE(status.ok()) << status.error_message();
    EXPECT_TRUE(done);
  };
  // Home to the scan pose.
  grpc::ClientContext state_ctx;
  rb::GetStateResponse state;
  ASSERT_TRUE(robot_stub_->GetState(&state_ctx, {}, &state).ok());
  grpc::ClientContext ctx;
  pl::PlanJointMotionRequest motion;
  *motion.mutable_start() = ToProto(Joints(state.joints().positions_rad()));
  motion.set_goal_name("scan/" + bin + "/0");
  pl::PlanJointMotionResponse to_scan;
  {
    // The head cannot turn past its servo's range.
    grpc::ClientContext bent_ctx;
    pl::PlanJointMotionRequest bent = motion;
    bent.set_head_angle_rad(2.0);
    const grpc::Status refused = plan_->PlanJointMotion(&bent_ctx, bent, &to_scan);
    EXPECT_EQ(refused.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << refused.error_message();
    EXPECT_NE(refused.error_message().find("servo"), std::string::npos) << refused.error_message();
  }
  const grpc::Status planned = plan_->PlanJointMotion(&ctx, motion, &to_scan);
  ASSERT_TRUE(planned.ok()) << planned.error_message();
  execute(to_scan.trajectory());

  // Plan again from the scan pose the robot now holds (the scene is still kept).
  grpc::ClientContext pick_ctx;
  auto writer = plan_->PlanPick(&pick_ctx, &pick);
  pl::PlanPickRequest request;
  request.mutable_params()->set_item(item);
  *request.mutable_params()->mutable_x_base_item() = pc::PoseToProto(X_BaseItem);
  request.mutable_params()->set_container(pc::ContainerFromName(bin));
  *request.mutable_params()->mutable_start() = ToProto(named_->at("scan/" + bin + "/0"));
  request.mutable_params()->set_scene_id(scene);
  writer->Write(request);
  writer->WritesDone();
  const grpc::Status status = writer->Finish();
  ASSERT_TRUE(status.ok()) << item << " in " << bin << ": " << status.error_message();
  execute(pick.approach());
  execute(pick.descend());
  grpc::ClientContext guarded_ctx;
  rb::GuardedMoveRequest guarded;
  *guarded.mutable_direction() = pick.guarded_direction();
  guarded.set_max_distance_m(pick.guarded_distance_m());
  guarded.set_force_threshold_n(10.0);
  rb::GuardedMoveResponse touched;
  const grpc::Status moved = robot_stub_->GuardedMove(&guarded_ctx, guarded, &touched);
  ASSERT_TRUE(moved.ok()) << moved.error_message();
  EXPECT_TRUE(touched.contact()) << "the guarded move ended after "
                                 << touched.distance_travelled_m() << " m without contact";
  // What the cup touches is the target: probe from 3 cm back along the guarded direction.
  Eigen::Isometry3d X_BaseTool = pc::PoseFromProto(touched.final_state().x_base_tool(), "tool");
  X_BaseTool.translation() -= 0.03 * pc::VectorFromProto(pick.guarded_direction(), "direction");
  grpc::ClientContext probe_ctx;
  sim::ProbeContactRequest probe;
  *probe.mutable_x_base_tool() = pc::PoseToProto(X_BaseTool);
  probe.mutable_direction_tcp()->set_z(1.0);
  probe.set_max_distance_m(0.06);
  sim::ProbeContactResponse contact;
  ASSERT_TRUE(sim_->ProbeContact(&probe_ctx, probe, &contact).ok());
  EXPECT_TRUE(contact.contact());
  EXPECT_EQ(contact.item().name(), item);
}

}  // namespace
}  // namespace picking::testing
