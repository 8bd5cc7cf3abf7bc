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

}  // namespace
}  // namespace picking::runtime
