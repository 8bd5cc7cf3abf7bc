#include "libs/proto_convert/proto_convert.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <utility>
#include <vector>

namespace picking::proto_convert {
namespace {

Eigen::Isometry3d RandomPose(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::Quaterniond(u(rng), u(rng), u(rng), u(rng)).normalized().toRotationMatrix();
  X.translation() = Eigen::Vector3d(u(rng), u(rng), u(rng));
  return X;
}

TEST(ProtoConvertTest, PoseRoundTrips) {
  std::mt19937 rng(7);
  for (int i = 0; i < 1000; ++i) {
    const Eigen::Isometry3d X = RandomPose(rng);
    const Eigen::Isometry3d Y = PoseFromProto(PoseToProto(X), "pose");
    EXPECT_TRUE(X.isApprox(Y, 1e-12));
    EXPECT_GE(PoseToProto(X).orientation().w(), 0.0);
  }
}

TEST(ProtoConvertTest, PoseRejectsNanAndNonUnitQuaternionNamingTheField) {
  pb::Pose pose = PoseToProto(Eigen::Isometry3d::Identity());
  pose.mutable_position()->set_y(std::numeric_limits<double>::quiet_NaN());
  try {
    PoseFromProto(pose, "target");
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_STREQ(e.what(), "target.position.y must be a finite number");
  }
  pose = PoseToProto(Eigen::Isometry3d::Identity());
  pose.mutable_orientation()->set_w(0.0);
  try {
    PoseFromProto(pose, "target");
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("target.orientation must be a unit quaternion"),
              std::string::npos);
  }
}

// A finite but huge position made the simulator's ray caster abort (SIGABRT in Embree).
TEST(ProtoConvertTest, PoseRejectsPositionsBeyondTheBoundNamingTheField) {
  pb::Pose pose = PoseToProto(Eigen::Isometry3d::Identity());
  pose.mutable_position()->set_x(2e18);
  try {
    PoseFromProto(pose, "X_base_camera");
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("X_base_camera.position"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("1000 m limit"), std::string::npos) << e.what();
  }
  pose.mutable_position()->set_x(kMaxPositionM * 0.6);
  pose.mutable_position()->set_y(kMaxPositionM * 0.6);  // |p| = 0.85 * the bound
  EXPECT_NO_THROW(PoseFromProto(pose, "pose"));
  pose.mutable_position()->set_z(kMaxPositionM * 0.6);  // |p| = 1.04 * the bound
  EXPECT_THROW(PoseFromProto(pose, "pose"), std::invalid_argument);
  EXPECT_NO_THROW(PoseFromProto(pose, "pose", 2.0 * kMaxPositionM));
}

TEST(ProtoConvertTest, JointsNeedSixFiniteValues) {
  pb::JointPositions j;
  for (int i = 0; i < 5; ++i) j.add_positions_rad(0.1 * i);
  EXPECT_THROW(JointsFromProto(j, "target"), std::invalid_argument);
  j.add_positions_rad(std::numeric_limits<double>::infinity());
  EXPECT_THROW(JointsFromProto(j, "target"), std::invalid_argument);
  j.set_positions_rad(5, 0.5);
  const auto q = JointsFromProto(j, "target");
  EXPECT_DOUBLE_EQ(q[5], 0.5);
  EXPECT_EQ(JointsToProto(q).positions_rad_size(), 6);
}

TEST(ProtoConvertTest, CameraIntrinsicsRoundTripAndAreChecked) {
  camera::Distortion d;
  d.k1 = -0.1;
  d.p2 = 0.001;
  const camera::PinholeCamera camera(640, 480, 525.0, 526.0, 319.5, 239.5, d);
  const camera::PinholeCamera back = CameraFromProto(CameraToProto(camera), "camera");
  EXPECT_EQ(back.width(), 640);
  EXPECT_EQ(back.height(), 480);
  EXPECT_DOUBLE_EQ(back.fy(), 526.0);
  EXPECT_DOUBLE_EQ(back.distortion().k1, -0.1);
  EXPECT_DOUBLE_EQ(back.distortion().p2, 0.001);
  EXPECT_EQ(CameraToProto(camera::PinholeCamera(10, 10, 5.0, 5.0, 4.5, 4.5)).distortion_size(), 0);

  auto refused = [](pb::CameraIntrinsics c, const std::string& expected) {
    try {
      CameraFromProto(c, "params.camera", 4096, 1u << 22);
      ADD_FAILURE() << "accepted, expected " << expected;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
    }
  };
  pb::CameraIntrinsics c = CameraToProto(camera);
  c.set_width(0);
  refused(c, "params.camera: width and height");
  c.set_width(4097);
  refused(c, "params.camera: width and height");
  c.set_width(4096);
  c.set_height(4096);
  refused(c, "params.camera: at most");
  c = CameraToProto(camera);
  c.set_fx(std::numeric_limits<double>::quiet_NaN());
  refused(c, "params.camera:");
  c = CameraToProto(camera);
  c.set_fy(-1.0);
  refused(c, "params.camera:");
  c = CameraToProto(camera);
  c.add_distortion(0.0);
  refused(c, "params.camera.distortion");
}

TEST(ProtoConvertTest, ContainerNamesRoundTrip) {
  for (int c = pb::CONTAINER_BIN_A; c <= pb::CONTAINER_OUTSIDE; ++c) {
    const auto container = static_cast<pb::Container>(c);
    EXPECT_EQ(ContainerFromName(ContainerName(container)), container);
  }
  EXPECT_EQ(ContainerName(pb::CONTAINER_BIN_C), "bin_C");
  EXPECT_THROW(ContainerFromName("bin_M"), std::invalid_argument);
  EXPECT_THROW(ContainerName(pb::CONTAINER_UNSPECIFIED), std::invalid_argument);
}

// A 10 kB container name used to be quoted in full in the error.
TEST(ProtoConvertTest, AnUnknownContainerIsQuotedCut) {
  try {
    ContainerFromName("bin_" + std::string(10000, 'Z'));
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("unknown container 'bin_ZZZ"), std::string::npos);
    EXPECT_LT(std::string(e.what()).size(), 200u) << e.what();
  }
}

geometry::PointCloud MakeCloud(std::size_t n, bool organised) {
  geometry::PointCloud c;
  c.frame_id = "base";
  for (std::size_t i = 0; i < n; ++i) {
    c.points.emplace_back(0.001f * i, -0.5f, i % 7 == 0 ? NAN : 1.0f);
    c.normals.emplace_back(0.f, 0.f, 1.f);
    c.colors.push_back({static_cast<std::uint8_t>(i), 2, 3});
    c.intensities.push_back(static_cast<float>(i % 255) / 255.f);
  }
  c.width = organised ? 100 : static_cast<std::uint32_t>(n);
  c.height = organised ? static_cast<std::uint32_t>(n / 100) : 1;
  return c;
}

TEST(ProtoConvertTest, CloudRoundTripsThroughChunks) {
  const auto cloud = MakeCloud(25000, /*organised=*/true);
  const auto chunks = CloudToChunks(cloud, 4096);
  EXPECT_EQ(chunks.size(), 7u);
  CloudAssembler assembler;
  for (const auto& c : chunks) assembler.Add(c);
  const auto back = assembler.Finish();
  EXPECT_EQ(back.width, 100u);
  EXPECT_EQ(back.height, 250u);
  EXPECT_EQ(back.frame_id, "base");
  ASSERT_EQ(back.size(), cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (std::isnan(cloud.points[i].z())) {
      EXPECT_TRUE(std::isnan(back.points[i].z()));
    } else {
      EXPECT_EQ(back.points[i], cloud.points[i]);
    }
    EXPECT_EQ(back.colors[i], cloud.colors[i]);
    EXPECT_EQ(back.intensities[i], cloud.intensities[i]);
  }
}

TEST(ProtoConvertTest, EveryChunkStaysUnderTheDefaultMessageLimit) {
  const auto chunks = CloudToChunks(MakeCloud(200000, false));
  for (const auto& c : chunks) EXPECT_LT(c.ByteSizeLong(), 4u * 1024 * 1024);
}

TEST(ProtoConvertTest, AssemblerRejectsBrokenStreams) {
  const auto chunks = CloudToChunks(MakeCloud(1000, false), 300);
  {
    CloudAssembler a;  // Missing header.
    EXPECT_THROW(a.Add(chunks[1]), std::invalid_argument);
  }
  {
    CloudAssembler a;  // Gap.
    a.Add(chunks[0]);
    EXPECT_THROW(a.Add(chunks[2]), std::invalid_argument);
  }
  {
    CloudAssembler a;  // Truncated stream.
    a.Add(chunks[0]);
    a.Add(chunks[1]);
    EXPECT_THROW(a.Finish(), std::invalid_argument);
  }
  {
    CloudAssembler a;  // Short positions.
    auto bad = chunks[0];
    bad.mutable_positions()->resize(10);
    EXPECT_THROW(a.Add(bad), std::invalid_argument);
  }
  {
    CloudAssembler a(500);  // Oversized.
    EXPECT_THROW(a.Add(chunks[0]), std::invalid_argument);
  }
  {
    CloudAssembler a;
    EXPECT_THROW(a.Finish(), std::invalid_argument);
  }
}

// A header with width = height = 0 and 1000 points was taken as an unorganised cloud.
TEST(ProtoConvertTest, AssemblerRefusesAHeaderWhoseShapeDisagreesWithItsPointCount) {
  const auto chunks = CloudToChunks(MakeCloud(1000, false), 300);
  for (const auto& [width, height] : std::vector<std::pair<int, int>>{{0, 0}, {0, 1}, {10, 10}}) {
    auto bad = chunks[0];
    bad.mutable_header()->set_width(width);
    bad.mutable_header()->set_height(height);
    CloudAssembler a;
    try {
      a.Add(bad);
      ADD_FAILURE() << width << " x " << height << " accepted for 1000 points";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("width * height"), std::string::npos) << e.what();
    }
  }
}

TEST(ProtoConvertTest, ImagesRoundTripThroughRowChunks) {
  Image img;
  img.width = 1280;
  img.height = 1024;
  img.name = "white";
  img.index = 3;
  img.data.resize(1280 * 1024);
  for (std::size_t i = 0; i < img.data.size(); ++i) img.data[i] = static_cast<std::uint8_t>(i * 31);
  const auto chunks = ImageToChunks(img, 100000);
  EXPECT_GT(chunks.size(), 1u);
  ImageAssembler a;
  for (std::size_t i = 0; i + 1 < chunks.size(); ++i) EXPECT_FALSE(a.Add(chunks[i]));
  EXPECT_TRUE(a.Add(chunks.back()));
  EXPECT_EQ(a.completed().data, img.data);
  EXPECT_EQ(a.completed().name, "white");
  EXPECT_EQ(a.completed().index, 3u);
  ImageAssembler b;
  EXPECT_THROW(b.Add(chunks[1]), std::invalid_argument);
}

}  // namespace
}  // namespace picking::proto_convert
