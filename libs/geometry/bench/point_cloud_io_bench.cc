// Read and write speed of the point cloud formats on real data: the APC scissors model
// (37,450 coloured points) and the organised Kinect scene (307,200 points, colours).

#include <benchmark/benchmark.h>

#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <string>

#include "libs/geometry/point_cloud_io.h"

namespace picking::geometry {
namespace {

const std::string kModel = std::string(PICKING_TEST_DATA_DIR) + "/models/fiskars_scissors_red.ply";
const std::string kScene =
    std::string(PICKING_TEST_DATA_DIR) + "/pointclouds/milk_cartoon_all_small_clorox.pcd";

const PointCloud& Scene() {
  static const PointCloud scene = ReadPointCloud(kScene);
  return scene;
}

std::string TempPath(const char* name) {
  return (std::filesystem::temp_directory_path() /
          ("picking_bench_" + std::to_string(::getpid()) + "_" + name))
      .string();
}

const char* Extension(PointCloudFormat f) {
  return f == PointCloudFormat::kPlyAscii || f == PointCloudFormat::kPlyBinaryLittleEndian ||
                 f == PointCloudFormat::kPlyBinaryBigEndian
             ? "scene.ply"
             : "scene.pcd";
}

void BM_ReadApcModelBinaryPly(benchmark::State& state) {
  std::size_t n = 0;
  for (auto _ : state) {
    const PointCloud cloud = ReadPointCloud(kModel);
    n = cloud.size();
    benchmark::DoNotOptimize(cloud.points.data());
  }
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * n));
}
BENCHMARK(BM_ReadApcModelBinaryPly)->Unit(benchmark::kMillisecond);

void BM_WriteScene(benchmark::State& state) {
  const auto format = static_cast<PointCloudFormat>(state.range(0));
  const std::string path = TempPath(Extension(format));
  for (auto _ : state) WritePointCloud(path, Scene(), format);
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * Scene().size()));
  std::remove(path.c_str());
}

void BM_ReadScene(benchmark::State& state) {
  const auto format = static_cast<PointCloudFormat>(state.range(0));
  const std::string path = TempPath(Extension(format));
  WritePointCloud(path, Scene(), format);
  for (auto _ : state) {
    const PointCloud cloud = ReadPointCloud(path);
    benchmark::DoNotOptimize(cloud.points.data());
  }
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * Scene().size()));
  std::remove(path.c_str());
}

// Argument: PointCloudFormat as int (0 PLY ascii, 1 PLY binary LE, 2 PLY binary BE,
// 3 PCD ascii, 4 PCD binary, 5 PCD binary_compressed).
BENCHMARK(BM_WriteScene)->DenseRange(0, 5)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ReadScene)->DenseRange(0, 5)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace picking::geometry

BENCHMARK_MAIN();
