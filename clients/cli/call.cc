#include "clients/cli/call.h"

#include <google/protobuf/descriptor.h>
#include <google/protobuf/descriptor.pb.h>
#include <google/protobuf/descriptor_database.h>
#include <google/protobuf/dynamic_message.h>
#include <google/protobuf/util/json_util.h>
#include <grpcpp/create_channel.h>
#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/support/byte_buffer.h>

#include <chrono>
#include <memory>
#include <set>
#include <vector>

#include "grpc/reflection/v1/reflection.grpc.pb.h"
#include "libs/runtime/status.h"

namespace picking::cli {
namespace {

namespace refl = ::grpc::reflection::v1;
namespace gp = ::google::protobuf;

constexpr int kOk = 0, kUsage = 2, kRpcError = 3;

// A failure with the exit status it maps to.
struct Failure {
  int exit_status;
  std::string message;
};

// The descriptors a server's reflection service sends, kept in a database that a
// DescriptorPool builds from on demand. One reflection stream serves every question.
class ReflectedDescriptors {
 public:
  explicit ReflectedDescriptors(const std::shared_ptr<grpc::Channel>& channel)
      : stub_(refl::ServerReflection::NewStub(channel)) {
    // Reflection answers at once; a deadline keeps a server that never answers from hanging
    // the command line.
    context_.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
    stream_ = stub_->ServerReflectionInfo(&context_);
  }
  ReflectedDescriptors(const ReflectedDescriptors&) = delete;
  ReflectedDescriptors& operator=(const ReflectedDescriptors&) = delete;

  // Ends the stream cleanly (the server sees the end of the requests, not a cancellation).
  ~ReflectedDescriptors() {
    if (finished_) return;
    stream_->WritesDone();
    refl::ServerReflectionResponse ignored;
    while (stream_->Read(&ignored)) {
    }
    stream_->Finish();
  }

  // Fetches the file defining `symbol` and every file it imports. Returns a failure, or an
  // empty message.
  Failure FetchSymbol(const std::string& symbol) {
    refl::ServerReflectionRequest request;
    request.set_file_containing_symbol(symbol);
    if (Failure f = Fetch(request); !f.message.empty()) return f;
    return FetchMissingImports();
  }

  const gp::DescriptorPool& pool() const { return pool_; }

 private:
  // Asks one question and adds the files of the answer to the database.
  Failure Fetch(const refl::ServerReflectionRequest& request) {
    refl::ServerReflectionResponse response;
    if (!stream_->Write(request) || !stream_->Read(&response)) {
      stream_->WritesDone();
      const grpc::Status status = stream_->Finish();
      finished_ = true;
      return {kRpcError, std::string("reflection (grpc.reflection.v1) failed: ") +
                             status.error_message() + " (" +
                             runtime::StatusCodeName(status.error_code()) + ")"};
    }
    if (response.has_error_response()) {
      const auto& e = response.error_response();
      const auto code = static_cast<grpc::StatusCode>(e.error_code());
      return {code == grpc::StatusCode::NOT_FOUND ? kUsage : kRpcError,
              "reflection: " + e.error_message() + " (" + runtime::StatusCodeName(code) + ")"};
    }
    for (const std::string& bytes : response.file_descriptor_response().file_descriptor_proto()) {
      gp::FileDescriptorProto file;
      if (!file.ParseFromString(bytes)) return {kRpcError, "reflection sent a bad descriptor"};
      if (known_.insert(file.name()).second) database_.Add(file);
      for (const std::string& dep : file.dependency()) imports_.insert(dep);
    }
    return {kOk, ""};
  }

  // A server may leave out files it sent earlier on the stream or that it expects the client
  // to have; ask for each import not received yet, until none is missing.
  Failure FetchMissingImports() {
    for (bool again = true; again;) {
      again = false;
      for (const std::string& name : std::set<std::string>(imports_)) {
        if (known_.count(name) != 0) continue;
        refl::ServerReflectionRequest request;
        request.set_file_by_filename(name);
        if (Failure f = Fetch(request); !f.message.empty()) return f;
        again = true;
      }
    }
    return {kOk, ""};
  }

  std::unique_ptr<refl::ServerReflection::Stub> stub_;
  grpc::ClientContext context_;
  std::unique_ptr<
      grpc::ClientReaderWriter<refl::ServerReflectionRequest, refl::ServerReflectionResponse>>
      stream_;
  bool finished_ = false;
  std::set<std::string> known_, imports_;
  gp::SimpleDescriptorDatabase database_;
  gp::DescriptorPool pool_{&database_};
};

// Splits "pkg.Service/Method" (or grpcurl's "pkg.Service.Method") into its two names.
bool SplitMethod(const std::string& full, std::string* service, std::string* method) {
  std::size_t cut = full.rfind('/');
  if (cut == std::string::npos) cut = full.rfind('.');
  if (cut == std::string::npos || cut == 0 || cut + 1 == full.size()) return false;
  *service = full.substr(full[0] == '/' ? 1 : 0, cut - (full[0] == '/' ? 1 : 0));
  *method = full.substr(cut + 1);
  return true;
}

std::string MethodList(const gp::ServiceDescriptor& service) {
  std::string names;
  for (int i = 0; i < service.method_count(); ++i) {
    names += (i == 0 ? "" : ", ") + service.method(i)->name();
  }
  return names;
}

grpc::ByteBuffer ToBuffer(const gp::Message& message) {
  std::string bytes;
  message.SerializeToString(&bytes);
  grpc::Slice slice(bytes);
  return grpc::ByteBuffer(&slice, 1);
}

bool FromBuffer(const grpc::ByteBuffer& buffer, gp::Message* message) {
  std::vector<grpc::Slice> slices;
  if (!buffer.Dump(&slices).ok()) return false;
  std::string bytes;
  for (const grpc::Slice& s : slices) {
    bytes.append(reinterpret_cast<const char*>(s.begin()), s.size());
  }
  return message->ParseFromString(bytes);
}

// Waits for the one operation in flight on `cq`; returns whether it succeeded.
bool Await(grpc::CompletionQueue& cq) {
  void* tag = nullptr;
  bool ok = false;
  return cq.Next(&tag, &ok) && ok;
}

// Sends `request` to `path` ("/pkg.Service/Method") as the one request of a generic stream,
// which serves unary and streaming methods alike, and prints each reply as a JSON line.
Failure Invoke(const std::shared_ptr<grpc::Channel>& channel, const std::string& path,
               const gp::Message& request, const gp::Message& reply_prototype, std::ostream& out) {
  grpc::GenericStub stub(channel);
  grpc::CompletionQueue cq;
  grpc::ClientContext context;
  auto call = stub.PrepareCall(&context, path, &cq);
  call->StartCall(nullptr);
  bool live = Await(cq);
  if (live) {
    call->Write(ToBuffer(request), nullptr);
    live = Await(cq);
  }
  if (live) {
    call->WritesDone(nullptr);
    live = Await(cq);
  }
  gp::util::JsonPrintOptions print;
  print.preserve_proto_field_names = true;
  std::unique_ptr<gp::Message> reply(reply_prototype.New());
  Failure failure{kOk, ""};
  for (grpc::ByteBuffer buffer; live;) {
    call->Read(&buffer, nullptr);
    if (!(live = Await(cq))) break;
    std::string json;
    if (!FromBuffer(buffer, reply.get()) ||
        !gp::util::MessageToJsonString(*reply, &json, print).ok()) {
      failure = {kRpcError, "a reply is not a " + reply_prototype.GetTypeName()};
      context.TryCancel();
      break;
    }
    out << json << "\n" << std::flush;
  }
  grpc::Status status;
  call->Finish(&status, nullptr);
  Await(cq);
  if (!failure.message.empty()) return failure;
  if (!status.ok()) {
    return {kRpcError, path.substr(1) + ": " + status.error_message() + " (" +
                           runtime::StatusCodeName(status.error_code()) + ")"};
  }
  return {kOk, ""};
}

Failure CallByReflection(const std::string& address, const std::string& full_method,
                         const std::string& json, std::ostream& out) {
  std::string service_name, method_name;
  if (!SplitMethod(full_method, &service_name, &method_name)) {
    return {kUsage, "expected SERVICE/METHOD (e.g. grpc.health.v1.Health/Check), got '" +
                        full_method + "'"};
  }
  auto channel = grpc::CreateChannel(address, grpc::InsecureChannelCredentials());
  ReflectedDescriptors descriptors(channel);
  if (Failure f = descriptors.FetchSymbol(service_name); !f.message.empty()) {
    if (f.exit_status == kUsage)
      f.message = "unknown service '" + service_name + "' at " + address + " (" + f.message + ")";
    return f;
  }
  const gp::ServiceDescriptor* service = descriptors.pool().FindServiceByName(service_name);
  if (service == nullptr) return {kUsage, "'" + service_name + "' is not a service"};
  const gp::MethodDescriptor* method = service->FindMethodByName(method_name);
  if (method == nullptr) {
    return {kUsage, "unknown method '" + method_name + "' of " + service_name +
                        " (its methods: " + MethodList(*service) + ")"};
  }
  gp::DynamicMessageFactory factory(&descriptors.pool());
  std::unique_ptr<gp::Message> request(factory.GetPrototype(method->input_type())->New());
  const auto parsed = gp::util::JsonStringToMessage(json.empty() ? "{}" : json, request.get());
  if (!parsed.ok()) {
    return {kUsage, "the request is not a " + method->input_type()->full_name() +
                        " in JSON: " + std::string(parsed.message())};
  }
  return Invoke(channel, "/" + service->full_name() + "/" + method->name(), *request,
                *factory.GetPrototype(method->output_type()), out);
}

}  // namespace

int Call(const std::string& address, const std::string& method, const std::string& json,
         std::ostream& out, std::ostream& err) {
  const Failure f = CallByReflection(address, method, json, out);
  if (!f.message.empty()) err << "picking: " << f.message << "\n";
  return f.exit_status;
}

}  // namespace picking::cli
