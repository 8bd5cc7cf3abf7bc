#include "libs/runtime/config.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>

#include <unistd.h>

namespace picking::runtime {
namespace {

TEST(ConfigTest, FlattensNestedYamlIntoDottedKeys) {
  const Config c = Config::FromYamlText(
      "backend: sim\n"
      "sim:\n"
      "  address: localhost:7000\n"
      "  speed: 2.5\n"
      "workspace_min: [-1.0, -1.5, 0.0]\n",
      "test.yaml");
  EXPECT_EQ(c.GetString("backend", ""), "sim");
  EXPECT_EQ(c.GetString("sim.address", ""), "localhost:7000");
  EXPECT_DOUBLE_EQ(c.GetDouble("sim.speed", 0), 2.5);
  EXPECT_EQ(c.GetDoubles("workspace_min", {}), (std::vector<double>{-1.0, -1.5, 0.0}));
}

TEST(ConfigTest, DefaultsApplyWhenKeyAbsent) {
  const Config c;
  EXPECT_EQ(c.GetString("x", "d"), "d");
  EXPECT_EQ(c.GetInt("n", 7), 7);
  EXPECT_TRUE(c.GetBool("b", true));
}

TEST(ConfigTest, OverrideReplacesFileValue) {
  Config c = Config::FromYamlText("rate_hz: 10\n", "t.yaml");
  c.Set("rate_hz", "25");
  EXPECT_EQ(c.GetInt("rate_hz", 0), 25);
}

TEST(ConfigTest, MalformedValuesNameTheKey) {
  Config c;
  c.Set("speed", "fast");
  c.Set("count", "3.5");
  c.Set("flag", "maybe");
  c.Set("nan", "nan");
  try {
    c.GetDouble("speed", 0);
    FAIL() << "expected an exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("speed"), std::string::npos);
  }
  EXPECT_THROW(c.GetInt("count", 0), std::invalid_argument);
  EXPECT_THROW(c.GetBool("flag", false), std::invalid_argument);
  EXPECT_THROW(c.GetDouble("nan", 0), std::invalid_argument);
}

TEST(ConfigTest, MalformedYamlNamesFileAndLine) {
  try {
    Config::FromYamlText("a: 1\nb: [1, 2\n", "bad.yaml");
    FAIL() << "expected an exception";
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("bad.yaml"), std::string::npos) << what;
    EXPECT_NE(what.find("line"), std::string::npos) << what;
  }
  EXPECT_THROW(Config::FromYamlText("- just\n- a list\n", "list.yaml"), std::invalid_argument);
  EXPECT_THROW(Config::FromYamlFile("/nonexistent/picking.yaml"), std::invalid_argument);
}

TEST(ConfigTest, ReportsKeysNobodyRead) {
  Config c = Config::FromYamlText("backend: sim\nbakend: ur\n", "t.yaml");
  c.GetString("backend", "");
  EXPECT_EQ(c.UnusedKeys(), std::vector<std::string>{"bakend"});
}

TEST(ConfigTest, RequireNamesMissingKey) {
  const Config c;
  try {
    c.Require("robot.address");
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("robot.address"), std::string::npos);
  }
}

TEST(ConfigTest, RelativePathsFromAFileAreBesideTheFile) {
  namespace fs = std::filesystem;
  const fs::path dir =
      fs::temp_directory_path() / ("picking_config_test_" + std::to_string(::getpid()));
  fs::create_directories(dir / "conf");
  const fs::path file = dir / "conf" / "server.yaml";
  {
    std::ofstream out(file);
    out << "cell: ../cell/my_cell.yaml\nabsolute: /etc/cell.yaml\nflag: here.yaml\n";
  }
  Config c = Config::FromYamlFile(file.string());
  c.Set("flag", "relative/to/cwd.yaml");
  EXPECT_EQ(c.GetPath("cell", ""), (dir / "cell" / "my_cell.yaml").string());
  EXPECT_EQ(c.GetString("cell", ""), "../cell/my_cell.yaml");
  EXPECT_EQ(c.GetPath("absolute", ""), "/etc/cell.yaml");
  EXPECT_EQ(c.GetPath("flag", ""), "relative/to/cwd.yaml");
  EXPECT_EQ(c.GetPath("missing", "default/path.yaml"), "default/path.yaml");
  const Config copy = c;
  EXPECT_EQ(copy.GetPath("cell", ""), (dir / "cell" / "my_cell.yaml").string());
  // Text without a file: paths as given.
  EXPECT_EQ(Config::FromYamlText("cell: a/b.yaml\n", "t.yaml").GetPath("cell", ""), "a/b.yaml");
  fs::remove_all(dir);
}

}  // namespace
}  // namespace picking::runtime
