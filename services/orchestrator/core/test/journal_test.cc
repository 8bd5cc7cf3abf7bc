#include "services/orchestrator/core/journal.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

namespace picking::orchestrator {
namespace {

std::string TempPath(const std::string& name) {
  const auto dir =
      std::filesystem::temp_directory_path() / ("journal_test_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const auto path = dir / name;
  std::filesystem::remove(path);
  return path.string();
}

TEST(Journal, RecordsSurviveReopeningInOrder) {
  const std::string path = TempPath("a.jsonl");
  {
    Journal journal(path);
    journal.Append("begin", "pick/bin_A/x/1/grasp", 1.5, {{"grasp", "+x face"}});
    journal.Append("done", "pick/bin_A/x/1/grasp", 2.0);
  }
  Journal journal(path);
  const auto records = journal.Records();
  ASSERT_EQ(records.size(), 2u);
  EXPECT_EQ(records[0].sequence, 0u);
  EXPECT_EQ(records[1].sequence, 1u);
  EXPECT_EQ(records[0].data.value("grasp", ""), "+x face");
  EXPECT_TRUE(journal.Has("done", "pick/bin_A/x/1/grasp"));
  EXPECT_FALSE(journal.Has("done", "pick/bin_A/x/1/place"));
  EXPECT_EQ(journal.Append("begin", "k", 3.0).sequence, 2u);
}

TEST(Journal, ATornLastLineFromACrashIsDroppedAndAppendsContinueCleanly) {
  const std::string path = TempPath("b.jsonl");
  {
    Journal journal(path);
    journal.Append("begin", "one", 0.0);
  }
  {
    std::ofstream out(path, std::ios::app);
    out << R"({"seq": 1, "type": "do)";  // the process died mid-write
  }
  Journal journal(path);
  EXPECT_EQ(journal.Records().size(), 1u);
  journal.Append("done", "one", 1.0);
  EXPECT_EQ(Journal::Read(path).size(), 2u);
}

TEST(Journal, ACorruptRecordBeforeTheEndIsAnError) {
  const std::string path = TempPath("c.jsonl");
  {
    std::ofstream out(path);
    out << "not json\n"
        << R"({"seq": 0, "type": "begin", "key": "", "t": 0, "data": {}})"
        << "\n";
  }
  EXPECT_THROW(Journal::Read(path), std::runtime_error);
}

}  // namespace
}  // namespace picking::orchestrator
