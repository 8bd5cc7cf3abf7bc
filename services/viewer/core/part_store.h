#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

namespace picking::viewer {

/// The parts of what the page shows ("task", "scan", "arm", ...), each a JSON value with a
/// version that grows on every change, so that each open page is sent what changed since it
/// last looked. Thread-safe.
class PartStore final {
 public:
  /// Which version of each part a reader has seen.
  using Seen = std::map<std::string, std::uint64_t>;

  void Set(const std::string& name, nlohmann::json value);
  /// Sets the part only when it differs from what it holds (a repeated reading is no news).
  void SetIfChanged(const std::string& name, nlohmann::json value);

  /// Every part newer than `seen` (all of them for an empty `seen`), as (name, JSON text);
  /// `seen` is updated. Waits up to `timeout` for a change when nothing is new.
  std::vector<std::pair<std::string, std::string>> Changes(Seen& seen,
                                                           std::chrono::milliseconds timeout);

  /// Every part as one object {name: value}.
  nlohmann::json Snapshot() const;

  /// Wakes every waiting reader (at shutdown).
  void WakeAll();

 private:
  struct Part {
    nlohmann::json value;
    std::uint64_t version = 0;
  };
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::map<std::string, Part> parts_;
  std::uint64_t next_version_ = 1;
};

}  // namespace picking::viewer
