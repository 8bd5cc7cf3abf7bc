// Decoding speed and quality of the scanner's Gray-code decoder against OpenCV's
// cv::structured_light::GrayCodePattern on the same synthetic 1280 x 1024 captures of a
// tilted plane and a sphere (rendered once, seeded, with blur, noise, gamma and ambient
// light), and the decode + triangulate + normals pipeline of one view.
//
// Counters: decoded = decoded fraction of all camera pixels; precision = fraction of the
// decoded pixels whose column and row equal the ground truth; precision_pm1 = within +-1.

#include "services/scanner/core/decoder.h"
#include "services/scanner/core/normals.h"
#include "services/scanner/core/patterns.h"
#include "services/scanner/core/synthetic_capture.h"
#include "services/scanner/core/triangulation.h"

#include <benchmark/benchmark.h>
#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/structured_light.hpp>

#include <cstdlib>
#include <iostream>
#include <stdexcept>

namespace picking::scanner {
namespace {

constexpr int kMinContrast = 16;
constexpr int kMinBitContrast = 5;  // OpenCV's default white threshold.

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
    SyntheticScene scene;
    SyntheticPlane plane;
    plane.normal = Eigen::Vector3d(0.25, -0.1, 1.0).normalized();
    plane.offset_m = plane.normal.dot(Eigen::Vector3d(0, 0, 1.0));
    scene.planes.push_back(plane);
    SyntheticSphere sphere;
    sphere.center_m = Eigen::Vector3d(-0.03, 0.02, 0.85);
    sphere.radius_m = 0.09;
    scene.spheres.push_back(sphere);
    SyntheticCaptureOptions options;
    options.blur_sigma_px = 0.6;
    options.noise_sigma = 2.0;
    options.gamma = 1.3;
    options.ambient_level = 25.0;
    options.seed = 42;
    capture = RenderSyntheticCapture(rig, patterns, scene, options);
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

}  // namespace
}  // namespace picking::scanner

BENCHMARK_MAIN();
