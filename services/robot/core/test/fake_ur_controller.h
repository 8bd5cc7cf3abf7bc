#pragma once

// An in-process stand-in for a UR controller on loopback ports: an RTDE server (protocol 2,
// output recipes from a fixed variable table), a URScript receiver (movej, speedl, stopj,
// stopl, protective_stop and servoj programs) and a dashboard server. The arm is a simple
// kinematic simulation advanced by one RTDE period per data package sent.

#include <atomic>
#include <cmath>
#include <map>
#include <memory>
#include <mutex>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "libs/ur10/kinematics.h"
#include "services/robot/core/byte_stream.h"
#include "services/robot/core/rtde.h"

namespace picking::robot::testing {

using ur10::JointVector;

inline std::vector<double> ParseNumbers(const std::string& text) {
  std::vector<double> out;
  static const std::regex kNumber(R"(-?\d+(\.\d+)?(e-?\d+)?)");
  for (auto it = std::sregex_iterator(text.begin(), text.end(), kNumber);
       it != std::sregex_iterator(); ++it) {
    out.push_back(std::stod(it->str()));
  }
  return out;
}

class FakeUrController {
 public:
  explicit FakeUrController(const ur10::Ur10Kinematics& kin) : kin_(kin) {
    q_ << 0.2, -1.6, 1.8, -1.8, -1.57, 0.3;
    rtde_thread_ = std::thread([this] { ServeRtde(); });
    script_thread_ = std::thread([this] { ServeScript(); });
    dashboard_thread_ = std::thread([this] { ServeDashboard(); });
  }
  ~FakeUrController() {
    closing_ = true;
    rtde_listener_.Close();
    script_listener_.Close();
    dashboard_listener_.Close();
    {
      std::lock_guard<std::mutex> lock(mutex_);
      for (auto& s : open_streams_) s->Close();
    }
    rtde_thread_.join();
    script_thread_.join();
    dashboard_thread_.join();
  }

  std::uint16_t rtde_port() const { return rtde_listener_.port(); }
  std::uint16_t script_port() const { return script_listener_.port(); }
  std::uint16_t dashboard_port() const { return dashboard_listener_.port(); }

  // Height (base z, m) of a horizontal surface the TCP presses on (force 2000 N/m).
  void set_surface_z(double z) {
    std::lock_guard<std::mutex> lock(mutex_);
    surface_z_ = z;
  }
  void set_robot_mode(int mode) {
    std::lock_guard<std::mutex> lock(mutex_);
    robot_mode_ = mode;
  }
  JointVector q() {
    std::lock_guard<std::mutex> lock(mutex_);
    return q_;
  }
  std::vector<std::string> script_lines() {
    std::lock_guard<std::mutex> lock(mutex_);
    return script_lines_;
  }
  std::vector<std::string> dashboard_commands() {
    std::lock_guard<std::mutex> lock(mutex_);
    return dashboard_commands_;
  }
  std::uint16_t negotiated_version() const { return negotiated_version_; }

 private:
  void Track(const std::shared_ptr<ByteStream>& s) {
    std::lock_guard<std::mutex> lock(mutex_);
    open_streams_.push_back(s);
  }

  // One simulation step of dt seconds.
  void Step(double dt) {
    JointVector qd = JointVector::Zero();
    if (safety_mode_ != 1) {
      motion_ = Motion::kNone;
    } else if (motion_ == Motion::kJoint) {
      const JointVector diff = target_ - q_;
      const double dist = diff.cwiseAbs().maxCoeff();
      if (dist <= joint_speed_ * dt) {
        qd = diff / dt;
        if (!servo_queue_.empty()) {
          target_ = servo_queue_.front().first;
          joint_speed_ =
              std::max(1e-6, (target_ - q_).cwiseAbs().maxCoeff()) / servo_queue_.front().second;
          servo_queue_.erase(servo_queue_.begin());
        } else {
          motion_ = Motion::kNone;
        }
      } else {
        qd = diff / dist * joint_speed_;
      }
    } else if (motion_ == Motion::kTool) {
      Eigen::Matrix<double, 6, 1> twist = Eigen::Matrix<double, 6, 1>::Zero();
      twist.head<3>() = tool_velocity_;
      qd = kin_.Jacobian(q_).completeOrthogonalDecomposition().solve(twist);
      tool_time_left_ -= dt;
      if (tool_time_left_ <= 0.0) motion_ = Motion::kNone;
    }
    q_ += qd * dt;
    qd_ = qd;
    time_ += dt;
  }

  std::string DataPackage(const rtde::Recipe& recipe) {
    std::lock_guard<std::mutex> lock(mutex_);
    Step(1.0 / frequency_);
    const Eigen::Vector3d tcp = kin_.ForwardKinematics(q_).translation();
    const double penetration = surface_z_ - tcp.z();
    std::array<double, 6> force{0, 0, penetration > 0 ? 2000.0 * penetration : 0.0, 0, 0, 0};
    std::vector<rtde::FieldValue> values;
    for (const auto& name : recipe.names) {
      std::array<double, 6> q, qd;
      for (int i = 0; i < 6; ++i) q[i] = q_[i], qd[i] = qd_[i];
      if (name == "timestamp") values.emplace_back(time_);
      if (name == "actual_q") values.emplace_back(q);
      if (name == "actual_qd") values.emplace_back(qd);
      if (name == "actual_TCP_force") values.emplace_back(force);
      if (name == "robot_mode") values.emplace_back(std::int32_t{robot_mode_});
      if (name == "safety_mode") values.emplace_back(std::int32_t{safety_mode_});
      if (name == "speed_scaling") values.emplace_back(1.0);
    }
    return rtde::EncodePackage(rtde::PackageType::kDataPackage,
                               rtde::EncodeDataPackage(recipe.id, recipe.types, values));
  }

  void ServeRtde() {
    static const std::map<std::string, std::string> kTypes = {
        {"timestamp", "DOUBLE"},     {"actual_q", "VECTOR6D"},
        {"actual_qd", "VECTOR6D"},   {"actual_TCP_force", "VECTOR6D"},
        {"robot_mode", "INT32"},     {"safety_mode", "INT32"},
        {"speed_scaling", "DOUBLE"}, {"input_int_register_0", "INT32"}};
    try {
      std::shared_ptr<TcpStream> stream = rtde_listener_.Accept(std::chrono::seconds(30));
      Track(stream);
      rtde::Recipe recipe;
      bool running = false;
      std::uint8_t next_id = 1;
      while (!closing_) {
        if (running) {
          stream->WriteAll(DataPackage(recipe));
          // Pace the stream; nothing waits on this for correctness.
          std::this_thread::sleep_for(std::chrono::milliseconds(1));
        }
        // Poll for requests without blocking the data stream for long.
        rtde::Package request;
        try {
          request = rtde::ReadPackage(*stream, std::chrono::milliseconds(running ? 0 : 200));
        } catch (const StreamError& e) {
          if (std::string(e.what()).find("timed out") != std::string::npos) continue;
          return;
        }
        using T = rtde::PackageType;
        std::string reply;
        switch (request.type) {
          case T::kRequestProtocolVersion:
            negotiated_version_ = rtde::DecodeRequestProtocolVersion(request.payload);
            reply = std::string(1, negotiated_version_ == 2 ? 1 : 0);
            break;
          case T::kGetUrControlVersion:
            reply = rtde::EncodeControllerVersion({3, 15, 8, 106339});
            break;
          case T::kControlPackageSetupOutputs: {
            auto [frequency, names] = rtde::DecodeSetupOutputs(request.payload);
            frequency_ = frequency;
            std::vector<std::string> types;
            for (const auto& n : names) {
              types.push_back(kTypes.count(n) ? kTypes.at(n) : "NOT_FOUND");
            }
            recipe.id = next_id++;
            recipe.names = names;
            recipe.types.clear();
            for (const auto& t : types) {
              if (t != "NOT_FOUND") recipe.types.push_back(rtde::ParseFieldType(t));
            }
            reply = rtde::EncodeSetupReply(recipe.id, types);
            break;
          }
          case T::kControlPackageSetupInputs: {
            std::vector<std::string> types;
            for (const auto& n : rtde::DecodeSetupInputs(request.payload)) {
              types.push_back(n == "input_int_register_0" ? "INT32" : "IN_USE");
            }
            reply = rtde::EncodeSetupReply(next_id++, types);
            break;
          }
          case T::kControlPackageStart:
            running = true;
            reply = std::string(1, 1);
            break;
          case T::kControlPackagePause:
            running = false;
            reply = std::string(1, 1);
            break;
          case T::kDataPackage:
            continue;
          default:
            continue;
        }
        if (request.type == T::kControlPackageStart) {
          // A warning text message before the reply, as a controller may send.
          stream->WriteAll(rtde::EncodePackage(T::kTextMessage,
                                               rtde::EncodeTextMessage({"starting", "RTDE", 2})));
        }
        stream->WriteAll(rtde::EncodePackage(request.type, reply));
      }
    } catch (const std::exception&) {
    }
  }

  void HandleScript(const std::string& line) {
    std::lock_guard<std::mutex> lock(mutex_);
    script_lines_.push_back(line);
    const std::vector<double> n = ParseNumbers(line);
    if (line.rfind("movej(", 0) == 0 && n.size() >= 8) {
      for (int i = 0; i < 6; ++i) target_[i] = n[i];
      joint_speed_ = n[7];
      motion_ = Motion::kJoint;
    } else if (line.rfind("servoj(", 0) == 0 && n.size() >= 9) {
      JointVector q;
      for (int i = 0; i < 6; ++i) q[i] = n[i];
      servo_queue_.push_back({q, n[8]});
    } else if (line.rfind("speedl(", 0) == 0 && n.size() >= 8) {
      tool_velocity_ = Eigen::Vector3d(n[0], n[1], n[2]);
      tool_time_left_ = n[7];
      motion_ = Motion::kTool;
    } else if (line.rfind("stopj(", 0) == 0 || line.rfind("stopl(", 0) == 0) {
      if (!in_program_) {
        motion_ = Motion::kNone;
        servo_queue_.clear();
      }
    } else if (line == "protective_stop()") {
      safety_mode_ = 3;
    } else if (line.rfind("def ", 0) == 0) {
      in_program_ = true;
      servo_queue_.clear();
    } else if (line == "end") {
      in_program_ = false;
      if (!servo_queue_.empty()) {
        target_ = servo_queue_.front().first;
        joint_speed_ =
            std::max(1e-6, (target_ - q_).cwiseAbs().maxCoeff()) / servo_queue_.front().second;
        servo_queue_.erase(servo_queue_.begin());
        motion_ = Motion::kJoint;
      }
    }
  }

  void ServeScript() {
    try {
      std::shared_ptr<TcpStream> stream = script_listener_.Accept(std::chrono::seconds(30));
      Track(stream);
      while (!closing_) {
        std::string line = stream->ReadLine(std::chrono::seconds(60));
        while (!line.empty() && line.front() == ' ') line.erase(0, 1);
        HandleScript(line);
      }
    } catch (const std::exception&) {
    }
  }

  void ServeDashboard() {
    try {
      std::shared_ptr<TcpStream> stream = dashboard_listener_.Accept(std::chrono::seconds(30));
      Track(stream);
      stream->WriteAll("Connected: Universal Robots Dashboard Server\n");
      while (!closing_) {
        const std::string command = stream->ReadLine(std::chrono::seconds(60));
        std::string reply;
        {
          std::lock_guard<std::mutex> lock(mutex_);
          dashboard_commands_.push_back(command);
          if (command == "power on") {
            robot_mode_ = 5;
            reply = "Powering on";
          } else if (command == "brake release") {
            robot_mode_ = 7;
            reply = "Brake releasing";
          } else if (command == "unlock protective stop") {
            if (safety_mode_ == 3) {
              safety_mode_ = 1;
              reply = "Protective stop releasing";
            } else {
              reply = "Cannot unlock protective stop: robot is not in protective stop";
            }
          } else if (command == "stop") {
            reply = "Stopped";
          } else if (command == "robotmode") {
            reply = robot_mode_ == 7 ? "Robotmode: RUNNING" : "Robotmode: POWER_OFF";
          } else if (command == "safetystatus") {
            reply = safety_mode_ == 3 ? "Safetystatus: PROTECTIVE_STOP" : "Safetystatus: NORMAL";
          } else {
            reply = "could not understand: '" + command + "'";
          }
        }
        stream->WriteAll(reply + "\n");
      }
    } catch (const std::exception&) {
    }
  }

  enum class Motion { kNone, kJoint, kTool };

  ur10::Ur10Kinematics kin_;
  TcpListener rtde_listener_{0};
  TcpListener script_listener_{0};
  TcpListener dashboard_listener_{0};
  std::atomic<bool> closing_{false};
  std::atomic<std::uint16_t> negotiated_version_{0};
  std::mutex mutex_;
  std::vector<std::shared_ptr<ByteStream>> open_streams_;
  double frequency_ = 125.0;
  double time_ = 0.0;
  JointVector q_ = JointVector::Zero();
  JointVector qd_ = JointVector::Zero();
  JointVector target_ = JointVector::Zero();
  double joint_speed_ = 0.0;
  std::vector<std::pair<JointVector, double>> servo_queue_;
  Eigen::Vector3d tool_velocity_ = Eigen::Vector3d::Zero();
  double tool_time_left_ = 0.0;
  bool in_program_ = false;
  Motion motion_ = Motion::kNone;
  int robot_mode_ = 3;   // POWER_OFF
  int safety_mode_ = 1;  // NORMAL
  double surface_z_ = -10.0;
  std::vector<std::string> script_lines_;
  std::vector<std::string> dashboard_commands_;
  std::thread rtde_thread_, script_thread_, dashboard_thread_;
};

}  // namespace picking::robot::testing
