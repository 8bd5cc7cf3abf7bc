#include "libs/runtime/tls.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>

#include "libs/runtime/channel.h"

namespace picking::runtime {
namespace {

// The message of the std::invalid_argument `fn` throws; fails the test when it throws none.
template <class Fn>
std::string InvalidArgumentMessage(Fn&& fn) {
  try {
    fn();
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  ADD_FAILURE() << "no std::invalid_argument thrown";
  return "";
}

TEST(TlsTest, RelativePathsInAYamlFileAreRelativeToItsFolder) {
  const std::filesystem::path dir = std::filesystem::path(::testing::TempDir()) / "tls_yaml";
  std::filesystem::create_directories(dir);
  const std::string path = (dir / "server.yaml").string();
  std::ofstream(path) << "tls:\n  cert: certs/planner.pem\n  key: certs/planner.key\n"
                         "  ca: /etc/picking/ca.pem\n";
  const TlsFiles files = TlsFilesFromConfig(Config::FromYamlFile(path));
  EXPECT_EQ(files.cert_path, (dir / "certs/planner.pem").string());
  EXPECT_EQ(files.key_path, (dir / "certs/planner.key").string());
  EXPECT_EQ(files.ca_path, "/etc/picking/ca.pem");
  EXPECT_TRUE(files.any());
}

TEST(TlsTest, NoFilesMeanPlaintext) {
  const TlsFiles none = TlsFilesFromConfig(Config());
  EXPECT_FALSE(none.any());
  EXPECT_NE(ServerCredentialsFor(none), nullptr);
  EXPECT_FALSE(ChannelFactory(none, "").tls());
  EXPECT_FALSE(ChannelFactory().tls());
}

TEST(TlsTest, ErrorsNameTheSettingOrTheFlagGiven) {
  TlsFiles key_only;
  key_only.key_path = "/no/such.key";
  EXPECT_EQ(InvalidArgumentMessage([&] { ReadTlsPem(key_only); }),
            "setting 'tls.key' needs setting 'tls.cert'");
  key_only.cert_name = "--tls-cert";
  key_only.key_name = "--tls-key";
  EXPECT_EQ(InvalidArgumentMessage([&] { ReadTlsPem(key_only); }), "--tls-key needs --tls-cert");

  TlsFiles missing_ca;
  missing_ca.ca_path = "/no/such/ca.pem";
  EXPECT_EQ(InvalidArgumentMessage([&] { ChannelFactory(missing_ca, ""); }),
            "setting 'tls.ca': '/no/such/ca.pem' cannot be read");
  EXPECT_NE(InvalidArgumentMessage([&] {
              ServerCredentialsFor(missing_ca);
            }).find("setting 'tls.ca' needs setting 'tls.cert' and setting 'tls.key'"),
            std::string::npos);
}

TEST(TlsTest, AServerNameWithoutTlsIsRefused) {
  const std::string message = InvalidArgumentMessage([] { ChannelFactory(TlsFiles(), "robot"); });
  EXPECT_NE(message.find("'robot'"), std::string::npos) << message;
  EXPECT_NE(message.find("tls.ca"), std::string::npos) << message;
}

}  // namespace
}  // namespace picking::runtime
