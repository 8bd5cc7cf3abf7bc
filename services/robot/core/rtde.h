#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <variant>
#include <vector>

#include "services/robot/core/byte_stream.h"

/// The UR Real-Time Data Exchange protocol (TCP port 30004), after Universal Robots' RTDE
/// guide: every package is uint16 size (of the whole package, header included, big-endian),
/// uint8 type, payload; all numbers big-endian.
namespace picking::robot::rtde {

inline constexpr std::uint16_t kPort = 30004;
inline constexpr std::uint16_t kProtocolVersion = 2;

enum class PackageType : std::uint8_t {
  kRequestProtocolVersion = 86,      // 'V'
  kGetUrControlVersion = 118,        // 'v'
  kTextMessage = 77,                 // 'M'
  kDataPackage = 85,                 // 'U'
  kControlPackageSetupOutputs = 79,  // 'O'
  kControlPackageSetupInputs = 73,   // 'I'
  kControlPackageStart = 83,         // 'S'
  kControlPackagePause = 80,         // 'P'
};

/// RTDE field types as named in recipe replies.
enum class FieldType {
  kBool,
  kUint8,
  kUint32,
  kUint64,
  kInt32,
  kDouble,
  kVector3d,
  kVector6d,
  kVector6Int32,
  kVector6Uint32
};
/// Parses "DOUBLE", "VECTOR6D", ... @throws std::invalid_argument naming the unknown type
/// (including the controller's "NOT_FOUND" and "IN_USE").
FieldType ParseFieldType(const std::string& name);
const char* FieldTypeName(FieldType type);
/// Encoded size in bytes.
std::size_t FieldSize(FieldType type);

using FieldValue = std::variant<bool, std::uint8_t, std::uint32_t, std::uint64_t, std::int32_t,
                                double, std::array<double, 3>, std::array<double, 6>,
                                std::array<std::int32_t, 6>, std::array<std::uint32_t, 6>>;

/// One package: type and raw payload (without the 3-byte header).
struct Package {
  PackageType type;
  std::string payload;
};

/// Header + payload. @throws std::invalid_argument if the package exceeds 65535 bytes.
std::string EncodePackage(PackageType type, const std::string& payload);
/// Reads one package. @throws StreamError (I/O, timeout) or std::runtime_error (size < 3).
Package ReadPackage(ByteStream& stream, std::chrono::milliseconds timeout);

/// A negotiated recipe: id, variable names and types.
struct Recipe {
  std::uint8_t id = 0;
  std::vector<std::string> names;
  std::vector<FieldType> types;
  /// Index of `name`. @throws std::out_of_range if absent.
  std::size_t IndexOf(const std::string& name) const;
};

struct ControllerVersion {
  std::uint32_t major = 0, minor = 0, bugfix = 0, build = 0;
};

/// TEXT_MESSAGE (protocol 2): uint8 length + message, uint8 length + source, uint8 level.
struct TextMessage {
  enum Level : std::uint8_t { kException = 0, kError = 1, kWarning = 2, kInfo = 3 };
  std::string message;
  std::string source;
  std::uint8_t level = kInfo;
};

/// A data package: recipe id and one value per recipe field.
struct DataPackage {
  std::uint8_t recipe_id = 0;
  std::vector<FieldValue> values;
};

// Payload encoders (client -> controller and, for tests and simulators, controller -> client).
std::string EncodeRequestProtocolVersion(std::uint16_t version);
std::string EncodeSetupOutputs(double frequency_hz, const std::vector<std::string>& names);
std::string EncodeSetupInputs(const std::vector<std::string>& names);
/// recipe id + values; @throws std::invalid_argument if a value's type does not match.
std::string EncodeDataPackage(std::uint8_t recipe_id, const std::vector<FieldType>& types,
                              const std::vector<FieldValue>& values);
std::string EncodeTextMessage(const TextMessage& message);
std::string EncodeControllerVersion(const ControllerVersion& version);
/// Reply to a setup request: uint8 recipe id + comma-separated type names.
std::string EncodeSetupReply(std::uint8_t recipe_id, const std::vector<std::string>& type_names);

// Payload decoders; @throws std::runtime_error naming the package on a malformed payload.
bool DecodeAccepted(const std::string& payload);
std::uint16_t DecodeRequestProtocolVersion(const std::string& payload);
ControllerVersion DecodeControllerVersion(const std::string& payload);
/// frequency (Hz) and names of a SETUP_OUTPUTS request.
std::pair<double, std::vector<std::string>> DecodeSetupOutputs(const std::string& payload);
std::vector<std::string> DecodeSetupInputs(const std::string& payload);
/// Recipe id and the raw type names of a setup reply.
std::pair<std::uint8_t, std::vector<std::string>> DecodeSetupReply(const std::string& payload);
DataPackage DecodeDataPackage(const std::string& payload, const std::vector<FieldType>& types);
TextMessage DecodeTextMessage(const std::string& payload);

/// Splits "a,b,c" at commas.
std::vector<std::string> SplitNames(const std::string& text);

/// RTDE client: negotiation, recipe setup, start/pause and data exchange over any
/// ByteStream. Not thread-safe except that Receive (one reader thread) may run while another
/// thread calls SendInputs.
class RtdeClient final {
 public:
  /// @param timeout for every reply.
  explicit RtdeClient(std::unique_ptr<ByteStream> stream,
                      std::chrono::milliseconds timeout = std::chrono::milliseconds(2000));

  /// REQUEST_PROTOCOL_VERSION; false if the controller refuses `version`.
  bool NegotiateProtocolVersion(std::uint16_t version = kProtocolVersion);
  ControllerVersion GetControllerVersion();
  /// CONTROL_PACKAGE_SETUP_OUTPUTS. @throws std::runtime_error naming variables the
  /// controller does not know (NOT_FOUND).
  Recipe SetupOutputs(double frequency_hz, const std::vector<std::string>& names);
  /// CONTROL_PACKAGE_SETUP_INPUTS. @throws std::runtime_error naming variables that are
  /// unknown or already in use (IN_USE).
  Recipe SetupInputs(const std::vector<std::string>& names);
  /// CONTROL_PACKAGE_START / PAUSE. @throws std::runtime_error if refused.
  void Start();
  void Pause();
  /// Sends a DATA_PACKAGE on an input recipe.
  void SendInputs(const Recipe& recipe, const std::vector<FieldValue>& values);
  /// The next data package of the output recipe; text messages met on the way are kept (see
  /// TakeMessages). @throws StreamError on I/O errors or timeout.
  DataPackage Receive(std::chrono::milliseconds timeout);
  /// Text messages received so far (and clears them).
  std::vector<TextMessage> TakeMessages();
  const Recipe& output_recipe() const { return output_recipe_; }
  void Close() { stream_->Close(); }

 private:
  // Sends a request and returns the payload of the first reply of the same type.
  std::string Request(PackageType type, const std::string& payload);

  std::unique_ptr<ByteStream> stream_;
  std::chrono::milliseconds timeout_;
  Recipe output_recipe_;
  std::vector<TextMessage> messages_;
};

}  // namespace picking::robot::rtde
