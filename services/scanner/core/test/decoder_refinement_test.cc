#include "services/scanner/core/decoder.h"
#include "services/scanner/core/synthetic_capture.h"
#include "services/scanner/core/triangulation.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

namespace picking::scanner {
namespace {

SyntheticPlane TiltedPlane() {
  SyntheticPlane plane;
  plane.normal = Eigen::Vector3d(0.2, -0.1, 1.0).normalized();
  plane.offset_m = plane.normal.dot(Eigen::Vector3d(0, 0, 1.0));  // Through (0, 0, 1 m).
  return plane;
}

SyntheticSphere Sphere() {
  SyntheticSphere sphere;
  sphere.center_m = Eigen::Vector3d(-0.02, 0.03, 0.8);
  sphere.radius_m = 0.08;
  return sphere;
}

// Blur, gamma, ambient light and sensor noise as in the decoder benchmark, and pixels that
// integrate the light over their area.
SyntheticCaptureOptions RealisticOptions(std::uint32_t seed) {
  SyntheticCaptureOptions options;
  options.blur_sigma_px = 0.6;
  options.noise_sigma = 2.0;
  options.gamma = 1.3;
  options.ambient_level = 25.0;
  options.samples_per_axis = 4;
  options.seed = seed;
  return options;
}

// The full-size rig's captures, rendered once for all tests (area sampling is slow).
struct Captures {
  ScannerRig rig = MakeExampleRig(1280, 1024);
  PatternSequence patterns;
  SyntheticCapture plane;
  SyntheticCapture sphere;

  Captures() {
    SyntheticScene plane_scene;
    plane_scene.planes.push_back(TiltedPlane());
    plane = RenderSyntheticCapture(rig, patterns, plane_scene, RealisticOptions(3));
    SyntheticScene sphere_scene = plane_scene;
    sphere_scene.spheres.push_back(Sphere());
    sphere = RenderSyntheticCapture(rig, patterns, sphere_scene, RealisticOptions(11));
  }
};

const Captures& GetCaptures() {
  static const Captures* captures = new Captures();
  return *captures;
}

double Median(std::vector<double> values) {
  if (values.empty()) return std::numeric_limits<double>::quiet_NaN();
  std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
  return values[values.size() / 2];
}

// Median |z - true z| over the finite points of a cloud.
double MedianDepthError(const TriangulationResult& result, const SyntheticCapture& capture) {
  std::vector<double> errors;
  for (std::size_t i = 0; i < result.cloud.points.size(); ++i) {
    const float z = result.cloud.points[i].z();
    if (!std::isnan(z) && !std::isnan(capture.depth_m[i])) {
      errors.push_back(std::abs(z - capture.depth_m[i]));
    }
  }
  return Median(errors);
}

struct PlaneFigures {
  double decoded_fraction = 0;
  double refined_fraction = 0;
  double point_fraction = 0;
  std::size_t rejected = 0;
  double median_column_error_px = 0;
  double median_row_error_px = 0;
  double integer_depth_error_m = 0;
  double subpixel_depth_error_m = 0;
};

PlaneFigures EvaluatePlane(const DecoderOptions& decoder_options) {
  const Captures& c = GetCaptures();
  const std::vector<ImageView> views = c.plane.views();
  const CorrespondenceMap decoded = GrayCodeDecoder(c.patterns, decoder_options).Decode(views);
  CorrespondenceMap refined = decoded;
  const RefinementResult refinement = SubpixelRefiner(c.patterns).Refine(views, &refined);
  EXPECT_TRUE(refined.has_subpixel());
  EXPECT_EQ(refinement.num_refined, refined.num_valid);
  EXPECT_EQ(refinement.num_rejected + refined.num_valid, decoded.num_valid);
  EXPECT_GT(refinement.num_column_transitions, 300000u);
  EXPECT_GT(refinement.num_row_transitions, 300000u);

  PlaneFigures figures;
  // Sub-pixel coordinates against the projector coordinates of the true surface point.
  std::vector<double> column_errors;
  std::vector<double> row_errors;
  for (std::size_t i = 0; i < refined.valid.size(); ++i) {
    if (!refined.valid[i] || std::isnan(c.plane.column_exact[i])) continue;
    column_errors.push_back(std::abs(refined.column_subpixel[i] - c.plane.column_exact[i]));
    row_errors.push_back(std::abs(refined.row_subpixel[i] - c.plane.row_exact[i]));
  }
  figures.median_column_error_px = Median(column_errors);
  figures.median_row_error_px = Median(row_errors);

  const Triangulator triangulator(c.rig.camera, c.rig.projector, c.rig.X_CameraProjector);
  const TriangulationResult integer_result = triangulator.Run(decoded, &views[0]);
  const TriangulationResult subpixel_result = triangulator.Run(refined, &views[0]);
  figures.integer_depth_error_m = MedianDepthError(integer_result, c.plane);
  figures.subpixel_depth_error_m = MedianDepthError(subpixel_result, c.plane);
  const double pixels = static_cast<double>(c.plane.width) * c.plane.height;
  figures.decoded_fraction = decoded.num_valid / pixels;
  figures.refined_fraction = refined.num_valid / pixels;
  figures.point_fraction = subpixel_result.num_points / pixels;
  figures.rejected = refinement.num_rejected;
  std::cout << "plane at 1 m, min_bit_contrast " << decoder_options.min_bit_contrast
            << ": coverage (of all camera pixels) decoded " << figures.decoded_fraction
            << ", refined " << figures.refined_fraction << " (" << figures.rejected
            << " rejected), points " << figures.point_fraction << "; median |column error| "
            << figures.median_column_error_px << " px, |row error| " << figures.median_row_error_px
            << " px; median |depth error| " << figures.integer_depth_error_m * 1e3
            << " mm integer, " << figures.subpixel_depth_error_m * 1e3 << " mm sub-pixel\n";
  EXPECT_LT(figures.rejected, decoded.num_valid / 100);
  EXPECT_GT(subpixel_result.num_points, refined.num_valid * 99 / 100);
  return figures;
}

TEST(DecoderRefinementTest, PlaneAtOneMetreHasSubMillimetreDepthError) {
  const PlaneFigures figures = EvaluatePlane(DecoderOptions{});
  RecordProperty("coverage_decoded", std::to_string(figures.decoded_fraction));
  RecordProperty("coverage_points", std::to_string(figures.point_fraction));
  RecordProperty("median_depth_error_mm", std::to_string(figures.subpixel_depth_error_m * 1e3));
  // Pixels straddling a stripe edge fail the bit-contrast test: ~22 % of the plane here.
  EXPECT_GT(figures.decoded_fraction, 0.75);
  EXPECT_GT(figures.point_fraction, 0.75);
  EXPECT_LT(figures.median_column_error_px, 0.1);
  EXPECT_LT(figures.median_row_error_px, 0.1);
  EXPECT_GT(figures.integer_depth_error_m, 1.0e-3);  // Integer columns: ~6 mm depth steps.
  EXPECT_LT(figures.subpixel_depth_error_m, 0.5e-3);
}

// Columns only (the scan pipeline's default): the column maps are those of the full
// refinement, rows stay integer, and the depth error is nearly that of the full refinement.
TEST(DecoderRefinementTest, IntegerRowsKeepColumnsAndDepthAccuracy) {
  const Captures& c = GetCaptures();
  const std::vector<ImageView> views = c.plane.views();
  const CorrespondenceMap decoded = GrayCodeDecoder(c.patterns).Decode(views);
  RefinementOptions options;
  options.reject_unrefined = false;  // The same pixels stay valid in both runs.
  CorrespondenceMap full = decoded;
  const RefinementResult full_result = SubpixelRefiner(c.patterns, options).Refine(views, &full);
  options.refine_rows = false;
  CorrespondenceMap columns = decoded;
  const RefinementResult columns_result =
      SubpixelRefiner(c.patterns, options).Refine(views, &columns);
  EXPECT_EQ(columns_result.num_column_transitions, full_result.num_column_transitions);
  EXPECT_EQ(columns_result.num_row_transitions, 0u);
  EXPECT_GT(full_result.num_row_transitions, 300000u);
  ASSERT_TRUE(columns.valid == full.valid);
  std::size_t column_mismatches = 0;
  std::size_t row_mismatches = 0;
  for (std::size_t i = 0; i < decoded.valid.size(); ++i) {
    if (!columns.valid[i]) {
      EXPECT_TRUE(std::isnan(columns.row_subpixel[i]));
      continue;
    }
    column_mismatches += columns.column_subpixel[i] != full.column_subpixel[i];
    row_mismatches += columns.row_subpixel[i] != static_cast<float>(decoded.row[i]);
  }
  EXPECT_EQ(column_mismatches, 0u);
  EXPECT_EQ(row_mismatches, 0u);

  const Triangulator triangulator(c.rig.camera, c.rig.projector, c.rig.X_CameraProjector);
  const double full_error_m = MedianDepthError(triangulator.Run(full, &views[0]), c.plane);
  const double columns_error_m = MedianDepthError(triangulator.Run(columns, &views[0]), c.plane);
  std::cout << "plane at 1 m: median |depth error| " << full_error_m * 1e3
            << " mm with refined rows, " << columns_error_m * 1e3 << " mm with integer rows\n";
  EXPECT_LT(columns_error_m, 0.25e-3);
  EXPECT_LT(columns_error_m, full_error_m + 0.05e-3);
}

// Gray code keeps a pixel with one ambiguous bit within one column of the truth, which the
// refinement tolerates: without the bit-contrast test nearly every lit pixel gets a point.
TEST(DecoderRefinementTest, PlaneWithoutBitContrastTestKeepsTheAccuracy) {
  DecoderOptions options;
  options.min_bit_contrast = 0;
  const PlaneFigures figures = EvaluatePlane(options);
  RecordProperty("coverage_points", std::to_string(figures.point_fraction));
  EXPECT_GT(figures.point_fraction, 0.95);
  EXPECT_LT(figures.subpixel_depth_error_m, 0.5e-3);
}

// A pixel is near an edge if a pixel within `radius` of it (square window) is invalid or
// two 4-neighbours there differ by more than one column or row.
bool NearEdge(const CorrespondenceMap& map, int x, int y, int radius) {
  for (int yy = std::max(0, y - radius); yy <= std::min(map.height - 1, y + radius); ++yy) {
    for (int xx = std::max(0, x - radius); xx <= std::min(map.width - 1, x + radius); ++xx) {
      const std::size_t i = static_cast<std::size_t>(yy) * map.width + xx;
      if (!map.valid[i]) return true;
      const auto jump = [&](std::size_t j) {
        return map.valid[j] && (std::abs(map.column[i] - map.column[j]) > 1 ||
                                std::abs(map.row[i] - map.row[j]) > 1);
      };
      if ((xx + 1 < map.width && jump(i + 1)) || (yy + 1 < map.height && jump(i + map.width))) {
        return true;
      }
    }
  }
  return false;
}

TEST(DecoderRefinementTest, ValidityChangesOnlyAtRejectedEdges) {
  const Captures& c = GetCaptures();
  const std::vector<ImageView> views = c.sphere.views();
  const CorrespondenceMap decoded = GrayCodeDecoder(c.patterns).Decode(views);
  CorrespondenceMap refined = decoded;
  const RefinementResult result = SubpixelRefiner(c.patterns).Refine(views, &refined);

  std::size_t rejected = 0;
  std::size_t rejected_inside = 0;
  for (int y = 0; y < decoded.height; ++y) {
    for (int x = 0; x < decoded.width; ++x) {
      const std::size_t i = static_cast<std::size_t>(y) * decoded.width + x;
      if (refined.valid[i]) {
        ASSERT_TRUE(decoded.valid[i]) << "pixel " << i << " became valid";
        ASSERT_EQ(refined.column[i], decoded.column[i]);
        ASSERT_EQ(refined.row[i], decoded.row[i]);
        ASSERT_LE(std::abs(refined.column_subpixel[i] - refined.column[i]), 0.5f);
        ASSERT_LE(std::abs(refined.row_subpixel[i] - refined.row[i]), 0.5f);
      } else {
        ASSERT_TRUE(std::isnan(refined.column_subpixel[i]));
        ASSERT_TRUE(std::isnan(refined.row_subpixel[i]));
        ASSERT_EQ(refined.column[i], 0);
        ASSERT_EQ(refined.row[i], 0);
        if (decoded.valid[i]) {
          ++rejected;
          rejected_inside += !NearEdge(decoded, x, y, 3);
        }
      }
    }
  }
  std::cout << "sphere + plane: " << decoded.num_valid << " decoded, " << rejected << " rejected ("
            << rejected_inside << " away from edges), " << result.num_filled_across
            << " coordinates filled across lines\n";
  EXPECT_EQ(rejected, result.num_rejected);
  EXPECT_EQ(refined.num_valid, decoded.num_valid - rejected);
  EXPECT_GT(rejected, 0u);  // The scene has occlusion and shadow edges.
  EXPECT_LT(rejected, decoded.num_valid / 100);
  EXPECT_EQ(rejected_inside, 0u);

  // Without rejection the valid set is the decoder's, the unrefined pixels keep their integer
  // coordinates and everything else is the same.
  RefinementOptions keep;
  keep.reject_unrefined = false;
  CorrespondenceMap kept = decoded;
  const RefinementResult kept_result = SubpixelRefiner(c.patterns, keep).Refine(views, &kept);
  EXPECT_EQ(kept_result.num_rejected, 0u);
  EXPECT_EQ(kept_result.num_kept_integer, result.num_rejected);
  EXPECT_EQ(kept_result.num_refined, result.num_refined);
  EXPECT_TRUE(kept.valid == decoded.valid);
  EXPECT_EQ(kept.num_valid, decoded.num_valid);
  for (std::size_t i = 0; i < kept.valid.size(); ++i) {
    if (!kept.valid[i]) continue;
    if (refined.valid[i]) {
      ASSERT_EQ(kept.column_subpixel[i], refined.column_subpixel[i]);
      ASSERT_EQ(kept.row_subpixel[i], refined.row_subpixel[i]);
    } else {
      ASSERT_TRUE(kept.column_subpixel[i] == kept.column[i] || kept.row_subpixel[i] == kept.row[i]);
    }
  }

  // One thread gives the same result as several.
  RefinementOptions single;
  single.num_threads = 1;
  CorrespondenceMap serial = decoded;
  SubpixelRefiner(c.patterns, single).Refine(views, &serial);
  EXPECT_TRUE(serial.valid == refined.valid);
  for (std::size_t i = 0; i < serial.valid.size(); ++i) {
    if (!serial.valid[i]) continue;
    ASSERT_EQ(serial.column_subpixel[i], refined.column_subpixel[i]);
    ASSERT_EQ(serial.row_subpixel[i], refined.row_subpixel[i]);
  }

  // Decoding into a refined map drops its sub-pixel maps.
  GrayCodeDecoder(c.patterns).Decode(views, &refined);
  EXPECT_FALSE(refined.has_subpixel());
  EXPECT_TRUE(refined.valid == decoded.valid);
}

TEST(DecoderRefinementTest, SphereSurfaceErrorImproves) {
  const Captures& c = GetCaptures();
  const std::vector<ImageView> views = c.sphere.views();
  const CorrespondenceMap decoded = GrayCodeDecoder(c.patterns).Decode(views);
  CorrespondenceMap refined = decoded;
  SubpixelRefiner(c.patterns).Refine(views, &refined);
  const Triangulator triangulator(c.rig.camera, c.rig.projector, c.rig.X_CameraProjector);
  const TriangulationResult integer_result = triangulator.Run(decoded);
  const TriangulationResult subpixel_result = triangulator.Run(refined);

  // Distance to the sphere's surface of the points at pixels that see the sphere.
  const SyntheticSphere sphere = Sphere();
  const camera::RayTable rays = c.rig.camera.ComputeRayTable();
  std::vector<std::uint8_t> on_sphere(rays.xy.size(), 0);
  for (std::size_t i = 0; i < rays.xy.size(); ++i) {
    if (std::isnan(c.sphere.depth_m[i])) continue;
    const Eigen::Vector3d p_true =
        c.sphere.depth_m[i] * Eigen::Vector3d(rays.xy[i].x(), rays.xy[i].y(), 1.0);
    on_sphere[i] = std::abs((p_true - sphere.center_m).norm() - sphere.radius_m) < 1e-4;
  }
  const auto median_surface_error = [&](const TriangulationResult& result, std::size_t* count) {
    std::vector<double> errors;
    for (std::size_t i = 0; i < result.cloud.points.size(); ++i) {
      const Eigen::Vector3f& p = result.cloud.points[i];
      if (!on_sphere[i] || std::isnan(p.z())) continue;
      errors.push_back(std::abs((p.cast<double>() - sphere.center_m).norm() - sphere.radius_m));
    }
    *count = errors.size();
    return Median(errors);
  };
  std::size_t integer_count = 0;
  std::size_t subpixel_count = 0;
  const double integer_error_m = median_surface_error(integer_result, &integer_count);
  const double subpixel_error_m = median_surface_error(subpixel_result, &subpixel_count);
  std::cout << "sphere r = 80 mm at 0.8 m: " << integer_count << " / " << subpixel_count
            << " points (integer / sub-pixel), median |distance to the surface| "
            << integer_error_m * 1e3 << " mm integer, " << subpixel_error_m * 1e3
            << " mm sub-pixel\n";
  ASSERT_GT(integer_count, 50000u);
  EXPECT_GT(subpixel_count, integer_count * 98 / 100);
  EXPECT_LT(subpixel_error_m, 0.3 * integer_error_m);
  EXPECT_LT(subpixel_error_m, 0.2e-3);
}

// A hand-made capture of one camera row of 16 pixels: the projector columns 100 ... 107 seen
// with the column coordinate u(x) = 100.2 + 0.5 x (a plane, noise-free, each pixel
// integrating its area), rows all 300. The edges' positions follow in closed form.
TEST(DecoderRefinementTest, LocatesEdgesOfAHandMadeRamp) {
  const PatternSequence patterns;
  const int width = 16;
  const int height = 3;
  const auto u_of_x = [](double x) { return 100.2 + 0.5 * x; };
  std::vector<std::vector<std::uint8_t>> images(patterns.num_images(),
                                                std::vector<std::uint8_t>(width * height));
  for (int k = 0; k < patterns.num_images(); ++k) {
    for (int y = 0; y < height; ++y) {
      for (int x = 0; x < width; ++x) {
        // Fraction of the pixel [x - 0.5, x + 0.5] lit, from 1000 sub-samples.
        double lit = 0;
        for (int s = 0; s < 1000; ++s) {
          const double u = u_of_x(x - 0.5 + (s + 0.5) / 1000.0);
          lit += patterns.IsLit(k, static_cast<int>(std::lround(u)), 300) ? 1e-3 : 0.0;
        }
        images[k][y * width + x] = static_cast<std::uint8_t>(std::lround(20 + 200 * lit));
      }
    }
  }
  std::vector<ImageView> views;
  for (const auto& image : images) views.push_back(MakeImageView(image.data(), width, height));
  DecoderOptions decoder_options;
  decoder_options.min_bit_contrast = 0;
  CorrespondenceMap map = GrayCodeDecoder(patterns, decoder_options).Decode(views);
  ASSERT_EQ(map.num_valid, static_cast<std::size_t>(width * height));
  RefinementOptions options;
  options.reject_unrefined = false;
  const RefinementResult result = SubpixelRefiner(patterns, options).Refine(views, &map);
  // Rows cannot be refined (no row edge anywhere), so every pixel keeps its integer row.
  EXPECT_EQ(result.num_kept_integer, static_cast<std::size_t>(width * height));
  EXPECT_EQ(result.num_column_transitions, 8u * height);  // Edges at u = 100.5 ... 107.5.
  EXPECT_EQ(result.num_row_transitions, 0u);
  for (int x = 0; x < width; ++x) {
    // Linear interpolation between box-filtered samples finds the edges to within ~0.05
    // camera pixels here (0.025 columns).
    EXPECT_NEAR(map.column_subpixel[width + x], u_of_x(x), 0.05) << "x = " << x;
    // No row edge along the camera columns: rows from the left and right neighbours are no
    // help either, so the integer row is kept.
    EXPECT_EQ(map.row_subpixel[width + x], 300.0f);
  }
}

TEST(DecoderRefinementTest, RejectsBadInputWithoutTouchingTheMap) {
  const PatternSequence patterns;
  const SubpixelRefiner refiner(patterns);
  std::vector<std::uint8_t> pixels(64 * 48, 100);
  const std::vector<ImageView> views(44, MakeImageView(pixels.data(), 64, 48));
  CorrespondenceMap map;
  map.width = 64;
  map.height = 48;
  map.column.assign(64 * 48, 5);
  map.row.assign(64 * 48, 7);
  map.valid.assign(64 * 48, 1);
  map.num_valid = 64 * 48;
  const CorrespondenceMap original = map;

  const auto expect_error = [&](const std::vector<ImageView>& images, CorrespondenceMap* target,
                                const std::string& text) {
    const CorrespondenceMap before = *target;
    try {
      refiner.Refine(images, target);
      ADD_FAILURE() << "expected std::invalid_argument containing '" << text << "'";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(text), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("SubpixelRefiner"), std::string::npos) << e.what();
    }
    EXPECT_TRUE(target->valid == before.valid);
    EXPECT_TRUE(target->column == before.column);
    EXPECT_EQ(target->num_valid, before.num_valid);
    EXPECT_FALSE(target->has_subpixel());
  };
  expect_error(std::vector<ImageView>(43, views[0]), &map, "expected 44 images");
  auto missing = views;
  missing[9].data = nullptr;
  expect_error(missing, &map, "image 9 has no data");
  CorrespondenceMap wrong_size = map;
  wrong_size.width = 32;
  expect_error(views, &wrong_size, "map is 32 x 48 but the images are 64 x 48");
  CorrespondenceMap short_buffer = map;
  short_buffer.valid.pop_back();
  expect_error(views, &short_buffer, "not width * height");
  CorrespondenceMap outside = map;
  outside.column[100] = 912;
  expect_error(views, &outside, "valid pixel 100 has correspondence (912, 7) outside");
  EXPECT_THROW(refiner.Refine(views, nullptr), std::invalid_argument);
  EXPECT_TRUE(map.valid == original.valid);

  RefinementOptions bad;
  bad.num_threads = -1;
  EXPECT_THROW(SubpixelRefiner(patterns, bad), std::invalid_argument);
  bad = RefinementOptions{};
  bad.max_gap_px = 17;
  EXPECT_THROW(SubpixelRefiner(patterns, bad), std::invalid_argument);

  // The triangulator checks the sub-pixel maps too.
  const ScannerRig rig = MakeExampleRig(64, 48);
  const Triangulator triangulator(rig.camera, rig.projector, rig.X_CameraProjector);
  CorrespondenceMap subpixel = map;
  subpixel.column_subpixel.assign(64 * 48, 5.2f);
  subpixel.row_subpixel.assign(64 * 48, 6.9f);
  EXPECT_NO_THROW(triangulator.Run(subpixel));
  CorrespondenceMap short_subpixel = subpixel;
  short_subpixel.row_subpixel.pop_back();
  EXPECT_THROW(triangulator.Run(short_subpixel), std::invalid_argument);
  CorrespondenceMap nan_subpixel = subpixel;
  nan_subpixel.column_subpixel[17] = std::numeric_limits<float>::quiet_NaN();
  try {
    triangulator.Run(nan_subpixel);
    ADD_FAILURE() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("at pixel 17 lies outside the 912 x 1140 projector"),
              std::string::npos)
        << e.what();
  }
  nan_subpixel.valid[17] = 0;  // Invalid pixels may carry anything.
  EXPECT_NO_THROW(triangulator.Run(nan_subpixel));
  CorrespondenceMap beyond = subpixel;
  beyond.row_subpixel[3] = 1139.6f;
  EXPECT_THROW(triangulator.Run(beyond), std::invalid_argument);
}

}  // namespace
}  // namespace picking::scanner
