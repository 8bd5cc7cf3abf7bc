#include "services/orchestrator/core/journal.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <fstream>
#include <stdexcept>

namespace picking::orchestrator {
namespace {

nlohmann::json ToJson(const JournalRecord& r) {
  return {{"seq", r.sequence}, {"type", r.type}, {"key", r.key}, {"t", r.time_s}, {"data", r.data}};
}

JournalRecord FromJson(const nlohmann::json& j) {
  JournalRecord r;
  r.sequence = j.at("seq").get<std::uint64_t>();
  r.type = j.at("type").get<std::string>();
  r.key = j.value("key", "");
  r.time_s = j.value("t", 0.0);
  r.data = j.value("data", nlohmann::json::object());
  return r;
}

}  // namespace

std::vector<JournalRecord> Journal::Read(const std::string& path) {
  std::vector<JournalRecord> records;
  std::ifstream in(path);
  if (!in) return records;
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    try {
      records.push_back(FromJson(nlohmann::json::parse(line)));
    } catch (const nlohmann::json::exception&) {
      // Only the last line can be torn (the process died mid-write); anything after it would
      // mean the file was edited, which is reported.
      if (in.peek() != EOF) {
        throw std::runtime_error(path + ": unreadable record " +
                                 std::to_string(records.size() + 1));
      }
    }
  }
  return records;
}

Journal::Journal(std::string path) : path_(std::move(path)) {
  records_ = Read(path_);
  // Rewrite without a torn tail so that appends start on a clean line.
  fd_ = ::open(path_.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  if (fd_ < 0) {
    throw std::runtime_error(path_ + ": cannot open the journal: " + std::strerror(errno));
  }
  const off_t size = ::lseek(fd_, 0, SEEK_END);
  if (size > 0) {
    char last = '\n';
    std::ifstream in(path_, std::ios::binary);
    in.seekg(size - 1);
    in.get(last);
    if (last != '\n') {
      // A torn last line: terminate it; Read skips it as unparsable only when last, so the
      // rewrite keeps the parsed records only.
      std::string text;
      for (const JournalRecord& r : records_) text += ToJson(r).dump() + "\n";
      if (::ftruncate(fd_, 0) != 0 || ::write(fd_, text.data(), text.size()) < 0) {
        throw std::runtime_error(path_ + ": cannot repair the journal: " + std::strerror(errno));
      }
      ::fsync(fd_);
    }
  }
}

Journal::~Journal() {
  if (fd_ >= 0) ::close(fd_);
}

JournalRecord Journal::Append(std::string type, std::string key, double time_s,
                              nlohmann::json data) {
  std::lock_guard<std::mutex> lock(mutex_);
  JournalRecord record;
  record.sequence = records_.empty() ? 0 : records_.back().sequence + 1;
  record.type = std::move(type);
  record.key = std::move(key);
  record.time_s = time_s;
  record.data = std::move(data);
  const std::string line = ToJson(record).dump() + "\n";
  std::size_t written = 0;
  while (written < line.size()) {
    const ssize_t n = ::write(fd_, line.data() + written, line.size() - written);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) throw std::runtime_error(path_ + ": journal write failed: " + std::strerror(errno));
    written += static_cast<std::size_t>(n);
  }
  if (::fsync(fd_) != 0) {
    throw std::runtime_error(path_ + ": journal sync failed: " + std::strerror(errno));
  }
  records_.push_back(record);
  return record;
}

std::vector<JournalRecord> Journal::Records() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return records_;
}

bool Journal::Has(const std::string& type, const std::string& key) const {
  std::lock_guard<std::mutex> lock(mutex_);
  for (const JournalRecord& r : records_) {
    if (r.type == type && r.key == key) return true;
  }
  return false;
}

}  // namespace picking::orchestrator
