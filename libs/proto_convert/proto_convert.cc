#include "libs/proto_convert/proto_convert.h"

#include <cmath>
#include <cstring>
#include <sstream>
#include <stdexcept>

#include "libs/geometry/pose.h"

namespace picking::proto_convert {
namespace {

std::string Field(std::string_view field, std::string_view sub) {
  std::string s(field);
  if (!sub.empty()) s.append(".").append(sub);
  return s;
}

double Finite(double v, std::string_view field, std::string_view sub) {
  if (!std::isfinite(v)) {
    throw std::invalid_argument(Field(field, sub) + " must be a finite number");
  }
  return v;
}

// Point data travels little-endian; this machine (and every target of the project) is
// little-endian too, so the copy is a memcpy. Checked at compile time.
static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "packed clouds assume little-endian");

template <class T>
void AppendBytes(std::string* out, const T* data, std::size_t count) {
  out->append(reinterpret_cast<const char*>(data), count * sizeof(T));
}

}  // namespace

Eigen::Vector3d VectorFromProto(const pb::Vector3& v, std::string_view field) {
  return {Finite(v.x(), field, "x"), Finite(v.y(), field, "y"), Finite(v.z(), field, "z")};
}

pb::Vector3 VectorToProto(const Eigen::Vector3d& v) {
  pb::Vector3 out;
  out.set_x(v.x());
  out.set_y(v.y());
  out.set_z(v.z());
  return out;
}

Eigen::Isometry3d PoseFromProto(const pb::Pose& pose, std::string_view field,
                                double max_position_m) {
  const Eigen::Vector3d p = VectorFromProto(pose.position(), Field(field, "position"));
  if (!(p.norm() <= max_position_m)) {
    std::ostringstream os;
    os << Field(field, "position") << " is " << p.norm() << " m from the origin, more than the "
       << max_position_m << " m limit";
    throw std::invalid_argument(os.str());
  }
  const auto& q = pose.orientation();
  const std::string qf = Field(field, "orientation");
  const Eigen::Quaterniond quat(Finite(q.w(), qf, "w"), Finite(q.x(), qf, "x"),
                                Finite(q.y(), qf, "y"), Finite(q.z(), qf, "z"));
  return geometry::FromTranslationQuaternion(p, quat, field);
}

pb::Pose PoseToProto(const Eigen::Isometry3d& X) {
  pb::Pose out;
  *out.mutable_position() = VectorToProto(X.translation());
  const Eigen::Quaterniond q = geometry::ToTranslationQuaternion(X).q_AB;  // w >= 0
  auto* o = out.mutable_orientation();
  o->set_w(q.w());
  o->set_x(q.x());
  o->set_y(q.y());
  o->set_z(q.z());
  return out;
}

std::array<double, 6> JointsFromProto(const pb::JointPositions& joints, std::string_view field) {
  if (joints.positions_rad_size() != 6) {
    throw std::invalid_argument(std::string(field) + " must hold 6 joint positions, got " +
                                std::to_string(joints.positions_rad_size()));
  }
  std::array<double, 6> q{};
  for (int i = 0; i < 6; ++i) {
    q[i] = Finite(joints.positions_rad(i), field, "positions_rad[" + std::to_string(i) + "]");
  }
  return q;
}

pb::JointPositions JointsToProto(const std::array<double, 6>& q) {
  pb::JointPositions out;
  for (double v : q) out.add_positions_rad(v);
  return out;
}

std::string ContainerName(pb::Container container) {
  if (container >= pb::CONTAINER_BIN_A && container <= pb::CONTAINER_BIN_L) {
    return std::string("bin_") + static_cast<char>('A' + (container - pb::CONTAINER_BIN_A));
  }
  switch (container) {
    case pb::CONTAINER_TOTE:
      return "tote";
    case pb::CONTAINER_GRIPPER:
      return "gripper";
    case pb::CONTAINER_TABLE:
      return "table";
    case pb::CONTAINER_OUTSIDE:
      return "outside";
    default:
      throw std::invalid_argument("container is unspecified or unknown (" +
                                  std::to_string(static_cast<int>(container)) + ")");
  }
}

pb::Container ContainerFromName(std::string_view name) {
  if (name.size() == 5 && name.substr(0, 4) == "bin_" && name[4] >= 'A' && name[4] <= 'L') {
    return static_cast<pb::Container>(pb::CONTAINER_BIN_A + (name[4] - 'A'));
  }
  if (name == "tote") return pb::CONTAINER_TOTE;
  if (name == "gripper") return pb::CONTAINER_GRIPPER;
  if (name == "table") return pb::CONTAINER_TABLE;
  if (name == "outside") return pb::CONTAINER_OUTSIDE;
  // The name is the caller's and may be any length: quote a short prefix.
  constexpr std::size_t kMaxQuoted = 64;
  const std::string quoted = name.size() <= kMaxQuoted
                                 ? std::string(name)
                                 : std::string(name.substr(0, kMaxQuoted)) + "...";
  throw std::invalid_argument("unknown container '" + quoted +
                              "' (expected bin_A..bin_L, tote, gripper, table or outside)");
}

std::vector<pb::PointCloudChunk> CloudToChunks(const geometry::PointCloud& cloud,
                                               std::uint32_t points_per_chunk) {
  if (points_per_chunk == 0) throw std::invalid_argument("points_per_chunk must be > 0");
  const std::size_t n = cloud.size();
  auto check = [&](std::size_t size, const char* name) {
    if (size != 0 && size != n) {
      throw std::invalid_argument(std::string("cloud channel '") + name + "' has " +
                                  std::to_string(size) + " entries for " + std::to_string(n) +
                                  " points");
    }
  };
  check(cloud.normals.size(), "normals");
  check(cloud.colors.size(), "colors");
  check(cloud.intensities.size(), "intensities");
  std::vector<pb::PointCloudChunk> chunks;
  std::size_t offset = 0;
  do {
    const std::size_t count = std::min<std::size_t>(points_per_chunk, n - offset);
    pb::PointCloudChunk chunk;
    if (offset == 0) {
      auto* h = chunk.mutable_header();
      h->set_frame_id(cloud.frame_id);
      h->set_point_count(n);
      h->set_width(cloud.height > 1 ? cloud.width : static_cast<std::uint32_t>(n));
      h->set_height(cloud.height > 1 ? cloud.height : 1);
      h->set_has_normals(cloud.has_normals());
      h->set_has_colors(cloud.has_colors());
      h->set_has_intensities(cloud.has_intensities());
    }
    chunk.set_point_offset(offset);
    chunk.set_point_count(static_cast<std::uint32_t>(count));
    if (count > 0) {
      AppendBytes(chunk.mutable_positions(), cloud.points[offset].data(), count * 3);
      if (cloud.has_normals()) {
        AppendBytes(chunk.mutable_normals(), cloud.normals[offset].data(), count * 3);
      }
      if (cloud.has_colors()) {
        AppendBytes(chunk.mutable_colors(), cloud.colors[offset].data(), count * 3);
      }
      if (cloud.has_intensities()) {
        AppendBytes(chunk.mutable_intensities(), &cloud.intensities[offset], count);
      }
    }
    chunks.push_back(std::move(chunk));
    offset += count;
  } while (offset < n);
  return chunks;
}

CloudAssembler::CloudAssembler(std::uint64_t max_points) : max_points_(max_points) {}

void CloudAssembler::Add(const pb::PointCloudChunk& chunk) {
  const std::string where = "cloud chunk " + std::to_string(chunks_);
  ++chunks_;
  if (!started_) {
    if (!chunk.has_header()) {
      throw std::invalid_argument(where + ": the first chunk must carry the header");
    }
    const auto& h = chunk.header();
    if (h.point_count() > max_points_) {
      throw std::invalid_argument("cloud of " + std::to_string(h.point_count()) +
                                  " points exceeds the limit of " + std::to_string(max_points_));
    }
    // The contract: point_count = width * height, height 1 for an unorganised cloud. A
    // header that leaves the shape out is refused rather than guessed.
    if (static_cast<std::uint64_t>(h.width()) * h.height() != h.point_count()) {
      throw std::invalid_argument("cloud header: width * height (" + std::to_string(h.width()) +
                                  " * " + std::to_string(h.height()) + ") != point_count (" +
                                  std::to_string(h.point_count()) + ")");
    }
    total_ = h.point_count();
    cloud_.frame_id = h.frame_id();
    cloud_.width = h.width();
    cloud_.height = h.height();
    cloud_.points.resize(total_);
    if (h.has_normals()) cloud_.normals.resize(total_);
    if (h.has_colors()) cloud_.colors.resize(total_);
    if (h.has_intensities()) cloud_.intensities.resize(total_);
    if (h.has_x_frame_sensor()) {
      sensor_pose_ = PoseFromProto(h.x_frame_sensor(), "cloud header.X_frame_sensor");
      has_sensor_pose_ = true;
    }
    started_ = true;
  } else if (chunk.has_header()) {
    throw std::invalid_argument(where + ": only the first chunk may carry a header");
  }
  if (chunk.point_offset() != next_) {
    throw std::invalid_argument(where + ": point_offset " + std::to_string(chunk.point_offset()) +
                                " but " + std::to_string(next_) + " points received so far");
  }
  const std::uint64_t count = chunk.point_count();
  if (next_ + count > total_) {
    throw std::invalid_argument(where + ": runs past the header's point_count " +
                                std::to_string(total_));
  }
  auto take = [&](const std::string& bytes, void* dst, std::size_t expected, const char* name,
                  bool present) {
    if (!present) {
      if (!bytes.empty()) {
        throw std::invalid_argument(where + ": carries '" + name +
                                    "' that the header does not announce");
      }
      return;
    }
    if (bytes.size() != expected) {
      throw std::invalid_argument(where + ": '" + name + "' has " + std::to_string(bytes.size()) +
                                  " bytes, expected " + std::to_string(expected));
    }
    std::memcpy(dst, bytes.data(), expected);
  };
  take(chunk.positions(), cloud_.points.data() + next_, count * 12, "positions", true);
  take(chunk.normals(), cloud_.has_normals() ? cloud_.normals.data() + next_ : nullptr, count * 12,
       "normals", cloud_.has_normals());
  take(chunk.colors(), cloud_.has_colors() ? cloud_.colors.data() + next_ : nullptr, count * 3,
       "colors", cloud_.has_colors());
  take(chunk.intensities(), cloud_.has_intensities() ? cloud_.intensities.data() + next_ : nullptr,
       count * 4, "intensities", cloud_.has_intensities());
  next_ += count;
}

geometry::PointCloud CloudAssembler::Finish() {
  if (!started_) throw std::invalid_argument("no point cloud was received");
  if (next_ != total_) {
    throw std::invalid_argument("point cloud stream ended after " + std::to_string(next_) + " of " +
                                std::to_string(total_) + " points");
  }
  return std::move(cloud_);
}

std::size_t BytesPerPixel(pb::PixelFormat format) {
  switch (format) {
    case pb::PIXEL_FORMAT_MONO8:
      return 1;
    case pb::PIXEL_FORMAT_MONO16:
      return 2;
    case pb::PIXEL_FORMAT_RGB8:
      return 3;
    case pb::PIXEL_FORMAT_FLOAT32:
      return 4;
    default:
      throw std::invalid_argument("image pixel format is unspecified or unknown");
  }
}

std::vector<pb::ImageChunk> ImageToChunks(const Image& image, std::size_t max_chunk_bytes) {
  const std::size_t row_bytes = image.width * BytesPerPixel(image.format);
  if (image.width == 0 || image.height == 0 || image.data.size() != row_bytes * image.height) {
    throw std::invalid_argument("image '" + image.name + "': " + std::to_string(image.width) + "x" +
                                std::to_string(image.height) + " does not match " +
                                std::to_string(image.data.size()) + " bytes");
  }
  const std::uint32_t rows_per_chunk =
      static_cast<std::uint32_t>(std::max<std::size_t>(1, max_chunk_bytes / row_bytes));
  std::vector<pb::ImageChunk> chunks;
  for (std::uint32_t row = 0; row < image.height; row += rows_per_chunk) {
    const std::uint32_t rows = std::min(rows_per_chunk, image.height - row);
    pb::ImageChunk chunk;
    if (row == 0) {
      auto* h = chunk.mutable_header();
      h->set_width(image.width);
      h->set_height(image.height);
      h->set_format(image.format);
      h->set_name(image.name);
      h->set_index(image.index);
    }
    chunk.set_row_offset(row);
    chunk.set_row_count(rows);
    chunk.set_data(reinterpret_cast<const char*>(image.data.data()) + row * row_bytes,
                   rows * row_bytes);
    chunks.push_back(std::move(chunk));
  }
  return chunks;
}

bool ImageAssembler::Add(const pb::ImageChunk& chunk) {
  if (chunk.has_header()) {
    if (in_progress_) {
      throw std::invalid_argument("image '" + image_.name + "' ended after " +
                                  std::to_string(next_row_) + " of " +
                                  std::to_string(image_.height) + " rows");
    }
    const auto& h = chunk.header();
    if (h.width() == 0 || h.height() == 0 || h.width() > 16384 || h.height() > 16384) {
      throw std::invalid_argument("image header: size " + std::to_string(h.width()) + "x" +
                                  std::to_string(h.height()) + " outside 1..16384");
    }
    image_ = Image{};
    image_.width = h.width();
    image_.height = h.height();
    image_.format = h.format();
    image_.name = h.name();
    image_.index = h.index();
    image_.data.resize(static_cast<std::size_t>(h.width()) * h.height() *
                       BytesPerPixel(h.format()));
    next_row_ = 0;
    in_progress_ = true;
  } else if (!in_progress_) {
    throw std::invalid_argument("image chunk without a preceding header");
  }
  const std::size_t row_bytes = image_.width * BytesPerPixel(image_.format);
  if (chunk.row_offset() != next_row_ || chunk.row_count() == 0 ||
      next_row_ + chunk.row_count() > image_.height ||
      chunk.data().size() != chunk.row_count() * row_bytes) {
    throw std::invalid_argument(
        "image '" + image_.name + "': chunk rows " + std::to_string(chunk.row_offset()) + "+" +
        std::to_string(chunk.row_count()) + " with " + std::to_string(chunk.data().size()) +
        " bytes do not continue the image at row " + std::to_string(next_row_));
  }
  std::memcpy(image_.data.data() + next_row_ * row_bytes, chunk.data().data(), chunk.data().size());
  next_row_ += chunk.row_count();
  if (next_row_ == image_.height) {
    in_progress_ = false;
    return true;
  }
  return false;
}

camera::PinholeCamera CameraFromProto(const pb::CameraIntrinsics& c, std::string_view field,
                                      std::uint32_t max_side_px, std::uint64_t max_pixels) {
  const std::string name(field);
  if (c.width() == 0 || c.height() == 0 || c.width() > max_side_px || c.height() > max_side_px) {
    throw std::invalid_argument(name + ": width and height must be in [1, " +
                                std::to_string(max_side_px) + "], got " +
                                std::to_string(c.width()) + " x " + std::to_string(c.height()));
  }
  if (std::uint64_t{c.width()} * c.height() > max_pixels) {
    throw std::invalid_argument(name + ": at most " + std::to_string(max_pixels) + " pixels, got " +
                                std::to_string(c.width()) + " x " + std::to_string(c.height()));
  }
  if (c.distortion_size() > 5) {
    throw std::invalid_argument(name + ".distortion: at most 5 coefficients (k1, k2, p1, p2, k3)");
  }
  std::array<double, 5> k{};
  for (int i = 0; i < c.distortion_size(); ++i) k[i] = c.distortion(i);
  const camera::Distortion d = camera::Distortion::FromOpenCv(k);
  try {
    return camera::PinholeCamera(static_cast<int>(c.width()), static_cast<int>(c.height()), c.fx(),
                                 c.fy(), c.cx(), c.cy(), d);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(name + ": " + e.what());
  }
}

pb::CameraIntrinsics CameraToProto(const camera::PinholeCamera& camera) {
  pb::CameraIntrinsics c;
  c.set_width(static_cast<std::uint32_t>(camera.width()));
  c.set_height(static_cast<std::uint32_t>(camera.height()));
  c.set_fx(camera.fx());
  c.set_fy(camera.fy());
  c.set_cx(camera.cx());
  c.set_cy(camera.cy());
  const camera::Distortion& d = camera.distortion();
  if (!d.is_zero()) {
    for (double k : {d.k1, d.k2, d.p1, d.p2, d.k3}) c.add_distortion(k);
  }
  return c;
}

}  // namespace picking::proto_convert
