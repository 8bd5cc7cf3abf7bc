#pragma once

#include <stdexcept>
#include <string>

#include "libs/geometry/point_cloud.h"

namespace picking::geometry {

/// File formats of ReadPointCloud / WritePointCloud.
enum class PointCloudFormat {
  kPlyAscii,
  kPlyBinaryLittleEndian,
  kPlyBinaryBigEndian,
  kPcdAscii,
  kPcdBinary,
  kPcdBinaryCompressed,  ///< LZF-compressed, as PCL writes it.
};

/// Thrown when a point cloud file cannot be read or written. The message starts with the file
/// path and names the header line or the element (e.g. "vertex 1234") at fault.
class PointCloudIoError final : public std::runtime_error {
 public:
  PointCloudIoError(const std::string& path, const std::string& what);
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

/// Reads a PLY or PCD file. The format is recognised by content: a file starting with "ply" is
/// PLY, otherwise the extension ".pcd" (any case) selects PCD.
///
/// PLY (ascii, binary_little_endian, binary_big_endian): the "vertex" element gives the points
/// from properties x y z (any numeric type), the normals from nx ny nz, the colours from
/// red green blue or r g b (integer types clamped to 0-255; float and double taken as 0-1) and
/// the intensities from intensity. Other vertex properties and other elements (faces, ...)
/// are skipped according to their declared types. Comments written by WritePointCloud
/// ("frame_id <id>", "organized <width> <height>") restore frame_id and the organisation;
/// otherwise the cloud is unorganised (height 1) with an empty frame_id.
///
/// PCD (ascii, binary, binary_compressed; read through PCL): fields x y z, normal_x
/// normal_y normal_z, rgb or rgba (packed 0xAARRGGBB), intensity; width and height are kept.
/// PCD has no frame id: frame_id is empty.
///
/// Throws PointCloudIoError naming the file and the header line or element on a missing
/// file, an unknown format, a malformed header, counts that disagree with the body, a
/// truncated binary body, non-numeric ASCII values or trailing data.
PointCloud ReadPointCloud(const std::string& path);

/// Writes `cloud` to `path` in `format`, atomically: the data goes to a temporary file in the
/// same folder that is renamed over `path` once complete, so a failure leaves `path` as it
/// was. PLY keeps every channel, frame_id and organisation; PCD keeps every channel and the
/// organisation (colours as an "rgba" U4 field, alpha 255) but not frame_id.
/// Throws std::invalid_argument when the cloud is inconsistent (a channel size differs from
/// the number of points, width * height != size, a newline in frame_id) and
/// PointCloudIoError when the file cannot be written.
void WritePointCloud(const std::string& path, const PointCloud& cloud, PointCloudFormat format);

/// Throws std::invalid_argument naming `name` and the field when the optional channels are
/// neither empty nor as long as `points`, or width * height != points.size().
void ValidatePointCloud(const PointCloud& cloud, const std::string& name);

}  // namespace picking::geometry
