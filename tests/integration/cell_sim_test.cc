// The simulated cell end to end: picking-simulator, picking-robot (sim backend) and
// picking-gripper (sim backend) as real binaries. The robot picks an item out of a shelf bin
// with the suction gripper: approach through the bin's opening with the cup's axis pointing
// into the bin, a guarded move onto the item's front face, vacuum on, lift and retract.
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "libs/ur10/kinematics.h"
#include "libs/ur10/ur10_model.h"
#include "libs/world/cell_config.h"
#include "picking/gripper/v1/gripper.grpc.pb.h"
#include "picking/robot/v1/robot.grpc.pb.h"
#include "picking/simulator/v1/simulator.grpc.pb.h"
#include "tests/harness/server_process.h"

namespace picking::testing {
namespace {

namespace sim = ::picking::simulator::v1;
namespace robot = ::picking::robot::v1;
namespace gripper = ::picking::gripper::v1;
namespace common = ::picking::common::v1;

constexpr std::uint64_t kSeed = 7;
constexpr double kForceThresholdN = 10.0;
constexpr double kLiftM = 0.01;
constexpr double kRetractM = 0.1;

Eigen::Isometry3d FromProto(const common::Pose& p) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(p.position().x(), p.position().y(), p.position().z());
  X.linear() = Eigen::Quaterniond(p.orientation().w(), p.orientation().x(), p.orientation().y(),
                                  p.orientation().z())
                   .normalized()
                   .toRotationMatrix();
  return X;
}

common::Pose ToProto(const Eigen::Isometry3d& X) {
  common::Pose p;
  p.mutable_position()->set_x(X.translation().x());
  p.mutable_position()->set_y(X.translation().y());
  p.mutable_position()->set_z(X.translation().z());
  const Eigen::Quaterniond q(X.linear());
  p.mutable_orientation()->set_w(q.w());
  p.mutable_orientation()->set_x(q.x());
  p.mutable_orientation()->set_y(q.y());
  p.mutable_orientation()->set_z(q.z());
  return p;
}

common::JointPositions JointsToProto(const ur10::JointVector& q) {
  common::JointPositions out;
  for (int i = 0; i < 6; ++i) out.add_positions_rad(q[i]);
  return out;
}

ur10::JointVector JointsFromProto(const common::JointPositions& j) {
  ur10::JointVector q = ur10::JointVector::Zero();
  for (int i = 0; i < std::min(6, j.positions_rad_size()); ++i) q[i] = j.positions_rad(i);
  return q;
}

// The cup (TCP) at p_Base with its axis along `axis_Base`; the TCP's x axis as close to
// `x_hint` as the axis allows.
Eigen::Isometry3d TcpPose(const Eigen::Vector3d& p_Base, const Eigen::Vector3d& axis_Base,
                          const Eigen::Vector3d& x_hint) {
  const Eigen::Vector3d z = axis_Base.normalized();
  const Eigen::Vector3d x = (x_hint - x_hint.dot(z) * z).normalized();
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear().col(0) = x;
  X.linear().col(1) = z.cross(x);
  X.linear().col(2) = z;
  X.translation() = p_Base;
  return X;
}

// The flange in the cup's frame: the inverse of the tool centre point of the bundled cell
// description, which every server loads.
Eigen::Isometry3d X_TcpTool() {
  static const Eigen::Isometry3d X =
      world::ReadCellConfig(world::DefaultCellConfigPath()).gripper.X_ToolTcp.inverse();
  return X;
}

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

class CellSimTest : public ::testing::Test {
 protected:
  CellSimTest()
      : kinematics_(ur10::Ur10Model::Load(std::string(PICKING_DATA_DIR) + "/ur10")),
        simulator_(ServerBinary("picking-simulator"), {}),
        robot_(ServerBinary("picking-robot"),
               {"--backend=sim", "--sim.address=" + simulator_.address(), "--sim.time_scale=5"}),
        gripper_(ServerBinary("picking-gripper"),
                 {"--backend=sim", "--sim.address=" + simulator_.address()}),
        sim_(sim::SimulatorService::NewStub(simulator_.Channel())),
        robot_stub_(robot::RobotService::NewStub(robot_.Channel())),
        gripper_stub_(gripper::GripperService::NewStub(gripper_.Channel())) {}

  ~CellSimTest() override {
    EXPECT_EQ(gripper_.Stop(), 0);
    EXPECT_EQ(robot_.Stop(), 0);
    EXPECT_EQ(simulator_.Stop(), 0);
  }

  sim::GetGroundTruthResponse Truth() {
    grpc::ClientContext ctx;
    sim::GetGroundTruthResponse truth;
    const grpc::Status s = sim_->GetGroundTruth(&ctx, sim::GetGroundTruthRequest(), &truth);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return truth;
  }

  // Probe of the simulator from the flange pose of a cup at X_BaseTcp, along the cup's axis.
  sim::ProbeContactResponse Probe(const Eigen::Isometry3d& X_BaseTcp, double max_distance_m) {
    grpc::ClientContext ctx;
    sim::ProbeContactRequest req;
    *req.mutable_x_base_tool() = ToProto(X_BaseTcp * X_TcpTool());
    req.mutable_direction_tcp()->set_z(1.0);
    req.set_max_distance_m(max_distance_m);
    sim::ProbeContactResponse out;
    const grpc::Status s = sim_->ProbeContact(&ctx, req, &out);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return out;
  }

  grpc::Status MoveJoints(const ur10::JointVector& q) {
    grpc::ClientContext ctx;
    robot::MoveJointsRequest req;
    *req.mutable_target() = JointsToProto(q);
    robot::MoveJointsResponse out;
    return robot_stub_->MoveJoints(&ctx, req, &out);
  }

  grpc::Status MoveLinear(const Eigen::Isometry3d& X_BaseTcp) {
    grpc::ClientContext ctx;
    robot::MoveLinearRequest req;
    *req.mutable_x_base_tcp_target() = ToProto(X_BaseTcp);
    req.mutable_options()->set_speed_fraction(0.5);
    robot::MoveLinearResponse out;
    return robot_stub_->MoveLinear(&ctx, req, &out);
  }

  robot::GetStateResponse RobotState() {
    grpc::ClientContext ctx;
    robot::GetStateResponse state;
    const grpc::Status s = robot_stub_->GetState(&ctx, robot::GetStateRequest(), &state);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return state;
  }

  ur10::Ur10Kinematics kinematics_;
  ServerProcess simulator_;
  ServerProcess robot_;
  ServerProcess gripper_;
  std::unique_ptr<sim::SimulatorService::Stub> sim_;
  std::unique_ptr<robot::RobotService::Stub> robot_stub_;
  std::unique_ptr<gripper::GripperService::Stub> gripper_stub_;
};

// An item the cup can reach through its bin's opening.
struct Target {
  sim::ItemState item;
  Eigen::Isometry3d X_BaseTcpStart;  // in the opening plane's front, aimed at the item
  double face_distance_m = 0.0;      // from X_BaseTcpStart to the item's front face
  double opening_x_m = 0.0;
  ur10::JointVector q_before;  // joints with the cup kRetractM in front of X_BaseTcpStart
};

TEST_F(CellSimTest, PicksAnItemOutOfAShelfBinWithTheSuctionGripper) {
  {
    grpc::ClientContext ctx;
    sim::LoadLayoutRequest req;
    req.set_task_json(
        ReadText(std::string(PICKING_DATA_DIR) + "/apc2016/tasks/pick_layout_1.json"));
    req.set_seed(kSeed);
    sim::LoadLayoutResponse out;
    const grpc::Status s = sim_->LoadLayout(&ctx, req, &out);
    ASSERT_TRUE(s.ok()) << s.error_message();
  }
  sim::GetCellResponse cell;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(sim_->GetCell(&ctx, sim::GetCellRequest(), &cell).ok());
  }
  // The robot puts the simulated arm at its initial joints on first use.
  const robot::GetStateResponse state = RobotState();
  ASSERT_EQ(state.joints().positions_rad_size(), 6);
  ur10::JointVector q_start;
  for (int i = 0; i < 6; ++i) q_start[i] = state.joints().positions_rad(i);
  ASSERT_EQ(Truth().arm_joints().positions_rad_size(), 6);

  // Choose the target: an item whose front face the cup meets flat and square through the
  // opening, nearest to the opening first; the cup's tube must clear the bin's floor, ceiling
  // and walls, and the item must have room to be lifted.
  const sim::GetGroundTruthResponse truth = Truth();
  const Eigen::Vector3d kInto(1.0, 0.0, 0.0);  // the bins open toward -x of base
  const Eigen::Vector3d kDown(0.0, 0.0, -1.0);
  constexpr double kClearanceM = 0.035;  // tube radius 0.02 m and a margin
  std::vector<Target> candidates;
  for (const auto& item : truth.items()) {
    const int b = item.container() - common::CONTAINER_BIN_A;
    if (b < 0 || b >= cell.bins_size()) continue;
    const auto& bin = cell.bins(b);
    const Eigen::Vector3d c = FromProto(bin.x_base_bin()).translation();
    const Eigen::Vector3d size(bin.size_m().x(), bin.size_m().y(), bin.size_m().z());
    const Eigen::Vector3d p = FromProto(item.x_base_item()).translation();
    const double floor = c.z() - 0.5 * size.z(), ceiling = c.z() + 0.5 * size.z();
    if (p.z() - floor < kClearanceM || ceiling - p.z() < kClearanceM + kLiftM) continue;
    if (std::abs(p.y() - c.y()) > 0.5 * size.y() - kClearanceM) continue;
    Target t;
    t.item = item;
    t.opening_x_m = c.x() - 0.5 * size.x();
    t.X_BaseTcpStart = TcpPose(Eigen::Vector3d(t.opening_x_m - 0.03, p.y(), p.z()), kInto, kDown);
    const auto hit = Probe(t.X_BaseTcpStart, 0.5);
    if (!hit.contact() || hit.item().name() != item.item().name() ||
        hit.item().instance() != item.item().instance() || hit.distance_m() > 0.25) {
      continue;
    }
    // Flat and square: the cup moved by +-1 cm meets the same item at the same depth.
    bool flat = true;
    for (const Eigen::Vector3d& d : {Eigen::Vector3d(0, 0.01, 0), Eigen::Vector3d(0, -0.01, 0),
                                     Eigen::Vector3d(0, 0, 0.01), Eigen::Vector3d(0, 0, -0.01)}) {
      Eigen::Isometry3d X = t.X_BaseTcpStart;
      X.translation() += d;
      const auto h = Probe(X, 0.5);
      flat = flat && h.contact() &&
             h.item().SerializeAsString() == item.item().SerializeAsString() &&
             std::abs(h.distance_m() - hit.distance_m()) < 0.003;
    }
    if (!flat) continue;
    // Headroom: the cup pointing down from just under the ceiling meets the item's top.
    const auto top =
        Probe(TcpPose(Eigen::Vector3d(p.x(), p.y(), ceiling - 0.005), kDown, kInto), size.z());
    if (!top.contact() || top.item().SerializeAsString() != item.item().SerializeAsString() ||
        top.distance_m() < kLiftM + 0.01) {
      continue;
    }
    // The arm's configuration: the IK branch farthest from singularities along the whole
    // approach line, from kRetractM in front of the opening to 1 cm beyond the face.
    Eigen::Isometry3d X_before = t.X_BaseTcpStart;
    X_before.translation().x() -= kRetractM;
    const double depth_m = kRetractM + hit.distance_m() + 0.01;
    double best_measure = 0.0;
    for (int branch = 0; branch < 8; ++branch) {
      double measure = std::numeric_limits<double>::infinity();
      std::optional<ur10::JointVector> q_first;
      for (int k = 0; k <= 20 && measure > 0.0; ++k) {
        Eigen::Isometry3d X = X_before;
        X.translation().x() += depth_m * k / 20.0;
        bool found = false;
        for (const auto& solution : kinematics_.Solve(X * X_TcpTool()).solutions) {
          if (solution.branch.id() != branch) continue;
          found = true;
          measure = std::min(measure, kinematics_.SingularityMeasure(solution.q_rad));
          if (k == 0) q_first = solution.q_rad;
        }
        if (!found) measure = 0.0;
      }
      if (q_first && measure > best_measure) {
        best_measure = measure;
        t.q_before = *q_first;
      }
    }
    if (best_measure < 0.05) continue;
    t.face_distance_m = hit.distance_m();
    candidates.push_back(t);
  }
  ASSERT_FALSE(candidates.empty()) << "no item can be reached through a bin opening";
  std::sort(candidates.begin(), candidates.end(),
            [](const Target& a, const Target& b) { return a.face_distance_m < b.face_distance_m; });
  const Target& target = candidates.front();
  RecordProperty("target",
                 target.item.item().name() + " #" + std::to_string(target.item.item().instance()));
  SCOPED_TRACE("target " + target.item.item().name() + " #" +
               std::to_string(target.item.item().instance()) + " in container " +
               std::to_string(target.item.container()));

  // In front of the bin, then straight to the opening.
  grpc::Status s = MoveJoints(target.q_before);
  ASSERT_TRUE(s.ok()) << s.error_message();
  s = MoveLinear(target.X_BaseTcpStart);
  ASSERT_TRUE(s.ok()) << s.error_message();

  // Guarded move along the cup's axis: stops pressed on the item's face.
  robot::GuardedMoveResponse guarded;
  {
    grpc::ClientContext ctx;
    robot::GuardedMoveRequest req;
    req.mutable_direction()->set_z(1.0);
    req.set_in_tool_frame(true);
    req.set_max_distance_m(target.face_distance_m + 0.05);
    req.set_force_threshold_n(kForceThresholdN);
    req.set_speed_m_s(0.05);
    s = robot_stub_->GuardedMove(&ctx, req, &guarded);
  }
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_TRUE(guarded.contact());
  EXPECT_GE(guarded.contact_force_n(), kForceThresholdN * (1.0 - 1e-6));
  EXPECT_NEAR(guarded.distance_travelled_m(), target.face_distance_m, 0.01);

  // Vacuum on: the cup seals on the face and the item is attached.
  {
    grpc::ClientContext ctx;
    gripper::SetVacuumRequest req;
    req.set_on(true);
    req.set_wait_for_seal_s(2.0);
    gripper::SetVacuumResponse out;
    s = gripper_stub_->SetVacuum(&ctx, req, &out);
    ASSERT_TRUE(s.ok()) << s.error_message();
    EXPECT_TRUE(out.state().item_attached());
  }
  sim::GetGroundTruthResponse held = Truth();
  ASSERT_EQ(held.attached_item().SerializeAsString(), target.item.item().SerializeAsString());
  auto find = [&](const sim::GetGroundTruthResponse& t) -> const sim::ItemState* {
    for (const auto& i : t.items()) {
      if (i.item().SerializeAsString() == target.item.item().SerializeAsString()) return &i;
    }
    return nullptr;
  };
  ASSERT_NE(find(held), nullptr);
  const Eigen::Isometry3d X_TcpItem_held =
      FromProto(held.x_base_tcp()).inverse() * FromProto(find(held)->x_base_item());

  // Lift, then retract out of the bin.
  const Eigen::Isometry3d X_BaseTcp_contact = FromProto(RobotState().x_base_tcp());
  Eigen::Isometry3d X_lift = X_BaseTcp_contact;
  X_lift.translation().z() += kLiftM;
  s = MoveLinear(X_lift);
  ASSERT_TRUE(s.ok()) << s.error_message();
  Eigen::Isometry3d X_out = X_lift;
  X_out.translation().x() = target.opening_x_m - kRetractM;
  s = MoveLinear(X_out);
  ASSERT_TRUE(s.ok()) << s.error_message();

  // The item left the bin with the tool: in the gripper, at the same place under the cup.
  const sim::GetGroundTruthResponse out = Truth();
  const sim::ItemState* carried = find(out);
  ASSERT_NE(carried, nullptr);
  EXPECT_EQ(carried->container(), common::CONTAINER_GRIPPER);
  EXPECT_EQ(out.attached_item().SerializeAsString(), target.item.item().SerializeAsString());
  const Eigen::Isometry3d X_BaseTcp = FromProto(out.x_base_tcp());
  EXPECT_LT((X_BaseTcp.translation() - X_out.translation()).norm(), 1e-3);
  const Eigen::Isometry3d X_TcpItem = X_BaseTcp.inverse() * FromProto(carried->x_base_item());
  EXPECT_LT((X_TcpItem.matrix() - X_TcpItem_held.matrix()).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_LT(FromProto(carried->x_base_item()).translation().x(), target.opening_x_m);
  for (const auto& e : out.events()) {
    EXPECT_NE(e.kind(), sim::EVENT_KIND_COLLISION) << e.detail();
  }
  {
    grpc::ClientContext ctx;
    gripper::GetStateResponse state;
    ASSERT_TRUE(gripper_stub_->GetState(&ctx, gripper::GetStateRequest(), &state).ok());
    EXPECT_TRUE(state.item_attached());
  }

  // A target outside the joint limits is refused and the simulated arm does not move.
  ur10::JointVector q_bad = JointsFromProto(out.arm_joints());
  q_bad[2] = 4.0;
  s = MoveJoints(q_bad);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_EQ(Truth().arm_joints().SerializeAsString(), out.arm_joints().SerializeAsString());
}

}  // namespace
}  // namespace picking::testing
