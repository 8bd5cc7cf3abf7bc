#include "libs/apc/scoring.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "libs/apc/bins.h"

namespace picking::apc {
namespace {

const std::string kTaskDir = std::string(PICKING_DATA_DIR) + "/apc2016/tasks";

const Catalogue& TheCatalogue() {
  static const Catalogue catalogue =
      Catalogue::FromCsvFile(std::string(PICKING_DATA_DIR) + "/apc2016/items/item_data.csv");
  return catalogue;
}

Task Load(const std::string& name) { return ReadTaskFile(kTaskDir + "/" + name, TheCatalogue()); }

// A small pick task: bin_A holds 2 items, bin_B 3, bin_C 5, the rest nothing.
Task SmallPick() {
  Task task;
  task.kind = TaskKind::kPick;
  for (int i = 0; i < kNumBins; ++i) task.bin_contents[BinName(i)] = {};
  task.bin_contents["bin_A"] = {"dove_beauty_bar", "crayola_24_ct"};
  task.bin_contents["bin_B"] = {"fiskars_scissors_red", "jane_eyre_dvd", "command_hooks"};
  task.bin_contents["bin_C"] = {"rawlings_baseball", "dasani_water_bottle", "command_hooks",
                                "hanes_tube_socks", "i_am_a_bunny_book"};
  task.work_order = {{"bin_A", "dove_beauty_bar"},
                     {"bin_B", "fiskars_scissors_red"},
                     {"bin_C", "dasani_water_bottle"}};
  return task;
}

// Builds a scoring input whose true final state and report are what the events produce.
ScoringInput Honest(const Task& initial, std::vector<Event> events) {
  ScoringInput input;
  input.initial = initial;
  input.events = std::move(events);
  const WorldState state = ReplayEvents(input.initial, input.events);
  input.true_final = state.places;
  input.true_gripper_contents = state.gripper_contents;
  input.reported = state.places;
  return input;
}

int CountRule(const ScoreReport& report, ScoreRule rule) {
  return static_cast<int>(std::count_if(report.lines.begin(), report.lines.end(),
                                        [rule](const ScoreLine& l) { return l.rule == rule; }));
}

int Sum(const ScoreReport& report) {
  int total = 0;
  for (const ScoreLine& line : report.lines) total += line.points;
  return total;
}

TEST(ScoringTest, NothingDoneScoresZero) {
  const ScoreReport report = Score(Honest(SmallPick(), {}), TheCatalogue());
  EXPECT_EQ(report.total, 0);
  EXPECT_TRUE(report.lines.empty());
}

TEST(ScoringTest, PickPointsDependOnBinPopulationAtTheStart) {
  // dove (bin_A: 2 items, bonus 0) -> 10; scissors (bin_B: 3, bonus 2) -> 15 + 2;
  // dasani (bin_C: 5, bonus 2) -> 20 + 2.
  const ScoreReport report =
      Score(Honest(SmallPick(), {MoveEvent("dove_beauty_bar", "bin_A", "tote"),
                                 MoveEvent("fiskars_scissors_red", "bin_B", "tote"),
                                 MoveEvent("dasani_water_bottle", "bin_C", "tote")}),
            TheCatalogue());
  ASSERT_EQ(report.lines.size(), 5u);
  EXPECT_EQ(report.lines[0].rule, ScoreRule::kTargetItem);
  EXPECT_EQ(report.lines[0].points, 10);
  EXPECT_EQ(report.lines[1].points, 15);
  EXPECT_EQ(report.lines[2].rule, ScoreRule::kItemBonus);
  EXPECT_EQ(report.lines[2].points, 2);
  EXPECT_EQ(report.lines[3].points, 20);
  EXPECT_EQ(report.lines[4].points, 2);
  EXPECT_EQ(report.total, 49);
  EXPECT_EQ(Sum(report), report.total);
  EXPECT_NE(report.lines[1].reason.find("bin_B (3 items at the start)"), std::string::npos);
}

TEST(ScoringTest, PopulationIsTakenAtTheStartNotWhenPicked) {
  // Emptying bin_C down to one item first does not lower the target's value.
  const ScoreReport report =
      Score(Honest(SmallPick(), {MoveEvent("rawlings_baseball", "bin_C", "bin_D"),
                                 MoveEvent("command_hooks", "bin_C", "bin_D"),
                                 MoveEvent("hanes_tube_socks", "bin_C", "bin_D"),
                                 MoveEvent("dasani_water_bottle", "bin_C", "tote")}),
            TheCatalogue());
  EXPECT_EQ(report.total, 22);
}

TEST(ScoringTest, NonTargetAndWrongBinCopiesDoNotScore) {
  Task task = SmallPick();
  task.bin_contents["bin_D"] = {"dasani_water_bottle"};
  // The dasani from bin_D is not the target (the work order names bin_C); the crayons are not
  // a target at all.
  const ScoreReport report = Score(Honest(task, {MoveEvent("dasani_water_bottle", "bin_D", "tote"),
                                                 MoveEvent("crayola_24_ct", "bin_A", "tote")}),
                                   TheCatalogue());
  EXPECT_EQ(report.total, 0);
}

TEST(ScoringTest, TargetMustEndInTheTote) {
  const ScoreReport in_gripper = Score(
      Honest(SmallPick(), {MoveEvent("dove_beauty_bar", "bin_A", "gripper")}), TheCatalogue());
  EXPECT_EQ(in_gripper.total, 0);
  const ScoreReport put_back =
      Score(Honest(SmallPick(), {MoveEvent("dove_beauty_bar", "bin_A", "tote"),
                                 MoveEvent("dove_beauty_bar", "tote", "bin_B")}),
            TheCatalogue());
  EXPECT_EQ(put_back.total, 0);
}

TEST(ScoringTest, ItemBonusComesFromTheCatalogue) {
  const ScoringInput input =
      Honest(SmallPick(), {MoveEvent("fiskars_scissors_red", "bin_B", "tote")});
  ScoreReport report = Score(input, TheCatalogue());
  ASSERT_EQ(report.lines.size(), 2u);
  EXPECT_EQ(report.lines[1].rule, ScoreRule::kItemBonus);
  EXPECT_EQ(report.lines[1].item, "fiskars_scissors_red");
  EXPECT_EQ(report.lines[1].points, 2);
  // The same move with a catalogue that gives the scissors 3 bonus points.
  std::vector<Item> items = TheCatalogue().items();
  for (Item& item : items) {
    if (item.name == "fiskars_scissors_red") item.bonus = 3;
  }
  report = Score(input, Catalogue(items));
  EXPECT_EQ(report.total, 15 + 3);
  // No bonus line for an item without bonus.
  report =
      Score(Honest(SmallPick(), {MoveEvent("dove_beauty_bar", "bin_A", "tote")}), TheCatalogue());
  EXPECT_EQ(CountRule(report, ScoreRule::kItemBonus), 0);
}

TEST(ScoringTest, StowPointsDependOnDestinationPopulationAtTheStart) {
  Task task = SmallPick();
  task.kind = TaskKind::kStow;
  task.work_order.clear();
  task.tote_contents = {"kleenex_tissue_box", "clorox_utility_brush", "scotch_duct_tape"};
  // kleenex -> bin_D (0 items): 10; clorox (bonus 2) -> bin_B (3): 15 + 2;
  // duct tape (bonus 1) -> bin_C (5): 20 + 1. Bin_D receiving two items counts its start.
  const ScoreReport report = Score(Honest(task, {MoveEvent("kleenex_tissue_box", "tote", "bin_D"),
                                                 MoveEvent("clorox_utility_brush", "tote", "bin_B"),
                                                 MoveEvent("scotch_duct_tape", "tote", "bin_C")}),
                                   TheCatalogue());
  EXPECT_EQ(CountRule(report, ScoreRule::kStowedItem), 3);
  EXPECT_EQ(report.total, 10 + 17 + 21);
  ScoringRules no_bonus;
  no_bonus.stow_item_bonus = false;
  EXPECT_EQ(Score(Honest(task, {MoveEvent("clorox_utility_brush", "tote", "bin_B")}),
                  TheCatalogue(), no_bonus)
                .total,
            15);
  // Items moved between bins in a stow task do not score.
  EXPECT_EQ(
      Score(Honest(task, {MoveEvent("crayola_24_ct", "bin_A", "bin_D")}), TheCatalogue()).total, 0);
}

TEST(ScoringTest, ItemOutsideCostsTen) {
  const ScoreReport report =
      Score(Honest(SmallPick(), {OutsideEvent("crayola_24_ct", "bin_A")}), TheCatalogue());
  ASSERT_EQ(report.lines.size(), 1u);
  EXPECT_EQ(report.lines[0].rule, ScoreRule::kOutside);
  EXPECT_EQ(report.lines[0].item, "crayola_24_ct");
  EXPECT_EQ(report.total, -10);
}

TEST(ScoringTest, ItemInTheGripperIsNotOutside) {
  const ScoreReport report =
      Score(Honest(SmallPick(), {MoveEvent("crayola_24_ct", "bin_A", "gripper")}), TheCatalogue());
  EXPECT_EQ(report.total, 0);
}

TEST(ScoringTest, EachMisreportedItemCostsTen) {
  ScoringInput input = Honest(SmallPick(), {MoveEvent("dove_beauty_bar", "bin_A", "tote")});
  // The report forgets the move: dove is really in the tote (1 wrong).
  input.reported = SmallPick();
  ScoreReport report = Score(input, TheCatalogue());
  EXPECT_EQ(CountRule(report, ScoreRule::kMisreported), 1);
  EXPECT_EQ(report.total, 10 - 10);
  // Two items swapped between bins: both wrong.
  input = Honest(SmallPick(), {});
  std::swap(input.reported.bin_contents["bin_A"][1], input.reported.bin_contents["bin_B"][1]);
  report = Score(input, TheCatalogue());
  EXPECT_EQ(CountRule(report, ScoreRule::kMisreported), 2);
  EXPECT_EQ(report.total, -20);
  // Order inside a bin does not matter.
  input = Honest(SmallPick(), {});
  std::reverse(input.reported.bin_contents["bin_C"].begin(),
               input.reported.bin_contents["bin_C"].end());
  EXPECT_EQ(Score(input, TheCatalogue()).total, 0);
  // An item held by the gripper is neither in a bin nor the tote: not a misreport.
  input = Honest(SmallPick(), {MoveEvent("crayola_24_ct", "bin_A", "gripper")});
  input.reported = SmallPick();
  EXPECT_EQ(Score(input, TheCatalogue()).total, 0);
}

TEST(ScoringTest, DamagePenalties) {
  const ScoreReport report = Score(
      Honest(SmallPick(),
             {DamageEvent("jane_eyre_dvd", /*major=*/false), DamageEvent("shelf", /*major=*/true)}),
      TheCatalogue());
  ASSERT_EQ(report.lines.size(), 2u);
  EXPECT_EQ(report.lines[0].rule, ScoreRule::kDamageMinor);
  EXPECT_EQ(report.lines[0].points, -5);
  EXPECT_EQ(report.lines[1].rule, ScoreRule::kDamageMajor);
  EXPECT_EQ(report.lines[1].points, -20);
  EXPECT_EQ(report.total, -25);
}

TEST(ScoringTest, DropsAboveThirtyCentimetresCostFive) {
  const ScoreReport report = Score(
      Honest(SmallPick(), {DropEvent("dove_beauty_bar", 0.30), DropEvent("dove_beauty_bar", 0.31),
                           DropEvent("crayola_24_ct", 1.2)}),
      TheCatalogue());
  EXPECT_EQ(CountRule(report, ScoreRule::kDrop), 2);
  EXPECT_EQ(report.total, -10);
}

TEST(ScoringTest, ProtrusionBeyondHalfACentimetreCostsFive) {
  const ScoreReport report =
      Score(Honest(SmallPick(), {ProtrudingEvent("crayola_24_ct", "bin_A", 0.005),
                                 ProtrudingEvent("jane_eyre_dvd", "bin_B", 0.02)}),
            TheCatalogue());
  ASSERT_EQ(report.lines.size(), 1u);
  EXPECT_EQ(report.lines[0].rule, ScoreRule::kProtruding);
  EXPECT_EQ(report.lines[0].item, "jane_eyre_dvd");
  EXPECT_EQ(report.total, -5);
}

TEST(ScoringTest, InconsistentEventsAreRejected) {
  // Taking an item from a bin that does not hold it.
  try {
    ReplayEvents(SmallPick(), {MoveEvent("jane_eyre_dvd", "bin_A", "tote")});
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("event 0 (jane_eyre_dvd): bin_A does not hold"),
              std::string::npos);
  }
  EXPECT_THROW(ReplayEvents(SmallPick(), {MoveEvent("jane_eyre_dvd", "bin_B", "floor")}),
               std::invalid_argument);
  // A true final state that the events cannot explain.
  ScoringInput input = Honest(SmallPick(), {MoveEvent("dove_beauty_bar", "bin_A", "tote")});
  input.true_final.tote_contents.push_back("crayola_24_ct");
  try {
    Score(input, TheCatalogue());
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("tote holds 1 x crayola_24_ct, the events leave 0"),
              std::string::npos)
        << e.what();
  }
}

TEST(ScoringTest, MalformedEventsAreRejected) {
  EXPECT_THROW(ReplayEvents(SmallPick(), {DropEvent("dove_beauty_bar", -0.1)}),
               std::invalid_argument);
  EXPECT_THROW(ReplayEvents(SmallPick(), {DropEvent("dove_beauty_bar", NAN)}),
               std::invalid_argument);
  EXPECT_THROW(ReplayEvents(SmallPick(), {ProtrudingEvent("dove_beauty_bar", "tote", 0.01)}),
               std::invalid_argument);
  EXPECT_THROW(ReplayEvents(SmallPick(), {ProtrudingEvent("dove_beauty_bar", "bin_A", INFINITY)}),
               std::invalid_argument);
}

TEST(ScoringTest, RuleNamesAreDistinct) {
  EXPECT_EQ(ScoreRuleName(ScoreRule::kTargetItem), "target_item");
  EXPECT_EQ(ScoreRuleName(ScoreRule::kMisreported), "misreported");
  EXPECT_NE(ScoreRuleName(ScoreRule::kDamageMinor), ScoreRuleName(ScoreRule::kDamageMajor));
}

TEST(ScoringTest, OfficialPickSampleScoresByHand) {
  const Task layout = Load("apc2016_pick_layout_sample.json");
  const Task output = Load("apc2016_pick_output_sample.json");
  std::vector<Event> events;
  for (const WorkOrderEntry& entry : layout.work_order) {
    events.push_back(MoveEvent(entry.item, entry.bin, "tote"));
  }
  ScoringInput input;
  input.initial = layout;
  input.events = events;
  input.reported = output;
  input.true_final = output;
  const ScoreReport report = Score(input, TheCatalogue());
  // Population at the start -> points, item bonus:
  //   A 2 -> 10 kleenex_tissue_box 0      B 7 -> 20 up_glucose_bottle 0
  //   C 4 -> 15 cherokee_easy_tee_shirt 1  D 1 -> 10 kleenex_paper_towels 1
  //   E 4 -> 15 laugh_out_loud_joke_book 0 F 3 -> 15 scotch_duct_tape 1
  //   G 2 -> 10 barkely_hide_bones 0       H 9 -> 20 staples_index_cards 0
  //   I 5 -> 20 dasani_water_bottle 2      J 2 -> 10 peva_shower_curtain_liner 0
  //   K 3 -> 15 clorox_utility_brush 2     L 4 -> 15 dr_browns_bottle_brush 2
  // Bin points 175, bonuses 9.
  EXPECT_EQ(CountRule(report, ScoreRule::kTargetItem), 12);
  EXPECT_EQ(CountRule(report, ScoreRule::kItemBonus), 6);
  EXPECT_EQ(report.total, 184);
  EXPECT_EQ(Sum(report), 184);

  // The same run with an output that reports the tee shirt still in bin_C although it is in
  // the tote: -10 for the misreport.
  input.reported.bin_contents["bin_C"].push_back("cherokee_easy_tee_shirt");
  input.reported.tote_contents.erase(input.reported.tote_contents.begin() + 2);
  EXPECT_EQ(Score(input, TheCatalogue()).total, 174);
}

TEST(ScoringTest, OfficialStowSampleScoresByHand) {
  const Task layout = Load("apc2016_stow_layout_sample.json");
  const Task output = Load("apc2016_stow_output_sample.json");
  // Where each tote item went in the official output.
  const std::vector<std::pair<std::string, std::string>> moves = {
      {"safety_first_outlet_plugs", "bin_B"},
      {"expo_dry_erase_board_eraser", "bin_B"},
      {"laugh_out_loud_joke_book", "bin_D"},
      {"barkely_hide_bones", "bin_D"},
      {"up_glucose_bottle", "bin_E"},
      {"kyjen_squeakin_eggs_plush_puppies", "bin_E"},
      {"jane_eyre_dvd", "bin_E"},
      {"scotch_bubble_mailer", "bin_G"},
      {"clorox_utility_brush", "bin_G"},
      {"scotch_duct_tape", "bin_I"},
      {"oral_b_toothbrush_green", "bin_K"},
      {"hanes_tube_socks", "bin_K"}};
  std::vector<Event> events;
  for (const auto& [item, bin] : moves) events.push_back(MoveEvent(item, "tote", bin));
  ScoringInput input;
  input.initial = layout;
  input.events = events;
  input.reported = output;
  input.true_final = output;
  const ScoreReport report = Score(input, TheCatalogue());
  // Start populations: B 5 -> 20 (x2), D 1 -> 10 (x2), E 1 -> 10 (x3), G 2 -> 10 (x2),
  // I 5 -> 20, K 1 -> 10 (x2): 150. Bonuses: kyjen 1, clorox 2, duct tape 1, socks 1: 5.
  EXPECT_EQ(CountRule(report, ScoreRule::kStowedItem), 12);
  EXPECT_EQ(report.total, 155);
}

}  // namespace
}  // namespace picking::apc
