// One meaning per frame across the servers: picking-simulator, picking-robot (sim backend),
// picking-planner and picking-scanner (simulated camera) as real binaries, all loading the
// bundled cell description. The robot moves the arm to several joint configurations; at each,
// every server that reports a pose of the flange (`tool`), of the suction cup (`tcp`) or of
// the scanner's camera must report the same pose, and the TCP must be the cell description's.
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <Eigen/Geometry>

#include <cmath>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "libs/world/cell_config.h"
#include "picking/planner/v1/planner.grpc.pb.h"
#include "picking/robot/v1/robot.grpc.pb.h"
#include "picking/scanner/v1/scanner.grpc.pb.h"
#include "picking/simulator/v1/simulator.grpc.pb.h"
#include "tests/harness/server_process.h"

namespace picking::testing {
namespace {

namespace sim = ::picking::simulator::v1;
namespace robot = ::picking::robot::v1;
namespace planner = ::picking::planner::v1;
namespace scanner = ::picking::scanner::v1;
namespace common = ::picking::common::v1;
namespace fs = std::filesystem;

constexpr double kToleranceM = 1e-6;
constexpr double kToleranceRad = 1e-6;

Eigen::Isometry3d FromProto(const common::Pose& p) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(p.position().x(), p.position().y(), p.position().z());
  X.linear() = Eigen::Quaterniond(p.orientation().w(), p.orientation().x(), p.orientation().y(),
                                  p.orientation().z())
                   .normalized()
                   .toRotationMatrix();
  return X;
}

common::JointPositions ToProto(const std::vector<double>& q) {
  common::JointPositions out;
  for (double v : q) out.add_positions_rad(v);
  return out;
}

// Passes when `a` and `b` are within 1e-6 m and 1e-6 rad of each other.
::testing::AssertionResult SamePose(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  const double distance_m = (a.translation() - b.translation()).norm();
  const double angle_rad = Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle();
  if (distance_m <= kToleranceM && angle_rad <= kToleranceRad) {
    return ::testing::AssertionSuccess();
  }
  return ::testing::AssertionFailure()
         << distance_m << " m and " << angle_rad << " rad apart: (" << a.translation().transpose()
         << ") vs (" << b.translation().transpose() << ")";
}

// A folder of its own under the system's temporary folder, removed at the end.
class TempDir {
 public:
  explicit TempDir(const std::string& name)
      : path_(fs::temp_directory_path() /
              ("picking_cell_frames_" + name + "_" + std::to_string(::getpid()))) {
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~TempDir() { fs::remove_all(path_); }
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

class CellFramesTest : public ::testing::Test {
 protected:
  CellFramesTest()
      : X_ToolTcp_(world::ReadCellConfig(world::DefaultCellConfigPath()).gripper.X_ToolTcp),
        simulator_(ServerBinary("picking-simulator")),
        robot_(ServerBinary("picking-robot"),
               {"--backend=sim", "--sim.address=" + simulator_.address(), "--sim.time_scale=20"}),
        planner_(ServerBinary("picking-planner")),
        calibration_robot_("robot"),
        calibration_sim_("sim"),
        // Two scanners on the simulated camera: one asks the robot for the flange pose at
        // capture, the other the simulator.
        scanner_robot_(
            ServerBinary("picking-scanner"),
            {"--sim.address=" + simulator_.address(), "--robot.address=" + robot_.address(),
             "--calibration.dir=" + calibration_robot_.path().string()}),
        scanner_sim_(ServerBinary("picking-scanner"),
                     {"--sim.address=" + simulator_.address(),
                      "--calibration.dir=" + calibration_sim_.path().string()}),
        sim_(sim::SimulatorService::NewStub(simulator_.Channel())),
        robot_stub_(robot::RobotService::NewStub(robot_.Channel())),
        planner_stub_(planner::PlannerService::NewStub(planner_.Channel())),
        scanner_robot_stub_(scanner::ScannerService::NewStub(scanner_robot_.Channel())),
        scanner_sim_stub_(scanner::ScannerService::NewStub(scanner_sim_.Channel())) {}

  ~CellFramesTest() override {
    EXPECT_EQ(scanner_sim_.Stop(), 0);
    EXPECT_EQ(scanner_robot_.Stop(), 0);
    EXPECT_EQ(planner_.Stop(), 0);
    EXPECT_EQ(robot_.Stop(), 0);
    EXPECT_EQ(simulator_.Stop(), 0);
  }

  robot::GetStateResponse RobotState() {
    grpc::ClientContext ctx;
    robot::GetStateResponse state;
    const grpc::Status s = robot_stub_->GetState(&ctx, robot::GetStateRequest(), &state);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return state;
  }

  // The camera pose in base of a one-view base-frame scan at the arm's current pose.
  grpc::Status ScanCameraPose(scanner::ScannerService::Stub& stub, Eigen::Isometry3d* X) {
    grpc::ClientContext ctx;
    scanner::ScanRequest request;
    request.set_frame_id("base");
    auto reader = stub.Scan(&ctx, request);
    scanner::ScanResponse response;
    int poses = 0;
    while (reader->Read(&response)) {
      if (response.has_summary()) {
        poses = response.summary().x_frame_sensor_size();
        if (poses == 1) *X = FromProto(response.summary().x_frame_sensor(0));
      }
    }
    const grpc::Status status = reader->Finish();
    EXPECT_EQ(poses, 1);
    return status;
  }

  const Eigen::Isometry3d X_ToolTcp_;
  ServerProcess simulator_;
  ServerProcess robot_;
  ServerProcess planner_;
  TempDir calibration_robot_;
  TempDir calibration_sim_;
  ServerProcess scanner_robot_;
  ServerProcess scanner_sim_;
  std::unique_ptr<sim::SimulatorService::Stub> sim_;
  std::unique_ptr<robot::RobotService::Stub> robot_stub_;
  std::unique_ptr<planner::PlannerService::Stub> planner_stub_;
  std::unique_ptr<scanner::ScannerService::Stub> scanner_robot_stub_;
  std::unique_ptr<scanner::ScannerService::Stub> scanner_sim_stub_;
};

TEST_F(CellFramesTest, EveryServerReportsTheSamePoseOfEachFrame) {
  // The scanners' hand-eye (the nominal sensor: their calibration folders are empty).
  Eigen::Isometry3d X_ToolCamera = Eigen::Isometry3d::Identity();
  for (auto* stub : {scanner_robot_stub_.get(), scanner_sim_stub_.get()}) {
    grpc::ClientContext ctx;
    scanner::GetCalibrationResponse calibration;
    ASSERT_TRUE(stub->GetCalibration(&ctx, scanner::GetCalibrationRequest(), &calibration).ok());
    ASSERT_TRUE(calibration.calibration().has_x_tool_camera());
    X_ToolCamera = FromProto(calibration.calibration().x_tool_camera());
  }

  // Collision-free configurations in front of the shelf, the wrist turned different ways; the
  // robot places the simulated arm at its initial joints on first use.
  const std::vector<std::vector<double>> targets = {
      {M_PI, -2.0, 2.0, -M_PI / 2, -M_PI / 2, 0.0},
      {M_PI - 0.3, -1.8, 1.7, -1.4, -1.57, 0.5},
      {M_PI + 0.4, -2.1, 2.2, -1.9, -1.3, -0.7},
      {2.6, -1.6, 1.5, -1.2, -1.9, 1.2},
  };
  for (std::size_t k = 0; k < targets.size(); ++k) {
    SCOPED_TRACE("configuration " + std::to_string(k));
    {
      grpc::ClientContext ctx;
      robot::MoveJointsRequest req;
      *req.mutable_target() = ToProto(targets[k]);
      robot::MoveJointsResponse out;
      const grpc::Status s = robot_stub_->MoveJoints(&ctx, req, &out);
      ASSERT_TRUE(s.ok()) << s.error_message();
    }

    // The robot: the joints it reports, its flange and TCP.
    const robot::GetStateResponse state = RobotState();
    ASSERT_EQ(state.joints().positions_rad_size(), 6);
    std::vector<double> q(state.joints().positions_rad().begin(),
                          state.joints().positions_rad().end());
    for (int j = 0; j < 6; ++j) EXPECT_NEAR(q[j], targets[k][j], 1e-9) << "joint " << j;
    const Eigen::Isometry3d X_BaseTool = FromProto(state.x_base_tool());
    const Eigen::Isometry3d X_BaseTcp = FromProto(state.x_base_tcp());
    // The TCP is the cell description's.
    EXPECT_TRUE(SamePose(X_BaseTcp, X_BaseTool * X_ToolTcp_)) << "robot tcp vs cell";

    // The planner's forward kinematics of those joints.
    {
      grpc::ClientContext ctx;
      planner::ComputeFkRequest req;
      *req.mutable_joints() = ToProto(q);
      planner::ComputeFkResponse fk;
      const grpc::Status s = planner_stub_->ComputeFk(&ctx, req, &fk);
      ASSERT_TRUE(s.ok()) << s.error_message();
      EXPECT_TRUE(SamePose(FromProto(fk.x_base_tool()), X_BaseTool)) << "planner tool";
      EXPECT_TRUE(SamePose(FromProto(fk.x_base_tcp()), X_BaseTcp)) << "planner tcp";
    }

    // The simulator's ground truth of the arm the robot placed.
    {
      grpc::ClientContext ctx;
      sim::GetGroundTruthResponse truth;
      const grpc::Status s = sim_->GetGroundTruth(&ctx, sim::GetGroundTruthRequest(), &truth);
      ASSERT_TRUE(s.ok()) << s.error_message();
      ASSERT_EQ(truth.arm_joints().positions_rad_size(), 6);
      for (int j = 0; j < 6; ++j) EXPECT_NEAR(truth.arm_joints().positions_rad(j), q[j], 1e-12);
      ASSERT_TRUE(truth.has_x_base_tcp());
      ASSERT_TRUE(truth.has_x_base_tool());
      EXPECT_TRUE(SamePose(FromProto(truth.x_base_tcp()), X_BaseTcp)) << "simulator truth tcp";
      EXPECT_TRUE(SamePose(FromProto(truth.x_base_tool()), X_BaseTool)) << "simulator truth tool";
    }
    // ... and its answer for placing the arm there (as the robot's sim backend does).
    {
      grpc::ClientContext ctx;
      sim::SetArmJointsRequest req;
      *req.mutable_joints() = ToProto(q);
      sim::SetArmJointsResponse placed;
      const grpc::Status s = sim_->SetArmJoints(&ctx, req, &placed);
      ASSERT_TRUE(s.ok()) << s.error_message();
      EXPECT_FALSE(placed.in_collision()) << placed.collision_detail();
      EXPECT_TRUE(SamePose(FromProto(placed.x_base_tcp()), X_BaseTcp)) << "SetArmJoints tcp";
      EXPECT_TRUE(SamePose(FromProto(placed.x_base_tool()), X_BaseTool)) << "SetArmJoints tool";
    }

    // The scanners' camera at capture: on the flange, whichever server they asked for it.
    {
      Eigen::Isometry3d X_BaseCamera_robot = Eigen::Isometry3d::Identity();
      Eigen::Isometry3d X_BaseCamera_sim = Eigen::Isometry3d::Identity();
      grpc::Status s = ScanCameraPose(*scanner_robot_stub_, &X_BaseCamera_robot);
      ASSERT_TRUE(s.ok()) << s.error_message();
      s = ScanCameraPose(*scanner_sim_stub_, &X_BaseCamera_sim);
      ASSERT_TRUE(s.ok()) << s.error_message();
      EXPECT_TRUE(SamePose(X_BaseCamera_robot, X_BaseTool * X_ToolCamera)) << "scanner (robot)";
      EXPECT_TRUE(SamePose(X_BaseCamera_sim, X_BaseTool * X_ToolCamera)) << "scanner (sim)";
    }
  }
}

}  // namespace
}  // namespace picking::testing
