#pragma once

#include <chrono>
#include <functional>
#include <future>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <grpcpp/channel.h>

#include "libs/world/cell_config.h"
#include "picking/detector/v1/detector.grpc.pb.h"
#include "picking/gripper/v1/gripper.grpc.pb.h"
#include "picking/planner/v1/planner.grpc.pb.h"
#include "picking/robot/v1/robot.grpc.pb.h"
#include "picking/scanner/v1/scanner.grpc.pb.h"
#include "services/orchestrator/core/cell_port.h"

namespace picking::orchestrator {

/// Sends one Detect call (params, then the cloud's chunks) to some detector replica; returns
/// the status and fills the response and which replica answered.
using DetectFn =
    std::function<grpc::Status(const detector::v1::DetectParams& params,
                               const std::vector<common::v1::PointCloudChunk>& chunks,
                               detector::v1::DetectResponse* response, std::string* replica)>;

/// Sends one Verify call to some detector replica.
using VerifyFn = std::function<grpc::Status(const detector::v1::VerifyParams& params,
                                            const std::vector<common::v1::PointCloudChunk>& chunks,
                                            detector::v1::VerifyResponse* response)>;

struct GrpcCellOptions {
  std::shared_ptr<grpc::Channel> scanner, planner, robot, gripper;
  DetectFn detect;
  VerifyFn verify;
  /// A held item's Verify needs this many of its model points in view to tell.
  int min_visible_points_to_verify = 200;
  /// Distinct poses asked of the detector per item when the container's other items are
  /// looked for with the target (the orchestrator tells them apart, ResolveAgainstOthers).
  int poses_per_item = 3;
  world::CellModel cell;  ///< For the bins' boxes (the detector's regions).
  /// Each item's box as modelled (long, middle, short side after folding, metres), for the
  /// look back's measure of the held item; an item not listed is not measured.
  std::map<std::string, Eigen::Vector3d> item_size_m;
  /// Per-call deadlines, seconds.
  double scan_deadline_s = 120.0;
  double plan_deadline_s = 30.0;
  double motion_deadline_s = 120.0;
  /// Guarded move: the force that ends it and its speed.
  double guarded_force_n = 10.0;
  double guarded_speed_m_s = 0.05;
  /// How long the vacuum may take to seal.
  double seal_wait_s = 1.0;
  /// Points within this distance of a bin's walls and floor are left out of detection.
  double wall_margin_m = 0.01;
};

/// The cell's operations done by its gRPC services (CellPort). One per task.
class GrpcCell final : public CellPort {
 public:
  explicit GrpcCell(GrpcCellOptions options);
  /// Waits for the scans still being read (each bounded by its deadline).
  ~GrpcCell() override;

  std::vector<std::string> ScanPoses(const std::string& container) override;
  StepOutcome MoveToNamed(const std::string& name) override;
  ScanView Scan() override;
  /// The Scan call read on another thread; returns at the first progress past the capture.
  std::shared_future<ScanView> StartScan() override;
  Detection Detect(const std::string& container, const std::string& item,
                   const std::vector<ScanView>& views,
                   const std::vector<std::string>& others) override;
  PlannedPick PlanPick(const std::string& container, const std::string& item,
                       const Eigen::Isometry3d& X_BaseItem,
                       const std::vector<ScanView>& views) override;
  StepOutcome ExecuteApproach(const PlannedPick& pick) override;
  TouchOutcome Touch(const PlannedPick& pick) override;
  SealReading VacuumOn() override;
  SealReading ReadSeal() override;
  StepOutcome ExecuteRetreat(const PlannedPick& pick) override;
  PlaceOutcome MoveToPlace(const std::string& item, const std::string& container,
                           const PlannedPick& pick, int placed_before) override;
  void VacuumOff() override;
  StepOutcome PutBack(const PlannedPick& pick) override;
  StepOutcome ReturnFromPlace() override;
  double VerifyHeld(const std::string& item, const PlannedPick& pick,
                    const ScanView& view) override;
  std::optional<HeldSurface> MeasureHeld(const std::string& container, const std::string& item,
                                         const PlannedPick& pick, const ScanView& view) override;

 private:
  struct StoredPick {
    planner::v1::PlanPickResponse response;
    Eigen::Isometry3d X_TcpItem = Eigen::Isometry3d::Identity();
  };
  // A container's free inner box: the box's centre and axes (a shelf bin's x out of its
  // opening, the tote's z up), and its size. "table": the space over the table's top.
  struct ContainerBox {
    Eigen::Isometry3d X_BaseBox;
    Eigen::Vector3d size_m;
  };
  ContainerBox InnerBox(const std::string& container) const;
  robot::v1::GetStateResponse RobotState();
  /// Executes a trajectory; returns its duration (robot seconds).
  double Execute(const common::v1::JointTrajectory& trajectory);
  std::string UpdateScene(const std::string& container, const std::string& item,
                          const Eigen::Isometry3d& X_BaseItem, const std::vector<ScanView>& views);
  const StoredPick& Stored(const PlannedPick& pick) const;
  StepOutcome Recover(const StoredPick& stored, const CellError& stopped);
  /// Vacuum off, then the robot's protective stop reset.
  void ReleaseAndResetStop();
  /// The gripper's head angle as last set (read from the gripper the first time).
  double HeadAngle();
  /// Turns the gripper's head (its servo's fixed mode). False, with the reason, when the
  /// gripper refuses (FAILED_PRECONDITION: no joint, or the head would hit the cell).
  bool SetHead(double angle_rad, std::string* reason);

  GrpcCellOptions options_;
  std::unique_ptr<scanner::v1::ScannerService::Stub> scanner_;
  // Reads one Scan stream to its end: `captured` set once the capture is over (or the call
  // has ended: its outcome set first in `finished`).
  void ReadScan(const scanner::v1::ScanRequest& request, const Eigen::Isometry3d& X_BaseTcp,
                std::promise<void>* captured, std::promise<ScanView>* finished) const;
  mutable std::mutex scans_mutex_;
  std::vector<std::future<void>> scans_;  // the scans being read
  std::unique_ptr<planner::v1::PlannerService::Stub> planner_;
  std::unique_ptr<robot::v1::RobotService::Stub> robot_;
  std::unique_ptr<gripper::v1::GripperService::Stub> gripper_;
  std::map<std::string, std::vector<std::string>> scan_poses_;
  std::map<int, StoredPick> picks_;
  common::v1::JointTrajectory last_place_;  // the last MoveToPlace's motion, as executed
  int next_handle_ = 0;
  std::optional<double> head_angle_rad_;  // unknown until read or set
};

/// Throws CellError for a failed call: retryable when the service did not answer.
void ThrowIfFailed(const std::string& service, const std::string& what, const grpc::Status& status);

}  // namespace picking::orchestrator
