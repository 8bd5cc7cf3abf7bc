#pragma once

// Internal to picking::geometry: the format back ends of point_cloud_io.h.

#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "libs/geometry/point_cloud.h"
#include "libs/geometry/point_cloud_io.h"

namespace picking::geometry::internal {

/// A file written under a temporary name in the destination folder and renamed over the
/// destination by Commit(); destroyed without Commit() it removes the temporary file.
class AtomicFile final {
 public:
  explicit AtomicFile(const std::string& path);
  ~AtomicFile();
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  /// Opens the temporary file for buffered writing (Write / stream()).
  void Open();
  void Write(const void* data, std::size_t size);
  void Write(const std::string& text) { Write(text.data(), text.size()); }
  /// Closes (if open) and renames the temporary file over the destination.
  void Commit();

  const std::string& path() const { return path_; }
  const std::string& temp_path() const { return temp_path_; }

 private:
  std::string path_;
  std::string temp_path_;
  std::FILE* file_ = nullptr;
  std::vector<char> buffer_;
  bool committed_ = false;
};

PointCloud ReadPly(const std::string& path);
void WritePly(const std::string& path, const PointCloud& cloud, PointCloudFormat format);
PointCloud ReadPcd(const std::string& path);
void WritePcd(const std::string& path, const PointCloud& cloud, PointCloudFormat format);

}  // namespace picking::geometry::internal
