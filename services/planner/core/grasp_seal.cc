#include "services/planner/core/grasp_seal.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace picking::planner {

void ModelSeal::Validate(const ModelSealOptions& options) {
  world::ValidateSealOptions(options.seal);
  if (!(options.press_m >= 0.0) || !(options.probe_back_m >= 0.0) ||
      !(options.probe_ahead_m > 0.0) || options.shift_directions < 1) {
    throw std::invalid_argument(
        "ModelSeal: press_m and probe_back_m >= 0, probe_ahead_m > 0, shift_directions >= 1");
  }
  for (const double d : options.shift_m) {
    if (!(d > 0.0)) throw std::invalid_argument("ModelSeal: shift_m must be > 0");
  }
}

ModelSeal::ModelSeal(const world::TriangleMesh& mesh_Item, const ModelSealOptions& options)
    : options_(options) {
  Validate(options_);
  if (mesh_Item.triangles.empty()) throw std::invalid_argument("ModelSeal: the mesh is empty");
  scene_Item_.Add(0, mesh_Item, Eigen::Isometry3d::Identity());
  scene_Item_.Commit();
}

std::optional<world::SealMeasure> ModelSeal::PressAndMeasure(
    const Eigen::Isometry3d& X_ItemTcp) const {
  // The first contact of the cup's centre or lip, as the guarded move meets the surface.
  const Eigen::Vector3d z = X_ItemTcp.linear().col(2);
  Eigen::Isometry3d X_start = X_ItemTcp;
  X_start.translation() -= options_.probe_back_m * z;
  const std::optional<world::RayHit> first = world::CupFirstContact(
      scene_Item_, X_start, z, options_.probe_back_m + options_.probe_ahead_m,
      options_.seal.cup_radius_m, options_.seal.rim_samples);
  if (!first) return std::nullopt;
  Eigen::Isometry3d X_pressed = X_start;
  X_pressed.translation() += (first->distance_m + options_.press_m) * z;
  return world::MeasureSeal(scene_Item_, X_pressed, options_.seal);
}

ModelSealResult ModelSeal::Check(const Eigen::Isometry3d& X_BaseItem,
                                 const Eigen::Isometry3d& X_BaseTcp) const {
  const Eigen::Isometry3d X_ItemTcp = X_BaseItem.inverse() * X_BaseTcp;
  ModelSealResult result;
  const std::optional<world::SealMeasure> planned = PressAndMeasure(X_ItemTcp);
  if (planned) {
    result.measure = *planned;
    result.sealed = planned->sealed;
  } else {
    result.measure.reason = "the cup meets nothing of the item along its approach";
  }
  if (result.sealed) return result;
  // Nearest first: each ring of shifts across the approach, its directions in turn.
  const Eigen::Vector3d x = X_ItemTcp.linear().col(0), y = X_ItemTcp.linear().col(1);
  for (const double d : options_.shift_m) {
    for (int k = 0; k < options_.shift_directions; ++k) {
      const double a = 2 * M_PI * k / options_.shift_directions;
      const Eigen::Vector3d shift_Item = d * (std::cos(a) * x + std::sin(a) * y);
      Eigen::Isometry3d X_shifted = X_ItemTcp;
      X_shifted.translation() += shift_Item;
      const auto moved = PressAndMeasure(X_shifted);
      if (moved && moved->sealed) {
        result.sealed = true;
        result.shift_Base = X_BaseItem.linear() * shift_Item;
        result.measure = *moved;
        return result;
      }
    }
  }
  return result;
}

}  // namespace picking::planner
