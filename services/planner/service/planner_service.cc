#include "services/planner/service/planner_service.h"

#include <algorithm>
#include <cmath>

#include "libs/apc/catalogue.h"
#include "libs/proto_convert/proto_convert.h"
#include "libs/runtime/status.h"
#include "libs/ur10/kinematics.h"
#include "libs/world/cell_config.h"

namespace picking::planner {
namespace {

namespace pb = ::picking::planner::v1;
namespace pc = ::picking::proto_convert;

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

// Kinematics RPCs are served now; the motion planning RPCs (PlanJointMotion, PlanPick,
// PlanPlace, ComputeGrasps, ListNamedPoses) need the collision world and answer
// UNIMPLEMENTED through the generated base class until it lands.
class PlannerServiceImpl final : public pb::PlannerService::Service {
 public:
  PlannerServiceImpl(ur10::Ur10Kinematics kinematics, const Eigen::Isometry3d& X_ToolTcp)
      : kinematics_(std::move(kinematics)), X_ToolTcp_(X_ToolTcp) {}

  grpc::Status ComputeFk(grpc::ServerContext*, const pb::ComputeFkRequest* request,
                         pb::ComputeFkResponse* response) override {
    return runtime::Guard([&] {
      const ur10::JointVector q = ToJointVector(pc::JointsFromProto(request->joints(), "joints"));
      if (!kinematics_.model().WithinPositionLimits(q)) {
        return runtime::InvalidArgument("joints are outside the UR10's joint position limits");
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
      if (request->has_seed()) {
        options.seed_rad = ToJointVector(pc::JointsFromProto(request->seed(), "seed"));
      }
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

 private:
  const ur10::Ur10Kinematics kinematics_;
  const Eigen::Isometry3d X_ToolTcp_;
};

}  // namespace

runtime::ServiceSet BuildPlannerServices(const runtime::Config& config) {
  const std::string data_dir = config.GetString("data_dir", apc::DefaultDataDir());
  ur10::Ur10ModelOptions model_options;
  model_options.max_acceleration_rad_s2 =
      config.GetDouble("ur10.max_acceleration_rad_s2", model_options.max_acceleration_rad_s2);
  ur10::Ur10Kinematics kinematics(ur10::Ur10Model::Load(data_dir + "/ur10", model_options));
  // The tool centre point (the suction cup's lip centre) in the flange frame: the gripper's
  // of the cell description.
  const std::string cell_path = config.GetPath("cell", world::DefaultCellConfigPath(data_dir));
  Eigen::Isometry3d X_ToolTcp = Eigen::Isometry3d::Identity();
  try {
    X_ToolTcp = world::ReadCellConfig(cell_path).gripper.X_ToolTcp;
  } catch (const world::CellConfigError& e) {
    throw std::invalid_argument(std::string("setting 'cell': ") + e.what());
  }

  runtime::ServiceSet set;
  set.Add(std::make_shared<PlannerServiceImpl>(std::move(kinematics), X_ToolTcp),
          pb::PlannerService::service_full_name());
  return set;
}

}  // namespace picking::planner
