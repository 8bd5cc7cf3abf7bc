#include "libs/runtime/reflection_v1.h"

#include <google/protobuf/descriptor.h>
#include <google/protobuf/descriptor.pb.h>
#include <grpcpp/impl/server_builder_option.h>
#include <grpcpp/impl/server_builder_plugin.h>
#include <grpcpp/impl/server_initializer.h>
#include <grpcpp/server_builder.h>

#include <memory>
#include <string>
#include <unordered_set>
#include <vector>

#include "grpc/health/v1/health.pb.h"
#include "grpc/reflection/v1/reflection.grpc.pb.h"

namespace picking::runtime {
namespace {

namespace refl = ::grpc::reflection::v1;
using google::protobuf::Descriptor;
using google::protobuf::DescriptorPool;
using google::protobuf::FieldDescriptor;
using google::protobuf::FileDescriptor;

// The answers of grpc.reflection.v1, from the generated descriptor pool: the same lookups
// gRPC's own v1alpha service makes, so both versions give the same answers.
class ReflectionV1Service final : public refl::ServerReflection::Service {
 public:
  // `services` is the server's list of service names; it is filled while the server starts,
  // after this service is registered, and read at each list_services request.
  void SetServiceList(const std::vector<std::string>* services) { services_ = services; }

  grpc::Status ServerReflectionInfo(
      grpc::ServerContext* /*context*/,
      grpc::ServerReaderWriter<refl::ServerReflectionResponse, refl::ServerReflectionRequest>*
          stream) override {
    refl::ServerReflectionRequest request;
    while (stream->Read(&request)) {
      refl::ServerReflectionResponse response;
      response.set_valid_host(request.host());
      *response.mutable_original_request() = request;
      const grpc::Status status = Answer(request, &response);
      if (!status.ok()) {
        response.mutable_error_response()->set_error_code(status.error_code());
        response.mutable_error_response()->set_error_message(status.error_message());
      }
      if (!stream->Write(response)) break;
    }
    return grpc::Status::OK;
  }

 private:
  grpc::Status Answer(const refl::ServerReflectionRequest& request,
                      refl::ServerReflectionResponse* response) const {
    using R = refl::ServerReflectionRequest;
    switch (request.message_request_case()) {
      case R::kListServices:
        return ListServices(response->mutable_list_services_response());
      case R::kFileByFilename:
        return SendFile(pool_->FindFileByName(request.file_by_filename()),
                        "file '" + request.file_by_filename() + "' not found", response);
      case R::kFileContainingSymbol:
        return SendFile(pool_->FindFileContainingSymbol(request.file_containing_symbol()),
                        "symbol '" + request.file_containing_symbol() + "' not found", response);
      case R::kFileContainingExtension:
        return SendExtensionFile(request.file_containing_extension(), response);
      case R::kAllExtensionNumbersOfType:
        return ListExtensionNumbers(request.all_extension_numbers_of_type(),
                                    response->mutable_all_extension_numbers_response());
      default:
        return {grpc::StatusCode::UNIMPLEMENTED, "request type not supported"};
    }
  }

  grpc::Status ListServices(refl::ListServiceResponse* out) const {
    if (services_ == nullptr) return {grpc::StatusCode::NOT_FOUND, "services not found"};
    for (const std::string& name : *services_) out->add_service()->set_name(name);
    return grpc::Status::OK;
  }

  // The file and, depth first, every file it imports, each once. Files sent in earlier
  // answers on the stream are sent again (as gRPC's C++ implementation does): clients such
  // as grpcurl build the files of each answer on their own.
  grpc::Status SendFile(const FileDescriptor* file, const std::string& not_found,
                        refl::ServerReflectionResponse* response) const {
    if (file == nullptr) return {grpc::StatusCode::NOT_FOUND, not_found};
    std::unordered_set<std::string> sent;
    AddFileAndImports(file, &sent, response->mutable_file_descriptor_response());
    return grpc::Status::OK;
  }

  static void AddFileAndImports(const FileDescriptor* file, std::unordered_set<std::string>* sent,
                                refl::FileDescriptorResponse* out) {
    if (!sent->insert(file->name()).second) return;
    google::protobuf::FileDescriptorProto proto;
    file->CopyTo(&proto);
    proto.SerializeToString(out->add_file_descriptor_proto());
    for (int i = 0; i < file->dependency_count(); ++i) {
      AddFileAndImports(file->dependency(i), sent, out);
    }
  }

  grpc::Status SendExtensionFile(const refl::ExtensionRequest& request,
                                 refl::ServerReflectionResponse* response) const {
    const Descriptor* type = pool_->FindMessageTypeByName(request.containing_type());
    if (type == nullptr) return {grpc::StatusCode::NOT_FOUND, "type not found"};
    const FieldDescriptor* extension =
        pool_->FindExtensionByNumber(type, request.extension_number());
    if (extension == nullptr) return {grpc::StatusCode::NOT_FOUND, "extension not found"};
    return SendFile(extension->file(), "", response);
  }

  grpc::Status ListExtensionNumbers(const std::string& type_name,
                                    refl::ExtensionNumberResponse* out) const {
    const Descriptor* type = pool_->FindMessageTypeByName(type_name);
    if (type == nullptr) return {grpc::StatusCode::NOT_FOUND, "type not found"};
    std::vector<const FieldDescriptor*> extensions;
    pool_->FindAllExtensions(type, &extensions);
    out->set_base_type_name(type->full_name());
    for (const FieldDescriptor* e : extensions) out->add_extension_number(e->number());
    return grpc::Status::OK;
  }

  const DescriptorPool* pool_ = DescriptorPool::generated_pool();
  const std::vector<std::string>* services_ = nullptr;
};

// gRPC's default health service is built on its own internal messages, so nothing in the
// process refers to the protobuf classes of grpc.health.v1 and the linker drops them with
// their file descriptor. Naming one here keeps health.pb.o, which registers the file in the
// generated pool when the process starts.
void KeepHealthDescriptorLinked() { (void)grpc::health::v1::HealthCheckRequest::descriptor(); }

// Registers the service when the server is created and hands it the server's service list,
// the way gRPC's v1alpha reflection plugin does.
class ReflectionV1Plugin final : public grpc::ServerBuilderPlugin {
 public:
  std::string name() override { return "picking_reflection_v1"; }
  void InitServer(grpc::ServerInitializer* si) override {
    KeepHealthDescriptorLinked();
    si->RegisterService(service_);
  }
  void Finish(grpc::ServerInitializer* si) override {
    service_->SetServiceList(si->GetServiceList());
  }
  void ChangeArguments(const std::string& /*name*/, void* /*value*/) override {}
  bool has_sync_methods() const override { return true; }
  bool has_async_methods() const override { return false; }

 private:
  std::shared_ptr<ReflectionV1Service> service_ = std::make_shared<ReflectionV1Service>();
};

// A builder option is how a plugin is added to one builder only (gRPC's own reflection
// plugin is added to every builder of the process, by a static registration).
class ReflectionV1Option final : public grpc::ServerBuilderOption {
 public:
  void UpdateArguments(grpc::ChannelArguments* /*args*/) override {}
  void UpdatePlugins(std::vector<std::unique_ptr<grpc::ServerBuilderPlugin>>* plugins) override {
    plugins->push_back(std::make_unique<ReflectionV1Plugin>());
  }
};

}  // namespace

void AddReflectionV1(grpc::ServerBuilder& builder) {
  builder.SetOption(std::make_unique<ReflectionV1Option>());
}

}  // namespace picking::runtime
