#include "tests/harness/certificates.h"

#include <filesystem>
#include <stdexcept>

#include "tests/harness/server_process.h"

#ifndef PICKING_SOURCE_DIR
#error "PICKING_SOURCE_DIR must name the source tree holding scripts/make-certs.sh"
#endif

namespace picking::testing {

TestCertificates::TestCertificates(std::string dir, const std::vector<std::string>& names)
    : dir_(std::move(dir)) {
  // A CA left from an earlier run would be reused by the script; each run gets its own.
  std::filesystem::remove_all(dir_);
  std::vector<std::string> args{dir_};
  args.insert(args.end(), names.begin(), names.end());
  const ProgramResult made =
      RunProgram(std::string(PICKING_SOURCE_DIR) + "/scripts/make-certs.sh", args);
  if (made.exit_status != 0) {
    throw std::runtime_error("make-certs.sh failed (status " + std::to_string(made.exit_status) +
                             "): " + made.output);
  }
}

std::vector<std::string> TestCertificates::ServerFlags(const std::string& name) const {
  return {"--tls.cert=" + cert(name), "--tls.key=" + key(name), "--tls.ca=" + ca()};
}

runtime::TlsFiles TestCertificates::Client(const std::string& name) const {
  runtime::TlsFiles files;
  files.cert_path = cert(name);
  files.key_path = key(name);
  files.ca_path = ca();
  return files;
}

}  // namespace picking::testing
