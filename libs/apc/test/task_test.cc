#include "libs/apc/task.h"

#include <gtest/gtest.h>

#include <cctype>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>

#include "libs/apc/bins.h"

namespace picking::apc {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

const std::string kTaskDir = std::string(PICKING_DATA_DIR) + "/apc2016/tasks";

const Catalogue& TheCatalogue() {
  static const Catalogue catalogue =
      Catalogue::FromCsvFile(std::string(PICKING_DATA_DIR) + "/apc2016/items/item_data.csv");
  return catalogue;
}

std::string ReadText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream out;
  out << in.rdbuf();
  return out.str();
}

std::string WithoutWhitespace(const std::string& text) {
  std::string out;
  for (char c : text) {
    if (!std::isspace(static_cast<unsigned char>(c))) out += c;
  }
  return out;
}

std::vector<std::string> TaskFiles() {
  std::vector<std::string> files;
  for (const auto& entry : fs::directory_iterator(kTaskDir)) {
    if (entry.path().extension() == ".json") files.push_back(entry.path().string());
  }
  std::sort(files.begin(), files.end());
  return files;
}

TEST(TaskTest, AllOfficialFilesArePresent) {
  // 4 official samples (2 layouts, 2 outputs) and 4 further layouts.
  EXPECT_EQ(TaskFiles().size(), 8u);
}

TEST(TaskTest, EveryOfficialFileRoundTrips) {
  for (const std::string& path : TaskFiles()) {
    SCOPED_TRACE(path);
    const std::string text = ReadText(path);
    const Task task = ReadTaskFile(path, TheCatalogue());
    const std::string serialized = SerializeTask(task);
    EXPECT_EQ(ParseTask(serialized, TheCatalogue(), "serialized"), task);
    EXPECT_EQ(WithoutWhitespace(serialized), WithoutWhitespace(text));
  }
}

TEST(TaskTest, SerializationUsesTheOfficialLayout) {
  const std::string path = kTaskDir + "/apc2016_pick_output_sample.json";
  std::string text = ReadText(path);
  text.erase(std::remove(text.begin(), text.end(), '\r'), text.end());
  const std::string serialized = SerializeTask(ReadTaskFile(path, TheCatalogue()));
  // The official file has CRLF line ends and no final newline; otherwise the text is
  // identical.
  EXPECT_EQ(serialized, text + "\n");
}

TEST(TaskTest, PickLayoutSampleContents) {
  const Task task = ReadTaskFile(kTaskDir + "/apc2016_pick_layout_sample.json", TheCatalogue());
  EXPECT_EQ(task.kind, TaskKind::kPick);
  ASSERT_EQ(task.bin_contents.size(), 12u);
  EXPECT_EQ(task.bin_contents.at("bin_H").size(), 9u);
  EXPECT_EQ(task.bin_contents.at("bin_D"), std::vector<std::string>{"kleenex_paper_towels"});
  EXPECT_TRUE(task.tote_contents.empty());
  ASSERT_EQ(task.work_order.size(), 12u);
  EXPECT_EQ(task.work_order[7], (WorkOrderEntry{"bin_H", "staples_index_cards"}));
  for (int i = 0; i < kNumBins; ++i) EXPECT_EQ(task.work_order[i].bin, BinName(i));
}

TEST(TaskTest, StowAndOutputFilesHaveNoWorkOrder) {
  const Task stow = ReadTaskFile(kTaskDir + "/apc2016_stow_layout_sample.json", TheCatalogue());
  EXPECT_EQ(stow.kind, TaskKind::kStow);
  EXPECT_EQ(stow.tote_contents.size(), 12u);
  EXPECT_TRUE(stow.work_order.empty());
  EXPECT_EQ(SerializeTask(stow).find("work_order"), std::string::npos);
  const Task output = ReadTaskFile(kTaskDir + "/apc2016_pick_output_sample.json", TheCatalogue());
  EXPECT_EQ(output.kind, TaskKind::kStow);
  EXPECT_EQ(output.tote_contents.size(), 12u);
}

TEST(TaskTest, OutputOfAPickStateMatchesTheOfficialOutputFile) {
  Task state = ReadTaskFile(kTaskDir + "/apc2016_pick_layout_sample.json", TheCatalogue());
  // Carry out the work order.
  for (const WorkOrderEntry& entry : state.work_order) {
    auto& bin = state.bin_contents.at(entry.bin);
    bin.erase(std::find(bin.begin(), bin.end(), entry.item));
    state.tote_contents.push_back(entry.item);
  }
  const Task output = ToOutput(state);
  EXPECT_EQ(output.kind, TaskKind::kStow);
  EXPECT_TRUE(output.work_order.empty());
  std::string text = ReadText(kTaskDir + "/apc2016_pick_output_sample.json");
  // bin_H holds two staples_index_cards; the official file lists the remaining copy after
  // dove_beauty_bar, this state before: compare as parsed tasks with sorted bins.
  Task expected = ParseTask(text, TheCatalogue(), "expected");
  Task actual = output;
  for (auto* task : {&expected, &actual}) {
    for (auto& [bin, items] : task->bin_contents) std::sort(items.begin(), items.end());
  }
  EXPECT_EQ(actual, expected);
  EXPECT_EQ(SerializeTask(output).find("work_order"), std::string::npos);
}

TEST(TaskTest, EmptyWorkOrderStaysAPickTask) {
  json doc = json::parse(ReadText(kTaskDir + "/apc2016_pick_layout_sample.json"));
  doc["work_order"] = json::array();
  const Task task = ParseTask(doc.dump(), TheCatalogue(), "t");
  EXPECT_EQ(task.kind, TaskKind::kPick);
  EXPECT_NE(SerializeTask(task).find("\"work_order\": []"), std::string::npos);
}

// Parses `text` and returns the TaskFileError it must raise.
TaskFileError ErrorOf(const std::string& text) {
  try {
    ParseTask(text, TheCatalogue(), "layout.json");
  } catch (const TaskFileError& e) {
    return e;
  }
  ADD_FAILURE() << "no TaskFileError for " << text;
  return TaskFileError("", "", "");
}

json PickSample() { return json::parse(ReadText(kTaskDir + "/apc2016_pick_layout_sample.json")); }

void ExpectFieldError(const json& doc, const std::string& field, const std::string& words) {
  const TaskFileError e = ErrorOf(doc.dump(4));
  EXPECT_EQ(e.source(), "layout.json");
  EXPECT_EQ(e.field(), field);
  const std::string message = e.what();
  EXPECT_NE(message.find("layout.json: " + field), std::string::npos) << message;
  EXPECT_NE(message.find(words), std::string::npos) << message;
}

TEST(TaskTest, MalformedJsonNamesLineAndColumn) {
  const std::string text = "{\n  \"bin_contents\": {\n    \"bin_A\": [\"dove_beauty_bar\",]\n";
  const TaskFileError e = ErrorOf(text);
  const std::string message = e.what();
  EXPECT_NE(message.find("layout.json: line 3, column 33: malformed JSON"), std::string::npos)
      << message;
  EXPECT_NE(std::string(ErrorOf("").what()).find("line 1, column 1"), std::string::npos);
  EXPECT_NE(std::string(ErrorOf("{\"bin_contents\": {}} trailing").what()).find("line 1"),
            std::string::npos);
}

TEST(TaskTest, TopLevelMustBeAnObjectWithKnownKeys) {
  EXPECT_NE(std::string(ErrorOf("[]").what()).find("top level must be an object"),
            std::string::npos);
  json doc = PickSample();
  doc["bonus_round"] = true;
  ExpectFieldError(doc, "bonus_round", "unknown key");
}

TEST(TaskTest, MissingKeys) {
  json doc = PickSample();
  doc.erase("bin_contents");
  ExpectFieldError(doc, "bin_contents", "missing");
  doc = PickSample();
  doc.erase("tote_contents");
  ExpectFieldError(doc, "tote_contents", "missing");
  doc = PickSample();
  doc["work_order"][2].erase("item");
  ExpectFieldError(doc, "work_order[2].item", "missing");
  doc = PickSample();
  doc["work_order"][0].erase("bin");
  ExpectFieldError(doc, "work_order[0].bin", "missing");
}

TEST(TaskTest, AllTwelveBinsAreRequired) {
  json doc = PickSample();
  doc["bin_contents"].erase("bin_F");
  doc["work_order"].erase(5);
  ExpectFieldError(doc, "bin_contents.bin_F", "all 12 bins are required");
}

TEST(TaskTest, UnknownBins) {
  json doc = PickSample();
  doc["bin_contents"]["bin_Q"] = json::array();
  ExpectFieldError(doc, "bin_contents.bin_Q", "unknown bin");
  doc = PickSample();
  doc["work_order"][3]["bin"] = "bin_M";
  ExpectFieldError(doc, "work_order[3].bin", "unknown bin \"bin_M\"");
}

TEST(TaskTest, UnknownItems) {
  json doc = PickSample();
  doc["bin_contents"]["bin_C"][1] = "kyjen_squeakin_eggs";
  ExpectFieldError(doc, "bin_contents.bin_C[1]", "unknown item \"kyjen_squeakin_eggs\"");
  doc = PickSample();
  doc["tote_contents"] = {"rubber_duck"};
  ExpectFieldError(doc, "tote_contents[0]", "unknown item \"rubber_duck\"");
  doc = PickSample();
  doc["work_order"][11]["item"] = "rubber_duck";
  ExpectFieldError(doc, "work_order[11].item", "unknown item");
}

TEST(TaskTest, WorkOrderItemMustBeInItsBin) {
  json doc = PickSample();
  doc["work_order"][0]["item"] = "dove_beauty_bar";  // In bin_H, not bin_A.
  ExpectFieldError(doc, "work_order[0].item", "\"dove_beauty_bar\" is not in bin_A");
  // Twice the same target needs two copies in the bin: bin_H has two staples_index_cards,
  // bin_A one kleenex_tissue_box.
  doc = PickSample();
  doc["work_order"].push_back({{"bin", "bin_H"}, {"item", "staples_index_cards"}});
  EXPECT_NO_THROW(ParseTask(doc.dump(), TheCatalogue(), "t"));
  doc["work_order"].push_back({{"bin", "bin_A"}, {"item", "kleenex_tissue_box"}});
  ExpectFieldError(doc, "work_order[13].item", "as often as the work order asks");
}

TEST(TaskTest, WrongJsonTypes) {
  json doc = PickSample();
  doc["bin_contents"] = json::array();
  ExpectFieldError(doc, "bin_contents", "expected an object");
  doc = PickSample();
  doc["bin_contents"]["bin_B"] = "up_glucose_bottle";
  ExpectFieldError(doc, "bin_contents.bin_B", "expected an array");
  doc = PickSample();
  doc["bin_contents"]["bin_B"][0] = 42;
  ExpectFieldError(doc, "bin_contents.bin_B[0]", "expected an item name, got a number");
  doc = PickSample();
  doc["work_order"] = json::object();
  ExpectFieldError(doc, "work_order", "expected an array");
  doc = PickSample();
  doc["work_order"][1] = "bin_B";
  ExpectFieldError(doc, "work_order[1]", "expected an object");
  doc = PickSample();
  doc["work_order"][1]["quantity"] = 1;
  ExpectFieldError(doc, "work_order[1].quantity", "unknown key");
}

TEST(TaskTest, DuplicateKeysAreRejected) {
  const std::string text =
      R"({"bin_contents": {"bin_A": [], "bin_A": ["dove_beauty_bar"]}, "tote_contents": []})";
  const TaskFileError e = ErrorOf(text);
  EXPECT_EQ(e.field(), "bin_A");
  EXPECT_NE(std::string(e.what()).find("appears twice"), std::string::npos);
}

TEST(TaskTest, ReadingAMissingFileNamesIt) {
  try {
    ReadTaskFile("/nonexistent/task.json", TheCatalogue());
    FAIL();
  } catch (const TaskFileError& e) {
    EXPECT_EQ(e.source(), "/nonexistent/task.json");
    EXPECT_NE(std::string(e.what()).find("/nonexistent/task.json"), std::string::npos);
  }
}

class TaskWriteTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ =
        fs::temp_directory_path() /
        ("picking_task_test_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) +
         "_" + ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

TEST_F(TaskWriteTest, WritesAndReadsBackAndReplacesAtomically) {
  const Task pick = ReadTaskFile(kTaskDir + "/apc2016_pick_layout_sample.json", TheCatalogue());
  const Task stow = ReadTaskFile(kTaskDir + "/apc2016_stow_layout_sample.json", TheCatalogue());
  const std::string path = (dir_ / "out.json").string();
  WriteTaskFile(path, pick);
  EXPECT_EQ(ReadTaskFile(path, TheCatalogue()), pick);
  WriteTaskFile(path, stow);
  EXPECT_EQ(ReadTaskFile(path, TheCatalogue()), stow);
  EXPECT_EQ(ReadText(path), SerializeTask(stow));
  // No temporary file is left behind.
  int files = 0;
  for (const auto& entry : fs::directory_iterator(dir_)) {
    (void)entry;
    ++files;
  }
  EXPECT_EQ(files, 1);
}

TEST_F(TaskWriteTest, UnwritablePathThrowsAndLeavesNothing) {
  const Task pick = ReadTaskFile(kTaskDir + "/apc2016_pick_layout_sample.json", TheCatalogue());
  const std::string path = (dir_ / "missing_folder" / "out.json").string();
  EXPECT_THROW(WriteTaskFile(path, pick), TaskFileError);
  EXPECT_FALSE(fs::exists(path));
  // A directory in the way: the rename fails, the temporary file is removed.
  fs::create_directories(dir_ / "taken.json" / "child");
  EXPECT_THROW(WriteTaskFile((dir_ / "taken.json").string(), pick), TaskFileError);
  int files = 0;
  for (const auto& entry : fs::directory_iterator(dir_)) {
    (void)entry;
    ++files;
  }
  EXPECT_EQ(files, 1);  // Only the "taken.json" directory.
}

TEST(TaskTest, SerializeRejectsUnknownBins) {
  Task task;
  task.bin_contents["shelf_top"] = {};
  EXPECT_THROW(SerializeTask(task), std::invalid_argument);
}

}  // namespace
}  // namespace picking::apc
