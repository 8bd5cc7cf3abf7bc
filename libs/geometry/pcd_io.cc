// PCD reading and writing through PCL. The header and the body size are checked here first
// so that a bad file gives an error naming the line or point instead of PCL's console
// message (and so that PCL never sees a truncated body).

#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <optional>
#include <string_view>

#include <pcl/PCLPointCloud2.h>
#include <pcl/io/pcd_io.h>

#include "libs/geometry/io_internal.h"

namespace picking::geometry::internal {
namespace {

struct PcdField {
  std::string name;
  int size = 4;
  char type = 'F';
  int count = 1;
};

struct PcdHeader {
  std::vector<PcdField> fields;
  std::uint64_t width = 0;
  std::uint64_t height = 0;
  std::uint64_t points = 0;
  std::string data;
  std::uint64_t data_offset = 0;  // Byte offset of the body.
  int lines = 0;                  // Header lines including DATA.

  std::uint64_t point_size() const {
    std::uint64_t s = 0;
    for (const PcdField& f : fields) s += static_cast<std::uint64_t>(f.size) * f.count;
    return s;
  }
  std::uint64_t values_per_point() const {
    std::uint64_t s = 0;
    for (const PcdField& f : fields) s += f.count;
    return s;
  }
};

std::vector<std::string_view> Split(std::string_view line) {
  std::vector<std::string_view> tokens;
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && std::isspace(static_cast<unsigned char>(line[i]))) ++i;
    if (i == line.size()) break;
    std::size_t j = i;
    while (j < line.size() && !std::isspace(static_cast<unsigned char>(line[j]))) ++j;
    tokens.push_back(line.substr(i, j - i));
    i = j;
  }
  return tokens;
}

template <typename T>
bool ParseNumber(std::string_view text, T* value) {
  const char* begin = text.data();
  const char* end = text.data() + text.size();
  if (begin != end && *begin == '+') ++begin;
  const auto [stop, ec] = std::from_chars(begin, end, *value);
  return ec == std::errc() && stop == end;
}

bool IsAsciiValue(std::string_view token, const PcdField& field) {
  if (field.type == 'F') {
    if (token == "nan" || token == "NaN" || token == "-nan") return true;
    double value;
    return ParseNumber(token, &value);
  }
  if (field.type == 'U') {
    std::uint64_t value;
    return ParseNumber(token, &value);
  }
  std::int64_t value;
  return ParseNumber(token, &value);
}

PcdHeader ReadHeader(std::istream& in, const std::string& path) {
  PcdHeader header;
  std::string line;
  int n = 0;
  auto fail = [&](const std::string& what) {
    throw PointCloudIoError(path, "line " + std::to_string(n) + ": " + what);
  };
  bool have_size = false, have_type = false, have_width = false, have_height = false,
       have_points = false, have_count = false;
  int points_line = 0;
  std::vector<std::string_view> t;
  while (std::getline(in, line)) {
    ++n;
    t = Split(line);
    if (t.empty() || t[0].front() == '#') continue;
    const std::string_view key = t[0];
    const std::size_t values = t.size() - 1;
    auto numbers = [&](std::uint64_t* out) {
      if (values != 1 || !ParseNumber(t[1], out) ||
          *out > std::numeric_limits<std::uint32_t>::max()) {
        fail(std::string(key) + " needs one integer from 0 to 2^32 - 1");
      }
    };
    auto per_field = [&](const char* what) {
      if (header.fields.empty()) fail(std::string(what) + " before FIELDS");
      if (values != header.fields.size()) {
        fail(std::string(what) + " has " + std::to_string(values) + " entries for " +
             std::to_string(header.fields.size()) + " fields");
      }
    };
    if (key == "VERSION") {
      continue;
    } else if (key == "FIELDS" || key == "COLUMNS") {
      if (values == 0) fail("FIELDS lists no field");
      header.fields.clear();
      for (std::size_t i = 1; i < t.size(); ++i) header.fields.push_back({std::string(t[i])});
    } else if (key == "SIZE") {
      per_field("SIZE");
      for (std::size_t i = 0; i < values; ++i) {
        int size = 0;
        if (!ParseNumber(t[i + 1], &size) || (size != 1 && size != 2 && size != 4 && size != 8)) {
          fail("SIZE \"" + std::string(t[i + 1]) + "\" is not 1, 2, 4 or 8");
        }
        header.fields[i].size = size;
      }
      have_size = true;
    } else if (key == "TYPE") {
      per_field("TYPE");
      for (std::size_t i = 0; i < values; ++i) {
        if (t[i + 1] != "F" && t[i + 1] != "I" && t[i + 1] != "U") {
          fail("TYPE \"" + std::string(t[i + 1]) + "\" is not F, I or U");
        }
        header.fields[i].type = t[i + 1][0];
      }
      have_type = true;
    } else if (key == "COUNT") {
      per_field("COUNT");
      for (std::size_t i = 0; i < values; ++i) {
        int count = 0;
        if (!ParseNumber(t[i + 1], &count) || count < 1) {
          fail("COUNT \"" + std::string(t[i + 1]) + "\" is not a positive integer");
        }
        header.fields[i].count = count;
      }
      have_count = true;
    } else if (key == "WIDTH") {
      numbers(&header.width);
      have_width = true;
    } else if (key == "HEIGHT") {
      numbers(&header.height);
      have_height = true;
    } else if (key == "POINTS") {
      numbers(&header.points);
      have_points = true;
      points_line = n;
    } else if (key == "VIEWPOINT") {
      if (values != 7) fail("VIEWPOINT needs 7 numbers");
      for (std::size_t i = 1; i < t.size(); ++i) {
        double v;
        if (!ParseNumber(t[i], &v)) fail("VIEWPOINT value \"" + std::string(t[i]) + "\"");
      }
    } else if (key == "DATA") {
      if (values != 1 || (t[1] != "ascii" && t[1] != "binary" && t[1] != "binary_compressed")) {
        fail("DATA must be ascii, binary or binary_compressed");
      }
      header.data = std::string(t[1]);
      break;
    } else {
      fail("unknown header keyword \"" + std::string(key) + "\"");
    }
  }
  if (n == 0) throw PointCloudIoError(path, "line 1: empty file");
  if (header.data.empty()) fail("end of file before the DATA line");
  if (header.fields.empty()) fail("no FIELDS line in the header");
  if (!have_size || !have_type) fail("the header needs SIZE and TYPE lines");
  (void)have_count;
  if (!have_width) fail("no WIDTH line in the header");
  if (!have_height) header.height = 1;
  if (!have_points) header.points = header.width * header.height;
  for (const PcdField& f : header.fields) {
    if (f.type == 'F' && f.size != 4 && f.size != 8) {
      fail("field " + f.name + " is F with SIZE " + std::to_string(f.size));
    }
  }
  if (header.width * header.height != header.points) {
    if (points_line > 0) n = points_line;
    fail("WIDTH * HEIGHT (" + std::to_string(header.width) + " * " + std::to_string(header.height) +
         ") != POINTS " + std::to_string(header.points));
  }
  if (header.points > std::numeric_limits<std::uint32_t>::max()) fail("too many points");
  bool x = false, y = false, z = false;
  for (const PcdField& f : header.fields) {
    x |= f.name == "x";
    y |= f.name == "y";
    z |= f.name == "z";
  }
  if (!x || !y || !z) fail("the cloud has no x y z fields");
  header.lines = n;
  return header;
}

// Checks the body against the header (sizes, ASCII values) before PCL reads it.
void CheckBody(std::istream& in, const PcdHeader& header, std::uint64_t file_size,
               const std::string& path) {
  const std::uint64_t body = file_size - header.data_offset;
  const std::uint64_t expected = header.points * header.point_size();
  if (header.data == "binary") {
    if (body < expected) {
      const std::uint64_t complete = body / header.point_size();
      throw PointCloudIoError(
          path, "point " + std::to_string(complete) + ": unexpected end of file (binary body has " +
                    std::to_string(body) + " of " + std::to_string(expected) + " bytes)");
    }
    return;
  }
  if (header.data == "binary_compressed") {
    std::uint32_t sizes[2] = {0, 0};
    if (header.points == 0) return;
    if (body < 8 || !in.read(reinterpret_cast<char*>(sizes), 8)) {
      throw PointCloudIoError(path, "unexpected end of file in the compressed body's sizes");
    }
    if (sizes[1] != expected) {
      throw PointCloudIoError(path, "compressed body unpacks to " + std::to_string(sizes[1]) +
                                        " bytes, the header declares " + std::to_string(expected));
    }
    if (body - 8 < sizes[0]) {
      throw PointCloudIoError(path, "unexpected end of file (compressed body has " +
                                        std::to_string(body - 8) + " of " +
                                        std::to_string(sizes[0]) + " bytes)");
    }
    return;
  }
  // ASCII: one point per line, every value numeric.
  std::string line;
  int line_number = header.lines;
  std::uint64_t point = 0;
  const std::uint64_t values = header.values_per_point();
  while (std::getline(in, line)) {
    ++line_number;
    const auto t = Split(line);
    if (t.empty()) continue;
    auto fail = [&](const std::string& what) {
      throw PointCloudIoError(path, "line " + std::to_string(line_number) + ": point " +
                                        std::to_string(point) + ": " + what);
    };
    if (point == header.points) fail("more points than POINTS declares");
    if (t.size() != values) {
      fail(std::to_string(t.size()) + " values, expected " + std::to_string(values));
    }
    std::size_t k = 0;
    for (const PcdField& f : header.fields) {
      for (int c = 0; c < f.count; ++c, ++k) {
        if (!IsAsciiValue(t[k], f)) {
          fail("\"" + std::string(t[k]) + "\" is not a valid value of field " + f.name);
        }
      }
    }
    ++point;
  }
  if (point != header.points) {
    throw PointCloudIoError(path, "line " + std::to_string(line_number + 1) + ": point " +
                                      std::to_string(point) + ": unexpected end of file (" +
                                      std::to_string(point) + " of " +
                                      std::to_string(header.points) + " points)");
  }
}

const pcl::PCLPointField* Find(const pcl::PCLPointCloud2& cloud, const char* name) {
  for (const auto& f : cloud.fields) {
    if (f.name == name) return &f;
  }
  return nullptr;
}

double LoadValue(const std::uint8_t* p, const pcl::PCLPointField& field) {
  switch (field.datatype) {
    case pcl::PCLPointField::INT8: {
      std::int8_t v;
      std::memcpy(&v, p, 1);
      return v;
    }
    case pcl::PCLPointField::UINT8: {
      std::uint8_t v;
      std::memcpy(&v, p, 1);
      return v;
    }
    case pcl::PCLPointField::INT16: {
      std::int16_t v;
      std::memcpy(&v, p, 2);
      return v;
    }
    case pcl::PCLPointField::UINT16: {
      std::uint16_t v;
      std::memcpy(&v, p, 2);
      return v;
    }
    case pcl::PCLPointField::INT32: {
      std::int32_t v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case pcl::PCLPointField::UINT32: {
      std::uint32_t v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case pcl::PCLPointField::FLOAT32: {
      float v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case pcl::PCLPointField::FLOAT64: {
      double v;
      std::memcpy(&v, p, 8);
      return v;
    }
    default:
      return std::numeric_limits<double>::quiet_NaN();
  }
}

pcl::PCLPointField MakeField(const std::string& name, std::uint32_t offset, std::uint8_t datatype) {
  pcl::PCLPointField field;
  field.name = name;
  field.offset = offset;
  field.datatype = datatype;
  field.count = 1;
  return field;
}

}  // namespace

PointCloud ReadPcd(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw PointCloudIoError(path, "cannot open");
  in.seekg(0, std::ios::end);
  const auto file_size = static_cast<std::uint64_t>(in.tellg());
  in.seekg(0);
  PcdHeader header = ReadHeader(in, path);
  header.data_offset = in.tellg() < 0 ? file_size : static_cast<std::uint64_t>(in.tellg());
  CheckBody(in, header, file_size, path);
  in.close();
  if (header.points == 0) {
    PointCloud empty;
    empty.width = static_cast<std::uint32_t>(header.width);
    empty.height = static_cast<std::uint32_t>(header.height);
    return empty;
  }

  pcl::PCLPointCloud2 blob;
  pcl::PCDReader reader;
  if (reader.read(path, blob) < 0) {
    throw PointCloudIoError(path, "PCL could not read the " + header.data + " body");
  }
  if (blob.width * blob.height != header.points ||
      blob.data.size() < static_cast<std::size_t>(blob.row_step) * blob.height) {
    throw PointCloudIoError(path, "PCL read a body that does not match the header");
  }

  const pcl::PCLPointField* fx = Find(blob, "x");
  const pcl::PCLPointField* fy = Find(blob, "y");
  const pcl::PCLPointField* fz = Find(blob, "z");
  const pcl::PCLPointField* fnx = Find(blob, "normal_x");
  const pcl::PCLPointField* fny = Find(blob, "normal_y");
  const pcl::PCLPointField* fnz = Find(blob, "normal_z");
  const pcl::PCLPointField* frgb = Find(blob, "rgba");
  if (frgb == nullptr) frgb = Find(blob, "rgb");
  const pcl::PCLPointField* fi = Find(blob, "intensity");
  if (fx == nullptr || fy == nullptr || fz == nullptr) {
    throw PointCloudIoError(path, "the cloud has no x y z fields");
  }
  const bool normals = fnx != nullptr && fny != nullptr && fnz != nullptr;
  if (!normals && (fnx != nullptr || fny != nullptr || fnz != nullptr)) {
    throw PointCloudIoError(path, "normals need all of normal_x normal_y normal_z");
  }
  if (frgb != nullptr && frgb->datatype != pcl::PCLPointField::FLOAT32 &&
      frgb->datatype != pcl::PCLPointField::UINT32 && frgb->datatype != pcl::PCLPointField::INT32) {
    throw PointCloudIoError(path, "field " + frgb->name + " must be 4 bytes (packed colour)");
  }

  PointCloud cloud;
  const std::size_t n = static_cast<std::size_t>(blob.width) * blob.height;
  cloud.width = blob.width;
  cloud.height = blob.height;
  cloud.points.resize(n);
  if (normals) cloud.normals.resize(n);
  if (frgb != nullptr) cloud.colors.resize(n);
  if (fi != nullptr) cloud.intensities.resize(n);
  std::size_t i = 0;
  for (std::uint32_t row = 0; row < blob.height; ++row) {
    for (std::uint32_t col = 0; col < blob.width; ++col, ++i) {
      const std::uint8_t* p = blob.data.data() + static_cast<std::size_t>(row) * blob.row_step +
                              static_cast<std::size_t>(col) * blob.point_step;
      cloud.points[i] = Eigen::Vector3f(static_cast<float>(LoadValue(p + fx->offset, *fx)),
                                        static_cast<float>(LoadValue(p + fy->offset, *fy)),
                                        static_cast<float>(LoadValue(p + fz->offset, *fz)));
      if (normals) {
        cloud.normals[i] = Eigen::Vector3f(static_cast<float>(LoadValue(p + fnx->offset, *fnx)),
                                           static_cast<float>(LoadValue(p + fny->offset, *fny)),
                                           static_cast<float>(LoadValue(p + fnz->offset, *fnz)));
      }
      if (frgb != nullptr) {
        std::uint32_t packed;
        std::memcpy(&packed, p + frgb->offset, 4);
        cloud.colors[i] = {static_cast<std::uint8_t>((packed >> 16) & 0xff),
                           static_cast<std::uint8_t>((packed >> 8) & 0xff),
                           static_cast<std::uint8_t>(packed & 0xff)};
      }
      if (fi != nullptr) cloud.intensities[i] = static_cast<float>(LoadValue(p + fi->offset, *fi));
    }
  }
  return cloud;
}

void WritePcd(const std::string& path, const PointCloud& cloud, PointCloudFormat format) {
  pcl::PCLPointCloud2 blob;
  std::uint32_t offset = 0;
  for (const char* name : {"x", "y", "z"}) {
    blob.fields.push_back(MakeField(name, offset, pcl::PCLPointField::FLOAT32));
    offset += 4;
  }
  if (cloud.has_normals()) {
    for (const char* name : {"normal_x", "normal_y", "normal_z"}) {
      blob.fields.push_back(MakeField(name, offset, pcl::PCLPointField::FLOAT32));
      offset += 4;
    }
  }
  const std::uint32_t color_offset = offset;
  if (cloud.has_colors()) {
    blob.fields.push_back(MakeField("rgba", offset, pcl::PCLPointField::UINT32));
    offset += 4;
  }
  const std::uint32_t intensity_offset = offset;
  if (cloud.has_intensities()) {
    blob.fields.push_back(MakeField("intensity", offset, pcl::PCLPointField::FLOAT32));
    offset += 4;
  }
  blob.point_step = offset;
  blob.width = cloud.width;
  blob.height = cloud.height;
  blob.row_step = blob.point_step * blob.width;
  blob.is_bigendian = false;
  blob.is_dense = true;
  blob.data.resize(static_cast<std::size_t>(blob.row_step) * blob.height);
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    std::uint8_t* p = blob.data.data() + i * blob.point_step;
    std::memcpy(p, cloud.points[i].data(), 12);
    if (!cloud.points[i].allFinite()) blob.is_dense = false;
    if (cloud.has_normals()) std::memcpy(p + 12, cloud.normals[i].data(), 12);
    if (cloud.has_colors()) {
      const auto& c = cloud.colors[i];
      const std::uint32_t packed = 0xff000000u | (std::uint32_t{c[0]} << 16) |
                                   (std::uint32_t{c[1]} << 8) | std::uint32_t{c[2]};
      std::memcpy(p + color_offset, &packed, 4);
    }
    if (cloud.has_intensities()) std::memcpy(p + intensity_offset, &cloud.intensities[i], 4);
  }

  AtomicFile file(path);
  pcl::PCDWriter writer;
  const Eigen::Vector4f origin = Eigen::Vector4f::Zero();
  const Eigen::Quaternionf orientation = Eigen::Quaternionf::Identity();
  int status = 0;
  if (cloud.empty()) {
    // PCL refuses to write an empty cloud; the header alone is a valid PCD file.
    file.Open();
    std::string header = "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS";
    std::string sizes = "SIZE", types = "TYPE", counts = "COUNT";
    for (const pcl::PCLPointField& f : blob.fields) {
      header += " " + f.name;
      sizes += " 4";
      types += f.datatype == pcl::PCLPointField::UINT32 ? " U" : " F";
      counts += " 1";
    }
    const std::string data = format == PointCloudFormat::kPcdAscii    ? "ascii"
                             : format == PointCloudFormat::kPcdBinary ? "binary"
                                                                      : "binary_compressed";
    header += "\n" + sizes + "\n" + types + "\n" + counts + "\nWIDTH 0\nHEIGHT " +
              std::to_string(cloud.height) + "\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 0\nDATA " + data +
              "\n";
    file.Write(header);
  } else if (format == PointCloudFormat::kPcdAscii) {
    // 9 significant digits reproduce every float exactly.
    status = writer.writeASCII(file.temp_path(), blob, origin, orientation, 9);
  } else if (format == PointCloudFormat::kPcdBinary) {
    status = writer.writeBinary(file.temp_path(), blob, origin, orientation);
  } else {
    status = writer.writeBinaryCompressed(file.temp_path(), blob, origin, orientation);
  }
  if (status != 0) throw PointCloudIoError(path, "PCL could not write the file");
  file.Commit();
}

}  // namespace picking::geometry::internal
