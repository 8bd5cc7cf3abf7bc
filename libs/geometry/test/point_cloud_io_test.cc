#include "libs/geometry/point_cloud_io.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <sstream>
#include <unordered_set>

#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/point_types.h>

namespace picking::geometry {
namespace {

namespace fs = std::filesystem;

const std::string kModel = std::string(PICKING_TEST_DATA_DIR) + "/models/fiskars_scissors_red.ply";
const std::string kMilk = std::string(PICKING_TEST_DATA_DIR) + "/pointclouds/milk.pcd";
const std::string kScene =
    std::string(PICKING_TEST_DATA_DIR) + "/pointclouds/milk_cartoon_all_small_clorox.pcd";

constexpr PointCloudFormat kAllFormats[] = {
    PointCloudFormat::kPlyAscii,           PointCloudFormat::kPlyBinaryLittleEndian,
    PointCloudFormat::kPlyBinaryBigEndian, PointCloudFormat::kPcdAscii,
    PointCloudFormat::kPcdBinary,          PointCloudFormat::kPcdBinaryCompressed};

bool IsPly(PointCloudFormat f) {
  return f == PointCloudFormat::kPlyAscii || f == PointCloudFormat::kPlyBinaryLittleEndian ||
         f == PointCloudFormat::kPlyBinaryBigEndian;
}

const char* Extension(PointCloudFormat f) { return IsPly(f) ? ".ply" : ".pcd"; }

std::string ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream out;
  out << in.rdbuf();
  return out.str();
}

void WriteBytes(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// Same bits (NaN == NaN), so that round trips are checked exactly.
bool SameFloat(float a, float b) {
  return std::memcmp(&a, &b, sizeof(float)) == 0 || (std::isnan(a) && std::isnan(b));
}

void ExpectSameCloud(const PointCloud& a, const PointCloud& b, bool frame_id = true) {
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.height, b.height);
  if (frame_id) {
    EXPECT_EQ(a.frame_id, b.frame_id);
  }
  ASSERT_EQ(a.normals.size(), b.normals.size());
  ASSERT_EQ(a.colors.size(), b.colors.size());
  ASSERT_EQ(a.intensities.size(), b.intensities.size());
  std::size_t mismatches = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    for (int k = 0; k < 3; ++k) {
      mismatches += !SameFloat(a.points[i][k], b.points[i][k]);
      if (a.has_normals()) mismatches += !SameFloat(a.normals[i][k], b.normals[i][k]);
      if (a.has_colors()) mismatches += a.colors[i][k] != b.colors[i][k];
    }
    if (a.has_intensities()) mismatches += !SameFloat(a.intensities[i], b.intensities[i]);
  }
  EXPECT_EQ(mismatches, 0u);
}

class PointCloudIoTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           (std::string("picking_pcio_") +
            ::testing::UnitTest::GetInstance()->current_test_info()->name() + "_" +
            std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string Path(const std::string& name) const { return (dir_ / name).string(); }
  std::size_t FilesInDir() const {
    return static_cast<std::size_t>(std::distance(fs::directory_iterator(dir_), {}));
  }

  // Expects ReadPointCloud(path) to throw PointCloudIoError whose message contains every
  // one of `words`.
  void ExpectReadError(const std::string& path, std::initializer_list<std::string> words) {
    try {
      ReadPointCloud(path);
      ADD_FAILURE() << "no error reading " << path;
    } catch (const PointCloudIoError& e) {
      const std::string message = e.what();
      EXPECT_EQ(e.path(), path);
      EXPECT_EQ(message.rfind(path + ": ", 0), 0u) << message;
      for (const std::string& word : words) {
        EXPECT_NE(message.find(word), std::string::npos) << "'" << word << "' not in: " << message;
      }
    }
  }

  fs::path dir_;
};

// A cloud with every channel, NaNs, extreme values and an organisation.
PointCloud SyntheticCloud() {
  std::mt19937 rng(42);
  std::uniform_real_distribution<float> uniform(-2.0f, 2.0f);
  std::uniform_int_distribution<int> byte(0, 255);
  PointCloud cloud;
  cloud.width = 8;
  cloud.height = 5;
  cloud.frame_id = "scanner_optical frame";
  for (std::uint32_t i = 0; i < cloud.width * cloud.height; ++i) {
    cloud.points.emplace_back(uniform(rng), uniform(rng), uniform(rng));
    cloud.normals.emplace_back(
        Eigen::Vector3f(uniform(rng), uniform(rng), uniform(rng)).normalized());
    cloud.colors.push_back({static_cast<std::uint8_t>(byte(rng)),
                            static_cast<std::uint8_t>(byte(rng)),
                            static_cast<std::uint8_t>(byte(rng))});
    cloud.intensities.push_back(uniform(rng) * 0.25f + 0.5f);
  }
  const float nan = std::numeric_limits<float>::quiet_NaN();
  cloud.points[3] = Eigen::Vector3f(nan, nan, nan);
  cloud.points[4] = Eigen::Vector3f(std::numeric_limits<float>::max(),
                                    std::numeric_limits<float>::denorm_min(), -0.0f);
  cloud.points[5] = Eigen::Vector3f(1e-30f, -1e30f, 0.1f);
  cloud.colors[6] = {0, 0, 0};
  cloud.colors[7] = {255, 255, 255};
  return cloud;
}

TEST_F(PointCloudIoTest, ReadsApcModelPly) {
  const PointCloud cloud = ReadPointCloud(kModel);
  ASSERT_EQ(cloud.size(), 37450u);
  EXPECT_EQ(cloud.width, 37450u);
  EXPECT_EQ(cloud.height, 1u);
  EXPECT_TRUE(cloud.has_colors());
  EXPECT_FALSE(cloud.has_normals());
  EXPECT_FALSE(cloud.has_intensities());
  Eigen::Vector3f lo = cloud.points[0], hi = cloud.points[0];
  for (const auto& p : cloud.points) {
    ASSERT_TRUE(p.allFinite());
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  // The scissors' box is 13.3 x 6.6 x 1.5 cm (catalogue); the scan is in metres.
  const float extent = (hi - lo).maxCoeff();
  EXPECT_GT(extent, 0.05f);
  EXPECT_LT(extent, 0.20f);
  // Mostly red.
  double red = 0, green = 0;
  for (const auto& c : cloud.colors) {
    red += c[0];
    green += c[1];
  }
  EXPECT_GT(red, 1.5 * green);
}

TEST_F(PointCloudIoTest, PlyReaderAgreesWithPcl) {
  const PointCloud cloud = ReadPointCloud(kModel);
  pcl::PointCloud<pcl::PointXYZRGB> reference;
  ASSERT_EQ(pcl::io::loadPLYFile(kModel, reference), 0);
  ASSERT_EQ(reference.size(), cloud.size());
  for (std::size_t i = 0; i < cloud.size(); i += 97) {
    EXPECT_EQ(cloud.points[i].x(), reference[i].x);
    EXPECT_EQ(cloud.points[i].y(), reference[i].y);
    EXPECT_EQ(cloud.points[i].z(), reference[i].z);
    EXPECT_EQ(cloud.colors[i][0], reference[i].r);
    EXPECT_EQ(cloud.colors[i][1], reference[i].g);
    EXPECT_EQ(cloud.colors[i][2], reference[i].b);
  }
}

TEST_F(PointCloudIoTest, PcdReaderAgreesWithPcl) {
  const PointCloud cloud = ReadPointCloud(kScene);
  ASSERT_TRUE(cloud.has_colors());
  pcl::PointCloud<pcl::PointXYZRGB> reference;
  ASSERT_EQ(pcl::io::loadPCDFile(kScene, reference), 0);
  ASSERT_EQ(cloud.size(), reference.size());
  EXPECT_EQ(cloud.width, reference.width);
  for (std::size_t i = 0; i < reference.size(); i += 101) {
    if (std::isnan(reference[i].x)) {
      EXPECT_TRUE(std::isnan(cloud.points[i].x()));
      continue;
    }
    EXPECT_EQ(cloud.points[i].x(), reference[i].x);
    EXPECT_EQ(cloud.points[i].z(), reference[i].z);
    EXPECT_EQ(cloud.colors[i][0], reference[i].r);
    EXPECT_EQ(cloud.colors[i][1], reference[i].g);
    EXPECT_EQ(cloud.colors[i][2], reference[i].b);
  }
}

TEST_F(PointCloudIoTest, ReadsCompressedPcdAndModelPointsOccurInScene) {
  const PointCloud milk = ReadPointCloud(kMilk);
  EXPECT_EQ(milk.size(), 13704u);
  EXPECT_FALSE(milk.has_colors());
  const PointCloud scene = ReadPointCloud(kScene);
  EXPECT_EQ(scene.width, 640u);
  EXPECT_EQ(scene.height, 480u);
  EXPECT_TRUE(scene.is_organized());
  EXPECT_TRUE(scene.has_colors());
  std::size_t nan_points = 0;
  for (const auto& p : scene.points) nan_points += !p.allFinite();
  EXPECT_GT(nan_points, 0u);  // Kinect pixels without depth.
  EXPECT_LT(nan_points, scene.size());
  // Ground truth of the data: every model point occurs exactly in the scene.
  auto key = [](const Eigen::Vector3f& p) {
    std::uint32_t b[3];
    std::memcpy(b, p.data(), sizeof(b));
    return (std::uint64_t{b[0]} * 0x9E3779B97F4A7C15ull) ^ (std::uint64_t{b[1]} << 21) ^
           std::uint64_t{b[2]};
  };
  std::unordered_multiset<std::uint64_t> keys;
  for (const auto& p : scene.points) {
    if (p.allFinite()) keys.insert(key(p));
  }
  std::size_t found = 0;
  for (const auto& p : milk.points) found += keys.count(key(p)) > 0;
  EXPECT_EQ(found, milk.size());
}

TEST_F(PointCloudIoTest, SyntheticCloudRoundTripsInEveryFormat) {
  const PointCloud cloud = SyntheticCloud();
  for (PointCloudFormat format : kAllFormats) {
    SCOPED_TRACE(static_cast<int>(format));
    const std::string path = Path(std::string("synthetic") + Extension(format));
    WritePointCloud(path, cloud, format);
    const PointCloud back = ReadPointCloud(path);
    ExpectSameCloud(cloud, back, /*frame_id=*/IsPly(format));
    if (!IsPly(format)) {
      EXPECT_EQ(back.frame_id, "");
    }
  }
  EXPECT_EQ(FilesInDir(), 2u);  // synthetic.ply and synthetic.pcd; no temporary files.
}

TEST_F(PointCloudIoTest, RealDataRoundTripsInEveryFormat) {
  const PointCloud model = ReadPointCloud(kModel);
  const PointCloud scene = ReadPointCloud(kScene);
  for (PointCloudFormat format : kAllFormats) {
    SCOPED_TRACE(static_cast<int>(format));
    const std::string model_path = Path(std::string("model") + Extension(format));
    WritePointCloud(model_path, model, format);
    ExpectSameCloud(model, ReadPointCloud(model_path));
    const std::string scene_path = Path(std::string("scene") + Extension(format));
    WritePointCloud(scene_path, scene, format);
    ExpectSameCloud(scene, ReadPointCloud(scene_path));
  }
}

TEST_F(PointCloudIoTest, BinaryPlyIsByteExactForTheApcModel) {
  // The APC model has exactly the layout the writer uses (x y z float, red green blue uchar).
  const PointCloud model = ReadPointCloud(kModel);
  const std::string path = Path("model.ply");
  WritePointCloud(path, model, PointCloudFormat::kPlyBinaryLittleEndian);
  const std::string original = ReadBytes(kModel);
  const std::string written = ReadBytes(path);
  const std::size_t body = 37450u * 15u;
  ASSERT_GE(written.size(), body);
  EXPECT_EQ(written.substr(written.size() - body), original.substr(original.size() - body));
}

TEST_F(PointCloudIoTest, BigEndianStoresSwappedBytes) {
  PointCloud cloud;
  cloud.points = {Eigen::Vector3f(1.0f, -2.0f, 0.5f)};
  cloud.width = 1;
  const std::string path = Path("be.ply");
  WritePointCloud(path, cloud, PointCloudFormat::kPlyBinaryBigEndian);
  const std::string bytes = ReadBytes(path);
  ASSERT_GE(bytes.size(), 12u);
  const std::string body = bytes.substr(bytes.size() - 12);
  // 1.0f = 0x3f800000, big endian first byte 0x3f.
  EXPECT_EQ(static_cast<unsigned char>(body[0]), 0x3f);
  EXPECT_EQ(static_cast<unsigned char>(body[1]), 0x80);
  EXPECT_EQ(static_cast<unsigned char>(body[4]), 0xc0);  // -2.0f = 0xc0000000.
  EXPECT_EQ(ReadPointCloud(path).points[0], cloud.points[0]);
}

TEST_F(PointCloudIoTest, EmptyCloudRoundTrips) {
  PointCloud empty;
  empty.frame_id = "world";
  for (PointCloudFormat format : kAllFormats) {
    SCOPED_TRACE(static_cast<int>(format));
    const std::string path = Path(std::string("empty") + Extension(format));
    WritePointCloud(path, empty, format);
    const PointCloud back = ReadPointCloud(path);
    EXPECT_TRUE(back.empty());
    EXPECT_EQ(back.width, 0u);
  }
}

TEST_F(PointCloudIoTest, AsciiPlyWithFacesUnknownPropertiesAndOtherNames) {
  const std::string path = Path("mesh.ply");
  WriteBytes(path,
             "ply\r\n"
             "format ascii 1.0\r\n"
             "comment made by hand\r\n"
             "element material 1\r\n"
             "property float shininess\r\n"
             "property list uchar int ids\r\n"
             "element vertex 3\r\n"
             "property double x\r\n"
             "property double y\r\n"
             "property double z\r\n"
             "property short quality\r\n"
             "property uchar r\r\n"
             "property uchar g\r\n"
             "property uchar b\r\n"
             "property uchar alpha\r\n"
             "property float intensity\r\n"
             "property list uchar float uv\r\n"
             "element face 1\r\n"
             "property list uchar int vertex_indices\r\n"
             "end_header\r\n"
             "0.5 3 1 2 3\r\n"
             "1 2 3 -7 10 20 30 255 0.25 2 0.1 0.2\r\n"
             "\r\n"
             "4.5 5 6 100 40 50 60 128 0.5 0\r\n"
             "-1e-3 +8 9 0 70 80 90 0 1 1 7\r\n"
             "3 0 1 2\r\n");
  const PointCloud cloud = ReadPointCloud(path);
  ASSERT_EQ(cloud.size(), 3u);
  EXPECT_EQ(cloud.points[0], Eigen::Vector3f(1, 2, 3));
  EXPECT_EQ(cloud.points[2], Eigen::Vector3f(-1e-3f, 8, 9));
  ASSERT_TRUE(cloud.has_colors());
  EXPECT_EQ(cloud.colors[1], (std::array<std::uint8_t, 3>{40, 50, 60}));
  ASSERT_TRUE(cloud.has_intensities());
  EXPECT_FLOAT_EQ(cloud.intensities[1], 0.5f);
  EXPECT_FALSE(cloud.has_normals());
}

// A binary PLY with an element before the vertices, a list property inside the vertex
// element, unknown properties of every type and a face element after.
std::string BinaryPlyWithLists(bool big_endian) {
  std::string header = std::string("ply\nformat ") +
                       (big_endian ? "binary_big_endian" : "binary_little_endian") +
                       " 1.0\n"
                       "element camera 2\n"
                       "property int8 a\nproperty uint16 b\nproperty list uint8 uint32 c\n"
                       "element vertex 2\n"
                       "property float32 x\nproperty float32 y\nproperty float32 z\n"
                       "property float64 extra\n"
                       "property float nx\nproperty float ny\nproperty float nz\n"
                       "property list ushort short labels\n"
                       "property ushort red\nproperty int green\nproperty float blue\n"
                       "end_header\n";
  std::string body;
  auto put = [&](const void* data, std::size_t size) {
    std::string bytes(static_cast<const char*>(data), size);
    if (big_endian) std::reverse(bytes.begin(), bytes.end());
    body += bytes;
  };
  for (int cam = 0; cam < 2; ++cam) {
    const std::int8_t a = -1;
    const std::uint16_t b = 7;
    const std::uint8_t n = static_cast<std::uint8_t>(cam + 1);
    put(&a, 1);
    put(&b, 2);
    put(&n, 1);
    for (int k = 0; k < n; ++k) {
      const std::uint32_t v = 1000 + k;
      put(&v, 4);
    }
  }
  for (int v = 0; v < 2; ++v) {
    const float xyz[3] = {1.5f + v, -2.25f, 3.0f};
    for (float f : xyz) put(&f, 4);
    const double extra = 9.75;
    put(&extra, 8);
    const float normal[3] = {0.0f, v == 0 ? 1.0f : -1.0f, 0.0f};
    for (float f : normal) put(&f, 4);
    const std::uint16_t labels = static_cast<std::uint16_t>(v * 2);
    put(&labels, 2);
    for (int k = 0; k < labels; ++k) {
      const std::int16_t label = static_cast<std::int16_t>(-k);
      put(&label, 2);
    }
    const std::uint16_t red = 300;  // Clamped to 255.
    const std::int32_t green = 17;
    const float blue = 0.5f;  // Float colour: 0-1 scaled.
    put(&red, 2);
    put(&green, 4);
    put(&blue, 4);
  }
  return header + body;
}

TEST_F(PointCloudIoTest, BinaryPlySkipsListsAndUnknownPropertiesInBothEndians) {
  for (bool big_endian : {false, true}) {
    SCOPED_TRACE(big_endian);
    const std::string path = Path("lists.ply");
    WriteBytes(path, BinaryPlyWithLists(big_endian));
    const PointCloud cloud = ReadPointCloud(path);
    ASSERT_EQ(cloud.size(), 2u);
    EXPECT_EQ(cloud.points[1], Eigen::Vector3f(2.5f, -2.25f, 3.0f));
    ASSERT_TRUE(cloud.has_normals());
    EXPECT_EQ(cloud.normals[1], Eigen::Vector3f(0, -1, 0));
    ASSERT_TRUE(cloud.has_colors());
    EXPECT_EQ(cloud.colors[0], (std::array<std::uint8_t, 3>{255, 17, 128}));
  }
}

TEST_F(PointCloudIoTest, TruncatedBinaryPlyNamesTheVertex) {
  const std::string original = ReadBytes(kModel);
  const std::string path = Path("truncated.ply");
  // Cut inside vertex 20000 (15 bytes per vertex).
  const std::size_t header = original.size() - 37450u * 15u;
  WriteBytes(path, original.substr(0, header + 20000u * 15u + 7u));
  ExpectReadError(path, {"vertex 20000", "unexpected end of file", "20000 of 37450"});
  // Cut in the header.
  WriteBytes(path, original.substr(0, 60));
  ExpectReadError(path, {"end of file before end_header"});
  // Trailing data.
  WriteBytes(path, original + "xyz");
  ExpectReadError(path, {"3 bytes after the last element"});
  // Truncated list element.
  const std::string lists = BinaryPlyWithLists(false);
  WriteBytes(path, lists.substr(0, lists.size() - 3));
  ExpectReadError(path, {"vertex 1", "unexpected end of file"});
}

TEST_F(PointCloudIoTest, MalformedPlyHeadersNameTheLine) {
  const std::string path = Path("bad.ply");
  const std::string vertex =
      "element vertex 1\nproperty float x\nproperty float y\nproperty float z\n";
  const struct {
    std::string text;
    std::vector<std::string> words;
  } cases[] = {
      {"ply\nformat binary_middle_endian 1.0\n" + vertex + "end_header\n",
       {"line 2", "unknown format \"binary_middle_endian\""}},
      {"ply\nformat ascii 2.0\n" + vertex + "end_header\n1 2 3\n", {"line 2", "version"}},
      {"ply\n" + vertex + "end_header\n1 2 3\n", {"no format line"}},
      {"ply\nformat ascii 1.0\nproperty float x\n" + vertex + "end_header\n",
       {"line 3", "before any element"}},
      {"ply\nformat ascii 1.0\nelement vertex -4\nend_header\n", {"line 3", "element count"}},
      {"ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n",
       {"line 4", "unknown property type \"float128\""}},
      {"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 "
       "0\n",
       {"line 3", "positions (x y z) need all three"}},
      {"ply\nformat ascii 1.0\n" + vertex + "property float nx\nend_header\n1 2 3 4\n",
       {"normals (nx ny nz) need all three"}},
      {"ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int "
       "vertex_indices\nend_header\n",
       {"no vertex element"}},
      {"ply\nformat ascii 1.0\n" + vertex + "colour red\nend_header\n",
       {"line 7", "unknown header keyword"}},
      {"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float x\nend_header\n",
       {"line 5", "twice"}},
      {"ply\nformat ascii 1.0\ncomment organized 2 2\n" + vertex + "end_header\n1 2 3\n",
       {"line 3", "organized 2 x 2 does not match 1 vertices"}},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.text);
    WriteBytes(path, c.text);
    try {
      ReadPointCloud(path);
      ADD_FAILURE() << "no error";
    } catch (const PointCloudIoError& e) {
      for (const std::string& word : c.words) {
        EXPECT_NE(std::string(e.what()).find(word), std::string::npos) << e.what();
      }
    }
  }
}

TEST_F(PointCloudIoTest, MalformedAsciiPlyBodiesNameLineAndVertex) {
  const std::string path = Path("bad.ply");
  const std::string header =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
      "end_header\n";  // 10 header lines.
  WriteBytes(path, header + "0 0 0 1 2 3\n1 one 1 1 2 3\n2 2 2 1 2 3\n");
  ExpectReadError(path, {"line 12", "vertex 1", "\"one\" is not a valid value of property y"});
  WriteBytes(path, header + "0 0 0 1 2 3\n1 1 1 1 2 300\n2 2 2 1 2 3\n");
  ExpectReadError(path, {"line 12", "\"300\" is not a valid value of property blue"});
  WriteBytes(path, header + "0 0 0 1 2 3\n1 1 1 1 2\n");
  ExpectReadError(path, {"line 12", "vertex 1", "too few values"});
  WriteBytes(path, header + "0 0 0 1 2 3 4\n");
  ExpectReadError(path, {"line 11", "vertex 0", "too many values"});
  WriteBytes(path, header + "0 0 0 1 2 3\n1 1 1 1 2 3\n");
  ExpectReadError(path, {"line 13", "vertex 2", "2 of 3 vertex elements read"});
  WriteBytes(path, header + "0 0 0 1 2 3\n1 1 1 1 2 3\n2 2 2 1 2 3\n3 3 3 1 2 3\n");
  ExpectReadError(path, {"line 14", "data after the last element"});
}

std::string PcdHeader(const std::string& fields, const std::string& size, const std::string& type,
                      const std::string& count, int width, int height, int points,
                      const std::string& data) {
  return "# .PCD v0.7\nVERSION 0.7\nFIELDS " + fields + "\nSIZE " + size + "\nTYPE " + type +
         "\nCOUNT " + count + "\nWIDTH " + std::to_string(width) + "\nHEIGHT " +
         std::to_string(height) + "\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS " + std::to_string(points) +
         "\nDATA " + data + "\n";
}

TEST_F(PointCloudIoTest, TruncatedAndGarbledPcdGiveErrors) {
  const std::string path = Path("bad.pcd");
  // Truncated compressed body.
  const std::string milk = ReadBytes(kMilk);
  WriteBytes(path, milk.substr(0, milk.size() / 2));
  ExpectReadError(path, {"unexpected end of file (compressed body has"});
  // Garbled compressed data (valid sizes, payload overwritten): LZF refuses it.
  std::string garbled = milk;
  const std::size_t body = garbled.find("DATA binary_compressed\n") + 23;
  std::fill(garbled.begin() + body + 8, garbled.begin() + body + 200, '\xff');
  WriteBytes(path, garbled);
  ExpectReadError(path, {"PCL could not read the binary_compressed body"});
  // Unpacked size disagrees with POINTS.
  std::string resized = milk;
  const std::uint32_t wrong = 12;
  std::memcpy(&resized[body + 4], &wrong, 4);
  WriteBytes(path, resized);
  ExpectReadError(path, {"unpacks to 12 bytes"});
  // Short binary body.
  WriteBytes(path, PcdHeader("x y z", "4 4 4", "F F F", "1 1 1", 10, 1, 10, "binary") +
                       std::string(12 * 7 + 5, '\0'));
  ExpectReadError(path, {"point 7", "binary body has 89 of 120 bytes"});
}

TEST_F(PointCloudIoTest, MalformedPcdHeadersNameTheLine) {
  const std::string path = Path("bad.pcd");
  const std::string body = "1 2 3\n";
  const struct {
    std::string text;
    std::vector<std::string> words;
  } cases[] = {
      {PcdHeader("x y z", "4 4", "F F F", "1 1 1", 1, 1, 1, "ascii") + body,
       {"line 4", "SIZE has 2 entries for 3 fields"}},
      {PcdHeader("x y z", "4 4 4", "F F D", "1 1 1", 1, 1, 1, "ascii") + body,
       {"line 5", "TYPE \"D\""}},
      {PcdHeader("x y z", "4 4 3", "F F F", "1 1 1", 1, 1, 1, "ascii") + body,
       {"line 4", "SIZE \"3\""}},
      {PcdHeader("x y z", "4 4 4", "F F F", "1 1 1", 2, 2, 3, "ascii") + body,
       {"line 10", "WIDTH * HEIGHT (2 * 2) != POINTS 3"}},
      {PcdHeader("x y z", "4 4 4", "F F F", "1 1 1", 1, 1, 1, "zipped") + body,
       {"line 11", "DATA must be"}},
      {PcdHeader("a b c", "4 4 4", "F F F", "1 1 1", 1, 1, 1, "ascii") + body, {"no x y z fields"}},
      {"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\n",
       {"end of file before the DATA line"}},
      {"# .PCD v0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH many\n", {"line 5", "WIDTH"}},
      {"# .PCD\nBLOB 1\n", {"line 2", "unknown header keyword \"BLOB\""}},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.text);
    WriteBytes(path, c.text);
    try {
      ReadPointCloud(path);
      ADD_FAILURE() << "no error";
    } catch (const PointCloudIoError& e) {
      for (const std::string& word : c.words) {
        EXPECT_NE(std::string(e.what()).find(word), std::string::npos) << e.what();
      }
    }
  }
}

TEST_F(PointCloudIoTest, MalformedAsciiPcdBodiesNameLineAndPoint) {
  const std::string path = Path("bad.pcd");
  // 11 header lines.
  const std::string header =
      PcdHeader("x y z rgb", "4 4 4 4", "F F F U", "1 1 1 1", 3, 1, 3, "ascii");
  WriteBytes(path, header + "1 2 3 4\nnan nan nan 0\n1 2 3 4\n");
  EXPECT_EQ(ReadPointCloud(path).size(), 3u);
  WriteBytes(path, header + "1 2 3 4\n1 two 3 4\n1 2 3 4\n");
  ExpectReadError(path, {"line 13", "point 1", "\"two\" is not a valid value of field y"});
  WriteBytes(path, header + "1 2 3 4\n1 2 3 -4\n1 2 3 4\n");
  ExpectReadError(path, {"line 13", "field rgb"});
  WriteBytes(path, header + "1 2 3 4\n1 2 3\n1 2 3 4\n");
  ExpectReadError(path, {"line 13", "3 values, expected 4"});
  WriteBytes(path, header + "1 2 3 4\n1 2 3 4\n");
  ExpectReadError(path, {"point 2", "2 of 3 points"});
  WriteBytes(path, header + "1 2 3 4\n1 2 3 4\n1 2 3 4\n1 2 3 4\n");
  ExpectReadError(path, {"line 15", "more points than POINTS declares"});
}

// Random truncations and byte changes never crash the readers: each file either reads as a
// consistent cloud or raises PointCloudIoError.
TEST_F(PointCloudIoTest, CorruptedFilesReadOrThrowTheIoError) {
  std::mt19937 rng(2016);
  PointCloud small = SyntheticCloud();
  std::vector<std::string> sources;
  for (PointCloudFormat format : kAllFormats) {
    const std::string path = Path(std::string("source") + Extension(format));
    WritePointCloud(path, small, format);
    sources.push_back(ReadBytes(path));
  }
  sources.push_back(ReadBytes(kMilk));
  sources.push_back(BinaryPlyWithLists(false));
  int errors = 0, reads = 0;
  for (std::size_t s = 0; s < sources.size(); ++s) {
    const std::string& original = sources[s];
    const bool ply = original.rfind("ply", 0) == 0;
    const std::string path = Path(ply ? "mutant.ply" : "mutant.pcd");
    for (int trial = 0; trial < 60; ++trial) {
      std::string bytes = original;
      std::uniform_int_distribution<std::size_t> position(0, bytes.size() - 1);
      if (trial % 3 == 0) {
        bytes.resize(position(rng));
      } else {
        const int changes = 1 + trial % 4;
        for (int c = 0; c < changes; ++c) {
          // Half of the changes hit the header (first 200 bytes).
          const std::size_t at =
              c % 2 == 0 ? position(rng) % std::min<std::size_t>(200, bytes.size()) : position(rng);
          bytes[at] = static_cast<char>(std::uniform_int_distribution<int>(0, 255)(rng));
        }
      }
      WriteBytes(path, bytes);
      try {
        const PointCloud cloud = ReadPointCloud(path);
        EXPECT_NO_THROW(ValidatePointCloud(cloud, "mutant"));
        ++reads;
      } catch (const PointCloudIoError& e) {
        EXPECT_EQ(e.path(), path);
        ++errors;
      }
    }
  }
  // Both outcomes occur: most truncations are detected, some byte changes only alter values.
  EXPECT_GT(errors, 100);
  EXPECT_GT(reads, 10);
}

TEST_F(PointCloudIoTest, UnknownFormatAndMissingFile) {
  const std::string path = Path("cloud.xyz");
  WriteBytes(path, "1 2 3\n");
  ExpectReadError(path, {"unknown point cloud format"});
  const std::string fake_ply = Path("cloud.ply");
  WriteBytes(fake_ply, "PLY\n");
  ExpectReadError(fake_ply, {"line 1", "not a PLY file"});
  ExpectReadError(Path("missing.ply"), {"cannot open"});
  WriteBytes(Path("empty.pcd"), "");
  ExpectReadError(Path("empty.pcd"), {"empty file"});
}

TEST_F(PointCloudIoTest, FailedWritesLeaveTheOldFile) {
  const PointCloud cloud = SyntheticCloud();
  for (PointCloudFormat format : kAllFormats) {
    SCOPED_TRACE(static_cast<int>(format));
    const std::string path = Path(std::string("keep") + Extension(format));
    WritePointCloud(path, cloud, format);
    const std::string before = ReadBytes(path);
    PointCloud broken = cloud;
    broken.colors.pop_back();
    EXPECT_THROW(WritePointCloud(path, broken, format), std::invalid_argument);
    broken = cloud;
    broken.width = 7;
    EXPECT_THROW(WritePointCloud(path, broken, format), std::invalid_argument);
    EXPECT_EQ(ReadBytes(path), before);
    // Destination in a folder that does not exist.
    EXPECT_THROW(WritePointCloud(Path("no/such/dir") + Extension(format), cloud, format),
                 PointCloudIoError);
    // A directory in the way of the rename: the error leaves no temporary file.
    const std::string blocked = Path(std::string("blocked") + Extension(format));
    fs::create_directories(fs::path(blocked) / "child");
    EXPECT_THROW(WritePointCloud(blocked, cloud, format), PointCloudIoError);
  }
  EXPECT_EQ(FilesInDir(), 4u);  // keep.ply, keep.pcd and the two blocking folders.
  PointCloud bad_id = cloud;
  bad_id.frame_id = "a\nb";
  EXPECT_THROW(WritePointCloud(Path("id.ply"), bad_id, PointCloudFormat::kPlyAscii),
               std::invalid_argument);
}

}  // namespace
}  // namespace picking::geometry
