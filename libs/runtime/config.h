#pragma once

#include <map>
#include <mutex>
#include <set>
#include <string>
#include <vector>

namespace picking::runtime {

/// Settings of one server: a flat map of dotted keys ("backend", "sim.address",
/// "safety.workspace_min") read from a YAML file and overridden by command-line flags
/// `--key=value`. Services read what they need with the typed getters; any key that no
/// getter asked for is reported by UnusedKeys(), so a misspelt setting is an error rather
/// than silently ignored.
class Config final {
 public:
  Config() = default;

  /// Loads a YAML mapping (nested mappings become dotted keys; sequences become
  /// comma-separated values). Throws std::invalid_argument naming the file and line.
  static Config FromYamlFile(const std::string& path);
  static Config FromYamlText(const std::string& text, const std::string& source_name);

  /// Sets or overrides one key (a command-line flag: a relative path in it is relative to the
  /// working directory).
  void Set(const std::string& key, const std::string& value);

  bool Has(const std::string& key) const;
  std::string GetString(const std::string& key, const std::string& default_value) const;
  /// A file path: as GetString, except that a relative path read from a YAML file
  /// (FromYamlFile) is resolved against that file's folder, so a settings file can name files
  /// beside it. Relative paths from Set() or the default are returned as given.
  std::string GetPath(const std::string& key, const std::string& default_value) const;
  /// Throws std::invalid_argument if the value is not a finite number.
  double GetDouble(const std::string& key, double default_value) const;
  /// Throws std::invalid_argument if the value is not an integer.
  long long GetInt(const std::string& key, long long default_value) const;
  /// Accepts true/false/1/0/yes/no/on/off; throws otherwise.
  bool GetBool(const std::string& key, bool default_value) const;
  /// Comma-separated numbers, e.g. "0.1, 0.2, 0.3"; throws on a malformed element.
  std::vector<double> GetDoubles(const std::string& key,
                                 const std::vector<double>& default_value) const;
  /// A required value: throws std::invalid_argument naming the key when absent.
  std::string Require(const std::string& key) const;

  /// Keys set but never read by any getter.
  std::vector<std::string> UnusedKeys() const;

  const std::map<std::string, std::string>& values() const { return values_; }

 private:
  const std::string* Find(const std::string& key) const;

  std::map<std::string, std::string> values_;
  // Folder of the YAML file each key was read from (FromYamlFile); none for Set() keys.
  std::map<std::string, std::string> file_dirs_;
  mutable std::set<std::string> used_;
  mutable std::mutex mutex_;

 public:
  Config(const Config& other);
  Config& operator=(const Config& other);
};

}  // namespace picking::runtime
