#pragma once

#include <Eigen/Geometry>

#include <string>
#include <vector>

#include "libs/ur10/ur10_model.h"

namespace picking::robot::urscript {

using ur10::JointVector;

/// URScript text for the UR controller's secondary (30002) and real-time (30003) interfaces.
/// Numbers are written in fixed notation with 6 decimals (1 micro-radian / 1 micrometre).
/// Every function throws std::invalid_argument for a non-finite or out-of-range argument
/// (negative speed, acceleration, time or blend radius).

/// "movej([q1, ..., q6], a=<a>, v=<v>, t=<t>, r=<r>)": joint-space move. a in rad/s^2, v in
/// rad/s, t in s (0 = use a and v), r blend radius in m.
std::string MoveJ(const JointVector& q_rad, double a_rad_s2, double v_rad_s, double t_s = 0.0,
                  double r_m = 0.0);

/// "movel(p[x, y, z, rx, ry, rz], a=<a>, v=<v>, t=<t>, r=<r>)": linear tool move to
/// X_BaseTcp (position in m, rotation as a rotation vector in rad), a in m/s^2, v in m/s.
std::string MoveL(const Eigen::Isometry3d& X_BaseTcp, double a_m_s2, double v_m_s, double t_s = 0.0,
                  double r_m = 0.0);

/// "speedj([qd1, ..., qd6], a=<a>, t=<t>)": joint speed command for t s.
std::string SpeedJ(const JointVector& qd_rad_s, double a_rad_s2, double t_s);

/// "speedl([vx, vy, vz, wx, wy, wz], a=<a>, t=<t>)": tool speed in the base frame for t s.
std::string SpeedL(const Eigen::Matrix<double, 6, 1>& twist_base, double a_m_s2, double t_s);

/// "stopj(a)" / "stopl(a)": decelerate to rest.
std::string StopJ(double a_rad_s2);
std::string StopL(double a_m_s2);

/// "servoj([q1..q6], 0, 0, <t>, <lookahead_time>, <gain>)": servo to q within t s;
/// lookahead_time in [0.03, 0.2] s, gain in [100, 2000] (URScript manual ranges).
std::string ServoJ(const JointVector& q_rad, double t_s, double lookahead_time_s = 0.1,
                   double gain = 300.0);

/// "p[x, y, z, rx, ry, rz]" of a pose.
std::string Pose(const Eigen::Isometry3d& X);

/// Wraps statement lines into "def <name>():\n  <line>\n  ...\nend\n". name:
/// [A-Za-z_][A-Za-z0-9_]*.
std::string Program(const std::string& name, const std::vector<std::string>& lines);

}  // namespace picking::robot::urscript
