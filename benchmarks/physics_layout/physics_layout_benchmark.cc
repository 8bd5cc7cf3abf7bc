// Time to settle a whole APC 2016 layout with rigid-body physics (PhysicsLayout::Settle):
// every bin and the tote, each item dropped and settled in turn. The goal is under 1 s for a
// full layout of about 46 items. Counters: items, solver steps and container retries per
// layout. The layouts come from data/apc2016/tasks; the seed changes with each iteration, so
// the figure is a mean over drops, not one lucky pile.
//
// After a pick (PhysicsLayout::Resettle): pick_layout_1 settled with seed 1, every item of
// every bin taken away in turn and what it supported settled again; the figure is the mean
// time of one such re-settle (most take no step: the item held nothing up), and of those
// where the item held others up. After a release
// (PhysicsLayout::Release): an item let go 0.3 m above stow_layout_1's settled tote pile.
//
//   build/bin/bench_physics_layout --benchmark_min_time=3

#include <benchmark/benchmark.h>

#include <algorithm>
#include <limits>
#include <memory>
#include <string>

#include "libs/apc/catalogue.h"
#include "libs/apc/task.h"
#include "libs/world/cell_config.h"
#include "libs/world/item_models.h"
#include "libs/world/mesh_utils.h"
#include "services/simulator/core/physics_layout.h"

namespace picking::simulator {
namespace {

struct Fixture {
  apc::Catalogue catalogue = apc::Catalogue::FromCsvFile(apc::DefaultCataloguePath());
  world::ItemModelLibrary models{catalogue};
  world::CellModel cell =
      world::LoadCellModel(world::ReadCellConfig(world::DefaultCellConfigPath()));
  PhysicsLayout layout{cell, models};

  apc::Task Task(const std::string& name) const {
    return apc::ReadTaskFile(std::string(PICKING_DATA_DIR) + "/apc2016/tasks/" + name + ".json",
                             catalogue);
  }
};

Fixture& Shared() {
  static Fixture* fixture = new Fixture();
  return *fixture;
}

void BM_SettleLayout(benchmark::State& state, const std::string& name) {
  Fixture& f = Shared();
  const apc::Task task = f.Task(name);
  f.layout.Settle(task, 0);  // item models built once, outside the timing
  std::uint32_t seed = 1;
  double items = 0, steps = 0, retries = 0;
  for (auto _ : state) {
    const SettleResult r = f.layout.Settle(task, seed++);
    items += r.items.size();
    steps += r.steps;
    retries += r.retries;
  }
  const double n = static_cast<double>(state.iterations());
  state.counters["items"] = items / n;
  state.counters["steps"] = steps / n;
  state.counters["retries"] = retries / n;
}

// Each item of each bin of a settled pick_layout_1 taken away in turn; `holding`: only the
// items that held others up.
void BM_ResettleAfterPick(benchmark::State& state, bool holding) {
  Fixture& f = Shared();
  const apc::Task task = f.Task("pick_layout_1");
  const SettleResult layout = f.layout.Settle(task, 1);
  struct Pick {
    std::string bin;
    std::vector<PlacedItem> rest;
    PlacedItem removed;
  };
  std::vector<Pick> picks;
  for (const auto& [bin, names] : task.bin_contents) {
    std::vector<PlacedItem> in_bin;
    for (const PlacedItem& p : layout.items) {
      if (p.container == bin) in_bin.push_back(p);
    }
    for (std::size_t r = 0; r < in_bin.size(); ++r) {
      Pick pick{bin, in_bin, in_bin[r]};
      pick.rest.erase(pick.rest.begin() + r);
      const std::vector<bool> loose = f.layout.Resettle(bin, pick.rest, pick.removed).loose;
      if (!holding || std::find(loose.begin(), loose.end(), true) != loose.end()) {
        picks.push_back(pick);
      }
    }
  }
  std::size_t k = 0;
  double loose = 0, steps = 0, moving = 0;
  for (auto _ : state) {
    const Pick& pick = picks[k++ % picks.size()];
    const RestResult r = f.layout.Resettle(pick.bin, pick.rest, pick.removed);
    const auto n = std::count(r.loose.begin(), r.loose.end(), true);
    loose += n;
    moving += n > 0;
    steps += r.steps;
  }
  const double n = static_cast<double>(state.iterations());
  state.counters["picks"] = static_cast<double>(picks.size());
  state.counters["loose"] = loose / n;
  state.counters["with_loose"] = moving / n;
  state.counters["steps"] = steps / n;
}

// A tissue box let go 0.3 m above the highest item of stow_layout_1's settled tote.
void BM_ReleaseOverTheTote(benchmark::State& state) {
  Fixture& f = Shared();
  const SettleResult layout = f.layout.Settle(f.Task("stow_layout_1"), 1);
  std::vector<PlacedItem> tote;
  double top_z = -std::numeric_limits<double>::infinity();
  for (const PlacedItem& p : layout.items) {
    if (p.container != "tote") continue;
    tote.push_back(p);
    top_z = std::max(top_z, world::Bounds(f.models.Get(p.name)->mesh, p.X_BaseItem).max().z());
  }
  const auto box = f.models.Get("kleenex_tissue_box");
  const Eigen::Vector3d centre_T = f.cell.tote_inner_T().center();
  Eigen::Isometry3d X_BaseItem =
      f.cell.config.X_BaseTote * Eigen::Translation3d(centre_T - box->box_I.center());
  X_BaseItem.translation().z() += top_z + 0.3 - world::Bounds(box->mesh, X_BaseItem).min().z();
  tote.push_back({box->item->name, "tote", X_BaseItem});
  double steps = 0, drop = 0;
  for (auto _ : state) {
    const RestResult r = f.layout.Release("tote", tote, tote.size() - 1);
    steps += r.steps;
    drop = r.drop_height_m;
  }
  state.counters["items"] = static_cast<double>(tote.size());
  state.counters["steps"] = steps / static_cast<double>(state.iterations());
  state.counters["drop_m"] = drop;
}

BENCHMARK_CAPTURE(BM_ResettleAfterPick, every_item, false)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_ResettleAfterPick, items_holding_others, true)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ReleaseOverTheTote)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_SettleLayout, pick_layout_1, std::string("pick_layout_1"))
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_SettleLayout, pick_layout_2, std::string("pick_layout_2"))
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_SettleLayout, pick_layout_3, std::string("pick_layout_3"))
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_SettleLayout, stow_layout_1, std::string("stow_layout_1"))
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_SettleLayout, apc2016_pick_layout_sample,
                  std::string("apc2016_pick_layout_sample"))
    ->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace picking::simulator

BENCHMARK_MAIN();
