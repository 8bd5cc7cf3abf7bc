#include "services/orchestrator/core/task_manager.h"

#include <chrono>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <optional>
#include <sstream>

#include "libs/errors/errors.h"

namespace picking::orchestrator {
namespace fs = std::filesystem;
namespace {

std::string ReadText(const fs::path& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

void WriteText(const fs::path& path, const std::string& text) {
  const fs::path temp = path.string() + ".tmp";
  {
    std::ofstream out(temp);
    out << text;
    if (!out) throw std::runtime_error(temp.string() + ": write failed");
  }
  fs::rename(temp, path);
}

Step StepFromName(const std::string& name) {
  for (Step s :
       {Step::kScan, Step::kDetect, Step::kPlan, Step::kGrasp, Step::kVerify, Step::kPlace}) {
    if (StepName(s) == name) return s;
  }
  return Step::kNone;
}

TaskEvent EventFromRecord(const JournalRecord& r) {
  TaskEvent e;
  e.time_s = r.time_s;
  e.item = r.data.value("item", "");
  e.from = r.data.value("from", "");
  e.to = r.data.value("to", "");
  e.step = StepFromName(r.data.value("step", ""));
  e.ok = r.data.value("ok", true);
  e.message = r.data.value("message", "");
  e.items_done = r.data.value("done", 0);
  e.items_total = r.data.value("total", 0);
  e.score = r.data.value("score", 0);
  e.time_limit_s = r.data.value("time_limit_s", 0.0);
  if (r.data.contains("scene")) e.scene = EventScene::FromJson(r.data.at("scene"));
  return e;
}

// The journal's work order, [[item, container], ...]; what is not in that form is left out
// (a journal from an older orchestrator has none).
std::vector<std::pair<std::string, std::string>> WorkOrderFromJson(const nlohmann::json& json) {
  std::vector<std::pair<std::string, std::string>> out;
  if (!json.is_array()) return out;
  for (const nlohmann::json& entry : json) {
    if (entry.is_array() && entry.size() == 2 && entry[0].is_string() && entry[1].is_string()) {
      out.emplace_back(entry[0].get<std::string>(), entry[1].get<std::string>());
    }
  }
  return out;
}

// The last event of a task: its end state, and the score or the error.
TaskEvent FinalEvent(const std::vector<TaskEvent>& events, TaskState state,
                     const std::string& error, int score, double duration_s, int items_done,
                     int items_total) {
  TaskEvent last;
  last.sequence = events.empty() ? 0 : events.back().sequence + 1;
  last.time_s = duration_s;
  last.message = state == TaskState::kFailed ? error : "score " + std::to_string(score);
  last.items_done = items_done;
  last.items_total = items_total;
  last.state = state;
  last.score = score;
  if (!events.empty()) last.time_limit_s = events.back().time_limit_s;
  return last;
}

}  // namespace

TaskManager::TaskManager(TaskManagerOptions options, const apc::Catalogue& catalogue,
                         CellFactory cell)
    : options_(std::move(options)), catalogue_(catalogue), cell_factory_(std::move(cell)) {
  fs::create_directories(options_.data_dir);
  LoadFromDisk();
}

TaskManager::~TaskManager() { Shutdown(60.0); }

void TaskManager::Shutdown(double wait_s) {
  std::unique_lock<std::mutex> lock(mutex_);
  for (auto& [id, entry] : tasks_) entry->cancel = true;
  changed_.wait_for(lock, std::chrono::duration<double>(wait_s), [&] { return !running_; });
  const bool stopped = !running_;
  lock.unlock();
  if (!worker_.joinable()) return;
  if (stopped) {
    worker_.join();
  } else {
    worker_.detach();
  }
}

// Tasks of an earlier process: their journal says how far they got; one without an "end"
// record was interrupted and can be resumed.
void TaskManager::LoadFromDisk() {
  std::vector<fs::path> dirs;
  for (const auto& d : fs::directory_iterator(options_.data_dir)) {
    if (d.is_directory() && fs::exists(d.path() / "journal.jsonl")) dirs.push_back(d.path());
  }
  std::sort(dirs.begin(), dirs.end());
  for (const fs::path& dir : dirs) {
    auto entry = std::make_shared<Entry>();
    entry->dir = dir.string();
    entry->info.task_id = dir.filename().string();
    entry->info.state = TaskState::kFailed;
    entry->info.error = "interrupted (the orchestrator stopped); resume it with resume_task_id";
    std::optional<JournalRecord> end;
    for (const JournalRecord& r : Journal::Read((dir / "journal.jsonl").string())) {
      if (r.type == "task") {
        entry->info.kind = r.data.value("kind", "pick");
        entry->info.work_order = WorkOrderFromJson(r.data.value("work_order", nlohmann::json()));
      }
      if (r.type == "event") {
        entry->events.push_back(EventFromRecord(r));
        entry->events.back().sequence = entry->events.size() - 1;  // events count 0, 1, ...
      }
      if (r.type == "end") end = r;
    }
    if (!entry->events.empty()) {
      entry->info.items_done = entry->events.back().items_done;
      entry->info.items_total = entry->events.back().items_total;
    }
    if (end) {
      entry->info.state = static_cast<TaskState>(end->data.value("state", 3));
      entry->info.error = end->data.value("error", "");
      // Watchers of a finished task see how it ended, as they would have live.
      entry->events.push_back(FinalEvent(
          entry->events, entry->info.state, entry->info.error, end->data.value("score", 0),
          end->time_s, end->data.value("moved", entry->info.items_done), entry->info.items_total));
    }
    if (fs::exists(dir / "output.json")) {
      entry->info.output_json = ReadText(dir / "output.json");
      entry->info.output_file = (dir / "output.json").string();
      entry->info.report_file = (dir / "report.html").string();
    }
    tasks_[entry->info.task_id] = entry;
    order_.push_back(entry->info.task_id);
  }
}

std::string TaskManager::NewTaskId() {
  const std::time_t now = std::time(nullptr);
  std::tm utc{};
  gmtime_r(&now, &utc);
  char stamp[32];
  std::strftime(stamp, sizeof stamp, "%Y%m%d-%H%M%S", &utc);
  std::string id;
  do {
    id = std::string("task-") + stamp + "-" + std::to_string(++counter_);
  } while (tasks_.count(id) > 0 || fs::exists(fs::path(options_.data_dir) / id));
  return id;
}

std::pair<apc::Task, std::vector<Target>> TaskManager::Prepare(const std::string& task_json,
                                                               const StartSpec& spec) const {
  apc::Task task;
  try {
    task = apc::ParseTask(task_json, catalogue_, "task_json");
  } catch (const apc::TaskFileError& e) {
    // The contract: an unknown item is NOT_FOUND, any other fault of the file INVALID_ARGUMENT.
    if (std::string(e.what()).find("unknown item") != std::string::npos) {
      throw NotFoundError(e.what());
    }
    throw std::invalid_argument(e.what());
  }
  const bool stow = task.kind == apc::TaskKind::kStow;
  if ((spec.kind == "stow" && !stow) || (spec.kind == "pick" && stow)) {
    throw std::invalid_argument("kind: the request says " + spec.kind + ", the task file is a " +
                                (stow ? "stow task (no work_order)" : "pick task (a work_order)"));
  }
  if (spec.time_limit_s < 0.0 || !std::isfinite(spec.time_limit_s) || spec.time_limit_s > 86400) {
    throw std::invalid_argument("time_limit_s: must be in [0, 86400] s");
  }
  std::vector<Target> order =
      OrderTargets(task, catalogue_, options_.ease, options_.preferred_method, spec.ease_order);
  return {std::move(task), std::move(order)};
}

void TaskManager::Validate(const StartSpec& spec) const {
  if (!spec.resume_task_id.empty()) {
    std::lock_guard<std::mutex> lock(mutex_);
    Find(spec.resume_task_id);
    return;
  }
  Prepare(spec.task_json, spec);
}

std::string TaskManager::Start(const StartSpec& spec) {
  std::unique_lock<std::mutex> lock(mutex_);
  if (running_) throw PreconditionError("a task is running; one task at a time per cell");
  std::string task_json = spec.task_json;
  std::shared_ptr<Entry> entry;
  if (!spec.resume_task_id.empty()) {
    const auto it = tasks_.find(spec.resume_task_id);
    if (it == tasks_.end()) throw NotFoundError("no task '" + spec.resume_task_id + "'");
    entry = it->second;
    if (entry->info.state == TaskState::kSucceeded || entry->info.state == TaskState::kCancelled) {
      throw PreconditionError("task '" + spec.resume_task_id + "' has already ended");
    }
    task_json = ReadText(fs::path(entry->dir) / "task.json");
  }
  auto [task, order] = Prepare(task_json, spec);
  PickTaskOptions options = options_.pick;
  if (spec.time_limit_s > 0.0) options.time_limit_s = spec.time_limit_s;
  if (!entry) {
    entry = std::make_shared<Entry>();
    entry->info.task_id = NewTaskId();
    entry->dir = (fs::path(options_.data_dir) / entry->info.task_id).string();
    fs::create_directories(entry->dir);
    WriteText(fs::path(entry->dir) / "task.json", task_json);
    tasks_[entry->info.task_id] = entry;
    order_.push_back(entry->info.task_id);
  }
  entry->info.kind = task.kind == apc::TaskKind::kStow ? "stow" : "pick";
  entry->info.state = TaskState::kRunning;
  entry->info.error.clear();
  entry->info.items_total = static_cast<int>(order.size());
  entry->info.work_order.clear();
  for (const Target& t : order) entry->info.work_order.emplace_back(t.item, t.bin);
  entry->cancel = false;
  if (worker_.joinable()) worker_.join();
  running_ = true;
  worker_ = std::thread(&TaskManager::RunTask, this, entry, task, std::move(order), options);
  return entry->info.task_id;
}

void TaskManager::RunTask(std::shared_ptr<Entry> entry, apc::Task task, std::vector<Target> order,
                          PickTaskOptions options) {
  PickTaskResult result;
  try {
    Journal journal((fs::path(entry->dir) / "journal.jsonl").string());
    if (journal.Records().empty()) {
      journal.Append("task", "", 0.0,
                     {{"kind", entry->info.kind}, {"work_order", entry->info.work_order}});
    }
    std::unique_ptr<CellPort> cell = cell_factory_();
    auto emit = [&](const TaskEvent& e) {
      std::lock_guard<std::mutex> lock(mutex_);
      entry->events.push_back(e);
      entry->info.items_done = e.items_done;
      changed_.notify_all();
    };
    PickTaskRunner runner(task, std::move(order), catalogue_, options, *cell, journal, emit,
                          entry->cancel);
    result = runner.Run();
    const auto [output, report] =
        WriteTaskFiles(entry->dir, entry->info.task_id, result, entry->events, options_.viewer_url);
    journal.Append("end", "", result.duration_s,
                   {{"state", static_cast<int>(result.state)},
                    {"error", result.error},
                    {"score", result.score.total},
                    {"moved", result.items_moved}});
    std::lock_guard<std::mutex> lock(mutex_);
    entry->info.output_file = output;
    entry->info.report_file = report;
    entry->info.output_json = ReadText(output);
  } catch (const std::exception& e) {
    result.state = TaskState::kFailed;
    result.error = e.what();
  }
  std::lock_guard<std::mutex> lock(mutex_);
  entry->info.state = result.state;
  entry->info.error = result.error;
  entry->info.items_done = result.items_moved;
  entry->info.has_result = true;
  entry->info.result = result;
  entry->events.push_back(FinalEvent(entry->events, result.state, result.error, result.score.total,
                                     result.duration_s, result.items_moved,
                                     entry->info.items_total));
  running_ = false;
  changed_.notify_all();
}

std::shared_ptr<TaskManager::Entry> TaskManager::Find(const std::string& task_id) const {
  const auto it = tasks_.find(task_id);
  if (it == tasks_.end()) throw NotFoundError("no task '" + task_id + "'");
  return it->second;
}

TaskInfo TaskManager::Get(const std::string& task_id) const {
  std::lock_guard<std::mutex> lock(mutex_);
  return Find(task_id)->info;
}

std::vector<TaskInfo> TaskManager::List() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<TaskInfo> out;
  for (auto it = order_.rbegin(); it != order_.rend(); ++it) out.push_back(tasks_.at(*it)->info);
  return out;
}

void TaskManager::Cancel(const std::string& task_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto entry = Find(task_id);
  if (entry->info.state != TaskState::kRunning) {
    throw PreconditionError("task '" + task_id + "' is not running");
  }
  entry->cancel = true;
}

void TaskManager::Watch(const std::string& task_id,
                        const std::function<void(const TaskEvent&)>& on_event,
                        const std::function<bool()>& stop, double poll_s) const {
  std::unique_lock<std::mutex> lock(mutex_);
  const auto entry = Find(task_id);
  std::size_t next = 0;
  for (;;) {
    while (next < entry->events.size()) {
      const TaskEvent e = entry->events[next++];
      lock.unlock();
      on_event(e);
      lock.lock();
    }
    // The last event and the end state are set under one lock: nothing follows an end.
    if (entry->info.state != TaskState::kRunning || stop()) return;
    changed_.wait_for(lock, std::chrono::duration<double>(poll_s));
  }
}

}  // namespace picking::orchestrator
