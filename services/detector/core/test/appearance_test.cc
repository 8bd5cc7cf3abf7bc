#include "services/detector/core/appearance.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>
#include <random>

#include "libs/apc/catalogue.h"
#include "libs/world/item_shapes.h"
#include "services/detector/core/model.h"
#include "services/detector/core/ppf_detector.h"
#include "services/detector/core/templates.h"
#include "services/detector/core/verify.h"

namespace picking::detector {
namespace {

apc::Item Item(int id, double long_m, double middle_m, double short_m) {
  apc::Item item;
  item.id = id;
  item.name = "item_" + std::to_string(id);
  item.long_side_m = long_m;
  item.middle_side_m = middle_m;
  item.short_side_m = short_m;
  return item;
}

world::TriangleMesh Mesh(const apc::Item& item, world::ShapeKind kind,
                         world::TextureKind texture = world::TextureKind::kBlocks) {
  world::ItemShape shape;
  shape.kind = kind;
  shape.albedo = 0.8f;
  shape.pattern_albedo = 0.25f;
  shape.texture = texture;
  return world::MakePrimitiveItemMesh(item, shape);
}

ObjectModel Model(const world::TriangleMesh& mesh, ModelSymmetry symmetry) {
  ObjectModelOptions options;
  options.use_input_normals = true;
  options.symmetry = symmetry;
  return ObjectModel(SampleTexturedMeshSurface(mesh, 0.002, 1), options);
}

Eigen::Isometry3d Turn(double angle, const Eigen::Vector3d& axis) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
  return X;
}

// What a structured-light sensor at the origin measures of `mesh` at X_SensorItem: the
// surface facing it (the meshes are convex), with the white capture's intensity
// 0.85 * albedo * (0.03 + cos(incidence) * (0.6 m / range)^2) plus noise, and position noise.
geometry::PointCloud ShadedScan(const world::TriangleMesh& mesh,
                                const Eigen::Isometry3d& X_SensorItem, std::uint32_t seed,
                                geometry::PointCloud* scene = nullptr) {
  const geometry::PointCloud surface = SampleTexturedMeshSurface(mesh, 0.0012, seed + 100);
  std::mt19937 rng(seed);
  std::normal_distribution<float> position_noise(0.0f, 0.0003f), intensity_noise(0.0f, 0.01f);
  geometry::PointCloud out = scene != nullptr ? *scene : geometry::PointCloud{};
  const Eigen::Isometry3f X = X_SensorItem.cast<float>();
  for (std::size_t i = 0; i < surface.size(); ++i) {
    const Eigen::Vector3f p = X * surface.points[i];
    const Eigen::Vector3f n = X.linear() * surface.normals[i];
    const float cos_incidence = -n.dot(p) / p.norm();
    if (cos_incidence <= 0.05f) continue;
    const float range_rel = 0.6f / p.norm();
    const float intensity =
        0.85f * surface.intensities[i] * (0.03f + cos_incidence * range_rel * range_rel);
    out.points.push_back(
        p + Eigen::Vector3f(position_noise(rng), position_noise(rng), position_noise(rng)));
    out.intensities.push_back(std::clamp(intensity + intensity_noise(rng), 0.0f, 1.0f));
  }
  out.width = static_cast<std::uint32_t>(out.points.size());
  out.height = 1;
  return out;
}

// The surface of `mesh` at X_SensorItem that faces a sensor at the origin, with its true
// normals and the intensity albedo * cos(incidence) * (0.6 m / range)^2; `distort` then
// may move each point and turn its normal, given the incidence cosine.
geometry::PointCloud LitSurface(
    const world::TriangleMesh& mesh, const Eigen::Isometry3d& X_SensorItem, std::uint32_t seed,
    const std::function<void(float, Eigen::Vector3f*, Eigen::Vector3f*)>& distort) {
  const geometry::PointCloud surface = SampleTexturedMeshSurface(mesh, 0.0012, seed);
  geometry::PointCloud scan;
  const Eigen::Isometry3f X = X_SensorItem.cast<float>();
  for (std::size_t i = 0; i < surface.size(); ++i) {
    Eigen::Vector3f p = X * surface.points[i];
    Eigen::Vector3f n = X.linear() * surface.normals[i];
    const float cos_incidence = -n.dot(p) / p.norm();
    if (cos_incidence <= 0.05f) continue;
    scan.intensities.push_back(surface.intensities[i] * cos_incidence * 0.36f / p.squaredNorm());
    distort(cos_incidence, &p, &n);
    scan.points.push_back(p);
    scan.normals.push_back(n);
  }
  scan.width = static_cast<std::uint32_t>(scan.points.size());
  scan.height = 1;
  return scan;
}

double RotationErrorRad(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle();
}

class AppearanceTest : public ::testing::Test {
 protected:
  void SetUp() override {
    target_ = Item(7, 0.20, 0.12, 0.06);
    X_true_ = Eigen::Translation3d(0.02, -0.01, 0.6) * Turn(0.5, {1.0, 0.3, 0.0}) *
              Turn(0.4, {0.0, 1.0, 0.2});
    scene_ = ShadedScan(Mesh(target_, world::ShapeKind::kBox), X_true_, 1);
  }

  apc::Item target_;
  Eigen::Isometry3d X_true_;
  geometry::PointCloud scene_;
};

TEST(SampleTexturedMeshSurfaceTest, SamplesTheSamePointsAsSampleMeshSurfaceWithTheirAlbedo) {
  const world::TriangleMesh mesh = Mesh(Item(3, 0.1, 0.08, 0.05), world::ShapeKind::kBox);
  const geometry::PointCloud plain = SampleMeshSurface(mesh, 0.003, 5);
  const geometry::PointCloud textured = SampleTexturedMeshSurface(mesh, 0.003, 5);
  ASSERT_EQ(plain.size(), textured.size());
  ASSERT_EQ(textured.intensities.size(), textured.size());
  int dark = 0;
  for (std::size_t i = 0; i < plain.size(); ++i) {
    ASSERT_EQ(plain.points[i], textured.points[i]);
    ASSERT_EQ(plain.normals[i], textured.normals[i]);
    // Each 1 cm cell has one albedo: the base colour or the print.
    const float a = textured.intensities[i];
    EXPECT_TRUE(std::abs(a - 0.8f) < 1e-5f || std::abs(a - 0.25f) < 1e-5f) << a;
    dark += a < 0.5f ? 1 : 0;
  }
  // A border and printed blocks on every face: a good part, but not all, is dark.
  EXPECT_GT(dark, static_cast<int>(plain.size() / 10));
  EXPECT_LT(dark, static_cast<int>(plain.size() * 9 / 10));

  world::TriangleMesh bad = mesh;
  bad.vertex_albedo.pop_back();
  EXPECT_THROW(SampleTexturedMeshSurface(bad, 0.003), std::invalid_argument);
  EXPECT_THROW(SampleTexturedMeshSurface(mesh, 0.0), std::invalid_argument);
}

TEST(CorrelateAppearanceTest, PearsonWithEvidenceChecks) {
  std::vector<float> albedo, intensity;
  for (int i = 0; i < 100; ++i) {
    albedo.push_back(i % 3 == 0 ? 0.2f : 0.8f);
    intensity.push_back(3.0f * albedo.back() + 0.1f);
  }
  AppearanceScore s = CorrelateAppearance(albedo, intensity);
  EXPECT_TRUE(s.defined);
  EXPECT_NEAR(s.correlation, 1.0, 1e-6);
  EXPECT_EQ(s.points, 100);
  std::vector<float> inverted = intensity;
  for (float& v : inverted) v = 3.0f - v;
  EXPECT_NEAR(CorrelateAppearance(albedo, inverted).correlation, -1.0, 1e-6);
  // A uniform model texture is no evidence, nor are too few points.
  const std::vector<float> uniform(100, 0.6f);
  s = CorrelateAppearance(uniform, intensity);
  EXPECT_FALSE(s.defined);
  EXPECT_EQ(s.correlation, 0.0);
  EXPECT_FALSE(CorrelateAppearance({0.2f, 0.8f}, {0.1f, 0.9f}).defined);
}

TEST(CorrelateAppearanceTest, RejectsMismatchedLengthsAndBadOptions) {
  EXPECT_THROW(CorrelateAppearance({0.1f, 0.2f}, {0.1f}), std::invalid_argument);
  AppearanceOptions options;
  options.min_cos = 0.0f;
  EXPECT_THROW(CorrelateAppearance({}, {}, options), std::invalid_argument);
  options = {};
  options.min_points = 1;
  EXPECT_THROW(CorrelateAppearance({}, {}, options), std::invalid_argument);
}

TEST(SurfacePatchTest, BoxFacesArePatchesOfTheirOwnAndNearNormalsShareOne) {
  std::vector<std::uint8_t> faces;
  for (int axis = 0; axis < 3; ++axis) {
    for (float sign : {1.0f, -1.0f}) {
      faces.push_back(SurfacePatch(sign * Eigen::Vector3f::Unit(axis)));
    }
  }
  for (std::size_t a = 0; a < faces.size(); ++a) {
    EXPECT_NE(faces[a], 255);
    for (std::size_t b = a + 1; b < faces.size(); ++b) EXPECT_NE(faces[a], faces[b]);
  }
  const Eigen::Vector3f tilted =
      Eigen::AngleAxisf(0.2f, Eigen::Vector3f::UnitX()) * Eigen::Vector3f::UnitZ();
  EXPECT_EQ(SurfacePatch(tilted), SurfacePatch(Eigen::Vector3f::UnitZ()));
  EXPECT_EQ(SurfacePatch(Eigen::Vector3f::Constant(std::nanf(""))), 255);
}

// Two printed faces that the light reaches differently (each face's intensity is its albedo
// times a factor of its own, as when the projector sits beside the camera) and a plain face
// whose intensity varies only with shading residue. One correlation over all of them mixes
// the faces' brightness levels into the print and lets the plain face dilute it; patch
// contrasts compare each face with itself and leave the plain one out.
TEST(PatchContrastTest, FaceBrightnessFactorsCancelAndPlainFacesAreLeftOut) {
  const std::uint8_t front = SurfacePatch(Eigen::Vector3f::UnitX());
  const std::uint8_t side = SurfacePatch(Eigen::Vector3f::UnitY());
  const std::uint8_t top = SurfacePatch(Eigen::Vector3f::UnitZ());
  std::mt19937 rng(3);
  std::normal_distribution<float> residue(0.0f, 0.1f);
  std::vector<float> albedo, intensity;
  std::vector<std::uint8_t> patches;
  for (int i = 0; i < 60; ++i) {
    const float a = i % 3 == 0 ? 0.2f : 0.8f;
    albedo.insert(albedo.end(), {a, a, 0.7f});
    // The side face is lit a third as strongly as the front: its light parts read darker
    // than the front's dark ones.
    intensity.insert(intensity.end(), {a, 0.15f * a, 0.7f * (1.0f + residue(rng))});
    patches.insert(patches.end(), {front, side, top});
  }
  AppearanceOptions pooled;
  pooled.patch_contrast = false;
  const AppearanceScore one = CorrelateAppearance(albedo, intensity, pooled, &patches);
  const AppearanceScore per_patch = CorrelateAppearance(albedo, intensity, {}, &patches);
  ASSERT_TRUE(one.defined);
  ASSERT_TRUE(per_patch.defined);
  EXPECT_LT(one.correlation, 0.7);
  EXPECT_NEAR(per_patch.correlation, 1.0, 1e-6);
  EXPECT_EQ(per_patch.points, 120);  // the plain top is not compared
  // A third of each printed face is dark: about 80 of the 120 points carry the print.
  EXPECT_GT(per_patch.contrast_points, 60.0);
  EXPECT_LT(per_patch.contrast_points, 120.0);

  // Without patches the same call is the plain correlation; a plain face alone is no
  // evidence; labels must match the pairs.
  EXPECT_DOUBLE_EQ(CorrelateAppearance(albedo, intensity).correlation, one.correlation);
  const std::vector<float> top_albedo(60, 0.7f), top_intensity(60, 0.5f);
  const std::vector<std::uint8_t> top_patches(60, top);
  EXPECT_FALSE(CorrelateAppearance(top_albedo, top_intensity, {}, &top_patches).defined);
  const std::vector<std::uint8_t> short_labels(3, front);
  EXPECT_THROW(CorrelateAppearance(albedo, intensity, {}, &short_labels), std::invalid_argument);
  AppearanceOptions any_patch;
  any_patch.min_albedo_stddev = 0.0f;
  EXPECT_FALSE(CorrelateAppearance(top_albedo, top_intensity, any_patch, &top_patches).defined);
  AppearanceOptions bad;
  bad.min_patch_points = 1;
  EXPECT_THROW(CorrelateAppearance(albedo, intensity, bad, &patches), std::invalid_argument);
}

// A large, nearly plain face (6 dark points among 300) whose few dark points read bright (a
// millimetre's misregistration at a grazing angle) beside a small printed face: the plain
// face's print is carried by too few points to count, so it cannot outvote the printed one.
TEST(PatchContrastTest, AFaceWhosePrintFewPointsCarryIsLeftOut) {
  const std::uint8_t front = SurfacePatch(Eigen::Vector3f::UnitX());
  const std::uint8_t top = SurfacePatch(Eigen::Vector3f::UnitZ());
  std::mt19937 rng(5);
  std::normal_distribution<float> noise(0.0f, 0.05f);
  std::vector<float> albedo, intensity;
  std::vector<std::uint8_t> patches;
  for (int i = 0; i < 40; ++i) {  // printed front: half dark, read as printed
    const float a = i % 2 == 0 ? 0.25f : 0.65f;
    albedo.push_back(a);
    intensity.push_back(a * (1.0f + noise(rng)));
    patches.push_back(front);
  }
  for (int i = 0; i < 300; ++i) {  // plain top: 6 dark points, all read bright
    albedo.push_back(i % 50 == 0 ? 0.25f : 0.65f);
    intensity.push_back(0.65f * (1.0f + noise(rng)));
    patches.push_back(top);
  }
  const AppearanceScore score = CorrelateAppearance(albedo, intensity, {}, &patches);
  ASSERT_TRUE(score.defined);
  EXPECT_EQ(score.points, 40);  // the front alone
  EXPECT_GT(score.correlation, 0.9);
  // Counting every patch with enough points, the plain top would drag it down.
  AppearanceOptions few;
  few.min_patch_points = 2;
  EXPECT_LT(CorrelateAppearance(albedo, intensity, few, &patches).correlation,
            score.correlation - 0.05);
}

// A point of a floor-lying face seen from a low view at a grazing angle and from a higher
// side view: the side view's intensity is compensated for its own shading; the low view's
// is left out.
TEST(CompensatedViewIntensityTest, CompensatesForItsOwnViewAndDropsGrazingViews) {
  const Eigen::Vector3f p(0.0f, 0.0f, 0.0f), n = Eigen::Vector3f::UnitZ();
  const Eigen::Vector3f low(-1.0f, 0.0f, 0.15f);  // cos about 0.15
  const Eigen::Vector3f high(-0.6f, 0.3f, 0.5f);  // cos about 0.6
  const AppearanceOptions options;
  const std::optional<float> side = CompensatedViewIntensity(0.3f, p, n, high, options);
  ASSERT_TRUE(side.has_value());
  EXPECT_NEAR(*side, ShadingCompensatedIntensity(0.3f, p, n, high, options.min_cos), 1e-6);
  EXPECT_FALSE(CompensatedViewIntensity(0.3f, p, n, low, options).has_value());
  EXPECT_FALSE(CompensatedViewIntensity(std::nanf(""), p, n, high, options).has_value());
  EXPECT_FALSE(
      CompensatedViewIntensity(0.3f, p, Eigen::Vector3f::Constant(std::nanf("")), high, options)
          .has_value());

  // The detector side: a sample at the low sensor's grazing angle is compared only when the
  // cloud was screened per view, and then as it is (already compensated); a NaN intensity
  // never is.
  AppearanceOptions screened;
  screened.screened_per_view = true;
  EXPECT_FALSE(AppearanceSample(*side, p, n, low, options).has_value());
  ASSERT_TRUE(AppearanceSample(*side, p, n, low, screened).has_value());
  EXPECT_FLOAT_EQ(*AppearanceSample(*side, p, n, low, screened), *side);
  EXPECT_FALSE(AppearanceSample(std::nanf(""), p, n, high, screened).has_value());
}

TEST(ShadingCompensatedIntensityTest, DividesOutIncidenceAndRange) {
  const Eigen::Vector3f viewpoint = Eigen::Vector3f::Zero();
  // The same albedo seen head-on at 0.5 m and at 60 degrees incidence at 1 m.
  const float head_on = 0.4f;
  const float oblique = 0.4f * 0.5f * 0.25f;
  const Eigen::Vector3f n_oblique =
      Eigen::Vector3f(std::sin(M_PI / 3), 0.0f, -std::cos(M_PI / 3)).normalized();
  EXPECT_NEAR(ShadingCompensatedIntensity(head_on, {0, 0, 0.5f}, {0, 0, -1}, viewpoint, 0.25f),
              ShadingCompensatedIntensity(oblique, {0, 0, 1.0f}, n_oblique, viewpoint, 0.25f),
              1e-6);
}

TEST_F(AppearanceTest, TruePoseCorrelatesAndWrongPosesDoNot) {
  const ObjectModel model = Model(Mesh(target_, world::ShapeKind::kBox), ModelSymmetry::kBox);
  ASSERT_TRUE(model.has_albedo());
  EXPECT_GT(model.albedo_stddev(), 0.1f);
  PpfSceneOptions scene_options;
  const PpfScene scene = PreparePpfScene(scene_, model, scene_options);
  ASSERT_TRUE(scene.fine.has_intensities());
  const float distance = 0.5f * model.sampling_distance_m();
  const AppearanceScore truth = MeasureAppearance(model, scene, X_true_, distance, 0.5f);
  ASSERT_TRUE(truth.defined);
  EXPECT_GT(truth.correlation, 0.8);
  EXPECT_GT(truth.points, 200);

  // Shifted along the box's long side by 3 cm (the geometry still overlaps in part).
  const AppearanceScore shifted = MeasureAppearance(
      model, scene, X_true_ * Eigen::Translation3d(0.03, 0.0, 0.0), distance, 0.5f);
  ASSERT_TRUE(shifted.defined);
  EXPECT_LT(shifted.correlation, truth.correlation - 0.3);

  // Each 180 degree flip fits the shape exactly but shows another part of the printing.
  for (std::size_t s = 1; s < model.symmetries().size(); ++s) {
    const AppearanceScore flipped =
        MeasureAppearance(model, scene, X_true_ * model.symmetries()[s], distance, 0.5f);
    ASSERT_TRUE(flipped.defined);
    EXPECT_LT(flipped.correlation, truth.correlation - 0.3) << "flip " << s;
  }

  // A box of the same size printed for another item.
  const ObjectModel neighbour =
      Model(Mesh(Item(8, 0.20, 0.12, 0.06), world::ShapeKind::kBox), ModelSymmetry::kBox);
  const AppearanceScore other = MeasureAppearance(neighbour, scene, X_true_, distance, 0.5f);
  ASSERT_TRUE(other.defined);
  EXPECT_LT(other.correlation, 0.4);
  // ... and none of its flips explains the scene either.
  const SymmetricAppearance best_other =
      MatchSymmetricAppearance(neighbour, scene, X_true_, distance, 0.5f);
  EXPECT_LT(best_other.appearance.correlation, 0.5);
}

// A flat box's large face seen 70 degrees off its normal, as a book lying on a shelf floor
// is from the bin's opening. The shading divided out of each intensity is cos(incidence),
// about 0.34 there, and the scan's normals are off by up to 15 degrees (noise at grazing
// incidence): compensating with the scan normal scatters 1 / cos by tens of percent, which
// drowns the print; the posed model's normal is the hypothesis's exact surface.
TEST(GrazingAppearanceTest, TheShadingOfAGrazingFaceIsTakenFromThePose) {
  const world::TriangleMesh mesh = Mesh(Item(9, 0.20, 0.12, 0.02), world::ShapeKind::kBox);
  const ObjectModel model = Model(mesh, ModelSymmetry::kBox);
  const Eigen::Isometry3d X_SensorItem =
      Eigen::Translation3d(0.0, 0.0, 0.6) * Turn(M_PI - 70.0 * M_PI / 180.0, {1.0, 0.0, 0.0});
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> tilt(-0.26f, 0.26f);  // +-15 degrees
  const geometry::PointCloud scan =
      LitSurface(mesh, X_SensorItem, 21, [&](float, Eigen::Vector3f*, Eigen::Vector3f* n) {
        const float about_x = tilt(rng);
        const float about_y = tilt(rng);
        *n = (Eigen::AngleAxisf(about_x, Eigen::Vector3f::UnitX()) *
              Eigen::AngleAxisf(about_y, Eigen::Vector3f::UnitY())) *
             *n;
      });
  PpfSceneOptions options;
  options.use_input_normals = true;
  const PpfScene scene = PreparePpfScene(scan, model, options);
  const AppearanceScore truth =
      MeasureAppearance(model, scene, X_SensorItem, 0.5f * model.sampling_distance_m(), 0.5f);
  ASSERT_TRUE(truth.defined);
  EXPECT_GT(truth.points, 200);
  EXPECT_GT(truth.correlation, 0.9);
}

// A box with one face seen head-on and one at 78 degrees (incidence cosine about 0.2), whose
// points a depth error of 8 mm along the rays has slid about 8 mm along that face, as
// structured light does where it grazes a surface. The slid face shows its print in the
// wrong place; AppearanceOptions::min_sample_cos leaves it out of the comparison.
TEST(GrazingAppearanceTest, AFaceSeenAtAGrazingAngleIsNotCompared) {
  const world::TriangleMesh mesh = Mesh(Item(11, 0.20, 0.12, 0.06), world::ShapeKind::kBox);
  const ObjectModel model = Model(mesh, ModelSymmetry::kBox);
  const Eigen::Isometry3d X_SensorItem =
      Eigen::Translation3d(0.0, 0.0, 0.6) * Turn(M_PI - 12.0 * M_PI / 180.0, {1.0, 0.0, 0.0});
  int grazing = 0;
  const geometry::PointCloud scan = LitSurface(
      mesh, X_SensorItem, 23, [&](float cos_incidence, Eigen::Vector3f* p, Eigen::Vector3f*) {
        if (cos_incidence >= 0.25f) return;
        *p += 0.008f * p->normalized();
        ++grazing;
      });
  ASSERT_GT(grazing, static_cast<int>(scan.size() / 5));
  PpfSceneOptions scene_options;
  scene_options.use_input_normals = true;
  const PpfScene scene = PreparePpfScene(scan, model, scene_options);
  const float distance = 0.5f * model.sampling_distance_m();
  // One correlation over both faces (per-patch contrasts would take the slid face apart
  // and soften its effect; see PatchContrastTest).
  AppearanceOptions pooled;
  pooled.patch_contrast = false;
  const AppearanceScore kept =
      MeasureAppearance(model, scene, X_SensorItem, distance, 0.5f, pooled);
  AppearanceOptions every_sample = pooled;
  every_sample.min_sample_cos = 0.0f;
  const AppearanceScore all =
      MeasureAppearance(model, scene, X_SensorItem, distance, 0.5f, every_sample);
  ASSERT_TRUE(kept.defined);
  ASSERT_TRUE(all.defined);
  EXPECT_LT(kept.points, all.points);
  EXPECT_GT(kept.correlation, 0.9);
  EXPECT_LT(all.correlation, kept.correlation - 0.1);

  // Verify leaves out the grazing face's samples that its z-buffer keeps.
  const PinholeCamera camera(640, 480, 600.0, 600.0, 319.5, 239.5);
  const VerificationScene verification(scan, Eigen::Isometry3d::Identity(), camera);
  VerifyOptions verify_pooled;
  verify_pooled.appearance = pooled;
  const VerifyResult verified =
      Verify(verification, model.icp_cloud(), X_SensorItem, verify_pooled);
  VerifyOptions every = verify_pooled;
  every.appearance.min_sample_cos = 0.0f;
  const VerifyResult verified_all = Verify(verification, model.icp_cloud(), X_SensorItem, every);
  ASSERT_TRUE(verified.appearance.defined);
  ASSERT_TRUE(verified_all.appearance.defined);
  EXPECT_LT(verified.appearance.points, verified_all.appearance.points);
  EXPECT_GT(verified.appearance.correlation, 0.8);

  AppearanceOptions bad;
  bad.min_sample_cos = 1.0f;
  EXPECT_THROW(MeasureAppearance(model, scene, X_SensorItem, distance, 0.5f, bad),
               std::invalid_argument);
}

TEST_F(AppearanceTest, UniformTextureAndMissingIntensitiesAreNoEvidence) {
  const ObjectModel plain = Model(
      Mesh(target_, world::ShapeKind::kBox, world::TextureKind::kUniform), ModelSymmetry::kBox);
  EXPECT_LT(plain.albedo_stddev(), 1e-6f);
  const PpfScene scene = PreparePpfScene(scene_, plain);
  EXPECT_FALSE(MeasureAppearance(plain, scene, X_true_, 0.005f, 0.5f).defined);

  const ObjectModel model = Model(Mesh(target_, world::ShapeKind::kBox), ModelSymmetry::kBox);
  geometry::PointCloud grey = scene_;
  grey.intensities.clear();
  const PpfScene no_intensities = PreparePpfScene(grey, model);
  EXPECT_FALSE(no_intensities.fine.has_intensities());
  const SymmetricAppearance a =
      MatchSymmetricAppearance(model, no_intensities, X_true_, 0.005f, 0.5f);
  EXPECT_FALSE(a.appearance.defined);
  EXPECT_EQ(a.symmetry, 0);
  EXPECT_TRUE(a.X_SceneModel.isApprox(X_true_));
}

TEST_F(AppearanceTest, SymmetricMatchTurnsAFlippedBoxBack) {
  const ObjectModel model = Model(Mesh(target_, world::ShapeKind::kBox), ModelSymmetry::kBox);
  ASSERT_EQ(model.symmetries().size(), 4u);
  const PpfScene scene = PreparePpfScene(scene_, model);
  const float distance = 0.5f * model.sampling_distance_m();
  for (std::size_t s = 1; s < 4; ++s) {
    const Eigen::Isometry3d flipped = X_true_ * model.symmetries()[s];
    const SymmetricAppearance m = MatchSymmetricAppearance(model, scene, flipped, distance, 0.5f);
    ASSERT_TRUE(m.appearance.defined);
    EXPECT_NE(m.symmetry, 0);
    EXPECT_LT(RotationErrorRad(m.X_SceneModel, X_true_), 1e-6) << "flip " << s;
    EXPECT_LT((m.X_SceneModel.translation() - X_true_.translation()).norm(), 1e-9);
    EXPECT_GT(m.appearance.correlation, m.unturned.correlation + 0.3);
  }
}

TEST(SymmetricAppearanceCylinderTest, FindsTheTurnAboutTheAxis) {
  const apc::Item bottle = Item(24, 0.22, 0.07, 0.07);
  const world::TriangleMesh mesh = Mesh(bottle, world::ShapeKind::kCylinder);
  const ObjectModel model = Model(mesh, ModelSymmetry::kCylinderX);
  ASSERT_EQ(model.symmetries().size(), 72u);
  const Eigen::Isometry3d X_true = Eigen::Translation3d(0.0, 0.02, 0.55) *
                                   Turn(0.3, {0.0, 0.0, 1.0}) * Turn(1.0, {1.0, 0.0, 0.0});
  const geometry::PointCloud cloud = ShadedScan(mesh, X_true, 2);
  const PpfScene scene = PreparePpfScene(cloud, model);
  const float distance = 0.5f * model.sampling_distance_m();
  // Turned by 100 degrees about its axis, and end over end: the same geometry.
  const Eigen::Isometry3d wrong = X_true * Turn(100.0 * M_PI / 180.0, Eigen::Vector3d::UnitX()) *
                                  Turn(M_PI, Eigen::Vector3d::UnitY());
  const SymmetricAppearance m = MatchSymmetricAppearance(model, scene, wrong, distance, 0.5f);
  ASSERT_TRUE(m.appearance.defined);
  EXPECT_GT(m.appearance.correlation, 0.6);
  // Within half a 10 degree step of the truth.
  EXPECT_LT(RotationErrorRad(m.X_SceneModel, X_true), 6.0 * M_PI / 180.0);
}

// A flat box face-on to the sensor, started 5 mm along its long side and 3 degrees about
// its face normal from the truth: the geometry cannot tell (the face slides along itself),
// the print can.
class AppearanceSearchTest : public ::testing::Test {
 protected:
  void SetUp() override {
    mesh_ = Mesh(Item(26, 0.20, 0.12, 0.03), world::ShapeKind::kBox);
    X_true_ = Eigen::Translation3d(0.01, 0.02, 0.55) * Turn(M_PI - 0.35, {1.0, 0.2, 0.0});
    scene_ = ShadedScan(mesh_, X_true_, 6);
  }

  world::TriangleMesh mesh_;
  Eigen::Isometry3d X_true_;
  geometry::PointCloud scene_;
};

TEST_F(AppearanceSearchTest, ThePrintSlidesAFaceBackAlongItself) {
  const ObjectModel model = Model(mesh_, ModelSymmetry::kNone);
  const PpfScene scene = PreparePpfScene(scene_, model);
  const float distance = 0.5f * model.sampling_distance_m();
  const Eigen::Isometry3d start = X_true_ * Eigen::Translation3d(0.005, 0.0, 0.0) *
                                  Turn(3.0 * M_PI / 180.0, Eigen::Vector3d::UnitZ());
  const AppearanceScore at_start = MeasureAppearance(model, scene, start, distance, 0.5f);
  const AppearancePose found = SearchAppearancePose(model, scene, start, distance, 0.5f);
  ASSERT_TRUE(found.appearance.defined);
  EXPECT_GT(found.appearance.correlation, at_start.correlation + 0.1);
  EXPECT_GT(found.appearance.correlation, 0.9);
  // Within the model's albedo resolution (its fine voxel, 1 % of the diameter: 2.3 mm).
  EXPECT_LT((found.X_SceneModel.translation() - X_true_.translation()).norm(), 0.002);
  EXPECT_LT(RotationErrorRad(found.X_SceneModel, X_true_), 0.8 * M_PI / 180.0);
  // The face stays in its plane: the geometric term holds what the print is blind to.
  const Eigen::Vector3d face_normal = X_true_.linear().col(2);
  EXPECT_LT(std::abs(face_normal.dot(found.X_SceneModel.translation() - X_true_.translation())),
            0.0005);
}

TEST_F(AppearanceSearchTest, TheTruePoseStaysAndNoSearchIsTheStart) {
  const ObjectModel model = Model(mesh_, ModelSymmetry::kNone);
  const PpfScene scene = PreparePpfScene(scene_, model);
  const float distance = 0.5f * model.sampling_distance_m();
  const AppearancePose stay = SearchAppearancePose(model, scene, X_true_, distance, 0.5f);
  EXPECT_LT((stay.X_SceneModel.translation() - X_true_.translation()).norm(), 0.0015);
  EXPECT_LT(RotationErrorRad(stay.X_SceneModel, X_true_), 0.5 * M_PI / 180.0);

  const Eigen::Isometry3d start = X_true_ * Eigen::Translation3d(0.005, 0.0, 0.0);
  AppearanceSearchOptions off;
  off.levels = 0;
  const AppearancePose same = SearchAppearancePose(model, scene, start, distance, 0.5f, {}, off);
  EXPECT_TRUE(same.X_SceneModel.isApprox(start));
  EXPECT_NEAR(same.appearance.correlation,
              MeasureAppearance(model, scene, start, distance, 0.5f).correlation, 1e-12);

  for (const auto& bad : std::vector<std::function<void(AppearanceSearchOptions*)>>{
           [](AppearanceSearchOptions* o) { o->levels = -1; },
           [](AppearanceSearchOptions* o) { o->start_step_m = 0.0; },
           [](AppearanceSearchOptions* o) { o->start_step_m = std::nan(""); },
           [](AppearanceSearchOptions* o) { o->max_samples = 10; },
           [](AppearanceSearchOptions* o) { o->max_moves_per_level = 0; }}) {
    AppearanceSearchOptions options;
    bad(&options);
    EXPECT_THROW(SearchAppearancePose(model, scene, start, distance, 0.5f, {}, options),
                 std::invalid_argument);
  }
}

TEST(ModelAlbedoTest, EdgesAreMaskedButAThinBooksCoversAreNot) {
  // A book 1 cm thick: the covers are closer than the edge radius, but face away.
  const ObjectModel book =
      Model(Mesh(Item(21, 0.22, 0.15, 0.01), world::ShapeKind::kBox), ModelSymmetry::kBox);
  int finite = 0, masked = 0;
  for (std::size_t i = 0; i < book.fine_cloud().size(); ++i) {
    const Eigen::Vector3f& p = book.fine_cloud().points[i];
    const bool interior = std::abs(p.x()) < 0.08f && std::abs(p.y()) < 0.05f;
    if (std::isfinite(book.fine_cloud().intensities[i])) {
      ++finite;
    } else {
      ++masked;
      EXPECT_FALSE(interior) << p.transpose();
    }
  }
  EXPECT_GT(masked, 0);
  EXPECT_GT(finite, masked);
  // A sphere's orientation is free: it keeps no albedo.
  const ObjectModel ball =
      Model(Mesh(Item(3, 0.07, 0.07, 0.07), world::ShapeKind::kSphere), ModelSymmetry::kSphere);
  EXPECT_FALSE(ball.has_albedo());
}

TEST(DetectPpfAppearanceTest, PicksTheTargetAmongSameSizeNeighbours) {
  // Two boxes of the same size side by side; only the printing tells them apart.
  const apc::Item target = Item(11, 0.16, 0.10, 0.05);
  const apc::Item other = Item(12, 0.16, 0.10, 0.05);
  const Eigen::Isometry3d X_target =
      Eigen::Translation3d(-0.07, 0.0, 0.6) * Turn(0.35, {1.0, 0.4, 0.0});
  const Eigen::Isometry3d X_other =
      Eigen::Translation3d(0.07, 0.0, 0.6) * Turn(0.35, {1.0, -0.4, 0.0});
  geometry::PointCloud cloud = ShadedScan(Mesh(other, world::ShapeKind::kBox), X_other, 3);
  cloud = ShadedScan(Mesh(target, world::ShapeKind::kBox), X_target, 4, &cloud);
  const ObjectModel model = Model(Mesh(target, world::ShapeKind::kBox), ModelSymmetry::kBox);
  const PpfScene scene = PreparePpfScene(cloud, model);
  PpfDetectorOptions options;
  options.hypotheses_to_verify = 12;
  const PpfDetectionResult result = DetectPpf(model, scene, options);
  ASSERT_FALSE(result.detections.empty());
  // The target ranks first, with its printing the right way round.
  const PpfDetection& best = result.detections.front();
  EXPECT_LT((best.X_SceneModel.translation() - X_target.translation()).norm(), 0.005);
  EXPECT_LT(RotationErrorRad(best.X_SceneModel, X_target), 0.05);
  ASSERT_TRUE(best.appearance.defined);
  EXPECT_GT(best.appearance.correlation, 0.6);
  // The neighbour fits the shape as well, but not the printing.
  for (std::size_t k = 1; k < result.detections.size(); ++k) {
    const PpfDetection& d = result.detections[k];
    if ((d.X_SceneModel.translation() - X_other.translation()).norm() > 0.01) continue;
    EXPECT_LT(d.appearance.correlation, best.appearance.correlation - 0.3);
  }
  // Demanding a correlation the neighbour cannot reach rejects it, the target stays.
  options.min_appearance_correlation = 0.5f;
  const PpfDetectionResult strict = DetectPpf(model, scene, options);
  ASSERT_FALSE(strict.detections.empty());
  for (const PpfDetection& d : strict.detections) {
    EXPECT_GT((d.X_SceneModel.translation() - X_other.translation()).norm(), 0.05);
    EXPECT_GE(d.appearance.correlation, 0.5);
  }
  // Without appearance evidence (a model without albedo) the neighbour is as good as the target.
  geometry::PointCloud grey =
      SampleTexturedMeshSurface(Mesh(target, world::ShapeKind::kBox), 0.002, 1);
  grey.intensities.clear();
  ObjectModelOptions grey_options;
  grey_options.use_input_normals = true;
  const ObjectModel grey_model(grey, grey_options);
  const PpfDetectionResult blind =
      DetectPpf(grey_model, PreparePpfScene(cloud, grey_model), options);
  bool neighbour_reported = false;
  for (const PpfDetection& d : blind.detections) {
    EXPECT_FALSE(d.appearance.defined);
    neighbour_reported |= (d.X_SceneModel.translation() - X_other.translation()).norm() < 0.01;
  }
  EXPECT_TRUE(neighbour_reported);
}

TEST(VerifyAppearanceTest, ReportsTheCorrelationAndScalesAContradictedScore) {
  const apc::Item target = Item(7, 0.20, 0.12, 0.06);
  const world::TriangleMesh mesh = Mesh(target, world::ShapeKind::kBox);
  const Eigen::Isometry3d X_true = Eigen::Translation3d(0.0, 0.0, 0.6) * Turn(0.5, {1.0, 0.3, 0.0});
  const geometry::PointCloud scene = ShadedScan(mesh, X_true, 5);
  const PinholeCamera camera(640, 480, 600.0, 600.0, 319.5, 239.5);
  const VerificationScene verification(scene, Eigen::Isometry3d::Identity(), camera);
  const geometry::PointCloud model = Model(mesh, ModelSymmetry::kBox).icp_cloud();

  const VerifyResult truth = Verify(verification, model, X_true);
  ASSERT_TRUE(truth.appearance.defined);
  EXPECT_GT(truth.appearance.correlation, 0.7);
  EXPECT_FALSE(truth.appearance_contradicts);
  EXPECT_GT(truth.score, 0.8);

  const geometry::PointCloud neighbour =
      Model(Mesh(Item(8, 0.20, 0.12, 0.06), world::ShapeKind::kBox), ModelSymmetry::kBox)
          .icp_cloud();
  VerifyOptions scaled;
  scaled.appearance_contradiction_scale = 0.5;
  const VerifyResult other = Verify(verification, neighbour, X_true, scaled);
  ASSERT_TRUE(other.appearance.defined);
  EXPECT_LT(other.appearance.correlation, 0.2);
  EXPECT_TRUE(other.appearance_contradicts);
  EXPECT_NEAR(other.score, 0.5 * truth.score, 0.1);

  // By default the contradiction is only reported: the geometric score is kept.
  const VerifyResult reported = Verify(verification, neighbour, X_true);
  EXPECT_TRUE(reported.appearance_contradicts);
  EXPECT_NEAR(reported.score, truth.score, 0.05);

  // A model without albedo is scored on geometry alone.
  geometry::PointCloud grey = model;
  grey.intensities.clear();
  const VerifyResult plain = Verify(verification, grey, X_true);
  EXPECT_FALSE(plain.appearance.defined);
  EXPECT_NEAR(plain.score, truth.score, 0.05);

  // Turned by a box flip, the printing contradicts; told the symmetries, Verify finds the
  // turn back.
  const ObjectModel box = Model(mesh, ModelSymmetry::kBox);
  const Eigen::Isometry3d X_flipped = X_true * box.symmetries()[2];
  const VerifyResult flipped = Verify(verification, model, X_flipped);
  ASSERT_TRUE(flipped.appearance.defined);
  VerifyOptions symmetric;
  symmetric.symmetries = box.symmetries();
  const VerifyResult turned = Verify(verification, model, X_flipped, symmetric);
  ASSERT_TRUE(turned.appearance.defined);
  EXPECT_GT(turned.appearance.correlation, 0.7);
  EXPECT_LT(flipped.appearance.correlation, turned.appearance.correlation - 0.3);
  EXPECT_EQ(turned.appearance_symmetry, 2);
  EXPECT_LT(RotationErrorRad(turned.X_BaseItem_appearance, X_true), 1e-6);
  EXPECT_NEAR(turned.score, flipped.score, 1e-9);  // the geometry is the same

  geometry::PointCloud broken = model;
  broken.intensities.pop_back();
  EXPECT_THROW(Verify(verification, broken, X_true), std::invalid_argument);
}

}  // namespace
}  // namespace picking::detector
