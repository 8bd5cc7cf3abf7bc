#pragma once

#include <initializer_list>
#include <string>
#include <string_view>
#include <utility>

namespace picking::runtime {

enum class LogLevel { kDebug = 0, kInfo = 1, kWarning = 2, kError = 3 };

/// One key=value field of a structured log line.
using LogField = std::pair<std::string_view, std::string>;

/// Writes one structured line to stderr in logfmt:
///   ts=2026-11-22T10:00:00.123Z level=info service=robot msg="moving" joint=3
/// Values with spaces, quotes or '=' are quoted. Thread-safe; lines never interleave.
void Log(LogLevel level, std::string_view message, std::initializer_list<LogField> fields = {});

/// Sets the `service=` field of every line and the minimum level written.
void ConfigureLogging(std::string_view service, LogLevel min_level);

/// Parses "debug", "info", "warning", "error"; throws std::invalid_argument otherwise.
LogLevel ParseLogLevel(std::string_view text);

inline void LogInfo(std::string_view m, std::initializer_list<LogField> f = {}) {
  Log(LogLevel::kInfo, m, f);
}
inline void LogWarning(std::string_view m, std::initializer_list<LogField> f = {}) {
  Log(LogLevel::kWarning, m, f);
}
inline void LogError(std::string_view m, std::initializer_list<LogField> f = {}) {
  Log(LogLevel::kError, m, f);
}
inline void LogDebug(std::string_view m, std::initializer_list<LogField> f = {}) {
  Log(LogLevel::kDebug, m, f);
}

}  // namespace picking::runtime
