#include "tests/harness/reflection_client.h"

#include <google/protobuf/descriptor.pb.h>
#include <grpcpp/client_context.h>

#include <chrono>
#include <stdexcept>

#include "grpc/reflection/v1/reflection.grpc.pb.h"
#include "grpc/reflection/v1alpha/reflection.grpc.pb.h"

namespace picking::testing {
namespace {

namespace v1 = ::grpc::reflection::v1;
namespace v1alpha = ::grpc::reflection::v1alpha;

// The two versions have the same messages in different packages: one implementation, over
// the generated types of either. Asks one question on a new stream and returns the answer.
template <typename ServerReflection, typename Request, typename Response>
Response Ask(const std::shared_ptr<grpc::Channel>& channel, const Request& request) {
  auto stub = ServerReflection::NewStub(channel);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  auto stream = stub->ServerReflectionInfo(&ctx);
  if (!stream->Write(request)) throw std::runtime_error("reflection: write failed");
  stream->WritesDone();
  Response response;
  if (!stream->Read(&response)) throw std::runtime_error("reflection: no response");
  Response ignored;
  while (stream->Read(&ignored)) {
  }
  const grpc::Status status = stream->Finish();
  if (!status.ok()) throw std::runtime_error("reflection: " + status.error_message());
  if (response.has_error_response()) {
    throw std::runtime_error("reflection error: " + response.error_response().error_message());
  }
  return response;
}

template <typename ServerReflection, typename Request, typename Response>
std::vector<std::string> ListServices(const std::shared_ptr<grpc::Channel>& channel) {
  Request request;
  request.set_list_services("");
  const auto response = Ask<ServerReflection, Request, Response>(channel, request);
  std::vector<std::string> names;
  for (const auto& s : response.list_services_response().service()) names.push_back(s.name());
  return names;
}

template <typename ServerReflection, typename Request, typename Response>
std::vector<std::string> FileNames(const std::shared_ptr<grpc::Channel>& channel,
                                   const std::string& symbol) {
  Request request;
  request.set_file_containing_symbol(symbol);
  const auto response = Ask<ServerReflection, Request, Response>(channel, request);
  std::vector<std::string> files;
  for (const auto& bytes : response.file_descriptor_response().file_descriptor_proto()) {
    google::protobuf::FileDescriptorProto fd;
    if (!fd.ParseFromString(bytes)) throw std::runtime_error("reflection: bad descriptor");
    files.push_back(fd.name());
  }
  return files;
}

}  // namespace

std::vector<std::string> ListServicesByReflection(const std::shared_ptr<grpc::Channel>& channel,
                                                  ReflectionVersion version) {
  if (version == ReflectionVersion::kV1) {
    return ListServices<v1::ServerReflection, v1::ServerReflectionRequest,
                        v1::ServerReflectionResponse>(channel);
  }
  return ListServices<v1alpha::ServerReflection, v1alpha::ServerReflectionRequest,
                      v1alpha::ServerReflectionResponse>(channel);
}

std::vector<std::string> FilesContainingSymbol(const std::shared_ptr<grpc::Channel>& channel,
                                               const std::string& symbol,
                                               ReflectionVersion version) {
  if (version == ReflectionVersion::kV1) {
    return FileNames<v1::ServerReflection, v1::ServerReflectionRequest,
                     v1::ServerReflectionResponse>(channel, symbol);
  }
  return FileNames<v1alpha::ServerReflection, v1alpha::ServerReflectionRequest,
                   v1alpha::ServerReflectionResponse>(channel, symbol);
}

}  // namespace picking::testing
