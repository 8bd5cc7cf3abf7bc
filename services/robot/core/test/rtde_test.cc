#include "services/robot/core/rtde.h"

#include <gtest/gtest.h>

#include <thread>

#include "services/robot/core/test/fake_ur_controller.h"

namespace picking::robot::rtde {
namespace {

std::string Bytes(std::initializer_list<int> bytes) {
  std::string s;
  for (int b : bytes) s.push_back(static_cast<char>(b));
  return s;
}

// Byte sequences written from the RTDE guide: uint16 size (whole package) + uint8 type.
TEST(RtdeCodecTest, RequestProtocolVersion) {
  EXPECT_EQ(EncodePackage(PackageType::kRequestProtocolVersion, EncodeRequestProtocolVersion(2)),
            Bytes({0x00, 0x05, 'V', 0x00, 0x02}));
}

TEST(RtdeCodecTest, EmptyRequests) {
  EXPECT_EQ(EncodePackage(PackageType::kGetUrControlVersion, ""), Bytes({0x00, 0x03, 'v'}));
  EXPECT_EQ(EncodePackage(PackageType::kControlPackageStart, ""), Bytes({0x00, 0x03, 'S'}));
  EXPECT_EQ(EncodePackage(PackageType::kControlPackagePause, ""), Bytes({0x00, 0x03, 'P'}));
}

TEST(RtdeCodecTest, SetupOutputs) {
  // 125 Hz = 0x405F400000000000; size 3 + 8 + 18 = 29.
  const std::string expected =
      Bytes({0x00, 0x1d, 'O', 0x40, 0x5f, 0x40, 0, 0, 0, 0, 0}) + "timestamp,actual_q";
  EXPECT_EQ(EncodePackage(PackageType::kControlPackageSetupOutputs,
                          EncodeSetupOutputs(125.0, {"timestamp", "actual_q"})),
            expected);
  const auto [frequency, names] = DecodeSetupOutputs(expected.substr(3));
  EXPECT_EQ(frequency, 125.0);
  EXPECT_EQ(names, (std::vector<std::string>{"timestamp", "actual_q"}));
}

TEST(RtdeCodecTest, SetupInputs) {
  EXPECT_EQ(EncodePackage(PackageType::kControlPackageSetupInputs,
                          EncodeSetupInputs({"input_int_register_0"})),
            Bytes({0x00, 0x17, 'I'}) + "input_int_register_0");
  EXPECT_THROW(EncodeSetupInputs({"a,b"}), std::invalid_argument);
}

TEST(RtdeCodecTest, SetupReplyAndAccepted) {
  const auto [id, types] = DecodeSetupReply(Bytes({0x01}) + "DOUBLE,VECTOR6D,INT32");
  EXPECT_EQ(id, 1);
  EXPECT_EQ(types, (std::vector<std::string>{"DOUBLE", "VECTOR6D", "INT32"}));
  EXPECT_TRUE(DecodeAccepted(Bytes({0x01})));
  EXPECT_FALSE(DecodeAccepted(Bytes({0x00})));
  EXPECT_THROW(DecodeAccepted(""), std::runtime_error);
  EXPECT_THROW(ParseFieldType("NOT_FOUND"), std::invalid_argument);
}

TEST(RtdeCodecTest, ControllerVersion) {
  const std::string payload = Bytes({0, 0, 0, 3, 0, 0, 0, 15, 0, 0, 0, 8, 0, 1, 0xa0, 0xe3});
  const ControllerVersion v = DecodeControllerVersion(payload);
  EXPECT_EQ(v.major, 3u);
  EXPECT_EQ(v.minor, 15u);
  EXPECT_EQ(v.bugfix, 8u);
  EXPECT_EQ(v.build, 106723u);
  EXPECT_EQ(EncodeControllerVersion(v), payload);
}

TEST(RtdeCodecTest, DataPackageEveryType) {
  const std::vector<FieldType> types = {
      FieldType::kDouble, FieldType::kInt32,  FieldType::kBool,     FieldType::kUint8,
      FieldType::kUint32, FieldType::kUint64, FieldType::kVector3d, FieldType::kVector6Int32};
  const std::vector<FieldValue> values = {1.5,
                                          std::int32_t{-2},
                                          true,
                                          std::uint8_t{7},
                                          std::uint32_t{0x01020304},
                                          std::uint64_t{1} << 40,
                                          std::array<double, 3>{1.0, 2.0, 3.0},
                                          std::array<std::int32_t, 6>{1, -1, 0, 0, 0, 256}};
  const std::string expected =
      Bytes({0x00, 0x4e, 'U',  0x03,                                      // size 78, recipe 3
             0x3f, 0xf8, 0,    0,    0,    0,    0,    0,                 // DOUBLE 1.5
             0xff, 0xff, 0xff, 0xfe,                                      // INT32 -2
             0x01,                                                        // BOOL true
             0x07,                                                        // UINT8 7
             0x01, 0x02, 0x03, 0x04,                                      // UINT32
             0x00, 0x00, 0x01, 0x00, 0x00, 0x00, 0x00, 0x00,              // UINT64 2^40
             0x3f, 0xf0, 0,    0,    0,    0,    0,    0,                 // VECTOR3D 1
             0x40, 0x00, 0,    0,    0,    0,    0,    0,                 //          2
             0x40, 0x08, 0,    0,    0,    0,    0,    0,                 //          3
             0,    0,    0,    1,    0xff, 0xff, 0xff, 0xff, 0, 0, 0, 0,  // VECTOR6INT32
             0,    0,    0,    0,    0,    0,    0,    0,    0, 0, 1, 0});
  const std::string encoded =
      EncodePackage(PackageType::kDataPackage, EncodeDataPackage(3, types, values));
  EXPECT_EQ(encoded, expected);
  const DataPackage decoded = DecodeDataPackage(expected.substr(3), types);
  EXPECT_EQ(decoded.recipe_id, 3);
  EXPECT_EQ(decoded.values, values);
  EXPECT_THROW(DecodeDataPackage(expected.substr(3, 20), types), std::runtime_error);
  EXPECT_THROW(EncodeDataPackage(3, {FieldType::kDouble}, {std::int32_t{1}}),
               std::invalid_argument);
}

TEST(RtdeCodecTest, TextMessage) {
  const std::string expected = Bytes({0x00, 0x0c, 'M', 2, 'h', 'i', 4, 'R', 'T', 'D', 'E', 2});
  EXPECT_EQ(EncodePackage(PackageType::kTextMessage,
                          EncodeTextMessage({"hi", "RTDE", TextMessage::kWarning})),
            expected);
  const TextMessage m = DecodeTextMessage(expected.substr(3));
  EXPECT_EQ(m.message, "hi");
  EXPECT_EQ(m.source, "RTDE");
  EXPECT_EQ(m.level, TextMessage::kWarning);
}

TEST(RtdeClientTest, NegotiatesAndReceivesFromFakeServer) {
  const ur10::Ur10Kinematics kin(ur10::Ur10Model::Load(std::string(PICKING_DATA_DIR) + "/ur10"));
  testing::FakeUrController fake(kin);
  RtdeClient client(TcpStream::Connect("127.0.0.1", fake.rtde_port(), std::chrono::seconds(5)));
  EXPECT_TRUE(client.NegotiateProtocolVersion(2));
  EXPECT_EQ(fake.negotiated_version(), 2);
  const ControllerVersion version = client.GetControllerVersion();
  EXPECT_EQ(version.major, 3u);
  EXPECT_EQ(version.minor, 15u);
  EXPECT_THROW(client.SetupOutputs(125.0, {"timestamp", "no_such_variable"}), std::runtime_error);
  const Recipe recipe = client.SetupOutputs(500.0, {"timestamp", "actual_q", "robot_mode"});
  EXPECT_EQ(recipe.types,
            (std::vector<FieldType>{FieldType::kDouble, FieldType::kVector6d, FieldType::kInt32}));
  try {
    client.SetupInputs({"input_int_register_0", "speed_slider_mask"});
    FAIL() << "IN_USE not reported";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("speed_slider_mask (IN_USE)"), std::string::npos);
  }
  client.Start();
  double last = -1.0;
  for (int i = 0; i < 20; ++i) {
    const DataPackage data = client.Receive(std::chrono::seconds(5));
    EXPECT_EQ(data.recipe_id, recipe.id);
    const double t = std::get<double>(data.values[0]);
    EXPECT_GT(t, last);
    last = t;
    const auto q = std::get<std::array<double, 6>>(data.values[1]);
    EXPECT_NEAR(q[0], 0.2, 1e-12);
    EXPECT_EQ(std::get<std::int32_t>(data.values[2]), 3);
  }
  client.Pause();
  const auto messages = client.TakeMessages();
  ASSERT_EQ(messages.size(), 1u);
  EXPECT_EQ(messages[0].message, "starting");
}

TEST(RtdeClientTest, ConnectionRefusedIsAStreamError) {
  std::uint16_t port;
  {
    TcpListener listener(0);
    port = listener.port();
  }
  EXPECT_THROW(TcpStream::Connect("127.0.0.1", port, std::chrono::seconds(2)), StreamError);
}

}  // namespace
}  // namespace picking::robot::rtde
