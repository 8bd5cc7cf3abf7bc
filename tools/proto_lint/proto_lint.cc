#include "tools/proto_lint/proto_lint.h"

#include <cctype>
#include <map>
#include <regex>
#include <stdexcept>
#include <utility>

#include <google/protobuf/descriptor.h>

namespace picking::proto_lint {
namespace {

namespace gp = google::protobuf;

const std::regex kPascal("^[A-Z][A-Za-z0-9]*$");
const std::regex kLowerSnake("^[a-z][a-z0-9]*(_[a-z0-9]+)*$");
const std::regex kUpperSnake("^[A-Z][A-Z0-9]*(_[A-Z0-9]+)*$");
// X_<a>_<b>[_<qualifier>...]: the pose of frame b in frame a, frames in lower case.
const std::regex kPoseName("^X_[a-z][a-z0-9]*(_[a-z][a-z0-9]*)+$");
const std::regex kPackage("^picking\\.[a-z][a-z0-9_]*\\.v[0-9]+$");
constexpr const char* kPoseType = "picking.common.v1.Pose";

class ErrorCollector : public gp::DescriptorPool::ErrorCollector {
 public:
  void AddError(const std::string& filename, const std::string& element_name,
                const gp::Message* /*descriptor*/, ErrorLocation /*location*/,
                const std::string& message) override {
    if (!errors_.empty()) errors_ += "; ";
    errors_ += filename + " (" + element_name + "): " + message;
  }
  const std::string& errors() const { return errors_; }

 private:
  std::string errors_;
};

template <typename D>
int LineOf(const D* descriptor) {
  gp::SourceLocation location;
  return descriptor->GetSourceLocation(&location) ? location.start_line + 1 : 0;
}

int FileLine(const gp::FileDescriptor* file, int field_number) {
  gp::SourceLocation location;
  return file->GetSourceLocation({field_number}, &location) ? location.start_line + 1 : 0;
}

class Linter {
 public:
  explicit Linter(std::vector<Finding>* out) : out_(out) {}

  void File(const gp::FileDescriptor* file) {
    const std::string& name = file->name();
    if (file->syntax() != gp::FileDescriptor::SYNTAX_PROTO3) {
      Add(file, FileLine(file, 12), "FILE_SYNTAX_PROTO3", "the file is not proto3");
    }
    const std::size_t slash = name.rfind('/');
    std::string folder = slash == std::string::npos ? "" : name.substr(0, slash);
    for (char& c : folder) {
      if (c == '/') c = '.';
    }
    if (!std::regex_match(file->package(), kPackage) || file->package() != folder) {
      Add(file, FileLine(file, 2), "PACKAGE_DIRECTORY_MATCH",
          "package '" + file->package() +
              "' must be picking.<name>.v<N> and equal to the folder ('" + folder + "')");
    }
    for (int i = 0; i < file->message_type_count(); ++i) Message(file->message_type(i));
    for (int i = 0; i < file->enum_type_count(); ++i) Enum(file->enum_type(i));
    for (int i = 0; i < file->service_count(); ++i) Service(file->service(i));
  }

  // After every file: a message that is the request or response of several RPCs.
  void Uses() {
    for (const auto& [message, uses] : uses_) {
      if (uses.size() < 2) continue;
      std::string list;
      for (const auto& use : uses) list += (list.empty() ? "" : ", ") + use.second;
      const gp::MethodDescriptor* second = uses[1].first;
      Add(second->file(), LineOf(second), "RPC_REQUEST_RESPONSE_UNIQUE",
          "'" + message + "' is used by several RPCs: " + list);
    }
  }

 private:
  void Add(const gp::FileDescriptor* file, int line, std::string rule, std::string message) {
    out_->push_back(Finding{file->name(), line, std::move(rule), std::move(message)});
  }

  void Message(const gp::Descriptor* message) {
    if (!std::regex_match(message->name(), kPascal)) {
      Add(message->file(), LineOf(message), "MESSAGE_PASCAL_CASE",
          "message '" + message->full_name() + "' is not PascalCase");
    }
    // A message that names the frames of its pose in fields (FramedPose) may call the pose
    // what it likes.
    const bool names_frames = message->FindFieldByName("parent_frame") != nullptr &&
                              message->FindFieldByName("child_frame") != nullptr;
    for (int i = 0; i < message->field_count(); ++i) Field(message->field(i), names_frames);
    for (int i = 0; i < message->real_oneof_decl_count(); ++i) {
      const gp::OneofDescriptor* oneof = message->oneof_decl(i);
      if (!std::regex_match(oneof->name(), kLowerSnake)) {
        Add(message->file(), LineOf(oneof), "ONEOF_LOWER_SNAKE_CASE",
            "oneof '" + oneof->full_name() + "' is not lower_snake_case");
      }
    }
    for (int i = 0; i < message->nested_type_count(); ++i) {
      if (message->nested_type(i)->options().map_entry()) continue;
      Message(message->nested_type(i));
    }
    for (int i = 0; i < message->enum_type_count(); ++i) Enum(message->enum_type(i));
  }

  void Field(const gp::FieldDescriptor* field, bool message_names_frames) {
    const std::string where = "field '" + field->full_name() + "'";
    const bool is_pose =
        field->message_type() != nullptr && field->message_type()->full_name() == kPoseType;
    if (is_pose && !message_names_frames) {
      if (!std::regex_match(field->name(), kPoseName)) {
        Add(field->file(), LineOf(field), "POSE_FIELD_NAME",
            where + " is a pose: name it X_<a>_<b> after its frames (lower case)");
      }
    } else if (!std::regex_match(field->name(), kLowerSnake)) {
      Add(field->file(), LineOf(field), "FIELD_LOWER_SNAKE_CASE",
          where + " is not lower_snake_case" +
              (field->name().rfind("X_", 0) == 0 ? " (X_<a>_<b> is for poses only)" : ""));
    }
    // proto3 `optional` is a field alone in a synthetic oneof.
    if (field->containing_oneof() != nullptr && field->real_containing_oneof() == nullptr) {
      Add(field->file(), LineOf(field), "FIELD_NO_PROTO3_OPTIONAL",
          where + " is proto3 optional, which Debian's Python grpc_tools refuses");
    }
  }

  void Enum(const gp::EnumDescriptor* e) {
    if (!std::regex_match(e->name(), kPascal)) {
      Add(e->file(), LineOf(e), "ENUM_PASCAL_CASE",
          "enum '" + e->full_name() + "' is not PascalCase");
    }
    const std::string prefix = UpperSnake(e->name()) + "_";
    for (int i = 0; i < e->value_count(); ++i) {
      const gp::EnumValueDescriptor* value = e->value(i);
      const std::string where = "enum value '" + value->full_name() + "'";
      if (!std::regex_match(value->name(), kUpperSnake)) {
        Add(e->file(), LineOf(value), "ENUM_VALUE_UPPER_SNAKE_CASE",
            where + " is not UPPER_SNAKE_CASE");
      }
      if (value->name().rfind(prefix, 0) != 0) {
        Add(e->file(), LineOf(value), "ENUM_VALUE_PREFIX",
            where + " does not start with '" + prefix + "'");
      }
      if (value->number() == 0 && value->name() != prefix + "UNSPECIFIED") {
        Add(e->file(), LineOf(value), "ENUM_ZERO_VALUE_SUFFIX",
            where + " is the zero value: name it " + prefix + "UNSPECIFIED");
      }
    }
  }

  void Service(const gp::ServiceDescriptor* service) {
    if (!std::regex_match(service->name(), kPascal)) {
      Add(service->file(), LineOf(service), "SERVICE_PASCAL_CASE",
          "service '" + service->full_name() + "' is not PascalCase");
    }
    const std::string suffix = "Service";
    if (service->name().size() <= suffix.size() ||
        service->name().compare(service->name().size() - suffix.size(), suffix.size(), suffix) !=
            0) {
      Add(service->file(), LineOf(service), "SERVICE_SUFFIX",
          "service '" + service->full_name() + "' does not end in 'Service'");
    }
    for (int i = 0; i < service->method_count(); ++i) Method(service->method(i));
  }

  void Method(const gp::MethodDescriptor* method) {
    const std::string rpc = method->service()->name() + "." + method->name();
    if (!std::regex_match(method->name(), kPascal)) {
      Add(method->file(), LineOf(method), "RPC_PASCAL_CASE", "rpc '" + rpc + "' is not PascalCase");
    }
    const std::string& package = method->file()->package();
    const auto check = [&](const gp::Descriptor* type, const std::string& kind,
                           const std::string& rule) {
      const std::string want = package + "." + method->name() + kind;
      if (type->full_name() != want) {
        Add(method->file(), LineOf(method), rule,
            "rpc '" + rpc + "' " + (kind == "Request" ? "takes" : "returns") + " '" +
                type->full_name() + "': make it '" + want + "'");
      }
      uses_[type->full_name()].emplace_back(method, rpc + " (" + kind + ")");
    };
    check(method->input_type(), "Request", "RPC_REQUEST_STANDARD_NAME");
    check(method->output_type(), "Response", "RPC_RESPONSE_STANDARD_NAME");
  }

  std::vector<Finding>* out_;
  // Message full name -> the RPCs that take or return it, in lint order.
  std::map<std::string, std::vector<std::pair<const gp::MethodDescriptor*, std::string>>> uses_;
};

}  // namespace

std::string ToString(const Finding& finding) {
  return finding.file + ":" + std::to_string(finding.line) + ": " + finding.rule + ": " +
         finding.message;
}

std::string UpperSnake(const std::string& pascal) {
  std::string out;
  for (std::size_t i = 0; i < pascal.size(); ++i) {
    const unsigned char c = pascal[i];
    if (i > 0 && std::isupper(c)) {
      const unsigned char prev = pascal[i - 1];
      const bool next_lower =
          i + 1 < pascal.size() && std::islower(static_cast<unsigned char>(pascal[i + 1]));
      if (std::islower(prev) || std::isdigit(prev) || (std::isupper(prev) && next_lower)) {
        out += '_';
      }
    }
    out += static_cast<char>(std::toupper(c));
  }
  return out;
}

std::vector<Finding> Lint(const gp::FileDescriptorSet& set, const Options& options) {
  gp::DescriptorPool pool;
  ErrorCollector errors;
  std::vector<const gp::FileDescriptor*> files;
  for (const gp::FileDescriptorProto& proto : set.file()) {
    const gp::FileDescriptor* file = pool.BuildFileCollectingErrors(proto, &errors);
    if (file == nullptr) {
      throw std::invalid_argument("descriptor set does not build: " + errors.errors());
    }
    if (file->name().rfind(options.file_prefix, 0) == 0) files.push_back(file);
  }
  std::vector<Finding> findings;
  Linter linter(&findings);
  for (const gp::FileDescriptor* file : files) linter.File(file);
  linter.Uses();
  return findings;
}

}  // namespace picking::proto_lint
