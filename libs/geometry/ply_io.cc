// PLY reading and writing (http://paulbourke.net/dataformats/ply/), streaming through a
// buffered reader so that large models never need a second copy in memory.

#include "libs/geometry/ply_io.h"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <optional>
#include <string_view>

#include "libs/geometry/io_internal.h"

namespace picking::geometry {
namespace {

enum class Encoding { kAscii, kLittleEndian, kBigEndian };

enum class ScalarType { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64 };

std::optional<ScalarType> ParseType(std::string_view name) {
  if (name == "char" || name == "int8") return ScalarType::kInt8;
  if (name == "uchar" || name == "uint8") return ScalarType::kUint8;
  if (name == "short" || name == "int16") return ScalarType::kInt16;
  if (name == "ushort" || name == "uint16") return ScalarType::kUint16;
  if (name == "int" || name == "int32") return ScalarType::kInt32;
  if (name == "uint" || name == "uint32") return ScalarType::kUint32;
  if (name == "float" || name == "float32") return ScalarType::kFloat32;
  if (name == "double" || name == "float64") return ScalarType::kFloat64;
  return std::nullopt;
}

std::size_t SizeOf(ScalarType type) {
  switch (type) {
    case ScalarType::kInt8:
    case ScalarType::kUint8:
      return 1;
    case ScalarType::kInt16:
    case ScalarType::kUint16:
      return 2;
    case ScalarType::kInt32:
    case ScalarType::kUint32:
    case ScalarType::kFloat32:
      return 4;
    case ScalarType::kFloat64:
      return 8;
  }
  return 0;
}

bool IsFloat(ScalarType type) {
  return type == ScalarType::kFloat32 || type == ScalarType::kFloat64;
}

// kFace: the vertex index list of a face element (read only when faces are asked for).
enum class Role { kIgnore, kX, kY, kZ, kNx, kNy, kNz, kRed, kGreen, kBlue, kIntensity, kFace };
constexpr std::size_t kRoles = static_cast<std::size_t>(Role::kFace) + 1;

struct Property {
  std::string name;
  ScalarType type = ScalarType::kFloat32;  // Item type for lists.
  bool is_list = false;
  ScalarType count_type = ScalarType::kUint8;
  Role role = Role::kIgnore;
};

struct Element {
  std::string name;
  std::uint64_t count = 0;
  std::vector<Property> properties;
  int header_line = 0;

  bool has_lists() const {
    return std::any_of(properties.begin(), properties.end(),
                       [](const Property& p) { return p.is_list; });
  }
  std::size_t stride() const {
    std::size_t s = 0;
    for (const Property& p : properties) s += SizeOf(p.type);
    return s;
  }
};

bool HostIsLittleEndian() {
  const std::uint16_t one = 1;
  unsigned char first;
  std::memcpy(&first, &one, 1);
  return first == 1;
}

// Buffered sequential reader over a FILE*.
class Reader final {
 public:
  Reader(const std::string& path) : path_(path) {
    file_ = std::fopen(path.c_str(), "rb");
    if (file_ == nullptr) {
      throw PointCloudIoError(path, std::string("cannot open: ") + std::strerror(errno));
    }
    if (std::fseek(file_, 0, SEEK_END) == 0) {
      const long size = std::ftell(file_);
      if (size >= 0) size_ = static_cast<std::uint64_t>(size);
      std::fseek(file_, 0, SEEK_SET);
    }
    buffer_.resize(1 << 20);
  }
  ~Reader() { std::fclose(file_); }
  Reader(const Reader&) = delete;
  Reader& operator=(const Reader&) = delete;

  // Bytes not consumed yet.
  std::uint64_t remaining() const { return size_ - consumed_; }

  // Reads a line without its terminator ("\n" or "\r\n"); false at end of file.
  // terminated() tells whether the line ended with "\n" (false for a last, cut line).
  bool terminated() const { return terminated_; }
  bool ReadLine(std::string* line) {
    line->clear();
    terminated_ = false;
    bool any = false;
    while (true) {
      if (pos_ == end_ && !Fill()) break;
      any = true;
      const char* start = buffer_.data() + pos_;
      const char* stop = static_cast<const char*>(std::memchr(start, '\n', end_ - pos_));
      if (stop != nullptr) {
        line->append(start, stop);
        Consume(stop - start + 1);
        if (!line->empty() && line->back() == '\r') line->pop_back();
        terminated_ = true;
        return true;
      }
      line->append(start, end_ - pos_);
      Consume(end_ - pos_);
    }
    if (!line->empty() && line->back() == '\r') line->pop_back();
    return any;
  }

  // Reads exactly n bytes; returns how many were available.
  std::size_t Read(char* dst, std::size_t n) {
    std::size_t done = 0;
    while (done < n) {
      if (pos_ == end_ && !Fill()) break;
      const std::size_t take = std::min(n - done, end_ - pos_);
      std::memcpy(dst + done, buffer_.data() + pos_, take);
      Consume(take);
      done += take;
    }
    return done;
  }

  // Skips n bytes; returns how many were available.
  std::uint64_t Skip(std::uint64_t n) {
    std::uint64_t done = 0;
    while (done < n) {
      if (pos_ == end_ && !Fill()) break;
      const std::size_t take =
          static_cast<std::size_t>(std::min<std::uint64_t>(n - done, end_ - pos_));
      Consume(take);
      done += take;
    }
    return done;
  }

 private:
  bool Fill() {
    pos_ = 0;
    end_ = std::fread(buffer_.data(), 1, buffer_.size(), file_);
    return end_ > 0;
  }
  void Consume(std::size_t n) {
    pos_ += n;
    consumed_ += n;
  }

  std::string path_;
  std::FILE* file_ = nullptr;
  std::vector<char> buffer_;
  std::size_t pos_ = 0;
  std::size_t end_ = 0;
  std::uint64_t size_ = 0;
  std::uint64_t consumed_ = 0;
  bool terminated_ = false;
};

std::vector<std::string_view> Split(std::string_view line) {
  std::vector<std::string_view> tokens;
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && (line[i] == ' ' || line[i] == '\t' || line[i] == '\r')) ++i;
    if (i == line.size()) break;
    std::size_t j = i;
    while (j < line.size() && line[j] != ' ' && line[j] != '\t' && line[j] != '\r') ++j;
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

// Parses an ASCII scalar of `type` as double; false when it is not a number of that type.
bool ParseScalar(std::string_view text, ScalarType type, double* value) {
  if (IsFloat(type)) return ParseNumber(text, value);
  std::int64_t integer = 0;
  if (!ParseNumber(text, &integer)) return false;
  const std::size_t bits = 8 * SizeOf(type);
  const bool is_signed =
      type == ScalarType::kInt8 || type == ScalarType::kInt16 || type == ScalarType::kInt32;
  const std::int64_t lo = is_signed ? -(std::int64_t{1} << (bits - 1)) : 0;
  const std::int64_t hi =
      is_signed ? (std::int64_t{1} << (bits - 1)) - 1 : (std::int64_t{1} << bits) - 1;
  if (integer < lo || integer > hi) return false;
  *value = static_cast<double>(integer);
  return true;
}

template <typename T>
T Load(const char* p, bool swap) {
  std::array<char, sizeof(T)> bytes;
  std::memcpy(bytes.data(), p, sizeof(T));
  if (swap) std::reverse(bytes.begin(), bytes.end());
  T value;
  std::memcpy(&value, bytes.data(), sizeof(T));
  return value;
}

double LoadScalar(const char* p, ScalarType type, bool swap) {
  switch (type) {
    case ScalarType::kInt8:
      return Load<std::int8_t>(p, false);
    case ScalarType::kUint8:
      return Load<std::uint8_t>(p, false);
    case ScalarType::kInt16:
      return Load<std::int16_t>(p, swap);
    case ScalarType::kUint16:
      return Load<std::uint16_t>(p, swap);
    case ScalarType::kInt32:
      return Load<std::int32_t>(p, swap);
    case ScalarType::kUint32:
      return Load<std::uint32_t>(p, swap);
    case ScalarType::kFloat32:
      return Load<float>(p, swap);
    case ScalarType::kFloat64:
      return Load<double>(p, swap);
  }
  return 0.0;
}

std::uint8_t ToColor(double value, ScalarType type) {
  const double scaled = IsFloat(type) ? value * 255.0 : value;
  if (!(scaled > 0.0)) return 0;  // Also NaN.
  if (scaled >= 255.0) return 255;
  return static_cast<std::uint8_t>(std::lround(scaled));
}

struct Header {
  Encoding encoding = Encoding::kAscii;
  std::vector<Element> elements;
  std::string frame_id;
  std::optional<std::pair<std::uint32_t, std::uint32_t>> organized;
  int organized_line = 0;
  int lines = 0;  // Number of header lines including end_header.
};

Header ReadHeader(Reader& reader, const std::string& path) {
  Header header;
  std::string line;
  int n = 0;
  auto fail = [&](const std::string& what) -> void {
    throw PointCloudIoError(path, "line " + std::to_string(n) + ": " + what);
  };
  bool have_format = false;
  bool ended = false;
  while (reader.ReadLine(&line)) {
    ++n;
    if (!reader.terminated()) fail("end of file before end_header");
    const std::vector<std::string_view> t = Split(line);
    if (n == 1) {
      if (t.size() != 1 || t[0] != "ply") fail("not a PLY file (it does not start with \"ply\")");
      continue;
    }
    if (t.empty()) continue;
    const std::string_view key = t[0];
    if (key == "format") {
      if (t.size() != 3) fail("malformed format line");
      if (t[1] == "ascii") {
        header.encoding = Encoding::kAscii;
      } else if (t[1] == "binary_little_endian") {
        header.encoding = Encoding::kLittleEndian;
      } else if (t[1] == "binary_big_endian") {
        header.encoding = Encoding::kBigEndian;
      } else {
        fail("unknown format \"" + std::string(t[1]) + "\"");
      }
      if (t[2] != "1.0") fail("unsupported PLY version \"" + std::string(t[2]) + "\"");
      have_format = true;
    } else if (key == "comment" || key == "obj_info") {
      if (t.size() >= 3 && t[1] == "frame_id") {
        const std::size_t at = line.find("frame_id") + std::strlen("frame_id");
        std::string id = line.substr(at);
        id.erase(0, id.find_first_not_of(" \t"));
        header.frame_id = id;
      } else if (t.size() == 4 && t[1] == "organized") {
        std::uint32_t w = 0, h = 0;
        if (!ParseNumber(t[2], &w) || !ParseNumber(t[3], &h)) fail("malformed organized comment");
        header.organized = {w, h};
        header.organized_line = n;
      }
    } else if (key == "element") {
      if (t.size() != 3) fail("malformed element line");
      Element element;
      element.name = std::string(t[1]);
      if (!ParseNumber(t[2], &element.count)) {
        fail("element count \"" + std::string(t[2]) + "\" is not a non-negative integer");
      }
      element.header_line = n;
      header.elements.push_back(std::move(element));
    } else if (key == "property") {
      if (header.elements.empty()) fail("property before any element");
      Property property;
      if (t.size() == 5 && t[1] == "list") {
        const auto count_type = ParseType(t[2]);
        const auto item_type = ParseType(t[3]);
        if (!count_type || IsFloat(*count_type)) {
          fail("bad list count type \"" + std::string(t[2]) + "\"");
        }
        if (!item_type) fail("unknown property type \"" + std::string(t[3]) + "\"");
        property.is_list = true;
        property.count_type = *count_type;
        property.type = *item_type;
        property.name = std::string(t[4]);
      } else if (t.size() == 3) {
        const auto type = ParseType(t[1]);
        if (!type) fail("unknown property type \"" + std::string(t[1]) + "\"");
        property.type = *type;
        property.name = std::string(t[2]);
      } else {
        fail("malformed property line");
      }
      for (const Property& other : header.elements.back().properties) {
        if (other.name == property.name) fail("property \"" + property.name + "\" twice");
      }
      header.elements.back().properties.push_back(std::move(property));
    } else if (key == "end_header") {
      ended = true;
      break;
    } else {
      fail("unknown header keyword \"" + std::string(key) + "\"");
    }
  }
  if (n == 0) throw PointCloudIoError(path, "line 1: empty file");
  if (!ended) fail("end of file before end_header");
  if (!have_format) fail("no format line in the header");
  header.lines = n;
  return header;
}

// Assigns roles to the vertex properties (`scalar` is the intensity property's name); throws
// on partial channels.
void AssignRoles(Element& vertex, const std::string& scalar, const std::string& path) {
  auto find = [&](std::initializer_list<const char*> names) -> Property* {
    for (const char* name : names) {
      for (Property& p : vertex.properties) {
        if (p.name == name) return &p;
      }
    }
    return nullptr;
  };
  auto fail = [&](const std::string& what) {
    throw PointCloudIoError(
        path, "line " + std::to_string(vertex.header_line) + ": element vertex: " + what);
  };
  auto assign = [&](std::initializer_list<std::initializer_list<const char*>> names,
                    std::initializer_list<Role> roles, const char* channel, bool required) {
    std::vector<Property*> found;
    for (const auto& alternatives : names) found.push_back(find(alternatives));
    const auto present = std::count_if(found.begin(), found.end(), [](Property* p) { return p; });
    if (present == 0 && !required) return;
    if (present != static_cast<long>(found.size())) {
      fail(std::string(channel) + " need all three properties");
    }
    auto role = roles.begin();
    for (Property* p : found) {
      if (p->is_list) fail("property \"" + p->name + "\" is a list");
      p->role = *role++;
    }
  };
  assign({{"x"}, {"y"}, {"z"}}, {Role::kX, Role::kY, Role::kZ}, "positions (x y z)", true);
  assign({{"nx"}, {"ny"}, {"nz"}}, {Role::kNx, Role::kNy, Role::kNz}, "normals (nx ny nz)", false);
  assign({{"red", "r"}, {"green", "g"}, {"blue", "b"}}, {Role::kRed, Role::kGreen, Role::kBlue},
         "colours (red green blue)", false);
  if (Property* p = find({scalar.c_str()})) {
    if (p->is_list) fail("property \"" + scalar + "\" is a list");
    p->role = Role::kIntensity;
  }
}

class VertexSink final {
 public:
  VertexSink(const Element& vertex, PointCloud* cloud) : cloud_(cloud) {
    for (const Property& p : vertex.properties) {
      has_normals_ |= p.role == Role::kNx;
      has_colors_ |= p.role == Role::kRed;
      has_intensity_ |= p.role == Role::kIntensity;
    }
  }
  void Reserve(std::size_t n) {
    cloud_->points.reserve(n);
    if (has_normals_) cloud_->normals.reserve(n);
    if (has_colors_) cloud_->colors.reserve(n);
    if (has_intensity_) cloud_->intensities.reserve(n);
  }
  void Set(const Property& property, double value) {
    switch (property.role) {
      case Role::kX:
        p_.x() = static_cast<float>(value);
        break;
      case Role::kY:
        p_.y() = static_cast<float>(value);
        break;
      case Role::kZ:
        p_.z() = static_cast<float>(value);
        break;
      case Role::kNx:
        n_.x() = static_cast<float>(value);
        break;
      case Role::kNy:
        n_.y() = static_cast<float>(value);
        break;
      case Role::kNz:
        n_.z() = static_cast<float>(value);
        break;
      case Role::kRed:
        c_[0] = ToColor(value, property.type);
        break;
      case Role::kGreen:
        c_[1] = ToColor(value, property.type);
        break;
      case Role::kBlue:
        c_[2] = ToColor(value, property.type);
        break;
      case Role::kIntensity:
        i_ = static_cast<float>(value);
        break;
      case Role::kIgnore:
      case Role::kFace:
        break;
    }
  }
  void Push() {
    cloud_->points.push_back(p_);
    if (has_normals_) cloud_->normals.push_back(n_);
    if (has_colors_) cloud_->colors.push_back(c_);
    if (has_intensity_) cloud_->intensities.push_back(i_);
  }

 private:
  PointCloud* cloud_;
  bool has_normals_ = false, has_colors_ = false, has_intensity_ = false;
  Eigen::Vector3f p_ = Eigen::Vector3f::Zero();
  Eigen::Vector3f n_ = Eigen::Vector3f::Zero();
  std::array<std::uint8_t, 3> c_ = {0, 0, 0};
  float i_ = 0.0f;
};

using Triangles = std::vector<std::array<std::uint32_t, 3>>;

// A face's vertex index; one that is no uint32 becomes UINT32_MAX, which is out of range.
std::uint32_t ToIndex(double value) {
  constexpr std::uint32_t kMax = std::numeric_limits<std::uint32_t>::max();
  return value >= 0 && value < kMax ? static_cast<std::uint32_t>(value) : kMax;
}

// Fans a polygon's vertex indices into triangles.
void Fan(const std::vector<std::uint32_t>& polygon, Triangles* triangles) {
  for (std::size_t k = 1; k + 1 < polygon.size(); ++k) {
    triangles->push_back({polygon[0], polygon[k], polygon[k + 1]});
  }
}

std::string Instance(const Element& element, std::uint64_t index) {
  return element.name + " " + std::to_string(index);
}

void ReadAsciiBody(Reader& reader, const Header& header, std::size_t vertex_index,
                   const std::string& path, PointCloud* cloud, Triangles* triangles) {
  std::string line;
  std::vector<std::uint32_t> polygon;
  int line_number = header.lines;
  for (std::size_t e = 0; e < header.elements.size(); ++e) {
    const Element& element = header.elements[e];
    const bool is_vertex = e == vertex_index;
    std::optional<VertexSink> sink;
    if (is_vertex) {
      sink.emplace(element, cloud);
      // A vertex line has at least two bytes per property: never reserve more than fits.
      sink->Reserve(static_cast<std::size_t>(std::min<std::uint64_t>(
          element.count, reader.remaining() / (2 * element.properties.size() + 1))));
    }
    for (std::uint64_t i = 0; i < element.count; ++i) {
      std::vector<std::string_view> tokens;
      do {
        if (!reader.ReadLine(&line)) {
          throw PointCloudIoError(
              path, "line " + std::to_string(line_number + 1) + ": " + Instance(element, i) +
                        ": unexpected end of file (" + std::to_string(i) + " of " +
                        std::to_string(element.count) + " " + element.name + " elements read)");
        }
        ++line_number;
        tokens = Split(line);
      } while (tokens.empty());
      polygon.clear();
      auto fail = [&](const std::string& what) {
        throw PointCloudIoError(path, "line " + std::to_string(line_number) + ": " +
                                          Instance(element, i) + ": " + what);
      };
      std::size_t t = 0;
      for (const Property& property : element.properties) {
        if (property.is_list) {
          if (t >= tokens.size()) fail("too few values");
          double count = 0;
          if (!ParseScalar(tokens[t], property.count_type, &count) || count < 0) {
            fail("list count \"" + std::string(tokens[t]) + "\" of property " + property.name +
                 " is not a valid count");
          }
          ++t;
          const auto items = static_cast<std::size_t>(count);
          if (t + items > tokens.size()) fail("too few values");
          for (std::size_t k = 0; k < items; ++k, ++t) {
            double value = 0;
            if (!ParseScalar(tokens[t], property.type, &value)) {
              fail("\"" + std::string(tokens[t]) + "\" is not a valid value of property " +
                   property.name);
            }
            if (property.role == Role::kFace) polygon.push_back(ToIndex(value));
          }
          continue;
        }
        if (t >= tokens.size()) fail("too few values");
        double value = 0;
        if (!ParseScalar(tokens[t], property.type, &value)) {
          fail("\"" + std::string(tokens[t]) + "\" is not a valid value of property " +
               property.name);
        }
        ++t;
        if (sink) sink->Set(property, value);
      }
      if (t != tokens.size()) {
        fail("too many values (" + std::to_string(tokens.size()) + ", expected " +
             std::to_string(t) + ")");
      }
      if (sink) sink->Push();
      Fan(polygon, triangles);
    }
  }
  while (reader.ReadLine(&line)) {
    ++line_number;
    if (!Split(line).empty()) {
      throw PointCloudIoError(path, "line " + std::to_string(line_number) +
                                        ": data after the last element the header declares");
    }
  }
}

// An element of fixed-size records (no lists): skipped, or read into the cloud when it is the
// vertex element (a fast path for float channels and uchar colours in host byte order).
void ReadFixedRecords(Reader& reader, const Element& element, bool is_vertex, bool swap,
                      const std::function<void(std::uint64_t)>& truncated, std::vector<char>& block,
                      PointCloud* cloud) {
  const std::size_t stride = element.stride();
  if (stride == 0) return;
  if (element.count > reader.remaining() / stride) truncated(reader.remaining() / stride);
  if (!is_vertex) {
    reader.Skip(element.count * stride);
    return;
  }
  VertexSink sink(element, cloud);
  sink.Reserve(static_cast<std::size_t>(element.count));
  std::vector<std::size_t> offsets;
  std::size_t offset = 0;
  for (const Property& p : element.properties) {
    offsets.push_back(offset);
    offset += SizeOf(p.type);
  }
  // Fast path for the usual layout in host byte order: float channels, uchar colours.
  std::array<std::ptrdiff_t, kRoles> at;
  at.fill(-1);
  bool direct = !swap;
  for (std::size_t q = 0; q < element.properties.size(); ++q) {
    const Property& p = element.properties[q];
    if (p.role == Role::kIgnore) continue;
    at[static_cast<int>(p.role)] = static_cast<std::ptrdiff_t>(offsets[q]);
    const bool is_color = p.role == Role::kRed || p.role == Role::kGreen || p.role == Role::kBlue;
    direct &= p.type == (is_color ? ScalarType::kUint8 : ScalarType::kFloat32);
  }
  const bool normals = at[static_cast<int>(Role::kNx)] >= 0;
  const bool colors = at[static_cast<int>(Role::kRed)] >= 0;
  const bool intensity = at[static_cast<int>(Role::kIntensity)] >= 0;
  auto offset_of = [&](Role role) { return at[static_cast<int>(role)]; };
  constexpr std::uint64_t kBlock = 1 << 14;
  block.resize(kBlock * stride);
  for (std::uint64_t first = 0; first < element.count; first += kBlock) {
    const std::uint64_t n = std::min(kBlock, element.count - first);
    const std::size_t got = reader.Read(block.data(), n * stride);
    if (got != n * stride) truncated(first + got / stride);
    if (direct) {
      for (std::uint64_t k = 0; k < n; ++k) {
        const char* record = block.data() + k * stride;
        Eigen::Vector3f v;
        std::memcpy(&v[0], record + offset_of(Role::kX), 4);
        std::memcpy(&v[1], record + offset_of(Role::kY), 4);
        std::memcpy(&v[2], record + offset_of(Role::kZ), 4);
        cloud->points.push_back(v);
        if (normals) {
          std::memcpy(&v[0], record + offset_of(Role::kNx), 4);
          std::memcpy(&v[1], record + offset_of(Role::kNy), 4);
          std::memcpy(&v[2], record + offset_of(Role::kNz), 4);
          cloud->normals.push_back(v);
        }
        if (colors) {
          cloud->colors.push_back({static_cast<std::uint8_t>(record[offset_of(Role::kRed)]),
                                   static_cast<std::uint8_t>(record[offset_of(Role::kGreen)]),
                                   static_cast<std::uint8_t>(record[offset_of(Role::kBlue)])});
        }
        if (intensity) {
          float value;
          std::memcpy(&value, record + offset_of(Role::kIntensity), 4);
          cloud->intensities.push_back(value);
        }
      }
      continue;
    }
    for (std::uint64_t k = 0; k < n; ++k) {
      const char* record = block.data() + k * stride;
      for (std::size_t q = 0; q < element.properties.size(); ++q) {
        const Property& property = element.properties[q];
        if (property.role == Role::kIgnore) continue;
        sink.Set(property, LoadScalar(record + offsets[q], property.type, swap));
      }
      sink.Push();
    }
  }
}

// An element with list properties, record by record: face lists become triangles, other lists
// are skipped, the scalars of the vertex element go to the cloud.
void ReadListRecords(Reader& reader, const Element& element, bool is_vertex, bool swap,
                     const std::function<void(std::uint64_t)>& truncated, const std::string& path,
                     PointCloud* cloud, Triangles* triangles) {
  std::optional<VertexSink> sink;
  if (is_vertex) sink.emplace(element, cloud);
  char scratch[8];
  std::vector<std::uint32_t> polygon;
  for (std::uint64_t i = 0; i < element.count; ++i) {
    polygon.clear();
    for (const Property& property : element.properties) {
      if (property.is_list) {
        const std::size_t count_size = SizeOf(property.count_type);
        if (reader.Read(scratch, count_size) != count_size) truncated(i);
        const double count = LoadScalar(scratch, property.count_type, swap);
        if (count < 0) {
          throw PointCloudIoError(
              path, Instance(element, i) + ": negative list count of " + property.name);
        }
        const auto items = static_cast<std::uint64_t>(count);
        const std::size_t size = SizeOf(property.type);
        if (property.role != Role::kFace) {
          if (reader.Skip(items * size) != items * size) truncated(i);
          continue;
        }
        for (std::uint64_t k = 0; k < items; ++k) {
          if (reader.Read(scratch, size) != size) truncated(i);
          polygon.push_back(ToIndex(LoadScalar(scratch, property.type, swap)));
        }
        continue;
      }
      const std::size_t size = SizeOf(property.type);
      if (reader.Read(scratch, size) != size) truncated(i);
      if (sink) sink->Set(property, LoadScalar(scratch, property.type, swap));
    }
    if (sink) sink->Push();
    Fan(polygon, triangles);
  }
}

void ReadBinaryBody(Reader& reader, const Header& header, std::size_t vertex_index,
                    const std::string& path, PointCloud* cloud, Triangles* triangles) {
  const bool swap = (header.encoding == Encoding::kBigEndian) == HostIsLittleEndian();
  std::vector<char> block;
  for (std::size_t e = 0; e < header.elements.size(); ++e) {
    const Element& element = header.elements[e];
    const bool is_vertex = e == vertex_index;
    const std::function<void(std::uint64_t)> truncated = [&](std::uint64_t i) {
      throw PointCloudIoError(path, Instance(element, i) + ": unexpected end of file (" +
                                        std::to_string(i) + " of " + std::to_string(element.count) +
                                        " " + element.name + " elements complete)");
    };
    if (element.has_lists()) {
      ReadListRecords(reader, element, is_vertex, swap, truncated, path, cloud, triangles);
    } else {
      ReadFixedRecords(reader, element, is_vertex, swap, truncated, block, cloud);
    }
  }
  if (reader.remaining() != 0) {
    throw PointCloudIoError(path, std::to_string(reader.remaining()) +
                                      " bytes after the last element the header declares");
  }
}

template <typename T>
void Store(T value, bool swap, std::vector<char>* out) {
  std::array<char, sizeof(T)> bytes;
  std::memcpy(bytes.data(), &value, sizeof(T));
  if (swap) std::reverse(bytes.begin(), bytes.end());
  out->insert(out->end(), bytes.begin(), bytes.end());
}

void AppendFloat(float value, std::string* out) {
  char text[32];
  const auto [end, ec] = std::to_chars(text, text + sizeof(text), value);
  out->append(text, end);
}

}  // namespace

PlyFile ReadPlyFile(const std::string& path, const PlyReadOptions& options) {
  Reader reader(path);
  Header header = ReadHeader(reader, path);
  std::size_t vertex_index = header.elements.size();
  for (std::size_t e = 0; e < header.elements.size(); ++e) {
    if (header.elements[e].name == "vertex") {
      if (vertex_index != header.elements.size()) {
        throw PointCloudIoError(path, "line " + std::to_string(header.elements[e].header_line) +
                                          ": second vertex element");
      }
      vertex_index = e;
    }
  }
  if (vertex_index == header.elements.size()) {
    throw PointCloudIoError(
        path, "line " + std::to_string(header.lines) + ": the header declares no vertex element");
  }
  AssignRoles(header.elements[vertex_index], options.scalar_property, path);
  for (Element& element : header.elements) {
    for (Property& p : element.properties) {
      if (options.faces && element.name == "face" && p.is_list &&
          (p.name == "vertex_indices" || p.name == "vertex_index")) {
        p.role = Role::kFace;
      }
    }
  }

  PlyFile file;
  PointCloud& cloud = file.cloud;
  if (header.encoding == Encoding::kAscii) {
    ReadAsciiBody(reader, header, vertex_index, path, &cloud, &file.triangles);
  } else {
    ReadBinaryBody(reader, header, vertex_index, path, &cloud, &file.triangles);
  }
  cloud.frame_id = header.frame_id;
  const std::size_t n = cloud.points.size();
  if (header.organized) {
    const auto [w, h] = *header.organized;
    if (static_cast<std::uint64_t>(w) * h != n) {
      throw PointCloudIoError(path, "line " + std::to_string(header.organized_line) +
                                        ": organized " + std::to_string(w) + " x " +
                                        std::to_string(h) + " does not match " + std::to_string(n) +
                                        " vertices");
    }
    cloud.width = w;
    cloud.height = h;
  } else {
    if (n > std::numeric_limits<std::uint32_t>::max()) {
      throw PointCloudIoError(path, "more than 2^32 - 1 vertices");
    }
    cloud.width = static_cast<std::uint32_t>(n);
    cloud.height = 1;
  }
  for (std::size_t t = 0; t < file.triangles.size(); ++t) {
    for (const std::uint32_t index : file.triangles[t]) {
      if (index >= n) {
        throw PointCloudIoError(path, "face " + std::to_string(t) + " has vertex index " +
                                          std::to_string(index) + " out of range");
      }
    }
  }
  return file;
}

namespace internal {

PointCloud ReadPly(const std::string& path) { return ReadPlyFile(path).cloud; }

void WritePly(const std::string& path, const PointCloud& cloud, PointCloudFormat format) {
  const std::size_t n = cloud.size();
  const bool normals = cloud.has_normals();
  const bool colors = cloud.has_colors();
  const bool intensities = cloud.has_intensities();

  std::string header = "ply\nformat ";
  header += format == PointCloudFormat::kPlyAscii                ? "ascii"
            : format == PointCloudFormat::kPlyBinaryLittleEndian ? "binary_little_endian"
                                                                 : "binary_big_endian";
  header += " 1.0\ncomment written by picking::geometry::WritePointCloud\n";
  if (!cloud.frame_id.empty()) header += "comment frame_id " + cloud.frame_id + "\n";
  if (cloud.height > 1) {
    header += "comment organized " + std::to_string(cloud.width) + " " +
              std::to_string(cloud.height) + "\n";
  }
  header += "element vertex " + std::to_string(n) + "\n";
  header += "property float x\nproperty float y\nproperty float z\n";
  if (normals) header += "property float nx\nproperty float ny\nproperty float nz\n";
  if (colors) header += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  if (intensities) header += "property float intensity\n";
  header += "end_header\n";

  AtomicFile file(path);
  file.Open();
  file.Write(header);
  constexpr std::size_t kBlock = 1 << 14;
  if (format == PointCloudFormat::kPlyAscii) {
    std::string text;
    for (std::size_t i = 0; i < n; ++i) {
      const Eigen::Vector3f& p = cloud.points[i];
      AppendFloat(p.x(), &text);
      text += ' ';
      AppendFloat(p.y(), &text);
      text += ' ';
      AppendFloat(p.z(), &text);
      if (normals) {
        for (int k = 0; k < 3; ++k) {
          text += ' ';
          AppendFloat(cloud.normals[i][k], &text);
        }
      }
      if (colors) {
        for (int k = 0; k < 3; ++k) {
          text += ' ';
          text += std::to_string(cloud.colors[i][k]);
        }
      }
      if (intensities) {
        text += ' ';
        AppendFloat(cloud.intensities[i], &text);
      }
      text += '\n';
      if (text.size() > (1 << 20)) {
        file.Write(text);
        text.clear();
      }
    }
    file.Write(text);
  } else {
    const bool swap = (format == PointCloudFormat::kPlyBinaryBigEndian) == HostIsLittleEndian();
    std::vector<char> bytes;
    for (std::size_t first = 0; first < n; first += kBlock) {
      bytes.clear();
      const std::size_t last = std::min(n, first + kBlock);
      for (std::size_t i = first; i < last; ++i) {
        for (int k = 0; k < 3; ++k) Store(cloud.points[i][k], swap, &bytes);
        if (normals) {
          for (int k = 0; k < 3; ++k) Store(cloud.normals[i][k], swap, &bytes);
        }
        if (colors) bytes.insert(bytes.end(), cloud.colors[i].begin(), cloud.colors[i].end());
        if (intensities) Store(cloud.intensities[i], swap, &bytes);
      }
      file.Write(bytes.data(), bytes.size());
    }
  }
  file.Commit();
}

}  // namespace internal
}  // namespace picking::geometry
