#pragma once

#include <cstdint>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

namespace picking::orchestrator {

/// One journal record: what happened or is about to happen, with an idempotency key that
/// names the action (e.g. "pick/bin_A/crayola_64_ct/1/release") so that a resumed task can
/// tell which actions are complete.
struct JournalRecord {
  std::uint64_t sequence = 0;
  std::string type;     ///< "task", "begin", "done", "failed", "event", "end".
  std::string key;      ///< Idempotency key of the action ("" for task-level records).
  double time_s = 0.0;  ///< Task clock when written.
  nlohmann::json data = nlohmann::json::object();
};

/// Append-only journal of one task: one JSON object per line. Every Append is written and
/// flushed to disk (fsync) before it returns, so a record of a physical step exists before the
/// step starts. Thread-safe.
class Journal final {
 public:
  /// Opens (creating if needed) the file; existing records are read first, a torn last line
  /// (a crash mid-write) is dropped. Throws std::runtime_error naming the file.
  explicit Journal(std::string path);
  ~Journal();
  Journal(const Journal&) = delete;
  Journal& operator=(const Journal&) = delete;

  /// Appends a record (its sequence number is assigned) and syncs it to disk.
  JournalRecord Append(std::string type, std::string key, double time_s,
                       nlohmann::json data = nlohmann::json::object());

  /// Every record, in order.
  std::vector<JournalRecord> Records() const;
  /// True when a record of `type` with `key` exists.
  bool Has(const std::string& type, const std::string& key) const;
  const std::string& path() const { return path_; }

  /// Reads a journal file without opening it for writing.
  static std::vector<JournalRecord> Read(const std::string& path);

 private:
  std::string path_;
  int fd_ = -1;
  mutable std::mutex mutex_;
  std::vector<JournalRecord> records_;
};

}  // namespace picking::orchestrator
