#pragma once

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <optional>
#include <vector>

#include "libs/geometry/point_cloud.h"
#include "libs/world/mesh.h"

namespace picking::detector {

/// Options of the appearance comparison between a model's albedo and a scene's intensities.
struct AppearanceOptions {
  /// Incidence cosines below this are clamped to it in the shading compensation (grazing
  /// surfaces, noisy normals), in (0, 1].
  float min_cos = 0.25f;
  /// Surface seen at a grazing angle, incidence cosine (with the posed model's normal) below
  /// this, is not compared at all, in [0, 1): there a small error in depth along the ray
  /// slides a measured point far along the surface (at a cosine of 0.2 a depth error of
  /// 5 mm moves it 5 mm along the surface and 1 mm off it), so the print it shows belongs
  /// elsewhere. A face seen that flat tells only its plane.
  float min_sample_cos = 0.25f;
  /// The scene merges several views (CompensatedViewIntensity): each point's intensity is
  /// already shading-compensated for the view that measured it, and NaN where that view saw
  /// it at a grazing angle. Samples are then taken as they are: the angle to the one sensor
  /// the detector is given says nothing about how well a point's print was read (a
  /// floor-lying item's top, grazed by a low front view, is seen well from a higher side
  /// view), and the shading was that view's, not this sensor's.
  bool screened_per_view = false;
  /// The model's texture over the compared points must have at least this standard deviation
  /// of albedo (reflectance units); below it the texture is uniform there and says nothing.
  float min_albedo_stddev = 0.04f;
  /// The compared scene intensities must vary at least this much (relative standard
  /// deviation, std / mean), else the scene shows no texture (e.g. saturated or unlit).
  float min_intensity_rel_stddev = 0.02f;
  /// Fewer compared points than this give no evidence.
  int min_points = 30;
  /// With surface patch labels (CorrelateAppearance), each patch is compared on its own
  /// contrasts, and patches with fewer points than this, or with fewer carrying its
  /// contrast (participation ratio of the relative albedo contrasts), are left out.
  int min_patch_points = 10;
  /// Compare patch contrasts when patch labels are given (CorrelateAppearance); false: one
  /// Pearson correlation over all pairs, as without labels.
  bool patch_contrast = true;

  /// Throws std::invalid_argument naming the bad field.
  void Validate() const;
};

/// How well a model's albedo explains the scene's shading-compensated intensities at a pose.
struct AppearanceScore {
  /// False when there is no evidence: too few points, a uniform model texture there, no
  /// scene intensities or no model albedo.
  bool defined = false;
  /// Pearson correlation of model albedo and compensated scene intensity, [-1, 1]; 0 when
  /// not defined. Near 1: the printed texture is where the model says; near 0 or below:
  /// another texture (another item, or the model turned the wrong way).
  double correlation = 0.0;
  int points = 0;              ///< Compared point pairs (finite ones).
  double albedo_stddev = 0.0;  ///< Of the model albedo over the compared points.
  /// How many of the compared points carry the print: the participation ratio
  /// (sum x^2)^2 / sum x^4 of the albedo contrasts x (deviations from the mean, relative to
  /// their patch's mean with patch labels). Half the points on a dark block of a light face
  /// give about half the points; a face that is plain but for a thin printed border gives
  /// about the border's points, and a correlation over so few says little.
  double contrast_points = 0.0;
};

/// The scene intensity with the projector's shading divided out: the structured-light
/// sensor's white capture is about albedo * cos(incidence) / range^2 (plus a little ambient),
/// so intensity * range^2 / max(cos, min_cos) is proportional to the albedo. `p`, `n` (unit)
/// and `viewpoint` in one frame, metres; the result is relative (m^2), not in [0, 1].
float ShadingCompensatedIntensity(float intensity, const Eigen::Vector3f& p,
                                  const Eigen::Vector3f& n, const Eigen::Vector3f& viewpoint,
                                  float min_cos);

/// A view's intensity at `p` (unit normal `n`, its own sensor at `viewpoint`) with that
/// view's shading divided out (ShadingCompensatedIntensity with options.min_cos), for a
/// cloud merged from several views; nothing where the intensity or normal is not finite or
/// the view grazes the surface (incidence cosine below options.min_sample_cos): the merged
/// cloud then holds NaN there and its print comes from the other views
/// (AppearanceOptions::screened_per_view).
std::optional<float> CompensatedViewIntensity(float intensity, const Eigen::Vector3f& p,
                                              const Eigen::Vector3f& n,
                                              const Eigen::Vector3f& viewpoint,
                                              const AppearanceOptions& options);

/// One sample of the appearance comparison: the shading-compensated intensity
/// (ShadingCompensatedIntensity with options.min_cos), or nothing where the intensity is
/// not finite or the sensor grazes the surface (incidence cosine below
/// options.min_sample_cos), whose print is not compared. With options.screened_per_view the
/// intensity is already compensated and screened: taken as it is (nothing if not finite).
/// `n` is the unit normal the shading is taken from (a pose's own surface normal).
std::optional<float> AppearanceSample(float intensity, const Eigen::Vector3f& p,
                                      const Eigen::Vector3f& n, const Eigen::Vector3f& viewpoint,
                                      const AppearanceOptions& options);

/// Label of the model surface patch a point with unit model-frame normal `n_Model` lies on:
/// the nearest of the 26 directions of a cube's faces, edges and corners (at most about
/// 27 degrees away), so that a box's faces are one patch each and a curved surface is cut
/// into patches of similar orientation. 255 for a non-finite normal.
std::uint8_t SurfacePatch(const Eigen::Vector3f& n_Model);

/// Pearson correlation of `albedo` and `intensity` (equal lengths, compensated intensities;
/// pairs with a NaN are left out) with the evidence checks of `options`.
///
/// With `patches` (SurfacePatch labels, same length; pairs with another label are left
/// out) and options.patch_contrast, the
/// correlation is pooled over patches instead: within each patch, albedo and intensity are
/// taken relative to the patch's means (a / mean_a - 1 against i / mean_i - 1), and patches
/// whose albedo is uniform (stddev below min_albedo_stddev) or that have fewer than
/// min_patch_points pairs, or fewer than min_patch_points carrying the contrast (the
/// participation ratio (sum x^2)^2 / sum x^4 of the relative albedo contrasts x), are left
/// out. The shading compensation assumes the light at the
/// sensor, while a structured-light projector sits a baseline beside it, so each face keeps
/// a brightness factor of its own; relative to its own mean it cancels. And a uniform face
/// (a plain top) shows only shading residue: left in, it dilutes the print the other faces
/// show, and a true pose can read as contradicted.
/// Throws std::invalid_argument for different lengths or invalid options.
AppearanceScore CorrelateAppearance(const std::vector<float>& albedo,
                                    const std::vector<float>& intensity,
                                    const AppearanceOptions& options = {},
                                    const std::vector<std::uint8_t>* patches = nullptr);

/// Points with outward face normals sampled uniformly over the mesh surface, exactly the
/// points of SampleMeshSurface (templates.h) for the same spacing and seed, with the mesh's
/// albedo at each point in `intensities` (interpolated per-vertex albedo, or the uniform
/// `albedo`). Throws std::invalid_argument on an empty mesh, an out-of-range index,
/// a vertex_albedo of the wrong length or spacing_m <= 0.
geometry::PointCloud SampleTexturedMeshSurface(const world::TriangleMesh& mesh, double spacing_m,
                                               std::uint32_t seed = 1);

/// The luma (0.299 R + 0.587 G + 0.114 B) / 255 of an RGB colour, in [0, 1]: the intensity a
/// monochrome sensor sees of it, and the albedo of a coloured scan's point.
float ColorLuma(const std::array<std::uint8_t, 3>& rgb);

/// Fills `cloud.intensities` with the colour luma (0-1) when it has colours and no
/// intensities.
void IntensitiesFromColors(geometry::PointCloud* cloud);

}  // namespace picking::detector
