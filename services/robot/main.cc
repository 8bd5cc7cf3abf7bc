// picking-robot: the robot server of the picking cell.
#include "libs/runtime/server.h"
#include "services/robot/service/robot_service.h"

int main(int argc, char** argv) {
  picking::runtime::ServerSpec spec;
  spec.program = "picking-robot";
  spec.service = "robot";
  spec.description = "the robot service of the picking cell (gRPC: picking.robot.v1)";
  spec.settings_help = {
      "backend=sim|ur                       arm backend (default sim)",
      "sim.address=HOST:PORT                picking-simulator (default 127.0.0.1:50051)",
      "sim.time_scale=S                     simulated s per wall-clock s (default 1)",
      "sim.rate_hz=R                        SetArmJoints per simulated s (default 50)",
      "sim.timeout_s=T                      deadline of each simulator call (default 2)",
      "sim.stop_acceleration_rad_s2=A       deceleration of Stop (default 3)",
      "sim.initial_joints_rad=Q1,..,Q6      arm joints of a fresh simulator",
      "ur.host=HOST                         UR controller (default 127.0.0.1)",
      "ur.rtde_port / ur.script_port / ur.dashboard_port  (default 30004 / 30002 / 29999)",
      "ur.rtde_frequency_hz=F               RTDE output rate (default 125)",
      "ur.connect_timeout_s=T               (default 3)",
      "ur.power_on=BOOL                     power on and release brakes at start (default false)",
      "data_dir=DIR                         bundled data (UR10 description in ur10/)",
      "cell=FILE                            cell description, with the gripper's TCP (default",
      "                                     <data_dir>/cell/default_cell.yaml)",
      "ur10.max_acceleration_rad_s2=A       joint acceleration limit (default 2.5)",
      "safety.workspace_min_m / safety.workspace_max_m=X,Y,Z  TCP box in base",
      "safety.forbidden_zones=NAME,...      zones (default pedestal,shelf_base); each needs",
      "  safety.zone.NAME.min_m / .max_m=X,Y,Z unless it is a built-in one",
      "safety.max_tcp_speed_m_s=V           (default 0.5)",
      "safety.max_tcp_acceleration_m_s2=A   linear moves (default 1)",
      "safety.max_contact_force_n=F         largest guarded-move threshold (default 50)",
      "safety.joint_speed_scale=K           fraction of the joint speed limits (default 1)",
      "motion.default_speed_fraction / motion.default_acceleration_fraction=F  (default 0.5)",
      "guarded.acceleration_m_s2=A          guarded-move acceleration (default 0.5)"};
  spec.build = picking::robot::BuildRobotServices;
  return picking::runtime::RunServerMain(argc, argv, spec);
}
