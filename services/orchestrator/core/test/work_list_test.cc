#include "services/orchestrator/core/work_list.h"

#include <gtest/gtest.h>

namespace picking::orchestrator {
namespace {

const apc::Catalogue& Catalogue() {
  static const apc::Catalogue catalogue = apc::Catalogue::FromCsvFile(apc::DefaultCataloguePath());
  return catalogue;
}

apc::Task PickTask() {
  return apc::ParseTask(R"({"bin_contents": {"bin_A": ["kleenex_tissue_box", "dove_beauty_bar"],
      "bin_B": ["rawlings_baseball"], "bin_C": ["hanes_tube_socks"], "bin_D": [], "bin_E": [], "bin_F": [],
      "bin_G": [], "bin_H": [], "bin_I": [], "bin_J": [], "bin_K": [], "bin_L": []},
      "tote_contents": [], "work_order": [{"bin": "bin_A", "item": "kleenex_tissue_box"},
      {"bin": "bin_B", "item": "rawlings_baseball"}, {"bin": "bin_C", "item": "hanes_tube_socks"}]})",
                        Catalogue(), "test");
}

TEST(EaseTable, EaseIsDifficultyTimesMethodSuccessUnlessOverridden) {
  const EaseTable table = EaseTable::FromYamlText(
      "method_success: {ppf: 0.9, sift: 0.3}\nitems: {rawlings_baseball: 0.1}\n", "t");
  const apc::Item& crayons = Catalogue().at("kleenex_tissue_box");
  EXPECT_DOUBLE_EQ(table.Ease(crayons, "ppf"), (4.0 - crayons.difficulty) / 3.0 * 0.9);
  EXPECT_DOUBLE_EQ(table.Ease(crayons, "sift"), (4.0 - crayons.difficulty) / 3.0 * 0.3);
  EXPECT_DOUBLE_EQ(table.Ease(Catalogue().at("rawlings_baseball"), "ppf"), 0.1);
}

TEST(EaseTable, RefusesValuesOutsideTheUnitIntervalAndUnknownKeys) {
  EXPECT_THROW(EaseTable::FromYamlText("method_success: {ppf: 1.5}\n", "t"), std::invalid_argument);
  EXPECT_THROW(EaseTable::FromYamlText("method_success: {ppf: nan}\n", "t"), std::invalid_argument);
  EXPECT_THROW(EaseTable::FromYamlText("items: {a: x}\n", "t"), std::invalid_argument);
  EXPECT_THROW(EaseTable::FromYamlText("speed: 1\n", "t"), std::invalid_argument);
  EXPECT_NO_THROW(EaseTable::FromYamlFile(PICKING_DATA_DIR "/orchestrator/ease.yaml"));
}

TEST(OrderTargets, EaseOrderFirstThenFallingEase) {
  const EaseTable table = EaseTable::FromYamlText(
      "items: {kleenex_tissue_box: 0.2, rawlings_baseball: 0.9, hanes_tube_socks: 0.5}\n", "t");
  const auto methods = ReadPreferredMethods(PICKING_DATA_DIR "/detector/models.json");
  std::vector<Target> order = OrderTargets(PickTask(), Catalogue(), table, methods, {});
  ASSERT_EQ(order.size(), 3u);
  EXPECT_EQ(order[0].item, "rawlings_baseball");
  EXPECT_EQ(order[1].item, "hanes_tube_socks");
  EXPECT_EQ(order[2].item, "kleenex_tissue_box");
  order = OrderTargets(PickTask(), Catalogue(), table, methods, {"kleenex_tissue_box"});
  EXPECT_EQ(order[0].item, "kleenex_tissue_box");
  EXPECT_EQ(order[1].item, "rawlings_baseball");
  EXPECT_THROW(OrderTargets(PickTask(), Catalogue(), table, methods, {"dove_beauty_bar"}),
               std::invalid_argument);
}

}  // namespace
}  // namespace picking::orchestrator
