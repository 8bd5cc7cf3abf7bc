#include "services/scanner/core/calibration.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "services/scanner/core/patterns.h"
#include "services/scanner/core/replay_camera.h"

namespace picking::scanner {
namespace {

using Eigen::Isometry3d;
using Eigen::Vector2d;
using Eigen::Vector3d;

constexpr double kPi = 3.14159265358979323846;

std::string CalibrationDataDir() { return std::string(PICKING_TEST_DATA_DIR) + "/calibration"; }

std::vector<ChessboardView> LoadRealViews() {
  std::vector<ChessboardView> views;
  for (int i : {1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14}) {
    char name[32];
    std::snprintf(name, sizeof(name), "left%02d.jpg", i);
    views.push_back({name, ReadGrayImage(CalibrationDataDir() + "/" + name)});
  }
  return views;
}

// --- Camera calibration on OpenCV's real chessboard images -------------------------------

TEST(CameraCalibrationTest, RealImagesCalibrateBelowHalfPixelRms) {
  const std::vector<ChessboardView> views = LoadRealViews();
  CameraCalibrationOptions options;
  options.board = {9, 6, 0.025};
  const CameraCalibrationResult result = CalibrateCamera(views, options);
  EXPECT_LT(result.rms_px, 0.5);
  EXPECT_GT(result.rms_px, 0.0);
  ASSERT_EQ(result.used_views.size(), views.size());
  ASSERT_EQ(result.per_view_rms_px.size(), views.size());
  ASSERT_EQ(result.X_CameraBoard.size(), views.size());
  for (double e : result.per_view_rms_px) EXPECT_LT(e, 2.0);
  EXPECT_EQ(result.intrinsics.width, 640u);
  EXPECT_EQ(result.intrinsics.height, 480u);
  // A 640 x 480 webcam: focal length of the order of the image width, centre near the middle.
  EXPECT_GT(result.intrinsics.fx, 400.0);
  EXPECT_LT(result.intrinsics.fx, 800.0);
  EXPECT_NEAR(result.intrinsics.fx / result.intrinsics.fy, 1.0, 0.02);
  EXPECT_NEAR(result.intrinsics.cx, 320.0, 40.0);
  EXPECT_NEAR(result.intrinsics.cy, 240.0, 40.0);
  // Boards are in front of the camera, some decimetres away.
  for (const Isometry3d& X : result.X_CameraBoard) {
    EXPECT_GT(X.translation().z(), 0.1);
    EXPECT_LT(X.translation().z(), 2.0);
  }
}

TEST(CameraCalibrationTest, ImageWithoutBoardIsNamed) {
  std::vector<ChessboardView> views = LoadRealViews();
  views.insert(views.begin() + 2, ChessboardView{"blank.png", GrayImage(640, 480, 128)});
  CameraCalibrationOptions options;
  try {
    CalibrateCamera(views, options);
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("blank.png"), std::string::npos) << e.what();
  }
  options.skip_views_without_board = true;
  const CameraCalibrationResult result = CalibrateCamera(views, options);
  ASSERT_EQ(result.skipped_views.size(), 1u);
  EXPECT_EQ(result.skipped_views[0], "blank.png");
  EXPECT_EQ(result.used_views.size(), views.size() - 1);
}

TEST(CameraCalibrationTest, TooFewViewsIsAnError) {
  std::vector<ChessboardView> views = LoadRealViews();
  views.resize(2);
  EXPECT_THROW(CalibrateCamera(views, {}), std::invalid_argument);
  // Three views with a board among four, the others skipped: still too few when min_views=4.
  views = LoadRealViews();
  views.resize(3);
  CameraCalibrationOptions options;
  options.min_views = 4;
  EXPECT_THROW(CalibrateCamera(views, options), std::invalid_argument);
}

TEST(CameraCalibrationTest, MixedImageSizesAreRejected) {
  std::vector<ChessboardView> views = LoadRealViews();
  views.push_back({"small.png", GrayImage(320, 240, 0)});
  try {
    CalibrateCamera(views, {});
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("small.png"), std::string::npos) << e.what();
  }
}

// --- Simulated structured-light captures ------------------------------------------------

// Undistorts normalised coordinates by fixed-point iteration (small distortion only).
Vector2d Undistort(const CameraIntrinsics& K, const Vector2d& xy_distorted) {
  Vector2d xy = xy_distorted;
  for (int i = 0; i < 30; ++i) {
    const double r2 = xy.squaredNorm();
    const double k1 = K.distortion[0], k2 = K.distortion[1], p1 = K.distortion[2],
                 p2 = K.distortion[3], k3 = K.distortion[4];
    const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
    const double dx = 2.0 * p1 * xy.x() * xy.y() + p2 * (r2 + 2.0 * xy.x() * xy.x());
    const double dy = p1 * (r2 + 2.0 * xy.y() * xy.y()) + 2.0 * p2 * xy.x() * xy.y();
    xy = Vector2d((xy_distorted.x() - dx) / radial, (xy_distorted.y() - dy) / radial);
  }
  return xy;
}

// A pinhole camera and a pinhole projector looking at a planar chessboard printed on white
// paper; renders the white, black and Gray-code images the camera records.
class StructuredLightSimulator {
 public:
  StructuredLightSimulator(const CameraIntrinsics& camera, const CameraIntrinsics& projector,
                           const Isometry3d& X_CameraProjector, const ChessboardSpec& board,
                           const ProjectorSpec& spec, std::uint32_t seed)
      : camera_(camera),
        projector_(projector),
        X_ProjectorCamera_(X_CameraProjector.inverse()),
        board_(board),
        spec_(spec),
        rng_(seed) {
    rays_.resize(static_cast<std::size_t>(camera.width) * camera.height);
    for (std::uint32_t v = 0; v < camera.height; ++v) {
      for (std::uint32_t u = 0; u < camera.width; ++u) {
        const Vector2d xy_d((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy);
        const Vector2d xy = Undistort(camera, xy_d);
        rays_[static_cast<std::size_t>(v) * camera.width + u] = Vector3d(xy.x(), xy.y(), 1.0);
      }
    }
    std::normal_distribution<float> normal(0.0f, 1.0f);
    noise_.resize(1 << 16);
    for (float& n : noise_) n = normal(rng_);
  }

  std::vector<GrayImage> Render(const Isometry3d& X_CameraBoard) {
    const std::size_t n = rays_.size();
    std::vector<float> albedo(n, 0.0f);
    std::vector<std::int32_t> column(n, -1), row(n, -1);
    const Vector3d normal = X_CameraBoard.linear().col(2);
    const Vector3d origin = X_CameraBoard.translation();
    const double s = board_.square_size_m;
    const int nx = board_.inner_corners_x, ny = board_.inner_corners_y;
    for (std::size_t i = 0; i < n; ++i) {
      const Vector3d& ray = rays_[i];
      const double denominator = normal.dot(ray);
      if (std::abs(denominator) < 1e-9) continue;
      const double lambda = normal.dot(origin) / denominator;
      if (lambda <= 0.0) continue;
      const Vector3d p_Camera = lambda * ray;
      const Vector3d p_Board = X_CameraBoard.inverse(Eigen::Isometry) * p_Camera;
      const double bx = p_Board.x() / s, by = p_Board.y() / s;
      float a = 0.35f;  // grey backing board
      if (bx >= -2.0 && bx <= nx + 1.0 && by >= -2.0 && by <= ny + 1.0) a = 0.9f;  // paper
      if (bx >= -1.0 && bx <= nx && by >= -1.0 && by <= ny) {
        const int ix = static_cast<int>(std::floor(bx)), iy = static_cast<int>(std::floor(by));
        a = ((ix + iy) % 2 == 0) ? 0.15f : 0.9f;
      }
      albedo[i] = a;
      const Vector3d p_Projector = X_ProjectorCamera_ * p_Camera;
      if (p_Projector.z() <= 0.0) continue;
      const Vector2d uv = projector_.Project(p_Projector);
      const int c = static_cast<int>(std::floor(uv.x() + 0.5));
      const int r = static_cast<int>(std::floor(uv.y() + 0.5));
      if (c < 0 || r < 0 || c >= static_cast<int>(spec_.width) ||
          r >= static_cast<int>(spec_.height)) {
        continue;
      }
      column[i] = c;
      row[i] = r;
    }
    std::vector<GrayImage> images;
    for (int k = 0; k < spec_.image_count(); ++k) {
      GrayImage image(camera_.width, camera_.height);
      std::vector<float> intensity(n);
      for (std::size_t i = 0; i < n; ++i) {
        bool lit = false;
        if (column[i] >= 0)
          lit = IsLit(k, static_cast<std::uint32_t>(column[i]), static_cast<std::uint32_t>(row[i]));
        intensity[i] = 255.0f * albedo[i] * (kAmbient + (lit ? kGain : 0.0f));
      }
      Blur(intensity, camera_.width, camera_.height);
      for (std::size_t i = 0; i < n; ++i) {
        state_ = state_ * 6364136223846793005ull + 1442695040888963407ull;
        const float noisy = intensity[i] + kNoise * noise_[(state_ >> 33) & 0xFFFF];
        image.pixels[i] = static_cast<std::uint8_t>(std::clamp(std::lround(noisy), 0l, 255l));
      }
      images.push_back(std::move(image));
    }
    return images;
  }

 private:
  static constexpr float kAmbient = 0.08f;
  static constexpr float kGain = 0.85f;
  static constexpr float kNoise = 1.5f;

  bool IsLit(int image, std::uint32_t c, std::uint32_t r) const {
    if (image == 0) return true;
    if (image == 1) return false;
    const int bit_image = image - 2;
    const int pair = bit_image / 2;
    const bool inverse = bit_image % 2 == 1;
    bool bit;
    if (pair < spec_.column_bits) {
      bit = (GrayEncode(c) >> (spec_.column_bits - 1 - pair)) & 1u;
    } else {
      const int b = pair - spec_.column_bits;
      bit = (GrayEncode(r) >> (spec_.row_bits - 1 - b)) & 1u;
    }
    return bit != inverse;
  }

  // Separable [1 2 1] / 4 blur: a slightly defocused lens.
  static void Blur(std::vector<float>& image, std::uint32_t w, std::uint32_t h) {
    std::vector<float> tmp(image.size());
    for (std::uint32_t y = 0; y < h; ++y) {
      for (std::uint32_t x = 0; x < w; ++x) {
        const std::size_t i = static_cast<std::size_t>(y) * w + x;
        const float left = image[x > 0 ? i - 1 : i], right = image[x + 1 < w ? i + 1 : i];
        tmp[i] = 0.25f * left + 0.5f * image[i] + 0.25f * right;
      }
    }
    for (std::uint32_t y = 0; y < h; ++y) {
      for (std::uint32_t x = 0; x < w; ++x) {
        const std::size_t i = static_cast<std::size_t>(y) * w + x;
        const float up = tmp[y > 0 ? i - w : i], down = tmp[y + 1 < h ? i + w : i];
        image[i] = 0.25f * up + 0.5f * tmp[i] + 0.25f * down;
      }
    }
  }

  CameraIntrinsics camera_;
  CameraIntrinsics projector_;
  Isometry3d X_ProjectorCamera_;
  ChessboardSpec board_;
  ProjectorSpec spec_;
  std::mt19937 rng_;
  std::vector<Vector3d> rays_;
  std::vector<float> noise_;
  std::uint64_t state_ = 12345;
};

CameraIntrinsics TrueCamera() {
  CameraIntrinsics K;
  K.width = 1280;
  K.height = 1024;
  K.fx = 1450.0;
  K.fy = 1452.0;
  K.cx = 646.0;
  K.cy = 508.0;
  K.distortion = {-0.08, 0.05, 0.0, 0.0, 0.0};
  return K;
}

CameraIntrinsics TrueProjector() {
  CameraIntrinsics K;
  K.width = 912;
  K.height = 1140;
  K.fx = 1320.0;
  K.fy = 1335.0;
  K.cx = 452.0;
  K.cy = 760.0;
  K.distortion = {0.03, 0.0, 0.0, 0.0, 0.0};
  return K;
}

// Projector 12 cm to the right of the camera, turned so that its image centre lands on the
// camera's optical axis 0.75 m away.
Isometry3d TrueCameraProjector(const CameraIntrinsics& projector) {
  const Vector3d p_CameraProjector(0.12, 0.01, 0.0);
  const Vector3d direction = (Vector3d(0.0, 0.0, 0.75) - p_CameraProjector).normalized();
  // Rotation taking the projector's z axis onto `direction` with x kept near the camera's x.
  Eigen::Matrix3d R_look;
  const Vector3d z = direction;
  const Vector3d x = Vector3d::UnitY().cross(z).normalized();
  R_look.col(0) = x;
  R_look.col(1) = z.cross(x);
  R_look.col(2) = z;
  const Vector3d centre_ray((projector.width / 2.0 - projector.cx) / projector.fx,
                            (projector.height / 2.0 - projector.cy) / projector.fy, 1.0);
  const Eigen::Matrix3d R_centre =
      Eigen::Quaterniond::FromTwoVectors(centre_ray.normalized(), Vector3d::UnitZ())
          .toRotationMatrix();
  Isometry3d X = Isometry3d::Identity();
  X.linear() = R_look * R_centre;
  X.translation() = p_CameraProjector;
  return X;
}

bool AllCornersVisible(const ChessboardSpec& board, const Isometry3d& X_CameraBoard,
                       const CameraIntrinsics& camera, const CameraIntrinsics& projector,
                       const Isometry3d& X_CameraProjector) {
  const double s = board.square_size_m;
  const Isometry3d X_ProjectorBoard = X_CameraProjector.inverse() * X_CameraBoard;
  for (double bx : {-2.5 * s, (board.inner_corners_x + 1.5) * s}) {
    for (double by : {-2.5 * s, (board.inner_corners_y + 1.5) * s}) {
      const Vector3d p_Board(bx, by, 0.0);
      for (const auto& [X, K] :
           {std::make_pair(X_CameraBoard, camera), std::make_pair(X_ProjectorBoard, projector)}) {
        const Vector3d p = X * p_Board;
        if (p.z() <= 0.0) return false;
        const Vector2d uv = K.Project(p);
        if (uv.x() < 10 || uv.y() < 10 || uv.x() > K.width - 10.0 || uv.y() > K.height - 10.0) {
          return false;
        }
      }
    }
  }
  return true;
}

std::vector<Isometry3d> RandomBoardPoses(const ChessboardSpec& board, int count, std::uint32_t seed,
                                         const CameraIntrinsics& camera,
                                         const CameraIntrinsics& projector,
                                         const Isometry3d& X_CameraProjector) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> depth(0.62, 0.85), offset(-0.04, 0.04), tilt(0.15, 0.6),
      spin(-0.3, 0.3), angle(0.0, 2.0 * kPi);
  const Vector3d c_Board((board.inner_corners_x - 1) * board.square_size_m / 2.0,
                         (board.inner_corners_y - 1) * board.square_size_m / 2.0, 0.0);
  std::vector<Isometry3d> poses;
  while (static_cast<int>(poses.size()) < count) {
    const double axis_angle = angle(rng);
    const Vector3d axis(std::cos(axis_angle), std::sin(axis_angle), 0.0);
    const Eigen::Matrix3d R =
        (Eigen::AngleAxisd(tilt(rng), axis) * Eigen::AngleAxisd(spin(rng), Vector3d::UnitZ()))
            .toRotationMatrix();
    const Vector3d centre(offset(rng), offset(rng), depth(rng));
    Isometry3d X = Isometry3d::Identity();
    X.linear() = R;
    X.translation() = centre - R * c_Board;
    if (AllCornersVisible(board, X, camera, projector, X_CameraProjector)) poses.push_back(X);
  }
  return poses;
}

TEST(GrayCodeDecodeTest, DecodesEveryProjectorPixelSeenDirectly) {
  // The camera sees the projector image 1:1 (a 64 x 48 projector): every pixel decodes to
  // its own column and row.
  ProjectorSpec spec{64, 48, 6, 6};
  std::vector<GrayImage> images;
  for (int k = 0; k < spec.image_count(); ++k) {
    GrayImage image(spec.width, spec.height);
    for (std::uint32_t r = 0; r < spec.height; ++r) {
      for (std::uint32_t c = 0; c < spec.width; ++c) {
        bool lit = k == 0;
        if (k >= 2) {
          const int pair = (k - 2) / 2;
          const bool inverse = (k - 2) % 2 == 1;
          const std::uint32_t code = pair < 6 ? GrayEncode(c) : GrayEncode(r);
          const int bit = pair < 6 ? pair : pair - 6;
          lit = (((code >> (5 - bit)) & 1u) != 0) != inverse;
        }
        image.at(c, r) = lit ? 200 : 30;
      }
    }
    images.push_back(std::move(image));
  }
  const ProjectorCorrespondence correspondence = DecodeGrayCode(images, spec);
  for (std::uint32_t r = 0; r < spec.height; ++r) {
    for (std::uint32_t c = 0; c < spec.width; ++c) {
      ASSERT_EQ(correspondence.column[r * spec.width + c], static_cast<std::int32_t>(c));
      ASSERT_EQ(correspondence.row[r * spec.width + c], static_cast<std::int32_t>(r));
    }
  }
  // Low contrast: nothing decodes.
  for (auto& image : images) {
    for (auto& p : image.pixels) p = static_cast<std::uint8_t>(100 + (p > 100 ? 2 : 0));
  }
  const ProjectorCorrespondence flat = DecodeGrayCode(images, spec);
  EXPECT_TRUE(std::all_of(flat.column.begin(), flat.column.end(), [](int v) { return v < 0; }));
  images.pop_back();
  EXPECT_THROW(DecodeGrayCode(images, spec), std::invalid_argument);
}

TEST(ProjectorCalibrationTest, RecoversSimulatedProjectorWithinOnePercent) {
  const ChessboardSpec board{9, 6, 0.03};
  const ProjectorSpec spec;  // 912 x 1140, 10 + 11 bits
  const CameraIntrinsics camera = TrueCamera();
  const CameraIntrinsics projector = TrueProjector();
  const Isometry3d X_CameraProjector = TrueCameraProjector(projector);
  StructuredLightSimulator simulator(camera, projector, X_CameraProjector, board, spec, 7);
  const std::vector<Isometry3d> poses =
      RandomBoardPoses(board, 8, 2016, camera, projector, X_CameraProjector);

  ProjectorCalibrationOptions options;
  options.board = board;
  options.projector = spec;
  ProjectorCalibrator calibrator(options);
  double max_projector_corner_error_px = 0.0;
  double sum_projector_corner_error_px = 0.0;
  int corner_count = 0;
  for (std::size_t i = 0; i < poses.size(); ++i) {
    const std::vector<GrayImage> images = simulator.Render(poses[i]);
    const ProjectorCalibrationView& view = calibrator.AddView("pose" + std::to_string(i), images);
    // The corners mapped through the local homographies land on the true projector pixels.
    const std::vector<Vector3d> corners = board.CornerPositions();
    const Isometry3d X_ProjectorBoard = X_CameraProjector.inverse() * poses[i];
    // Detected corner order may run either way along the board; match by nearest.
    for (const Vector2d& measured : view.projector_corners_px) {
      double best = 1e9;
      for (const Vector3d& p : corners) {
        best = std::min(best, (projector.Project(X_ProjectorBoard * p) - measured).norm());
      }
      max_projector_corner_error_px = std::max(max_projector_corner_error_px, best);
      sum_projector_corner_error_px += best;
      ++corner_count;
    }
  }
  EXPECT_LT(max_projector_corner_error_px, 1.0);
  EXPECT_LT(sum_projector_corner_error_px / corner_count, 0.25);
  const ProjectorCalibrationResult result = calibrator.Calibrate();

  EXPECT_NEAR(result.projector.fx, projector.fx, 0.01 * projector.fx);
  EXPECT_NEAR(result.projector.fy, projector.fy, 0.01 * projector.fy);
  EXPECT_NEAR(result.projector.cx, projector.cx, 0.01 * projector.cx);
  EXPECT_NEAR(result.projector.cy, projector.cy, 0.01 * projector.cy);
  EXPECT_NEAR(result.camera.fx, camera.fx, 0.005 * camera.fx);
  EXPECT_NEAR(result.camera.fy, camera.fy, 0.005 * camera.fy);
  EXPECT_NEAR(result.camera.cx, camera.cx, 0.01 * camera.cx);
  EXPECT_NEAR(result.camera.cy, camera.cy, 0.01 * camera.cy);
  EXPECT_NEAR(result.camera.distortion[0], camera.distortion[0], 0.02);
  EXPECT_LT(result.camera_rms_px, 0.3);
  EXPECT_LT(result.projector_rms_px, 0.5);
  EXPECT_LT(result.stereo_rms_px, 0.5);
  const double translation_error_m =
      (result.X_CameraProjector.translation() - X_CameraProjector.translation()).norm();
  const double rotation_error_rad =
      Eigen::AngleAxisd(result.X_CameraProjector.linear().transpose() * X_CameraProjector.linear())
          .angle();
  EXPECT_LT(translation_error_m, 0.002);
  EXPECT_LT(rotation_error_rad, 0.2 * kPi / 180.0);
  RecordProperty("projector_fx", std::to_string(result.projector.fx));
  RecordProperty("projector_cy", std::to_string(result.projector.cy));
  RecordProperty("translation_error_mm", std::to_string(translation_error_m * 1000.0));
}

TEST(ProjectorCalibrationTest, RejectsBadViewsAndTooFewPoses) {
  ProjectorCalibrationOptions options;
  options.board = {9, 6, 0.03};
  ProjectorCalibrator calibrator(options);
  std::vector<GrayImage> images(options.projector.image_count(), GrayImage(320, 240, 0));
  try {
    calibrator.AddView("empty_pose", images);
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("empty_pose"), std::string::npos) << e.what();
  }
  images.pop_back();
  EXPECT_THROW(calibrator.AddView("short_pose", images), std::invalid_argument);
  EXPECT_EQ(calibrator.view_count(), 0);
  EXPECT_THROW(calibrator.Calibrate(), std::invalid_argument);
  ProjectorCalibrationView wrong;
  wrong.name = "wrong";
  wrong.camera_corners_px.resize(3);
  wrong.projector_corners_px.resize(3);
  EXPECT_THROW(calibrator.AddCorners(wrong), std::invalid_argument);
}

// --- Hand-eye ---------------------------------------------------------------------------

Isometry3d MakePose(const Vector3d& rotation_vector, const Vector3d& translation) {
  Isometry3d X = Isometry3d::Identity();
  if (rotation_vector.norm() > 0) {
    X.linear() =
        Eigen::AngleAxisd(rotation_vector.norm(), rotation_vector.normalized()).toRotationMatrix();
  }
  X.translation() = translation;
  return X;
}

struct HandEyeScene {
  Isometry3d X_ToolCamera;
  Isometry3d X_BaseBoard;
  std::vector<Isometry3d> X_BaseTool;
  std::vector<Isometry3d> X_CameraBoard;
};

HandEyeScene MakeHandEyeScene(int count, std::uint32_t seed, double noise_m, double noise_rad,
                              bool only_about_z) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  std::normal_distribution<double> normal(0.0, 1.0);
  HandEyeScene scene;
  scene.X_ToolCamera = MakePose(Vector3d(0.05, -0.1, 1.5), Vector3d(0.06, -0.03, 0.09));
  scene.X_BaseBoard = MakePose(Vector3d(0.0, 0.0, 0.3), Vector3d(0.8, 0.1, 0.0));
  // Nominal tool pose looking down at the board from 0.5 m above it.
  const Isometry3d X_BaseToolNominal = MakePose(Vector3d(kPi, 0.0, 0.0), Vector3d(0.8, 0.1, 0.55));
  for (int i = 0; i < count; ++i) {
    Vector3d rotation = only_about_z
                            ? Vector3d(0.0, 0.0, 0.6 * uniform(rng))
                            : Vector3d(0.4 * uniform(rng), 0.4 * uniform(rng), 0.6 * uniform(rng));
    const Vector3d translation(0.15 * uniform(rng), 0.15 * uniform(rng), 0.1 * uniform(rng));
    const Isometry3d X_BaseTool = X_BaseToolNominal * MakePose(rotation, translation);
    Isometry3d X_CameraBoard = (X_BaseTool * scene.X_ToolCamera).inverse() * scene.X_BaseBoard;
    X_CameraBoard =
        X_CameraBoard * MakePose(noise_rad * Vector3d(normal(rng), normal(rng), normal(rng)),
                                 noise_m * Vector3d(normal(rng), normal(rng), normal(rng)));
    scene.X_BaseTool.push_back(X_BaseTool);
    scene.X_CameraBoard.push_back(X_CameraBoard);
  }
  return scene;
}

TEST(HandEyeTest, RecoversToolCameraFromNoisyPoses) {
  const HandEyeScene scene = MakeHandEyeScene(15, 42, 0.0005, 0.002, false);
  for (auto method : {HandEyeOptions::Method::kPark, HandEyeOptions::Method::kTsai,
                      HandEyeOptions::Method::kDaniilidis}) {
    HandEyeOptions options;
    options.method = method;
    const HandEyeResult result = CalibrateHandEye(scene.X_BaseTool, scene.X_CameraBoard, options);
    EXPECT_LT((result.X_ToolCamera.translation() - scene.X_ToolCamera.translation()).norm(), 0.003);
    EXPECT_LT(
        Eigen::AngleAxisd(result.X_ToolCamera.linear().transpose() * scene.X_ToolCamera.linear())
            .angle(),
        0.005);
    EXPECT_LT((result.X_BaseBoard.translation() - scene.X_BaseBoard.translation()).norm(), 0.003);
    EXPECT_LT(result.translation_rms_m, 0.005);
    EXPECT_LT(result.rotation_rms_rad, 0.01);
  }
}

TEST(HandEyeTest, NoiseFreePosesAreExact) {
  const HandEyeScene scene = MakeHandEyeScene(6, 3, 0.0, 0.0, false);
  const HandEyeResult result = CalibrateHandEye(scene.X_BaseTool, scene.X_CameraBoard);
  EXPECT_TRUE(result.X_ToolCamera.isApprox(scene.X_ToolCamera, 1e-6));
  EXPECT_LT(result.translation_rms_m, 1e-6);
}

TEST(HandEyeTest, TooFewOrDegeneratePosesAreErrors) {
  const HandEyeScene scene = MakeHandEyeScene(8, 5, 0.0, 0.0, false);
  std::vector<Isometry3d> two_tool(scene.X_BaseTool.begin(), scene.X_BaseTool.begin() + 2);
  std::vector<Isometry3d> two_board(scene.X_CameraBoard.begin(), scene.X_CameraBoard.begin() + 2);
  EXPECT_THROW(CalibrateHandEye(two_tool, two_board), std::invalid_argument);
  std::vector<Isometry3d> short_board = scene.X_CameraBoard;
  short_board.pop_back();
  EXPECT_THROW(CalibrateHandEye(scene.X_BaseTool, short_board), std::invalid_argument);
  // All motions about one axis: translation along that axis is unobservable.
  const HandEyeScene planar = MakeHandEyeScene(8, 6, 0.0, 0.0, true);
  try {
    CalibrateHandEye(planar.X_BaseTool, planar.X_CameraBoard);
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("degenerate"), std::string::npos) << e.what();
  }
  // Pure translations: no rotation at all.
  std::vector<Isometry3d> translated_tool, translated_board;
  for (int i = 0; i < 5; ++i) {
    const Isometry3d X_BaseTool = MakePose(Vector3d(kPi, 0, 0), Vector3d(0.8 + 0.02 * i, 0.1, 0.5));
    translated_tool.push_back(X_BaseTool);
    translated_board.push_back((X_BaseTool * scene.X_ToolCamera).inverse() * scene.X_BaseBoard);
  }
  EXPECT_THROW(CalibrateHandEye(translated_tool, translated_board), std::invalid_argument);
}

}  // namespace
}  // namespace picking::scanner
