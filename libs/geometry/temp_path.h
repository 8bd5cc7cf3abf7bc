#pragma once

#include <cstdio>
#include <random>
#include <string>

namespace picking::geometry {

/// A fresh name beside `path` to write a file under before renaming it into place. Random
/// rather than from the process id: servers in containers are all process 1, and replicas
/// share cache folders through volumes, so a pid-based name would collide.
inline std::string TemporaryPathBeside(const std::string& path) {
  static thread_local std::mt19937_64 random{std::random_device{}()};
  char suffix[24];
  std::snprintf(suffix, sizeof(suffix), ".tmp.%016llx", static_cast<unsigned long long>(random()));
  return path + suffix;
}

}  // namespace picking::geometry
