#include "libs/runtime/channel.h"

#include <grpcpp/create_channel.h>
#include <grpcpp/security/credentials.h>

#include <stdexcept>

namespace picking::runtime {

ChannelFactory::ChannelFactory() : credentials_(grpc::InsecureChannelCredentials()) {}

ChannelFactory::ChannelFactory(const TlsFiles& files, const std::string& server_name)
    : server_name_(server_name), tls_(files.any()) {
  if (!tls_) {
    if (!server_name.empty()) {
      throw std::invalid_argument("a TLS server name ('" + server_name + "') without TLS: give " +
                                  files.ca_name + " (and " + files.cert_name + ", " +
                                  files.key_name + ")");
    }
    credentials_ = grpc::InsecureChannelCredentials();
    return;
  }
  const TlsPem pem = ReadTlsPem(files);
  grpc::SslCredentialsOptions options;
  options.pem_root_certs = pem.ca_certs;
  options.pem_private_key = pem.private_key;
  options.pem_cert_chain = pem.cert_chain;
  credentials_ = grpc::SslCredentials(options);
}

ChannelFactory ChannelFactory::FromConfig(const Config& config) {
  return ChannelFactory(TlsFilesFromConfig(config), config.GetString("tls.server_name", ""));
}

std::shared_ptr<grpc::Channel> ChannelFactory::Connect(const std::string& address,
                                                       grpc::ChannelArguments args) const {
  if (!server_name_.empty()) args.SetSslTargetNameOverride(server_name_);
  return grpc::CreateCustomChannel(address, credentials_, args);
}

}  // namespace picking::runtime
