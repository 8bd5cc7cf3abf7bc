#include "services/planner/core/voxel_contacts.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace picking::planner {

VoxelContacts::VoxelContacts(const std::vector<Eigen::Vector3f>& centres_Base, double voxel_m,
                             double margin_m)
    : centres_Base_(&centres_Base) {
  if (!(voxel_m > 0.0) || !std::isfinite(voxel_m)) {
    throw std::invalid_argument("the voxel edge must be positive and finite");
  }
  if (!(margin_m >= 0.0) || !std::isfinite(margin_m)) {
    throw std::invalid_argument("the contact margin must be non-negative and finite");
  }
  reach_m_ = 0.5 * std::sqrt(3.0) * voxel_m + margin_m;
}

template <typename Visit>
void VoxelContacts::ForEachTouching(const Eigen::Isometry3d& X_BaseItem,
                                    const Eigen::AlignedBox3d& box_Item, Visit&& visit) const {
  // The box's base-frame bounds grown by the reach rule most voxels out with three compares.
  Eigen::AlignedBox3d bounds_Base;
  for (int i = 0; i < 8; ++i) {
    bounds_Base.extend(X_BaseItem *
                       box_Item.corner(static_cast<Eigen::AlignedBox3d::CornerType>(i)));
  }
  const Eigen::Vector3f lo = (bounds_Base.min().array() - reach_m_).cast<float>();
  const Eigen::Vector3f hi = (bounds_Base.max().array() + reach_m_).cast<float>();
  const Eigen::Isometry3d X_ItemBase = X_BaseItem.inverse();
  const double reach_sq = reach_m_ * reach_m_;
  const std::vector<Eigen::Vector3f>& centres_Base = *centres_Base_;
  for (int i = 0; i < static_cast<int>(centres_Base.size()); ++i) {
    const Eigen::Vector3f& c = centres_Base[i];
    if ((c.array() < lo.array()).any() || (c.array() > hi.array()).any()) continue;
    const Eigen::Vector3d p_Item = X_ItemBase * c.cast<double>();
    const Eigen::Vector3d outside = (box_Item.min() - p_Item).cwiseMax(p_Item - box_Item.max());
    if (outside.cwiseMax(0.0).squaredNorm() <= reach_sq) {
      if (!visit(i)) return;
    }
  }
}

std::vector<int> VoxelContacts::Touching(const Eigen::Isometry3d& X_BaseItem,
                                         const Eigen::AlignedBox3d& box_Item) const {
  std::vector<int> touching;
  ForEachTouching(X_BaseItem, box_Item, [&](int i) {
    touching.push_back(i);
    return true;
  });
  return touching;
}

int VoxelContacts::NewContact(const Eigen::Isometry3d& X_BaseItem,
                              const Eigen::AlignedBox3d& box_Item,
                              const std::vector<int>& allowed) const {
  int found = -1;
  ForEachTouching(X_BaseItem, box_Item, [&](int i) {
    if (std::binary_search(allowed.begin(), allowed.end(), i)) return true;
    found = i;
    return false;
  });
  return found;
}

}  // namespace picking::planner
