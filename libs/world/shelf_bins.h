#pragma once

#include <Eigen/Geometry>

#include <string>
#include <vector>

#include "libs/world/mesh.h"

namespace picking::world {

/// The free volume of one shelf bin, measured from the shelf mesh, in the shelf frame S
/// (the frame of the mesh file: x out of the bins' openings, z up, metres).
struct BinGeometry {
  std::string name;  ///< "bin_A".."bin_L".
  int row = 0;       ///< 0 = top row (A-C) .. 3 = bottom row (J-L).
  int column = 0;    ///< 0 = left seen from the front (A, D, G, J) .. 2 = right.
  /// Free box of the bin: x from the back wall to the opening plane, y between the side
  /// walls (closest wall over the whole depth), z from the lowest floor point to the lowest
  /// ceiling point. Anything strictly inside does not touch the shelf except the floor where
  /// the floor is higher than `inner_S.min().z()` (see floor_max_z_m).
  Eigen::AlignedBox3d inner_S;
  /// Highest floor point over the bin's depth (the pod's boards rise slightly toward the
  /// front lip). Equal to inner_S.min().z() for a flat floor.
  double floor_max_z_m = 0.0;
  /// x of the opening plane (normal +x): the front edge of the bin floor.
  double opening_x_m = 0.0;

  double width_m() const { return inner_S.sizes().y(); }
  double height_m() const { return inner_S.sizes().z(); }
  double depth_m() const { return inner_S.sizes().x(); }
};

/// Options of MeasureBins. Defaults suit the APC 2016 Kiva pod (bins 0.25-0.30 m wide,
/// 0.22-0.27 m tall, 0.43 m deep).
struct MeasureBinsOptions {
  int rows = 4;                    ///< Rows of bins expected (top row first).
  int columns = 3;                 ///< Bins per row expected.
  double min_row_height_m = 0.15;  ///< Free vertical gaps outside [min, max] are not rows.
  double max_row_height_m = 0.35;
  double min_column_width_m = 0.18;  ///< Free horizontal gaps outside [min, max] are not bins.
  double max_column_width_m = 0.40;
  double probe_depth_fraction = 0.5;  ///< Where the scans run: fraction of the front half's
                                      ///< depth measured from the mesh's x centre.
  int depth_samples = 15;             ///< Floor/ceiling/wall rays along the depth per bin.
  int lateral_samples = 3;            ///< Floor/ceiling rays across the width per depth.
};

/// Measures the 12 bins A-L of a shelf mesh by ray casting (no dimensions are assumed).
///
/// 1. A vertical ray through the front half of the mesh at the centre of its width finds the
///    free gaps between boards; the `rows` gaps whose height is plausible are the rows.
/// 2. In each row a ray along +y at mid height finds the gaps between dividers: the columns.
/// 3. From each bin's centre, rays to the back find the back wall; rays down over the depth
///    find where the floor ends (the opening plane, refined by bisection to 0.5 mm); a grid of
///    rays down, up, left and right over the depth and width gives floor, ceiling and walls.
///
/// Bins are returned in the order A..L (row-major from the top-left seen from the front,
/// i.e. looking along -x; left is -y). Throws std::runtime_error naming the stage when the
/// mesh does not show `rows` x `columns` bins.
std::vector<BinGeometry> MeasureBins(const TriangleMesh& shelf_S,
                                     const MeasureBinsOptions& options = {});

/// The free inner box of a tote mesh in its own frame T (z up, open at the top): rays from
/// the centre of the mesh's bounds along -x, +x, -y, +y and -z find the inner walls and the
/// floor; the top is the rim (the bounds' top). Throws std::runtime_error when a ray finds no
/// wall or floor.
Eigen::AlignedBox3d MeasureToteInner(const TriangleMesh& tote_T);

/// Where a camera scans a shelf bin from: a point in front of the bin's opening, looking at
/// the middle of the bin's floor.
struct BinScanView {
  /// Sideways from the bin's middle (along the shelf's y), metres.
  double lateral_offset_m = 0.0;
  /// Above the middle of the bin's opening, metres.
  double height_above_centre_m = 0.10;
  /// In front of the bin's opening plane (along the shelf's x), metres: about the
  /// structured-light scanner's working distance.
  double standoff_m = 0.55;
  /// The point looked at is this far above the middle of the bin's floor, metres.
  double aim_above_floor_m = 0.03;
};

/// The cell's three scan views of a bin, in capture order: the middle one, then one to either
/// side. The side views are higher, so that they see over the items at the front into the back
/// of the bin, and far enough apart that each sees past the sides of the front items (the joke
/// book lying behind the command hooks in pick_layout_1's bin E shows 1,667 of its model's
/// points to these views, 628 to three views at the middle one's height 0.1 m to either side).
std::vector<BinScanView> CellBinScanViews();

/// The camera's position for `view` of `bin`, in the shelf frame.
Eigen::Vector3d BinScanEye_S(const BinGeometry& bin, const BinScanView& view);

/// The point `view` of `bin` looks at, in the shelf frame.
Eigen::Vector3d BinScanTarget_S(const BinGeometry& bin, const BinScanView& view);

}  // namespace picking::world
