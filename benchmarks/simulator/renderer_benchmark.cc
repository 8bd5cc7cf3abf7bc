// Rendering time of the scanner's 44-image sequence (42 Gray-code patterns + white + black)
// at the camera's 1280 x 1024 on a shelf-bin scene: the one-time ray casting (Prepare), the
// per-pattern shading (RenderSequence) and both together.
//
//   build/bin/bench_simulator_renderer --benchmark_min_time=2

#include <benchmark/benchmark.h>

#include <algorithm>

#include <cmath>
#include <vector>

#include "libs/camera/pinhole_camera.h"
#include "libs/world/mesh.h"
#include "libs/world/mesh_utils.h"
#include "services/simulator/core/renderer.h"

namespace picking::simulator {
namespace {

// Rectangle of size_u x size_v (metres) in the x-y plane of its frame, normal +z, split
// into cells x cells squares (2 triangles each), with a faint checker albedo texture.
world::TriangleMesh Grid(double size_u, double size_v, int cells) {
  world::TriangleMesh mesh;
  for (int j = 0; j <= cells; ++j) {
    for (int i = 0; i <= cells; ++i) {
      mesh.vertices.emplace_back(static_cast<float>(size_u * (double(i) / cells - 0.5)),
                                 static_cast<float>(size_v * (double(j) / cells - 0.5)), 0.0f);
      mesh.vertex_albedo.push_back(((i / 4 + j / 4) % 2) ? 0.55f : 0.65f);
    }
  }
  const auto index = [cells](int i, int j) { return std::uint32_t(j * (cells + 1) + i); };
  for (int j = 0; j < cells; ++j) {
    for (int i = 0; i < cells; ++i) {
      mesh.triangles.push_back({index(i, j), index(i + 1, j), index(i + 1, j + 1)});
      mesh.triangles.push_back({index(i, j), index(i + 1, j + 1), index(i, j + 1)});
    }
  }
  return mesh;
}

Eigen::Isometry3d Pose(double x, double y, double z, const Eigen::Matrix3d& R) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = R;
  X.translation() = Eigen::Vector3d(x, y, z);
  return X;
}

Eigen::Matrix3d Rot(double angle, const Eigen::Vector3d& axis) {
  return Eigen::AngleAxisd(angle, axis).toRotationMatrix();
}

// A shelf bin (opening toward -z of the base, 0.27 m wide, 0.22 m high, 0.43 m deep, its
// opening 0.55 m in front of the sensor) with a few items inside, ~25k triangles.
struct Cell {
  std::vector<world::TriangleMesh> meshes;
  std::vector<SceneObject> objects;

  Cell() {
    constexpr double kW = 0.27, kH = 0.22, kD = 0.43, kZ0 = 0.55;
    constexpr int kCells = 48;
    const Eigen::Vector3d x = Eigen::Vector3d::UnitX(), y = Eigen::Vector3d::UnitY();
    meshes.reserve(16);
    std::vector<Eigen::Isometry3d> poses;
    // Walls, normals toward the inside (y is down, as in the camera frame).
    meshes.push_back(Grid(kW, kD, kCells));  // Floor at y = +kH/2, normal -y.
    poses.push_back(Pose(0, kH / 2, kZ0 + kD / 2, Rot(M_PI / 2, x)));
    meshes.push_back(Grid(kW, kD, kCells));  // Ceiling, normal +y.
    poses.push_back(Pose(0, -kH / 2, kZ0 + kD / 2, Rot(-M_PI / 2, x)));
    meshes.push_back(Grid(kD, kH, kCells));  // Left wall, normal +x.
    poses.push_back(Pose(-kW / 2, 0, kZ0 + kD / 2, Rot(M_PI / 2, y)));
    meshes.push_back(Grid(kD, kH, kCells));  // Right wall, normal -x.
    poses.push_back(Pose(kW / 2, 0, kZ0 + kD / 2, Rot(-M_PI / 2, y)));
    meshes.push_back(Grid(kW, kH, kCells));  // Back, normal -z.
    poses.push_back(Pose(0, 0, kZ0 + kD, Rot(M_PI, y)));
    // Items standing on the floor.
    meshes.push_back(world::MakeBox({0.08, 0.12, 0.05}));
    poses.push_back(Pose(-0.07, kH / 2 - 0.06, kZ0 + 0.25, Rot(0.3, y)));
    meshes.push_back(world::MakeBox({0.06, 0.04, 0.15}));
    poses.push_back(Pose(0.06, kH / 2 - 0.02, kZ0 + 0.18, Rot(-0.5, y)));
    meshes.push_back(world::MakeCylinder(0.035, 0.10, 64));
    poses.push_back(Pose(0.08, kH / 2 - 0.05, kZ0 + 0.32, Rot(M_PI / 2, x)));
    meshes.push_back(world::MakeSphere(0.03, 32, 64));
    poses.push_back(Pose(-0.02, kH / 2 - 0.03, kZ0 + 0.12, Eigen::Matrix3d::Identity()));
    for (std::size_t k = 0; k < meshes.size(); ++k) objects.push_back({&meshes[k], poses[k]});
  }
};

// Scanner of the paper: Flea3 1280 x 1024 camera with an 8 mm lens (4.8 um pixels) and a
// LightCrafter 4500 (912 x 1140) 0.15 m to its side, toed in toward the camera axis at 0.6 m.
ScanPose SensorPose() {
  camera::Distortion d;
  d.k1 = -0.09;
  d.k2 = 0.11;
  d.p1 = 0.0004;
  d.p2 = -0.0003;
  const camera::PinholeCamera cam(1280, 1024, 1667.0, 1667.0, 639.5, 511.5, d);
  camera::Distortion dp;
  dp.k1 = 0.02;
  const camera::PinholeCamera projector(912, 1140, 1100.0, 1100.0, 455.5, 569.5, dp);
  Eigen::Isometry3d X_BaseProjector = Eigen::Isometry3d::Identity();
  X_BaseProjector.translation() = Eigen::Vector3d(0.15, 0.0, 0.0);
  X_BaseProjector.linear() = Rot(-std::atan2(0.15, 0.6), Eigen::Vector3d::UnitY());
  return ScanPose{cam, Eigen::Isometry3d::Identity(), projector, X_BaseProjector};
}

// 10 column + 11 row Gray-code bit planes and their inverses (42), then white and black.
std::vector<GrayImage> GrayCodeSequence(int width, int height) {
  std::vector<GrayImage> images;
  auto gray = [](int i) { return i ^ (i >> 1); };
  const int column_bits = static_cast<int>(std::ceil(std::log2(width)));
  const int row_bits = static_cast<int>(std::ceil(std::log2(height)));
  for (int axis = 0; axis < 2; ++axis) {
    const int bits = axis == 0 ? column_bits : row_bits;
    for (int bit = bits - 1; bit >= 0; --bit) {
      GrayImage pattern(width, height), inverse(width, height);
      for (int r = 0; r < height; ++r) {
        for (int c = 0; c < width; ++c) {
          const bool on = (gray(axis == 0 ? c : r) >> bit) & 1;
          pattern.at(c, r) = on ? 255 : 0;
          inverse.at(c, r) = on ? 0 : 255;
        }
      }
      images.push_back(std::move(pattern));
      images.push_back(std::move(inverse));
    }
  }
  images.emplace_back(width, height, 255);
  images.emplace_back(width, height, 0);
  return images;
}

struct Fixture {
  Cell cell;
  StructuredLightRenderer renderer{cell.objects};
  ScanPose pose = SensorPose();
  std::vector<GrayImage> patterns = GrayCodeSequence(912, 1140);
  ScanGeometry geometry = renderer.Prepare(pose);  // Also warms the camera ray cache.
};

Fixture& Shared() {
  static Fixture fixture;
  return fixture;
}

void SetCounters(benchmark::State& state, const Fixture& f) {
  std::size_t lit = 0;
  for (Illumination i : f.geometry.illumination) lit += i == Illumination::kLit;
  state.counters["triangles"] = static_cast<double>(f.renderer.num_triangles());
  state.counters["lit_fraction"] = static_cast<double>(lit) / f.geometry.size();
  state.counters["images"] = static_cast<double>(f.patterns.size());
}

// One-time per scan: camera rays, hits, normals, albedo, shadow rays, projector coordinates.
// The ScanGeometry is reused across scans, as the scanner's loop does.
void BM_RayCasting(benchmark::State& state) {
  Fixture& f = Shared();
  ScanGeometry g;
  for (auto _ : state) {
    f.renderer.Prepare(f.pose, {}, &g);
    benchmark::DoNotOptimize(g.gain.data());
  }
  SetCounters(state, f);
}
BENCHMARK(BM_RayCasting)->Unit(benchmark::kMillisecond)->UseRealTime()->MeasureProcessCPUTime();

// The 44 camera images from a prepared geometry, into reused image buffers. Arg: projector
// blur sigma in 1/10 projector pixels (0 = off).
void BM_Shading44(benchmark::State& state) {
  Fixture& f = Shared();
  RenderOptions options;
  options.projector_blur_sigma_px = state.range(0) / 10.0;
  std::vector<GrayImage> images;
  for (auto _ : state) {
    RenderSequence(f.geometry, f.patterns, options, &images);
    benchmark::DoNotOptimize(images.data());
  }
  SetCounters(state, f);
}
BENCHMARK(BM_Shading44)
    ->Arg(0)
    ->Arg(10)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MeasureProcessCPUTime();

// Ground-truth depth of the same camera (RenderDepth: camera rays only, no projector).
void BM_RenderDepth(benchmark::State& state) {
  Fixture& f = Shared();
  std::size_t hits = 0;
  for (auto _ : state) {
    const DepthImage depth = f.renderer.RenderDepth(f.pose.camera, f.pose.X_BaseCamera);
    hits = static_cast<std::size_t>(
        std::count_if(depth.depth_m.begin(), depth.depth_m.end(), [](float d) { return d == d; }));
    benchmark::DoNotOptimize(depth.depth_m.data());
  }
  SetCounters(state, f);
  state.counters["hit_fraction"] = static_cast<double>(hits) / f.geometry.size();
}
BENCHMARK(BM_RenderDepth)->Unit(benchmark::kMillisecond)->UseRealTime()->MeasureProcessCPUTime();

// The 44 images one RenderImage call each (fresh image, tables and threads per frame), as
// the simulator service rendered them before. Arg: projector blur sigma in 1/10 pixels.
void BM_Shading44PerImage(benchmark::State& state) {
  Fixture& f = Shared();
  RenderOptions options;
  options.projector_blur_sigma_px = state.range(0) / 10.0;
  for (auto _ : state) {
    for (std::size_t k = 0; k < f.patterns.size(); ++k) {
      const GrayImage image = RenderImage(f.geometry, f.patterns[k], options, k);
      benchmark::DoNotOptimize(image.pixels.data());
    }
  }
  SetCounters(state, f);
}
BENCHMARK(BM_Shading44PerImage)
    ->Arg(0)
    ->Arg(6)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MeasureProcessCPUTime();

// The 44 images in parts of 4 frames into reused buffers (RenderSequence with first_frame),
// as the simulator service streams them. Arg: projector blur sigma in 1/10 pixels.
void BM_Shading44InPartsOf4(benchmark::State& state) {
  Fixture& f = Shared();
  RenderOptions options;
  options.projector_blur_sigma_px = state.range(0) / 10.0;
  std::vector<GrayImage> part(4), images;
  for (auto _ : state) {
    for (std::size_t first = 0; first < f.patterns.size(); first += 4) {
      const std::size_t count = std::min<std::size_t>(4, f.patterns.size() - first);
      part.assign(f.patterns.begin() + first, f.patterns.begin() + first + count);
      RenderSequence(f.geometry, part, options, &images, first);
      benchmark::DoNotOptimize(images.data());
    }
  }
  SetCounters(state, f);
}
BENCHMARK(BM_Shading44InPartsOf4)
    ->Arg(0)
    ->Arg(6)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MeasureProcessCPUTime();

// A whole scan: ray casting once, then the 44 images, all buffers reused.
void BM_FullScan44(benchmark::State& state) {
  Fixture& f = Shared();
  const RenderOptions options;
  ScanGeometry g;
  std::vector<GrayImage> images;
  for (auto _ : state) {
    f.renderer.Prepare(f.pose, {}, &g);
    RenderSequence(g, f.patterns, options, &images);
    benchmark::DoNotOptimize(images.data());
  }
  SetCounters(state, f);
}
BENCHMARK(BM_FullScan44)->Unit(benchmark::kMillisecond)->UseRealTime()->MeasureProcessCPUTime();

// The same with fresh buffers every scan (the value-returning overloads): shows the cost of
// allocating and first touching ~120 MB per scan.
void BM_FullScan44Allocating(benchmark::State& state) {
  Fixture& f = Shared();
  const RenderOptions options;
  for (auto _ : state) {
    const ScanGeometry g = f.renderer.Prepare(f.pose);
    std::vector<GrayImage> images = RenderSequence(g, f.patterns, options);
    benchmark::DoNotOptimize(images.data());
  }
  SetCounters(state, f);
}
BENCHMARK(BM_FullScan44Allocating)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MeasureProcessCPUTime();

// Moving one item (an item picked or dropped): vertex update and BVH rebuild.
void BM_MoveObject(benchmark::State& state) {
  Fixture& f = Shared();
  const std::size_t item = f.cell.objects.size() - 1;
  const Eigen::Isometry3d X_BaseItem = f.cell.objects[item].X_BaseObject;
  int step = 0;
  for (auto _ : state) {
    Eigen::Isometry3d X = X_BaseItem;
    X.translation().x() += 0.001 * (++step % 10);
    f.renderer.SetObjectPose(item, X);
  }
  f.renderer.SetObjectPose(item, X_BaseItem);
  SetCounters(state, f);
}
BENCHMARK(BM_MoveObject)->Unit(benchmark::kMillisecond)->UseRealTime()->MeasureProcessCPUTime();

// Building the scene from scratch (copy of the meshes, Embree BVH build).
void BM_BuildScene(benchmark::State& state) {
  Fixture& f = Shared();
  for (auto _ : state) {
    StructuredLightRenderer renderer(f.cell.objects);
    benchmark::DoNotOptimize(renderer.num_triangles());
  }
  SetCounters(state, f);
}
BENCHMARK(BM_BuildScene)->Unit(benchmark::kMillisecond)->UseRealTime()->MeasureProcessCPUTime();

}  // namespace
}  // namespace picking::simulator

BENCHMARK_MAIN();
