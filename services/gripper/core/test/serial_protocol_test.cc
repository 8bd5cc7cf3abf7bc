#include "services/gripper/core/serial_protocol.h"

#include <gtest/gtest.h>

#include <stdexcept>
#include <string>

namespace picking::gripper::serial {
namespace {

TEST(SerialProtocolTest, ChecksumIsTheNmeaXor) {
  // The NMEA 0183 example sentence $GPGLL,4916.45,N,12311.12,W,225444,A,*1D.
  EXPECT_EQ(Checksum("GPGLL,4916.45,N,12311.12,W,225444,A,"), 0x1D);
  EXPECT_EQ(EncodeLine("GPGLL,4916.45,N,12311.12,W,225444,A,"),
            "$GPGLL,4916.45,N,12311.12,W,225444,A,*1D\n");
  EXPECT_EQ(Checksum(""), 0);
}

TEST(SerialProtocolTest, DecodesWhatItEncodes) {
  for (const std::string body : {"12 V1", "OK 12", "ERR 7 ARG angle out of range",
                                 "OK 3 P 27.40 A 0.000 0.120 9.806 J -3.50 M K R 1"}) {
    const std::string line = EncodeLine(body);
    ASSERT_EQ(line.back(), '\n');
    const auto decoded = DecodeLine(std::string_view(line).substr(0, line.size() - 1));
    ASSERT_TRUE(decoded.has_value()) << line;
    EXPECT_EQ(*decoded, body);
    // A CR before the newline (a terminal program) is accepted too.
    EXPECT_EQ(DecodeLine(line.substr(0, line.size() - 1) + "\r"), body);
  }
}

TEST(SerialProtocolTest, EverySingleBitErrorIsDetected) {
  const std::string line = EncodeLine("42 S -30.00");
  const std::string text = line.substr(0, line.size() - 1);
  int detected = 0;
  for (std::size_t i = 0; i < text.size(); ++i) {
    for (int bit = 0; bit < 8; ++bit) {
      std::string bad = text;
      bad[i] = static_cast<char>(bad[i] ^ (1 << bit));
      EXPECT_FALSE(DecodeLine(bad).has_value()) << "byte " << i << " bit " << bit;
      ++detected;
    }
  }
  EXPECT_EQ(detected, static_cast<int>(text.size()) * 8);
}

TEST(SerialProtocolTest, RejectsFramingErrors) {
  EXPECT_FALSE(DecodeLine("").has_value());
  EXPECT_FALSE(DecodeLine("12 V1*3A").has_value());       // No '$'.
  EXPECT_FALSE(DecodeLine("$12 V1").has_value());         // No checksum.
  EXPECT_FALSE(DecodeLine("$12 V1*G0").has_value());      // Not hex.
  EXPECT_FALSE(DecodeLine("xx$OK 1*15").has_value());     // Bytes before '$'.
  EXPECT_FALSE(DecodeLine("$OK 1$OK 1*24").has_value());  // Two starts.
  EXPECT_THROW(EncodeLine("1 V1*"), std::invalid_argument);
  EXPECT_THROW(EncodeLine("1 $V1"), std::invalid_argument);
  EXPECT_THROW(EncodeLine("1 V1\n"), std::invalid_argument);
  EXPECT_THROW(EncodeLine(std::string(kMaxLineBytes, 'x')), std::invalid_argument);
}

TEST(SerialProtocolTest, TheDocumentedExampleExchangeDecodes) {
  // docs/gripper-serial-protocol.md, "Example".
  EXPECT_EQ(EncodeLine(CommandBody(1, "V1")), "$1 V1*76\n");
  EXPECT_EQ(EncodeLine(OkBody(1)), "$OK 1*15\n");
  EXPECT_EQ(EncodeLine(CommandBody(2, "Q")), "$2 Q*43\n");
  Telemetry t;
  t.vacuum_kpa = 15.0;
  t.gravity_head_m_s2 = Eigen::Vector3d(0.0, 0.0, 9.80665);
  t.relay_on = true;
  EXPECT_EQ(EncodeLine(OkBody(2, FormatTelemetry(t))),
            "$OK 2 P 15.00 A 0.000 0.000 9.807 J 0.00 M U R 1*2A\n");
  EXPECT_EQ(EncodeLine(CommandBody(3, "S " + FormatNumber(-30.0, 2))), "$3 S -30.00*60\n");
  EXPECT_EQ(EncodeLine(OkBody(3)), "$OK 3*17\n");
  EXPECT_EQ(EncodeLine(CommandBody(4, "M F")), "$4 M F*3F\n");
  EXPECT_EQ(EncodeLine(OkBody(4)), "$OK 4*10\n");
}

TEST(SerialProtocolTest, NumbersAreLocaleFree) {
  EXPECT_EQ(FormatNumber(-30.0, 2), "-30.00");
  EXPECT_EQ(FormatNumber(-0.001, 2), "0.00");
  EXPECT_EQ(FormatNumber(9.80665, 3), "9.807");
  EXPECT_EQ(ParseNumber("1.5"), 1.5);
  EXPECT_EQ(ParseNumber("-0.25"), -0.25);
  EXPECT_EQ(ParseNumber("+2"), 2.0);
  EXPECT_FALSE(ParseNumber("1,5").has_value());
  EXPECT_FALSE(ParseNumber("1.5x").has_value());
  EXPECT_FALSE(ParseNumber("nan").has_value());
  EXPECT_FALSE(ParseNumber("inf").has_value());
  EXPECT_FALSE(ParseNumber("").has_value());
  EXPECT_EQ(ParseSeq("65535"), 65535u);
  EXPECT_FALSE(ParseSeq("65536").has_value());
  EXPECT_FALSE(ParseSeq("-1").has_value());
}

TEST(SerialProtocolTest, ParsesCommandsAndReplies) {
  const auto command = ParseCommand("17 S -30.00");
  ASSERT_TRUE(command.has_value());
  EXPECT_EQ(command->seq, 17u);
  EXPECT_EQ(command->verb, "S");
  ASSERT_EQ(command->args.size(), 1u);
  EXPECT_EQ(command->args[0], "-30.00");
  EXPECT_FALSE(ParseCommand("V1").has_value());
  EXPECT_FALSE(ParseCommand("x V1").has_value());

  auto reply = ParseReply(OkBody(9));
  ASSERT_TRUE(reply.has_value());
  EXPECT_TRUE(reply->ok);
  EXPECT_EQ(reply->seq, 9u);
  EXPECT_TRUE(reply->fields.empty());
  reply = ParseReply(ErrBody(10, "ARG angle out of range"));
  ASSERT_TRUE(reply.has_value());
  EXPECT_FALSE(reply->ok);
  EXPECT_EQ(reply->fields.front(), "ARG");
  EXPECT_FALSE(ParseReply("ERR 10").has_value());  // An error needs a reason.
  EXPECT_FALSE(ParseReply("YES 10").has_value());
}

TEST(SerialProtocolTest, TelemetryRoundTripsAndNamesBadFields) {
  Telemetry t;
  t.vacuum_kpa = 27.4;
  t.gravity_head_m_s2 = Eigen::Vector3d(0.0, 0.12, 9.806);
  t.joint_deg = -3.5;
  t.mode = JointMode::kKeepVertical;
  t.relay_on = true;
  const std::string text = FormatTelemetry(t);
  EXPECT_EQ(text, "P 27.40 A 0.000 0.120 9.806 J -3.50 M K R 1");
  const Telemetry back = ParseTelemetry(SplitFields(text));
  EXPECT_DOUBLE_EQ(back.vacuum_kpa, 27.4);
  EXPECT_DOUBLE_EQ(back.gravity_head_m_s2.y(), 0.12);
  EXPECT_DOUBLE_EQ(back.joint_deg, -3.5);
  EXPECT_EQ(back.mode, JointMode::kKeepVertical);
  EXPECT_TRUE(back.relay_on);

  // Fields of newer firmware are skipped.
  const Telemetry extended =
      ParseTelemetry(SplitFields("T 31.5 P 1.00 A 0 0 9.8 X 1 2 3 J 0 M U R 0"));
  EXPECT_DOUBLE_EQ(extended.vacuum_kpa, 1.0);
  EXPECT_EQ(extended.mode, JointMode::kUnactuated);

  try {
    ParseTelemetry(SplitFields("P 1.0 A 0 0 9.8 J abc M U R 0"));
    FAIL() << "expected invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("J (joint degrees) 'abc'"), std::string::npos) << e.what();
  }
  EXPECT_THROW(ParseTelemetry(SplitFields("P 1.0 A 0 0 9.8 J 0 M U")), std::invalid_argument);
  EXPECT_THROW(ParseTelemetry(SplitFields("P 1.0 A 0 0 J 0 M U R 0")), std::invalid_argument);
  EXPECT_THROW(ParseTelemetry(SplitFields("P 1.0 A 0 0 9.8 J 0 M Z R 0")), std::invalid_argument);
  EXPECT_THROW(ParseTelemetry(SplitFields("P 1.0 A 0 0 9.8 J 0 M U R 2")), std::invalid_argument);
}

TEST(LineReaderTest, SplitsLinesAcrossReadsAndDropsOverlongOnes) {
  LineReader reader(16);
  reader.Append("$OK 1");
  EXPECT_FALSE(reader.Next().has_value());
  reader.Append("*1F\n$OK");
  EXPECT_EQ(reader.Next(), "$OK 1*1F");
  EXPECT_FALSE(reader.Next().has_value());
  reader.Append(" 2*1C\n");
  EXPECT_EQ(reader.Next(), "$OK 2*1C");

  // Noise with no newline does not grow the buffer; the line it belongs to is dropped.
  reader.Append(std::string(100, 'z'));
  EXPECT_FALSE(reader.Next().has_value());
  reader.Append(std::string(100, 'z'));
  reader.Append("zz\n$OK 3*1D\n");
  EXPECT_EQ(reader.Next(), "$OK 3*1D");
  EXPECT_EQ(reader.overlong_lines(), 1u);
  // An overlong line that arrives in one piece is dropped too.
  reader.Append(std::string(20, 'y') + "\nabc\n");
  EXPECT_EQ(reader.Next(), "abc");
  EXPECT_EQ(reader.overlong_lines(), 2u);
}

}  // namespace
}  // namespace picking::gripper::serial
