#pragma once

#include <Eigen/Geometry>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "libs/apc/task.h"
#include "libs/camera/pinhole_camera.h"
#include "libs/geometry/point_cloud.h"
#include "libs/world/shelf_bins.h"
#include "services/detector/core/preprocess.h"
#include "services/simulator/core/layout.h"

namespace picking::detector_eval {

/// Ground truth of one item instance in a scanned bin.
struct TrueItem {
  std::string name;
  /// Pose of the item frame (libs/world: bounding-box centre, x long, y middle, z short side)
  /// in the robot base frame.
  Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();
};

/// What scans the bin.
enum class BinSensor {
  kStructuredLight,  ///< The cell's Gray-code scanner (data/scanner/sim_sensor), 42 captures.
  kRgbd,             ///< A commodity RGB-D camera (simulator::RenderRgbd, Xtion-like).
};

/// Options of SimulatedBinScanner::Scan.
struct BinScanOptions {
  BinSensor sensor = BinSensor::kStructuredLight;
  /// Where the camera stands and what it looks at (by default the cell's middle view).
  world::BinScanView view;
  /// Noise seed of the rendered captures.
  std::uint64_t seed = 1;
  /// Camera read noise (Gaussian sigma, grey levels); shot noise is added on top.
  double read_noise_dn = 1.0;
  /// Ambient light relative to the projector's white.
  double ambient = 0.03;
};

/// One simulated structured-light scan of a shelf bin.
struct BinScan {
  std::string bin;  ///< "bin_A".."bin_L".
  /// Organised cloud (one point per camera pixel, NaN where nothing was decoded) in the robot
  /// base frame, with normals and intensities (0-1) from the structured-light scanner, with
  /// colours and without normals from the RGB-D camera.
  geometry::PointCloud cloud;
  Eigen::Isometry3d X_BaseCamera = Eigen::Isometry3d::Identity();
  /// The camera's intrinsics (what the scanner triangulated with).
  camera::PinholeCamera camera{1, 1, 1.0, 1.0, 0.0, 0.0};
  /// A scan of several views (MergeViews): the views' organised clouds are stacked row-wise
  /// in `cloud`, and these are their sensors' poses (the first is X_BaseCamera). Empty for
  /// one view.
  std::vector<Eigen::Isometry3d> view_poses;
  /// The bin's free inner volume (Box frame axes along the shelf's: x out of the opening,
  /// z up) in the base frame.
  detector::OrientedBox bin_box;
  /// Items in the bin, ground truth.
  std::vector<TrueItem> items;
  double valid_fraction = 0.0;  ///< Camera pixels with a decoded point.
  double render_s = 0.0;        ///< Ray casting and rendering of the 42 captures.
  double process_s = 0.0;       ///< Decoding, triangulation and normals.
};

/// The simulated APC cell (simulator core: SimWorld, LayoutPlanner, the Embree structured
/// light renderer) scanned by the scanner core (Gray-code decoding, sub-pixel refinement,
/// triangulation, normals) with the nominal simulated sensor of data/scanner/sim_sensor, all
/// in process. Not thread safe.
class SimulatedBinScanner final {
 public:
  /// Loads the cell, the item catalogue and shapes and the sensor from `data_dir` (the
  /// project's data/ folder). Throws std::runtime_error / std::invalid_argument naming the
  /// file when something cannot be read.
  explicit SimulatedBinScanner(const std::string& data_dir);
  ~SimulatedBinScanner();
  SimulatedBinScanner(const SimulatedBinScanner&) = delete;
  SimulatedBinScanner& operator=(const SimulatedBinScanner&) = delete;

  /// Reads an APC task file with the catalogue. Throws apc::TaskFileError.
  apc::Task ReadTask(const std::string& path) const;
  /// Lays out `task` in the shelf and tote (seeded; tidy, or settled by physics). Throws
  /// simulator::LayoutError.
  void LoadTask(const apc::Task& task, std::uint32_t seed,
                simulator::LayoutMode mode = simulator::LayoutMode::kTidy);
  /// Removes every item of `bin` whose name is `item` (to scan a bin without it). Throws
  /// std::invalid_argument for an unknown bin.
  void RemoveItems(const std::string& bin, const std::string& item);
  /// Scans `bin` ("bin_A".."bin_L") from in front of it. Throws std::invalid_argument for an
  /// unknown bin.
  BinScan Scan(const std::string& bin, const BinScanOptions& options = {});

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace picking::detector_eval
