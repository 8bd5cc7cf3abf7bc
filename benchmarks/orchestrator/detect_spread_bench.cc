// The detection of a three-view step through the orchestrator's detector pool: one
// picking-detector replica pinned to one core against two replicas pinned to a core each, on
// the same requests. Each request is what the orchestrator sends for a target: the three views
// of its bin stacked (simulated structured-light scans of pick_layout_N laid out with the
// seed), the bin's region, and one query for the target and one for each other item of the
// bin. One replica answers them in one call (DetectorPool::Detect); two answer them spread
// (DetectorPool::DetectSpread: the items split over the replicas, each preparing the scene).
//
//   bench_detect_spread [--layout=1] [--seed=7] [--bins=A,B,...] [--cache_dir=DIR]
//
// Prints per bin the wall time of both and their ratio, then the total; the goal is a ratio of
// at most 0.6. The models are built into the detector's cache (--cache_dir, default the
// detector's) on the first run, which takes a few minutes.
#include <sched.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "benchmarks/detector_eval/bin_detection.h"
#include "benchmarks/detector_eval/bin_scan_sim.h"
#include "libs/apc/catalogue.h"
#include "libs/proto_convert/proto_convert.h"
#include "services/orchestrator/detector_pool/detector_pool.h"
#include "tests/harness/server_process.h"

namespace picking::orchestrator {
namespace {

namespace dt = ::picking::detector::v1;
using Clock = std::chrono::steady_clock;

struct Args {
  std::string layout = "1";
  std::uint32_t seed = 7;
  std::vector<std::string> bins;  // empty: every bin of the work order
  std::string cache_dir;          // empty: the detector's default cache
};

Args ParseArgs(int argc, char** argv) {
  Args args;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&](const char* key) -> const char* {
      const std::string prefix = std::string("--") + key + "=";
      return a.rfind(prefix, 0) == 0 ? argv[i] + prefix.size() : nullptr;
    };
    if (const char* v = value("layout")) {
      args.layout = v;
    } else if (const char* v = value("seed")) {
      args.seed = static_cast<std::uint32_t>(std::stoul(v));
    } else if (const char* v = value("cache_dir")) {
      args.cache_dir = v;
    } else if (const char* v = value("bins")) {
      std::string list = v;
      for (std::size_t start = 0; start <= list.size();) {
        const std::size_t comma = std::min(list.find(',', start), list.size());
        if (comma > start) args.bins.push_back("bin_" + list.substr(start, comma - start));
        start = comma + 1;
      }
    } else {
      throw std::invalid_argument("unknown argument '" + a +
                                  "'; usage: bench_detect_spread [--layout=1] [--seed=7] "
                                  "[--bins=A,B] [--cache_dir=DIR]");
    }
  }
  return args;
}

// Every thread of process `pid` on core `cpu` (threads it makes later inherit it).
void PinToCore(pid_t pid, int cpu) {
  cpu_set_t set;
  CPU_ZERO(&set);
  CPU_SET(cpu, &set);
  for (const auto& task :
       std::filesystem::directory_iterator("/proc/" + std::to_string(pid) + "/task")) {
    const pid_t tid = static_cast<pid_t>(std::stol(task.path().filename().string()));
    if (sched_setaffinity(tid, sizeof(set), &set) != 0) {
      throw std::runtime_error("cannot pin thread " + std::to_string(tid) + " to core " +
                               std::to_string(cpu));
    }
  }
}

// The request the orchestrator sends for `target` (GrpcCell::Detect): the stacked views,
// their sensor poses, the bin's region and a query per item of the bin, the target first.
DetectCall RequestFor(const detector_eval::BinScan& scan, const std::string& target) {
  DetectCall call;
  std::vector<std::string> items = {target};
  for (const detector_eval::TrueItem& t : scan.items) {
    if (std::find(items.begin(), items.end(), t.name) == items.end()) items.push_back(t.name);
  }
  for (const std::string& item : items) {
    auto* query = call.params.add_queries();
    query->set_item(item);
    query->set_max_results(items.size() > 1 ? 3 : 1);
  }
  auto* region = call.params.mutable_region();
  *region->mutable_x_frame_region() = proto_convert::PoseToProto(scan.bin_box.X_BaseBox);
  *region->mutable_size_m() = proto_convert::VectorToProto(scan.bin_box.size_m);
  region->set_wall_margin_m(0.01);
  for (const Eigen::Isometry3d& pose : scan.view_poses) {
    *call.params.add_x_frame_sensor() = proto_convert::PoseToProto(pose);
  }
  auto chunks = proto_convert::CloudToChunks(scan.cloud);
  *chunks.front().mutable_header()->mutable_x_frame_sensor() =
      proto_convert::PoseToProto(scan.X_BaseCamera);
  call.cloud =
      std::make_shared<const std::vector<picking::common::v1::PointCloudChunk>>(std::move(chunks));
  call.deadline_s = 120.0;
  return call;
}

std::unique_ptr<DetectorPool> MakePool(const std::vector<const testing::ServerProcess*>& servers) {
  DetectorPoolOptions options;
  for (const auto* s : servers) options.endpoints.push_back(s->address());
  options.health_period_s = 0.0;
  options.deadline_s = 120.0;
  return std::make_unique<DetectorPool>(std::move(options));
}

double Seconds(Clock::time_point since) {
  return std::chrono::duration<double>(Clock::now() - since).count();
}

// The scene's preparation in a replica's answer (receiving the scan, cropping, walls, floor,
// normals, view merge; the smallest preprocess time of its detections), seconds; 0 without
// detections.
double PreparationSeconds(const DetectOutcome& outcome) {
  double prep_s = 0.0;
  for (const dt::ItemResult& r : outcome.response.results()) {
    for (const dt::Detection& d : r.detections()) {
      const double s = d.timings().preprocess_s();
      if (prep_s == 0.0 || s < prep_s) prep_s = s;
    }
  }
  return prep_s;
}

// The target's best pose, for telling whether both answers agree.
std::string Best(const DetectOutcome& outcome) {
  if (!outcome.ok()) return "error: " + outcome.status.error_message();
  const dt::ItemResult& r = outcome.response.results(0);
  if (r.detections_size() == 0) return "none";
  const auto& p = r.detections(0).x_frame_item().position();
  char text[96];
  std::snprintf(text, sizeof(text), "%.3f %.3f %.3f", p.x(), p.y(), p.z());
  return text;
}

int Run(const Args& args) {
  const std::string data_dir = apc::DefaultDataDir();
  detector_eval::SimulatedBinScanner scanner(data_dir);
  const apc::Task task =
      scanner.ReadTask(data_dir + "/apc2016/tasks/pick_layout_" + args.layout + ".json");
  scanner.LoadTask(task, args.seed);
  std::vector<std::string> flags;
  if (!args.cache_dir.empty()) flags.push_back("--cache_dir=" + args.cache_dir);
  // The first replica builds the models into the cache; the second then loads them.
  testing::ServerProcess first(testing::ServerBinary("picking-detector"), flags,
                               std::chrono::minutes(20));
  testing::ServerProcess second(testing::ServerBinary("picking-detector"), flags,
                                std::chrono::minutes(20));
  PinToCore(first.pid(), 0);
  PinToCore(second.pid(), 1);
  const auto one = MakePool({&first});
  const auto two = MakePool({&first, &second});

  std::printf(
      "| bin | target | items | one replica (s) | its scene preparation (s) | two replicas (s) | "
      "ratio | same pose |\n");
  std::printf("|---|---|---|---|---|---|---|---|\n");
  double total_one = 0.0, total_two = 0.0;
  int agree = 0, runs = 0;
  for (const apc::WorkOrderEntry& entry : task.work_order) {
    if (!args.bins.empty() &&
        std::find(args.bins.begin(), args.bins.end(), entry.bin) == args.bins.end()) {
      continue;
    }
    const DetectCall call = RequestFor(detector_eval::ScanViews(scanner, entry.bin), entry.item);
    if (runs == 0) one->Detect(call);  // warm up: connections, models paged in
    auto start = Clock::now();
    const DetectOutcome alone = one->Detect(call);
    const double one_s = Seconds(start);
    start = Clock::now();
    const DetectOutcome spread = two->DetectSpread(call);
    const double two_s = Seconds(start);
    if (!alone.ok() || !spread.ok()) {
      std::cerr << entry.bin << ": " << alone.status.error_message() << " / "
                << spread.status.error_message() << "\n";
      return 2;
    }
    const bool same = Best(alone) == Best(spread);
    agree += same;
    ++runs;
    total_one += one_s;
    total_two += two_s;
    std::printf("| %s | %s | %d | %.2f | %.2f | %.2f | %.2f | %s |\n", entry.bin.c_str(),
                entry.item.c_str(), call.params.queries_size(), one_s, PreparationSeconds(alone),
                two_s, two_s / one_s, same ? "yes" : "no");
    std::fflush(stdout);
  }
  if (runs == 0) throw std::invalid_argument("no bin of the work order selected");
  std::printf(
      "\ntotal: one replica %.2f s, two replicas %.2f s, ratio %.2f (goal <= 0.6); the "
      "target's best pose the same in %d of %d\n",
      total_one, total_two, total_two / total_one, agree, runs);
  return 0;
}

}  // namespace
}  // namespace picking::orchestrator

int main(int argc, char** argv) {
  try {
    return picking::orchestrator::Run(picking::orchestrator::ParseArgs(argc, argv));
  } catch (const std::exception& e) {
    std::cerr << "bench_detect_spread: " << e.what() << "\n";
    return 1;
  }
}
