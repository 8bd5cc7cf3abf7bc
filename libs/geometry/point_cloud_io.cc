#include "libs/geometry/point_cloud_io.h"
#include "libs/geometry/temp_path.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <cstring>

#include "libs/geometry/io_internal.h"

namespace picking::geometry {

PointCloudIoError::PointCloudIoError(const std::string& path, const std::string& what)
    : std::runtime_error(path + ": " + what), path_(path) {}

void ValidatePointCloud(const PointCloud& cloud, const std::string& name) {
  const std::size_t n = cloud.points.size();
  auto check = [&](std::size_t size, const char* field) {
    if (size != 0 && size != n) {
      throw std::invalid_argument(name + "." + field + " has " + std::to_string(size) +
                                  " entries for " + std::to_string(n) + " points");
    }
  };
  check(cloud.normals.size(), "normals");
  check(cloud.colors.size(), "colors");
  check(cloud.intensities.size(), "intensities");
  if (static_cast<std::uint64_t>(cloud.width) * cloud.height != n) {
    throw std::invalid_argument(name + ": width * height = " + std::to_string(cloud.width) + " * " +
                                std::to_string(cloud.height) + " != " + std::to_string(n) +
                                " points");
  }
}

PointCloud ReadPointCloud(const std::string& path) {
  std::FILE* file = std::fopen(path.c_str(), "rb");
  if (file == nullptr) {
    throw PointCloudIoError(path, std::string("cannot open: ") + std::strerror(errno));
  }
  char magic[4] = {0, 0, 0, 0};
  const std::size_t got = std::fread(magic, 1, 4, file);
  std::fclose(file);
  if (got >= 4 && std::memcmp(magic, "ply", 3) == 0 && (magic[3] == '\n' || magic[3] == '\r')) {
    return internal::ReadPly(path);
  }
  std::string extension;
  const std::size_t dot = path.find_last_of('.');
  if (dot != std::string::npos && path.find('/', dot) == std::string::npos) {
    extension = path.substr(dot + 1);
    std::transform(extension.begin(), extension.end(), extension.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  }
  if (extension == "pcd") return internal::ReadPcd(path);
  if (extension == "ply") {
    throw PointCloudIoError(path, "line 1: not a PLY file (it does not start with \"ply\")");
  }
  throw PointCloudIoError(path, "unknown point cloud format (expected a PLY or .pcd file)");
}

void WritePointCloud(const std::string& path, const PointCloud& cloud, PointCloudFormat format) {
  ValidatePointCloud(cloud, "point cloud for " + path);
  switch (format) {
    case PointCloudFormat::kPlyAscii:
    case PointCloudFormat::kPlyBinaryLittleEndian:
    case PointCloudFormat::kPlyBinaryBigEndian:
      if (cloud.frame_id.find_first_of("\r\n") != std::string::npos) {
        throw std::invalid_argument("point cloud for " + path + ": frame_id contains a line break");
      }
      internal::WritePly(path, cloud, format);
      return;
    case PointCloudFormat::kPcdAscii:
    case PointCloudFormat::kPcdBinary:
    case PointCloudFormat::kPcdBinaryCompressed:
      internal::WritePcd(path, cloud, format);
      return;
  }
  throw std::invalid_argument("unknown point cloud format");
}

namespace internal {

AtomicFile::AtomicFile(const std::string& path)
    : path_(path), temp_path_(TemporaryPathBeside(path)) {}

AtomicFile::~AtomicFile() {
  if (file_ != nullptr) std::fclose(file_);
  if (!committed_) std::remove(temp_path_.c_str());
}

void AtomicFile::Open() {
  file_ = std::fopen(temp_path_.c_str(), "wb");
  if (file_ == nullptr) {
    throw PointCloudIoError(path_, "cannot create " + temp_path_ + ": " + std::strerror(errno));
  }
  buffer_.resize(1 << 20);
  std::setvbuf(file_, buffer_.data(), _IOFBF, buffer_.size());
}

void AtomicFile::Write(const void* data, std::size_t size) {
  if (size == 0) return;
  if (std::fwrite(data, 1, size, file_) != size) {
    throw PointCloudIoError(path_, std::string("write error: ") + std::strerror(errno));
  }
}

void AtomicFile::Commit() {
  if (file_ != nullptr) {
    const bool ok = std::fflush(file_) == 0;
    const int error = errno;
    const bool closed = std::fclose(file_) == 0;
    file_ = nullptr;
    if (!ok || !closed) {
      throw PointCloudIoError(path_, std::string("write error: ") + std::strerror(error));
    }
  }
  if (std::rename(temp_path_.c_str(), path_.c_str()) != 0) {
    throw PointCloudIoError(path_, std::string("cannot replace the file: ") + std::strerror(errno));
  }
  committed_ = true;
}

}  // namespace internal
}  // namespace picking::geometry
