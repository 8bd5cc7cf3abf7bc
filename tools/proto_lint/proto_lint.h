#pragma once

#include <string>
#include <vector>

#include <google/protobuf/descriptor.pb.h>

namespace picking::proto_lint {

/// One rule a contract breaks, where.
struct Finding {
  std::string file;  ///< The .proto file's name relative to the import root.
  int line = 0;      ///< 1-based; 0 when the descriptor set has no source info.
  std::string rule;  ///< e.g. "RPC_RESPONSE_STANDARD_NAME".
  std::string message;
};

/// "file:line: RULE: message".
std::string ToString(const Finding& finding);

struct Options {
  /// Only files whose name starts with this are linted (their imports are only loaded):
  /// the vendored google/ and grpc/ contracts are not the project's to rename.
  std::string file_prefix = "picking/";
};

/// Lints the contracts of a descriptor set (protoc --descriptor_set_out --include_imports,
/// with --include_source_info for line numbers). The rules (docs/protocols.md):
///   FILE_SYNTAX_PROTO3            syntax = "proto3".
///   PACKAGE_DIRECTORY_MATCH       package picking.<name>.v<N>, equal to the file's folder.
///   SERVICE_PASCAL_CASE, SERVICE_SUFFIX   PascalCase, ending in "Service".
///   RPC_PASCAL_CASE
///   RPC_REQUEST_STANDARD_NAME     the request of rpc Foo is FooRequest, of the same package.
///   RPC_RESPONSE_STANDARD_NAME    the response of rpc Foo is FooResponse, of the same package.
///   RPC_REQUEST_RESPONSE_UNIQUE   a message is the request or response of one RPC only.
///   MESSAGE_PASCAL_CASE, ENUM_PASCAL_CASE (nested ones too)
///   FIELD_LOWER_SNAKE_CASE        lower_snake_case, except poses (next rule).
///   POSE_FIELD_NAME               a picking.common.v1.Pose field is named after its frames,
///                                 X_<a>_<b>[_<qualifier>] in lower case (the pose of frame b
///                                 in frame a); only a message that names the frames in
///                                 `parent_frame` / `child_frame` fields may call it otherwise.
///   ONEOF_LOWER_SNAKE_CASE
///   FIELD_NO_PROTO3_OPTIONAL      no proto3 `optional` (Debian's Python grpc_tools refuses it).
///   ENUM_VALUE_UPPER_SNAKE_CASE
///   ENUM_VALUE_PREFIX             values start with the enum's name in UPPER_SNAKE_CASE and
///                                 "_" (FooBar -> FOO_BAR_).
///   ENUM_ZERO_VALUE_SUFFIX        the zero value is <PREFIX>_UNSPECIFIED.
/// Throws std::invalid_argument when the set does not build into a descriptor pool.
std::vector<Finding> Lint(const google::protobuf::FileDescriptorSet& set,
                          const Options& options = {});

/// PascalCase name to UPPER_SNAKE_CASE: "ModelSymmetry" -> "MODEL_SYMMETRY".
std::string UpperSnake(const std::string& pascal);

}  // namespace picking::proto_lint
