#include "services/scanner/core/dlpc350.h"

#include <gtest/gtest.h>

#include <deque>
#include <vector>

namespace picking::scanner {
namespace {

using namespace dlpc350;
using Bytes = std::vector<std::uint8_t>;

// The first `n` bytes of the single report of `message`; the rest must be zero.
Bytes SingleReport(const Message& message, std::size_t n) {
  const std::vector<HidReport> reports = EncodeMessage(message);
  EXPECT_EQ(reports.size(), 1u);
  for (std::size_t i = n; i < reports[0].size(); ++i) EXPECT_EQ(reports[0][i], 0) << i;
  return Bytes(reports[0].begin(), reports[0].begin() + static_cast<std::ptrdiff_t>(n));
}

TEST(Dlpc350EncodingTest, DisplayModePatternSequence) {
  // report id, flags (write, reply wanted), sequence, length 3 (LE), CMD3, CMD2, payload.
  EXPECT_EQ(SingleReport(DisplayMode(true), 8),
            (Bytes{0x00, 0x40, 0x00, 0x03, 0x00, 0x1B, 0x1A, 0x01}));
  EXPECT_EQ(SingleReport(DisplayMode(false), 8),
            (Bytes{0x00, 0x40, 0x00, 0x03, 0x00, 0x1B, 0x1A, 0x00}));
}

TEST(Dlpc350EncodingTest, SequenceAndFlags) {
  Message message = PatternStartStop(PatternAction::kStart);
  message.sequence = 0x7F;
  message.reply_wanted = false;
  EXPECT_EQ(SingleReport(message, 8), (Bytes{0x00, 0x00, 0x7F, 0x03, 0x00, 0x24, 0x1A, 0x02}));
  EXPECT_EQ(SingleReport(ReadValidationStatus(), 7),
            (Bytes{0x00, 0xC0, 0x00, 0x02, 0x00, 0x1A, 0x1A}));
}

TEST(Dlpc350EncodingTest, EveryCommand) {
  EXPECT_EQ(SingleReport(PatternDisplaySource(PatternSource::kInternalFlash), 8),
            (Bytes{0x00, 0x40, 0x00, 0x03, 0x00, 0x22, 0x1A, 0x03}));
  EXPECT_EQ(SingleReport(PatternDisplaySource(PatternSource::kVideoPort), 8),
            (Bytes{0x00, 0x40, 0x00, 0x03, 0x00, 0x22, 0x1A, 0x00}));
  EXPECT_EQ(SingleReport(PatternTriggerMode(true), 8),
            (Bytes{0x00, 0x40, 0x00, 0x03, 0x00, 0x23, 0x1A, 0x01}));
  // 8333 us = 0x208D, 10000 us = 0x2710, both 32-bit little-endian.
  EXPECT_EQ(SingleReport(ExposureFramePeriod(8333, 10000), 15),
            (Bytes{0x00, 0x40, 0x00, 0x0A, 0x00, 0x29, 0x1A, 0x8D, 0x20, 0x00, 0x00, 0x10, 0x27,
                   0x00, 0x00}));
  EXPECT_EQ(SingleReport(TriggerOut1(false, 0xBB, 0xC0), 10),
            (Bytes{0x00, 0x40, 0x00, 0x05, 0x00, 0x1D, 0x1A, 0x00, 0xBB, 0xC0}));
  EXPECT_EQ(SingleReport(TriggerOut2(true, 0x10), 9),
            (Bytes{0x00, 0x40, 0x00, 0x04, 0x00, 0x1E, 0x1A, 0x01, 0x10}));
  EXPECT_EQ(SingleReport(PatternStartStop(PatternAction::kStop), 8),
            (Bytes{0x00, 0x40, 0x00, 0x03, 0x00, 0x24, 0x1A, 0x00}));
  EXPECT_EQ(SingleReport(PatternStartStop(PatternAction::kPause), 8),
            (Bytes{0x00, 0x40, 0x00, 0x03, 0x00, 0x24, 0x1A, 0x01}));
  // 44 entries, no repeat, trigger out 2 after 44 patterns, 1 image: sent 0-based.
  EXPECT_EQ(SingleReport(PatternConfig(44, false, 44, 1), 11),
            (Bytes{0x00, 0x40, 0x00, 0x06, 0x00, 0x31, 0x1A, 0x2B, 0x00, 0x2B, 0x00}));
  EXPECT_EQ(SingleReport(PatternConfig(128, true, 256, 64), 11),
            (Bytes{0x00, 0x40, 0x00, 0x06, 0x00, 0x31, 0x1A, 0x7F, 0x01, 0xFF, 0x3F}));
  EXPECT_EQ(SingleReport(MailboxControl(Mailbox::kPatternLut), 8),
            (Bytes{0x00, 0x40, 0x00, 0x03, 0x00, 0x33, 0x1A, 0x02}));
  EXPECT_EQ(SingleReport(MailboxControl(Mailbox::kImageLut), 8),
            (Bytes{0x00, 0x40, 0x00, 0x03, 0x00, 0x33, 0x1A, 0x01}));
  EXPECT_EQ(SingleReport(MailboxControl(Mailbox::kClosed), 8),
            (Bytes{0x00, 0x40, 0x00, 0x03, 0x00, 0x33, 0x1A, 0x00}));
  EXPECT_EQ(SingleReport(MailboxAddress(5), 8),
            (Bytes{0x00, 0x40, 0x00, 0x03, 0x00, 0x32, 0x1A, 0x05}));
  EXPECT_EQ(SingleReport(MailboxData({0xAA, 0xBB, 0xCC}), 10),
            (Bytes{0x00, 0x40, 0x00, 0x05, 0x00, 0x34, 0x1A, 0xAA, 0xBB, 0xCC}));
  EXPECT_EQ(SingleReport(ValidatePatternLut(), 8),
            (Bytes{0x00, 0x40, 0x00, 0x03, 0x00, 0x1A, 0x1A, 0x00}));
}

TEST(Dlpc350EncodingTest, InvalidArgumentsAreRejected) {
  EXPECT_THROW(PatternConfig(0, false, 1, 1), std::invalid_argument);
  EXPECT_THROW(PatternConfig(129, false, 1, 1), std::invalid_argument);
  EXPECT_THROW(PatternConfig(1, false, 257, 1), std::invalid_argument);
  EXPECT_THROW(PatternConfig(1, false, 1, 65), std::invalid_argument);
  EXPECT_THROW(MailboxAddress(128), std::invalid_argument);
  PatternLutEntry entry;
  entry.pattern_number = 25;
  EXPECT_THROW(entry.Encode(), std::invalid_argument);
  entry.pattern_number = 0;
  entry.bit_depth = 0;
  EXPECT_THROW(entry.Encode(), std::invalid_argument);
  entry.bit_depth = 1;
  entry.insert_black = true;
  entry.trigger_out_previous = true;
  EXPECT_THROW(entry.Encode(), std::invalid_argument);
  EXPECT_THROW(GrayCodeLut(12, 13), std::invalid_argument);
}

TEST(Dlpc350EncodingTest, PatternLutEntryBitLayout) {
  PatternLutEntry entry;
  entry.trigger = TriggerType::kInternal;
  entry.pattern_number = 5;
  entry.bit_depth = 1;
  entry.leds = 7;
  entry.invert = true;
  entry.buffer_swap = true;
  // 5 << 2 | 1 << 8 | 7 << 12 | bit 16 | bit 18
  EXPECT_EQ(entry.Encode(), 0x57114u);
  EXPECT_EQ(PackPatternLut({entry}), (Bytes{0x14, 0x71, 0x05}));
  PatternLutEntry other;
  other.trigger = TriggerType::kExternalNegative;
  other.pattern_number = 23;
  other.bit_depth = 8;
  other.leds = 4;
  other.insert_black = true;
  // 2 | 23 << 2 | 8 << 8 | 4 << 12 | bit 17
  EXPECT_EQ(other.Encode(), 0x2485Eu);
  other.insert_black = false;
  other.trigger_out_previous = true;
  EXPECT_EQ(other.Encode(), 0x8485Eu);
  // Round trip for every field combination that matters.
  for (int trigger = 0; trigger < 4; ++trigger) {
    for (int pattern = 0; pattern <= kWhiteFillPattern; pattern += 3) {
      for (int flags = 0; flags < 16; ++flags) {
        PatternLutEntry e;
        e.trigger = static_cast<TriggerType>(trigger);
        e.pattern_number = pattern;
        e.bit_depth = 1 + pattern % 8;
        e.leds = pattern % 8;
        e.invert = flags & 1;
        e.insert_black = flags & 2;
        e.buffer_swap = flags & 4;
        e.trigger_out_previous = (flags & 8) && !(flags & 2);
        EXPECT_EQ(PatternLutEntry::Decode(e.Encode()), e);
      }
    }
  }
}

TEST(Dlpc350EncodingTest, LongMessagesSpanSeveralReports) {
  Bytes data(132);
  for (std::size_t i = 0; i < data.size(); ++i) data[i] = static_cast<std::uint8_t>(i + 1);
  const std::vector<HidReport> reports = EncodeMessage(MailboxData(data));
  // 2 command bytes + 132 data bytes = 134 = 60 + 64 + 10.
  ASSERT_EQ(reports.size(), 3u);
  EXPECT_EQ(reports[0][3], 134);
  EXPECT_EQ(reports[0][4], 0);
  EXPECT_EQ(reports[0][5], 0x34);
  EXPECT_EQ(reports[0][6], 0x1A);
  EXPECT_EQ(reports[0][7], 1);
  EXPECT_EQ(reports[0][64], 58);  // 58 data bytes fit beside the command in the first report
  EXPECT_EQ(reports[1][0], 0);    // report id
  EXPECT_EQ(reports[1][1], 59);
  EXPECT_EQ(reports[1][64], 122);
  EXPECT_EQ(reports[2][1], 123);
  EXPECT_EQ(reports[2][10], 132);
  EXPECT_EQ(reports[2][11], 0);
}

TEST(Dlpc350EncodingTest, GrayCodeLutShowsWhiteBlackAndEveryBitWithItsInverse) {
  const std::vector<PatternLutEntry> lut = GrayCodeLut(10, 11);
  ASSERT_EQ(lut.size(), 44u);
  EXPECT_EQ(lut[0].pattern_number, kWhiteFillPattern);
  EXPECT_FALSE(lut[0].invert);
  EXPECT_TRUE(lut[0].buffer_swap);
  EXPECT_EQ(lut[1].pattern_number, kWhiteFillPattern);
  EXPECT_TRUE(lut[1].invert);
  for (int plane = 0; plane < 21; ++plane) {
    EXPECT_EQ(lut[2 + 2 * plane].pattern_number, plane);
    EXPECT_FALSE(lut[2 + 2 * plane].invert);
    EXPECT_EQ(lut[3 + 2 * plane].pattern_number, plane);
    EXPECT_TRUE(lut[3 + 2 * plane].invert);
  }
  for (const auto& entry : lut) {
    EXPECT_EQ(entry.bit_depth, 1);
    EXPECT_EQ(entry.trigger, TriggerType::kInternal);
    EXPECT_FALSE(entry.trigger_out_previous);  // one trigger-out pulse per pattern
  }
}

// Records every report and answers like the device: an acknowledge for writes, the
// validation status for reads of 0x1A1A.
class FakeHidTransport final : public HidTransport {
 public:
  struct Log {
    std::vector<HidReport> written;
    std::deque<std::uint8_t> validation_statuses;
    bool nack_next = false;
  };
  explicit FakeHidTransport(Log* log) : log_(log) {}

  void Write(const HidReport& report) override {
    log_->written.push_back(report);
    if (remaining_ > 0) {
      remaining_ -= std::min<int>(remaining_, 64);
      return;
    }
    const int length = report[3] | (report[4] << 8);
    remaining_ = std::max(0, length - 60);
    pending_flags_ = report[1];
    pending_sequence_ = report[2];
    pending_command_ = static_cast<std::uint16_t>(report[5] | (report[6] << 8));
  }

  HidInput Read(std::chrono::milliseconds) override {
    HidInput reply{};
    reply[0] = static_cast<std::uint8_t>(pending_flags_ & 0xC0);
    if (log_->nack_next) {
      reply[0] |= 0x20;
      log_->nack_next = false;
    }
    reply[1] = pending_sequence_;
    if ((pending_flags_ & 0x80) && pending_command_ == 0x1A1A) {
      reply[2] = 1;
      reply[4] = log_->validation_statuses.empty() ? 0 : log_->validation_statuses.front();
      if (!log_->validation_statuses.empty()) log_->validation_statuses.pop_front();
    }
    return reply;
  }

 private:
  Log* log_;
  int remaining_ = 0;
  std::uint8_t pending_flags_ = 0;
  std::uint8_t pending_sequence_ = 0;
  std::uint16_t pending_command_ = 0;
};

std::uint16_t CommandOf(const HidReport& report) {
  return static_cast<std::uint16_t>(report[5] | (report[6] << 8));
}

Dlpc350Options FastOptions() {
  Dlpc350Options options;
  options.validation_poll_interval = std::chrono::milliseconds(0);
  return options;
}

TEST(Dlpc350ProjectorTest, ProgramsTheGrayCodeSequence) {
  FakeHidTransport::Log log;
  log.validation_statuses = {0x80, 0x80, 0x00};  // busy twice, then valid
  Dlpc350Projector projector(std::make_unique<FakeHidTransport>(&log), FastOptions());
  EXPECT_EQ(projector.width(), 912u);
  EXPECT_EQ(projector.height(), 1140u);
  EXPECT_THROW(projector.Start(), ProjectorError);
  ProjectorSequenceSettings settings;
  settings.exposure_us = 8333;
  settings.frame_period_us = 8333;
  projector.LoadSequence(settings);

  // Command order and the payloads that matter.
  std::vector<std::uint16_t> commands;
  std::vector<const HidReport*> first_reports;
  for (std::size_t i = 0; i < log.written.size(); ++i) {
    const HidReport& report = log.written[i];
    commands.push_back(CommandOf(report));
    first_reports.push_back(&report);
    const int length = report[3] | (report[4] << 8);
    i += static_cast<std::size_t>(std::max(0, (length - 60 + 63) / 64));  // skip continuations
  }
  const std::vector<std::uint16_t> expected = {
      0x1A24, 0x1A1B, 0x1A22, 0x1A23, 0x1A29, 0x1A1D, 0x1A1E, 0x1A31, 0x1A33, 0x1A32,
      0x1A34, 0x1A33, 0x1A33, 0x1A32, 0x1A34, 0x1A33, 0x1A1A, 0x1A1A, 0x1A1A, 0x1A1A};
  EXPECT_EQ(commands, expected);
  // Sequence numbers count up.
  for (std::size_t i = 0; i < first_reports.size(); ++i) {
    EXPECT_EQ((*first_reports[i])[2], static_cast<std::uint8_t>(i));
  }
  // Pattern LUT: 44 entries = 132 bytes in three reports; the first entry is the white fill
  // with buffer swap: 24 << 2 | 1 << 8 | 7 << 12 | bit 18 = 0x47160.
  const HidReport& lut = *first_reports[10];
  EXPECT_EQ(lut[3] | (lut[4] << 8), 134);
  EXPECT_EQ(lut[7], 0x60);
  EXPECT_EQ(lut[8], 0x71);
  EXPECT_EQ(lut[9], 0x04);
  // The image LUT selects flash image 0.
  EXPECT_EQ((*first_reports[14])[7], 0x00);
  // Pattern config: 44 entries, 1 image.
  EXPECT_EQ((*first_reports[7])[7], 43);
  EXPECT_EQ((*first_reports[7])[10], 0);
  // Trigger out 1 not inverted: it pulses for the camera.
  EXPECT_EQ((*first_reports[5])[7], 0);

  log.written.clear();
  projector.Start();
  ASSERT_EQ(log.written.size(), 1u);
  EXPECT_EQ(CommandOf(log.written[0]), 0x1A24);
  EXPECT_EQ(log.written[0][7], 0x02);
  projector.Stop();
  EXPECT_EQ(log.written[1][7], 0x00);
}

TEST(Dlpc350ProjectorTest, InvalidLutIsReported) {
  FakeHidTransport::Log log;
  log.validation_statuses = {kInvalidExposureOrPeriod};
  Dlpc350Projector projector(std::make_unique<FakeHidTransport>(&log), FastOptions());
  try {
    projector.LoadSequence({});
    FAIL() << "expected an error";
  } catch (const ProjectorError& e) {
    EXPECT_NE(std::string(e.what()).find("exposure"), std::string::npos) << e.what();
  }
  EXPECT_THROW(projector.Start(), ProjectorError);
}

TEST(Dlpc350ProjectorTest, NackAndBadSettingsAreErrors) {
  FakeHidTransport::Log log;
  Dlpc350Projector projector(std::make_unique<FakeHidTransport>(&log), FastOptions());
  log.nack_next = true;
  EXPECT_THROW(projector.LoadSequence({}), ProjectorError);
  ProjectorSequenceSettings settings;
  settings.frame_period_us = settings.exposure_us - 1;
  const std::size_t before = log.written.size();
  EXPECT_THROW(projector.LoadSequence(settings), std::invalid_argument);
  EXPECT_EQ(log.written.size(), before);  // nothing sent for bad settings
  EXPECT_THROW(Dlpc350Projector(nullptr), std::invalid_argument);
}

TEST(Dlpc350ProjectorTest, MissingHidDeviceIsNamed) {
  try {
    HidrawTransport transport("/dev/hidraw_does_not_exist");
    FAIL() << "expected an error";
  } catch (const ProjectorError& e) {
    EXPECT_NE(std::string(e.what()).find("/dev/hidraw_does_not_exist"), std::string::npos);
  }
}

}  // namespace
}  // namespace picking::scanner
