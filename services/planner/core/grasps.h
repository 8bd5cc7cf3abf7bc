#pragma once

#include <Eigen/Geometry>

#include <functional>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

#include "libs/apc/catalogue.h"
#include "libs/world/cell_config.h"
#include "libs/world/item_shapes.h"

namespace picking::planner {

/// One place where the suction cup may take an item, in the item frame I (origin at the centre
/// of the item's bounding box, long side along x, middle along y, short along z; metres).
struct SuctionPoint {
  std::string name;  ///< Surface name, e.g. "+z face", "side +y", "-x end".
  Eigen::Vector3d p_ItemPoint = Eigen::Vector3d::Zero();  ///< Contact point on the surface.
  /// Unit direction the cup travels to touch the surface: INTO the surface (the inward normal
  /// of a flat face). Item frame.
  Eigen::Vector3d approach_Item = -Eigen::Vector3d::UnitZ();
  /// Extent of the (nearly) flat patch around the point, larger side first, metres. For a box
  /// face its two sides, for a cylinder's side its length and diameter, for a disc or a sphere
  /// its diameter twice.
  Eigen::Vector2d face_m = Eigen::Vector2d::Zero();
  /// Per-point suction factor in (0, 1]: curvature under the cup lip (see DefaultSuctionPoints).
  double quality = 1.0;
};

/// The suction points of one item.
struct ItemGrasps {
  std::string item;
  /// The box the points refer to (long, middle, short side as modelled, i.e. after folding;
  /// see world::ModelledSize), metres. Every point lies within it.
  Eigen::Vector3d size_m = Eigen::Vector3d::Zero();
  /// Per-item suction factor in (0, 1]: porosity and flatness of the item's surface.
  double quality = 1.0;
  std::vector<SuctionPoint> points;
};

/// Thrown for an unreadable or invalid grasp table. The message names the file, the item (when
/// the problem is in one) and the field, e.g.
/// "grasp table 'grasps.yaml', item 'dasani_water_bottle', field 'points[2].approach_Item':
/// must be a unit vector (norm 0.5)".
class GraspTableError final : public std::runtime_error {
 public:
  GraspTableError(const std::string& source, const std::string& item, const std::string& field,
                  const std::string& what);
  const std::string& source() const { return source_; }
  const std::string& item() const { return item_; }
  const std::string& field() const { return field_; }

 private:
  std::string source_;
  std::string item_;
  std::string field_;
};

/// Suction points per item, read from data/planner/grasps.yaml:
///
///     version: 1
///     cup_diameter_m: 0.04
///     items:
///       i_am_a_bunny_book:
///         size_m: [0.200, 0.167, 0.004]
///         quality: 1.0                      # optional, default 1
///         points:
///           - {name: "+z face", p_ItemPoint: [0, 0, 0.002], approach_Item: [0, 0, -1],
///              face_m: [0.200, 0.167], quality: 1.0}   # point quality optional
///
/// Validation: every catalogue item is present and no other; unknown keys are errors; numbers
/// are finite; size_m and face_m are positive; approach_Item has unit norm (within 1e-3; it is
/// normalised on reading) and does not point away from the item's centre; every point lies in
/// the item box (within 1 mm); qualities are in (0, 1]; each item has at least one point.
class GraspTable final {
 public:
  /// Reads and validates a table file against `catalogue`. Throws GraspTableError.
  static GraspTable FromYamlFile(const std::string& path, const apc::Catalogue& catalogue);
  /// As FromYamlFile, from YAML text; `source_name` is used in error messages.
  static GraspTable FromYaml(const std::string& yaml_text, const std::string& source_name,
                             const apc::Catalogue& catalogue);

  /// The grasps of `item`; throws apc::UnknownItemError naming it.
  const ItemGrasps& at(const std::string& item) const;
  /// The grasps of `item`, or nullptr.
  const ItemGrasps* find(const std::string& item) const;
  const std::map<std::string, ItemGrasps>& items() const { return items_; }
  std::size_t size() const { return items_.size(); }
  /// Suction cup lip diameter the table was written for, metres.
  double cup_diameter_m() const { return cup_diameter_m_; }
  const std::string& source() const { return source_; }

 private:
  std::string source_;
  double cup_diameter_m_ = 0.04;
  std::map<std::string, ItemGrasps> items_;
};

/// data/planner/grasps.yaml under apc::DefaultDataDir().
std::string DefaultGraspTablePath();

/// The rule that generated the defaults of data/planner/grasps.yaml, for an item whose modelled
/// box is `size_m` (long, middle, short; metres) and whose shape is `shape`:
///
/// - box and scan: the centre of every box face whose smaller side is at least
///   `cup_diameter_m`, approached along the inward face normal; on a face whose larger side is
///   at least 4 cup diameters, also the centres of its two halves ("+z face, -x half"). When no
///   face is wide enough (e.g. a toothbrush), the faces with the largest smaller side.
/// - cylinder (the largest inside the box, axis along x or z): 8 points around the curved side
///   at mid length (every 45 deg, approached radially) if the diameter and length are at least a
///   cup diameter, and the centres of both flat ends if the diameter is.
/// - sphere (the smallest side as diameter): 14 points, along the 6 axis directions and the 8
///   cube diagonals, approached toward the centre.
///
/// Curved patches get a point quality 1 - s / (d / 2), where s is the sag of the surface under
/// a cup lip of diameter d (s = r - sqrt(r^2 - d^2 / 4)), 0.1 at the least.
/// Throws std::invalid_argument for non-positive sizes or cup diameter.
std::vector<SuctionPoint> DefaultSuctionPoints(const Eigen::Vector3d& size_m,
                                               const world::ItemShape& shape,
                                               double cup_diameter_m);

/// What the item sits in, in the base frame (metres).
enum class GraspContainerKind {
  kShelfBin,  ///< Approaches must come through the opening (max_approach_angle_rad).
  /// Open from above, the tote or the table: approaches must be near vertical
  /// (max_tote_approach_angle_rad) and lifts go straight up.
  kOpenTop,
};

/// The inner volume of a shelf bin, the tote or the space over the table.
struct GraspContainer {
  std::string name;  ///< "bin_A".."bin_L", "tote", "table"; used in messages.
  GraspContainerKind kind = GraspContainerKind::kShelfBin;
  /// Pose of the inner box's centre (axes along its sides) in the base frame.
  Eigen::Isometry3d X_BaseContainer = Eigen::Isometry3d::Identity();
  /// Inner box sides along the container frame's x, y, z, metres (all > 0).
  Eigen::Vector3d inner_size_m = Eigen::Vector3d::Zero();
  /// Unit vector in the base frame pointing OUT of the opening, toward where the gripper comes
  /// from: for a shelf bin the shelf frame's +x expressed in base, for the tote +z of base.
  Eigen::Vector3d opening_direction_Base = Eigen::Vector3d::UnitZ();
};

/// The container of shelf bin `bin` ("bin_A".."bin_L") of `cell`: its measured inner box
/// (world::BinGeometry::inner_S) placed by X_BaseShelf, opening along the shelf's +x.
/// Throws std::invalid_argument for an unknown bin.
GraspContainer ShelfBinContainer(const world::CellModel& cell, const std::string& bin);

/// The tote of `cell`: its mesh bounds in the tote frame less `wall_m` on the four sides, from
/// the floor to the rim, opening along +z of the tote frame.
GraspContainer ToteContainer(const world::CellModel& cell, double wall_m = 0.015);

/// The space over the verification table of `cell`: its top (the container's floor) by
/// `height_m`, open upward. Items are put down on it to be looked at alone and picked again.
GraspContainer TableContainer(const world::CellModel& cell, double height_m = 0.3);

/// Free distance (metres, in [0, max_m]) from `p_Base` along the unit `direction_Base`, e.g. an
/// obstacle query of the planner's collision world (which should ignore the item being taken).
/// ComputeGrasps calls it with the contact point and -approach_Base (backwards along the
/// approach), once per approach that passed the container and angle checks; results outside
/// [0, max_m] are clamped, a non-finite result is an error.
using ClearanceFunction = std::function<double(
    const Eigen::Vector3d& p_Base, const Eigen::Vector3d& direction_Base, double max_m)>;

/// The suction cup seals on a flat surface met at up to this angle between the surface's
/// normal and the cup's axis. It is the cell's value, which the simulator enforces
/// (SimOptions::seal_angle_tolerance_rad in services/simulator/core/sim_world.h);
/// test_planner_pick fails if the two differ. Radians.
inline constexpr double kSealAngleToleranceRad = 0.35;
/// What the planner keeps in hand below kSealAngleToleranceRad when it tilts the cup off a
/// surface's normal: the item's detected orientation is a few degrees off at worst, and a
/// plan whose cup cannot seal is worse than a refusal. Radians.
inline constexpr double kSealAngleMarginRad = 0.05;

/// Options of ComputeGrasps. Angles in radians, lengths in metres.
struct GraspOptions {
  /// The pre-grasp stands this far back from the grasp along -approach.
  double pregrasp_standoff_m = 0.10;
  /// Shelf bins: largest angle between the reversed approach and the opening direction. Wide
  /// enough for a top face tilted by max_tilt_rad (73 deg): whether the straight tube can
  /// stand at such a grasp inside the bin is the planner's tube test (CheckTubeReach), which
  /// says why not in the bin's own measures.
  double max_approach_angle_rad = 80.0 * EIGEN_PI / 180.0;
  /// Tote: largest angle between the reversed approach and the opening (+z) direction.
  double max_tote_approach_angle_rad = 25.0 * EIGEN_PI / 180.0;
  /// The foam lip seals on a surface met at an angle: besides the surface normal, each point
  /// is tried with the approach tilted toward the ideal approach (-opening direction) by
  /// max_tilt_rad * k / tilt_steps, k = 1..tilt_steps, never past the ideal approach
  /// (max_tilt_rad = 0 or tilt_steps = 0 disable tilting). At most kSealAngleToleranceRad
  /// (CheckOptions refuses more): the cup would not seal. Less in practice: a tilted cup
  /// meets the face with one side of its lip first and the guarded move stops when that
  /// side is pressed to the force threshold, so the far side must then be within the lip's
  /// reach: with the cell's 3 cm lip, 5 mm of compression at 10 N and 4 mm of reach, a face
  /// tilted past asin(9 / 30) = 17.5 deg does not seal however small the seal angle's limit
  /// (measured: every 17.2 deg grasp of pick_layout_1..3 missed its seal). 0.21 rad (12
  /// deg) leaves the detected orientation's few degrees.
  double max_tilt_rad = 0.21;
  int tilt_steps = 2;
  /// In a shelf bin, an approach within this angle of horizontal is also tried pitched down
  /// by the same tilts (the tube rising toward the opening, over the floor's front lip).
  double max_pitch_from_horizontal_rad = 30.0 * EIGEN_PI / 180.0;
  /// Shelf bins: a point at the centre of a box face (listed with the face's full size) is
  /// also tried moved across the face toward the opening, as far as the whole cup stays on the
  /// face with this margin to its edge (the detected pose's error), when that is at least
  /// min_shift_toward_opening_m. A flat item lying deep in a bin is then taken near its front
  /// edge, where the bent head's tube reaches from outside the opening: the UR10's wrist,
  /// stacked 0.23 m tall with the tube level, does not fit into a bin. Negative: off.
  double edge_margin_toward_opening_m = 0.005;
  double min_shift_toward_opening_m = 0.02;
  /// Points further than this outside the container's inner box are rejected.
  double container_tolerance_m = 0.01;
  /// Candidates with less free distance behind the point than this are rejected (blocked).
  double min_clearance_m = 0.03;
  /// Clearance at which the clearance score reaches 1.
  double required_clearance_m = 0.10;
  /// Longest clearance looked for (passed to `clearance` as max_m).
  double max_clearance_m = 0.30;
  /// Smaller face side at which the face-size score reaches 1 (two cup diameters).
  double full_face_size_m = 0.08;
  /// An approach within this angle of base +-z is near vertical (roll reference base +x),
  /// otherwise near horizontal (roll reference base -z).
  double vertical_roll_threshold_rad = 45.0 * EIGEN_PI / 180.0;
  /// Exponents of the score components (see GraspScore), each >= 0.
  double face_size_weight = 1.0;
  double centrality_weight = 0.5;
  double clearance_weight = 1.0;
  double approach_weight = 1.0;
  double tilt_weight = 2.0;
  /// Free distance behind a point. Empty: the distance to leave the container's inner box along
  /// -approach, or max_clearance_m if it leaves through the opening face.
  ClearanceFunction clearance;
};

/// Score components of a candidate, each in [0, 1].
///
///     total = quality * face_size^w_f * centrality^w_c * clearance^w_cl * approach^w_a
///             * tilt^w_t
///
/// with the weights of GraspOptions.
struct GraspScore {
  double total = 0.0;
  /// Item quality times point quality (the table's porosity / flatness / curvature factors).
  double quality = 0.0;
  /// min(1, smaller side of the point's face / full_face_size_m).
  double face_size = 0.0;
  /// 1 - (distance of the item centre from the line through the point along the surface
  /// normal) / (half the item box diagonal): 1 when the cup pulls through the centre.
  double centrality = 0.0;
  /// min(1, clearance_m / required_clearance_m).
  double clearance = 0.0;
  /// max(0, cos(angle between -approach and the opening direction)).
  double approach = 0.0;
  /// cos(tilt between the approach and the surface normal).
  double tilt = 0.0;
};

/// One suction grasp in the base frame.
struct GraspCandidate {
  std::string surface;  ///< SuctionPoint::name.
  int point_index = 0;  ///< Index into ItemGrasps::points.
  /// The tool centre point (the cup's lip centre) at the contact point, +z_tcp along
  /// approach_Base. Roll about z_tcp: x_tcp is the projection of base -z on the plane normal to
  /// the approach for a near-horizontal approach, of base +x for a near-vertical one (see
  /// GraspOptions::vertical_roll_threshold_rad).
  Eigen::Isometry3d X_BaseTcp = Eigen::Isometry3d::Identity();
  /// X_BaseTcp moved back along -approach_Base by pregrasp_standoff_m.
  Eigen::Isometry3d X_BaseTcpPreGrasp = Eigen::Isometry3d::Identity();
  /// Suction is symmetric about the approach axis: the planner may roll X_BaseTcp (and the
  /// pre-grasp) freely about its z axis.
  bool roll_symmetric = true;
  Eigen::Vector3d p_BasePoint = Eigen::Vector3d::Zero();    ///< Contact point.
  Eigen::Vector3d approach_Base = Eigen::Vector3d::Zero();  ///< Unit, direction the cup travels.
  /// The table's approach (the inward surface normal) in base; approach_Base is this, tilted.
  Eigen::Vector3d surface_approach_Base = Eigen::Vector3d::Zero();
  double tilt_rad = 0.0;            ///< Angle between approach_Base and surface_approach_Base.
  double approach_angle_rad = 0.0;  ///< Angle between -approach_Base and the opening direction.
  double clearance_m = 0.0;         ///< Free distance behind the point (capped).
  GraspScore score;
};

/// Why a candidate was rejected.
enum class GraspRejection {
  kOutsideContainer,  ///< The point is outside the container's inner box.
  kApproachAngle,     ///< The approach comes from behind the opening (angle above the limit).
  kBlocked,           ///< Less free distance behind the point than min_clearance_m.
};

/// Human-readable name of a rejection ("outside container", ...).
const char* GraspRejectionName(GraspRejection reason);

/// A rejected candidate.
struct RejectedGrasp {
  std::string surface;
  int point_index = 0;
  double tilt_rad = 0.0;
  GraspRejection reason = GraspRejection::kApproachAngle;
  std::string detail;  ///< E.g. "angle 90.0 deg > 70.0 deg".
};

/// Result of ComputeGrasps.
struct GraspResult {
  std::string item;
  std::string container;
  /// Accepted candidates, best (highest score.total) first; ties keep the table order.
  std::vector<GraspCandidate> candidates;
  /// Rejected candidates: one entry per point outside the container (its tilts are not tried),
  /// otherwise one per (point, tilt) approach.
  std::vector<RejectedGrasp> rejected;
  int rejected_outside_container = 0;
  int rejected_approach_angle = 0;
  int rejected_blocked = 0;
  /// Empty when there are candidates; otherwise why not and what to change.
  std::string reason;

  bool empty() const { return candidates.empty(); }
  const GraspCandidate& best() const { return candidates.front(); }  ///< Precondition: !empty().
};

/// Suction grasps of `item` at X_BaseItem (its item frame in the base frame) in `container`.
///
/// Every point of the item's table entry is tried with its surface normal approach and with
/// tilted approaches (GraspOptions::max_tilt_rad); a candidate is rejected when the point lies
/// outside the container box, the approach comes from behind the opening or the point is
/// blocked. Throws apc::UnknownItemError for an item not in the table, std::invalid_argument
/// for a non-finite or non-rigid X_BaseItem, an invalid container (non-positive size, opening
/// direction not unit, pose not rigid) or invalid options, std::runtime_error if the clearance
/// callback returns a non-finite value.
GraspResult ComputeGrasps(const GraspTable& table, const std::string& item,
                          const Eigen::Isometry3d& X_BaseItem, const GraspContainer& container,
                          const GraspOptions& options = {});

}  // namespace picking::planner
