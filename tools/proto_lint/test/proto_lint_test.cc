#include "tools/proto_lint/proto_lint.h"

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <string>

#include <gtest/gtest.h>

namespace picking::proto_lint {
namespace {

namespace fs = std::filesystem;

// Compiles .proto files (name relative to the import root -> text) with protoc, the project's
// contracts on the import path, into a descriptor set with source info.
google::protobuf::FileDescriptorSet Compile(const std::map<std::string, std::string>& files) {
  const fs::path root =
      fs::path(testing::TempDir()) /
      ("proto_lint_" + std::string(testing::UnitTest::GetInstance()->current_test_info()->name()));
  fs::remove_all(root);
  std::string names;
  for (const auto& [name, text] : files) {
    fs::create_directories((root / name).parent_path());
    std::ofstream(root / name) << text;
    names += " " + name;
  }
  const fs::path out = root / "set.pb";
  const std::string command = std::string(PICKING_PROTOC) + " -I " + root.string() + " -I " +
                              PICKING_SOURCE_DIR +
                              "/proto --include_imports --include_source_info" +
                              " --descriptor_set_out=" + out.string() + names;
  EXPECT_EQ(std::system(command.c_str()), 0) << command;
  google::protobuf::FileDescriptorSet set;
  std::ifstream in(out, std::ios::binary);
  EXPECT_TRUE(set.ParseFromIstream(&in));
  return set;
}

std::multiset<std::string> Rules(const std::vector<Finding>& findings) {
  std::multiset<std::string> rules;
  for (const Finding& f : findings) rules.insert(f.rule);
  return rules;
}

std::string Dump(const std::vector<Finding>& findings) {
  std::string out;
  for (const Finding& f : findings) out += ToString(f) + "\n";
  return out;
}

TEST(UpperSnake, SplitsWords) {
  EXPECT_EQ(UpperSnake("ModelSymmetry"), "MODEL_SYMMETRY");
  EXPECT_EQ(UpperSnake("Method"), "METHOD");
  EXPECT_EQ(UpperSnake("RGBImage"), "RGB_IMAGE");
}

TEST(ProtoLint, AcceptsAContractThatFollowsTheRules) {
  const auto set = Compile({{"picking/good/v1/good.proto", R"(
syntax = "proto3";
package picking.good.v1;
import "picking/common/v1/data.proto";
import "picking/common/v1/geometry.proto";
service GoodService {
  rpc GetThing(GetThingRequest) returns (GetThingResponse);
  rpc StreamImages(StreamImagesRequest) returns (stream StreamImagesResponse);
}
enum ThingKind {
  THING_KIND_UNSPECIFIED = 0;
  THING_KIND_BOX = 1;
}
message GetThingRequest { string thing_name = 1; }
message GetThingResponse {
  ThingKind kind = 1;
  picking.common.v1.Pose X_base_thing = 2;
  picking.common.v1.Pose X_base_tcp_pregrasp = 3;
  oneof payload { string text = 4; uint32 count_2 = 5; }
  message Nested { enum Outcome { OUTCOME_UNSPECIFIED = 0; OUTCOME_OK = 1; } }
}
message StreamImagesRequest {}
message StreamImagesResponse { picking.common.v1.ImageChunk chunk = 1; }
)"}});
  const auto findings = Lint(set);
  EXPECT_TRUE(findings.empty()) << Dump(findings);
}

TEST(ProtoLint, RejectsABadContract) {
  const auto set = Compile({{"picking/bad/v1/bad.proto", R"(
syntax = "proto3";
package picking.wrong.v1;
import "picking/common/v1/data.proto";
import "picking/common/v1/geometry.proto";
service Bad {
  rpc GetThing(GetThingRequest) returns (stream picking.common.v1.ImageChunk);
  rpc other_thing(GetThingRequest) returns (Thing);
}
enum Color {
  RED = 0;
  COLOR_BLUE = 1;
  COLOR_green = 2;
}
message GetThingRequest {}
message Thing {
  string FooBar = 1;
  picking.common.v1.Pose sensor_pose = 2;
  optional int32 count = 3;
  oneof Choice { string a = 4; string b = 5; }
  string X_base_name = 6;
}
message bad_message {}
)"}});
  const auto findings = Lint(set);
  const std::multiset<std::string> want = {
      "PACKAGE_DIRECTORY_MATCH",
      "SERVICE_SUFFIX",
      "RPC_RESPONSE_STANDARD_NAME",   // GetThing -> ImageChunk.
      "RPC_PASCAL_CASE",              // other_thing.
      "RPC_REQUEST_STANDARD_NAME",    // other_thing takes GetThingRequest.
      "RPC_RESPONSE_STANDARD_NAME",   // other_thing -> Thing.
      "RPC_REQUEST_RESPONSE_UNIQUE",  // GetThingRequest twice.
      "ENUM_VALUE_PREFIX",            // RED.
      "ENUM_ZERO_VALUE_SUFFIX",       // RED.
      "ENUM_VALUE_UPPER_SNAKE_CASE",  // COLOR_green.
      "FIELD_LOWER_SNAKE_CASE",       // FooBar.
      "POSE_FIELD_NAME",              // sensor_pose.
      "FIELD_NO_PROTO3_OPTIONAL",     // count.
      "ONEOF_LOWER_SNAKE_CASE",       // Choice.
      "FIELD_LOWER_SNAKE_CASE",       // X_base_name is not a pose.
      "MESSAGE_PASCAL_CASE",          // bad_message.
  };
  EXPECT_EQ(Rules(findings), want) << Dump(findings);
  for (const Finding& f : findings) {
    EXPECT_EQ(f.file, "picking/bad/v1/bad.proto");
    EXPECT_GT(f.line, 0) << ToString(f);
  }
}

TEST(ProtoLint, ChecksTheSyntaxAndLeavesOtherFoldersAlone) {
  const auto set = Compile({{"picking/old/v1/old.proto", R"(
syntax = "proto2";
package picking.old.v1;
message Old { optional string name = 1; }
)"},
                            {"vendor/v1/vendor.proto", R"(
syntax = "proto3";
package vendor.v1;
enum color { red = 0; }
)"}});
  const auto findings = Lint(set);
  EXPECT_EQ(Rules(findings), std::multiset<std::string>{"FILE_SYNTAX_PROTO3"}) << Dump(findings);
}

TEST(ProtoLint, RefusesASetThatDoesNotBuild) {
  google::protobuf::FileDescriptorSet set;
  auto* file = set.add_file();
  file->set_name("picking/x/v1/x.proto");
  file->add_dependency("picking/missing/v1/missing.proto");
  EXPECT_THROW(Lint(set), std::invalid_argument);
}

}  // namespace
}  // namespace picking::proto_lint
