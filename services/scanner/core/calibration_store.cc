#include "services/scanner/core/calibration_store.h"

#include <chrono>
#include <ctime>
#include <filesystem>
#include <stdexcept>

namespace picking::scanner {
namespace {

namespace fs = std::filesystem;

const char* FileName(CalibrationKind kind) {
  switch (kind) {
    case CalibrationKind::kCameraIntrinsics:
      return "camera_intrinsics.json";
    case CalibrationKind::kProjectorIntrinsics:
      return "projector_intrinsics.json";
    case CalibrationKind::kCameraProjectorExtrinsics:
      return "camera_projector.json";
    case CalibrationKind::kHandEye:
      return "hand_eye.json";
    case CalibrationKind::kShelfPose:
      return "shelf_pose.json";
  }
  throw std::invalid_argument("unknown calibration kind");
}

std::string Stamp() {
  const auto now = std::chrono::system_clock::now();
  const std::time_t t = std::chrono::system_clock::to_time_t(now);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof(buf), "%Y%m%dT%H%M%S", &tm);
  const auto us =
      std::chrono::duration_cast<std::chrono::microseconds>(now.time_since_epoch()).count() %
      1000000;
  return std::string(buf) + "." + std::to_string(us) + "Z";
}

}  // namespace

CalibrationStore::CalibrationStore(std::string dir, std::string nominal_dir)
    : dir_(std::move(dir)), nominal_dir_(std::move(nominal_dir)) {
  if (dir_.empty()) throw std::invalid_argument("setting 'calibration.dir' is empty");
}

std::string CalibrationStore::PathOf(CalibrationKind kind) const {
  return (fs::path(dir_) / FileName(kind)).string();
}

CalibrationState CalibrationStore::Load() const {
  CalibrationState state;
  // Returns the path to load and whether it is a calibrated (not nominal) file.
  auto locate = [&](CalibrationKind kind) -> std::optional<std::pair<std::string, bool>> {
    const fs::path current = fs::path(dir_) / FileName(kind);
    if (fs::exists(current)) return std::make_pair(current.string(), true);
    if (!nominal_dir_.empty()) {
      const fs::path nominal = fs::path(nominal_dir_) / FileName(kind);
      if (fs::exists(nominal)) return std::make_pair(nominal.string(), false);
    }
    return std::nullopt;
  };
  if (auto f = locate(CalibrationKind::kCameraIntrinsics)) {
    state.camera = LoadIntrinsics(f->first, CalibrationKind::kCameraIntrinsics).intrinsics;
    state.camera_calibrated = f->second;
  }
  if (auto f = locate(CalibrationKind::kProjectorIntrinsics)) {
    state.projector = LoadIntrinsics(f->first, CalibrationKind::kProjectorIntrinsics).intrinsics;
    state.projector_calibrated = f->second;
  }
  if (auto f = locate(CalibrationKind::kCameraProjectorExtrinsics)) {
    state.X_CameraProjector = LoadPose(f->first, CalibrationKind::kCameraProjectorExtrinsics).pose;
    state.projector_calibrated = state.projector_calibrated && f->second;
  }
  if (auto f = locate(CalibrationKind::kHandEye)) {
    state.X_ToolCamera = LoadPose(f->first, CalibrationKind::kHandEye).pose;
    state.hand_eye_calibrated = f->second;
  }
  if (auto f = locate(CalibrationKind::kShelfPose)) {
    state.X_BaseShelf = LoadPose(f->first, CalibrationKind::kShelfPose).pose;
    state.shelf_calibrated = f->second;
  }
  return state;
}

std::string CalibrationStore::SaveIntrinsics(CalibrationKind kind,
                                             const IntrinsicsFile& file) const {
  fs::create_directories(fs::path(dir_) / "history");
  const std::string path = PathOf(kind);
  scanner::SaveIntrinsics(path, kind, file);
  const std::string stem = fs::path(FileName(kind)).stem().string();
  scanner::SaveIntrinsics((fs::path(dir_) / "history" / (stem + "-" + Stamp() + ".json")).string(),
                          kind, LoadIntrinsics(path, kind));
  return path;
}

std::string CalibrationStore::SavePose(CalibrationKind kind, const PoseFile& file) const {
  fs::create_directories(fs::path(dir_) / "history");
  const std::string path = PathOf(kind);
  scanner::SavePose(path, kind, file);
  const std::string stem = fs::path(FileName(kind)).stem().string();
  scanner::SavePose((fs::path(dir_) / "history" / (stem + "-" + Stamp() + ".json")).string(), kind,
                    LoadPose(path, kind));
  return path;
}

}  // namespace picking::scanner
