#include "services/viewer/core/part_store.h"

namespace picking::viewer {

void PartStore::Set(const std::string& name, nlohmann::json value) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    Part& part = parts_[name];
    part.value = std::move(value);
    part.version = next_version_++;
  }
  changed_.notify_all();
}

void PartStore::SetIfChanged(const std::string& name, nlohmann::json value) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = parts_.find(name);
    if (it != parts_.end() && it->second.value == value) return;
  }
  Set(name, std::move(value));
}

std::vector<std::pair<std::string, std::string>> PartStore::Changes(
    Seen& seen, std::chrono::milliseconds timeout) {
  std::unique_lock<std::mutex> lock(mutex_);
  auto newer = [&] {
    for (const auto& [name, part] : parts_) {
      const auto it = seen.find(name);
      if (it == seen.end() || it->second < part.version) return true;
    }
    return false;
  };
  changed_.wait_for(lock, timeout, newer);
  std::vector<std::pair<std::string, std::string>> out;
  for (const auto& [name, part] : parts_) {
    std::uint64_t& version = seen[name];
    if (version >= part.version) continue;
    version = part.version;
    out.emplace_back(name, part.value.dump());
  }
  return out;
}

nlohmann::json PartStore::Snapshot() const {
  std::lock_guard<std::mutex> lock(mutex_);
  nlohmann::json out = nlohmann::json::object();
  for (const auto& [name, part] : parts_) out[name] = part.value;
  return out;
}

void PartStore::WakeAll() { changed_.notify_all(); }

}  // namespace picking::viewer
