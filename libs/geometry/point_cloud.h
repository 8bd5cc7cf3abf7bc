#pragma once

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace picking::geometry {

/// A point cloud as the whole system passes it between libraries: positions in metres in
/// the frame named by `frame_id`, with optional per-point normals, colours and intensities.
///
/// Optional channels are either empty or exactly as long as `points`. An organised cloud
/// (one point per camera pixel) has `height > 1` and `width * height == points.size()`,
/// row-major; pixels without a measurement hold NaN coordinates. An unorganised cloud has
/// `height == 1` and `width == points.size()`.
struct PointCloud {
  std::vector<Eigen::Vector3f> points;              ///< p_FramePoint, metres.
  std::vector<Eigen::Vector3f> normals;             ///< Unit normals in `frame_id`, or empty.
  std::vector<std::array<std::uint8_t, 3>> colors;  ///< RGB 0-255, or empty.
  std::vector<float> intensities;                   ///< Camera intensity 0-1, or empty.
  std::uint32_t width = 0;
  std::uint32_t height = 1;
  std::string frame_id;

  std::size_t size() const { return points.size(); }
  bool empty() const { return points.empty(); }
  bool has_normals() const { return !normals.empty(); }
  bool has_colors() const { return !colors.empty(); }
  bool has_intensities() const { return !intensities.empty(); }
  bool is_organized() const { return height > 1; }
};

}  // namespace picking::geometry
