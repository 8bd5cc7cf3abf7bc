#pragma once

#include <chrono>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>

#include "services/planner/core/motion_planner.h"

namespace picking::planner {

/// Planning scenes kept between requests, by id, each for a time after its last use. The
/// oldest scene is dropped when the store is full. Thread-safe.
class SceneStore final {
 public:
  using Clock = std::function<std::chrono::steady_clock::time_point()>;

  /// `clock` is injected for tests (default: the steady clock).
  explicit SceneStore(std::size_t max_scenes = 32, Clock clock = nullptr);

  /// Stores `scene` under a new id (or replaces `id` if not empty) for `ttl_s` seconds.
  std::string Put(std::shared_ptr<const PlanningScene> scene, double ttl_s,
                  const std::string& id = "");
  /// The scene with `id`, its expiry pushed back; throws NotFoundError if unknown or expired.
  std::shared_ptr<const PlanningScene> Get(const std::string& id);
  std::size_t size() const;

 private:
  struct Entry {
    std::shared_ptr<const PlanningScene> scene;
    double ttl_s = 0.0;
    std::chrono::steady_clock::time_point expires;
    std::uint64_t order = 0;
  };
  void DropExpired(std::chrono::steady_clock::time_point now);

  std::size_t max_scenes_;
  Clock clock_;
  mutable std::mutex mutex_;
  std::map<std::string, Entry> scenes_;
  std::uint64_t next_ = 1;
};

}  // namespace picking::planner
