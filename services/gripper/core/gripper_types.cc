#include "services/gripper/core/gripper_types.h"

#include <stdexcept>

namespace picking::gripper {

GripperKind GripperKindFromName(std::string_view name, std::string_view field) {
  if (name == "shelf") return GripperKind::kShelf;
  if (name == "tote") return GripperKind::kTote;
  throw std::invalid_argument(std::string(field) + ": unknown gripper kind '" + std::string(name) +
                              "' (expected shelf or tote)");
}

std::string_view GripperKindName(GripperKind kind) {
  return kind == GripperKind::kShelf ? "shelf" : "tote";
}

std::string_view JointModeName(JointMode mode) {
  switch (mode) {
    case JointMode::kUnactuated:
      return "unactuated";
    case JointMode::kFixed:
      return "fixed";
    case JointMode::kKeepVertical:
      return "keep_vertical";
  }
  return "unknown";
}

}  // namespace picking::gripper
