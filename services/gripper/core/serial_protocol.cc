#include "services/gripper/core/serial_protocol.h"

#include <charconv>
#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace picking::gripper::serial {
namespace {

int HexValue(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  return -1;
}

// Telemetry keys are single upper-case letters; values never are.
bool IsKey(const std::string& field) {
  return field.size() == 1 && field[0] >= 'A' && field[0] <= 'Z';
}

}  // namespace

std::uint8_t Checksum(std::string_view body) {
  std::uint8_t x = 0;
  for (char c : body) x ^= static_cast<std::uint8_t>(c);
  return x;
}

std::string EncodeLine(std::string_view body) {
  for (char c : body) {
    const auto u = static_cast<unsigned char>(c);
    if (c == '$' || c == '*' || u < 0x20 || u > 0x7e) {
      throw std::invalid_argument("serial line body contains a reserved or control character: '" +
                                  std::string(body) + "'");
    }
  }
  if (body.size() + 5 > kMaxLineBytes) {
    throw std::invalid_argument("serial line body too long (" + std::to_string(body.size()) +
                                " bytes)");
  }
  char tail[8];
  std::snprintf(tail, sizeof(tail), "*%02X\n", Checksum(body));
  std::string line;
  line.reserve(body.size() + 5);
  line += '$';
  line += body;
  line += tail;
  return line;
}

std::optional<std::string> DecodeLine(std::string_view line) {
  if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
  if (line.size() < 4 || line.front() != '$') return std::nullopt;
  const std::size_t star = line.size() - 3;
  if (line[star] != '*') return std::nullopt;
  const int hi = HexValue(line[star + 1]);
  const int lo = HexValue(line[star + 2]);
  if (hi < 0 || lo < 0) return std::nullopt;
  const std::string_view body = line.substr(1, star - 1);
  for (char c : body) {
    const auto u = static_cast<unsigned char>(c);
    if (c == '$' || c == '*' || u < 0x20 || u > 0x7e) return std::nullopt;
  }
  if (Checksum(body) != static_cast<std::uint8_t>(hi * 16 + lo)) return std::nullopt;
  return std::string(body);
}

std::vector<std::string> SplitFields(std::string_view body) {
  std::vector<std::string> fields;
  std::size_t i = 0;
  while (i < body.size()) {
    while (i < body.size() && body[i] == ' ') ++i;
    const std::size_t start = i;
    while (i < body.size() && body[i] != ' ') ++i;
    if (i > start) fields.emplace_back(body.substr(start, i - start));
  }
  return fields;
}

std::string FormatNumber(double value, int decimals) {
  char buf[64];
  // Avoid "-0.00", which reads the same but makes logs and checksums of equal states differ.
  const double scale = std::pow(10.0, decimals);
  if (std::round(value * scale) == 0.0) value = 0.0;
  std::snprintf(buf, sizeof(buf), "%.*f", decimals, value);
  return buf;
}

std::optional<double> ParseNumber(std::string_view field) {
  if (field.empty()) return std::nullopt;
  double value = 0.0;
  const char* begin = field.data();
  const char* end = field.data() + field.size();
  if (*begin == '+') ++begin;
  const auto [ptr, ec] = std::from_chars(begin, end, value, std::chars_format::fixed);
  if (ec != std::errc() || ptr != end || !std::isfinite(value)) return std::nullopt;
  return value;
}

std::optional<std::uint32_t> ParseSeq(std::string_view field) {
  if (field.empty() || field.size() > 5) return std::nullopt;
  std::uint32_t value = 0;
  const auto [ptr, ec] = std::from_chars(field.data(), field.data() + field.size(), value);
  if (ec != std::errc() || ptr != field.data() + field.size() || value > kMaxSeq) {
    return std::nullopt;
  }
  return value;
}

std::string CommandBody(std::uint32_t seq, std::string_view command) {
  return std::to_string(seq) + " " + std::string(command);
}

std::optional<Command> ParseCommand(std::string_view body) {
  std::vector<std::string> fields = SplitFields(body);
  if (fields.size() < 2) return std::nullopt;
  const auto seq = ParseSeq(fields[0]);
  if (!seq) return std::nullopt;
  Command command;
  command.seq = *seq;
  command.verb = fields[1];
  command.args.assign(fields.begin() + 2, fields.end());
  return command;
}

std::string OkBody(std::uint32_t seq, std::string_view payload) {
  std::string body = "OK " + std::to_string(seq);
  if (!payload.empty()) {
    body += ' ';
    body += payload;
  }
  return body;
}

std::string ErrBody(std::uint32_t seq, std::string_view reason) {
  return "ERR " + std::to_string(seq) + " " + std::string(reason);
}

std::optional<Reply> ParseReply(std::string_view body) {
  std::vector<std::string> fields = SplitFields(body);
  if (fields.size() < 2) return std::nullopt;
  Reply reply;
  if (fields[0] == "OK") {
    reply.ok = true;
  } else if (fields[0] == "ERR") {
    reply.ok = false;
    if (fields.size() < 3) return std::nullopt;  // ERR needs a reason.
  } else {
    return std::nullopt;
  }
  const auto seq = ParseSeq(fields[1]);
  if (!seq) return std::nullopt;
  reply.seq = *seq;
  reply.fields.assign(fields.begin() + 2, fields.end());
  return reply;
}

char ModeCode(JointMode mode) {
  switch (mode) {
    case JointMode::kUnactuated:
      return 'U';
    case JointMode::kFixed:
      return 'F';
    case JointMode::kKeepVertical:
      return 'K';
  }
  throw std::invalid_argument("unknown joint mode");
}

std::optional<JointMode> ModeFromCode(std::string_view code) {
  if (code == "U") return JointMode::kUnactuated;
  if (code == "F") return JointMode::kFixed;
  if (code == "K") return JointMode::kKeepVertical;
  return std::nullopt;
}

std::string FormatTelemetry(const Telemetry& t) {
  return "P " + FormatNumber(t.vacuum_kpa, 2) + " A " + FormatNumber(t.gravity_head_m_s2.x(), 3) +
         " " + FormatNumber(t.gravity_head_m_s2.y(), 3) + " " +
         FormatNumber(t.gravity_head_m_s2.z(), 3) + " J " + FormatNumber(t.joint_deg, 2) + " M " +
         ModeCode(t.mode) + " R " + (t.relay_on ? "1" : "0");
}

Telemetry ParseTelemetry(const std::vector<std::string>& fields) {
  Telemetry t;
  bool seen_p = false, seen_a = false, seen_j = false, seen_m = false, seen_r = false;
  auto number = [&](std::size_t i, const char* what) {
    if (i >= fields.size()) {
      throw std::invalid_argument(std::string("telemetry: ") + what + " is missing");
    }
    const auto v = ParseNumber(fields[i]);
    if (!v) {
      throw std::invalid_argument(std::string("telemetry: ") + what + " '" + fields[i] +
                                  "' is not a number");
    }
    return *v;
  };
  std::size_t i = 0;
  while (i < fields.size()) {
    const std::string& key = fields[i];
    if (key == "P") {
      t.vacuum_kpa = number(i + 1, "P (vacuum kPa)");
      seen_p = true;
      i += 2;
    } else if (key == "A") {
      t.gravity_head_m_s2 =
          Eigen::Vector3d(number(i + 1, "A x"), number(i + 2, "A y"), number(i + 3, "A z"));
      seen_a = true;
      i += 4;
    } else if (key == "J") {
      t.joint_deg = number(i + 1, "J (joint degrees)");
      seen_j = true;
      i += 2;
    } else if (key == "M") {
      if (i + 1 >= fields.size()) throw std::invalid_argument("telemetry: M (mode) is missing");
      const auto mode = ModeFromCode(fields[i + 1]);
      if (!mode) throw std::invalid_argument("telemetry: unknown mode '" + fields[i + 1] + "'");
      t.mode = *mode;
      seen_m = true;
      i += 2;
    } else if (key == "R") {
      if (i + 1 >= fields.size() || (fields[i + 1] != "0" && fields[i + 1] != "1")) {
        throw std::invalid_argument("telemetry: R (relay) must be 0 or 1");
      }
      t.relay_on = fields[i + 1] == "1";
      seen_r = true;
      i += 2;
    } else {
      // A field added by newer firmware: skipped with its values, up to the next key.
      ++i;
      while (i < fields.size() && !IsKey(fields[i])) ++i;
    }
  }
  if (!seen_p || !seen_a || !seen_j || !seen_m || !seen_r) {
    throw std::invalid_argument("telemetry: needs the fields P, A, J, M and R");
  }
  return t;
}

LineReader::LineReader(std::size_t max_line_bytes) : max_line_bytes_(max_line_bytes) {
  if (max_line_bytes == 0) throw std::invalid_argument("LineReader: max_line_bytes must be > 0");
}

void LineReader::Append(std::string_view bytes) { buffer_.append(bytes); }

std::optional<std::string> LineReader::Next() {
  while (true) {
    const std::size_t nl = buffer_.find('\n');
    if (nl == std::string::npos) {
      if (buffer_.size() > max_line_bytes_) {
        if (!skipping_) ++overlong_lines_;
        skipping_ = true;
        buffer_.clear();
      }
      return std::nullopt;
    }
    std::string line = buffer_.substr(0, nl);
    buffer_.erase(0, nl + 1);
    if (skipping_) {
      skipping_ = false;  // The tail of an overlong line.
      continue;
    }
    if (line.size() > max_line_bytes_) {
      ++overlong_lines_;
      continue;
    }
    return line;
  }
}

void LineReader::Clear() {
  buffer_.clear();
  skipping_ = false;
}

}  // namespace picking::gripper::serial
