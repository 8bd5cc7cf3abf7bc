#include "services/viewer/service/followers.h"

#include <algorithm>
#include <cctype>
#include <chrono>

#include "libs/proto_convert/proto_convert.h"
#include "libs/runtime/log.h"
#include "picking/detector/v1/detector.pb.h"
#include "picking/orchestrator/v1/orchestrator.grpc.pb.h"
#include "picking/robot/v1/robot.grpc.pb.h"

namespace picking::viewer {
namespace {

namespace pb = picking::orchestrator::v1;
namespace rb = picking::robot::v1;
namespace pc = picking::proto_convert;

constexpr double kCallDeadlineS = 3.0;
constexpr double kRetryMinS = 0.5, kRetryMaxS = 5.0;

void SetDeadline(grpc::ClientContext& ctx, double seconds) {
  ctx.set_deadline(std::chrono::system_clock::now() +
                   std::chrono::milliseconds(static_cast<long long>(seconds * 1000)));
}

// The contract's enum value as the page says it: "STEP_SCAN" -> "scan"; "" when unspecified.
std::string Word(const std::string& enum_name, const std::string& prefix) {
  std::string word = enum_name.rfind(prefix, 0) == 0 ? enum_name.substr(prefix.size()) : enum_name;
  for (char& c : word) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return word == "unspecified" ? "" : word;
}

std::string StepName(pb::Step step) { return Word(pb::Step_Name(step), "STEP_"); }

std::string ContainerOrEmpty(picking::common::v1::Container container) {
  if (container == picking::common::v1::CONTAINER_UNSPECIFIED) return "";
  try {
    return pc::ContainerName(container);
  } catch (const std::exception&) {
    return "";
  }
}

ViewEvent FromProto(const pb::TaskEvent& e) {
  ViewEvent out;
  out.time_s = e.time_s();
  out.item = e.item();
  out.from = ContainerOrEmpty(e.from());
  out.to = ContainerOrEmpty(e.to());
  out.step = StepName(e.step());
  out.ok = e.step_ok();
  out.message = e.message();
  out.items_done = static_cast<int>(e.items_done());
  out.items_total = static_cast<int>(e.items_total());
  out.state = StateName(e.state());
  out.score = e.score();
  out.time_limit_s = e.time_limit_s();
  out.scan_m.assign(e.scan().positions_m().begin(), e.scan().positions_m().end());
  if (e.has_detection()) {
    try {
      ViewEvent::Found found;
      found.X_BaseItem = pc::PoseFromProto(e.detection().x_base_item(), "detection.X_base_item");
      found.score = e.detection().score();
      found.method = Word(picking::detector::v1::Method_Name(e.detection().method()), "METHOD_");
      out.detection = found;
    } catch (const std::exception& error) {
      runtime::LogWarning("event with an invalid detection pose", {{"error", error.what()}});
    }
  }
  for (const auto& q : e.planned_path()) {
    if (q.positions_rad_size() != 6) continue;
    std::array<double, 6> joints{};
    std::copy(q.positions_rad().begin(), q.positions_rad().end(), joints.begin());
    out.planned_path_q.push_back(joints);
  }
  out.planned_head_angle_rad = e.planned_head_angle_rad();
  return out;
}

TaskHeader HeaderFromProto(const pb::GetTaskResponse& task) {
  TaskHeader header;
  header.task_id = task.task_id();
  header.kind = task.kind() == pb::TASK_KIND_STOW ? "stow" : "pick";
  header.state = StateName(task.state());
  for (const pb::WorkItem& w : task.work_order()) {
    header.work_order.emplace_back(w.item(), ContainerOrEmpty(w.from()));
  }
  return header;
}

}  // namespace

std::string StateName(orchestrator::v1::TaskState state) {
  const std::string word = Word(pb::TaskState_Name(state), "TASK_STATE_");
  return word.empty() ? "running" : word;
}

TaskFollower::TaskFollower(std::shared_ptr<grpc::Channel> orchestrator, const ViewerModel& model,
                           std::string task_id)
    : channel_(std::move(orchestrator)), model_(model), task_id_(std::move(task_id)) {
  SetStatus(false, "connecting to the orchestrator");
  store_.Set(
      "task",
      {{"task", nullptr}, {"items", nlohmann::json::array()}, {"log", nlohmann::json::array()}});
  store_.Set("scan", nullptr);
  store_.Set("detections", nlohmann::json::array());
  store_.Set("path", nullptr);
  thread_ = std::thread(&TaskFollower::Run, this);
}

TaskFollower::~TaskFollower() { Stop(); }

void TaskFollower::Stop() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
    if (watch_ != nullptr) watch_->TryCancel();
  }
  wake_.notify_all();
  store_.WakeAll();
  if (thread_.joinable()) thread_.join();
}

void TaskFollower::Pause(double seconds) {
  std::unique_lock<std::mutex> lock(mutex_);
  wake_.wait_for(lock, std::chrono::duration<double>(seconds), [&] { return stop_.load(); });
}

void TaskFollower::SetStatus(bool connected, const std::string& message) {
  store_.SetIfChanged("orchestrator", {{"orchestrator", connected ? "connected" : "unreachable"},
                                       {"message", message}});
}

void TaskFollower::Run() {
  double retry_s = kRetryMinS;
  std::string shown;  // the task whose finished stream has been shown in full
  while (!stop_) {
    try {
      TaskHeader header;
      if (!ChooseTask(header)) {
        Pause(retry_s);
        retry_s = std::min(kRetryMaxS, retry_s * 2);
        continue;
      }
      retry_s = kRetryMinS;
      // A finished task is replayed once; then only a newer task (when following the
      // newest) or a resumed one changes what is shown.
      if (header.state != "running" && header.task_id == shown) {
        Pause(1.0);
        continue;
      }
      if (Watch(header)) shown = header.task_id;
    } catch (const std::exception& e) {
      // Whatever a peer sends, the viewer goes on: it says what went wrong and tries again.
      runtime::LogWarning("following the task failed", {{"error", e.what()}});
      SetStatus(false, std::string("viewer: ") + e.what() + ": retrying");
      Pause(kRetryMaxS);
    }
  }
}

bool TaskFollower::ChooseTask(TaskHeader& header) {
  auto stub = pb::OrchestratorService::NewStub(channel_);
  grpc::ClientContext ctx;
  SetDeadline(ctx, kCallDeadlineS);
  if (!task_id_.empty()) {
    pb::GetTaskRequest request;
    request.set_task_id(task_id_);
    pb::GetTaskResponse task;
    const grpc::Status status = stub->GetTask(&ctx, request, &task);
    if (status.error_code() == grpc::StatusCode::NOT_FOUND) {
      SetStatus(true, "no task '" + task_id_ + "' (yet): retrying");
      return false;
    }
    if (!status.ok()) {
      SetStatus(false, "orchestrator: " + status.error_message() + ": retrying");
      return false;
    }
    header = HeaderFromProto(task);
    return true;
  }
  pb::ListTasksResponse list;
  const grpc::Status status = stub->ListTasks(&ctx, {}, &list);
  if (!status.ok()) {
    SetStatus(false, "orchestrator: " + status.error_message() + ": retrying");
    return false;
  }
  if (list.tasks().empty()) {
    SetStatus(true, "waiting for a task");
    return false;
  }
  // Task ids sort by their start time; a running task is the one to watch.
  const pb::GetTaskResponse* newest = &list.tasks(0);
  for (const pb::GetTaskResponse& t : list.tasks()) {
    const bool running = t.state() == pb::TASK_STATE_RUNNING;
    const bool newest_running = newest->state() == pb::TASK_STATE_RUNNING;
    if ((running && !newest_running) ||
        (running == newest_running && t.task_id() > newest->task_id())) {
      newest = &t;
    }
  }
  header = HeaderFromProto(*newest);
  return true;
}

bool TaskFollower::Watch(const TaskHeader& header) {
  auto stub = pb::OrchestratorService::NewStub(channel_);
  grpc::ClientContext ctx;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stop_) return false;
    watch_ = &ctx;
  }
  // Stop() cancels the call through watch_: cleared however this function ends.
  struct Unwatch {
    TaskFollower* follower;
    ~Unwatch() {
      std::lock_guard<std::mutex> lock(follower->mutex_);
      follower->watch_ = nullptr;
    }
  } unwatch{this};
  TaskView view(model_, header);
  Publish(view, ~0u);
  SetStatus(true, "");
  pb::WatchTaskRequest request;
  request.set_task_id(header.task_id);
  auto reader = stub->WatchTask(&ctx, request);
  pb::WatchTaskResponse response;
  while (reader->Read(&response)) Publish(view, view.Apply(FromProto(response.event())));
  const grpc::Status status = reader->Finish();
  if (!status.ok() && !stop_) {
    SetStatus(false, "orchestrator: " + status.error_message() + ": retrying");
    Pause(kRetryMinS);
  }
  return status.ok();
}

void TaskFollower::Publish(const TaskView& view, unsigned parts) {
  if (parts & TaskView::kTask) store_.Set("task", view.TaskJson());
  if (parts & TaskView::kScan) store_.Set("scan", view.ScanJson());
  if (parts & TaskView::kDetections) store_.Set("detections", view.DetectionsJson());
  if (parts & TaskView::kPath) store_.Set("path", view.PathJson());
}

ArmFollower::ArmFollower(std::shared_ptr<grpc::Channel> robot, const ViewerModel& model,
                         double rate_hz)
    : channel_(std::move(robot)), model_(model), period_s_(1.0 / std::clamp(rate_hz, 0.5, 50.0)) {
  store_.Set("arm", nullptr);
  store_.Set("robot", {{"robot", "unreachable"}, {"message", "connecting to the robot"}});
  thread_ = std::thread(&ArmFollower::Run, this);
}

ArmFollower::~ArmFollower() { Stop(); }

void ArmFollower::Stop() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  wake_.notify_all();
  store_.WakeAll();
  if (thread_.joinable()) thread_.join();
}

void ArmFollower::Pause(double seconds) {
  std::unique_lock<std::mutex> lock(mutex_);
  wake_.wait_for(lock, std::chrono::duration<double>(seconds), [&] { return stop_.load(); });
}

void ArmFollower::Run() {
  auto stub = rb::RobotService::NewStub(channel_);
  double retry_s = kRetryMinS;
  while (!stop_) {
    grpc::ClientContext ctx;
    SetDeadline(ctx, kCallDeadlineS);
    rb::GetStateResponse state;
    const grpc::Status status = stub->GetState(&ctx, {}, &state);
    if (!status.ok() || state.joints().positions_rad_size() != 6) {
      store_.SetIfChanged("robot",
                          {{"robot", "unreachable"},
                           {"message", "robot: " + status.error_message() + ": retrying"}});
      Pause(retry_s);
      retry_s = std::min(kRetryMaxS, retry_s * 2);
      continue;
    }
    retry_s = kRetryMinS;
    store_.SetIfChanged("robot", {{"robot", "connected"}, {"message", ""}});
    ur10::JointVector q;
    for (int i = 0; i < 6; ++i) q[i] = state.joints().positions_rad(i);
    std::optional<Eigen::Vector3d> p_Base_tcp;
    if (state.has_x_base_tcp()) {
      const auto& p = state.x_base_tcp().position();
      p_Base_tcp = Eigen::Vector3d(p.x(), p.y(), p.z());
      if (!p_Base_tcp->allFinite()) p_Base_tcp.reset();
    }
    if (q.allFinite()) store_.SetIfChanged("arm", model_.ArmJson(q, p_Base_tcp));
    Pause(period_s_);
  }
}

}  // namespace picking::viewer
