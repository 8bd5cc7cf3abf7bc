#pragma once

#include <Eigen/Geometry>

#include <array>
#include <cstdint>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include "libs/camera/pinhole_camera.h"
#include "libs/geometry/point_cloud.h"
#include "picking/common/v1/apc.pb.h"
#include "picking/common/v1/data.pb.h"
#include "picking/common/v1/geometry.pb.h"
#include "picking/common/v1/robot_types.pb.h"

/// Conversions between the protobuf contracts (proto/picking/common/v1) and the core
/// libraries' types. Every FromProto validates its input and throws std::invalid_argument
/// whose message names the offending field (`field` is the caller's name for it, e.g.
/// "target" or "views[2].X_base_tool"), so an adapter can answer INVALID_ARGUMENT with a
/// message a person can act on.
namespace picking::proto_convert {

namespace pb = ::picking::common::v1;

/// Largest distance of a pose's position from its frame's origin accepted from a request,
/// metres. The cell is a few metres across; a finite but huge position (e.g. 2e18 m) has
/// no meaning and broke the ray casters downstream (Embree asserts on such rays).
constexpr double kMaxPositionM = 1e3;

/// Pose <-> Eigen::Isometry3d. Rejects NaN/inf, positions with |p| > `max_position_m`
/// (default kMaxPositionM) and quaternions whose norm is not within 1e-3 of 1 (the
/// quaternion is then normalised exactly).
Eigen::Isometry3d PoseFromProto(const pb::Pose& pose, std::string_view field,
                                double max_position_m = kMaxPositionM);
pb::Pose PoseToProto(const Eigen::Isometry3d& X);

Eigen::Vector3d VectorFromProto(const pb::Vector3& v, std::string_view field);
pb::Vector3 VectorToProto(const Eigen::Vector3d& v);

/// Exactly 6 finite joint positions (radians).
std::array<double, 6> JointsFromProto(const pb::JointPositions& joints, std::string_view field);
pb::JointPositions JointsToProto(const std::array<double, 6>& q);

/// Camera intrinsics <-> camera::PinholeCamera. Rejects an image side of 0 or over
/// `max_side_px`, more than `max_pixels`, more than five distortion coefficients (k1, k2, p1,
/// p2, k3; missing ones are 0) and what PinholeCamera refuses (focal lengths, non-finite
/// values, a distortion it cannot invert), naming `field`.
camera::PinholeCamera CameraFromProto(const pb::CameraIntrinsics& c, std::string_view field,
                                      std::uint32_t max_side_px = 4096,
                                      std::uint64_t max_pixels = std::uint64_t{1} << 24);
pb::CameraIntrinsics CameraToProto(const camera::PinholeCamera& camera);

/// "bin_A".."bin_L", "tote", ... <-> Container. Throws for UNSPECIFIED / unknown names.
std::string ContainerName(pb::Container container);
pb::Container ContainerFromName(std::string_view name);

/// Maximum points per chunk when streaming a cloud: 65,536 points with every channel is
/// about 2.2 MB, well under gRPC's 4 MiB default limit.
constexpr std::uint32_t kDefaultPointsPerChunk = 65536;
/// Largest cloud accepted from a stream.
constexpr std::uint64_t kMaxStreamPoints = 50'000'000;

/// Splits a cloud into chunks (the first carries the header).
std::vector<pb::PointCloudChunk> CloudToChunks(
    const geometry::PointCloud& cloud, std::uint32_t points_per_chunk = kDefaultPointsPerChunk);

/// Assembles a cloud from a stream of chunks, checking the header, that runs tile the cloud
/// in order, and that each channel's byte count matches. Feed chunks with Add() and call
/// Finish() at the end of the stream.
class CloudAssembler final {
 public:
  explicit CloudAssembler(std::uint64_t max_points = kMaxStreamPoints);
  /// Throws std::invalid_argument naming the chunk index and what is wrong.
  void Add(const pb::PointCloudChunk& chunk);
  /// Throws std::invalid_argument if no header came or points are missing.
  geometry::PointCloud Finish();
  bool started() const { return started_; }
  std::uint64_t points_received() const { return next_; }
  /// The sensor pose from the header (X_frame_sensor: X_FrameSensor), if any.
  bool has_sensor_pose() const { return has_sensor_pose_; }
  const Eigen::Isometry3d& sensor_pose() const { return sensor_pose_; }

 private:
  geometry::PointCloud cloud_;
  std::uint64_t max_points_;
  std::uint64_t total_ = 0;
  std::uint64_t next_ = 0;
  std::size_t chunks_ = 0;
  bool started_ = false;
  bool has_sensor_pose_ = false;
  Eigen::Isometry3d sensor_pose_ = Eigen::Isometry3d::Identity();
};

/// An 8-bit or float image as plain bytes (row-major, tightly packed).
struct Image {
  std::uint32_t width = 0;
  std::uint32_t height = 0;
  pb::PixelFormat format = pb::PIXEL_FORMAT_MONO8;
  std::string name;
  std::uint32_t index = 0;
  std::vector<std::uint8_t> data;
};

std::size_t BytesPerPixel(pb::PixelFormat format);

/// Splits an image into row chunks of at most `max_chunk_bytes` (the first carries the
/// header).
std::vector<pb::ImageChunk> ImageToChunks(const Image& image,
                                          std::size_t max_chunk_bytes = 1 << 20);

/// Assembles images from a stream of chunks (several images may follow each other).
/// Add() returns true when the chunk completed an image, which is then in `completed()`.
class ImageAssembler final {
 public:
  bool Add(const pb::ImageChunk& chunk);
  const Image& completed() const { return image_; }
  Image TakeCompleted() { return std::move(image_); }
  bool in_progress() const { return in_progress_; }

 private:
  Image image_;
  std::uint32_t next_row_ = 0;
  bool in_progress_ = false;
};

}  // namespace picking::proto_convert
