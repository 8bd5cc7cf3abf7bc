#include "services/simulator/core/sim_world.h"

#include <Eigen/SVD>

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "libs/apc/bins.h"
#include "libs/world/mesh_utils.h"
#include "services/simulator/core/physics_layout.h"

namespace picking::simulator {
namespace {

bool IsRigid(const Eigen::Isometry3d& X) {
  if (!X.matrix().allFinite()) return false;
  const Eigen::Matrix3d R = X.linear();
  return (R.transpose() * R - Eigen::Matrix3d::Identity()).norm() < 1e-6 &&
         std::abs(R.determinant() - 1.0) < 1e-6;
}

}  // namespace

SimWorld::SimWorld(world::CellModel cell, std::shared_ptr<const world::ItemModelLibrary> models,
                   SimOptions options, std::shared_ptr<const ur10::Ur10Kinematics> kinematics)
    : cell_(std::move(cell)),
      models_(std::move(models)),
      options_(options),
      kinematics_(std::move(kinematics)) {
  if (!models_) throw std::invalid_argument("SimWorld: no item model library");
  if (!(options_.cup_radius_m > 0) || options_.rim_samples < 3 ||
      !(options_.contact_stiffness_n_per_m > 0) || !(options_.contact_force_threshold_n > 0) ||
      !(options_.seal_flatness_tolerance_m > 0) || !(options_.seal_angle_tolerance_rad > 0) ||
      !(options_.seal_max_gap_m >= 0) || !(options_.seal_lookback_m >= 0) ||
      !(options_.drop_event_height_m > 0) || !(options_.fell_threshold_m > 0) ||
      !(options_.fell_threshold_rad > 0)) {
    throw std::invalid_argument(
        "SimOptions: cup_radius_m, stiffness, force threshold, tolerances, drop height and fell "
        "thresholds must be positive, rim_samples >= 3");
  }
  if (!IsRigid(cell_.config.gripper.X_ToolTcp)) {
    throw std::invalid_argument("SimWorld: the cell's gripper.X_ToolTcp is not a rigid transform");
  }
  static_scene_ = std::make_unique<world::RayScene>();
  static_scene_->Add(kShelfId, cell_.shelf, cell_.config.X_BaseShelf);
  static_scene_->Add(kToteId, cell_.tote, cell_.config.X_BaseTote);
  static_scene_->Add(kTableId, cell_.table, cell_.config.X_BaseTable);
  static_scene_->Commit();
  regions_ = LayoutRegions(cell_, LayoutOptions{});
}

SimWorld::~SimWorld() = default;

void SimWorld::ValidatePose(const Eigen::Isometry3d& X, const std::string& what) const {
  if (!X.matrix().allFinite()) throw std::invalid_argument(what + ": pose is not finite");
  if (!IsRigid(X)) throw std::invalid_argument(what + ": pose is not a rigid transform");
}

void SimWorld::LoadTask(const apc::Task& task, std::uint32_t seed, const LayoutOptions& layout) {
  // Either may throw: nothing has changed yet.
  const std::vector<PlacedItem> placed =
      layout.mode == LayoutMode::kSettled
          ? Physics().Settle(task, seed).items
          : LayoutPlanner(cell_, *models_, *static_scene_, layout).Plan(task, seed);
  std::vector<ItemState> items;
  std::vector<std::shared_ptr<const world::ItemModel>> item_models;
  int id = 0;
  for (const PlacedItem& p : placed) {
    items.push_back({++id, p.name, p.X_BaseItem, p.container});
    item_models.push_back(models_->Get(p.name));
  }
  items_ = std::move(items);
  item_models_ = std::move(item_models);
  events_.clear();
  vacuum_on_ = false;
  attached_ = 0;
  X_TcpItem_ = Eigen::Isometry3d::Identity();
  pending_settle_box_.reset();
  MarkMoved();
}

const PhysicsLayout& SimWorld::Physics() const {
  if (!physics_) physics_ = std::make_unique<PhysicsLayout>(cell_, *models_);
  return *physics_;
}

int SimWorld::AddItem(const std::string& name, const std::string& container, std::uint32_t seed) {
  auto model = models_->Get(name);  // throws UnknownItemError
  std::vector<PlacedItem> existing;
  for (const ItemState& s : items_) {
    if (s.container == container) existing.push_back({s.name, s.container, s.X_BaseItem});
  }
  const LayoutPlanner planner(cell_, *models_, *static_scene_);
  const auto placed = planner.PlaceIn(container, {name}, existing, seed);
  int id = 1;
  for (const ItemState& s : items_) id = std::max(id, s.id + 1);
  items_.push_back({id, name, placed.front().X_BaseItem, container});
  item_models_.push_back(std::move(model));
  MarkMoved();
  return id;
}

const ItemState& SimWorld::item(int item_id) const {
  for (const ItemState& s : items_) {
    if (s.id == item_id) return s;
  }
  throw std::out_of_range("no item with id " + std::to_string(item_id));
}

ItemState& SimWorld::Mutable(int item_id) {
  return const_cast<ItemState&>(static_cast<const SimWorld*>(this)->item(item_id));
}

const world::ItemModel& SimWorld::model(int item_id) const {
  for (std::size_t i = 0; i < items_.size(); ++i) {
    if (items_[i].id == item_id) return *item_models_[i];
  }
  throw std::out_of_range("no item with id " + std::to_string(item_id));
}

std::vector<ItemState> SimWorld::ItemsIn(const std::string& container) const {
  if (!apc::IsBinName(container) && container != kTote && container != kGripper &&
      container != kTable && container != kOutside) {
    throw std::invalid_argument("unknown container '" + container + "'");
  }
  std::vector<ItemState> out;
  for (const ItemState& s : items_) {
    if (s.container == container) out.push_back(s);
  }
  return out;
}

SimState SimWorld::state() const {
  return {items_, X_BaseTcp_, q_rad_, vacuum_on_, attached_, X_TcpItem_, events_, head_angle_rad_};
}

void SimWorld::SetTcpPose(const Eigen::Isometry3d& X_BaseTcp) {
  ValidatePose(X_BaseTcp, "SetTcpPose");
  X_BaseTcp_ = X_BaseTcp;
  q_rad_.reset();
  if (attached_ != 0) {
    ItemState& s = Mutable(attached_);
    s.X_BaseItem = X_BaseTcp_ * X_TcpItem_;
    MarkMoved();
    if (pending_settle_box_ &&
        !pending_settle_box_->intersects(world::Bounds(model(attached_).mesh, s.X_BaseItem))) {
      pending_settle_box_.reset();
      SettleContainer(pending_settle_item_.container, &pending_settle_item_, 0);
    }
  }
}

void SimWorld::SetJointPositions(const ur10::JointVector& q_rad) {
  if (!kinematics_) throw std::logic_error("SetJointPositions: the world has no UR10 kinematics");
  if (!q_rad.allFinite()) throw std::invalid_argument("SetJointPositions: non-finite angle");
  SetTcpPose(kinematics_->ForwardKinematics(q_rad) * X_ToolTcp());
  q_rad_ = q_rad;
}

void SimWorld::SetHeadAngle(double head_angle_rad) {
  const world::GripperConfig& gripper = cell_.config.gripper;
  if (const std::string problem =
          world::HeadAngleProblem(head_angle_rad, gripper.max_head_angle_rad);
      !problem.empty()) {
    throw std::invalid_argument("SetHeadAngle: " + problem);
  }
  const Eigen::Isometry3d X_BaseTool = this->X_BaseTool();
  const std::optional<ur10::JointVector> q = q_rad_;
  head_angle_rad_ = head_angle_rad;
  SetTcpPose(X_BaseTool * X_ToolTcp());
  q_rad_ = q;  // the arm has not moved
}

const ur10::Ur10Kinematics& SimWorld::kinematics() const {
  if (!kinematics_) throw std::logic_error("SimWorld: no UR10 kinematics");
  return *kinematics_;
}

const world::RayScene& SimWorld::ItemScene() const {
  if (!item_scene_) {
    auto scene = std::make_unique<world::RayScene>();
    scene->Add(kShelfId, cell_.shelf, cell_.config.X_BaseShelf);
    scene->Add(kToteId, cell_.tote, cell_.config.X_BaseTote);
    scene->Add(kTableId, cell_.table, cell_.config.X_BaseTable);
    for (std::size_t i = 0; i < items_.size(); ++i) {
      scene->Add(items_[i].id, item_models_[i]->mesh, items_[i].X_BaseItem);
    }
    scene->Commit();
    item_scene_ = std::move(scene);
  }
  return *item_scene_;
}

GuardedMoveResult SimWorld::GuardedMove(double max_distance_m) {
  if (!std::isfinite(max_distance_m) || max_distance_m <= 0.0) {
    throw std::invalid_argument("GuardedMove: max_distance_m must be positive and finite");
  }
  const Eigen::Vector3d z = X_BaseTcp_.linear().col(2);
  GuardedMoveResult result;
  const std::optional<world::RayHit> first = world::CupFirstContact(
      ItemScene(), X_BaseTcp_, z, max_distance_m + 1.0, options_.cup_radius_m, options_.rim_samples,
      attached_ == 0 ? -1 : attached_);
  const double penetration_to_stop =
      options_.contact_force_threshold_n / options_.contact_stiffness_n_per_m;
  double travel = max_distance_m;
  if (first && first->distance_m + penetration_to_stop <= max_distance_m) {
    travel = first->distance_m + penetration_to_stop;
    result.contact = true;
  }
  if (first && first->distance_m < travel) {
    result.force_n = options_.contact_stiffness_n_per_m * (travel - first->distance_m);
    result.p_BaseContact = first->p_BaseHit;
    result.contact_item_id = first->object_id > 0 ? first->object_id : 0;
    result.contact_object = first->object_id > 0           ? item(first->object_id).name
                            : first->object_id == kShelfId ? "shelf"
                            : first->object_id == kToteId  ? "tote"
                                                           : "table";
  }
  result.travelled_m = travel;
  Eigen::Isometry3d X = X_BaseTcp_;
  X.translation() += travel * z;
  SetTcpPose(X);
  return result;
}

ProbeResult SimWorld::Probe(const Eigen::Isometry3d& X_BaseTcp,
                            const Eigen::Vector3d& direction_Base, double max_distance_m) const {
  ValidatePose(X_BaseTcp, "Probe");
  if (!direction_Base.allFinite() || direction_Base.norm() < 1e-9) {
    throw std::invalid_argument("Probe: direction must be finite and non-zero");
  }
  if (!std::isfinite(max_distance_m) || max_distance_m <= 0.0) {
    throw std::invalid_argument("Probe: max_distance_m must be positive and finite");
  }
  const std::optional<world::RayHit> first = world::CupFirstContact(
      ItemScene(), X_BaseTcp, direction_Base.normalized(), max_distance_m, options_.cup_radius_m,
      options_.rim_samples, attached_ == 0 ? -1 : attached_);
  ProbeResult result;
  if (!first) return result;
  result.contact = true;
  result.distance_m = first->distance_m;
  result.item_id = first->object_id > 0 ? first->object_id : 0;
  result.object = first->object_id > 0           ? item(first->object_id).name
                  : first->object_id == kShelfId ? "shelf"
                  : first->object_id == kToteId  ? "tote"
                                                 : "table";
  result.surface = first->object_id > 0           ? ContactSurface::kItem
                   : first->object_id == kShelfId ? ContactSurface::kShelf
                   : first->object_id == kToteId  ? ContactSurface::kTote
                                                  : ContactSurface::kTable;
  result.p_BaseContact = first->p_BaseHit;
  result.n_Base = first->n_Base;
  return result;
}

void SimWorld::LogCollision(const std::string& detail) {
  Event e;
  e.sequence = events_.size() + 1;
  e.kind = EventKind::kCollision;
  e.detail = detail;
  events_.push_back(e);
}

world::SealOptions SimWorld::SealOptionsOf(const SimOptions& options) {
  world::SealOptions seal;
  seal.cup_radius_m = options.cup_radius_m;
  seal.rim_samples = options.rim_samples;
  seal.flatness_tolerance_m = options.seal_flatness_tolerance_m;
  seal.angle_tolerance_rad = options.seal_angle_tolerance_rad;
  seal.max_gap_m = options.seal_max_gap_m;
  seal.lookback_m = options.seal_lookback_m;
  return seal;
}

world::SealMeasure SimWorld::SealAt(const Eigen::Isometry3d& X_BaseTcp) const {
  return world::MeasureSeal(ItemScene(), X_BaseTcp, SealOptionsOf(options_));
}

SuctionResult SimWorld::SuctionOn() {
  SuctionResult result;
  vacuum_on_ = true;
  if (attached_ != 0) {
    result.sealed = true;
    result.attached_item_id = attached_;
    return result;
  }
  const world::SealMeasure seal = SealAt(X_BaseTcp_);
  result.flatness_m = seal.flatness_m;
  result.angle_rad = seal.angle_rad;
  if (!seal.sealed) {
    result.reason = seal.reason;
    return result;
  }
  const int object = seal.object_id;
  result.sealed = true;
  if (object > 0) {
    ItemState& s = Mutable(object);
    attached_ = object;
    X_TcpItem_ = X_BaseTcp_.inverse() * s.X_BaseItem;
    pending_settle_item_ = {s.name, s.container, s.X_BaseItem};
    s.container = kGripper;
    result.attached_item_id = object;
    Log(EventKind::kAttached, s, 0.0);
    MarkMoved();
    // Items resting on the picked one lose their support once it has moved away.
    pending_settle_box_ = world::Bounds(model(object).mesh, s.X_BaseItem);
  }
  return result;
}

int SimWorld::SuctionOff() {
  vacuum_on_ = false;
  if (attached_ == 0) return 0;
  const int id = attached_;
  attached_ = 0;
  X_TcpItem_ = Eigen::Isometry3d::Identity();
  // Let go before it left its place: what it supported has not settled yet.
  const bool unsettled = pending_settle_box_.has_value();
  pending_settle_box_.reset();
  ItemState& s = Mutable(id);
  const world::ItemModel& m = model(id);
  const std::optional<std::string> into = Physics().ContainerUnder(
      0.5 * m.box_I.sizes(), s.X_BaseItem * Eigen::Translation3d(m.box_I.center()));
  if (into) {
    SettleContainer(*into, nullptr, id);
  } else {
    const double fall = RestOnSupport(s);
    LogFall(EventKind::kReleased, s, fall);
  }
  if (unsettled) SettleContainer(pending_settle_item_.container, &pending_settle_item_, 0);
  return id;
}

void SimWorld::SetItemPose(int item_id, const Eigen::Isometry3d& X_BaseItem) {
  ItemState& s = Mutable(item_id);  // throws for unknown id
  ValidatePose(X_BaseItem, "SetItemPose(" + std::to_string(item_id) + ")");
  if (item_id == attached_) {
    throw std::invalid_argument("SetItemPose: item " + std::to_string(item_id) +
                                " is in the gripper");
  }
  s.X_BaseItem = X_BaseItem;
  s.container = ClassifyContainer(model(item_id), X_BaseItem);
  MarkMoved();
}

std::string SimWorld::ClassifyContainer(const world::ItemModel& model,
                                        const Eigen::Isometry3d& X_BaseItem) const {
  const Eigen::Vector3d c_Base = X_BaseItem * model.box_I.center();
  for (const auto& bin : cell_.bins) {
    const Eigen::Vector3d c_S = cell_.config.X_BaseShelf.inverse() * c_Base;
    if (bin.inner_S.contains(c_S)) return bin.name;
  }
  // An item resting in the tote may stand out above its rim (a roll on end, a pile): its
  // centre over the tote's floor counts, up to 0.3 m above the rim.
  const Eigen::Vector3d c_T = cell_.config.X_BaseTote.inverse() * c_Base;
  Eigen::AlignedBox3d tote = cell_.tote_inner_T();
  tote.max().z() += 0.3;
  if (tote.contains(c_T)) return kTote;
  const Eigen::Vector3d c_Table = cell_.config.X_BaseTable.inverse() * c_Base;
  const Eigen::Vector3d& size = cell_.config.table_size_m;
  if (std::abs(c_Table.x()) <= 0.5 * size.x() && std::abs(c_Table.y()) <= 0.5 * size.y() &&
      c_Table.z() >= 0.0 && c_Table.z() <= 0.3) {
    return kTable;
  }
  return kOutside;
}

double SimWorld::SupportBelow(int self_id, const world::ItemModel& model,
                              const Eigen::Isometry3d& X_BaseItem, double from_z) const {
  const world::RayScene& scene = ItemScene();
  const Eigen::AlignedBox3d box = world::Bounds(model.mesh, X_BaseItem);
  double support = cell_.config.floor_z_m();
  constexpr int kGrid = 5;
  for (int i = 0; i < kGrid; ++i) {
    for (int j = 0; j < kGrid; ++j) {
      const double fx = 0.02 + 0.96 * i / (kGrid - 1), fy = 0.02 + 0.96 * j / (kGrid - 1);
      const Eigen::Vector3d p(box.min().x() + fx * box.sizes().x(),
                              box.min().y() + fy * box.sizes().y(), from_z);
      const auto hit = scene.Cast(p, -Eigen::Vector3d::UnitZ(), 100.0, self_id);
      if (hit) support = std::max(support, hit->p_BaseHit.z());
    }
  }
  return support;
}

double SimWorld::RestOnSupport(ItemState& s) {
  const world::ItemModel& m = model(s.id);
  // Turn the item onto the face whose normal points most nearly down.
  const Eigen::Matrix3d R = s.X_BaseItem.linear();
  int best_axis = 2;
  double best_sign = -1.0, best = -2.0;
  for (int a = 0; a < 3; ++a) {
    for (double sign : {1.0, -1.0}) {
      const double down = (sign * R.col(a)).dot(-Eigen::Vector3d::UnitZ());
      if (down > best + 1e-12) {
        best = down;
        best_axis = a;
        best_sign = sign;
      }
    }
  }
  const Eigen::Vector3d axis_Base = best_sign * R.col(best_axis);
  const Eigen::Matrix3d turn =
      Eigen::Quaterniond::FromTwoVectors(axis_Base, -Eigen::Vector3d::UnitZ()).toRotationMatrix();
  const Eigen::Vector3d c_Base = s.X_BaseItem * m.box_I.center();
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = turn * R;
  X.translation() = c_Base - X.linear() * m.box_I.center();  // turn about the box centre
  const Eigen::AlignedBox3d before = world::Bounds(m.mesh, X);
  const double support = SupportBelow(s.id, m, X, before.max().z());
  const double fall = std::max(0.0, before.min().z() - support);
  X.translation().z() += support + 0.0005 - before.min().z();
  s.X_BaseItem = X;
  s.container = ClassifyContainer(m, X);
  MarkMoved();
  return fall;
}

void SimWorld::LogFall(EventKind kind, const ItemState& s, double drop_height_m) {
  Log(kind, s, drop_height_m);
  if (drop_height_m > options_.drop_event_height_m) Log(EventKind::kDropped, s, drop_height_m);
  if (s.container == kOutside) Log(EventKind::kOutside, s, drop_height_m);
}

void SimWorld::SettleContainer(const std::string& container, const PlacedItem* removed,
                               int released_id) {
  if (container != kTote && !apc::IsBinName(container)) return;  // not simulated
  std::vector<int> ids;
  std::vector<PlacedItem> placed;
  std::optional<std::size_t> released;
  for (const ItemState& s : items_) {
    if (s.id == released_id) released = ids.size();
    if (s.id == released_id || (s.container == container && s.id != attached_)) {
      ids.push_back(s.id);
      placed.push_back({s.name, container, s.X_BaseItem});
    }
  }
  if (placed.empty()) return;
  const RestResult rest = released ? Physics().Release(container, placed, *released)
                                   : Physics().Resettle(container, placed, *removed);
  for (std::size_t k = 0; k < ids.size(); ++k) {
    ItemState& s = Mutable(ids[k]);
    const world::ItemModel& m = model(s.id);
    const Eigen::Isometry3d& X_after = rest.items[k].X_BaseItem;
    const Eigen::Vector3d c_before = s.X_BaseItem * m.box_I.center();
    const double turn =
        Eigen::AngleAxisd(X_after.linear() * s.X_BaseItem.linear().transpose()).angle();
    const bool moved = (X_after * m.box_I.center() - c_before).norm() > options_.fell_threshold_m ||
                       turn > options_.fell_threshold_rad;
    if (!rest.loose[k] || (k != released && !moved && !rest.left_container[k])) continue;
    s.X_BaseItem = X_after;
    s.container = ClassifyContainer(m, X_after);
    // Out over a bin's lip: the rest of its fall is outside the physics' containers.
    if (rest.left_container[k]) RestOnSupport(s);
    MarkMoved();
    if (k == released) {
      LogFall(EventKind::kReleased, s, rest.drop_height_m);
    } else {
      LogFall(EventKind::kFell, s,
              std::max(0.0, c_before.z() - (s.X_BaseItem * m.box_I.center()).z()));
    }
  }
}

void SimWorld::Log(EventKind kind, const ItemState& s, double drop_height_m) {
  Event e;
  e.sequence = events_.size() + 1;
  e.kind = kind;
  e.item_id = s.id;
  e.item_name = s.name;
  e.container = s.container;
  e.drop_height_m = drop_height_m;
  events_.push_back(e);
}

std::vector<SceneObject> SimWorld::SceneMeshes() const {
  std::vector<SceneObject> objects;
  objects.push_back({&cell_.shelf, cell_.config.X_BaseShelf});
  objects.push_back({&cell_.tote, cell_.config.X_BaseTote});
  objects.push_back({&cell_.table, cell_.config.X_BaseTable});
  for (std::size_t i = 0; i < items_.size(); ++i) {
    objects.push_back({&item_models_[i]->mesh, items_[i].X_BaseItem});
  }
  return objects;
}

std::vector<std::string> SimWorld::SceneNames() const {
  std::vector<std::string> names = {"shelf", "tote", "table"};
  for (const ItemState& s : items_) names.push_back(s.name);
  return names;
}

}  // namespace picking::simulator
