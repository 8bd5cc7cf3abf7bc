#include "services/scanner/core/scan_pipeline.h"

#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>
#include <utility>

#include "libs/errors/errors.h"

namespace picking::scanner {
namespace {

using Clock = std::chrono::steady_clock;

double Seconds(Clock::time_point since) {
  return std::chrono::duration<double>(Clock::now() - since).count();
}

bool SameTriangulation(const TriangulationOptions& a, const TriangulationOptions& b) {
  return a.max_residual_projector_px == b.max_residual_projector_px &&
         a.min_depth_m == b.min_depth_m && a.max_depth_m == b.max_depth_m &&
         a.remove_isolated == b.remove_isolated && a.min_neighbors == b.min_neighbors &&
         a.neighbor_depth_tolerance_m == b.neighbor_depth_tolerance_m &&
         a.num_threads == b.num_threads;
}

bool SameRefinement(const RefinementOptions& a, const RefinementOptions& b) {
  return a.reject_unrefined == b.reject_unrefined && a.max_gap_px == b.max_gap_px &&
         a.refine_rows == b.refine_rows && a.num_threads == b.num_threads;
}

bool SameDecoder(const DecoderOptions& a, const DecoderOptions& b) {
  return a.min_contrast == b.min_contrast && a.min_bit_contrast == b.min_bit_contrast &&
         a.num_threads == b.num_threads;
}

// Runs a device call and maps device failures onto the error kinds of libs/errors.
template <class Fn>
auto DeviceCall(const char* what, Fn&& fn) -> decltype(fn()) {
  try {
    return fn();
  } catch (const CameraTimeoutError& e) {
    throw TimeoutError(std::string(what) + ": " + e.what());
  } catch (const DroppedFrameError& e) {
    throw DataLossError(std::string(what) + ": " + e.what());
  } catch (const CameraError& e) {
    throw UnavailableError(std::string(what) + ": " + e.what());
  } catch (const ProjectorError& e) {
    throw UnavailableError(std::string(what) + ": " + e.what());
  }
}

}  // namespace

const char* ScanStageName(ScanStage stage) {
  switch (stage) {
    case ScanStage::kCapture:
      return "capture";
    case ScanStage::kDecode:
      return "decode";
    case ScanStage::kTriangulate:
      return "triangulate";
    case ScanStage::kMerge:
      return "merge";
  }
  return "unknown";
}

struct ScanPipeline::Cache {
  std::unique_ptr<GrayCodeDecoder> decoder;
  std::unique_ptr<SubpixelRefiner> refiner;
  std::unique_ptr<Triangulator> triangulator;
  // The correspondence map of the last view: its buffers (~17 MB at 1280 x 1024) are reused,
  // so that a view does not page-fault fresh memory for them.
  CorrespondenceMap map;
};

ScanPipeline::ScanPipeline(ScanCalibration calibration, PatternSequence patterns,
                           ProjectorSequenceSettings projector_settings)
    : calibration_(std::move(calibration)),
      patterns_(std::move(patterns)),
      projector_settings_(projector_settings),
      cache_(std::make_unique<Cache>()) {
  if (calibration_.projector.width() != patterns_.projector_width() ||
      calibration_.projector.height() != patterns_.projector_height()) {
    throw std::invalid_argument("ScanPipeline: the calibrated projector is " +
                                std::to_string(calibration_.projector.width()) + " x " +
                                std::to_string(calibration_.projector.height()) +
                                " but the patterns are for " +
                                std::to_string(patterns_.projector_width()) + " x " +
                                std::to_string(patterns_.projector_height()));
  }
  projector_settings_.column_bits = patterns_.column_bits();
  projector_settings_.row_bits = patterns_.row_bits();
  projector_settings_.Validate();
}

ScanPipeline::~ScanPipeline() = default;

std::vector<GrayImage> ScanPipeline::Capture(const ScanDevices& devices,
                                             const std::optional<Eigen::Isometry3d>& X_BaseTool) {
  if (devices.camera == nullptr) throw std::invalid_argument("ScanPipeline: no camera");
  if (devices.before_capture) devices.before_capture(X_BaseTool);
  const int count = patterns_.num_images();
  std::vector<Frame> frames;
  if (devices.projector != nullptr) {
    DeviceCall("projector", [&] {
      devices.projector->LoadSequence(projector_settings_);
      devices.projector->Start();
    });
    try {
      frames = DeviceCall("camera", [&] { return devices.camera->Capture(count); });
    } catch (...) {
      DeviceCall("projector", [&] { devices.projector->Stop(); });
      throw;
    }
    DeviceCall("projector", [&] { devices.projector->Stop(); });
  } else {
    frames = DeviceCall("camera", [&] { return devices.camera->Capture(count); });
  }
  // The camera backend has checked its frame ids: only it knows which frames it took again.
  if (static_cast<int>(frames.size()) != count) {
    throw DataLossError("camera: delivered " + std::to_string(frames.size()) + " of " +
                        std::to_string(count) + " frames");
  }
  std::vector<GrayImage> images;
  images.reserve(frames.size());
  for (auto& f : frames) images.push_back(std::move(f.image));
  const auto& cam = calibration_.camera;
  if (static_cast<int>(images[0].width) != cam.width() ||
      static_cast<int>(images[0].height) != cam.height()) {
    throw PreconditionError("camera: frames are " + std::to_string(images[0].width) + " x " +
                            std::to_string(images[0].height) + " but the calibration is for " +
                            std::to_string(cam.width()) + " x " + std::to_string(cam.height()));
  }
  return images;
}

geometry::PointCloud ScanPipeline::ProcessView(const std::vector<GrayImage>& images,
                                               const ScanOptions& options, double* valid_fraction) {
  std::lock_guard<std::mutex> lock(mutex_);
  return ProcessViewLocked(images, options, valid_fraction);
}

geometry::PointCloud ScanPipeline::ProcessViewLocked(const std::vector<GrayImage>& images,
                                                     const ScanOptions& options,
                                                     double* valid_fraction) {
  if (static_cast<int>(images.size()) != patterns_.num_images()) {
    throw std::invalid_argument("ScanPipeline: " + std::to_string(images.size()) +
                                " images for a sequence of " +
                                std::to_string(patterns_.num_images()));
  }
  std::vector<ImageView> views;
  views.reserve(images.size());
  for (std::size_t i = 0; i < images.size(); ++i) {
    const GrayImage& image = images[i];
    if (image.pixels.size() != static_cast<std::size_t>(image.width) * image.height) {
      throw std::invalid_argument("ScanPipeline: image " + std::to_string(i) +
                                  " has the wrong number of pixels");
    }
    views.push_back(MakeImageView(image.pixels.data(), static_cast<int>(image.width),
                                  static_cast<int>(image.height)));
  }
  if (!cache_->decoder || !SameDecoder(cache_->decoder->options(), options.decode)) {
    cache_->decoder = std::make_unique<GrayCodeDecoder>(patterns_, options.decode);
  }
  TriangulationOptions triangulation = options.triangulation;
  triangulation.frame_id = "camera";
  if (!cache_->triangulator || !SameTriangulation(cache_->triangulator->options(), triangulation)) {
    cache_->triangulator = std::make_unique<Triangulator>(
        calibration_.camera, calibration_.projector, calibration_.X_CameraProjector, triangulation);
  }
  CorrespondenceMap& map = cache_->map;
  cache_->decoder->Decode(views, &map);
  if (options.subpixel) {
    if (!cache_->refiner || !SameRefinement(cache_->refiner->options(), options.refinement)) {
      cache_->refiner = std::make_unique<SubpixelRefiner>(patterns_, options.refinement);
    }
    cache_->refiner->Refine(views, &map);
  }
  if (valid_fraction) *valid_fraction = map.decoded_fraction();
  const ImageView& white = views[PatternSequence::kWhiteIndex];
  const ImageView* intensity = options.with_intensities ? &white : nullptr;
  TriangulationResult result;
  if (options.with_normals) {
    // Triangulation, filtering and normals in one pass over the rows.
    cache_->triangulator->Run(map, intensity, options.normals, &result);
  } else {
    cache_->triangulator->Run(map, intensity, &result);
  }
  return std::move(result.cloud);
}

ScanResult ScanPipeline::Run(const ScanDevices& devices, const std::vector<ScanViewSpec>& views_in,
                             const ScanOptions& options, const ScanProgress& progress) {
  std::vector<ScanViewSpec> views = views_in;
  if (views.empty()) views.emplace_back();
  if (options.frame == ScanFrame::kCamera && views.size() != 1) {
    throw std::invalid_argument("a scan in the camera frame takes exactly one view, got " +
                                std::to_string(views.size()));
  }
  if (options.frame == ScanFrame::kBase) {
    if (!calibration_.X_ToolCamera) {
      throw PreconditionError(
          "a scan in the base frame needs the hand-eye calibration "
          "(X_ToolCamera), which is missing");
    }
    for (std::size_t i = 0; i < views.size(); ++i) {
      if (!views[i].X_BaseTool) {
        throw PreconditionError("view " + std::to_string(i) +
                                " has no robot pose (X_BaseTool) for a scan in the base frame");
      }
    }
  }
  if (options.crop) {
    for (int a = 0; a < 3; ++a) {
      if (!(options.crop->first[a] <= options.crop->second[a])) {
        throw std::invalid_argument("crop: min must not exceed max (axis " +
                                    std::string(1, "xyz"[a]) + ")");
      }
    }
  }
  std::lock_guard<std::mutex> lock(mutex_);
  const int n = static_cast<int>(views.size());
  auto report = [&](int i, ScanStage stage) {
    if (progress) progress(i, n, stage);
  };
  ScanResult result;
  std::vector<geometry::PointCloud> clouds;
  clouds.reserve(views.size());
  for (int i = 0; i < n; ++i) {
    ScanViewResult view;
    report(i, ScanStage::kCapture);
    auto start = Clock::now();
    const std::vector<GrayImage> images = Capture(devices, views[i].X_BaseTool);
    view.capture_time_s = Seconds(start);

    start = Clock::now();
    report(i, ScanStage::kDecode);
    geometry::PointCloud cloud = ProcessViewLocked(images, options, &view.valid_fraction);
    report(i, ScanStage::kTriangulate);
    view.num_points = CountFinitePoints(cloud);
    if (options.frame == ScanFrame::kBase) {
      view.X_FrameCamera = *views[i].X_BaseTool * *calibration_.X_ToolCamera;
      TransformCloud(view.X_FrameCamera, "base", &cloud);
    }
    view.processing_time_s = Seconds(start);
    clouds.push_back(std::move(cloud));
    result.views.push_back(view);
  }
  report(n - 1, ScanStage::kMerge);
  const auto start = Clock::now();
  MergeResult merged = MergeClouds(clouds, options.merge);
  clouds.clear();
  result.cloud = std::move(merged.cloud);
  result.num_points = merged.num_points;
  if (options.crop) {
    result.num_points = CropToBox(options.crop->first, options.crop->second, &result.cloud);
  }
  const double merge_time_s = Seconds(start);
  result.processing_time_s = merge_time_s;
  for (const auto& v : result.views) {
    result.capture_time_s += v.capture_time_s;
    result.processing_time_s += v.processing_time_s;
  }
  return result;
}

}  // namespace picking::scanner
