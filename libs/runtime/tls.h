#pragma once

#include <memory>
#include <string>

#include "libs/runtime/config.h"

namespace grpc {
class ServerCredentials;
}

namespace picking::runtime {

/// The PEM files of one process's TLS identity and trust. Servers and the clients inside them
/// read the same settings:
///   tls.cert  certificate (chain) this process presents, as a server and to its peers
///   tls.key   the private key of tls.cert
///   tls.ca    CA certificate(s): a server accepts only clients with a certificate signed by
///             them (mutual TLS); a client accepts only servers signed by them
/// All empty: plaintext.
struct TlsFiles {
  std::string cert_path;
  std::string key_path;
  std::string ca_path;
  /// How error messages name the three: the settings; a command line names its flags.
  std::string cert_name = "setting 'tls.cert'";
  std::string key_name = "setting 'tls.key'";
  std::string ca_name = "setting 'tls.ca'";

  /// True when any file is named.
  bool any() const { return !cert_path.empty() || !key_path.empty() || !ca_path.empty(); }
};

/// The same files read and checked: each PEM block parsed, the key matching the certificate.
struct TlsPem {
  std::string cert_chain;  ///< Empty when no tls.cert.
  std::string private_key;
  std::string ca_certs;  ///< Empty when no tls.ca.
};

/// Reads tls.cert, tls.key and tls.ca (relative paths in a YAML file are relative to it).
TlsFiles TlsFilesFromConfig(const Config& config);

/// Reads and checks the files. Throws std::invalid_argument with one line naming the setting
/// (TlsFiles::cert_name...) and the file when one cannot be read, holds no PEM certificate or
/// key, or the key is not the certificate's; or when tls.key is given without tls.cert or the
/// other way round.
TlsPem ReadTlsPem(const TlsFiles& files);

/// Credentials of a server's listening port: plaintext when no tls.* file is given; TLS with
/// tls.cert and tls.key; mutual TLS when tls.ca is given too (a client must present a
/// certificate signed by that CA, or the handshake fails). Throws std::invalid_argument as
/// ReadTlsPem, and when tls.ca is given without a certificate to serve.
std::shared_ptr<grpc::ServerCredentials> ServerCredentialsFor(const TlsFiles& files);

}  // namespace picking::runtime
