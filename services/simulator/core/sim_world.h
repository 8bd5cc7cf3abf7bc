#pragma once

#include <Eigen/Geometry>

#include <cmath>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "libs/apc/task.h"
#include "libs/ur10/kinematics.h"
#include "libs/world/cell_config.h"
#include "libs/world/item_models.h"
#include "libs/world/ray_scene.h"
#include "libs/world/suction_seal.h"
#include "services/simulator/core/layout.h"
#include "services/simulator/core/physics_layout.h"
#include "services/simulator/core/renderer.h"

namespace picking::simulator {

/// Container names: "bin_A".."bin_L", "tote", "gripper", "table", "outside" (anywhere else,
/// which the APC rules penalise).
inline constexpr const char* kTote = "tote";
inline constexpr const char* kGripper = "gripper";
inline constexpr const char* kTable = "table";
inline constexpr const char* kOutside = "outside";

/// Ground truth of one item instance.
struct ItemState {
  int id = 0;                                                    ///< Unique in the world, from 1.
  std::string name;                                              ///< Catalogue name.
  Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();  ///< Item frame in Base.
  std::string container;

  bool operator==(const ItemState& o) const {
    return id == o.id && name == o.name && X_BaseItem.matrix() == o.X_BaseItem.matrix() &&
           container == o.container;
  }
};

enum class EventKind {
  kAttached,  ///< The suction cup sealed on the item; it follows the cup.
  /// The item left the gripper and fell onto `container`: `drop_height_m` is how far it
  /// fell before it first touched anything (every point of it, its lowest included), the
  /// height the APC rules' drop penalty is about.
  kReleased,
  kDropped,  ///< A fall from higher than SimOptions::drop_event_height_m (penalised).
  /// The item lost its support (e.g. the item below was picked) and settled again by physics:
  /// `drop_height_m` is how far its centre fell (0 if it slid or turned without falling).
  kFell,
  kOutside,    ///< The item came to rest outside every bin, the tote, the table and gripper.
  kCollision,  ///< The arm, gripper or carried item hit the cell (see Event::detail).
};

/// One entry of the event log.
struct Event {
  std::uint64_t sequence = 0;  ///< Increasing from 1.
  EventKind kind = EventKind::kAttached;
  int item_id = 0;
  std::string item_name;
  std::string container;       ///< Where the item is after the event.
  double drop_height_m = 0.0;  ///< kReleased / kDropped / kFell: height of the fall.
  std::string detail;          ///< kCollision: what hit what.

  bool operator==(const Event& o) const {
    return sequence == o.sequence && kind == o.kind && item_id == o.item_id &&
           item_name == o.item_name && container == o.container &&
           drop_height_m == o.drop_height_m && detail == o.detail;
  }
};

/// Everything that changes in the world, for snapshots and comparisons.
struct SimState {
  std::vector<ItemState> items;
  Eigen::Isometry3d X_BaseTcp = Eigen::Isometry3d::Identity();  ///< The suction cup (TCP).
  std::optional<ur10::JointVector> q_rad;
  bool vacuum_on = false;
  int attached_item_id = 0;                                     ///< 0: none.
  Eigen::Isometry3d X_TcpItem = Eigen::Isometry3d::Identity();  ///< The attached item.
  std::vector<Event> events;
  double head_angle_rad = 0.0;  ///< The gripper's head on its servo joint (0: straight).

  bool operator==(const SimState& o) const {
    return items == o.items && X_BaseTcp.matrix() == o.X_BaseTcp.matrix() && q_rad == o.q_rad &&
           vacuum_on == o.vacuum_on && attached_item_id == o.attached_item_id &&
           X_TcpItem.matrix() == o.X_TcpItem.matrix() && events == o.events &&
           head_angle_rad == o.head_angle_rad;
  }
  bool operator!=(const SimState& o) const { return !(*this == o); }
};

/// Physical parameters of the simulated gripper and world. The gripper's tool centre point
/// (X_ToolTcp) is the cell's (world::CellConfig::gripper).
struct SimOptions {
  double cup_radius_m = 0.015;                ///< Radius of the cup's lip.
  int rim_samples = 16;                       ///< Points on the lip tested for contact and seal.
  double contact_stiffness_n_per_m = 2000.0;  ///< Spring of the compliant cup (bellows).
  double contact_force_threshold_n = 10.0;    ///< A guarded move stops at this force.
  double seal_flatness_tolerance_m = 0.002;   ///< Max deviation of lip points from a plane.
  double seal_angle_tolerance_rad = 0.35;     ///< Max angle between surface normal and -z_tcp.
  double seal_max_gap_m = 0.004;     ///< Lip points may be at most this far in front of the cup.
  double seal_lookback_m = 0.02;     ///< Surfaces up to this far behind the lip (compressed cup).
  double drop_event_height_m = 0.3;  ///< Falls above this are recorded as kDropped.
  /// After a pick, an item of the container that the physics moved by more than this much
  /// (its centre, or its turn) fell: it gets its new pose and a kFell event. Smaller moves
  /// are the solver's jitter on a pile at rest and leave the item where it was.
  double fell_threshold_m = 0.005;
  double fell_threshold_rad = 3.0 * M_PI / 180.0;
};

/// Result of a guarded move along the TCP's +z axis.
struct GuardedMoveResult {
  bool contact = false;        ///< The force threshold was reached.
  double travelled_m = 0.0;    ///< Distance moved along +z_tcp.
  double force_n = 0.0;        ///< Spring force at the end (k * penetration).
  int contact_item_id = 0;     ///< Item touched (0: none or a static object).
  std::string contact_object;  ///< Item name, "shelf", "tote", "table", or empty.
  Eigen::Vector3d p_BaseContact = Eigen::Vector3d::Zero();  ///< First contact point.
};

/// What a probe touched.
enum class ContactSurface {
  kNone,  ///< No contact.
  kItem,  ///< An item (ProbeResult::item_id).
  kShelf,
  kTote,
  kTable,
};

/// Where the cup first touches along a straight motion (SimWorld::Probe).
struct ProbeResult {
  bool contact = false;     ///< A surface lies within the probed distance.
  double distance_m = 0.0;  ///< Travel until the first lip or centre point touches.
  ContactSurface surface = ContactSurface::kNone;  ///< What is touched.
  int item_id = 0;                                 ///< Item touched (0: none or a static object).
  std::string object;  ///< Item name, "shelf", "tote", "table", or empty.
  Eigen::Vector3d p_BaseContact = Eigen::Vector3d::Zero();  ///< First contact point.
  Eigen::Vector3d n_Base = Eigen::Vector3d::Zero();         ///< Surface normal there.
};

/// Result of switching the vacuum on.
struct SuctionResult {
  bool sealed = false;       ///< Every lip point met one flat surface facing the cup.
  int attached_item_id = 0;  ///< The sealed item (0 when sealed on a static object).
  double flatness_m = 0.0;   ///< Max deviation of the lip hits from their plane.
  double angle_rad = 0.0;    ///< Angle between surface normal and -z_tcp.
  std::string reason;        ///< Why there is no seal, when sealed is false.
};

/// The simulated APC cell: static shelf / tote / table, the items with their poses and
/// containers, the suction cup's pose (the TCP: X_BaseTcp; the flange, X_BaseTool, is
/// X_BaseTcp * X_ToolTcp^-1 with the cell's gripper), contact, suction, falling and the event
/// log.
///
/// Every request is validated before anything changes: on an exception the state is exactly
/// as before. Not thread safe (one owner; the service adapter serialises requests).
class SimWorld final {
 public:
  /// `models` must hold every item used later. `kinematics` (optional) enables
  /// SetJointPositions. Throws std::invalid_argument for bad options or a cell whose
  /// gripper's X_ToolTcp is not rigid.
  SimWorld(world::CellModel cell, std::shared_ptr<const world::ItemModelLibrary> models,
           SimOptions options = {},
           std::shared_ptr<const ur10::Ur10Kinematics> kinematics = nullptr);
  ~SimWorld();

  /// Replaces every item by the layout of `task` (bins and tote) drawn with `seed` (tidy or
  /// settled by physics: layout.mode), clears the event log, releases the gripper. Throws
  /// LayoutError (naming the bin) or apc::UnknownItemError; then nothing changes.
  void LoadTask(const apc::Task& task, std::uint32_t seed, const LayoutOptions& layout = {});

  /// Adds one item resting in `container` (a bin or "tote") beside what is there. Returns
  /// its id. Throws apc::UnknownItemError, LayoutError (unknown container or no room).
  int AddItem(const std::string& name, const std::string& container, std::uint32_t seed);

  /// Moves the suction cup (the TCP) to X_BaseTcp; an attached item follows. No collision
  /// checking (the planner's job). Forgets the arm's joints. Throws std::invalid_argument for
  /// a non-finite or non-rigid pose.
  void SetTcpPose(const Eigen::Isometry3d& X_BaseTcp);

  /// Sets the arm's joints: X_BaseTcp = FK(q) * X_ToolTcp. Throws std::logic_error without
  /// kinematics, std::invalid_argument for non-finite angles.
  void SetJointPositions(const ur10::JointVector& q_rad);

  /// Turns the gripper's head on its servo joint (the cell's gripper; 0: straight): the
  /// flange stays, the cup and an attached item move with the head. No collision checking.
  /// Throws std::invalid_argument for a non-finite angle or one outside the servo's range.
  void SetHeadAngle(double head_angle_rad);
  double head_angle_rad() const { return head_angle_rad_; }

  /// Moves the cup along the TCP's +z axis by up to `max_distance_m` (> 0), stopping where
  /// the cup (centre and lip points) pressed on the first surface reaches the force
  /// threshold. Throws std::invalid_argument for a non-positive or non-finite distance.
  GuardedMoveResult GuardedMove(double max_distance_m);

  /// Where the cup (centre and lip points) at X_BaseTcp first touches a surface when moved
  /// along the unit `direction_Base` by up to `max_distance_m` (> 0); the attached item is
  /// ignored. Changes nothing. Throws std::invalid_argument for a bad pose, a non-finite or
  /// zero direction or a non-positive distance.
  ProbeResult Probe(const Eigen::Isometry3d& X_BaseTcp, const Eigen::Vector3d& direction_Base,
                    double max_distance_m) const;

  /// Appends a kCollision event with `detail` (the arm is checked by ArmCollisionChecker).
  void LogCollision(const std::string& detail);

  /// Vacuum on: seals if the lip meets one flat surface facing the cup; a sealed item is
  /// attached (it follows the cup, X_TcpItem kept). Already attached: returns the seal. Once
  /// the attached item has left the box it occupied (SetTcpPose), the items it supported in
  /// the bin or tote it came from settle again by physics (PhysicsLayout::Resettle): each one
  /// moved by more than the fell thresholds gets its new pose and a kFell event.
  SuctionResult SuctionOn();

  /// Whether the cup would seal with its lip at X_BaseTcp (SuctionOn's test), changing
  /// nothing: the attached item is part of the scene.
  world::SealMeasure SealAt(const Eigen::Isometry3d& X_BaseTcp) const;
  /// The cup's seal parameters (cup_radius_m and the seal_* options of `options`) as
  /// world::MeasureSeal takes them.
  static world::SealOptions SealOptionsOf(const SimOptions& options);

  /// Vacuum off: an attached item is released. Over a bin or the tote (its whole box within
  /// the container's walls, seen from above) it falls by physics on to what lies below and
  /// settles there (PhysicsLayout::Release; the items already there stay); elsewhere it falls
  /// on to the highest support under it, turned onto its nearest face. Logs kReleased with
  /// the fall until first contact, and kDropped / kOutside where they apply. Returns the
  /// released item's id (0: none).
  int SuctionOff();

  /// Teleports an item (tests, scripted scenarios); its container is re-derived from the
  /// pose. Throws std::out_of_range for an unknown id, std::invalid_argument for a bad pose
  /// or an item in the gripper.
  void SetItemPose(int item_id, const Eigen::Isometry3d& X_BaseItem);

  /// Ground truth.
  const std::vector<ItemState>& items() const { return items_; }
  /// Throws std::out_of_range naming the id.
  const ItemState& item(int item_id) const;
  /// Items currently in `container`; throws std::invalid_argument for an unknown container.
  std::vector<ItemState> ItemsIn(const std::string& container) const;
  const std::vector<Event>& events() const { return events_; }
  /// The suction cup (TCP) in Base.
  const Eigen::Isometry3d& X_BaseTcp() const { return X_BaseTcp_; }
  /// The UR10's flange in Base: X_BaseTcp * X_ToolTcp^-1.
  Eigen::Isometry3d X_BaseTool() const { return X_BaseTcp_ * X_ToolTcp().inverse(); }
  /// The TCP in the flange frame: the cell's gripper's, with its head at head_angle_rad().
  Eigen::Isometry3d X_ToolTcp() const { return cell_.config.gripper.X_ToolTcpAt(head_angle_rad_); }
  bool vacuum_on() const { return vacuum_on_; }
  int attached_item_id() const { return attached_; }
  SimState state() const;

  /// Current meshes with their poses in Base: shelf, tote, table, then every item, for the
  /// renderer. The pointers stay valid until the item set changes (LoadTask / AddItem).
  std::vector<SceneObject> SceneMeshes() const;
  /// Names parallel to SceneMeshes(): "shelf", "tote", "table", then item names.
  std::vector<std::string> SceneNames() const;

  const world::CellModel& cell() const { return cell_; }
  const world::ItemModelLibrary& models() const { return *models_; }
  const SimOptions& options() const { return options_; }
  bool has_kinematics() const { return kinematics_ != nullptr; }
  /// The UR10 kinematics given at construction; throws std::logic_error without.
  const ur10::Ur10Kinematics& kinematics() const;
  /// The model of an item instance.
  const world::ItemModel& model(int item_id) const;

  /// Container of an item at X_BaseItem from geometry alone (box centre inside a bin's free
  /// box, the tote's inner box (CellModel::tote_inner_T), or above the table top); "outside"
  /// otherwise.
  std::string ClassifyContainer(const world::ItemModel& model,
                                const Eigen::Isometry3d& X_BaseItem) const;

 private:
  enum : int { kShelfId = -2, kToteId = -3, kTableId = -4 };
  void ValidatePose(const Eigen::Isometry3d& X, const std::string& what) const;
  const world::RayScene& ItemScene() const;  // items + static, rebuilt when dirty
  void MarkMoved() { item_scene_.reset(); }
  // Highest support below the footprint of `model` at X_BaseItem (excluding `self_id`),
  // searched from `from_z` down; returns its z (Base), at least the floor.
  double SupportBelow(int self_id, const world::ItemModel& model,
                      const Eigen::Isometry3d& X_BaseItem, double from_z) const;
  // Turns the item onto its nearest face and puts it on the highest support under it (for a
  // fall outside the bins and the tote, which the physics does not simulate); returns how far
  // its lowest point fell.
  double RestOnSupport(ItemState& item);
  // Logs `kind`, then kDropped and kOutside where they apply.
  void LogFall(EventKind kind, const ItemState& item, double drop_height_m);
  // The physics of one bin or the tote, built on first use.
  const PhysicsLayout& Physics() const;
  // Lets the items of `container` (a bin or the tote) settle again by physics: those that
  // `removed` supported (a pick), or item `released_id` let go there; logs kReleased and
  // kFell events.
  void SettleContainer(const std::string& container, const PlacedItem* removed, int released_id);
  void Log(EventKind kind, const ItemState& item, double drop_height_m);
  ItemState& Mutable(int item_id);

  world::CellModel cell_;
  std::shared_ptr<const world::ItemModelLibrary> models_;
  SimOptions options_;
  std::shared_ptr<const ur10::Ur10Kinematics> kinematics_;
  std::unique_ptr<world::RayScene> static_scene_;
  mutable std::unique_ptr<world::RayScene> item_scene_;
  std::vector<ItemState> items_;
  std::vector<std::shared_ptr<const world::ItemModel>> item_models_;  // parallel to items_
  Eigen::Isometry3d X_BaseTcp_ = Eigen::Isometry3d::Identity();
  double head_angle_rad_ = 0.0;
  std::optional<ur10::JointVector> q_rad_;
  bool vacuum_on_ = false;
  int attached_ = 0;
  Eigen::Isometry3d X_TcpItem_ = Eigen::Isometry3d::Identity();
  // The attached item as it lay when picked (its container and pose) and its bounds then:
  // once it has left that box, the items it supported settle again.
  std::optional<Eigen::AlignedBox3d> pending_settle_box_;
  PlacedItem pending_settle_item_;
  mutable std::unique_ptr<PhysicsLayout> physics_;
  std::vector<Event> events_;
  std::vector<LayoutRegion> regions_;
};

}  // namespace picking::simulator
