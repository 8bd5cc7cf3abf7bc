#pragma once

#include <string>
#include <vector>

#include "libs/runtime/tls.h"

namespace picking::testing {

/// Certificates made at test time by scripts/make-certs.sh (no private key is committed):
/// a CA and, per name, a certificate for serving and calling (SAN DNS:name, DNS:localhost,
/// IP:127.0.0.1), plus the `picking` client certificate.
class TestCertificates final {
 public:
  /// Runs the script into `dir` (emptied first) for `names`. Throws std::runtime_error with
  /// the script's output when it fails.
  TestCertificates(std::string dir, const std::vector<std::string>& names);

  const std::string& dir() const { return dir_; }
  std::string ca() const { return dir_ + "/ca.pem"; }
  std::string cert(const std::string& name) const { return dir_ + "/" + name + ".pem"; }
  std::string key(const std::string& name) const { return dir_ + "/" + name + ".key"; }

  /// The flags that make a server `name` serve mutual TLS with these certificates (and call
  /// its peers with them): --tls.cert, --tls.key, --tls.ca.
  std::vector<std::string> ServerFlags(const std::string& name) const;
  /// The files of a client presenting `name`'s certificate and trusting this CA.
  runtime::TlsFiles Client(const std::string& name) const;

 private:
  std::string dir_;
};

}  // namespace picking::testing
