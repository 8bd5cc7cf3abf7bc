#include "libs/runtime/status.h"

#include <gtest/gtest.h>

namespace picking::runtime {
namespace {

TEST(StatusTest, MapsEachErrorTypeToItsCode) {
  auto code_of = [](auto thrower) {
    return Guard([&]() -> grpc::Status {
             thrower();
             return grpc::Status::OK;
           })
        .error_code();
  };
  EXPECT_EQ(code_of([] { throw std::invalid_argument("x"); }), grpc::INVALID_ARGUMENT);
  EXPECT_EQ(code_of([] { throw NotFoundError("x"); }), grpc::NOT_FOUND);
  EXPECT_EQ(code_of([] { throw PreconditionError("x"); }), grpc::FAILED_PRECONDITION);
  EXPECT_EQ(code_of([] { throw UnavailableError("x"); }), grpc::UNAVAILABLE);
  EXPECT_EQ(code_of([] { throw TimeoutError("x"); }), grpc::DEADLINE_EXCEEDED);
  EXPECT_EQ(code_of([] { throw DataLossError("x"); }), grpc::DATA_LOSS);
  EXPECT_EQ(code_of([] { throw ResourceExhaustedError("x"); }), grpc::RESOURCE_EXHAUSTED);
  EXPECT_EQ(code_of([] { throw std::runtime_error("x"); }), grpc::INTERNAL);
  EXPECT_EQ(code_of([] {}), grpc::OK);
}

TEST(StatusTest, KeepsTheMessage) {
  const grpc::Status s = Guard([]() -> grpc::Status { throw NotFoundError("unknown item 'foo'"); });
  EXPECT_EQ(s.error_message(), "unknown item 'foo'");
}

TEST(StatusTest, CutsLongMessagesToAKilobyte) {
  const std::string item(10000, 'x');
  const grpc::Status s =
      Guard([&]() -> grpc::Status { throw NotFoundError("unknown item '" + item + "'"); });
  EXPECT_EQ(s.error_code(), grpc::NOT_FOUND);
  EXPECT_LE(s.error_message().size(), kMaxStatusMessageBytes);
  EXPECT_EQ(s.error_message().substr(0, 14), "unknown item '");
  EXPECT_EQ(s.error_message().substr(s.error_message().size() - 3), "...");
}

TEST(StatusTest, CutsReturnedStatusesToo) {
  const grpc::Status s = Guard([] { return InvalidArgument(std::string(5000, 'y')); });
  EXPECT_EQ(s.error_code(), grpc::INVALID_ARGUMENT);
  EXPECT_EQ(s.error_message().size(), kMaxStatusMessageBytes);
}

TEST(StatusTest, CutMessageKeepsShortTextAndUtf8Characters) {
  EXPECT_EQ(CutMessage("short", 10), "short");
  EXPECT_EQ(CutMessage("abcdefghij", 10), "abcdefghij");
  EXPECT_EQ(CutMessage("abcdefghijk", 10), "abcdefg...");
  // "\xc3\xa9" is one character: a cut inside it drops the whole character.
  EXPECT_EQ(CutMessage("abcdef\xc3\xa9zzz", 10), "abcdef...");
  EXPECT_EQ(Quoted(std::string(1000, 'n')).size(), kMaxQuotedBytes);
}

}  // namespace
}  // namespace picking::runtime
