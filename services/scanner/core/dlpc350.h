#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "services/scanner/core/projector_backend.h"

namespace picking::scanner::dlpc350 {

/// One USB HID output report as written to the device: report id 0 followed by 64 bytes.
using HidReport = std::array<std::uint8_t, 65>;
/// One USB HID input report as read from the device (64 bytes, no report id).
using HidInput = std::array<std::uint8_t, 64>;

/// USB command codes (CMD2 << 8 | CMD3) of the DLPC350 Programmer's Guide (TI DLPU010).
enum class Command : std::uint16_t {
  kPatternLutValidate = 0x1A1A,    ///< LUT_VALID
  kDisplayMode = 0x1A1B,           ///< DISP_MODE: 0 video, 1 pattern sequence
  kTriggerOut1 = 0x1A1D,           ///< TRIG_OUT1_CTL: invert, rising delay, falling delay
  kTriggerOut2 = 0x1A1E,           ///< TRIG_OUT2_CTL: invert, rising delay
  kPatternDisplaySource = 0x1A22,  ///< PAT_DISP_MODE: 0 video port, 3 internal flash
  kPatternTriggerMode = 0x1A23,    ///< PAT_TRIG_MODE: 0 VSYNC, 1 internal/external trigger
  kPatternStartStop = 0x1A24,      ///< PAT_START_STOP: 0 stop, 1 pause, 2 start
  kExposureFramePeriod = 0x1A29,   ///< PAT_EXPO_PRD: two 32-bit little-endian microseconds
  kPatternConfig = 0x1A31,         ///< PAT_CONFIG
  kMailboxAddress = 0x1A32,        ///< MBOX_ADDRESS
  kMailboxControl = 0x1A33,        ///< MBOX_CONTROL: 0 close, 1 image LUT, 2 pattern LUT
  kMailboxData = 0x1A34,           ///< MBOX_DATA
};

enum class PatternSource : std::uint8_t { kVideoPort = 0, kInternalFlash = 3 };
enum class PatternAction : std::uint8_t { kStop = 0, kPause = 1, kStart = 2 };
enum class Mailbox : std::uint8_t { kClosed = 0, kImageLut = 1, kPatternLut = 2 };

/// One command message. Packet layout (little-endian): flags byte (bit 7 read, bit 6 reply
/// wanted, bit 5 nack in replies, bits 2:0 destination, 0 = main processor), sequence byte,
/// 16-bit length of what follows, the command as CMD3 then CMD2 (the 16-bit code stored
/// little-endian), then the payload.
struct Message {
  Command command = Command::kDisplayMode;
  std::vector<std::uint8_t> payload;
  bool read = false;         ///< Read request (payload usually empty).
  bool reply_wanted = true;  ///< Ask the device for an acknowledge or the read data.
  std::uint8_t sequence = 0;
};

/// Splits `message` into HID output reports: the first carries the 4-byte header and up to
/// 60 bytes of command + payload, each further report 64 more bytes; unused bytes are 0.
/// Throws std::invalid_argument when command + payload exceed 65535 bytes.
std::vector<HidReport> EncodeMessage(const Message& message);

Message DisplayMode(bool pattern_sequence_mode);
Message PatternDisplaySource(PatternSource source);
/// `triggered` true = internal or external trigger (needed for pattern LUTs), false = VSYNC.
Message PatternTriggerMode(bool triggered);
Message ExposureFramePeriod(std::uint32_t exposure_us, std::uint32_t frame_period_us);
/// Delays are the Programmer's Guide's raw codes: 107.136 ns per step, 0xBB = no delay.
inline constexpr std::uint8_t kNoTriggerDelay = 0xBB;
Message TriggerOut1(bool invert, std::uint8_t rising_delay, std::uint8_t falling_delay);
Message TriggerOut2(bool invert, std::uint8_t rising_delay);
Message PatternStartStop(PatternAction action);
/// Counts are 1-based here and sent 0-based as the firmware expects. Throws
/// std::invalid_argument for lut_entries outside [1, 128], trigger_out2_patterns outside
/// [1, 256] or image_lut_entries outside [1, 64].
Message PatternConfig(int lut_entries, bool repeat, int trigger_out2_patterns,
                      int image_lut_entries);
Message MailboxControl(Mailbox mailbox);
Message MailboxAddress(std::uint8_t address);
Message MailboxData(std::vector<std::uint8_t> data);
/// Starts the validation of the programmed LUT; read its status with ReadValidationStatus.
Message ValidatePatternLut();
Message ReadValidationStatus();

/// Bits of the validation status byte.
inline constexpr std::uint8_t kInvalidExposureOrPeriod = 0x01;
inline constexpr std::uint8_t kInvalidPatternNumber = 0x02;
inline constexpr std::uint8_t kTriggerOutWarning = 0x04;
inline constexpr std::uint8_t kPostVectorWarning = 0x08;
inline constexpr std::uint8_t kPeriodExposureWarning = 0x10;
inline constexpr std::uint8_t kValidationBusy = 0x80;

enum class TriggerType : std::uint8_t {
  kInternal = 0,
  kExternalPositive = 1,
  kExternalNegative = 2,
  kContinueFromPrevious = 3,
};

/// One 24-bit pattern LUT entry: bits 1:0 trigger type, 7:2 pattern number, 11:8 bit depth,
/// 14:12 LEDs (bit 0 red, 1 green, 2 blue), 16 invert, 17 insert black, 18 buffer swap,
/// 19 trigger out 1 continues from the previous pattern.
struct PatternLutEntry {
  TriggerType trigger = TriggerType::kInternal;
  int pattern_number = 0;  ///< Bit plane 0-23 of the current image; 24 = all-white fill.
  int bit_depth = 1;       ///< 1-8.
  int leds = 7;            ///< 0-7.
  bool invert = false;
  bool insert_black = false;
  bool buffer_swap = false;
  bool trigger_out_previous = false;

  /// Throws std::invalid_argument naming the field when out of range.
  std::uint32_t Encode() const;
  static PatternLutEntry Decode(std::uint32_t word);
  bool operator==(const PatternLutEntry& other) const;
};

/// Number of the all-white 1-bit fill pattern (inverted: all black).
inline constexpr int kWhiteFillPattern = 24;

/// The mailbox bytes of a pattern LUT: 3 bytes per entry, little-endian.
std::vector<std::uint8_t> PackPatternLut(const std::vector<PatternLutEntry>& entries);

/// The scanner's sequence as a pattern LUT, assuming the Gray-code bit planes are stored in
/// one 24-bit flash image: bit plane b < column_bits is column bit b (b = 0 the most
/// significant), bit plane column_bits + b row bit b. Inverse images use the invert flag, so
/// one image holds all 21 planes of a 912 x 1140 code. Throws std::invalid_argument when
/// column_bits + row_bits > 24.
std::vector<PatternLutEntry> GrayCodeLut(int column_bits, int row_bits, int leds = 7);

/// A USB HID connection to the DLPC350.
class HidTransport {
 public:
  virtual ~HidTransport() = default;
  /// Writes one output report. Throws ProjectorError on failure.
  virtual void Write(const HidReport& report) = 0;
  /// Reads one input report, waiting at most `timeout`. Throws ProjectorError on timeout
  /// or failure.
  virtual HidInput Read(std::chrono::milliseconds timeout) = 0;
};

/// HidTransport over a Linux hidraw node (e.g. /dev/hidraw0 of the LightCrafter 4500,
/// USB id 0451:6401).
class HidrawTransport final : public HidTransport {
 public:
  /// Opens `device_path`. Throws ProjectorError naming it when it cannot be opened.
  explicit HidrawTransport(const std::string& device_path);
  ~HidrawTransport() override;
  HidrawTransport(const HidrawTransport&) = delete;
  HidrawTransport& operator=(const HidrawTransport&) = delete;

  void Write(const HidReport& report) override;
  HidInput Read(std::chrono::milliseconds timeout) override;

 private:
  std::string path_;
  int fd_ = -1;
};

}  // namespace picking::scanner::dlpc350

namespace picking::scanner {

struct Dlpc350Options {
  /// Flash image index holding the Gray-code bit planes (see dlpc350::GrayCodeLut).
  int image_index = 0;
  int leds = 7;  ///< LEDs used for the patterns (bit 0 red, 1 green, 2 blue).
  std::chrono::milliseconds reply_timeout{500};
  /// Validation status polls before giving up, and the wait between polls.
  int validation_polls = 50;
  std::chrono::milliseconds validation_poll_interval{20};
};

/// The TI DLP LightCrafter 4500 (DLPC350 controller, 912 x 1140 mirrors) as a
/// ProjectorBackend: programs the white / black / Gray-code sequence from internal flash with
/// trigger out 1 pulsing once per pattern to start the camera's exposure.
class Dlpc350Projector final : public ProjectorBackend {
 public:
  static constexpr std::uint32_t kWidth = 912;
  static constexpr std::uint32_t kHeight = 1140;

  /// Throws std::invalid_argument for a null transport or bad options.
  Dlpc350Projector(std::unique_ptr<dlpc350::HidTransport> transport,
                   const Dlpc350Options& options = {});

  std::uint32_t width() const override { return kWidth; }
  std::uint32_t height() const override { return kHeight; }
  /// Throws ProjectorError when the device answers with a nack, does not answer, or reports
  /// an invalid LUT.
  void LoadSequence(const ProjectorSequenceSettings& settings) override;
  void Start() override;
  void Stop() override;

  /// Sends one message and returns the reply's data bytes (after the 4-byte header); writes
  /// without a wanted reply return nothing. Throws ProjectorError on a nack or timeout.
  std::vector<std::uint8_t> Send(dlpc350::Message message);

 private:
  std::unique_ptr<dlpc350::HidTransport> transport_;
  Dlpc350Options options_;
  std::uint8_t sequence_ = 0;
  bool loaded_ = false;
};

}  // namespace picking::scanner
