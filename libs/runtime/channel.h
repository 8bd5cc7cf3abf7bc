#pragma once

#include <grpcpp/channel.h>
#include <grpcpp/support/channel_arguments.h>

#include <memory>
#include <string>

#include "libs/runtime/config.h"
#include "libs/runtime/tls.h"

namespace grpc {
class ChannelCredentials;
}

namespace picking::runtime {

/// Makes the channels a process opens to other servers, all with the same security: plaintext,
/// or TLS from the process's own tls.* settings (the ones its server uses), so a server run
/// with mutual TLS also talks mutual TLS to its peers. As a client:
///   tls.ca           the CA a server's certificate must be signed by (without it, the
///                    system's roots)
///   tls.cert/key     the certificate shown to servers that require one (mutual TLS)
///   tls.server_name  the name checked against the server's certificate instead of the host of
///                    the address (e.g. when connecting by IP to a certificate for "robot")
/// The files are read and checked once, at construction.
class ChannelFactory final {
 public:
  /// Plaintext channels.
  ChannelFactory();
  /// TLS channels when `files` names any file, plaintext otherwise. Throws
  /// std::invalid_argument as ReadTlsPem, and when `server_name` is given without TLS.
  ChannelFactory(const TlsFiles& files, const std::string& server_name);

  /// From the settings tls.cert, tls.key, tls.ca and tls.server_name.
  static ChannelFactory FromConfig(const Config& config);

  /// A channel to `address` (HOST:PORT or a gRPC target such as dns:///name:port) with `args`
  /// (message sizes, backoff) and this factory's security.
  std::shared_ptr<grpc::Channel> Connect(const std::string& address,
                                         grpc::ChannelArguments args = {}) const;

  bool tls() const { return tls_; }

 private:
  std::shared_ptr<grpc::ChannelCredentials> credentials_;
  std::string server_name_;
  bool tls_ = false;
};

}  // namespace picking::runtime
