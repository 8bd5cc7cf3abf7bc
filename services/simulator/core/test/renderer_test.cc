#include "services/simulator/core/renderer.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>

namespace picking::simulator {
namespace {

using camera::Distortion;
using camera::PinholeCamera;

// A small camera (fast tests) with the scanner's field of view and some lens distortion.
PinholeCamera TestCamera() {
  Distortion d;
  d.k1 = -0.1;
  d.k2 = 0.05;
  d.p1 = 0.001;
  d.p2 = -0.0005;
  return PinholeCamera(160, 128, 190.0, 189.0, 80.3, 63.1, d);
}

// A small projector, 912 x 1140 scaled by 1/8, slightly distorted.
PinholeCamera TestProjector() {
  Distortion d;
  d.k1 = 0.02;
  return PinholeCamera(114, 143, 170.0, 170.0, 56.5, 71.0, d);
}

// Projector 0.1 m to the right of the camera (base x), toed in by 7 degrees toward it.
Eigen::Isometry3d ProjectorPose() {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(0.1, 0.0, 0.0);
  X.linear() = Eigen::AngleAxisd(-7.0 * M_PI / 180.0, Eigen::Vector3d::UnitY()).toRotationMatrix();
  return X;
}

ScanPose TestPose() {
  return ScanPose{TestCamera(), Eigen::Isometry3d::Identity(), TestProjector(), ProjectorPose()};
}

// Square in the z = 0 plane of its frame, half size `half_m`, normal +z, CCW.
world::TriangleMesh Square(double half_m) {
  world::TriangleMesh mesh;
  const float h = static_cast<float>(half_m);
  mesh.vertices = {{-h, -h, 0.0f}, {h, -h, 0.0f}, {h, h, 0.0f}, {-h, h, 0.0f}};
  mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
  mesh.albedo = 0.6f;
  mesh.name = "square";
  return mesh;
}

Eigen::Isometry3d Translation(double x, double y, double z) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(x, y, z);
  return X;
}

RenderOptions NoiseFree() {
  RenderOptions options;
  options.read_noise_dn = 0.0;
  options.electrons_per_dn = 0.0;
  return options;
}

GrayImage Uniform(const ScanGeometry& g, std::uint8_t value) {
  return GrayImage(g.projector_width, g.projector_height, value);
}

TEST(StructuredLightRendererTest, PlaneAtKnownDistanceGivesExactDepthEverywhere) {
  const world::TriangleMesh plane = Square(5.0);
  const double distance_m = 0.8;
  StructuredLightRenderer renderer({{&plane, Translation(0.0, 0.0, distance_m)}});
  const ScanPose pose = TestPose();
  const ScanGeometry g = renderer.Prepare(pose);
  ASSERT_EQ(g.width, 160);
  ASSERT_EQ(g.height, 128);
  for (int y = 0; y < g.height; ++y) {
    for (int x = 0; x < g.width; ++x) {
      const std::size_t i = std::size_t(y) * g.width + x;
      ASSERT_EQ(g.object_index[i], 0) << x << "," << y;
      EXPECT_NEAR(g.depth_m[i], distance_m, 1e-5) << x << "," << y;
      EXPECT_NEAR(g.points_camera[i].z(), distance_m, 1e-5);
      // The point lies on the ray of its pixel (through the lens distortion).
      const auto uv = pose.camera.Project(g.points_camera[i].cast<double>());
      ASSERT_TRUE(uv.has_value());
      EXPECT_NEAR(uv->x(), x, 1e-3);
      EXPECT_NEAR(uv->y(), y, 1e-3);
      EXPECT_NEAR(g.normals_camera[i].z(), -1.0f, 1e-5f);
      EXPECT_FLOAT_EQ(g.albedo[i], 0.6f);
    }
  }
}

TEST(StructuredLightRendererTest, TiltedPlaneMatchesAnalyticRayIntersection) {
  const world::TriangleMesh plane = Square(5.0);
  Eigen::Isometry3d X_BasePlane = Translation(0.02, -0.01, 0.7);
  X_BasePlane.linear() = (Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitY()) *
                          Eigen::AngleAxisd(-0.25, Eigen::Vector3d::UnitX()))
                             .toRotationMatrix();
  Eigen::Isometry3d X_BaseCamera = Translation(0.01, 0.02, -0.05);
  X_BaseCamera.linear() = Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  StructuredLightRenderer renderer({{&plane, X_BasePlane}});
  const ScanPose pose{TestCamera(), X_BaseCamera, TestProjector(), X_BaseCamera * ProjectorPose()};
  const ScanGeometry g = renderer.Prepare(pose);
  // Plane in the camera frame: n . p = c.
  const Eigen::Isometry3d X_CameraPlane = X_BaseCamera.inverse() * X_BasePlane;
  const Eigen::Vector3d n_C = X_CameraPlane.linear().col(2);
  const double c = n_C.dot(X_CameraPlane.translation());
  for (int y = 0; y < g.height; y += 3) {
    for (int x = 0; x < g.width; x += 3) {
      const std::size_t i = std::size_t(y) * g.width + x;
      const Eigen::Vector3d ray = pose.camera.Unproject(Eigen::Vector2d(x, y));
      const double depth = c / n_C.dot(ray);
      ASSERT_EQ(g.object_index[i], 0);
      EXPECT_NEAR(g.depth_m[i], depth, 2e-5 * depth) << x << "," << y;
      EXPECT_GT(std::abs(g.normals_camera[i].cast<double>().dot(n_C)), 1.0 - 1e-5);
      EXPECT_LT(g.normals_camera[i].cast<double>().dot(ray), 0.0);  // Toward the camera.
    }
  }
}

TEST(StructuredLightRendererTest, ProjectorMappingAgreesWithProjectorModel) {
  const world::TriangleMesh plane = Square(5.0);
  Eigen::Isometry3d X_BasePlane = Translation(0.0, 0.0, 0.75);
  X_BasePlane.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitY()).toRotationMatrix();
  StructuredLightRenderer renderer({{&plane, X_BasePlane}});
  const ScanPose pose = TestPose();
  const ScanGeometry g = renderer.Prepare(pose);
  const Eigen::Isometry3d X_ProjectorCamera = pose.X_BaseProjector.inverse() * pose.X_BaseCamera;
  int lit = 0;
  for (std::size_t i = 0; i < g.size(); ++i) {
    const auto uv = pose.projector.Project(X_ProjectorCamera * g.points_camera[i].cast<double>());
    ASSERT_TRUE(uv.has_value());
    if (g.illumination[i] == Illumination::kLit) {
      ++lit;
      EXPECT_NEAR(g.projector_uv[i].x(), uv->x(), 1e-3);
      EXPECT_NEAR(g.projector_uv[i].y(), uv->y(), 1e-3);
    } else {
      // Nothing blocks the projector here, so only pixels it does not reach are unlit.
      EXPECT_EQ(g.illumination[i], Illumination::kOutsideProjector);
      EXPECT_FALSE(pose.projector.Contains(*uv));
      EXPECT_TRUE(std::isnan(g.projector_uv[i].x()));
    }
  }
  EXPECT_GT(lit, static_cast<int>(g.size() / 2));
}

TEST(StructuredLightRendererTest, ProjectorAtCameraSeesEachPixelAtItsOwnCoordinates) {
  // A projector with the camera's pose and lens sees every surface point at the camera
  // pixel it came from: checks the distortion round trip camera -> scene -> projector.
  const world::TriangleMesh plane = Square(5.0);
  Eigen::Isometry3d X_BasePlane = Translation(0.0, 0.0, 0.9);
  X_BasePlane.linear() = Eigen::AngleAxisd(-0.5, Eigen::Vector3d::UnitX()).toRotationMatrix();
  StructuredLightRenderer renderer({{&plane, X_BasePlane}});
  const ScanPose pose{TestCamera(), Translation(0.1, 0.2, 0.0), TestCamera(),
                      Translation(0.1, 0.2, 0.0)};
  const ScanGeometry g = renderer.Prepare(pose);
  for (int y = 0; y < g.height; ++y) {
    for (int x = 0; x < g.width; ++x) {
      const std::size_t i = std::size_t(y) * g.width + x;
      ASSERT_EQ(g.illumination[i], Illumination::kLit) << x << "," << y;
      EXPECT_NEAR(g.projector_uv[i].x(), x, 2e-3);
      EXPECT_NEAR(g.projector_uv[i].y(), y, 2e-3);
    }
  }
}

// Plane at z = 0.8 and a 4 x 4 cm plate at z = 0.5 in front of the projector. The expected
// shadow is computed analytically: the segment from the surface point to the projector
// centre crosses the plate.
class ShadowTest : public ::testing::Test {
 protected:
  static constexpr double kPlateHalf = 0.02;
  static constexpr double kPlateZ = 0.5;
  static constexpr double kPlateX = 0.06;
  static constexpr double kPlateY = 0.01;

  void SetUp() override {
    plane_ = Square(5.0);
    plate_ = Square(kPlateHalf);
    plate_.albedo = 0.3f;
    renderer_ = std::make_unique<StructuredLightRenderer>(std::vector<SceneObject>{
        {&plane_, Translation(0.0, 0.0, 0.8)}, {&plate_, Translation(kPlateX, kPlateY, kPlateZ)}});
    geometry_ = renderer_->Prepare(TestPose());
  }

  // Signed distance (metres, > 0 inside) of the crossing of segment point -> projector with
  // the plate's plane from the plate border.
  static double InsidePlate(const Eigen::Vector3d& p_BasePoint) {
    const Eigen::Vector3d p_BP = ProjectorPose().translation();
    const double s = (kPlateZ - p_BasePoint.z()) / (p_BP.z() - p_BasePoint.z());
    const Eigen::Vector3d q = p_BasePoint + s * (p_BP - p_BasePoint);
    return kPlateHalf - std::max(std::abs(q.x() - kPlateX), std::abs(q.y() - kPlateY));
  }

  world::TriangleMesh plane_;
  world::TriangleMesh plate_;
  std::unique_ptr<StructuredLightRenderer> renderer_;
  ScanGeometry geometry_;
};

TEST_F(ShadowTest, ShadowFallsWhereTheGeometrySays) {
  const ScanGeometry& g = geometry_;
  int shadowed = 0;
  int plate_pixels = 0;
  for (std::size_t i = 0; i < g.size(); ++i) {
    if (g.object_index[i] == 1) {
      ++plate_pixels;
      EXPECT_NEAR(g.depth_m[i], kPlateZ, 1e-5);
      continue;
    }
    ASSERT_EQ(g.object_index[i], 0);
    const double inside = InsidePlate(g.points_camera[i].cast<double>());  // Camera = base.
    if (std::abs(inside) < 1e-4) continue;                                 // On the shadow border.
    if (inside > 0.0) {
      ++shadowed;
      EXPECT_EQ(g.illumination[i], Illumination::kShadowed) << i;
      EXPECT_EQ(g.gain[i], 0.0f);
    } else if (g.illumination[i] != Illumination::kOutsideProjector) {
      EXPECT_EQ(g.illumination[i], Illumination::kLit) << i;
    }
  }
  EXPECT_GT(plate_pixels, 100);
  EXPECT_GT(shadowed, 100);  // The shadow is visible next to the plate.
}

TEST_F(ShadowTest, ShadowIsEquallyDarkInWhiteAndBlackImages) {
  const ScanGeometry& g = geometry_;
  const RenderOptions options = NoiseFree();
  const GrayImage white = RenderImage(g, Uniform(g, 255), options);
  const GrayImage black = RenderImage(g, Uniform(g, 0), options);
  int shadowed = 0;
  for (std::size_t i = 0; i < g.size(); ++i) {
    if (g.illumination[i] == Illumination::kShadowed) {
      ++shadowed;
      EXPECT_EQ(white.pixels[i], black.pixels[i]);
      // Only the ambient light: 255 * 0.85 * 0.03 * 0.6 ~ 4 DN.
      EXPECT_LE(white.pixels[i], 5);
    } else if (g.illumination[i] == Illumination::kLit) {
      EXPECT_GT(white.pixels[i], black.pixels[i] + 50);
    }
  }
  EXPECT_GT(shadowed, 100);
}

TEST(StructuredLightRendererTest, WhiteIsBrighterThanBlackWhereLitWithNoise) {
  const world::TriangleMesh plane = Square(5.0);
  StructuredLightRenderer renderer({{&plane, Translation(0.0, 0.0, 0.8)}});
  const ScanGeometry g = renderer.Prepare(TestPose());
  RenderOptions options;
  options.read_noise_dn = 2.0;
  options.seed = 7;
  const GrayImage white = RenderImage(g, Uniform(g, 255), options, 0);
  const GrayImage black = RenderImage(g, Uniform(g, 0), options, 1);
  int lit = 0;
  for (std::size_t i = 0; i < g.size(); ++i) {
    if (g.illumination[i] != Illumination::kLit) continue;
    ++lit;
    EXPECT_GT(int(white.pixels[i]), int(black.pixels[i]) + 60);
  }
  EXPECT_GT(lit, static_cast<int>(g.size() / 2));
}

TEST(StructuredLightRendererTest, RenderingIsDeterministicForASeed) {
  const world::TriangleMesh plane = Square(5.0);
  StructuredLightRenderer renderer({{&plane, Translation(0.0, 0.0, 0.8)}});
  const ScanGeometry g = renderer.Prepare(TestPose());
  GrayImage stripes(g.projector_width, g.projector_height);
  for (int r = 0; r < stripes.height; ++r) {
    for (int c = 0; c < stripes.width; ++c) stripes.at(c, r) = (c / 8) % 2 ? 255 : 0;
  }
  RenderOptions options;
  options.seed = 42;
  options.num_threads = 3;
  const std::vector<GrayImage> images = {stripes, Uniform(g, 128), Uniform(g, 255)};
  const std::vector<GrayImage> a = RenderSequence(g, images, options);
  options.num_threads = 1;
  const std::vector<GrayImage> b = RenderSequence(g, images, options);
  ASSERT_EQ(a.size(), 3u);
  for (std::size_t k = 0; k < a.size(); ++k) {
    EXPECT_EQ(a[k].pixels, b[k].pixels) << k;
    EXPECT_EQ(a[k].pixels, RenderImage(g, images[k], options, k).pixels) << k;
  }
  options.seed = 43;
  const GrayImage other = RenderImage(g, stripes, options, 0);
  EXPECT_NE(other.pixels, a[0].pixels);
  // Different frames of one sequence get different noise.
  const GrayImage frame1 = RenderImage(g, stripes, options, 1);
  EXPECT_NE(other.pixels, frame1.pixels);
}

TEST(StructuredLightRendererTest, SequenceRenderedInPartsEqualsTheWholeSequence) {
  const world::TriangleMesh plane = Square(5.0);
  StructuredLightRenderer renderer({{&plane, Translation(0.0, 0.0, 0.8)}});
  const ScanGeometry g = renderer.Prepare(TestPose());
  std::vector<GrayImage> images;
  for (int k = 0; k < 6; ++k) {
    GrayImage stripes(g.projector_width, g.projector_height);
    for (int r = 0; r < stripes.height; ++r) {
      for (int c = 0; c < stripes.width; ++c) stripes.at(c, r) = (c >> k) % 2 ? 255 : 0;
    }
    images.push_back(stripes);
  }
  for (double blur : {0.0, 0.8}) {
    RenderOptions options;
    options.seed = 5;
    options.projector_blur_sigma_px = blur;
    const std::vector<GrayImage> whole = RenderSequence(g, images, options);
    std::vector<GrayImage> part;
    for (std::size_t first : {0u, 4u}) {
      const std::vector<GrayImage> projected(images.begin() + first,
                                             images.begin() + std::min<std::size_t>(first + 4, 6));
      RenderSequence(g, projected, options, &part, first);
      ASSERT_EQ(part.size(), projected.size());
      for (std::size_t k = 0; k < part.size(); ++k) {
        EXPECT_EQ(part[k].pixels, whole[first + k].pixels) << first + k << " blur " << blur;
      }
    }
    // Without the offset the second part would repeat the first frames' noise.
    RenderSequence(g, {images[4]}, options, &part);
    EXPECT_NE(part[0].pixels, whole[4].pixels);
  }
}

TEST(StructuredLightRendererTest, NoiseHasTheConfiguredStatistics) {
  const world::TriangleMesh plane = Square(5.0);
  StructuredLightRenderer renderer({{&plane, Translation(0.0, 0.0, 0.8)}});
  const ScanGeometry g = renderer.Prepare(TestPose());
  RenderOptions clean = NoiseFree();
  clean.projector_brightness = 0.5;
  RenderOptions noisy = clean;
  noisy.read_noise_dn = 2.0;
  noisy.electrons_per_dn = 10.0;
  const GrayImage projected = Uniform(g, 255);
  const GrayImage reference = RenderImage(g, projected, clean);
  const GrayImage sample = RenderImage(g, projected, noisy);
  double sum = 0.0, sum2 = 0.0, expected_var = 0.0;
  int n = 0;
  for (std::size_t i = 0; i < g.size(); ++i) {
    if (g.illumination[i] != Illumination::kLit) continue;
    const double d = double(sample.pixels[i]) - double(reference.pixels[i]);
    sum += d;
    sum2 += d * d;
    expected_var += 4.0 + reference.pixels[i] / 10.0;
    ++n;
  }
  ASSERT_GT(n, 5000);
  const double mean = sum / n;
  const double var = sum2 / n - mean * mean;
  EXPECT_NEAR(mean, 0.0, 0.15);
  // Rounding both images adds about 2/12 DN^2.
  EXPECT_NEAR(var, expected_var / n + 1.0 / 6.0, 0.1 * expected_var / n);
}

TEST(StructuredLightRendererTest, StripePatternFollowsProjectorColumns) {
  const world::TriangleMesh plane = Square(5.0);
  StructuredLightRenderer renderer({{&plane, Translation(0.0, 0.0, 0.8)}});
  const ScanGeometry g = renderer.Prepare(TestPose());
  const int half = g.projector_width / 2;
  GrayImage left(g.projector_width, g.projector_height);
  for (int r = 0; r < left.height; ++r) {
    for (int c = 0; c < half; ++c) left.at(c, r) = 255;
  }
  RenderOptions options = NoiseFree();
  options.sampling = ProjectorSampling::kNearest;
  const GrayImage image = RenderImage(g, left, options);
  const GrayImage white = RenderImage(g, Uniform(g, 255), options);
  const GrayImage black = RenderImage(g, Uniform(g, 0), options);
  for (std::size_t i = 0; i < g.size(); ++i) {
    if (g.illumination[i] != Illumination::kLit) continue;
    const float u = g.projector_uv[i].x();
    if (u < half - 0.5f - 1e-3f) {
      EXPECT_EQ(image.pixels[i], white.pixels[i]);
    } else if (u > half - 0.5f + 1e-3f) {
      EXPECT_EQ(image.pixels[i], black.pixels[i]);
    }
  }
}

TEST(StructuredLightRendererTest, GrayCodeSequenceDecodesToTheProjectorCoordinates) {
  // Render a noisy Gray-code scan of a tilted plane, decode each pixel by comparing each
  // pattern with its inverse, and compare with the ground-truth projector pixel.
  const world::TriangleMesh plane = Square(5.0);
  Eigen::Isometry3d X_BasePlane = Translation(0.0, 0.0, 0.7);
  X_BasePlane.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitY()).toRotationMatrix() *
                         Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitX()).toRotationMatrix();
  StructuredLightRenderer renderer({{&plane, X_BasePlane}});
  const ScanGeometry g = renderer.Prepare(TestPose());
  const int column_bits = 7;  // 114 columns
  const int row_bits = 8;     // 143 rows
  std::vector<GrayImage> sequence;
  for (int axis = 0; axis < 2; ++axis) {
    for (int bit = (axis == 0 ? column_bits : row_bits) - 1; bit >= 0; --bit) {
      GrayImage pattern(g.projector_width, g.projector_height);
      GrayImage inverse(g.projector_width, g.projector_height);
      for (int r = 0; r < pattern.height; ++r) {
        for (int c = 0; c < pattern.width; ++c) {
          const int index = axis == 0 ? c : r;
          const bool on = ((index ^ (index >> 1)) >> bit) & 1;
          pattern.at(c, r) = on ? 255 : 0;
          inverse.at(c, r) = on ? 0 : 255;
        }
      }
      sequence.push_back(pattern);
      sequence.push_back(inverse);
    }
  }
  RenderOptions options;
  options.read_noise_dn = 2.0;
  options.seed = 11;
  const std::vector<GrayImage> images = RenderSequence(g, sequence, options);
  auto decode = [&](std::size_t i, int first_image, int bits) {
    int gray = 0;
    for (int b = 0; b < bits; ++b) {
      const int k = first_image + 2 * b;
      gray = (gray << 1) | (images[k].pixels[i] > images[k + 1].pixels[i] ? 1 : 0);
    }
    int value = 0;
    for (; gray != 0; gray >>= 1) value ^= gray;
    return value;
  };
  int checked = 0;
  for (std::size_t i = 0; i < g.size(); ++i) {
    if (g.illumination[i] != Illumination::kLit) continue;
    const float u = g.projector_uv[i].x();
    const float v = g.projector_uv[i].y();
    // Skip pixels within 0.1 projector pixel of a projector pixel border.
    const auto near_border = [](float w) { return std::abs(w - std::floor(w) - 0.5f) < 0.1f; };
    if (near_border(u) || near_border(v)) continue;
    ++checked;
    ASSERT_EQ(decode(i, 0, column_bits), static_cast<int>(std::lround(u))) << i;
    ASSERT_EQ(decode(i, 2 * column_bits, row_bits), static_cast<int>(std::lround(v))) << i;
  }
  EXPECT_GT(checked, static_cast<int>(g.size() / 3));
}

TEST(StructuredLightRendererTest, IrradianceFollowsCosineAndInverseSquare) {
  const world::TriangleMesh plane = Square(5.0);
  Eigen::Isometry3d X_BasePlane = Translation(0.0, 0.0, 1.1);
  X_BasePlane.linear() = Eigen::AngleAxisd(0.35, Eigen::Vector3d::UnitY()).toRotationMatrix();
  StructuredLightRenderer renderer({{&plane, X_BasePlane}});
  const ScanPose pose = TestPose();
  GeometryOptions options;
  options.reference_distance_m = 0.5;
  const ScanGeometry g = renderer.Prepare(pose, options);
  options.inverse_square_falloff = false;
  const ScanGeometry flat = renderer.Prepare(pose, options);
  const Eigen::Vector3d n_B = X_BasePlane.linear().col(2);
  const Eigen::Vector3d p_BP = pose.X_BaseProjector.translation();
  int checked = 0;
  for (std::size_t i = 0; i < g.size(); i += 7) {
    if (g.illumination[i] != Illumination::kLit) continue;
    const Eigen::Vector3d to_projector = p_BP - g.points_camera[i].cast<double>();
    const double r = to_projector.norm();
    const double cos_theta = std::abs(n_B.dot(to_projector / r));
    EXPECT_NEAR(flat.gain[i], 0.6 * cos_theta, 1e-5);
    EXPECT_NEAR(g.gain[i], 0.6 * cos_theta * 0.25 / (r * r), 1e-5);
    ++checked;
  }
  EXPECT_GT(checked, 100);
}

TEST(StructuredLightRendererTest, PerVertexAlbedoIsInterpolated) {
  world::TriangleMesh plane = Square(1.0);
  plane.vertex_albedo = {0.0f, 1.0f, 1.0f, 0.0f};  // Linear in x: (x + 1) / 2.
  StructuredLightRenderer renderer({{&plane, Translation(0.0, 0.0, 0.8)}});
  const ScanGeometry g = renderer.Prepare(TestPose());
  for (std::size_t i = 0; i < g.size(); ++i) {
    ASSERT_EQ(g.object_index[i], 0);
    EXPECT_NEAR(g.albedo[i], (g.points_camera[i].x() + 1.0f) / 2.0f, 1e-5f);
  }
}

TEST(StructuredLightRendererTest, MovedObjectIsSeenAtItsNewPose) {
  const world::TriangleMesh plane = Square(5.0);
  const world::TriangleMesh card = Square(0.05);
  StructuredLightRenderer renderer(
      {{&plane, Translation(0.0, 0.0, 0.8)}, {&card, Translation(0.0, 0.0, 0.6)}});
  EXPECT_EQ(renderer.num_objects(), 2u);
  EXPECT_EQ(renderer.num_triangles(), 4u);
  const ScanPose pose = TestPose();
  const std::size_t centre = std::size_t(63) * 160 + 80;
  ScanGeometry g = renderer.Prepare(pose);
  EXPECT_EQ(g.object_index[centre], 1);
  EXPECT_NEAR(g.depth_m[centre], 0.6, 1e-5);
  renderer.SetObjectPose(1, Translation(0.0, 0.0, 0.4));
  g = renderer.Prepare(pose);
  EXPECT_EQ(g.object_index[centre], 1);
  EXPECT_NEAR(g.depth_m[centre], 0.4, 1e-5);
  renderer.SetObjectPose(1, Translation(1.0, 0.0, 0.4));  // Out of view.
  g = renderer.Prepare(pose);
  EXPECT_EQ(g.object_index[centre], 0);
  EXPECT_NEAR(g.depth_m[centre], 0.8, 1e-5);
  renderer.SetObjects({{&card, Translation(0.0, 0.0, 0.5)}});
  g = renderer.Prepare(pose);
  EXPECT_EQ(g.object_index[centre], 0);
  EXPECT_NEAR(g.depth_m[centre], 0.5, 1e-5);
  EXPECT_EQ(g.object_index[0], -1);  // Corner pixel misses the card.
  EXPECT_TRUE(std::isnan(g.depth_m[0]));
  EXPECT_EQ(g.illumination[0], Illumination::kNoSurface);
}

TEST(StructuredLightRendererTest, SurfaceFacingAwayFromProjectorIsUnlit) {
  // A wall in the plane x = 0.05 m, between the camera (x = 0) and the projector (x = 0.1):
  // the camera sees one side, the projector only the other.
  const world::TriangleMesh wall = Square(5.0);
  Eigen::Isometry3d X_BaseWall = Translation(0.05, 0.0, 0.5);
  X_BaseWall.linear() = Eigen::AngleAxisd(M_PI / 2.0, Eigen::Vector3d::UnitY()).toRotationMatrix();
  StructuredLightRenderer renderer({{&wall, X_BaseWall}});
  const ScanGeometry g = renderer.Prepare(TestPose());
  int facing_away = 0;
  int seen = 0;
  for (std::size_t i = 0; i < g.size(); ++i) {
    if (g.object_index[i] == 0) ++seen;
    if (g.illumination[i] == Illumination::kFacingAway) ++facing_away;
    EXPECT_NE(g.illumination[i], Illumination::kLit) << i;
  }
  EXPECT_GT(seen, 1000);
  EXPECT_GT(facing_away, 500);
}

TEST(StructuredLightRendererTest, BlurKeepsFlatLightAndSoftensEdges) {
  const world::TriangleMesh plane = Square(5.0);
  StructuredLightRenderer renderer({{&plane, Translation(0.0, 0.0, 0.8)}});
  const ScanGeometry g = renderer.Prepare(TestPose());
  RenderOptions sharp = NoiseFree();
  RenderOptions blurred = sharp;
  blurred.projector_blur_sigma_px = 2.0;
  const GrayImage flat = Uniform(g, 200);
  EXPECT_EQ(RenderImage(g, flat, sharp).pixels, RenderImage(g, flat, blurred).pixels);
  GrayImage step(g.projector_width, g.projector_height);
  for (int r = 0; r < step.height; ++r) {
    for (int c = g.projector_width / 2; c < g.projector_width; ++c) step.at(c, r) = 255;
  }
  const GrayImage white = RenderImage(g, Uniform(g, 255), sharp);
  const GrayImage black = RenderImage(g, Uniform(g, 0), sharp);
  auto count_between = [&](const GrayImage& image) {
    int n = 0;
    for (std::size_t i = 0; i < g.size(); ++i) {
      if (g.illumination[i] != Illumination::kLit) continue;
      if (image.pixels[i] > black.pixels[i] + 5 && image.pixels[i] + 5 < white.pixels[i]) ++n;
    }
    return n;
  };
  EXPECT_GT(count_between(RenderImage(g, step, blurred)),
            3 * count_between(RenderImage(g, step, sharp)));
  // A sequence longer than the blur's frame chunk gives each frame's own image and noise.
  blurred.read_noise_dn = 1.5;
  const std::vector<GrayImage> sequence = {step, flat, step, Uniform(g, 0), step, flat, step};
  const std::vector<GrayImage> images = RenderSequence(g, sequence, blurred);
  ASSERT_EQ(images.size(), sequence.size());
  for (std::size_t k = 0; k < sequence.size(); ++k) {
    EXPECT_EQ(images[k].pixels, RenderImage(g, sequence[k], blurred, k).pixels) << k;
  }
}

TEST(StructuredLightRendererTest, BufferReusingOverloadsGiveTheSameResult) {
  const world::TriangleMesh plane = Square(5.0);
  const world::TriangleMesh card = Square(0.05);
  StructuredLightRenderer renderer(
      {{&plane, Translation(0.0, 0.0, 0.8)}, {&card, Translation(0.0, 0.0, 0.6)}});
  const ScanGeometry expected = renderer.Prepare(TestPose());
  // Start from a geometry of another scan (other camera size) to check it is fully reset.
  ScanGeometry g =
      renderer.Prepare(ScanPose{PinholeCamera(40, 30, 50.0, 50.0, 20.0, 15.0),
                                Eigen::Isometry3d::Identity(), TestProjector(), ProjectorPose()});
  renderer.Prepare(TestPose(), {}, &g);
  EXPECT_EQ(g.width, expected.width);
  EXPECT_EQ(g.height, expected.height);
  EXPECT_EQ(g.object_index, expected.object_index);
  EXPECT_EQ(g.illumination, expected.illumination);
  EXPECT_EQ(g.gain, expected.gain);
  for (std::size_t i = 0; i < g.size(); ++i) {
    ASSERT_EQ(std::isnan(g.depth_m[i]), std::isnan(expected.depth_m[i]));
    if (!std::isnan(g.depth_m[i])) {
      ASSERT_EQ(g.depth_m[i], expected.depth_m[i]);
    }
  }
  const std::vector<GrayImage> projected = {Uniform(g, 255), Uniform(g, 60), Uniform(g, 0)};
  RenderOptions options;
  options.seed = 3;
  std::vector<GrayImage> images(5, GrayImage(7, 7));  // Wrong count and sizes.
  RenderSequence(g, projected, options, &images);
  const std::vector<GrayImage> fresh = RenderSequence(g, projected, options);
  ASSERT_EQ(images.size(), 3u);
  for (std::size_t k = 0; k < 3; ++k) EXPECT_EQ(images[k].pixels, fresh[k].pixels);
  RenderSequence(g, projected, options, &images);  // Same sizes: buffers reused.
  for (std::size_t k = 0; k < 3; ++k) EXPECT_EQ(images[k].pixels, fresh[k].pixels);
}

TEST(StructuredLightRendererTest, GroundTruthCloudIsOrganised) {
  const world::TriangleMesh plane = Square(5.0);
  StructuredLightRenderer renderer({{&plane, Translation(0.0, 0.0, 0.8)}});
  const ScanGeometry g = renderer.Prepare(TestPose());
  const geometry::PointCloud cloud = GroundTruthCloud(g);
  EXPECT_TRUE(cloud.is_organized());
  EXPECT_EQ(cloud.width, 160u);
  EXPECT_EQ(cloud.height, 128u);
  ASSERT_EQ(cloud.size(), g.size());
  EXPECT_TRUE(cloud.has_normals());
  EXPECT_EQ(cloud.points[1000], g.points_camera[1000]);
}

TEST(StructuredLightRendererTest, BadInputIsRejectedAndChangesNothing) {
  const world::TriangleMesh plane = Square(5.0);
  StructuredLightRenderer renderer({{&plane, Translation(0.0, 0.0, 0.8)}});
  world::TriangleMesh broken = Square(1.0);
  broken.triangles.push_back({0, 1, 9});
  EXPECT_THROW(renderer.SetObjects({{&plane, Eigen::Isometry3d::Identity()}, {&broken, {}}}),
               std::invalid_argument);
  EXPECT_THROW(renderer.SetObjects({{nullptr, Eigen::Isometry3d::Identity()}}),
               std::invalid_argument);
  world::TriangleMesh bad_albedo = Square(1.0);
  bad_albedo.vertex_albedo = {0.5f};
  EXPECT_THROW(renderer.SetObjects({{&bad_albedo, Eigen::Isometry3d::Identity()}}),
               std::invalid_argument);
  Eigen::Isometry3d scaled = Eigen::Isometry3d::Identity();
  scaled.linear() *= 2.0;
  EXPECT_THROW(renderer.SetObjects({{&plane, scaled}}), std::invalid_argument);
  EXPECT_THROW(renderer.SetObjectPose(1, Eigen::Isometry3d::Identity()), std::out_of_range);
  EXPECT_EQ(renderer.num_objects(), 1u);
  const ScanGeometry g = renderer.Prepare(TestPose());
  EXPECT_NEAR(g.depth_m[5000], 0.8, 1e-5);  // Scene unchanged.

  EXPECT_THROW(RenderImage(g, GrayImage(10, 10), NoiseFree()), std::invalid_argument);
  RenderOptions negative = NoiseFree();
  negative.exposure = -1.0;
  EXPECT_THROW(RenderImage(g, Uniform(g, 0), negative), std::invalid_argument);
  GeometryOptions geometry_options;
  geometry_options.reference_distance_m = 0.0;
  EXPECT_THROW(renderer.Prepare(TestPose(), geometry_options), std::invalid_argument);
  EXPECT_THROW(RenderImage(ScanGeometry{}, Uniform(g, 0), NoiseFree()), std::invalid_argument);
}

// A square nearer than a tilted back plane: two depths, edges and empty pixels.
struct DepthScene {
  world::TriangleMesh back = Square(0.35);
  world::TriangleMesh front = Square(0.06);
  Eigen::Isometry3d X_BaseBack = Translation(0.03, -0.02, 0.9);
  Eigen::Isometry3d X_BaseFront = Translation(-0.02, 0.01, 0.6);
  Eigen::Isometry3d X_BaseCamera = Translation(0.01, 0.02, -0.05);
  DepthScene() {
    X_BaseBack.linear() = (Eigen::AngleAxisd(0.35, Eigen::Vector3d::UnitY()) *
                           Eigen::AngleAxisd(-0.2, Eigen::Vector3d::UnitX()))
                              .toRotationMatrix();
    X_BaseCamera.linear() = Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  }
  std::vector<SceneObject> objects() const { return {{&back, X_BaseBack}, {&front, X_BaseFront}}; }
};

TEST(StructuredLightRendererTest, RenderDepthEqualsPrepareDepthBitForBit) {
  const DepthScene scene;
  StructuredLightRenderer renderer(scene.objects());
  const ScanPose pose{TestCamera(), scene.X_BaseCamera, TestProjector(),
                      scene.X_BaseCamera * ProjectorPose()};
  const ScanGeometry g = renderer.Prepare(pose);
  for (int threads : {1, 3, 0}) {
    const DepthImage depth = renderer.RenderDepth(TestCamera(), scene.X_BaseCamera, threads);
    ASSERT_EQ(depth.width, 160);
    ASSERT_EQ(depth.height, 128);
    ASSERT_EQ(depth.depth_m.size(), g.size());
    std::size_t hits = 0, empty = 0;
    for (std::size_t i = 0; i < g.size(); ++i) {
      if (std::isnan(g.depth_m[i])) {
        ASSERT_TRUE(std::isnan(depth.depth_m[i])) << i;
        ++empty;
      } else {
        ASSERT_EQ(depth.depth_m[i], g.depth_m[i]) << i;
        ++hits;
      }
    }
    // The scene fills part of the image only: both kinds of pixel occur.
    EXPECT_GT(hits, g.size() / 4);
    EXPECT_GT(empty, 100u);
  }
}

TEST(StructuredLightRendererTest, RenderDepthIsTheNearestSurfaceAlongEachDistortedRay) {
  const DepthScene scene;
  StructuredLightRenderer renderer(scene.objects());
  const PinholeCamera camera = TestCamera();
  const DepthImage depth = renderer.RenderDepth(camera, scene.X_BaseCamera);
  // Both squares as planes n . p = c in the camera frame, with their extents.
  struct Plane {
    Eigen::Isometry3d X_CameraPlane;
    double half_m;
  };
  const Plane planes[] = {{scene.X_BaseCamera.inverse() * scene.X_BaseBack, 0.35},
                          {scene.X_BaseCamera.inverse() * scene.X_BaseFront, 0.06}};
  std::size_t front = 0, back = 0, none = 0;
  for (int y = 0; y < depth.height; ++y) {
    for (int x = 0; x < depth.width; ++x) {
      // The ray through the pixel centre, with the lens distortion.
      const Eigen::Vector3d ray = camera.Unproject(Eigen::Vector2d(x, y));
      double expected = std::numeric_limits<double>::infinity();
      bool near_edge = false;
      for (const Plane& plane : planes) {
        const Eigen::Vector3d n_C = plane.X_CameraPlane.linear().col(2);
        const double t = n_C.dot(plane.X_CameraPlane.translation()) / n_C.dot(ray);
        const Eigen::Vector3d p_Plane = plane.X_CameraPlane.inverse() * (t * ray);
        const double inside = plane.half_m - p_Plane.head<2>().cwiseAbs().maxCoeff();
        if (std::abs(inside) < 2e-3) near_edge = true;
        if (inside > 0.0 && t > 0.0) expected = std::min(expected, t * ray.z());
      }
      if (near_edge) continue;  // Which side a pixel's ray falls on is a matter of rounding.
      const float d = depth.at(x, y);
      if (std::isinf(expected)) {
        EXPECT_TRUE(std::isnan(d)) << x << "," << y;
        ++none;
      } else {
        EXPECT_NEAR(d, expected, 2e-5 * expected) << x << "," << y;
        ++(expected < 0.7 ? front : back);
      }
    }
  }
  EXPECT_GT(front, 500u);
  EXPECT_GT(back, 2000u);
  EXPECT_GT(none, 100u);
}

TEST(StructuredLightRendererTest, RenderDepthRejectsBadInput) {
  const world::TriangleMesh plane = Square(5.0);
  StructuredLightRenderer renderer({{&plane, Translation(0.0, 0.0, 0.8)}});
  Eigen::Isometry3d nan_pose = Eigen::Isometry3d::Identity();
  nan_pose.translation().x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(renderer.RenderDepth(TestCamera(), nan_pose), std::invalid_argument);
  Eigen::Isometry3d scaled = Eigen::Isometry3d::Identity();
  scaled.linear() *= 1.5;
  EXPECT_THROW(renderer.RenderDepth(TestCamera(), scaled), std::invalid_argument);
  EXPECT_THROW(renderer.RenderDepth(TestCamera(), Eigen::Isometry3d::Identity(), -1),
               std::invalid_argument);
  const DepthImage depth = renderer.RenderDepth(TestCamera(), Eigen::Isometry3d::Identity());
  EXPECT_NEAR(depth.at(80, 63), 0.8, 1e-6);
}

}  // namespace
}  // namespace picking::simulator
