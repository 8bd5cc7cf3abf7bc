#pragma once

#include <Eigen/Geometry>

#include <vector>

namespace picking::planner {

/// Which of a scan's voxels an item's box touches.
///
/// A picked item starts in contact with the scan: it rests on other items, leans on them, or
/// lies partly under a neighbour's curved flank, and its box (larger than the item) reaches
/// into their voxels. No motion of the item is then free by a clearance test, yet a motion
/// that only draws the item away from what it already touches disturbs nothing more than
/// the pick itself does. This tells the two apart: the voxels touched at the grasp are
/// allowed along a lift or a slide, any other voxel the box comes near is a new contact.
///
/// A voxel touches the box when its centre lies within the voxel's half diagonal plus
/// `margin_m` of the box (a sphere around the cube: never misses a cube that meets the box).
class VoxelContacts final {
 public:
  /// `centres_Base`: the occupied voxels' centres (ScanObstacles::voxel_centres_Base; kept
  /// by reference, so they must outlive this); `voxel_m`: their edge. Throws
  /// std::invalid_argument for a non-positive or non-finite edge or a negative margin.
  VoxelContacts(const std::vector<Eigen::Vector3f>& centres_Base, double voxel_m, double margin_m);

  /// Indices (ascending) of the voxels touching the box `box_Item` at X_BaseItem.
  std::vector<int> Touching(const Eigen::Isometry3d& X_BaseItem,
                            const Eigen::AlignedBox3d& box_Item) const;

  /// The first voxel touching the box that is not in `allowed` (ascending indices, as from
  /// Touching), or -1 when there is none.
  int NewContact(const Eigen::Isometry3d& X_BaseItem, const Eigen::AlignedBox3d& box_Item,
                 const std::vector<int>& allowed) const;

  const Eigen::Vector3f& centre(int index) const { return (*centres_Base_)[index]; }
  std::size_t size() const { return centres_Base_->size(); }

 private:
  template <typename Visit>
  void ForEachTouching(const Eigen::Isometry3d& X_BaseItem, const Eigen::AlignedBox3d& box_Item,
                       Visit&& visit) const;

  const std::vector<Eigen::Vector3f>* centres_Base_;
  double reach_m_;  // half diagonal + margin
};

}  // namespace picking::planner
