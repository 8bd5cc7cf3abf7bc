#include "tests/fuzz/request_mutator.h"

#include <google/protobuf/descriptor.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <memory>

namespace picking::testing {
namespace {

using google::protobuf::FieldDescriptor;
using google::protobuf::Message;
using google::protobuf::Reflection;

constexpr int kMaxDepth = 10;

std::string Describe(const FieldDescriptor* field, const std::string& what) {
  return field->name() + ": " + what;
}

// Copies of the existing elements appended until the field holds `target` elements.
void RepeatElements(Message& message, const FieldDescriptor* field, int target) {
  const Reflection* reflection = message.GetReflection();
  const int n = reflection->FieldSize(message, field);
  for (int i = n; i < target; ++i) {
    const int from = i % n;
    switch (field->cpp_type()) {
      case FieldDescriptor::CPPTYPE_MESSAGE:
        reflection->AddMessage(&message, field)
            ->CopyFrom(reflection->GetRepeatedMessage(message, field, from));
        break;
      case FieldDescriptor::CPPTYPE_DOUBLE:
        reflection->AddDouble(&message, field, reflection->GetRepeatedDouble(message, field, from));
        break;
      case FieldDescriptor::CPPTYPE_FLOAT:
        reflection->AddFloat(&message, field, reflection->GetRepeatedFloat(message, field, from));
        break;
      case FieldDescriptor::CPPTYPE_INT32:
        reflection->AddInt32(&message, field, reflection->GetRepeatedInt32(message, field, from));
        break;
      case FieldDescriptor::CPPTYPE_INT64:
        reflection->AddInt64(&message, field, reflection->GetRepeatedInt64(message, field, from));
        break;
      case FieldDescriptor::CPPTYPE_UINT32:
        reflection->AddUInt32(&message, field, reflection->GetRepeatedUInt32(message, field, from));
        break;
      case FieldDescriptor::CPPTYPE_UINT64:
        reflection->AddUInt64(&message, field, reflection->GetRepeatedUInt64(message, field, from));
        break;
      case FieldDescriptor::CPPTYPE_BOOL:
        reflection->AddBool(&message, field, reflection->GetRepeatedBool(message, field, from));
        break;
      case FieldDescriptor::CPPTYPE_ENUM:
        reflection->AddEnumValue(&message, field,
                                 reflection->GetRepeatedEnumValue(message, field, from));
        break;
      case FieldDescriptor::CPPTYPE_STRING:
        reflection->AddString(&message, field, reflection->GetRepeatedString(message, field, from));
        break;
    }
  }
}

}  // namespace

RequestMutator::RequestMutator(std::uint64_t seed, std::size_t max_bytes)
    : rng_(seed), max_bytes_(max_bytes) {}

void RequestMutator::AddDictionary(const std::vector<std::string>& words) {
  dictionary_.insert(dictionary_.end(), words.begin(), words.end());
}

std::size_t RequestMutator::Below(std::size_t n) {
  return n == 0 ? 0 : std::uniform_int_distribution<std::size_t>(0, n - 1)(rng_);
}

std::string RequestMutator::Mutate(Message& message) {
  const std::unique_ptr<Message> before(message.New());
  const int count = 1 + static_cast<int>(Below(3));
  std::string description;
  for (int i = 0; i < count; ++i) {
    before->CopyFrom(message);
    std::string what = MutateOnce(message, 0);
    if (message.ByteSizeLong() > max_bytes_) {  // Too big to send: undo this one.
      message.CopyFrom(*before);
      what = "(undone: over the size cap) " + what;
    }
    description += (description.empty() ? "" : "; ") + what;
  }
  return description;
}

const FieldDescriptor* RequestMutator::PickField(const Message& message) {
  const google::protobuf::Descriptor* descriptor = message.GetDescriptor();
  if (descriptor->field_count() == 0) return nullptr;
  // Mostly fields that are set, so that mutations reach deep into valid requests.
  std::vector<const FieldDescriptor*> set;
  message.GetReflection()->ListFields(message, &set);
  if (!set.empty() && Below(10) < 7) return set[Below(set.size())];
  return descriptor->field(static_cast<int>(Below(descriptor->field_count())));
}

std::string RequestMutator::MutateOnce(Message& message, int depth) {
  const FieldDescriptor* field = PickField(message);
  if (field == nullptr) return "(no fields)";
  if (field->is_repeated()) return MutateRepeated(message, field, depth);
  return MutateSingular(message, field, depth);
}

std::string RequestMutator::MutateSingular(Message& message, const FieldDescriptor* field,
                                           int depth) {
  const Reflection* reflection = message.GetReflection();
  if (field->cpp_type() != FieldDescriptor::CPPTYPE_MESSAGE) {
    if (Below(8) == 0) {
      reflection->ClearField(&message, field);
      return Describe(field, "cleared");
    }
    return SetExtremeScalar(message, field, /*append=*/false);
  }
  if (depth < kMaxDepth && Below(4) != 0) {
    return field->name() + "." +
           MutateOnce(*reflection->MutableMessage(&message, field), depth + 1);
  }
  reflection->ClearField(&message, field);
  return Describe(field, "cleared");
}

std::string RequestMutator::MutateRepeated(Message& message, const FieldDescriptor* field,
                                           int depth) {
  const Reflection* reflection = message.GetReflection();
  const int n = reflection->FieldSize(message, field);
  const bool is_message = field->cpp_type() == FieldDescriptor::CPPTYPE_MESSAGE;
  switch (Below(5)) {
    case 0:
      reflection->ClearField(&message, field);
      return Describe(field, "emptied");
    case 1:
      if (n > 0) {
        reflection->RemoveLast(&message, field);
        return Describe(field, "last removed");
      }
      [[fallthrough]];
    case 2:
      if (is_message) {
        Message* added = reflection->AddMessage(&message, field);
        return Describe(field, "added") +
               (depth < kMaxDepth && Below(2) == 0 ? " then " + MutateOnce(*added, depth + 1) : "");
      }
      return SetExtremeScalar(message, field, /*append=*/true);
    case 3:
      if (n > 0) return GrowRepeated(message, field);
      [[fallthrough]];
    default:
      if (n == 0) return MutateRepeated(message, field, depth);
      if (is_message && depth < kMaxDepth) {
        const int index = static_cast<int>(Below(n));
        return field->name() + "[" + std::to_string(index) + "]." +
               MutateOnce(*reflection->MutableRepeatedMessage(&message, field, index), depth + 1);
      }
      // A scalar element: replace the last with an extreme value.
      reflection->RemoveLast(&message, field);
      return SetExtremeScalar(message, field, /*append=*/true);
  }
}

std::string RequestMutator::GrowRepeated(Message& message, const FieldDescriptor* field) {
  static constexpr int kTargets[] = {7, 100, 5000, 100000};
  const int n = message.GetReflection()->FieldSize(message, field);
  const std::size_t bytes = message.ByteSizeLong();
  int target = kTargets[Below(std::size(kTargets))];
  // Keep the message under the size cap: the estimate assumes equal elements.
  const double per_element = static_cast<double>(bytes) / n;
  const int fit = static_cast<int>(static_cast<double>(max_bytes_) / std::max(per_element, 1.0));
  target = std::max(n, std::min(target, fit));
  RepeatElements(message, field, target);
  return Describe(field, "grown from " + std::to_string(n) + " to " + std::to_string(target));
}

std::string RequestMutator::SetExtremeScalar(Message& message, const FieldDescriptor* field,
                                             bool append) {
  const Reflection* reflection = message.GetReflection();
  std::string value;
  switch (field->cpp_type()) {
    case FieldDescriptor::CPPTYPE_DOUBLE: {
      const double v = ExtremeDouble();
      append ? reflection->AddDouble(&message, field, v)
             : reflection->SetDouble(&message, field, v);
      value = std::to_string(v);
      break;
    }
    case FieldDescriptor::CPPTYPE_FLOAT: {
      const float v = static_cast<float>(ExtremeDouble());
      append ? reflection->AddFloat(&message, field, v) : reflection->SetFloat(&message, field, v);
      value = std::to_string(v);
      break;
    }
    case FieldDescriptor::CPPTYPE_INT32: {
      const auto v = static_cast<std::int32_t>(ExtremeInt64(false, 32));
      append ? reflection->AddInt32(&message, field, v) : reflection->SetInt32(&message, field, v);
      value = std::to_string(v);
      break;
    }
    case FieldDescriptor::CPPTYPE_INT64: {
      const std::int64_t v = ExtremeInt64(false, 64);
      append ? reflection->AddInt64(&message, field, v) : reflection->SetInt64(&message, field, v);
      value = std::to_string(v);
      break;
    }
    case FieldDescriptor::CPPTYPE_UINT32: {
      const auto v = static_cast<std::uint32_t>(ExtremeInt64(true, 32));
      append ? reflection->AddUInt32(&message, field, v)
             : reflection->SetUInt32(&message, field, v);
      value = std::to_string(v);
      break;
    }
    case FieldDescriptor::CPPTYPE_UINT64: {
      const auto v = static_cast<std::uint64_t>(ExtremeInt64(true, 64));
      append ? reflection->AddUInt64(&message, field, v)
             : reflection->SetUInt64(&message, field, v);
      value = std::to_string(v);
      break;
    }
    case FieldDescriptor::CPPTYPE_BOOL: {
      const bool v = Below(2) == 0;
      append ? reflection->AddBool(&message, field, v) : reflection->SetBool(&message, field, v);
      value = v ? "true" : "false";
      break;
    }
    case FieldDescriptor::CPPTYPE_ENUM: {
      // A declared value, or a number the contract does not declare.
      const google::protobuf::EnumDescriptor* type = field->enum_type();
      const int v = Below(3) == 0
                        ? static_cast<int>(Below(1000)) - 500
                        : type->value(static_cast<int>(Below(type->value_count())))->number();
      append ? reflection->AddEnumValue(&message, field, v)
             : reflection->SetEnumValue(&message, field, v);
      value = std::to_string(v);
      break;
    }
    case FieldDescriptor::CPPTYPE_STRING: {
      const std::string v =
          field->type() == FieldDescriptor::TYPE_BYTES ? ExtremeBytes() : ExtremeString();
      append ? reflection->AddString(&message, field, v)
             : reflection->SetString(&message, field, v);
      value = std::to_string(v.size()) + " bytes";
      break;
    }
    case FieldDescriptor::CPPTYPE_MESSAGE:
      return Describe(field, "(message)");
  }
  return Describe(field, (append ? "appended " : "= ") + value);
}

double RequestMutator::ExtremeDouble() {
  static const double kValues[] = {std::numeric_limits<double>::quiet_NaN(),
                                   std::numeric_limits<double>::infinity(),
                                   -std::numeric_limits<double>::infinity(),
                                   1e308,
                                   -1e308,
                                   std::numeric_limits<double>::max(),
                                   std::numeric_limits<double>::lowest(),
                                   2e18,
                                   -2e18,
                                   1e9,
                                   -1e9,
                                   1e6,
                                   1e-300,
                                   -1e-300,
                                   std::numeric_limits<double>::denorm_min(),
                                   0.0,
                                   -0.0,
                                   -1.0,
                                   1.0};
  if (Below(4) == 0) return std::uniform_real_distribution<double>(-10.0, 10.0)(rng_);
  return kValues[Below(std::size(kValues))];
}

std::int64_t RequestMutator::ExtremeInt64(bool is_unsigned, int bits) {
  const std::int64_t max = bits == 32 ? (is_unsigned ? 0xffffffffLL : 0x7fffffffLL)
                                      : std::numeric_limits<std::int64_t>::max();
  const std::int64_t min =
      is_unsigned ? 0 : (bits == 32 ? -0x80000000LL : std::numeric_limits<std::int64_t>::min());
  const std::int64_t values[] = {0,       1,     2,     3,       -1,         max,   min,
                                 max - 1, 16384, 65536, 1 << 20, 1000000000, 100000};
  if (Below(4) == 0) return static_cast<std::int64_t>(Below(1000));
  return values[Below(std::size(values))];
}

std::string RequestMutator::ExtremeString() {
  static const std::vector<std::string> kValues = {
      "",
      "x",
      std::string(10000, 'a'),
      std::string(300, 'z'),
      "../../../../etc/passwd",
      "/dev/zero",
      "/proc/self/mem",
      "/tmp",
      std::string("a\0b", 3),
      "\xc3\xa9\xe2\x9c\x93\xe6\x97\xa5\xe6\x9c\xac",
      "%s%s%n%x",
      " \n\r\t ",
      "{",
      "{\"bin_contents\": {\"bin_A\": [1, 2]}}",
      "null",
  };
  if (!dictionary_.empty() && Below(3) == 0) return dictionary_[Below(dictionary_.size())];
  return kValues[Below(kValues.size())];
}

std::string RequestMutator::ExtremeBytes() {
  switch (Below(6)) {
    case 0:
      return "";
    case 1:
      return RandomBytes(64);
    case 2:
      return std::string(3, '\x7f');  // Not a whole float.
    case 3:
      return std::string(1 << 20, '\0');
    case 4: {  // Floats: NaN, infinities and huge values among ordinary ones.
      std::string out;
      const int count = 3 * static_cast<int>(1 + Below(400));
      for (int i = 0; i < count; ++i) {
        const float f = Below(3) == 0 ? static_cast<float>(ExtremeDouble())
                                      : std::uniform_real_distribution<float>(-2.0f, 2.0f)(rng_);
        char raw[sizeof f];
        std::memcpy(raw, &f, sizeof f);
        out.append(raw, sizeof f);
      }
      return out;
    }
    default:
      return RandomBytes(4096);
  }
}

std::string RequestMutator::RandomBytes(std::size_t max_length) {
  std::string out(Below(max_length + 1), '\0');
  for (char& c : out) c = static_cast<char>(Below(256));
  return out;
}

std::string RequestMutator::MutateBytes(const std::string& serialized) {
  std::string out = serialized;
  const int count = 1 + static_cast<int>(Below(4));
  for (int i = 0; i < count; ++i) {
    switch (out.empty() ? 3 : Below(4)) {
      case 0:  // Bit flip.
        out[Below(out.size())] ^= static_cast<char>(1u << Below(8));
        break;
      case 1:  // Truncate.
        out.resize(Below(out.size()));
        break;
      case 2: {  // Duplicate a slice.
        const std::size_t at = Below(out.size());
        const std::size_t length = std::min<std::size_t>(Below(64) + 1, out.size() - at);
        out.insert(at, out.substr(at, length));
        break;
      }
      default:  // Insert random bytes.
        out.insert(Below(out.size() + 1), RandomBytes(16));
        break;
    }
  }
  return out;
}

}  // namespace picking::testing
