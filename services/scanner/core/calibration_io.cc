#include "services/scanner/core/calibration_io.h"

#include <nlohmann/json.hpp>

#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace picking::scanner {
namespace {

using nlohmann::json;

bool IsIntrinsicsKind(CalibrationKind kind) {
  return kind == CalibrationKind::kCameraIntrinsics ||
         kind == CalibrationKind::kProjectorIntrinsics;
}

std::pair<const char*, const char*> Frames(CalibrationKind kind) {
  switch (kind) {
    case CalibrationKind::kCameraProjectorExtrinsics:
      return {"camera", "projector"};
    case CalibrationKind::kHandEye:
      return {"tool", "camera"};
    case CalibrationKind::kShelfPose:
      return {"base", "shelf"};
    default:
      return {"", ""};
  }
}

std::string NowUtc() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char buffer[32];
  std::strftime(buffer, sizeof(buffer), "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buffer;
}

void WriteAtomically(const std::string& path, const std::string& text) {
  const std::string temporary = path + ".tmp." + std::to_string(::getpid());
  {
    std::ofstream out(temporary, std::ios::binary | std::ios::trunc);
    if (!out) {
      throw std::runtime_error("cannot write calibration file '" + temporary +
                               "': " + std::strerror(errno));
    }
    out << text;
    out.flush();
    if (!out) {
      std::remove(temporary.c_str());
      throw std::runtime_error("cannot write calibration file '" + temporary + "'");
    }
  }
  if (std::rename(temporary.c_str(), path.c_str()) != 0) {
    const std::string reason = std::strerror(errno);
    std::remove(temporary.c_str());
    throw std::runtime_error("cannot replace calibration file '" + path + "': " + reason);
  }
}

json Header(CalibrationKind kind, const CalibrationInfo& info) {
  json j;
  j["format_version"] = kCalibrationFormatVersion;
  j["kind"] = CalibrationKindName(kind);
  j["timestamp_utc"] = info.timestamp_utc.empty() ? NowUtc() : info.timestamp_utc;
  j["error"] = info.error;
  j["error_unit"] = info.error_unit;
  return j;
}

// Field access with errors that name the file and the field.
class Reader {
 public:
  Reader(std::string path, CalibrationKind kind) : path_(std::move(path)) {
    std::ifstream in(path_);
    if (!in) throw std::runtime_error("cannot open calibration file '" + path_ + "'");
    try {
      root_ = json::parse(in);
    } catch (const json::parse_error& e) {
      throw std::runtime_error("calibration file '" + path_ + "' is not valid JSON: " + e.what());
    }
    if (!root_.is_object()) Fail("", "the file is not a JSON object");
    const json& version = Get(root_, "", "format_version");
    if (!version.is_number_integer() || version.get<int>() != kCalibrationFormatVersion) {
      Fail("format_version", "unsupported version " + version.dump() + " (expected " +
                                 std::to_string(kCalibrationFormatVersion) + ")");
    }
    const std::string found = String(root_, "", "kind");
    if (found != CalibrationKindName(kind)) {
      Fail("kind", "is '" + found + "', expected '" + CalibrationKindName(kind) + "'");
    }
    info_.timestamp_utc = String(root_, "", "timestamp_utc");
    info_.error = Number(root_, "", "error");
    info_.error_unit = String(root_, "", "error_unit");
    values_ = &Get(root_, "", "values");
    if (!values_->is_object()) Fail("values", "is not an object");
  }

  [[noreturn]] void Fail(const std::string& field, const std::string& what) const {
    throw std::runtime_error("calibration file '" + path_ + "'" +
                             (field.empty() ? "" : ", field '" + field + "'") + ": " + what);
  }

  const json& Get(const json& parent, const std::string& prefix, const std::string& name) const {
    const auto it = parent.find(name);
    if (it == parent.end()) Fail(prefix + name, "missing");
    return *it;
  }

  double Number(const json& parent, const std::string& prefix, const std::string& name) const {
    const json& value = Get(parent, prefix, name);
    if (!value.is_number()) Fail(prefix + name, "is not a number");
    const double number = value.get<double>();
    if (!std::isfinite(number)) Fail(prefix + name, "is not finite");
    return number;
  }

  std::string String(const json& parent, const std::string& prefix, const std::string& name) const {
    const json& value = Get(parent, prefix, name);
    if (!value.is_string()) Fail(prefix + name, "is not a string");
    return value.get<std::string>();
  }

  std::vector<double> Array(const json& parent, const std::string& prefix, const std::string& name,
                            std::size_t size) const {
    const json& value = Get(parent, prefix, name);
    if (!value.is_array() || value.size() != size) {
      Fail(prefix + name, "must be an array of " + std::to_string(size) + " numbers");
    }
    std::vector<double> out;
    for (const json& element : value) {
      if (!element.is_number()) Fail(prefix + name, "holds a non-number");
      out.push_back(element.get<double>());
      if (!std::isfinite(out.back())) Fail(prefix + name, "holds a non-finite number");
    }
    return out;
  }

  const json& values() const { return *values_; }
  const CalibrationInfo& info() const { return info_; }

 private:
  std::string path_;
  json root_;
  const json* values_ = nullptr;
  CalibrationInfo info_;
};

}  // namespace

std::string CalibrationKindName(CalibrationKind kind) {
  switch (kind) {
    case CalibrationKind::kCameraIntrinsics:
      return "camera_intrinsics";
    case CalibrationKind::kProjectorIntrinsics:
      return "projector_intrinsics";
    case CalibrationKind::kCameraProjectorExtrinsics:
      return "camera_projector_extrinsics";
    case CalibrationKind::kHandEye:
      return "hand_eye";
    case CalibrationKind::kShelfPose:
      return "shelf_pose";
  }
  return "unknown";
}

void SaveIntrinsics(const std::string& path, CalibrationKind kind, const IntrinsicsFile& file) {
  if (!IsIntrinsicsKind(kind)) {
    throw std::invalid_argument("SaveIntrinsics: kind '" + CalibrationKindName(kind) +
                                "' does not hold intrinsics");
  }
  file.intrinsics.Validate();
  json j = Header(kind, file.info);
  const CameraIntrinsics& k = file.intrinsics;
  j["values"] = {
      {"width", k.width}, {"height", k.height},        {"fx", k.fx}, {"fy", k.fy}, {"cx", k.cx},
      {"cy", k.cy},       {"distortion", k.distortion}};
  WriteAtomically(path, j.dump(2) + "\n");
}

void SavePose(const std::string& path, CalibrationKind kind, const PoseFile& file) {
  if (IsIntrinsicsKind(kind)) {
    throw std::invalid_argument("SavePose: kind '" + CalibrationKindName(kind) +
                                "' does not hold a pose");
  }
  const Eigen::Matrix3d R = file.pose.linear();
  if (!file.pose.matrix().allFinite() ||
      !(R.transpose() * R).isApprox(Eigen::Matrix3d::Identity(), 1e-6) || R.determinant() < 0) {
    throw std::invalid_argument("SavePose: the pose is not a finite rigid transform");
  }
  json j = Header(kind, file.info);
  const Eigen::Quaterniond q(R);
  const Eigen::Vector3d t = file.pose.translation();
  const auto [parent, child] = Frames(kind);
  j["values"] = {{"parent_frame", parent},
                 {"child_frame", child},
                 {"translation_m", {t.x(), t.y(), t.z()}},
                 {"rotation_xyzw", {q.x(), q.y(), q.z(), q.w()}}};
  WriteAtomically(path, j.dump(2) + "\n");
}

IntrinsicsFile LoadIntrinsics(const std::string& path, CalibrationKind kind) {
  if (!IsIntrinsicsKind(kind)) {
    throw std::invalid_argument("LoadIntrinsics: kind '" + CalibrationKindName(kind) +
                                "' does not hold intrinsics");
  }
  const Reader reader(path, kind);
  const json& v = reader.values();
  IntrinsicsFile file;
  file.info = reader.info();
  CameraIntrinsics& k = file.intrinsics;
  for (const char* name : {"width", "height"}) {
    const json& value = reader.Get(v, "values.", name);
    if (!value.is_number_integer() || value.get<long long>() <= 0) {
      reader.Fail(std::string("values.") + name, "must be a positive integer");
    }
  }
  k.width = v["width"].get<std::uint32_t>();
  k.height = v["height"].get<std::uint32_t>();
  k.fx = reader.Number(v, "values.", "fx");
  k.fy = reader.Number(v, "values.", "fy");
  k.cx = reader.Number(v, "values.", "cx");
  k.cy = reader.Number(v, "values.", "cy");
  const std::vector<double> d = reader.Array(v, "values.", "distortion", 5);
  for (int i = 0; i < 5; ++i) k.distortion[i] = d[i];
  if (!(k.fx > 0.0)) reader.Fail("values.fx", "must be > 0");
  if (!(k.fy > 0.0)) reader.Fail("values.fy", "must be > 0");
  return file;
}

PoseFile LoadPose(const std::string& path, CalibrationKind kind) {
  if (IsIntrinsicsKind(kind)) {
    throw std::invalid_argument("LoadPose: kind '" + CalibrationKindName(kind) +
                                "' does not hold a pose");
  }
  const Reader reader(path, kind);
  const json& v = reader.values();
  PoseFile file;
  file.info = reader.info();
  const auto [parent, child] = Frames(kind);
  if (reader.String(v, "values.", "parent_frame") != parent) {
    reader.Fail("values.parent_frame", std::string("must be '") + parent + "'");
  }
  if (reader.String(v, "values.", "child_frame") != child) {
    reader.Fail("values.child_frame", std::string("must be '") + child + "'");
  }
  const std::vector<double> t = reader.Array(v, "values.", "translation_m", 3);
  const std::vector<double> q = reader.Array(v, "values.", "rotation_xyzw", 4);
  Eigen::Quaterniond quaternion(q[3], q[0], q[1], q[2]);
  if (std::abs(quaternion.norm() - 1.0) > 1e-6) {
    reader.Fail("values.rotation_xyzw",
                "is not a unit quaternion (norm " + std::to_string(quaternion.norm()) + ")");
  }
  quaternion.normalize();
  file.pose = Eigen::Isometry3d::Identity();
  file.pose.linear() = quaternion.toRotationMatrix();
  file.pose.translation() = Eigen::Vector3d(t[0], t[1], t[2]);
  return file;
}

}  // namespace picking::scanner
