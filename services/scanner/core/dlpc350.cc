#include "services/scanner/core/dlpc350.h"

#include <fcntl.h>
#include <poll.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <sstream>
#include <stdexcept>
#include <thread>

namespace picking::scanner::dlpc350 {
namespace {

constexpr std::uint8_t kFlagRead = 0x80;
constexpr std::uint8_t kFlagReply = 0x40;
constexpr std::uint8_t kFlagNack = 0x20;
constexpr std::size_t kHeaderSize = 4;
constexpr std::size_t kReportPayload = 64;

Message Write(Command command, std::vector<std::uint8_t> payload) {
  Message message;
  message.command = command;
  message.payload = std::move(payload);
  return message;
}

std::string Hex(std::uint16_t value) {
  std::ostringstream s;
  s << "0x" << std::hex << std::uppercase << value;
  return s.str();
}

}  // namespace

std::vector<HidReport> EncodeMessage(const Message& message) {
  std::vector<std::uint8_t> body;
  const auto code = static_cast<std::uint16_t>(message.command);
  body.push_back(static_cast<std::uint8_t>(code & 0xFF));  // CMD3
  body.push_back(static_cast<std::uint8_t>(code >> 8));    // CMD2
  body.insert(body.end(), message.payload.begin(), message.payload.end());
  if (body.size() > 0xFFFF) {
    throw std::invalid_argument("DLPC350 message for command " + Hex(code) + " is too long");
  }
  std::vector<HidReport> reports;
  HidReport first{};
  first[0] = 0;  // report id
  first[1] = static_cast<std::uint8_t>((message.read ? kFlagRead : 0) |
                                       (message.reply_wanted ? kFlagReply : 0));
  first[2] = message.sequence;
  first[3] = static_cast<std::uint8_t>(body.size() & 0xFF);
  first[4] = static_cast<std::uint8_t>(body.size() >> 8);
  std::size_t sent = std::min(body.size(), kReportPayload - kHeaderSize);
  std::copy(body.begin(), body.begin() + static_cast<std::ptrdiff_t>(sent), first.begin() + 5);
  reports.push_back(first);
  while (sent < body.size()) {
    HidReport next{};
    const std::size_t n = std::min(body.size() - sent, kReportPayload);
    std::copy(body.begin() + static_cast<std::ptrdiff_t>(sent),
              body.begin() + static_cast<std::ptrdiff_t>(sent + n), next.begin() + 1);
    reports.push_back(next);
    sent += n;
  }
  return reports;
}

Message DisplayMode(bool pattern_sequence_mode) {
  return Write(Command::kDisplayMode, {static_cast<std::uint8_t>(pattern_sequence_mode ? 1 : 0)});
}

Message PatternDisplaySource(PatternSource source) {
  return Write(Command::kPatternDisplaySource, {static_cast<std::uint8_t>(source)});
}

Message PatternTriggerMode(bool triggered) {
  return Write(Command::kPatternTriggerMode, {static_cast<std::uint8_t>(triggered ? 1 : 0)});
}

Message ExposureFramePeriod(std::uint32_t exposure_us, std::uint32_t frame_period_us) {
  std::vector<std::uint8_t> payload;
  for (std::uint32_t value : {exposure_us, frame_period_us}) {
    for (int i = 0; i < 4; ++i) payload.push_back(static_cast<std::uint8_t>(value >> (8 * i)));
  }
  return Write(Command::kExposureFramePeriod, std::move(payload));
}

Message TriggerOut1(bool invert, std::uint8_t rising_delay, std::uint8_t falling_delay) {
  return Write(Command::kTriggerOut1,
               {static_cast<std::uint8_t>(invert ? 1 : 0), rising_delay, falling_delay});
}

Message TriggerOut2(bool invert, std::uint8_t rising_delay) {
  return Write(Command::kTriggerOut2, {static_cast<std::uint8_t>(invert ? 1 : 0), rising_delay});
}

Message PatternStartStop(PatternAction action) {
  return Write(Command::kPatternStartStop, {static_cast<std::uint8_t>(action)});
}

Message PatternConfig(int lut_entries, bool repeat, int trigger_out2_patterns,
                      int image_lut_entries) {
  if (lut_entries < 1 || lut_entries > 128) {
    throw std::invalid_argument("DLPC350 PatternConfig: lut_entries must be in [1, 128], got " +
                                std::to_string(lut_entries));
  }
  if (trigger_out2_patterns < 1 || trigger_out2_patterns > 256) {
    throw std::invalid_argument(
        "DLPC350 PatternConfig: trigger_out2_patterns must be in [1, 256], got " +
        std::to_string(trigger_out2_patterns));
  }
  if (image_lut_entries < 1 || image_lut_entries > 64) {
    throw std::invalid_argument(
        "DLPC350 PatternConfig: image_lut_entries must be in [1, 64], got " +
        std::to_string(image_lut_entries));
  }
  return Write(Command::kPatternConfig, {static_cast<std::uint8_t>(lut_entries - 1),
                                         static_cast<std::uint8_t>(repeat ? 1 : 0),
                                         static_cast<std::uint8_t>(trigger_out2_patterns - 1),
                                         static_cast<std::uint8_t>(image_lut_entries - 1)});
}

Message MailboxControl(Mailbox mailbox) {
  return Write(Command::kMailboxControl, {static_cast<std::uint8_t>(mailbox)});
}

Message MailboxAddress(std::uint8_t address) {
  if (address > 127) {
    throw std::invalid_argument("DLPC350 MailboxAddress must be <= 127, got " +
                                std::to_string(address));
  }
  return Write(Command::kMailboxAddress, {address});
}

Message MailboxData(std::vector<std::uint8_t> data) {
  return Write(Command::kMailboxData, std::move(data));
}

Message ValidatePatternLut() { return Write(Command::kPatternLutValidate, {0x00}); }

Message ReadValidationStatus() {
  Message message;
  message.command = Command::kPatternLutValidate;
  message.read = true;
  return message;
}

std::uint32_t PatternLutEntry::Encode() const {
  const auto check = [](bool ok, const std::string& field, int value) {
    if (!ok) {
      throw std::invalid_argument("DLPC350 pattern LUT entry: " + field +
                                  " out of range: " + std::to_string(value));
    }
  };
  check(static_cast<int>(trigger) <= 3, "trigger", static_cast<int>(trigger));
  check(pattern_number >= 0 && pattern_number <= kWhiteFillPattern, "pattern_number",
        pattern_number);
  check(bit_depth >= 1 && bit_depth <= 8, "bit_depth", bit_depth);
  check(leds >= 0 && leds <= 7, "leds", leds);
  check(!(insert_black && trigger_out_previous), "insert_black with trigger_out_previous", 1);
  std::uint32_t word = static_cast<std::uint32_t>(trigger) & 0x3u;
  word |= (static_cast<std::uint32_t>(pattern_number) & 0x3Fu) << 2;
  word |= (static_cast<std::uint32_t>(bit_depth) & 0xFu) << 8;
  word |= (static_cast<std::uint32_t>(leds) & 0x7u) << 12;
  if (invert) word |= 1u << 16;
  if (insert_black) word |= 1u << 17;
  if (buffer_swap) word |= 1u << 18;
  if (trigger_out_previous) word |= 1u << 19;
  return word;
}

PatternLutEntry PatternLutEntry::Decode(std::uint32_t word) {
  PatternLutEntry entry;
  entry.trigger = static_cast<TriggerType>(word & 0x3u);
  entry.pattern_number = static_cast<int>((word >> 2) & 0x3Fu);
  entry.bit_depth = static_cast<int>((word >> 8) & 0xFu);
  entry.leds = static_cast<int>((word >> 12) & 0x7u);
  entry.invert = (word >> 16) & 1u;
  entry.insert_black = (word >> 17) & 1u;
  entry.buffer_swap = (word >> 18) & 1u;
  entry.trigger_out_previous = (word >> 19) & 1u;
  return entry;
}

bool PatternLutEntry::operator==(const PatternLutEntry& o) const {
  return trigger == o.trigger && pattern_number == o.pattern_number && bit_depth == o.bit_depth &&
         leds == o.leds && invert == o.invert && insert_black == o.insert_black &&
         buffer_swap == o.buffer_swap && trigger_out_previous == o.trigger_out_previous;
}

std::vector<std::uint8_t> PackPatternLut(const std::vector<PatternLutEntry>& entries) {
  std::vector<std::uint8_t> bytes;
  bytes.reserve(entries.size() * 3);
  for (const PatternLutEntry& entry : entries) {
    const std::uint32_t word = entry.Encode();
    bytes.push_back(static_cast<std::uint8_t>(word));
    bytes.push_back(static_cast<std::uint8_t>(word >> 8));
    bytes.push_back(static_cast<std::uint8_t>(word >> 16));
  }
  return bytes;
}

std::vector<PatternLutEntry> GrayCodeLut(int column_bits, int row_bits, int leds) {
  if (column_bits < 1 || row_bits < 1 || column_bits + row_bits > 24) {
    throw std::invalid_argument("DLPC350 GrayCodeLut: " + std::to_string(column_bits) + " + " +
                                std::to_string(row_bits) +
                                " bit planes do not fit one 24-bit image");
  }
  std::vector<PatternLutEntry> lut;
  PatternLutEntry white;
  white.pattern_number = kWhiteFillPattern;
  white.leds = leds;
  white.buffer_swap = true;  // show the Gray-code image loaded from flash
  lut.push_back(white);
  PatternLutEntry black = white;
  black.invert = true;
  black.buffer_swap = false;
  lut.push_back(black);
  for (int plane = 0; plane < column_bits + row_bits; ++plane) {
    PatternLutEntry entry;
    entry.pattern_number = plane;
    entry.leds = leds;
    lut.push_back(entry);
    entry.invert = true;
    lut.push_back(entry);
  }
  return lut;
}

HidrawTransport::HidrawTransport(const std::string& device_path) : path_(device_path) {
  fd_ = ::open(device_path.c_str(), O_RDWR | O_CLOEXEC);
  if (fd_ < 0) {
    throw ProjectorError("cannot open DLPC350 HID device '" + device_path +
                         "': " + std::strerror(errno));
  }
}

HidrawTransport::~HidrawTransport() {
  if (fd_ >= 0) ::close(fd_);
}

void HidrawTransport::Write(const HidReport& report) {
  const ssize_t n = ::write(fd_, report.data(), report.size());
  if (n != static_cast<ssize_t>(report.size())) {
    throw ProjectorError("write to DLPC350 HID device '" + path_ +
                         "' failed: " + (n < 0 ? std::strerror(errno) : "short write"));
  }
}

HidInput HidrawTransport::Read(std::chrono::milliseconds timeout) {
  pollfd descriptor{fd_, POLLIN, 0};
  const int ready = ::poll(&descriptor, 1, static_cast<int>(timeout.count()));
  if (ready == 0) {
    throw ProjectorError("DLPC350 HID device '" + path_ + "' did not answer within " +
                         std::to_string(timeout.count()) + " ms");
  }
  if (ready < 0) {
    throw ProjectorError("poll on DLPC350 HID device '" + path_ +
                         "' failed: " + std::strerror(errno));
  }
  HidInput input{};
  const ssize_t n = ::read(fd_, input.data(), input.size());
  if (n <= 0) {
    throw ProjectorError("read from DLPC350 HID device '" + path_ +
                         "' failed: " + (n < 0 ? std::strerror(errno) : "no data"));
  }
  return input;
}

}  // namespace picking::scanner::dlpc350

namespace picking::scanner {

using namespace dlpc350;

Dlpc350Projector::Dlpc350Projector(std::unique_ptr<HidTransport> transport,
                                   const Dlpc350Options& options)
    : transport_(std::move(transport)), options_(options) {
  if (!transport_) throw std::invalid_argument("Dlpc350Projector: transport is null");
  if (options_.image_index < 0 || options_.image_index > 255) {
    throw std::invalid_argument("Dlpc350Options.image_index must be in [0, 255]");
  }
  if (options_.leds < 0 || options_.leds > 7) {
    throw std::invalid_argument("Dlpc350Options.leds must be in [0, 7]");
  }
  if (options_.validation_polls < 1) {
    throw std::invalid_argument("Dlpc350Options.validation_polls must be >= 1");
  }
}

std::vector<std::uint8_t> Dlpc350Projector::Send(Message message) {
  message.sequence = sequence_++;
  for (const HidReport& report : EncodeMessage(message)) transport_->Write(report);
  if (!message.reply_wanted) return {};
  const HidInput reply = transport_->Read(options_.reply_timeout);
  const std::string name = Hex(static_cast<std::uint16_t>(message.command));
  if (reply[0] & kFlagNack) {
    throw ProjectorError("DLPC350 refused command " + name + " (nack)");
  }
  const std::size_t length = reply[2] | (static_cast<std::size_t>(reply[3]) << 8);
  const std::size_t available = std::min(length, reply.size() - kHeaderSize);
  return std::vector<std::uint8_t>(
      reply.begin() + kHeaderSize,
      reply.begin() + static_cast<std::ptrdiff_t>(kHeaderSize + available));
}

void Dlpc350Projector::LoadSequence(const ProjectorSequenceSettings& settings) {
  settings.Validate();
  const std::vector<PatternLutEntry> lut =
      GrayCodeLut(settings.column_bits, settings.row_bits, options_.leds);
  loaded_ = false;
  Send(PatternStartStop(PatternAction::kStop));
  Send(DisplayMode(true));
  Send(PatternDisplaySource(PatternSource::kInternalFlash));
  Send(PatternTriggerMode(true));
  Send(ExposureFramePeriod(settings.exposure_us, settings.frame_period_us));
  // Trigger out 1 pulses with every pattern; an inverted output holds it low when disabled.
  Send(TriggerOut1(!settings.trigger_camera, kNoTriggerDelay, kNoTriggerDelay));
  Send(TriggerOut2(false, kNoTriggerDelay));
  const int entries = static_cast<int>(lut.size());
  Send(PatternConfig(entries, /*repeat=*/false, /*trigger_out2_patterns=*/entries,
                     /*image_lut_entries=*/1));
  Send(MailboxControl(Mailbox::kPatternLut));
  Send(MailboxAddress(0));
  Send(MailboxData(PackPatternLut(lut)));
  Send(MailboxControl(Mailbox::kClosed));
  Send(MailboxControl(Mailbox::kImageLut));
  Send(MailboxAddress(0));
  Send(MailboxData({static_cast<std::uint8_t>(options_.image_index)}));
  Send(MailboxControl(Mailbox::kClosed));
  Send(ValidatePatternLut());
  for (int poll = 0; poll < options_.validation_polls; ++poll) {
    const std::vector<std::uint8_t> data = Send(ReadValidationStatus());
    if (data.empty()) throw ProjectorError("DLPC350 sent an empty LUT validation status");
    const std::uint8_t status = data[0];
    if (status & kValidationBusy) {
      std::this_thread::sleep_for(options_.validation_poll_interval);
      continue;
    }
    if (status & (kInvalidExposureOrPeriod | kInvalidPatternNumber)) {
      throw ProjectorError(
          std::string("DLPC350 rejected the pattern sequence:") +
          ((status & kInvalidExposureOrPeriod) ? " invalid exposure or frame period;" : "") +
          ((status & kInvalidPatternNumber) ? " invalid pattern number;" : ""));
    }
    loaded_ = true;
    return;
  }
  throw ProjectorError("DLPC350 LUT validation did not finish after " +
                       std::to_string(options_.validation_polls) + " polls");
}

void Dlpc350Projector::Start() {
  if (!loaded_) throw ProjectorError("Dlpc350Projector::Start: no pattern sequence loaded");
  Send(PatternStartStop(PatternAction::kStart));
}

void Dlpc350Projector::Stop() { Send(PatternStartStop(PatternAction::kStop)); }

}  // namespace picking::scanner
