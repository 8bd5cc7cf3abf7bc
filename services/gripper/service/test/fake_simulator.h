#pragma once

#include <grpcpp/server.h>
#include <grpcpp/server_builder.h>
#include <grpcpp/server_context.h>

#include <Eigen/Geometry>

#include <cmath>
#include <memory>
#include <mutex>
#include <string>

#include "libs/proto_convert/proto_convert.h"
#include "picking/simulator/v1/simulator.grpc.pb.h"

namespace picking::gripper::testing {

/// The part of picking.simulator.v1.SimulatorService the gripper uses, served in-process on
/// a free port: a tool pose, an item that may be under the cup, and the suction seal.
class FakeSimulator final : public simulator::v1::SimulatorService::Service {
 public:
  FakeSimulator() {
    grpc::ServerBuilder builder;
    builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port_);
    builder.RegisterService(this);
    server_ = builder.BuildAndStart();
  }
  ~FakeSimulator() override { server_->Shutdown(); }

  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }

  // World, set by the test.
  void SetToolPose(const Eigen::Isometry3d& X_BaseTool) {
    std::lock_guard<std::mutex> lock(mutex_);
    X_BaseTool_ = X_BaseTool;
  }
  void SetItemUnderCup(const std::string& name) {
    std::lock_guard<std::mutex> lock(mutex_);
    item_under_cup_ = name;
  }
  /// The level SetSuction reports (0: none, as a simulator without a pressure model).
  void SetReportedKpa(double sealed_kpa, double open_kpa) {
    std::lock_guard<std::mutex> lock(mutex_);
    sealed_kpa_ = sealed_kpa;
    open_kpa_ = open_kpa;
  }
  /// The attached item falls off.
  void DropAttachedItem() {
    std::lock_guard<std::mutex> lock(mutex_);
    attached_.clear();
  }
  void SetNoLayout(bool no_layout) {
    std::lock_guard<std::mutex> lock(mutex_);
    no_layout_ = no_layout;
  }
  int suction_calls() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return suction_calls_;
  }
  bool suction_on() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return suction_on_;
  }

  grpc::Status SetSuction(grpc::ServerContext*, const simulator::v1::SetSuctionRequest* request,
                          simulator::v1::SetSuctionResponse* response) override {
    std::lock_guard<std::mutex> lock(mutex_);
    if (no_layout_) return {grpc::StatusCode::FAILED_PRECONDITION, "no layout loaded"};
    ++suction_calls_;
    suction_on_ = request->on();
    if (request->on()) {
      if (attached_.empty()) attached_ = item_under_cup_;
      const bool sealed = !attached_.empty();
      response->set_sealed(sealed);
      response->set_vacuum_kpa(sealed ? sealed_kpa_ : open_kpa_);
      response->mutable_attached_item()->set_name(attached_);
    } else {
      attached_.clear();
    }
    return grpc::Status::OK;
  }

  grpc::Status GetGroundTruth(grpc::ServerContext*, const simulator::v1::GetGroundTruthRequest*,
                              simulator::v1::GetGroundTruthResponse* response) override {
    std::lock_guard<std::mutex> lock(mutex_);
    if (no_layout_) return {grpc::StatusCode::FAILED_PRECONDITION, "no layout loaded"};
    *response->mutable_x_base_tool() = proto_convert::PoseToProto(X_BaseTool_);
    response->mutable_attached_item()->set_name(attached_);
    response->set_gripper_head_angle_rad(head_angle_rad_);
    return grpc::Status::OK;
  }

  grpc::Status SetGripperHead(grpc::ServerContext*,
                              const simulator::v1::SetGripperHeadRequest* request,
                              simulator::v1::SetGripperHeadResponse* response) override {
    std::lock_guard<std::mutex> lock(mutex_);
    if (std::abs(request->angle_rad()) > max_head_angle_rad_) {
      return {grpc::StatusCode::INVALID_ARGUMENT, "outside the servo's range"};
    }
    if (head_blocked_) return {grpc::StatusCode::FAILED_PRECONDITION, "the head hits the shelf"};
    head_angle_rad_ = request->angle_rad();
    ++head_calls_;
    response->set_angle_rad(head_angle_rad_);
    return grpc::Status::OK;
  }
  /// The simulated head's angle, and how often it was turned.
  double head_angle_rad() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return head_angle_rad_;
  }
  int head_calls() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return head_calls_;
  }
  /// Every turn of the head is refused as a collision.
  void BlockHead(bool blocked) {
    std::lock_guard<std::mutex> lock(mutex_);
    head_blocked_ = blocked;
  }

 private:
  mutable std::mutex mutex_;
  Eigen::Isometry3d X_BaseTool_ = Eigen::Isometry3d::Identity();
  std::string item_under_cup_;
  std::string attached_;
  double sealed_kpa_ = 0.0;
  double open_kpa_ = 0.0;
  bool no_layout_ = false;
  bool suction_on_ = false;
  int suction_calls_ = 0;
  double head_angle_rad_ = 0.0;
  double max_head_angle_rad_ = 1.5707963267948966;
  bool head_blocked_ = false;
  int head_calls_ = 0;
  int port_ = 0;
  std::unique_ptr<grpc::Server> server_;
};

/// A tool pointing down (+z_tool along -z_base), then tilted by `phi` about its x axis:
/// gravity in the tool frame is g * (0, sin phi, cos phi).
inline Eigen::Isometry3d TiltedDownTool(double phi) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() =
      Eigen::AngleAxisd(3.14159265358979323846 + phi, Eigen::Vector3d::UnitX()).toRotationMatrix();
  X.translation() = Eigen::Vector3d(0.5, 0.2, 0.8);
  return X;
}

}  // namespace picking::gripper::testing
