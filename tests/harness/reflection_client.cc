#include "tests/harness/reflection_client.h"

#include <google/protobuf/descriptor.pb.h>
#include <grpcpp/client_context.h>

#include <chrono>
#include <stdexcept>

#include "grpc/reflection/v1alpha/reflection.grpc.pb.h"

namespace picking::testing {
namespace {

using grpc::reflection::v1alpha::ServerReflection;
using grpc::reflection::v1alpha::ServerReflectionRequest;
using grpc::reflection::v1alpha::ServerReflectionResponse;

ServerReflectionResponse Ask(const std::shared_ptr<grpc::Channel>& channel,
                             const ServerReflectionRequest& request) {
  auto stub = ServerReflection::NewStub(channel);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  auto stream = stub->ServerReflectionInfo(&ctx);
  if (!stream->Write(request)) throw std::runtime_error("reflection: write failed");
  stream->WritesDone();
  ServerReflectionResponse response;
  if (!stream->Read(&response)) throw std::runtime_error("reflection: no response");
  ServerReflectionResponse ignored;
  while (stream->Read(&ignored)) {
  }
  const grpc::Status status = stream->Finish();
  if (!status.ok()) throw std::runtime_error("reflection: " + status.error_message());
  if (response.has_error_response()) {
    throw std::runtime_error("reflection error: " + response.error_response().error_message());
  }
  return response;
}

}  // namespace

std::vector<std::string> ListServicesByReflection(const std::shared_ptr<grpc::Channel>& channel) {
  ServerReflectionRequest request;
  request.set_list_services("");
  const auto response = Ask(channel, request);
  std::vector<std::string> names;
  for (const auto& s : response.list_services_response().service()) names.push_back(s.name());
  return names;
}

std::vector<std::string> FilesContainingSymbol(const std::shared_ptr<grpc::Channel>& channel,
                                               const std::string& symbol) {
  ServerReflectionRequest request;
  request.set_file_containing_symbol(symbol);
  const auto response = Ask(channel, request);
  std::vector<std::string> files;
  for (const auto& bytes : response.file_descriptor_response().file_descriptor_proto()) {
    google::protobuf::FileDescriptorProto fd;
    if (!fd.ParseFromString(bytes)) throw std::runtime_error("reflection: bad descriptor");
    files.push_back(fd.name());
  }
  return files;
}

}  // namespace picking::testing
