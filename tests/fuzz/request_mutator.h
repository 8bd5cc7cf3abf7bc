#pragma once

#include <google/protobuf/message.h>

#include <cstdint>
#include <random>
#include <string>
#include <vector>

namespace picking::testing {

/// Structure-aware mutations of protobuf requests, through reflection, so one mutator
/// serves every RPC of every contract: a field anywhere in the message (oneof members
/// included) is replaced by an extreme value of its type (NaN, infinities, 1e308, 2e18,
/// denormals; 0, -1, the type's extremes; empty, 10 kB, path-like and non-ASCII strings;
/// empty, odd-sized and 1 MB byte blobs; unknown enum numbers), cleared, or, when repeated,
/// emptied, extended or multiplied. Byte-level mutations (bit flips, truncation, splices,
/// random bytes) cover what a structured message cannot say.
///
/// Deterministic for a given seed. Messages never grow past `max_bytes` when serialized.
class RequestMutator final {
 public:
  explicit RequestMutator(std::uint64_t seed, std::size_t max_bytes = 8 << 20);

  /// Strings the contracts give meaning to (item names, bins, session names), mixed in
  /// with the extreme strings so that mutations also reach past name lookups.
  void AddDictionary(const std::vector<std::string>& words);

  /// Applies one to three structural mutations; returns a one-line description of them.
  std::string Mutate(google::protobuf::Message& message);

  /// Bit flips, truncation, duplicated or inserted bytes over `serialized`.
  std::string MutateBytes(const std::string& serialized);
  /// Up to `max_length` uniformly random bytes.
  std::string RandomBytes(std::size_t max_length);

  std::mt19937_64& rng() { return rng_; }
  /// A uniform integer in [0, n).
  std::size_t Below(std::size_t n);

 private:
  std::string MutateOnce(google::protobuf::Message& message, int depth);
  const google::protobuf::FieldDescriptor* PickField(const google::protobuf::Message& message);
  std::string MutateSingular(google::protobuf::Message& message,
                             const google::protobuf::FieldDescriptor* field, int depth);
  std::string MutateRepeated(google::protobuf::Message& message,
                             const google::protobuf::FieldDescriptor* field, int depth);
  std::string GrowRepeated(google::protobuf::Message& message,
                           const google::protobuf::FieldDescriptor* field);
  /// Sets (singular) or appends (repeated) an extreme scalar value of the field's type.
  std::string SetExtremeScalar(google::protobuf::Message& message,
                               const google::protobuf::FieldDescriptor* field, bool append);

  double ExtremeDouble();
  std::int64_t ExtremeInt64(bool is_unsigned, int bits);
  std::string ExtremeString();
  std::string ExtremeBytes();

  std::mt19937_64 rng_;
  std::size_t max_bytes_;
  std::vector<std::string> dictionary_;
};

}  // namespace picking::testing
