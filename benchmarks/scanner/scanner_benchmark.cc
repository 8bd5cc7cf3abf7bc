// Decoding speed and quality of the scanner's Gray-code decoder against OpenCV's
// cv::structured_light::GrayCodePattern on the same synthetic 1280 x 1024 captures of a
// tilted plane and a sphere (rendered once, seeded, with blur, noise, gamma and ambient
// light), and the decode + triangulate + normals pipeline of one view; then the optional
// sub-pixel refinement stage, sub-pixel triangulation and the decode + refine + triangulate
// + normals pipeline on area-sampled captures of the same scene (each camera pixel
// integrates 4 x 4 rays, so pixels straddling a stripe edge are mixed as in a real camera).
//
// Counters: decoded = decoded fraction of all camera pixels; precision = fraction of the
// decoded pixels whose column and row equal the ground truth; precision_pm1 = within +-1.
// Refinement: coverage = fraction of all camera pixels with a point (or a refined
// correspondence); col_err_px / row_err_px = median |sub-pixel - true projector coordinate|;
// depth_err_mm = median |z - true z| of the points.
// BM_DecodeRefineTriangulateNormals/1/* is the scan pipeline's path (triangulation,
// filtering and normals in one streamed pass); /0/* runs Triangulator::Run and
// EstimateNormals apart. The second argument: 1 refines projector rows too, 0 only columns
// (ScanOptions' default). BM_ScanPipelineProcessView runs ScanPipeline::ProcessView with the
// default ScanOptions: what the scanner server does with one view's captures, including a
// fresh cloud per call.

#include "services/scanner/core/decoder.h"
#include "services/scanner/core/normals.h"
#include "services/scanner/core/patterns.h"
#include "services/scanner/core/scan_pipeline.h"
#include "services/scanner/core/synthetic_capture.h"
#include "services/scanner/core/triangulation.h"

#include <benchmark/benchmark.h>
#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/structured_light.hpp>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <iostream>
#include <stdexcept>
#include <vector>

namespace picking::scanner {
namespace {

constexpr int kMinContrast = 16;
constexpr int kMinBitContrast = 5;  // OpenCV's default white threshold.

SyntheticScene BenchmarkScene() {
  SyntheticScene scene;
  SyntheticPlane plane;
  plane.normal = Eigen::Vector3d(0.25, -0.1, 1.0).normalized();
  plane.offset_m = plane.normal.dot(Eigen::Vector3d(0, 0, 1.0));
  scene.planes.push_back(plane);
  SyntheticSphere sphere;
  sphere.center_m = Eigen::Vector3d(-0.03, 0.02, 0.85);
  sphere.radius_m = 0.09;
  scene.spheres.push_back(sphere);
  return scene;
}

SyntheticCaptureOptions BenchmarkCaptureOptions(int samples_per_axis) {
  SyntheticCaptureOptions options;
  options.blur_sigma_px = 0.6;
  options.noise_sigma = 2.0;
  options.gamma = 1.3;
  options.ambient_level = 25.0;
  options.seed = 42;
  options.samples_per_axis = samples_per_axis;
  return options;
}

struct Fixture {
  ScannerRig rig = MakeExampleRig(1280, 1024);
  PatternSequence patterns;
  SyntheticCapture capture;
  std::vector<ImageView> views;
  // OpenCV's inputs: its own pattern order, pointing at the same capture buffers.
  cv::Ptr<cv::structured_light::GrayCodePattern> opencv;
  std::vector<cv::Mat> opencv_patterns;
  cv::Mat white;
  cv::Mat black;

  Fixture() {
    capture = RenderSyntheticCapture(rig, patterns, BenchmarkScene(), BenchmarkCaptureOptions(1));
    views = capture.views();

    cv::structured_light::GrayCodePattern::Params params;
    params.width = patterns.projector_width();
    params.height = patterns.projector_height();
    opencv = cv::structured_light::GrayCodePattern::create(params);
    opencv->setWhiteThreshold(kMinBitContrast);
    opencv->setBlackThreshold(kMinContrast);
    // Find, for each image OpenCV generates, the image of our sequence that shows the same
    // thing, and hand OpenCV our capture of it: both decoders decode the same captures.
    std::vector<cv::Mat> generated;
    opencv->generate(generated);
    for (const cv::Mat& image : generated) {
      cv::Mat gray = image;
      if (image.channels() == 3) cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
      int match = -1;
      for (int k = 0; k < patterns.num_images() && match < 0; ++k) {
        const std::vector<std::uint8_t> ours = patterns.Render(k);
        const cv::Mat ours_mat(patterns.projector_height(), patterns.projector_width(), CV_8U,
                               const_cast<std::uint8_t*>(ours.data()));
        if (cv::norm(gray, ours_mat, cv::NORM_INF) == 0) match = k;
      }
      if (match < 0) throw std::runtime_error("an OpenCV pattern matches none of ours");
      opencv_patterns.push_back(WrapCapture(match));
    }
    white = WrapCapture(PatternSequence::kWhiteIndex);
    black = WrapCapture(PatternSequence::kBlackIndex);
  }

  cv::Mat WrapCapture(int k) {
    return cv::Mat(capture.height, capture.width, CV_8U, capture.images[k].data());
  }
};

Fixture& GetFixture() {
  static Fixture* fixture = new Fixture();
  return *fixture;
}

void ReportQuality(benchmark::State& state, const CorrespondenceMap& map) {
  const Fixture& f = GetFixture();
  std::size_t decoded = 0;
  std::size_t exact = 0;
  std::size_t within_one = 0;
  for (std::size_t i = 0; i < map.valid.size(); ++i) {
    if (!map.valid[i]) continue;
    ++decoded;
    const int dc = std::abs(map.column[i] - f.capture.column[i]);
    const int dr = std::abs(map.row[i] - f.capture.row[i]);
    exact += dc == 0 && dr == 0;
    within_one += dc <= 1 && dr <= 1;
  }
  state.counters["decoded"] = static_cast<double>(decoded) / map.valid.size();
  state.counters["precision"] = decoded ? static_cast<double>(exact) / decoded : 0.0;
  state.counters["precision_pm1"] = decoded ? static_cast<double>(within_one) / decoded : 0.0;
}

void BM_Decode(benchmark::State& state) {
  Fixture& f = GetFixture();
  DecoderOptions options;
  options.min_contrast = kMinContrast;
  options.min_bit_contrast = kMinBitContrast;
  options.num_threads = static_cast<int>(state.range(0));
  const GrayCodeDecoder decoder(f.patterns, options);
  CorrespondenceMap map;
  for (auto _ : state) {
    decoder.Decode(f.views, &map);
    benchmark::DoNotOptimize(map.num_valid);
  }
  ReportQuality(state, map);
}
BENCHMARK(BM_Decode)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

// OpenCV's per-pixel decode for rows [y0, y1), with the same shadow test as ours.
void OpenCvDecodeRows(const Fixture& f, int y0, int y1, CorrespondenceMap* map) {
  for (int y = y0; y < y1; ++y) {
    for (int x = 0; x < map->width; ++x) {
      const std::size_t i = static_cast<std::size_t>(y) * map->width + x;
      map->valid[i] = 0;
      if (f.white.at<std::uint8_t>(y, x) - f.black.at<std::uint8_t>(y, x) < kMinContrast) {
        continue;
      }
      cv::Point projector_pixel;
      const bool error = f.opencv->getProjPixel(f.opencv_patterns, x, y, projector_pixel);
      if (error || projector_pixel.x >= f.patterns.projector_width() ||
          projector_pixel.y >= f.patterns.projector_height()) {
        continue;
      }
      map->valid[i] = 1;
      map->column[i] = static_cast<std::uint16_t>(projector_pixel.x);
      map->row[i] = static_cast<std::uint16_t>(projector_pixel.y);
    }
  }
}

CorrespondenceMap EmptyMap(const Fixture& f) {
  CorrespondenceMap map;
  map.width = f.capture.width;
  map.height = f.capture.height;
  const std::size_t n = static_cast<std::size_t>(map.width) * map.height;
  map.column.assign(n, 0);
  map.row.assign(n, 0);
  map.valid.assign(n, 0);
  return map;
}

void CountValid(CorrespondenceMap* map) {
  map->num_valid = 0;
  for (std::uint8_t v : map->valid) map->num_valid += v;
}

void BM_OpenCvGetProjPixel(benchmark::State& state) {
  Fixture& f = GetFixture();
  CorrespondenceMap map = EmptyMap(f);
  for (auto _ : state) {
    OpenCvDecodeRows(f, 0, map.height, &map);
    CountValid(&map);
  }
  ReportQuality(state, map);
}
BENCHMARK(BM_OpenCvGetProjPixel)->Unit(benchmark::kMillisecond)->Iterations(2)->UseRealTime();

void BM_OpenCvGetProjPixelParallel(benchmark::State& state) {
  Fixture& f = GetFixture();
  CorrespondenceMap map = EmptyMap(f);
  for (auto _ : state) {
    cv::parallel_for_(cv::Range(0, map.height), [&](const cv::Range& rows) {
      OpenCvDecodeRows(f, rows.start, rows.end, &map);
    });
    CountValid(&map);
  }
  state.counters["threads"] = cv::getNumThreads();
  ReportQuality(state, map);
}
BENCHMARK(BM_OpenCvGetProjPixelParallel)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(3)
    ->UseRealTime();

void BM_Triangulate(benchmark::State& state) {
  Fixture& f = GetFixture();
  const GrayCodeDecoder decoder(f.patterns, DecoderOptions{kMinContrast, kMinBitContrast, 0});
  const CorrespondenceMap map = decoder.Decode(f.views);
  const Triangulator triangulator(f.rig.camera, f.rig.projector, f.rig.X_CameraProjector);
  TriangulationResult result;
  for (auto _ : state) {
    triangulator.Run(map, &f.views[PatternSequence::kWhiteIndex], &result);
    benchmark::DoNotOptimize(result.num_points);
  }
  state.counters["points"] = static_cast<double>(result.num_points);
}
BENCHMARK(BM_Triangulate)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_Normals(benchmark::State& state) {
  Fixture& f = GetFixture();
  const GrayCodeDecoder decoder(f.patterns, DecoderOptions{kMinContrast, kMinBitContrast, 0});
  const Triangulator triangulator(f.rig.camera, f.rig.projector, f.rig.X_CameraProjector);
  TriangulationResult result = triangulator.Run(decoder.Decode(f.views));
  NormalResult normals;
  for (auto _ : state) {
    normals = EstimateNormals(&result.cloud);
    benchmark::DoNotOptimize(normals.num_normals);
  }
  state.counters["normals"] = static_cast<double>(normals.num_normals);
}
BENCHMARK(BM_Normals)->Unit(benchmark::kMillisecond)->UseRealTime();

// One view end to end: 44 captures in, organised cloud with intensities and normals out.
void BM_DecodeTriangulateNormals(benchmark::State& state) {
  Fixture& f = GetFixture();
  const GrayCodeDecoder decoder(f.patterns, DecoderOptions{kMinContrast, kMinBitContrast, 0});
  const Triangulator triangulator(f.rig.camera, f.rig.projector, f.rig.X_CameraProjector);
  CorrespondenceMap map;
  TriangulationResult result;
  NormalResult normals;
  for (auto _ : state) {
    decoder.Decode(f.views, &map);
    triangulator.Run(map, &f.views[PatternSequence::kWhiteIndex], &result);
    normals = EstimateNormals(&result.cloud);
    benchmark::DoNotOptimize(normals.num_normals);
  }
  state.counters["points"] = static_cast<double>(result.num_points);
  state.counters["normals"] = static_cast<double>(normals.num_normals);
}
BENCHMARK(BM_DecodeTriangulateNormals)->Unit(benchmark::kMillisecond)->UseRealTime();

// The same scene rendered with area sampling, for the refinement benchmarks.
struct AreaSampledFixture {
  ScannerRig rig = MakeExampleRig(1280, 1024);
  PatternSequence patterns;
  SyntheticCapture capture;
  std::vector<ImageView> views;
  CorrespondenceMap decoded;

  AreaSampledFixture() {
    capture = RenderSyntheticCapture(rig, patterns, BenchmarkScene(), BenchmarkCaptureOptions(4));
    views = capture.views();
    decoded =
        GrayCodeDecoder(patterns, DecoderOptions{kMinContrast, kMinBitContrast, 0}).Decode(views);
  }
};

AreaSampledFixture& GetAreaSampledFixture() {
  static AreaSampledFixture* fixture = new AreaSampledFixture();
  return *fixture;
}

double Median(std::vector<double> values) {
  if (values.empty()) return std::nan("");
  std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
  return values[values.size() / 2];
}

void ReportRefinement(benchmark::State& state, const CorrespondenceMap& map) {
  const AreaSampledFixture& f = GetAreaSampledFixture();
  std::vector<double> column_errors;
  std::vector<double> row_errors;
  for (std::size_t i = 0; i < map.valid.size(); ++i) {
    if (!map.valid[i] || std::isnan(f.capture.column_exact[i])) continue;
    column_errors.push_back(std::abs(map.column_subpixel[i] - f.capture.column_exact[i]));
    row_errors.push_back(std::abs(map.row_subpixel[i] - f.capture.row_exact[i]));
  }
  state.counters["coverage"] = map.decoded_fraction();
  state.counters["col_err_px"] = Median(column_errors);
  state.counters["row_err_px"] = Median(row_errors);
}

void ReportPoints(benchmark::State& state, const TriangulationResult& result) {
  const AreaSampledFixture& f = GetAreaSampledFixture();
  std::vector<double> errors;
  for (std::size_t i = 0; i < result.cloud.points.size(); ++i) {
    const float z = result.cloud.points[i].z();
    if (!std::isnan(z) && !std::isnan(f.capture.depth_m[i])) {
      errors.push_back(std::abs(z - f.capture.depth_m[i]));
    }
  }
  state.counters["points"] = static_cast<double>(result.num_points);
  state.counters["coverage"] =
      static_cast<double>(result.num_points) / static_cast<double>(result.cloud.points.size());
  state.counters["depth_err_mm"] = Median(errors) * 1e3;
}

// The refinement stage alone: from the decoded map (copied in, as Decode would have
// written it) to the sub-pixel maps.
// Arguments: threads, refine rows too (1) or columns only (0).
void BM_Refine(benchmark::State& state) {
  AreaSampledFixture& f = GetAreaSampledFixture();
  RefinementOptions options;
  options.num_threads = static_cast<int>(state.range(0));
  options.refine_rows = state.range(1) != 0;
  const SubpixelRefiner refiner(f.patterns, options);
  CorrespondenceMap map = f.decoded;
  RefinementResult result;
  for (auto _ : state) {
    state.PauseTiming();
    map.valid = f.decoded.valid;  // Refine may have invalidated pixels.
    map.column = f.decoded.column;
    map.row = f.decoded.row;
    map.num_valid = f.decoded.num_valid;
    state.ResumeTiming();
    result = refiner.Refine(f.views, &map);
    benchmark::DoNotOptimize(result.num_refined);
  }
  ReportRefinement(state, map);
  state.counters["rejected"] = static_cast<double>(result.num_rejected);
}
BENCHMARK(BM_Refine)
    ->Args({1, 1})
    ->Args({2, 1})
    ->Args({1, 0})
    ->Args({2, 0})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// Integer decode on the area-sampled captures, for comparison with the refined runs.
void BM_TriangulateInteger_AreaSampled(benchmark::State& state) {
  AreaSampledFixture& f = GetAreaSampledFixture();
  const Triangulator triangulator(f.rig.camera, f.rig.projector, f.rig.X_CameraProjector);
  TriangulationResult result;
  for (auto _ : state) {
    triangulator.Run(f.decoded, &f.views[PatternSequence::kWhiteIndex], &result);
    benchmark::DoNotOptimize(result.num_points);
  }
  ReportPoints(state, result);
}
BENCHMARK(BM_TriangulateInteger_AreaSampled)->Unit(benchmark::kMillisecond)->UseRealTime();

// Argument: rows refined too (1) or integer rows (0).
void BM_TriangulateSubpixel(benchmark::State& state) {
  AreaSampledFixture& f = GetAreaSampledFixture();
  CorrespondenceMap map = f.decoded;
  RefinementOptions options;
  options.refine_rows = state.range(0) != 0;
  SubpixelRefiner(f.patterns, options).Refine(f.views, &map);
  const Triangulator triangulator(f.rig.camera, f.rig.projector, f.rig.X_CameraProjector);
  TriangulationResult result;
  for (auto _ : state) {
    triangulator.Run(map, &f.views[PatternSequence::kWhiteIndex], &result);
    benchmark::DoNotOptimize(result.num_points);
  }
  ReportPoints(state, result);
}
BENCHMARK(BM_TriangulateSubpixel)->Arg(1)->Arg(0)->Unit(benchmark::kMillisecond)->UseRealTime();

// One view end to end with refinement: 44 captures in, organised cloud with intensities and
// normals from sub-pixel correspondences out.
void BM_DecodeRefineTriangulateNormals(benchmark::State& state) {
  AreaSampledFixture& f = GetAreaSampledFixture();
  const GrayCodeDecoder decoder(f.patterns, DecoderOptions{kMinContrast, kMinBitContrast, 0});
  // The scan pipeline's refinement options (unrefined pixels keep their integer
  // correspondence), with or without the rows.
  RefinementOptions refinement = ScanOptions{}.refinement;
  refinement.refine_rows = state.range(1) != 0;
  const SubpixelRefiner refiner(f.patterns, refinement);
  const Triangulator triangulator(f.rig.camera, f.rig.projector, f.rig.X_CameraProjector);
  CorrespondenceMap map;
  TriangulationResult result;
  NormalResult normals;
  for (auto _ : state) {
    decoder.Decode(f.views, &map);
    refiner.Refine(f.views, &map);
    if (state.range(0) == 1) {
      triangulator.Run(map, &f.views[PatternSequence::kWhiteIndex], NormalOptions{}, &result,
                       &normals);
    } else {
      triangulator.Run(map, &f.views[PatternSequence::kWhiteIndex], &result);
      normals = EstimateNormals(&result.cloud);
    }
    benchmark::DoNotOptimize(normals.num_normals);
  }
  ReportPoints(state, result);
  state.counters["normals"] = static_cast<double>(normals.num_normals);
}
// First argument 1: triangulation and normals in one pass (Triangulator::Run with
// NormalOptions, as ScanPipeline does); 0: Run, then EstimateNormals. Second argument: rows
// refined too (1) or columns only (0, ScanOptions' default).
BENCHMARK(BM_DecodeRefineTriangulateNormals)
    ->Args({0, 1})
    ->Args({1, 1})
    ->Args({1, 0})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// ScanPipeline::ProcessView with the default ScanOptions in the camera frame: decode,
// refine, triangulate, normals and intensities into a new cloud per call, as the scanner
// server processes each view.
void BM_ScanPipelineProcessView(benchmark::State& state) {
  AreaSampledFixture& f = GetAreaSampledFixture();
  ScanPipeline pipeline(ScanCalibration{f.rig.camera, f.rig.projector, f.rig.X_CameraProjector, {}},
                        f.patterns);
  std::vector<GrayImage> images;
  for (const ImageView& view : f.views) {
    GrayImage image(static_cast<std::uint32_t>(view.width),
                    static_cast<std::uint32_t>(view.height));
    for (int y = 0; y < view.height; ++y) {
      std::copy(view.row(y), view.row(y) + view.width,
                image.pixels.begin() + static_cast<std::ptrdiff_t>(y) * view.width);
    }
    images.push_back(std::move(image));
  }
  ScanOptions options;
  options.frame = ScanFrame::kCamera;
  TriangulationResult result;
  // The first call builds the decoder, refiner and triangulator (ray tables) once.
  result.cloud = pipeline.ProcessView(images, options);
  for (auto _ : state) {
    result.cloud = pipeline.ProcessView(images, options);
    benchmark::DoNotOptimize(result.cloud.points.data());
  }
  result.num_points = 0;
  for (const Eigen::Vector3f& p : result.cloud.points) result.num_points += !std::isnan(p.z());
  ReportPoints(state, result);
}
BENCHMARK(BM_ScanPipelineProcessView)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
}  // namespace picking::scanner

BENCHMARK_MAIN();
