#include "services/scanner/core/scan_pipeline.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

#include "libs/errors/errors.h"
#include "services/scanner/core/sim_backends.h"
#include "services/scanner/core/synthetic_capture.h"

namespace picking::scanner {
namespace {

// A world of one plane { p_Base : n . p = d } rendered analytically.
class PlaneRenderer final : public PatternRenderer {
 public:
  PlaneRenderer(Eigen::Vector3d n_Base, double d_m) : n_Base_(n_Base.normalized()), d_m_(d_m) {}

  std::vector<GrayImage> Render(const PatternRenderRequest& request) override {
    const Eigen::Isometry3d X_CameraProjector =
        request.X_BaseCamera.inverse() * request.X_BaseProjector;
    const ScannerRig rig{request.camera, request.projector, X_CameraProjector};
    const PatternSequence sequence(request.projector.width(), request.projector.height(),
                                   request.column_bits, request.row_bits);
    SyntheticPlane plane;
    plane.normal = request.X_BaseCamera.linear().transpose() * n_Base_;
    plane.offset_m = d_m_ - n_Base_.dot(request.X_BaseCamera.translation());
    SyntheticScene scene;
    scene.planes.push_back(plane);
    SyntheticCaptureOptions options;
    options.noise_sigma = 1.5;
    options.blur_sigma_px = 0.5;
    options.seed = static_cast<std::uint32_t>(request.seed);
    const SyntheticCapture capture = RenderSyntheticCapture(rig, sequence, scene, options);
    std::vector<GrayImage> images;
    for (const PatternImage& p : request.patterns) {
      int index = PatternSequence::kWhiteIndex;
      if (p.kind == PatternImage::Kind::kBlack) index = PatternSequence::kBlackIndex;
      if (p.kind == PatternImage::Kind::kColumnBit)
        index = sequence.ColumnImageIndex(p.bit, p.inverse);
      if (p.kind == PatternImage::Kind::kRowBit) index = sequence.RowImageIndex(p.bit, p.inverse);
      GrayImage image;
      image.width = capture.width;
      image.height = capture.height;
      image.pixels = capture.images[index];
      images.push_back(std::move(image));
    }
    ++renders;
    return images;
  }
  int renders = 0;

 private:
  Eigen::Vector3d n_Base_;
  double d_m_;
};

// A sensor looking down at a table plane z = kTableZ of the base frame from about 1 m (in the
// middle of a 1 cm voxel layer).
constexpr double kTableZ = 0.005;

struct Fixture {
  Fixture() : rig(MakeExampleRig(320, 256)) {
    X_ToolCamera.translation() = Eigen::Vector3d(0.0, 0.06, 0.09);
    renderer = std::make_shared<PlaneRenderer>(Eigen::Vector3d::UnitZ(), kTableZ);
    link = std::make_shared<SimSensorLink>();
    projector = std::make_unique<SimProjector>(link, 912, 1140);
    camera = std::make_unique<SimCamera>(
        link, renderer,
        SimSensorModel{rig.camera, rig.projector, rig.X_CameraProjector, X_ToolCamera});
    devices.camera = camera.get();
    devices.projector = projector.get();
    devices.before_capture = [this](const std::optional<Eigen::Isometry3d>& X) {
      link->SetToolPose(X);
    };
  }
  ScanPipeline Pipeline(bool with_hand_eye = true) {
    return ScanPipeline(ScanCalibration{rig.camera, rig.projector, rig.X_CameraProjector,
                                        with_hand_eye ? std::optional(X_ToolCamera) : std::nullopt},
                        PatternSequence());
  }
  static Eigen::Isometry3d ToolAbove(double x, double y, double z, double tilt_rad) {
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = (Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()) *
                  Eigen::AngleAxisd(tilt_rad, Eigen::Vector3d::UnitY()))
                     .toRotationMatrix();
    X.translation() = Eigen::Vector3d(x, y, z);
    return X;
  }

  ScannerRig rig;
  Eigen::Isometry3d X_ToolCamera = Eigen::Isometry3d::Identity();
  std::shared_ptr<PlaneRenderer> renderer;
  std::shared_ptr<SimSensorLink> link;
  std::unique_ptr<SimProjector> projector;
  std::unique_ptr<SimCamera> camera;
  ScanDevices devices;
};

double MedianAbsZ(const geometry::PointCloud& cloud) {
  std::vector<double> z;
  for (const auto& p : cloud.points) {
    if (std::isfinite(p.z())) z.push_back(std::abs(p.z() - kTableZ));
  }
  std::nth_element(z.begin(), z.begin() + z.size() / 2, z.end());
  return z[z.size() / 2];
}

TEST(ScanPipelineTest, TwoViewsOfATableMergeOntoThePlaneInTheBaseFrame) {
  Fixture f;
  ScanPipeline pipeline = f.Pipeline();
  std::vector<ScanViewSpec> views{{Fixture::ToolAbove(0.6, 0.0, 1.1, 0.0)},
                                  {Fixture::ToolAbove(0.7, 0.05, 1.05, 0.15)}};
  ScanOptions options;
  std::vector<std::string> stages;
  const ScanResult result = pipeline.Run(f.devices, views, options, [&](int i, int n, ScanStage s) {
    EXPECT_EQ(n, 2);
    stages.push_back(std::to_string(i) + ScanStageName(s));
  });
  EXPECT_EQ(stages, (std::vector<std::string>{"0capture", "0decode", "0triangulate", "1capture",
                                              "1decode", "1triangulate", "1merge"}));
  EXPECT_EQ(f.renderer->renders, 2);
  EXPECT_EQ(result.cloud.frame_id, "base");
  EXPECT_EQ(result.cloud.width, 320u);
  EXPECT_EQ(result.cloud.height, 512u);  // Two organised views stacked.
  ASSERT_EQ(result.views.size(), 2u);
  for (const auto& v : result.views) {
    EXPECT_GT(v.valid_fraction, 0.5);
    EXPECT_GT(v.num_points, 30000u);
  }
  EXPECT_EQ(result.num_points, result.views[0].num_points + result.views[1].num_points);
  EXPECT_TRUE(result.cloud.has_normals());
  EXPECT_TRUE(result.cloud.has_intensities());
  // Every view lands on the table; quantisation by projector columns is a few mm at 1 m.
  EXPECT_LT(MedianAbsZ(result.cloud), 3e-3);
  double normal_z = 0;
  std::size_t normals = 0;
  for (const auto& n : result.cloud.normals) {
    if (std::isfinite(n.z())) normal_z += n.z(), ++normals;
  }
  // Upwards, towards the sensor (noisy where depth steps by one projector column).
  EXPECT_GT(normal_z / normals, 0.9);
  EXPECT_TRUE(result.views[1].X_FrameCamera.isApprox(views[1].X_BaseTool.value() * f.X_ToolCamera));
  EXPECT_GE(result.processing_time_s, 0.0);
  EXPECT_GE(result.capture_time_s, 0.0);
}

TEST(ScanPipelineTest, VoxelMergeAndCrop) {
  Fixture f;
  ScanPipeline pipeline = f.Pipeline();
  std::vector<ScanViewSpec> views{{Fixture::ToolAbove(0.6, 0.0, 1.1, 0.0)},
                                  {Fixture::ToolAbove(0.6, 0.0, 1.1, 0.0)}};
  ScanOptions options;
  options.merge.voxel_m = 0.01;
  options.crop =
      std::make_pair(Eigen::Vector3d(0.5, -0.05, -0.02), Eigen::Vector3d(0.7, 0.05, 0.02));
  options.with_intensities = false;
  const ScanResult result = pipeline.Run(f.devices, views, options);
  EXPECT_EQ(result.cloud.height, 1u);
  EXPECT_FALSE(result.cloud.has_intensities());
  // A 0.2 x 0.1 m window at 1 cm: about 20 x 10 voxels (edges may add a row or column).
  EXPECT_GE(result.num_points, 180u);
  EXPECT_LE(result.num_points, 240u);
  for (const auto& p : result.cloud.points) {
    EXPECT_GE(p.x(), 0.5f);
    EXPECT_LE(p.x(), 0.7f);
    EXPECT_NEAR(p.z(), kTableZ, 3e-3);
  }
}

TEST(ScanPipelineTest, CameraFrameScanNeedsNoPoseButOneView) {
  Fixture f;
  ScanPipeline pipeline = f.Pipeline(/*with_hand_eye=*/false);
  ScanOptions options;
  options.frame = ScanFrame::kCamera;
  options.with_normals = false;
  f.link->SetToolPose(Fixture::ToolAbove(0.6, 0.0, 1.1, 0.0));
  f.devices.before_capture = nullptr;
  const ScanResult result = pipeline.Run(f.devices, {}, options);
  EXPECT_EQ(result.cloud.frame_id, "camera");
  EXPECT_FALSE(result.cloud.has_normals());
  EXPECT_GT(result.num_points, 30000u);
  EXPECT_THROW(pipeline.Run(f.devices, {{}, {}}, options), std::invalid_argument);
}

TEST(ScanPipelineTest, MissingCalibrationPoseAndDeviceFailuresAreReported) {
  Fixture f;
  ScanPipeline no_hand_eye = f.Pipeline(false);
  EXPECT_THROW(no_hand_eye.Run(f.devices, {{Fixture::ToolAbove(0.6, 0, 1.1, 0)}}, {}),
               PreconditionError);
  ScanPipeline pipeline = f.Pipeline();
  EXPECT_THROW(pipeline.Run(f.devices, {{}}, {}), PreconditionError);  // No X_BaseTool.
  // Without the projector the simulated camera gets no trigger.
  ScanDevices no_projector = f.devices;
  no_projector.projector = nullptr;
  EXPECT_THROW(pipeline.Run(no_projector, {{Fixture::ToolAbove(0.6, 0, 1.1, 0)}}, {}),
               TimeoutError);
  // A calibration for another camera size.
  const ScannerRig other = MakeExampleRig(640, 512);
  ScanPipeline mismatched(
      ScanCalibration{other.camera, other.projector, other.X_CameraProjector, f.X_ToolCamera},
      PatternSequence());
  EXPECT_THROW(mismatched.Run(f.devices, {{Fixture::ToolAbove(0.6, 0, 1.1, 0)}}, {}),
               PreconditionError);
  // Patterns for another projector.
  EXPECT_THROW(ScanPipeline(ScanCalibration{f.rig.camera, f.rig.projector, f.rig.X_CameraProjector},
                            PatternSequence(800, 600)),
               std::invalid_argument);
}

}  // namespace
}  // namespace picking::scanner
