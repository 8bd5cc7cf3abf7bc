#include "services/planner/core/scene_store.h"

#include <cmath>
#include <stdexcept>

#include "libs/errors/errors.h"

namespace picking::planner {

SceneStore::SceneStore(std::size_t max_scenes, Clock clock)
    : max_scenes_(std::max<std::size_t>(1, max_scenes)), clock_(std::move(clock)) {
  if (!clock_) clock_ = [] { return std::chrono::steady_clock::now(); };
}

void SceneStore::DropExpired(std::chrono::steady_clock::time_point now) {
  for (auto it = scenes_.begin(); it != scenes_.end();) {
    it = it->second.expires < now ? scenes_.erase(it) : std::next(it);
  }
}

std::string SceneStore::Put(std::shared_ptr<const PlanningScene> scene, double ttl_s,
                            const std::string& id) {
  if (!(ttl_s > 0.0) || !std::isfinite(ttl_s) || ttl_s > 86400.0) {
    throw std::invalid_argument("scene ttl must be in (0, 86400] s");
  }
  std::lock_guard<std::mutex> lock(mutex_);
  const auto now = clock_();
  DropExpired(now);
  std::string key = id;
  if (key.empty()) {
    key = "scene-" + std::to_string(next_);
  } else if (scenes_.count(key) == 0) {
    throw NotFoundError("unknown or expired scene '" + key.substr(0, 40) + "'");
  }
  while (scenes_.size() >= max_scenes_ && scenes_.count(key) == 0) {
    auto oldest = scenes_.begin();
    for (auto it = scenes_.begin(); it != scenes_.end(); ++it) {
      if (it->second.order < oldest->second.order) oldest = it;
    }
    scenes_.erase(oldest);
  }
  Entry& entry = scenes_[key];
  entry.scene = std::move(scene);
  entry.ttl_s = ttl_s;
  entry.expires = now + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                            std::chrono::duration<double>(ttl_s));
  entry.order = next_++;
  return key;
}

std::shared_ptr<const PlanningScene> SceneStore::Get(const std::string& id) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto now = clock_();
  DropExpired(now);
  const auto it = scenes_.find(id);
  if (it == scenes_.end()) {
    throw NotFoundError("unknown or expired scene '" + id.substr(0, 40) +
                        "': send the scan again with UpdateScene");
  }
  it->second.expires = now + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                 std::chrono::duration<double>(it->second.ttl_s));
  return it->second.scene;
}

std::size_t SceneStore::size() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return scenes_.size();
}

}  // namespace picking::planner
