#include "libs/runtime/tls.h"

#include <grpcpp/security/server_credentials.h>
#include <openssl/bio.h>
#include <openssl/err.h>
#include <openssl/pem.h>
#include <openssl/x509.h>

#include <fstream>
#include <sstream>
#include <stdexcept>

namespace picking::runtime {
namespace {

[[noreturn]] void Bad(const std::string& name, const std::string& path, const std::string& why) {
  throw std::invalid_argument(name + ": '" + path + "' " + why);
}

std::string ReadFile(const std::string& name, const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) Bad(name, path, "cannot be read");
  std::stringstream text;
  text << in.rdbuf();
  if (in.bad()) Bad(name, path, "cannot be read");
  return text.str();
}

struct BioDeleter {
  void operator()(BIO* bio) const { BIO_free(bio); }
};
struct X509Deleter {
  void operator()(X509* cert) const { X509_free(cert); }
};
struct KeyDeleter {
  void operator()(EVP_PKEY* key) const { EVP_PKEY_free(key); }
};
using Bio = std::unique_ptr<BIO, BioDeleter>;
using Cert = std::unique_ptr<X509, X509Deleter>;
using Key = std::unique_ptr<EVP_PKEY, KeyDeleter>;

Bio MemoryBio(const std::string& pem) {
  return Bio(BIO_new_mem_buf(pem.data(), static_cast<int>(pem.size())));
}

// The certificates of a PEM text, in order; throws when there is none or one is malformed.
std::vector<Cert> ParseCertificates(const std::string& name, const std::string& path,
                                    const std::string& pem) {
  std::vector<Cert> certs;
  const Bio bio = MemoryBio(pem);
  while (X509* cert = PEM_read_bio_X509(bio.get(), nullptr, nullptr, nullptr)) {
    certs.emplace_back(cert);
  }
  // The end of the text leaves a "no start line" error queued; gRPC's own OpenSSL calls in
  // this thread must not find it.
  ERR_clear_error();
  if (certs.empty()) Bad(name, path, "holds no PEM certificate");
  return certs;
}

// A passphrase callback that has none, so an encrypted key fails instead of prompting on the
// terminal of a server.
int NoPassphrase(char*, int, int, void*) { return 0; }

Key ParsePrivateKey(const std::string& name, const std::string& path, const std::string& pem) {
  const Bio bio = MemoryBio(pem);
  Key private_key(PEM_read_bio_PrivateKey(bio.get(), nullptr, NoPassphrase, nullptr));
  ERR_clear_error();
  if (!private_key) Bad(name, path, "holds no PEM private key (or it is encrypted)");
  return private_key;
}

}  // namespace

TlsFiles TlsFilesFromConfig(const Config& config) {
  TlsFiles files;
  files.cert_path = config.GetPath("tls.cert", "");
  files.key_path = config.GetPath("tls.key", "");
  files.ca_path = config.GetPath("tls.ca", "");
  return files;
}

TlsPem ReadTlsPem(const TlsFiles& files) {
  if (files.cert_path.empty() != files.key_path.empty()) {
    throw std::invalid_argument(files.cert_path.empty()
                                    ? files.key_name + " needs " + files.cert_name
                                    : files.cert_name + " needs " + files.key_name);
  }
  TlsPem pem;
  if (!files.cert_path.empty()) {
    pem.cert_chain = ReadFile(files.cert_name, files.cert_path);
    pem.private_key = ReadFile(files.key_name, files.key_path);
    const std::vector<Cert> chain =
        ParseCertificates(files.cert_name, files.cert_path, pem.cert_chain);
    const Key private_key = ParsePrivateKey(files.key_name, files.key_path, pem.private_key);
    if (X509_check_private_key(chain.front().get(), private_key.get()) != 1) {
      ERR_clear_error();
      Bad(files.key_name, files.key_path,
          "is not the private key of the certificate '" + files.cert_path + "'");
    }
  }
  if (!files.ca_path.empty()) {
    pem.ca_certs = ReadFile(files.ca_name, files.ca_path);
    ParseCertificates(files.ca_name, files.ca_path, pem.ca_certs);
  }
  return pem;
}

std::shared_ptr<grpc::ServerCredentials> ServerCredentialsFor(const TlsFiles& files) {
  if (!files.any()) return grpc::InsecureServerCredentials();
  if (files.cert_path.empty() && files.key_path.empty()) {
    throw std::invalid_argument(files.ca_name + " needs " + files.cert_name + " and " +
                                files.key_name + ": the certificate this server presents");
  }
  const TlsPem pem = ReadTlsPem(files);
  // With a CA the handshake itself refuses a client without a certificate signed by it, so no
  // call of an unauthenticated client ever reaches a service.
  grpc::SslServerCredentialsOptions options(
      pem.ca_certs.empty() ? GRPC_SSL_DONT_REQUEST_CLIENT_CERTIFICATE
                           : GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY);
  options.pem_root_certs = pem.ca_certs;
  options.pem_key_cert_pairs.push_back({pem.private_key, pem.cert_chain});
  return grpc::SslServerCredentials(options);
}

}  // namespace picking::runtime
