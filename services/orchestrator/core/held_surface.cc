#include "services/orchestrator/core/held_surface.h"

#include <cmath>

namespace picking::orchestrator {

HeldSurface MeasureHeldSurface(const geometry::PointCloud& cloud_Base,
                               const Eigen::Isometry3d& X_BaseTcp,
                               const Eigen::Isometry3d& X_TcpItem, const Eigen::Vector3d& size_m,
                               const Eigen::Vector3d& p_BaseOpening,
                               const Eigen::Vector3d& n_BaseOpening,
                               const HeldSurfaceOptions& options) {
  const Eigen::Isometry3d X_ItemBase = (X_BaseTcp * X_TcpItem).inverse();
  const Eigen::Isometry3d X_TcpBase = X_BaseTcp.inverse();
  const Eigen::Vector3d half_m = 0.5 * size_m + Eigen::Vector3d::Constant(options.box_margin_m);
  const Eigen::Vector3d n = n_BaseOpening.normalized();
  const double reach2 = options.reach_m * options.reach_m;
  HeldSurface out;
  for (const Eigen::Vector3f& point : cloud_Base.points) {
    const Eigen::Vector3d p_Base = point.cast<double>();
    if (!p_Base.allFinite()) continue;
    if ((p_Base - p_BaseOpening).dot(n) < options.out_of_opening_m) continue;
    const Eigen::Vector3d p_Tcp = X_TcpBase * p_Base;
    if (p_Tcp.squaredNorm() > reach2 || p_Tcp.z() < -options.behind_lip_m) continue;
    const Eigen::Vector3d p_Item = X_ItemBase * p_Base;
    if ((p_Item.cwiseAbs().array() <= half_m.array()).all()) {
      ++out.on_item;
    } else {
      ++out.beyond;
    }
  }
  return out;
}

}  // namespace picking::orchestrator
