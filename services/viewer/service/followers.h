#pragma once

#include <grpcpp/channel.h>
#include <grpcpp/client_context.h>

#include <atomic>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "picking/orchestrator/v1/orchestrator.pb.h"
#include "services/viewer/core/part_store.h"
#include "services/viewer/core/task_view.h"
#include "services/viewer/core/viewer_model.h"

namespace picking::viewer {

/// A task's state as the page says it: "running", "succeeded", "failed", "cancelled".
std::string StateName(orchestrator::v1::TaskState state);

/// Follows one task of the orchestrator (`task_id`, or "" for the newest, switching to each
/// new task as it starts): replays its events from the journal, then live, into a TaskView,
/// and publishes the view's parts ("task", "scan", "detections", "path") and how the
/// orchestrator answers ("orchestrator") in its store. Reconnects with backoff for as long
/// as it runs: a viewer started before the orchestrator, or one that lost it, keeps trying.
class TaskFollower final {
 public:
  TaskFollower(std::shared_ptr<grpc::Channel> orchestrator, const ViewerModel& model,
               std::string task_id);
  ~TaskFollower();  ///< Stop()s.
  void Stop();

  PartStore& store() { return store_; }
  const std::string& task_id() const { return task_id_; }

 private:
  void Run();
  /// The task to show: the asked one, or the newest (a running one before finished ones);
  /// false when there is none yet.
  bool ChooseTask(TaskHeader& header);
  /// Streams the task's events into a fresh view until the stream ends (true: the task has
  /// ended and all of it is shown) or fails or Stop().
  bool Watch(const TaskHeader& header);
  void Publish(const TaskView& view, unsigned parts);
  void SetStatus(bool connected, const std::string& message);
  /// Waits `seconds` or until Stop().
  void Pause(double seconds);

  std::shared_ptr<grpc::Channel> channel_;
  const ViewerModel& model_;
  const std::string task_id_;
  PartStore store_;
  std::atomic<bool> stop_{false};
  std::mutex mutex_;
  std::condition_variable wake_;
  grpc::ClientContext* watch_ = nullptr;  ///< The running WatchTask call, for Stop().
  std::thread thread_;
};

/// Reads the robot's joints about `rate_hz` times a second and publishes the arm as the page
/// draws it ("arm") and whether the robot answers ("robot").
class ArmFollower final {
 public:
  ArmFollower(std::shared_ptr<grpc::Channel> robot, const ViewerModel& model, double rate_hz);
  ~ArmFollower();
  void Stop();
  PartStore& store() { return store_; }

 private:
  void Run();
  void Pause(double seconds);

  std::shared_ptr<grpc::Channel> channel_;
  const ViewerModel& model_;
  const double period_s_;
  PartStore store_;
  std::atomic<bool> stop_{false};
  std::mutex mutex_;
  std::condition_variable wake_;
  std::thread thread_;
};

}  // namespace picking::viewer
