#pragma once

#include <atomic>
#include <condition_variable>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "libs/apc/catalogue.h"
#include "services/orchestrator/core/pick_task.h"

namespace picking::orchestrator {

struct TaskManagerOptions {
  /// Each task gets a folder here: task.json, journal.jsonl, output.json, report.json and
  /// report.html.
  std::string data_dir;
  PickTaskOptions pick;
  EaseTable ease;
  std::map<std::string, std::string> preferred_method;  ///< ReadPreferredMethods.
  /// The viewer's page (e.g. http://localhost:8080/): the report links each item to its view
  /// there; empty for no links.
  std::string viewer_url;
};

struct StartSpec {
  std::string task_json;
  std::string kind;  ///< "", "pick" or "stow".
  std::vector<std::string> ease_order;
  double time_limit_s = 0.0;  ///< 0: the options' limit.
  std::string resume_task_id;
};

struct TaskInfo {
  std::string task_id;
  std::string kind = "pick";
  TaskState state = TaskState::kRunning;
  int items_done = 0, items_total = 0;
  /// The targets in the order they are attempted: (item, container).
  std::vector<std::pair<std::string, std::string>> work_order;
  std::string error;
  bool has_result = false;
  PickTaskResult result;
  std::string output_json;
  std::string output_file, report_file;
};

/// Runs tasks one at a time per cell on a background thread, keeps their events for watchers
/// and their files on disk; tasks found on disk at start (an earlier process) are listed and
/// can be resumed.
class TaskManager final {
 public:
  using CellFactory = std::function<std::unique_ptr<CellPort>()>;
  TaskManager(TaskManagerOptions options, const apc::Catalogue& catalogue, CellFactory cell);
  /// Shutdown(60): cancels a running task and waits for it to stop at its next step.
  ~TaskManager();
  /// Cancels a running task and waits up to `wait_s` for it to stop; a task still busy then
  /// (a long motion) is left to end with the process: its journal holds what was done, and it
  /// is listed as interrupted, resumable, by the next orchestrator.
  void Shutdown(double wait_s);

  /// Validates and starts. Throws std::invalid_argument (malformed task, ease order),
  /// apc::TaskFileError (names the field), NotFoundError (unknown resume id),
  /// PreconditionError (a task is running; resuming a finished task).
  std::string Start(const StartSpec& spec);
  /// The checks of Start without starting: throws as Start does for a bad request.
  void Validate(const StartSpec& spec) const;
  /// Throws NotFoundError.
  TaskInfo Get(const std::string& task_id) const;
  std::vector<TaskInfo> List() const;
  /// Throws NotFoundError; PreconditionError if the task has ended.
  void Cancel(const std::string& task_id);
  /// Calls `on_event` for each event of the task from its first, then live until the task
  /// ends or `stop()` returns true (polled at least every `poll_s`). Throws NotFoundError.
  void Watch(const std::string& task_id, const std::function<void(const TaskEvent&)>& on_event,
             const std::function<bool()>& stop, double poll_s = 0.2) const;

 private:
  struct Entry {
    TaskInfo info;
    std::vector<TaskEvent> events;
    std::atomic<bool> cancel{false};
    std::string dir;
  };
  void RunTask(std::shared_ptr<Entry> entry, apc::Task task, std::vector<Target> order,
               PickTaskOptions options);
  void LoadFromDisk();
  /// The task file parsed and the targets ordered; throws std::invalid_argument naming the
  /// field, NotFoundError for an unknown item.
  std::pair<apc::Task, std::vector<Target>> Prepare(const std::string& task_json,
                                                    const StartSpec& spec) const;
  std::shared_ptr<Entry> Find(const std::string& task_id) const;
  std::string NewTaskId();

  TaskManagerOptions options_;
  const apc::Catalogue& catalogue_;
  CellFactory cell_factory_;
  mutable std::mutex mutex_;
  mutable std::condition_variable changed_;
  std::map<std::string, std::shared_ptr<Entry>> tasks_;
  std::vector<std::string> order_;  ///< Task ids, oldest first.
  std::thread worker_;
  bool running_ = false;
  int counter_ = 0;
};

/// Writes output.json (the APC output file), report.json and report.html of a finished task
/// into `dir`; returns the paths of the output and the HTML report. With a `viewer_url`, the
/// report links each item to the task's view there (`<viewer_url>?task=ID&item=NAME`).
std::pair<std::string, std::string> WriteTaskFiles(const std::string& dir,
                                                   const std::string& task_id,
                                                   const PickTaskResult& result,
                                                   const std::vector<TaskEvent>& events,
                                                   const std::string& viewer_url = "");

}  // namespace picking::orchestrator
