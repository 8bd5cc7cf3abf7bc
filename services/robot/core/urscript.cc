#include "services/robot/core/urscript.h"

#include <cctype>
#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace picking::robot::urscript {
namespace {

std::string Number(double value, const char* what) {
  if (!std::isfinite(value)) {
    throw std::invalid_argument(std::string("URScript: ") + what + " is not finite");
  }
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "%.6f", value);
  std::string s = buffer;
  if (s == "-0.000000") s = "0.000000";
  return s;
}

std::string NonNegative(double value, const char* what) {
  if (!(value >= 0.0)) {
    throw std::invalid_argument(std::string("URScript: ") + what + " must be >= 0");
  }
  return Number(value, what);
}

std::string Positive(double value, const char* what) {
  if (!(value > 0.0)) {
    throw std::invalid_argument(std::string("URScript: ") + what + " must be > 0");
  }
  return Number(value, what);
}

template <typename Vector>
std::string List(const Vector& v, const char* what) {
  std::string s = "[";
  for (int i = 0; i < v.size(); ++i) {
    if (i > 0) s += ", ";
    s += Number(v[i], what);
  }
  return s + "]";
}

}  // namespace

std::string Pose(const Eigen::Isometry3d& X) {
  const Eigen::AngleAxisd aa(X.linear());
  const Eigen::Vector3d r = aa.axis() * aa.angle();
  Eigen::Matrix<double, 6, 1> v;
  v << X.translation(), r;
  return "p" + List(v, "pose");
}

std::string MoveJ(const JointVector& q_rad, double a_rad_s2, double v_rad_s, double t_s,
                  double r_m) {
  return "movej(" + List(q_rad, "joint position") + ", a=" + Positive(a_rad_s2, "a") +
         ", v=" + Positive(v_rad_s, "v") + ", t=" + NonNegative(t_s, "t") +
         ", r=" + NonNegative(r_m, "r") + ")";
}

std::string MoveL(const Eigen::Isometry3d& X_BaseTcp, double a_m_s2, double v_m_s, double t_s,
                  double r_m) {
  return "movel(" + Pose(X_BaseTcp) + ", a=" + Positive(a_m_s2, "a") +
         ", v=" + Positive(v_m_s, "v") + ", t=" + NonNegative(t_s, "t") +
         ", r=" + NonNegative(r_m, "r") + ")";
}

std::string SpeedJ(const JointVector& qd_rad_s, double a_rad_s2, double t_s) {
  return "speedj(" + List(qd_rad_s, "joint speed") + ", a=" + Positive(a_rad_s2, "a") +
         ", t=" + NonNegative(t_s, "t") + ")";
}

std::string SpeedL(const Eigen::Matrix<double, 6, 1>& twist_base, double a_m_s2, double t_s) {
  return "speedl(" + List(twist_base, "tool speed") + ", a=" + Positive(a_m_s2, "a") +
         ", t=" + NonNegative(t_s, "t") + ")";
}

std::string StopJ(double a_rad_s2) { return "stopj(" + Positive(a_rad_s2, "a") + ")"; }
std::string StopL(double a_m_s2) { return "stopl(" + Positive(a_m_s2, "a") + ")"; }

std::string ServoJ(const JointVector& q_rad, double t_s, double lookahead_time_s, double gain) {
  if (!(lookahead_time_s >= 0.03 && lookahead_time_s <= 0.2)) {
    throw std::invalid_argument("URScript: servoj lookahead_time must be in [0.03, 0.2] s");
  }
  if (!(gain >= 100.0 && gain <= 2000.0)) {
    throw std::invalid_argument("URScript: servoj gain must be in [100, 2000]");
  }
  return "servoj(" + List(q_rad, "joint position") + ", 0, 0, " + Positive(t_s, "t") + ", " +
         Number(lookahead_time_s, "lookahead_time") + ", " + Number(gain, "gain") + ")";
}

std::string Program(const std::string& name, const std::vector<std::string>& lines) {
  bool valid = !name.empty() && !std::isdigit(static_cast<unsigned char>(name[0]));
  for (char c : name) valid = valid && (std::isalnum(static_cast<unsigned char>(c)) || c == '_');
  if (!valid) throw std::invalid_argument("URScript: invalid program name '" + name + "'");
  std::string text = "def " + name + "():\n";
  for (const auto& line : lines) {
    if (line.find('\n') != std::string::npos) {
      throw std::invalid_argument("URScript: a program line contains a newline");
    }
    text += "  " + line + "\n";
  }
  return text + "end\n";
}

}  // namespace picking::robot::urscript
