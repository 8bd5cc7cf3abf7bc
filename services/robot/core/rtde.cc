#include "services/robot/core/rtde.h"

#include <cstring>
#include <sstream>
#include <stdexcept>

namespace picking::robot::rtde {
namespace {

struct TypeInfo {
  FieldType type;
  const char* name;
  std::size_t size;
};
constexpr TypeInfo kTypes[] = {
    {FieldType::kBool, "BOOL", 1},
    {FieldType::kUint8, "UINT8", 1},
    {FieldType::kUint32, "UINT32", 4},
    {FieldType::kUint64, "UINT64", 8},
    {FieldType::kInt32, "INT32", 4},
    {FieldType::kDouble, "DOUBLE", 8},
    {FieldType::kVector3d, "VECTOR3D", 24},
    {FieldType::kVector6d, "VECTOR6D", 48},
    {FieldType::kVector6Int32, "VECTOR6INT32", 24},
    {FieldType::kVector6Uint32, "VECTOR6UINT32", 24},
};

void PutU8(std::string* out, std::uint8_t v) { out->push_back(static_cast<char>(v)); }
void PutU16(std::string* out, std::uint16_t v) {
  PutU8(out, static_cast<std::uint8_t>(v >> 8));
  PutU8(out, static_cast<std::uint8_t>(v));
}
void PutU32(std::string* out, std::uint32_t v) {
  for (int shift = 24; shift >= 0; shift -= 8) PutU8(out, static_cast<std::uint8_t>(v >> shift));
}
void PutU64(std::string* out, std::uint64_t v) {
  for (int shift = 56; shift >= 0; shift -= 8) PutU8(out, static_cast<std::uint8_t>(v >> shift));
}
void PutDouble(std::string* out, double v) {
  std::uint64_t bits;
  std::memcpy(&bits, &v, sizeof(bits));
  PutU64(out, bits);
}

// Big-endian reader over a payload; throws naming the package.
class Reader {
 public:
  Reader(const std::string& data, const char* what) : data_(data), what_(what) {}
  std::uint64_t Unsigned(int bytes) {
    Need(bytes);
    std::uint64_t v = 0;
    for (int i = 0; i < bytes; ++i) v = (v << 8) | static_cast<unsigned char>(data_[pos_++]);
    return v;
  }
  std::uint8_t U8() { return static_cast<std::uint8_t>(Unsigned(1)); }
  std::uint16_t U16() { return static_cast<std::uint16_t>(Unsigned(2)); }
  std::uint32_t U32() { return static_cast<std::uint32_t>(Unsigned(4)); }
  std::uint64_t U64() { return Unsigned(8); }
  double Double() {
    const std::uint64_t bits = U64();
    double v;
    std::memcpy(&v, &bits, sizeof(v));
    return v;
  }
  std::string Bytes(std::size_t n) {
    Need(n);
    std::string s = data_.substr(pos_, n);
    pos_ += n;
    return s;
  }
  std::string Rest() { return Bytes(data_.size() - pos_); }
  void ExpectEnd() {
    if (pos_ != data_.size()) {
      throw std::runtime_error(std::string("RTDE ") + what_ + ": " +
                               std::to_string(data_.size() - pos_) + " unexpected trailing bytes");
    }
  }

 private:
  void Need(std::size_t n) {
    if (pos_ + n > data_.size()) {
      throw std::runtime_error(std::string("RTDE ") + what_ + ": payload too short (" +
                               std::to_string(data_.size()) + " bytes)");
    }
  }
  const std::string& data_;
  const char* what_;
  std::size_t pos_ = 0;
};

std::string JoinNames(const std::vector<std::string>& names) {
  std::string s;
  for (std::size_t i = 0; i < names.size(); ++i) {
    if (names[i].empty() || names[i].find(',') != std::string::npos) {
      throw std::invalid_argument("RTDE: invalid variable name '" + names[i] + "'");
    }
    s += (i ? "," : "") + names[i];
  }
  return s;
}

template <typename T>
const T& Get(const FieldValue& v, FieldType type) {
  if (!std::holds_alternative<T>(v)) {
    throw std::invalid_argument(std::string("RTDE: value does not match field type ") +
                                FieldTypeName(type));
  }
  return std::get<T>(v);
}

}  // namespace

FieldType ParseFieldType(const std::string& name) {
  for (const auto& t : kTypes) {
    if (name == t.name) return t.type;
  }
  throw std::invalid_argument("RTDE: unknown field type '" + name + "'");
}

const char* FieldTypeName(FieldType type) { return kTypes[static_cast<int>(type)].name; }
std::size_t FieldSize(FieldType type) { return kTypes[static_cast<int>(type)].size; }

std::size_t Recipe::IndexOf(const std::string& name) const {
  for (std::size_t i = 0; i < names.size(); ++i) {
    if (names[i] == name) return i;
  }
  throw std::out_of_range("RTDE recipe has no variable '" + name + "'");
}

std::string EncodePackage(PackageType type, const std::string& payload) {
  const std::size_t size = payload.size() + 3;
  if (size > 0xFFFF) throw std::invalid_argument("RTDE: package larger than 65535 bytes");
  std::string out;
  PutU16(&out, static_cast<std::uint16_t>(size));
  PutU8(&out, static_cast<std::uint8_t>(type));
  return out + payload;
}

Package ReadPackage(ByteStream& stream, std::chrono::milliseconds timeout) {
  const std::string header = stream.ReadExact(3, timeout);
  Reader r(header, "header");
  const std::uint16_t size = r.U16();
  const std::uint8_t type = r.U8();
  if (size < 3) throw std::runtime_error("RTDE: package size " + std::to_string(size) + " < 3");
  return {static_cast<PackageType>(type), stream.ReadExact(size - 3u, timeout)};
}

std::string EncodeRequestProtocolVersion(std::uint16_t version) {
  std::string out;
  PutU16(&out, version);
  return out;
}

std::string EncodeSetupOutputs(double frequency_hz, const std::vector<std::string>& names) {
  std::string out;
  PutDouble(&out, frequency_hz);
  return out + JoinNames(names);
}

std::string EncodeSetupInputs(const std::vector<std::string>& names) { return JoinNames(names); }

std::string EncodeDataPackage(std::uint8_t recipe_id, const std::vector<FieldType>& types,
                              const std::vector<FieldValue>& values) {
  if (types.size() != values.size()) {
    throw std::invalid_argument("RTDE: " + std::to_string(values.size()) + " values for " +
                                std::to_string(types.size()) + " recipe fields");
  }
  std::string out;
  PutU8(&out, recipe_id);
  for (std::size_t i = 0; i < types.size(); ++i) {
    const FieldValue& v = values[i];
    switch (types[i]) {
      case FieldType::kBool:
        PutU8(&out, Get<bool>(v, types[i]) ? 1 : 0);
        break;
      case FieldType::kUint8:
        PutU8(&out, Get<std::uint8_t>(v, types[i]));
        break;
      case FieldType::kUint32:
        PutU32(&out, Get<std::uint32_t>(v, types[i]));
        break;
      case FieldType::kUint64:
        PutU64(&out, Get<std::uint64_t>(v, types[i]));
        break;
      case FieldType::kInt32:
        PutU32(&out, static_cast<std::uint32_t>(Get<std::int32_t>(v, types[i])));
        break;
      case FieldType::kDouble:
        PutDouble(&out, Get<double>(v, types[i]));
        break;
      case FieldType::kVector3d:
        for (double d : Get<std::array<double, 3>>(v, types[i])) PutDouble(&out, d);
        break;
      case FieldType::kVector6d:
        for (double d : Get<std::array<double, 6>>(v, types[i])) PutDouble(&out, d);
        break;
      case FieldType::kVector6Int32:
        for (std::int32_t d : Get<std::array<std::int32_t, 6>>(v, types[i])) {
          PutU32(&out, static_cast<std::uint32_t>(d));
        }
        break;
      case FieldType::kVector6Uint32:
        for (std::uint32_t d : Get<std::array<std::uint32_t, 6>>(v, types[i])) PutU32(&out, d);
        break;
    }
  }
  return out;
}

std::string EncodeTextMessage(const TextMessage& message) {
  if (message.message.size() > 255 || message.source.size() > 255) {
    throw std::invalid_argument("RTDE: text message or source longer than 255 bytes");
  }
  std::string out;
  PutU8(&out, static_cast<std::uint8_t>(message.message.size()));
  out += message.message;
  PutU8(&out, static_cast<std::uint8_t>(message.source.size()));
  out += message.source;
  PutU8(&out, message.level);
  return out;
}

std::string EncodeControllerVersion(const ControllerVersion& v) {
  std::string out;
  PutU32(&out, v.major);
  PutU32(&out, v.minor);
  PutU32(&out, v.bugfix);
  PutU32(&out, v.build);
  return out;
}

std::string EncodeSetupReply(std::uint8_t recipe_id, const std::vector<std::string>& type_names) {
  std::string out;
  PutU8(&out, recipe_id);
  return out + JoinNames(type_names);
}

bool DecodeAccepted(const std::string& payload) {
  Reader r(payload, "accept reply");
  const std::uint8_t v = r.U8();
  r.ExpectEnd();
  return v != 0;
}

std::uint16_t DecodeRequestProtocolVersion(const std::string& payload) {
  Reader r(payload, "REQUEST_PROTOCOL_VERSION");
  const std::uint16_t v = r.U16();
  r.ExpectEnd();
  return v;
}

ControllerVersion DecodeControllerVersion(const std::string& payload) {
  Reader r(payload, "GET_URCONTROL_VERSION");
  ControllerVersion v;
  v.major = r.U32();
  v.minor = r.U32();
  v.bugfix = r.U32();
  v.build = r.U32();
  r.ExpectEnd();
  return v;
}

std::vector<std::string> SplitNames(const std::string& text) {
  std::vector<std::string> names;
  std::string item;
  std::istringstream in(text);
  while (std::getline(in, item, ',')) names.push_back(item);
  return names;
}

std::pair<double, std::vector<std::string>> DecodeSetupOutputs(const std::string& payload) {
  Reader r(payload, "CONTROL_PACKAGE_SETUP_OUTPUTS");
  const double frequency = r.Double();
  return {frequency, SplitNames(r.Rest())};
}

std::vector<std::string> DecodeSetupInputs(const std::string& payload) {
  return SplitNames(payload);
}

std::pair<std::uint8_t, std::vector<std::string>> DecodeSetupReply(const std::string& payload) {
  Reader r(payload, "setup reply");
  const std::uint8_t id = r.U8();
  return {id, SplitNames(r.Rest())};
}

DataPackage DecodeDataPackage(const std::string& payload, const std::vector<FieldType>& types) {
  Reader r(payload, "DATA_PACKAGE");
  DataPackage data;
  data.recipe_id = r.U8();
  for (FieldType type : types) {
    switch (type) {
      case FieldType::kBool:
        data.values.emplace_back(r.U8() != 0);
        break;
      case FieldType::kUint8:
        data.values.emplace_back(r.U8());
        break;
      case FieldType::kUint32:
        data.values.emplace_back(r.U32());
        break;
      case FieldType::kUint64:
        data.values.emplace_back(r.U64());
        break;
      case FieldType::kInt32:
        data.values.emplace_back(static_cast<std::int32_t>(r.U32()));
        break;
      case FieldType::kDouble:
        data.values.emplace_back(r.Double());
        break;
      case FieldType::kVector3d: {
        std::array<double, 3> v;
        for (double& d : v) d = r.Double();
        data.values.emplace_back(v);
        break;
      }
      case FieldType::kVector6d: {
        std::array<double, 6> v;
        for (double& d : v) d = r.Double();
        data.values.emplace_back(v);
        break;
      }
      case FieldType::kVector6Int32: {
        std::array<std::int32_t, 6> v;
        for (auto& d : v) d = static_cast<std::int32_t>(r.U32());
        data.values.emplace_back(v);
        break;
      }
      case FieldType::kVector6Uint32: {
        std::array<std::uint32_t, 6> v;
        for (auto& d : v) d = r.U32();
        data.values.emplace_back(v);
        break;
      }
    }
  }
  r.ExpectEnd();
  return data;
}

TextMessage DecodeTextMessage(const std::string& payload) {
  Reader r(payload, "TEXT_MESSAGE");
  TextMessage m;
  m.message = r.Bytes(r.U8());
  m.source = r.Bytes(r.U8());
  m.level = r.U8();
  r.ExpectEnd();
  return m;
}

RtdeClient::RtdeClient(std::unique_ptr<ByteStream> stream, std::chrono::milliseconds timeout)
    : stream_(std::move(stream)), timeout_(timeout) {
  if (!stream_) throw std::invalid_argument("RtdeClient: null stream");
}

std::string RtdeClient::Request(PackageType type, const std::string& payload) {
  stream_->WriteAll(EncodePackage(type, payload));
  const auto deadline = std::chrono::steady_clock::now() + timeout_;
  while (true) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) {
      throw StreamError("RTDE: no reply to request '" + std::string(1, static_cast<char>(type)) +
                        "'");
    }
    Package package = ReadPackage(*stream_, left);
    if (package.type == type) return package.payload;
    if (package.type == PackageType::kTextMessage) {
      messages_.push_back(DecodeTextMessage(package.payload));
    }
    // Data packages still in flight (e.g. before a PAUSE reply) are dropped.
  }
}

bool RtdeClient::NegotiateProtocolVersion(std::uint16_t version) {
  return DecodeAccepted(
      Request(PackageType::kRequestProtocolVersion, EncodeRequestProtocolVersion(version)));
}

ControllerVersion RtdeClient::GetControllerVersion() {
  return DecodeControllerVersion(Request(PackageType::kGetUrControlVersion, ""));
}

namespace {
Recipe MakeRecipe(const std::pair<std::uint8_t, std::vector<std::string>>& reply,
                  const std::vector<std::string>& names, const char* what) {
  const auto& [id, type_names] = reply;
  if (type_names.size() != names.size()) {
    throw std::runtime_error(std::string("RTDE ") + what + ": " +
                             std::to_string(type_names.size()) + " types for " +
                             std::to_string(names.size()) + " variables");
  }
  Recipe recipe;
  recipe.id = id;
  recipe.names = names;
  std::string problems;
  for (std::size_t i = 0; i < names.size(); ++i) {
    if (type_names[i] == "NOT_FOUND" || type_names[i] == "IN_USE") {
      problems += (problems.empty() ? "" : ", ") + names[i] + " (" + type_names[i] + ")";
      continue;
    }
    recipe.types.push_back(ParseFieldType(type_names[i]));
  }
  if (!problems.empty()) {
    throw std::runtime_error(std::string("RTDE ") + what + " refused variables: " + problems);
  }
  return recipe;
}
}  // namespace

Recipe RtdeClient::SetupOutputs(double frequency_hz, const std::vector<std::string>& names) {
  output_recipe_ = MakeRecipe(DecodeSetupReply(Request(PackageType::kControlPackageSetupOutputs,
                                                       EncodeSetupOutputs(frequency_hz, names))),
                              names, "CONTROL_PACKAGE_SETUP_OUTPUTS");
  return output_recipe_;
}

Recipe RtdeClient::SetupInputs(const std::vector<std::string>& names) {
  return MakeRecipe(
      DecodeSetupReply(Request(PackageType::kControlPackageSetupInputs, EncodeSetupInputs(names))),
      names, "CONTROL_PACKAGE_SETUP_INPUTS");
}

void RtdeClient::Start() {
  if (!DecodeAccepted(Request(PackageType::kControlPackageStart, ""))) {
    throw std::runtime_error("RTDE: CONTROL_PACKAGE_START refused");
  }
}

void RtdeClient::Pause() {
  if (!DecodeAccepted(Request(PackageType::kControlPackagePause, ""))) {
    throw std::runtime_error("RTDE: CONTROL_PACKAGE_PAUSE refused");
  }
}

void RtdeClient::SendInputs(const Recipe& recipe, const std::vector<FieldValue>& values) {
  stream_->WriteAll(
      EncodePackage(PackageType::kDataPackage, EncodeDataPackage(recipe.id, recipe.types, values)));
}

DataPackage RtdeClient::Receive(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (true) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    Package package = ReadPackage(*stream_, std::max(left, std::chrono::milliseconds(0)));
    if (package.type == PackageType::kTextMessage) {
      messages_.push_back(DecodeTextMessage(package.payload));
      continue;
    }
    if (package.type != PackageType::kDataPackage) continue;
    DataPackage data = DecodeDataPackage(package.payload, output_recipe_.types);
    if (data.recipe_id != output_recipe_.id) continue;
    return data;
  }
}

std::vector<TextMessage> RtdeClient::TakeMessages() {
  std::vector<TextMessage> out;
  out.swap(messages_);
  return out;
}

}  // namespace picking::robot::rtde
