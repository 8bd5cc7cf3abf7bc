#include "services/simulator/service/simulator_service.h"

#include <grpcpp/server_context.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>
#include <mutex>
#include <optional>
#include <sstream>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "libs/apc/catalogue.h"
#include "libs/apc/task.h"
#include "libs/camera/pinhole_camera.h"
#include "libs/errors/errors.h"
#include "libs/proto_convert/proto_convert.h"
#include "libs/runtime/log.h"
#include "libs/runtime/server.h"
#include "libs/runtime/status.h"
#include "libs/ur10/ur10_model.h"
#include "libs/world/mesh_utils.h"

namespace picking::simulator {
namespace {

namespace pb = ::picking::simulator::v1;
namespace common = ::picking::common::v1;
namespace pc = ::picking::proto_convert;

// Largest camera or projector image: a side of 4096 pixels and 4 Mpx (the cell's camera
// has 1.3 Mpx). A 16384 x 16384 render held about 4 GB for over a minute.
constexpr std::uint32_t kMaxImageSide = 4096;
constexpr std::uint64_t kMaxImagePixels = std::uint64_t{1} << 22;
// Most projector pixels of one RenderPatterns call (patterns x projector pixels): every
// pattern is built up front so that all are validated before the first image is sent.
constexpr std::uint64_t kMaxPatternPixels = std::uint64_t{1} << 28;
// Largest projector defocus: the blur kernel spans 6 sigma, so a sigma of 1e6 ran for
// minutes; a real projector is out of focus by a few pixels.
constexpr double kMaxProjectorBlurSigmaPx = 20.0;
constexpr std::uint32_t kMaxGrayBits = 16;

std::string Num(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}

// Names a catalogue item that the task JSON mentions but the catalogue does not know, with
// its field; empty if there is none (or the JSON is not even well-formed).
std::string FindUnknownItem(const std::string& json_text, const apc::Catalogue& catalogue) {
  const nlohmann::json doc = nlohmann::json::parse(json_text, nullptr, /*allow_exceptions=*/false);
  if (!doc.is_object()) return {};
  auto check = [&](const nlohmann::json& list, const std::string& field) -> std::string {
    if (!list.is_array()) return {};
    for (std::size_t i = 0; i < list.size(); ++i) {
      if (list[i].is_string() && !catalogue.contains(list[i].get<std::string>())) {
        return field + "[" + std::to_string(i) + "]: unknown item \"" +
               runtime::Quoted(list[i].get<std::string>()) + "\"";
      }
    }
    return {};
  };
  if (auto it = doc.find("bin_contents"); it != doc.end() && it->is_object()) {
    for (auto bin = it->begin(); bin != it->end(); ++bin) {
      if (std::string m = check(bin.value(), "bin_contents." + bin.key()); !m.empty()) return m;
    }
  }
  if (auto it = doc.find("tote_contents"); it != doc.end()) {
    if (std::string m = check(*it, "tote_contents"); !m.empty()) return m;
  }
  if (auto it = doc.find("work_order"); it != doc.end() && it->is_array()) {
    for (std::size_t i = 0; i < it->size(); ++i) {
      const auto& entry = (*it)[i];
      if (entry.is_object() && entry.contains("item") && entry["item"].is_string() &&
          !catalogue.contains(entry["item"].get<std::string>())) {
        return "work_order[" + std::to_string(i) + "].item: unknown item \"" +
               runtime::Quoted(entry["item"].get<std::string>()) + "\"";
      }
    }
  }
  return {};
}

// Parses task JSON: NotFoundError for an unknown item, std::invalid_argument (naming the
// field, or the line and column) for anything else wrong.
apc::Task ParseTaskJson(const std::string& json_text, const apc::Catalogue& catalogue,
                        const std::string& source) {
  try {
    return apc::ParseTask(json_text, catalogue, source);
  } catch (const apc::TaskFileError& e) {
    const std::string unknown = FindUnknownItem(json_text, catalogue);
    if (!unknown.empty()) throw NotFoundError(source + ": " + unknown);
    throw std::invalid_argument(e.what());
  }
}

// Loads `task` into the world: ResourceExhaustedError naming the bin when items do not fit,
// NotFoundError for an item without a model.
void LoadTaskInto(SimWorld& world, const apc::Task& task, std::uint64_t seed, LayoutMode mode) {
  if (seed > std::numeric_limits<std::uint32_t>::max()) {
    throw std::invalid_argument("seed must be below 2^32, got " + std::to_string(seed));
  }
  try {
    LayoutOptions layout;
    layout.mode = mode;
    world.LoadTask(task, static_cast<std::uint32_t>(seed), layout);
  } catch (const LayoutError& e) {
    throw ResourceExhaustedError(e.what());
  } catch (const apc::UnknownItemError& e) {
    throw NotFoundError(e.what());
  }
}

std::array<double, 6> ToArray(const ur10::JointVector& q) {
  std::array<double, 6> a{};
  for (int i = 0; i < 6; ++i) a[i] = q[i];
  return a;
}

// 0-based instance of each item among the items of the same name, in id order.
std::map<int, std::uint32_t> Instances(const std::vector<ItemState>& items) {
  std::map<int, const ItemState*> by_id;
  for (const ItemState& s : items) by_id[s.id] = &s;
  std::map<std::string, std::uint32_t> count;
  std::map<int, std::uint32_t> out;
  for (const auto& [id, s] : by_id) out[id] = count[s->name]++;
  return out;
}

common::ItemRef ItemRefOf(const std::string& name, std::uint32_t instance) {
  common::ItemRef ref;
  ref.set_name(name);
  ref.set_instance(instance);
  return ref;
}

pb::ItemState ItemStateToProto(const ItemState& s, std::uint32_t instance) {
  pb::ItemState out;
  *out.mutable_item() = ItemRefOf(s.name, instance);
  *out.mutable_x_base_item() = pc::PoseToProto(s.X_BaseItem);
  out.set_container(pc::ContainerFromName(s.container));
  return out;
}

pb::EventKind EventKindToProto(EventKind kind) {
  switch (kind) {
    case EventKind::kAttached:
      return pb::EVENT_KIND_ATTACHED;
    case EventKind::kReleased:
      return pb::EVENT_KIND_RELEASED;
    case EventKind::kDropped:
      return pb::EVENT_KIND_DROPPED_HIGH;
    case EventKind::kFell:
      return pb::EVENT_KIND_FELL;
    case EventKind::kOutside:
      return pb::EVENT_KIND_OUTSIDE;
    case EventKind::kCollision:
      return pb::EVENT_KIND_COLLISION;
  }
  throw std::logic_error("unhandled simulator event kind");
}

pb::ContactSurface ContactSurfaceToProto(ContactSurface surface) {
  switch (surface) {
    case ContactSurface::kNone:
      return pb::CONTACT_SURFACE_UNSPECIFIED;
    case ContactSurface::kItem:
      return pb::CONTACT_SURFACE_ITEM;
    case ContactSurface::kShelf:
      return pb::CONTACT_SURFACE_SHELF;
    case ContactSurface::kTote:
      return pb::CONTACT_SURFACE_TOTE;
    case ContactSurface::kTable:
      return pb::CONTACT_SURFACE_TABLE;
  }
  throw std::logic_error("unhandled simulator contact surface");
}

camera::PinholeCamera PinholeFromProto(const common::CameraIntrinsics& m,
                                       const std::string& field) {
  return pc::CameraFromProto(m, field, kMaxImageSide, kMaxImagePixels);
}

// Gray-code image as the scanner projects it (services/scanner/core/patterns.h): projector
// column c is lit iff bit (bit_count - 1 - bit) of GrayEncode(c) is 1; rows likewise.
GrayImage GrayCodeImage(const pb::GrayCodeStripe& g, int width, int height,
                        const std::string& field) {
  const int count = g.rows() ? height : width;
  std::uint32_t bits = g.bit_count();
  if (bits == 0) {
    while ((1u << bits) < static_cast<std::uint32_t>(count)) ++bits;
  }
  if (bits > kMaxGrayBits || (1u << bits) < static_cast<std::uint32_t>(count)) {
    throw std::invalid_argument(field + ".bit_count: " + std::to_string(g.bit_count()) +
                                " bits cannot number " + std::to_string(count) +
                                (g.rows() ? " rows" : " columns"));
  }
  if (g.bit() >= bits) {
    throw std::invalid_argument(field + ".bit: " + std::to_string(g.bit()) + " is not below " +
                                std::to_string(bits));
  }
  const std::uint32_t shift = bits - 1 - g.bit();
  std::vector<std::uint8_t> line(static_cast<std::size_t>(count));
  for (int c = 0; c < count; ++c) {
    const std::uint32_t gray = static_cast<std::uint32_t>(c) ^ (static_cast<std::uint32_t>(c) >> 1);
    const bool lit = ((gray >> shift) & 1u) != g.inverted();
    line[c] = lit ? 255 : 0;
  }
  GrayImage image(width, height);
  for (int v = 0; v < height; ++v) {
    for (int u = 0; u < width; ++u) image.at(u, v) = g.rows() ? line[v] : line[u];
  }
  return image;
}

struct PatternImage {
  GrayImage image;
  std::string name;
};

PatternImage PatternFromProto(const pb::ProjectorPattern& p, int width, int height,
                              const std::string& field) {
  switch (p.kind_case()) {
    case pb::ProjectorPattern::kSolidLevel: {
      const double level = p.solid_level();
      if (!std::isfinite(level) || level < 0.0 || level > 1.0) {
        throw std::invalid_argument(field + ".solid_level must be in [0, 1], got " + Num(level));
      }
      return {GrayImage(width, height, static_cast<std::uint8_t>(std::lround(255.0 * level))),
              "solid/" + Num(level)};
    }
    case pb::ProjectorPattern::kGrayCode: {
      const auto& g = p.gray_code();
      return {GrayCodeImage(g, width, height, field + ".gray_code"),
              std::string("pattern/") + (g.rows() ? "row/" : "col/") + std::to_string(g.bit()) +
                  (g.inverted() ? "/inverse" : "")};
    }
    case pb::ProjectorPattern::kMono8: {
      const std::string& bytes = p.mono8();
      if (bytes.size() != static_cast<std::size_t>(width) * height) {
        throw std::invalid_argument(field + ".mono8 has " + std::to_string(bytes.size()) +
                                    " bytes, the projector needs " + std::to_string(width) + " x " +
                                    std::to_string(height));
      }
      GrayImage image(width, height);
      std::copy(bytes.begin(), bytes.end(), image.pixels.begin());
      return {std::move(image), "mono8"};
    }
    case pb::ProjectorPattern::KIND_NOT_SET:
      break;
  }
  throw std::invalid_argument(field + ": no pattern set (solid_level, gray_code or mono8)");
}

RenderOptions RenderOptionsFromProto(const pb::RenderOptions& o) {
  auto check = [](double v, const char* field, bool allow_zero) {
    if (!std::isfinite(v) || v < 0.0 || (!allow_zero && v == 0.0)) {
      throw std::invalid_argument(std::string("options.") + field +
                                  " must be finite and >= 0, got " + Num(v));
    }
  };
  check(o.ambient(), "ambient", true);
  check(o.noise_sigma(), "noise_sigma", true);
  check(o.gamma(), "gamma", true);
  check(o.exposure(), "exposure", true);
  check(o.electrons_per_dn(), "electrons_per_dn", true);
  check(o.projector_blur_sigma_px(), "projector_blur_sigma_px", true);
  if (o.projector_blur_sigma_px() > kMaxProjectorBlurSigmaPx) {
    throw std::invalid_argument("options.projector_blur_sigma_px must be at most " +
                                Num(kMaxProjectorBlurSigmaPx) + ", got " +
                                Num(o.projector_blur_sigma_px()));
  }
  RenderOptions r;
  r.ambient = o.ambient();
  r.read_noise_dn = o.noise_sigma();
  r.electrons_per_dn = o.electrons_per_dn();  // 0: read noise only.
  r.projector_blur_sigma_px = o.projector_blur_sigma_px();
  r.camera_gamma = o.gamma() == 0.0 ? 1.0 : o.gamma();
  r.exposure = o.exposure() == 0.0 ? 1.0 : o.exposure();
  r.seed = o.seed();
  r.Validate();
  return r;
}

// Why a render should end now (the call's deadline passed, the client cancelled, the server
// is stopping), or OK. Checked between images, so a long render ends within one part.
grpc::Status Interruption(const grpc::ServerContext& context) {
  if (std::chrono::system_clock::now() >= context.deadline()) {
    return grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED,
                        "the render did not finish within the call's deadline");
  }
  if (context.IsCancelled()) return grpc::Status(grpc::StatusCode::CANCELLED, "cancelled");
  if (runtime::ShuttingDown()) return runtime::Unavailable("the simulator is shutting down");
  return grpc::Status::OK;
}

class SimulatorServiceImpl final : public pb::SimulatorService::Service {
 public:
  SimulatorServiceImpl(std::unique_ptr<SimWorld> world,
                       std::unique_ptr<ArmCollisionChecker> collisions,
                       const SimulatorServiceOptions& options)
      : world_(std::move(world)), collisions_(std::move(collisions)), options_(options) {
    if (!world_) throw std::invalid_argument("SimulatorService: null world");
    if (!collisions_) throw std::invalid_argument("SimulatorService: null collision checker");
    options_.Validate();
  }

  grpc::Status LoadLayout(grpc::ServerContext*, const pb::LoadLayoutRequest* request,
                          pb::LoadLayoutResponse* response) override {
    return runtime::Guard([&] {
      const apc::Task task =
          ParseTaskJson(request->task_json(), world_->models().catalogue(), "task_json");
      std::lock_guard<std::mutex> lock(mutex_);
      ++scene_generation_;
      LoadTaskInto(*world_, task, request->seed(), options_.layout_mode);
      in_collision_ = false;
      const auto instances = Instances(world_->items());
      for (const ItemState& s : world_->items()) {
        *response->add_items() = ItemStateToProto(s, instances.at(s.id));
      }
      return grpc::Status::OK;
    });
  }

  grpc::Status GetGroundTruth(grpc::ServerContext*, const pb::GetGroundTruthRequest*,
                              pb::GetGroundTruthResponse* response) override {
    return runtime::Guard([&] {
      std::lock_guard<std::mutex> lock(mutex_);
      const auto instances = Instances(world_->items());
      for (const ItemState& s : world_->items()) {
        *response->add_items() = ItemStateToProto(s, instances.at(s.id));
      }
      for (const Event& e : world_->events()) {
        auto* out = response->add_events();
        out->set_kind(EventKindToProto(e.kind));
        out->set_sequence(e.sequence);
        out->set_drop_height_m(e.drop_height_m);
        if (e.item_id != 0) {
          const auto it = instances.find(e.item_id);
          *out->mutable_item() = ItemRefOf(e.item_name, it == instances.end() ? 0 : it->second);
        }
        out->set_detail(e.kind == EventKind::kCollision ? e.detail
                        : e.container.empty()           ? std::string()
                                                        : "now in " + e.container);
      }
      const SimState state = world_->state();
      if (state.q_rad) {
        // The arm is placed: the cup, and the flange it hangs from.
        *response->mutable_arm_joints() = pc::JointsToProto(ToArray(*state.q_rad));
        *response->mutable_x_base_tcp() = pc::PoseToProto(state.X_BaseTcp);
        *response->mutable_x_base_tool() = pc::PoseToProto(world_->X_BaseTool());
      }
      response->set_gripper_head_angle_rad(state.head_angle_rad);
      if (state.attached_item_id != 0) {
        *response->mutable_attached_item() = ItemRefOf(world_->item(state.attached_item_id).name,
                                                       instances.at(state.attached_item_id));
      }
      return grpc::Status::OK;
    });
  }

  grpc::Status GetCell(grpc::ServerContext*, const pb::GetCellRequest*,
                       pb::GetCellResponse* response) override {
    return runtime::Guard([&] {
      std::lock_guard<std::mutex> lock(mutex_);
      const world::CellModel& cell = world_->cell();
      const Eigen::Isometry3d& X_BaseShelf = cell.config.X_BaseShelf;
      *response->mutable_x_base_shelf() = pc::PoseToProto(X_BaseShelf);
      for (const world::BinGeometry& bin : cell.bins) {
        auto* out = response->add_bins();
        out->set_bin(pc::ContainerFromName(bin.name));
        *out->mutable_x_base_bin() =
            pc::PoseToProto(X_BaseShelf * Eigen::Translation3d(bin.inner_S.center()));
        *out->mutable_size_m() = pc::VectorToProto(bin.inner_S.sizes());
      }
      // The tote's inner box, measured from its mesh (as the layouts use it).
      const Eigen::AlignedBox3d& inner = cell.tote_inner_T();
      *response->mutable_x_base_tote() =
          pc::PoseToProto(cell.config.X_BaseTote * Eigen::Translation3d(inner.center()));
      *response->mutable_tote_inner_size_m() = pc::VectorToProto(inner.sizes());
      *response->mutable_x_base_table() = pc::PoseToProto(cell.config.X_BaseTable);
      return grpc::Status::OK;
    });
  }

  grpc::Status SetArmJoints(grpc::ServerContext*, const pb::SetArmJointsRequest* request,
                            pb::SetArmJointsResponse* response) override {
    return runtime::Guard([&] {
      const std::array<double, 6> a = pc::JointsFromProto(request->joints(), "joints");
      ur10::JointVector q;
      for (int i = 0; i < 6; ++i) q[i] = a[i];
      const ur10::Ur10Model& model = collisions_kinematics().model();
      for (int i = 0; i < ur10::kNumJoints; ++i) {
        const auto& limit = model.limits()[i];
        if (q[i] < limit.min_position_rad || q[i] > limit.max_position_rad) {
          throw std::invalid_argument("joints[" + std::to_string(i) + "] (" + ur10::kJointNames[i] +
                                      ") = " + Num(q[i]) + " rad is outside [" +
                                      Num(limit.min_position_rad) + ", " +
                                      Num(limit.max_position_rad) + "]");
        }
      }
      std::lock_guard<std::mutex> lock(mutex_);
      const Eigen::Isometry3d X_BaseTool = collisions_kinematics().ForwardKinematics(q);
      const Eigen::Isometry3d X_BaseTcp = X_BaseTool * world_->X_ToolTcp();
      const SimState state = world_->state();
      ArmCollision collision;
      if (state.attached_item_id != 0) {
        CarriedItem carried;
        carried.id = state.attached_item_id;
        carried.name = world_->item(carried.id).name;
        carried.mesh = &world_->model(carried.id).mesh;
        carried.X_BaseItem = X_BaseTcp * state.X_TcpItem;
        collision = collisions_->Check(q, &carried, world_->head_angle_rad());
      } else {
        collision = collisions_->Check(q, nullptr, world_->head_angle_rad());
      }
      world_->SetJointPositions(q);
      // One event per contact episode, not per streamed sample.
      if (collision.in_collision && !in_collision_) world_->LogCollision(collision.detail);
      in_collision_ = collision.in_collision;
      response->set_in_collision(collision.in_collision);
      response->set_collision_detail(collision.detail);
      *response->mutable_x_base_tcp() = pc::PoseToProto(world_->X_BaseTcp());
      *response->mutable_x_base_tool() = pc::PoseToProto(X_BaseTool);
      response->set_gripper_head_angle_rad(world_->head_angle_rad());
      return grpc::Status::OK;
    });
  }

  grpc::Status SetGripperHead(grpc::ServerContext*, const pb::SetGripperHeadRequest* request,
                              pb::SetGripperHeadResponse* response) override {
    return runtime::Guard([&] {
      const double angle = request->angle_rad();
      const world::GripperConfig& gripper = world_->cell().config.gripper;
      if (const std::string problem = world::HeadAngleProblem(angle, gripper.max_head_angle_rad);
          !problem.empty()) {
        throw std::invalid_argument("angle_rad " + problem);
      }
      std::lock_guard<std::mutex> lock(mutex_);
      const SimState state = world_->state();
      if (state.q_rad) {
        // The head may not swing into the cell.
        CarriedItem carried;
        const CarriedItem* carrying = nullptr;
        if (state.attached_item_id != 0) {
          carried.id = state.attached_item_id;
          carried.name = world_->item(carried.id).name;
          carried.mesh = &world_->model(carried.id).mesh;
          carried.X_BaseItem = collisions_kinematics().ForwardKinematics(*state.q_rad) *
                               gripper.X_ToolTcpAt(angle) * state.X_TcpItem;
          carrying = &carried;
        }
        const ArmCollision collision = collisions_->Check(*state.q_rad, carrying, angle);
        if (collision.in_collision) {
          throw PreconditionError("turning the head to " + Num(angle) +
                                  " rad collides: " + collision.detail);
        }
        world_->SetHeadAngle(angle);
        *response->mutable_x_base_tcp() = pc::PoseToProto(world_->X_BaseTcp());
      } else {
        world_->SetHeadAngle(angle);
      }
      response->set_angle_rad(world_->head_angle_rad());
      return grpc::Status::OK;
    });
  }

  grpc::Status ProbeContact(grpc::ServerContext*, const pb::ProbeContactRequest* request,
                            pb::ProbeContactResponse* response) override {
    return runtime::Guard([&] {
      const Eigen::Vector3d direction_tcp =
          pc::VectorFromProto(request->direction_tcp(), "direction_tcp");
      if (std::abs(direction_tcp.norm() - 1.0) > 1e-3) {
        throw std::invalid_argument("direction_tcp must be a unit vector, its norm is " +
                                    Num(direction_tcp.norm()));
      }
      const double max_distance_m = request->max_distance_m();
      if (!std::isfinite(max_distance_m) || max_distance_m <= 0.0 || max_distance_m > 10.0) {
        throw std::invalid_argument("max_distance_m must be in (0, 10], got " +
                                    Num(max_distance_m));
      }
      std::optional<Eigen::Isometry3d> X_BaseTool;
      if (request->has_x_base_tool()) {
        X_BaseTool = pc::PoseFromProto(request->x_base_tool(), "X_base_tool");
      }
      std::lock_guard<std::mutex> lock(mutex_);
      if (!X_BaseTool) {
        const SimState state = world_->state();
        if (!state.q_rad) {
          throw PreconditionError(
              "X_base_tool is unset and the arm has not been placed yet (SetArmJoints)");
        }
        X_BaseTool = collisions_kinematics().ForwardKinematics(*state.q_rad);
      }
      const Eigen::Isometry3d X_BaseTcp = *X_BaseTool * world_->X_ToolTcp();
      const ProbeResult probe =
          world_->Probe(X_BaseTcp, X_BaseTcp.linear() * direction_tcp, max_distance_m);
      response->set_contact(probe.contact);
      if (probe.contact) {
        response->set_distance_m(probe.distance_m);
        response->set_stiffness_n_per_m(world_->options().contact_stiffness_n_per_m);
        response->set_surface(ContactSurfaceToProto(probe.surface));
        if (probe.item_id != 0) {
          const auto instances = Instances(world_->items());
          *response->mutable_item() = ItemRefOf(probe.object, instances.at(probe.item_id));
        }
      }
      return grpc::Status::OK;
    });
  }

  grpc::Status SetSuction(grpc::ServerContext*, const pb::SetSuctionRequest* request,
                          pb::SetSuctionResponse* response) override {
    return runtime::Guard([&] {
      std::lock_guard<std::mutex> lock(mutex_);
      if (request->on()) {
        const SuctionResult seal = world_->SuctionOn();
        // Why the cup did not seal is the simulated world's to say (a real gripper only reads
        // its vacuum): logged, for whoever wonders why a grasp failed.
        if (!seal.sealed) runtime::LogInfo("no seal", {{"reason", seal.reason}});
        response->set_sealed(seal.sealed);
        response->set_vacuum_kpa(seal.sealed ? options_.sealed_kpa : options_.open_kpa);
        if (seal.attached_item_id != 0) {
          const auto instances = Instances(world_->items());
          *response->mutable_attached_item() = ItemRefOf(world_->item(seal.attached_item_id).name,
                                                         instances.at(seal.attached_item_id));
        }
        return grpc::Status::OK;
      }
      const std::size_t events_before = world_->events().size();
      const int released = world_->SuctionOff();
      response->set_vacuum_kpa(0.0);
      if (released != 0) {
        const auto instances = Instances(world_->items());
        *response->mutable_released() =
            ItemStateToProto(world_->item(released), instances.at(released));
        for (std::size_t i = events_before; i < world_->events().size(); ++i) {
          const Event& e = world_->events()[i];
          if (e.kind == EventKind::kReleased && e.item_id == released) {
            response->set_drop_height_m(e.drop_height_m);
          }
        }
      }
      return grpc::Status::OK;
    });
  }

  grpc::Status RenderPatterns(grpc::ServerContext* context,
                              const pb::RenderPatternsRequest* request,
                              grpc::ServerWriter<pb::RenderPatternsResponse>* writer) override {
    return runtime::Guard([&] {
      // Everything is validated before any image is sent.
      const camera::PinholeCamera camera_model = PinholeFromProto(request->camera(), "camera");
      const camera::PinholeCamera projector_model =
          PinholeFromProto(request->projector(), "projector");
      const Eigen::Isometry3d X_BaseCamera =
          pc::PoseFromProto(request->x_base_camera(), "X_base_camera");
      const Eigen::Isometry3d X_BaseProjector =
          pc::PoseFromProto(request->x_base_projector(), "X_base_projector");
      if (request->patterns_size() == 0) {
        throw std::invalid_argument("patterns: at least one pattern is needed");
      }
      if (request->patterns_size() > options_.max_patterns) {
        throw std::invalid_argument("patterns: at most " + std::to_string(options_.max_patterns) +
                                    " per call, got " + std::to_string(request->patterns_size()));
      }
      const RenderOptions render_options = RenderOptionsFromProto(request->options());
      const std::uint64_t pattern_pixels = std::uint64_t{projector_model.width()} *
                                           projector_model.height() *
                                           static_cast<std::uint64_t>(request->patterns_size());
      if (pattern_pixels > kMaxPatternPixels) {
        throw std::invalid_argument("patterns: " + std::to_string(request->patterns_size()) +
                                    " patterns of the projector's size are " +
                                    std::to_string(pattern_pixels) + " pixels, more than " +
                                    std::to_string(kMaxPatternPixels) + " per call");
      }
      std::vector<PatternImage> patterns;
      for (int i = 0; i < request->patterns_size(); ++i) {
        patterns.push_back(PatternFromProto(request->patterns(i), projector_model.width(),
                                            projector_model.height(),
                                            "patterns[" + std::to_string(i) + "]"));
      }
      const ScanPose pose{camera_model, X_BaseCamera, projector_model, X_BaseProjector};
      if (grpc::Status why = Interruption(*context); !why.ok()) return why;
      const ScanGeometry geometry =
          WithSceneRenderer([&](const StructuredLightRenderer& r) { return r.Prepare(pose); });
      // A few frames per RenderSequence call share its per-block shading tables and threads,
      // and the camera images' buffers are reused from part to part.
      constexpr std::size_t kFramesPerPart = 4;
      std::vector<GrayImage> part;
      std::vector<GrayImage> images;
      for (std::size_t first = 0; first < patterns.size(); first += kFramesPerPart) {
        if (grpc::Status why = Interruption(*context); !why.ok()) return why;
        const std::size_t count = std::min(kFramesPerPart, patterns.size() - first);
        part.resize(count);
        for (std::size_t k = 0; k < count; ++k) part[k] = std::move(patterns[first + k].image);
        RenderSequence(geometry, part, render_options, &images, first);
        for (std::size_t k = 0; k < count; ++k) {
          pc::Image out;
          out.width = static_cast<std::uint32_t>(images[k].width);
          out.height = static_cast<std::uint32_t>(images[k].height);
          out.format = common::PIXEL_FORMAT_MONO8;
          out.name = patterns[first + k].name;
          out.index = static_cast<std::uint32_t>(first + k);
          out.data = images[k].pixels;
          for (common::ImageChunk& chunk : pc::ImageToChunks(out)) {
            pb::RenderPatternsResponse response;
            *response.mutable_chunk() = std::move(chunk);
            if (!writer->Write(response)) {
              return grpc::Status(grpc::StatusCode::CANCELLED, "the client stopped reading");
            }
          }
        }
      }
      return grpc::Status::OK;
    });
  }

  grpc::Status RenderDepth(grpc::ServerContext* context, const pb::RenderDepthRequest* request,
                           grpc::ServerWriter<pb::RenderDepthResponse>* writer) override {
    return runtime::Guard([&] {
      const camera::PinholeCamera camera_model = PinholeFromProto(request->camera(), "camera");
      if (!request->has_x_base_camera()) throw std::invalid_argument("X_base_camera is unset");
      const Eigen::Isometry3d X_BaseCamera =
          pc::PoseFromProto(request->x_base_camera(), "X_base_camera");
      // The wait for the renderer (another call may hold it) can outlast the deadline.
      std::optional<DepthImage> depth_or;
      grpc::Status interrupted;
      WithSceneRenderer([&](const StructuredLightRenderer& r) {
        interrupted = Interruption(*context);
        if (interrupted.ok()) depth_or = r.RenderDepth(camera_model, X_BaseCamera);
        return 0;
      });
      if (!interrupted.ok()) return interrupted;
      const DepthImage& depth = *depth_or;
      pc::Image out;
      out.width = static_cast<std::uint32_t>(depth.width);
      out.height = static_cast<std::uint32_t>(depth.height);
      out.format = common::PIXEL_FORMAT_FLOAT32;
      out.name = "depth";
      out.index = 0;
      out.data.resize(depth.depth_m.size() * sizeof(float));
      static_assert(sizeof(float) == 4, "FLOAT32 pixels");
      // Little-endian IEEE 754 on the wire, as on every supported host.
      std::memcpy(out.data.data(), depth.depth_m.data(), out.data.size());
      for (common::ImageChunk& chunk : pc::ImageToChunks(out)) {
        pb::RenderDepthResponse response;
        *response.mutable_chunk() = std::move(chunk);
        if (!writer->Write(response)) {
          return grpc::Status(grpc::StatusCode::CANCELLED, "the client stopped reading");
        }
      }
      return grpc::Status::OK;
    });
  }

 private:
  // Calls f(renderer) with the renderer of the world's scene as it is now. The renderer is
  // kept between calls, so that its BVH and its per-pixel camera rays (the lens model's
  // undistortion) are reused: it is rebuilt when the item set changed (LoadLayout) and only
  // moves the objects whose pose changed otherwise. Rendering calls are serialised; the
  // world is only held while the renderer is brought up to date (it copies the meshes).
  template <class F>
  std::invoke_result_t<const F&, const StructuredLightRenderer&> WithSceneRenderer(const F& f) {
    std::lock_guard<std::mutex> render_lock(render_mutex_);
    {
      std::lock_guard<std::mutex> lock(mutex_);
      const std::vector<SceneObject> objects = world_->SceneMeshes();
      if (!renderer_) {
        renderer_ = std::make_unique<StructuredLightRenderer>(objects);
      } else if (rendered_generation_ != scene_generation_ ||
                 rendered_poses_.size() != objects.size()) {
        renderer_->SetObjects(objects);
      } else {
        for (std::size_t i = 0; i < objects.size(); ++i) {
          if (objects[i].X_BaseObject.matrix() != rendered_poses_[i].matrix()) {
            renderer_->SetObjectPose(i, objects[i].X_BaseObject);
          }
        }
      }
      rendered_generation_ = scene_generation_;
      rendered_poses_.clear();
      for (const SceneObject& o : objects) rendered_poses_.push_back(o.X_BaseObject);
    }
    return f(static_cast<const StructuredLightRenderer&>(*renderer_));
  }

  const ur10::Ur10Kinematics& collisions_kinematics() const { return world_->kinematics(); }

  std::mutex mutex_;
  std::unique_ptr<SimWorld> world_;
  // Bumped (under mutex_) whenever the world's item set may change.
  std::uint64_t scene_generation_ = 0;
  // The scene renderer (WithSceneRenderer), guarded by render_mutex_, which is taken before
  // mutex_ when both are held.
  std::mutex render_mutex_;
  std::unique_ptr<StructuredLightRenderer> renderer_;
  std::uint64_t rendered_generation_ = 0;
  std::vector<Eigen::Isometry3d, Eigen::aligned_allocator<Eigen::Isometry3d>> rendered_poses_;
  std::unique_ptr<ArmCollisionChecker> collisions_;
  SimulatorServiceOptions options_;
  bool in_collision_ = false;  // the last SetArmJoints was in collision
};

double PositiveSetting(const runtime::Config& config, const std::string& key, double fallback) {
  const double v = config.GetDouble(key, fallback);
  if (!(v > 0.0)) throw std::invalid_argument("setting '" + key + "' must be > 0");
  return v;
}

}  // namespace

void SimulatorServiceOptions::Validate() const {
  if (!std::isfinite(sealed_kpa) || !std::isfinite(open_kpa) || !(open_kpa >= 0.0) ||
      !(open_kpa < sealed_kpa)) {
    throw std::invalid_argument("suction.open_kpa and suction.sealed_kpa: need 0 <= open < sealed");
  }
  if (max_patterns <= 0) throw std::invalid_argument("max_patterns must be > 0");
}

std::shared_ptr<v1::SimulatorService::Service> MakeSimulatorService(
    std::unique_ptr<SimWorld> world, std::unique_ptr<ArmCollisionChecker> collisions,
    const SimulatorServiceOptions& options) {
  if (world && !world->has_kinematics()) {
    throw std::invalid_argument("SimulatorService: the world needs UR10 kinematics");
  }
  if (world && collisions &&
      !world->cell().config.gripper.X_ToolTcp.isApprox(collisions->gripper().X_ToolTcp, 1e-12)) {
    throw std::invalid_argument(
        "SimulatorService: the world and the collision checker have different grippers "
        "(X_ToolTcp)");
  }
  return std::make_shared<SimulatorServiceImpl>(std::move(world), std::move(collisions), options);
}

runtime::ServiceSet BuildSimulatorServices(const runtime::Config& config) {
  const std::string data_dir = config.GetString("data_dir", apc::DefaultDataDir());
  const std::string cell_path = config.GetPath("cell", world::DefaultCellConfigPath(data_dir));
  const std::string layout_path = config.GetString("layout", "");
  const long long seed = config.GetInt("seed", 1);
  if (seed < 0 || seed > static_cast<long long>(std::numeric_limits<std::uint32_t>::max())) {
    throw std::invalid_argument("setting 'seed' must be in [0, 2^32)");
  }
  SimOptions sim_options;
  sim_options.cup_radius_m = PositiveSetting(config, "tool.cup_radius_m", sim_options.cup_radius_m);
  sim_options.contact_stiffness_n_per_m =
      PositiveSetting(config, "contact.stiffness_n_per_m", sim_options.contact_stiffness_n_per_m);
  SimulatorServiceOptions options;
  options.sealed_kpa = config.GetDouble("suction.sealed_kpa", options.sealed_kpa);
  options.open_kpa = config.GetDouble("suction.open_kpa", options.open_kpa);
  try {
    options.layout_mode = LayoutModeFromString(config.GetString("layout_mode", "tidy"));
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(std::string("setting 'layout_mode': ") + e.what());
  }
  options.Validate();

  // The cell description: the static cell and the gripper (the tool centre point, the tube).
  world::CellModel cell;
  try {
    cell = world::LoadCellModel(world::ReadCellConfig(cell_path));
  } catch (const world::CellConfigError& e) {
    throw std::invalid_argument(std::string("setting 'cell': ") + e.what());
  }
  auto models = std::make_shared<world::ItemModelLibrary>(
      apc::Catalogue::FromCsvFile(data_dir + "/apc2016/items/item_data.csv"));
  auto kinematics =
      std::make_shared<ur10::Ur10Kinematics>(ur10::Ur10Model::Load(data_dir + "/ur10"));
  auto collisions = std::make_unique<ArmCollisionChecker>(cell, *kinematics);
  auto world = std::make_unique<SimWorld>(std::move(cell), models, sim_options, kinematics);
  if (!layout_path.empty()) {
    std::ifstream in(layout_path);
    if (!in) throw std::invalid_argument("setting 'layout': cannot read '" + layout_path + "'");
    std::stringstream text;
    text << in.rdbuf();
    try {
      LoadTaskInto(*world, ParseTaskJson(text.str(), models->catalogue(), layout_path),
                   static_cast<std::uint64_t>(seed), options.layout_mode);
    } catch (const std::exception& e) {
      throw std::invalid_argument(std::string("setting 'layout': ") + e.what());
    }
  }
  runtime::ServiceSet set;
  set.Add(MakeSimulatorService(std::move(world), std::move(collisions), options),
          v1::SimulatorService::service_full_name());
  return set;
}

}  // namespace picking::simulator
