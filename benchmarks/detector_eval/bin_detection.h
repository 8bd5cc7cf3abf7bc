#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "benchmarks/detector_eval/bin_scan_sim.h"
#include "services/detector/core/detection.h"
#include "services/detector/core/estimators.h"
#include "services/detector/core/model_library.h"
#include "services/detector/core/ppf_detector.h"

namespace picking::detector_eval {

/// Options of DetectInBin: the region options (detector::SceneOptions) the detector service
/// gives a Detect request with the bin as region.
struct BinDetectionOptions {
  /// Points within this distance of the bin's walls, floor and ceiling are removed, metres
  /// (the Region's wall_margin_m).
  double wall_margin_m = 0.01;
  /// Faces of the bin box whose points are removed (default: all, the open front too: items
  /// stand at least 1 cm behind it, the shelf's lip does not).
  std::uint32_t wall_faces = detector::kAllFaces;
  /// Then the measured floor (the boards are not flat) is removed (RemoveBoxFloor).
  bool remove_floor = true;
  /// The item's time budget (ObjectConfig::time_budget_s) is multiplied by this (> 0): on a
  /// machine loaded by other work, a factor of the load keeps the budget's share of the
  /// search as on a quiet one.
  double budget_scale = 1.0;
  /// A scan of several views is verified from every view's sensor
  /// (SceneContextOptions::other_sensors), not from the first one's alone.
  bool multi_sensor_verification = true;
  /// The estimators' options (PPF per-segment hypotheses, sphere fits, ...).
  detector::EstimatorOptions estimators;
  /// Distinct poses kept in BinDetectionResult::poses (ItemQuery::max_results, >= 1).
  std::size_t max_results = 1;
};

/// One scan of the bin made of several views (the paper scans each bin from three angles), as
/// the scanner service merges views without voxels: the views' organised clouds stacked
/// row-wise in one organised cloud, their sensors' poses in `view_poses`; the sensor pose and
/// intrinsics, bin box and items are the first view's, the timings the sums. DetectInBin
/// then passes the view poses as the detector service passes DetectParams.X_frame_sensor
/// (detector::SceneOptions::view_poses): the views are split (each view's intrinsics fitted,
/// its shading divided out of its intensities), and poses are verified from every view's
/// sensor (unless multi_sensor_verification is off). Throws std::invalid_argument when
/// `views` is empty, the views disagree on the bin or are not organised clouds of one size
/// with the same channels.
BinScan MergeViews(const std::vector<BinScan>& views);

/// `bin` scanned from each of `views` (in order; by default the cell's three,
/// world::CellBinScanViews) with `options`' sensor and noise, merged (MergeViews).
BinScan ScanViews(SimulatedBinScanner& scanner, const std::string& bin,
                  const BinScanOptions& options = {},
                  const std::vector<world::BinScanView>& views = world::CellBinScanViews());

/// One full detection call and what it saw.
struct BinDetectionResult {
  detector::ChainResult chain;
  /// The accepted pose, then the accepting method's other candidates above its thresholds
  /// (up to BinDetectionOptions::max_results, detector::ItemDetections::poses).
  std::vector<detector::Detection> poses;
  std::size_t points_in_region = 0;  ///< Finite points after crop and wall removal.
  bool intrinsics_fitted = false;    ///< The camera was recovered from the organised cloud.
  double total_s = 0.0;              ///< Wall-clock time of the whole call.
};

/// Detects `item` in `scan` with the detector service's own workflow
/// (detector::PrepareScene and detector::DetectItem, services/detector/core/detect_in_region.h)
/// and the bin as region: crop to the bin box, remove the walls and the floor, fit the camera
/// intrinsics to the organised cloud (falling back to the scan's true intrinsics), then the
/// item's method chain from the library (or only `method`). Throws as the detector core does
/// (unknown item, empty region).
BinDetectionResult DetectInBin(const std::shared_ptr<const detector::ModelLibrary>& library,
                               const BinScan& scan, const std::string& item,
                               std::optional<detector::Method> method = std::nullopt,
                               const BinDetectionOptions& options = {});

/// The verification of the true pose `X_BaseItem` of `item` in the same pre-processed
/// region (no refinement): what a perfect estimator would score. Throws as DetectInBin.
detector::Detection ScoreTruePose(const std::shared_ptr<const detector::ModelLibrary>& library,
                                  const BinScan& scan, const std::string& item,
                                  const Eigen::Isometry3d& X_BaseItem,
                                  const BinDetectionOptions& options = {});

/// The PPF detector's free-space agreement (support and conflicts with the default
/// PpfDetectorOptions distances) of the true pose in the same pre-processed region.
detector::SceneAgreement TruePoseAgreement(
    const std::shared_ptr<const detector::ModelLibrary>& library, const BinScan& scan,
    const std::string& item, const Eigen::Isometry3d& X_BaseItem,
    const BinDetectionOptions& options = {});

}  // namespace picking::detector_eval
