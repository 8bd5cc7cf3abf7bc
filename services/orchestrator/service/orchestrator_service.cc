#include "services/orchestrator/service/orchestrator_service.h"

#include <atomic>

#include "libs/apc/catalogue.h"
#include "libs/proto_convert/proto_convert.h"
#include "libs/runtime/channel.h"
#include "libs/runtime/status.h"
#include "libs/world/cell_config.h"
#include "libs/world/item_shapes.h"
#include "services/orchestrator/core/task_manager.h"
#include "services/orchestrator/detector_pool/detector_pool.h"
#include "services/orchestrator/service/grpc_cell.h"

namespace picking::orchestrator {
namespace {

namespace pb = ::picking::orchestrator::v1;
namespace dt = ::picking::detector::v1;

pb::TaskState ToProto(TaskState s) {
  switch (s) {
    case TaskState::kRunning:
      return pb::TASK_STATE_RUNNING;
    case TaskState::kSucceeded:
      return pb::TASK_STATE_SUCCEEDED;
    case TaskState::kFailed:
      return pb::TASK_STATE_FAILED;
    case TaskState::kCancelled:
      return pb::TASK_STATE_CANCELLED;
  }
  return pb::TASK_STATE_UNSPECIFIED;
}

pb::Step ToProto(Step s) {
  switch (s) {
    case Step::kScan:
      return pb::STEP_SCAN;
    case Step::kDetect:
      return pb::STEP_DETECT;
    case Step::kPlan:
      return pb::STEP_PLAN;
    case Step::kGrasp:
      return pb::STEP_GRASP;
    case Step::kVerify:
      return pb::STEP_VERIFY;
    case Step::kPlace:
      return pb::STEP_PLACE;
    case Step::kNone:
      break;
  }
  return pb::STEP_UNSPECIFIED;
}

common::v1::Container ContainerOrUnspecified(const std::string& name) {
  if (name.empty()) return common::v1::CONTAINER_UNSPECIFIED;
  return proto_convert::ContainerFromName(name);
}

// The detector's method as the pick journals it (its contract's name, "METHOD_PPF").
dt::Method MethodToProto(const std::string& name) {
  dt::Method method = dt::METHOD_UNSPECIFIED;
  return dt::Method_Parse(name, &method) ? method : dt::METHOD_UNSPECIFIED;
}

void SceneToProto(const EventScene& scene, pb::TaskEvent* out) {
  if (!scene.scan_Base.empty()) {
    auto* positions = out->mutable_scan()->mutable_positions_m();
    positions->Reserve(static_cast<int>(scene.scan_Base.size() * 3));
    for (const Eigen::Vector3f& p : scene.scan_Base) {
      positions->Add(p.x());
      positions->Add(p.y());
      positions->Add(p.z());
    }
  }
  if (scene.detected) {
    pb::ItemDetection* detection = out->mutable_detection();
    *detection->mutable_x_base_item() = proto_convert::PoseToProto(scene.X_BaseItem);
    detection->set_score(scene.detection_score);
    detection->set_method(MethodToProto(scene.method));
  }
  for (const auto& q : scene.planned_path_q) {
    out->add_planned_path()->mutable_positions_rad()->Add(q.begin(), q.end());
  }
  out->set_planned_head_angle_rad(scene.head_angle_rad);
}

pb::TaskEvent ToProto(const TaskEvent& e) {
  pb::TaskEvent out;
  out.set_sequence(e.sequence);
  out.set_time_s(e.time_s);
  out.set_item(e.item);
  out.set_from(ContainerOrUnspecified(e.from));
  out.set_to(ContainerOrUnspecified(e.to));
  out.set_step(ToProto(e.step));
  out.set_step_ok(e.ok);
  out.set_message(e.message);
  out.set_items_done(e.items_done);
  out.set_items_total(e.items_total);
  out.set_state(ToProto(e.state));
  out.set_score(e.score);
  out.set_time_limit_s(e.time_limit_s);
  SceneToProto(e.scene, &out);
  return out;
}

void ToProto(const TaskInfo& info, pb::GetTaskResponse* out) {
  out->set_task_id(info.task_id);
  out->set_kind(info.kind == "stow" ? pb::TASK_KIND_STOW : pb::TASK_KIND_PICK);
  out->set_state(ToProto(info.state));
  out->set_items_done(info.items_done);
  out->set_items_total(info.items_total);
  for (const auto& [item, from] : info.work_order) {
    pb::WorkItem* w = out->add_work_order();
    w->set_item(item);
    w->set_from(ContainerOrUnspecified(from));
  }
  out->set_error(info.error);
  if (info.state == TaskState::kRunning) return;
  auto* result = out->mutable_result();
  result->set_output_json(info.output_json);
  result->set_output_file(info.output_file);
  result->set_report_file(info.report_file);
  if (!info.has_result) return;
  result->set_score(info.result.score.total);
  for (const apc::ScoreLine& line : info.result.score.lines) {
    auto* l = result->add_score_lines();
    l->set_points(line.points);
    l->set_reason(line.reason);
  }
  result->set_items_moved(info.result.items_moved);
  result->set_items_failed(info.result.items_failed);
  result->set_duration_s(info.result.duration_s);
}

struct Peer {
  std::string name, address;
  std::shared_ptr<grpc::Channel> channel;
};

// UNAVAILABLE naming the first peer that does not connect within `wait_s`.
grpc::Status CheckPeers(const std::vector<Peer>& peers, double wait_s) {
  const auto deadline = std::chrono::system_clock::now() +
                        std::chrono::milliseconds(static_cast<long long>(wait_s * 1000));
  for (const Peer& peer : peers) {
    if (!peer.channel->WaitForConnected(deadline)) {
      return runtime::Unavailable("the " + peer.name + " at " + peer.address +
                                  " does not answer; start it or set " + peer.name + ".address");
    }
  }
  return grpc::Status::OK;
}

class OrchestratorServiceImpl final : public pb::OrchestratorService::Service {
 public:
  OrchestratorServiceImpl(std::shared_ptr<TaskManager> tasks, std::vector<Peer> peers,
                          std::shared_ptr<DetectorPool> detectors)
      : tasks_(std::move(tasks)), peers_(std::move(peers)), detectors_(std::move(detectors)) {}

  grpc::Status StartTask(grpc::ServerContext*, const pb::StartTaskRequest* request,
                         pb::StartTaskResponse* response) override {
    return runtime::Guard([&] {
      StartSpec spec;
      spec.task_json = request->task_json();
      spec.kind = request->kind() == pb::TASK_KIND_STOW   ? "stow"
                  : request->kind() == pb::TASK_KIND_PICK ? "pick"
                                                          : "";
      spec.ease_order.assign(request->ease_order().begin(), request->ease_order().end());
      spec.time_limit_s = request->time_limit_s();
      spec.resume_task_id = request->resume_task_id();
      if (spec.task_json.empty() && spec.resume_task_id.empty()) {
        return runtime::InvalidArgument("task_json: empty (give the task file's JSON text)");
      }
      tasks_->Validate(spec);  // a bad task file is refused before the peers are asked
      const grpc::Status peers = CheckPeers(peers_, 3.0);
      if (!peers.ok()) return peers;
      // Detection needs one live replica; the pool takes dead ones out and back by itself.
      detectors_->CheckHealthNow();
      bool any_detector = false;
      for (const ReplicaSnapshot& r : detectors_->Snapshot()) any_detector |= r.healthy;
      if (!any_detector) {
        return runtime::Unavailable(
            "no detector replica answers (detector.endpoints); start one or fix the setting");
      }
      response->set_task_id(tasks_->Start(spec));
      return grpc::Status::OK;
    });
  }

  grpc::Status WatchTask(grpc::ServerContext* ctx, const pb::WatchTaskRequest* request,
                         grpc::ServerWriter<pb::WatchTaskResponse>* writer) override {
    return runtime::Guard([&] {
      std::atomic<bool> broken{false};
      tasks_->Watch(
          request->task_id(),
          [&](const TaskEvent& e) {
            if (broken) return;
            pb::WatchTaskResponse response;
            *response.mutable_event() = ToProto(e);
            if (!writer->Write(response)) broken = true;
          },
          [&] { return broken.load() || ctx->IsCancelled() || runtime::ShuttingDown(); });
      if (runtime::ShuttingDown()) {
        return runtime::Unavailable("the orchestrator is shutting down; watch again later");
      }
      return grpc::Status::OK;
    });
  }

  grpc::Status GetTask(grpc::ServerContext*, const pb::GetTaskRequest* request,
                       pb::GetTaskResponse* response) override {
    return runtime::Guard([&] {
      ToProto(tasks_->Get(request->task_id()), response);
      return grpc::Status::OK;
    });
  }

  grpc::Status ListTasks(grpc::ServerContext*, const pb::ListTasksRequest*,
                         pb::ListTasksResponse* response) override {
    return runtime::Guard([&] {
      for (const TaskInfo& info : tasks_->List()) ToProto(info, response->add_tasks());
      return grpc::Status::OK;
    });
  }

  grpc::Status CancelTask(grpc::ServerContext*, const pb::CancelTaskRequest* request,
                          pb::CancelTaskResponse*) override {
    return runtime::Guard([&] {
      tasks_->Cancel(request->task_id());
      return grpc::Status::OK;
    });
  }

  void Shutdown(double wait_s) { tasks_->Shutdown(wait_s); }

 private:
  std::shared_ptr<TaskManager> tasks_;
  std::vector<Peer> peers_;
  std::shared_ptr<DetectorPool> detectors_;
};

// A peer's address: `<service>.address`, by default the service's name on port 50051 (the
// names docker-compose and Kubernetes give them).
std::string Address(const runtime::Config& config, const std::string& service) {
  return config.GetString(service + ".address", service + ":50051");
}

std::shared_ptr<grpc::Channel> Channel(const runtime::Config& config,
                                       const runtime::ChannelFactory& channels,
                                       const std::string& service) {
  const std::string key = service + ".address";
  const std::string address = Address(config, service);
  if (address.empty()) throw std::invalid_argument("setting '" + key + "': empty");
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(256 << 20);
  args.SetMaxSendMessageSize(256 << 20);
  return channels.Connect(address, args);
}

// Detect through the pool of replicas: the items spread over them, each job retried on
// another replica when one does not answer.
DetectFn PoolDetector(std::shared_ptr<DetectorPool> pool) {
  return
      [pool](const dt::DetectParams& params, const std::vector<common::v1::PointCloudChunk>& chunks,
             dt::DetectResponse* response, std::string* replica) {
        DetectCall call;
        call.params = params;
        call.cloud = std::make_shared<const std::vector<common::v1::PointCloudChunk>>(chunks);
        // The item queries (the target, the bin's other items) spread over the replicas.
        DetectOutcome outcome = pool->DetectSpread(call);
        *replica = outcome.replica;
        if (outcome.ok()) *response = std::move(outcome.response);
        return outcome.status;
      };
}

// Verify through the pool, as Detect.
VerifyFn PoolVerifier(std::shared_ptr<DetectorPool> pool) {
  return
      [pool](const dt::VerifyParams& params, const std::vector<common::v1::PointCloudChunk>& chunks,
             dt::VerifyResponse* response) {
        VerifyCall call;
        call.params = params;
        call.cloud = std::make_shared<const std::vector<common::v1::PointCloudChunk>>(chunks);
        VerifyOutcome outcome = pool->Verify(call);
        if (outcome.ok()) *response = std::move(outcome.response);
        return outcome.status;
      };
}

// Setting `key`: which items are set down on the table and told apart there first.
PickTaskOptions::TableCheck TableCheckSetting(const runtime::Config& config,
                                              const std::string& key) {
  using TableCheck = PickTaskOptions::TableCheck;
  const std::string table = config.GetString(key, "never");
  if (table == "in_doubt") return TableCheck::kInDoubt;
  if (table == "always") return TableCheck::kAlways;
  if (table == "never") return TableCheck::kNever;
  throw std::invalid_argument("setting '" + key + "' must be in_doubt, always or never, got '" +
                              table.substr(0, 40) + "'");
}

}  // namespace

runtime::ServiceSet BuildOrchestratorServices(const runtime::Config& config) {
  const std::string data_dir = config.GetString("data_dir", apc::DefaultDataDir());
  static const apc::Catalogue catalogue =
      apc::Catalogue::FromCsvFile(data_dir + "/apc2016/items/item_data.csv");
  TaskManagerOptions options;
  options.data_dir = config.GetPath("tasks_dir", "picking-tasks");
  options.ease =
      EaseTable::FromYamlFile(config.GetPath("ease", data_dir + "/orchestrator/ease.yaml"));
  options.preferred_method =
      ReadPreferredMethods(config.GetPath("detector_models", data_dir + "/detector/models.json"));
  options.viewer_url = config.GetString("viewer.url", "");
  if (!options.viewer_url.empty() && options.viewer_url.rfind("http://", 0) != 0 &&
      options.viewer_url.rfind("https://", 0) != 0) {
    throw std::invalid_argument("setting 'viewer.url': must start with http:// or https://");
  }
  options.pick.time_limit_s = config.GetDouble("time_limit_s", options.pick.time_limit_s);
  options.pick.max_attempts =
      static_cast<int>(config.GetInt("max_attempts", options.pick.max_attempts));
  options.pick.min_time_per_item_s =
      config.GetDouble("min_time_per_item_s", options.pick.min_time_per_item_s);
  options.pick.detect_ahead = config.GetBool("detect_ahead", options.pick.detect_ahead);
  options.pick.table_check = TableCheckSetting(config, "stow.table");
  options.pick.pick_table_check = TableCheckSetting(config, "pick.table");
  options.pick.make_room = config.GetBool("pick.make_room", options.pick.make_room);
  options.pick.max_room_moves =
      static_cast<int>(config.GetInt("pick.max_room_moves", options.pick.max_room_moves));
  if (options.pick.time_limit_s <= 0.0 || options.pick.max_attempts < 1) {
    throw std::invalid_argument("time_limit_s must be > 0 and max_attempts >= 1");
  }
  if (options.pick.max_room_moves < 0 || options.pick.max_room_moves > 12) {
    throw std::invalid_argument("setting 'pick.max_room_moves': must be in [0, 12]");
  }
  GrpcCellOptions cell;
  const std::string cell_path = config.GetPath("cell", world::DefaultCellConfigPath(data_dir));
  cell.cell = world::LoadCellModel(world::ReadCellConfig(cell_path));
  const world::ShapeTable shapes = world::ShapeTable::FromYamlFile(
      config.GetPath("shapes", data_dir + "/items/shapes.yaml"), catalogue);
  for (const apc::Item& item : catalogue.items()) {
    cell.item_size_m[item.name] = world::ModelledSize(item, shapes.at(item.name));
  }
  for (const world::BinGeometry& bin : cell.cell.bins) {
    options.pick.bin_volume_m3[bin.name] = bin.inner_S.volume();
  }
  options.pick.max_bin_fill = config.GetDouble("stow.max_bin_fill", options.pick.max_bin_fill);
  // Every peer, the detector replicas included, is called with this server's tls.* settings.
  const runtime::ChannelFactory channels = runtime::ChannelFactory::FromConfig(config);
  cell.scanner = Channel(config, channels, "scanner");
  cell.planner = Channel(config, channels, "planner");
  cell.robot = Channel(config, channels, "robot");
  cell.gripper = Channel(config, channels, "gripper");
  DetectorPoolOptions pool_options = FromConfig(config);
  pool_options.channels = channels;
  auto pool = std::make_shared<DetectorPool>(std::move(pool_options));
  cell.detect = PoolDetector(pool);
  cell.verify = PoolVerifier(pool);
  std::vector<Peer> peers;
  for (const std::string name : {"scanner", "planner", "robot", "gripper"}) {
    peers.push_back({name, Address(config, name), Channel(config, channels, name)});
  }
  const double shutdown_wait_s = config.GetDouble("shutdown_wait_s", 3.0);
  auto tasks = std::make_shared<TaskManager>(options, catalogue,
                                             [cell] { return std::make_unique<GrpcCell>(cell); });
  auto service =
      std::make_shared<OrchestratorServiceImpl>(std::move(tasks), std::move(peers), pool);
  runtime::ServiceSet set;
  set.Add(service, pb::OrchestratorService::service_full_name());
  set.on_shutdown = [service, shutdown_wait_s] { service->Shutdown(shutdown_wait_s); };
  return set;
}

}  // namespace picking::orchestrator
