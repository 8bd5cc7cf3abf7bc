#include "libs/runtime/config.h"

#include <yaml-cpp/yaml.h>

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace picking::runtime {
namespace {

void Flatten(const YAML::Node& node, const std::string& prefix, const std::string& source,
             std::map<std::string, std::string>& out) {
  if (node.IsMap()) {
    for (const auto& kv : node) {
      const std::string key = kv.first.as<std::string>();
      Flatten(kv.second, prefix.empty() ? key : prefix + "." + key, source, out);
    }
  } else if (node.IsSequence()) {
    std::string joined;
    for (std::size_t i = 0; i < node.size(); ++i) {
      if (!node[i].IsScalar()) {
        throw std::invalid_argument(source + ": line " + std::to_string(node[i].Mark().line + 1) +
                                    ": '" + prefix + "' must be a list of plain values");
      }
      if (i) joined += ",";
      joined += node[i].as<std::string>();
    }
    out[prefix] = joined;
  } else if (node.IsScalar()) {
    out[prefix] = node.as<std::string>();
  } else if (node.IsNull()) {
    out[prefix] = "";
  }
}

std::string Trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t");
  if (b == std::string::npos) return "";
  const auto e = s.find_last_not_of(" \t");
  return s.substr(b, e - b + 1);
}

double ParseDouble(const std::string& key, const std::string& text) {
  const std::string t = Trim(text);
  char* end = nullptr;
  errno = 0;
  const double v = std::strtod(t.c_str(), &end);
  if (t.empty() || end != t.c_str() + t.size() || errno == ERANGE || !std::isfinite(v)) {
    throw std::invalid_argument("setting '" + key + "': '" + text + "' is not a finite number");
  }
  return v;
}

}  // namespace

Config::Config(const Config& other) {
  std::lock_guard<std::mutex> lock(other.mutex_);
  values_ = other.values_;
  file_dirs_ = other.file_dirs_;
  used_ = other.used_;
}

Config& Config::operator=(const Config& other) {
  if (this == &other) return *this;
  std::map<std::string, std::string> values;
  std::map<std::string, std::string> file_dirs;
  std::set<std::string> used;
  {
    std::lock_guard<std::mutex> lock(other.mutex_);
    values = other.values_;
    file_dirs = other.file_dirs_;
    used = other.used_;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  values_ = std::move(values);
  file_dirs_ = std::move(file_dirs);
  used_ = std::move(used);
  return *this;
}

Config Config::FromYamlText(const std::string& text, const std::string& source_name) {
  Config config;
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument(source_name + ": line " + std::to_string(e.mark.line + 1) + ": " +
                                e.msg);
  }
  if (root.IsNull()) return config;
  if (!root.IsMap()) {
    throw std::invalid_argument(source_name + ": the top level must be a mapping of settings");
  }
  Flatten(root, "", source_name, config.values_);
  return config;
}

Config Config::FromYamlFile(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::invalid_argument("cannot open config file '" + path + "'");
  std::stringstream ss;
  ss << in.rdbuf();
  Config config = FromYamlText(ss.str(), path);
  const std::string dir = std::filesystem::absolute(path).parent_path().string();
  for (const auto& [key, value] : config.values_) config.file_dirs_[key] = dir;
  return config;
}

void Config::Set(const std::string& key, const std::string& value) {
  std::lock_guard<std::mutex> lock(mutex_);
  values_[key] = value;
  file_dirs_.erase(key);
}

const std::string* Config::Find(const std::string& key) const {
  std::lock_guard<std::mutex> lock(mutex_);
  used_.insert(key);
  const auto it = values_.find(key);
  return it == values_.end() ? nullptr : &it->second;
}

bool Config::Has(const std::string& key) const { return Find(key) != nullptr; }

std::string Config::GetString(const std::string& key, const std::string& default_value) const {
  const std::string* v = Find(key);
  return v ? *v : default_value;
}

std::string Config::GetPath(const std::string& key, const std::string& default_value) const {
  const std::string* v = Find(key);
  if (!v) return default_value;
  std::string dir;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = file_dirs_.find(key);
    if (it != file_dirs_.end()) dir = it->second;
  }
  const std::filesystem::path path(*v);
  if (dir.empty() || v->empty() || path.is_absolute()) return *v;
  return (std::filesystem::path(dir) / path).lexically_normal().string();
}

std::string Config::Require(const std::string& key) const {
  const std::string* v = Find(key);
  if (!v || v->empty()) throw std::invalid_argument("missing required setting '" + key + "'");
  return *v;
}

double Config::GetDouble(const std::string& key, double default_value) const {
  const std::string* v = Find(key);
  return v ? ParseDouble(key, *v) : default_value;
}

long long Config::GetInt(const std::string& key, long long default_value) const {
  const std::string* v = Find(key);
  if (!v) return default_value;
  const std::string t = Trim(*v);
  char* end = nullptr;
  errno = 0;
  const long long r = std::strtoll(t.c_str(), &end, 10);
  if (t.empty() || end != t.c_str() + t.size() || errno == ERANGE) {
    throw std::invalid_argument("setting '" + key + "': '" + *v + "' is not an integer");
  }
  return r;
}

bool Config::GetBool(const std::string& key, bool default_value) const {
  const std::string* v = Find(key);
  if (!v) return default_value;
  const std::string t = Trim(*v);
  if (t == "true" || t == "1" || t == "yes" || t == "on") return true;
  if (t == "false" || t == "0" || t == "no" || t == "off") return false;
  throw std::invalid_argument("setting '" + key + "': '" + *v + "' is not a boolean");
}

std::vector<double> Config::GetDoubles(const std::string& key,
                                       const std::vector<double>& default_value) const {
  const std::string* v = Find(key);
  if (!v) return default_value;
  std::vector<double> out;
  std::stringstream ss(*v);
  std::string item;
  while (std::getline(ss, item, ',')) out.push_back(ParseDouble(key, item));
  return out;
}

std::vector<std::string> Config::UnusedKeys() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<std::string> unused;
  for (const auto& [key, value] : values_) {
    if (!used_.count(key)) unused.push_back(key);
  }
  return unused;
}

}  // namespace picking::runtime
