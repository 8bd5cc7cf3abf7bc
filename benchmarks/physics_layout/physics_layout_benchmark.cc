// Time to settle a whole APC 2016 layout with rigid-body physics (PhysicsLayout::Settle):
// every bin and the tote, each item dropped and settled in turn. The goal is under 1 s for a
// full layout of about 46 items. Counters: items, solver steps and container retries per
// layout. The layouts come from data/apc2016/tasks; the seed changes with each iteration, so
// the figure is a mean over drops, not one lucky pile.
//
//   build/bin/bench_physics_layout --benchmark_min_time=3

#include <benchmark/benchmark.h>

#include <memory>
#include <string>

#include "libs/apc/catalogue.h"
#include "libs/apc/task.h"
#include "libs/world/cell_config.h"
#include "libs/world/item_models.h"
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
