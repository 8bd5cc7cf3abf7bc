#include "services/scanner/core/calibration_workflow.h"

#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "libs/errors/errors.h"
#include "services/scanner/core/replay_camera.h"

namespace picking::scanner {
namespace {

namespace fs = std::filesystem;
using Eigen::Isometry3d;
using Eigen::Vector3d;

Isometry3d SamplePose() {
  Isometry3d X = Isometry3d::Identity();
  X.linear() = Eigen::AngleAxisd(0.3, Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  X.translation() = Vector3d(0.1, -0.2, 0.3);
  return X;
}

// Three small images of distinct grey levels: a stand-in for a pattern sequence.
std::vector<GrayImage> SampleSequence() {
  std::vector<GrayImage> images;
  for (std::uint8_t level : {200, 10, 120}) images.emplace_back(8, 6, level);
  return images;
}

fs::path SampleImagesDir() { return fs::path(PICKING_TEST_DATA_DIR) / "calibration"; }

class CalibrationWorkflowTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("calibration_workflow_test_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  fs::path dir_;
};

// --- Captures on disk -----------------------------------------------------------------------

TEST_F(CalibrationWorkflowTest, StoredViewsComeBackWithTheirImagesAndPoses) {
  const CaptureStore store((dir_ / "sessions").string());
  const std::vector<GrayImage> images = SampleSequence();
  EXPECT_EQ(store.AddView("bench_1", images, SamplePose()), 0);
  EXPECT_EQ(store.AddView("bench_1", images, std::nullopt), 1);
  EXPECT_TRUE(fs::exists(dir_ / "sessions" / "bench_1" / "view_000" / "img_02.png"));

  const std::vector<StoredView> views = store.SessionViews("bench_1");
  ASSERT_EQ(views.size(), 2u);
  EXPECT_EQ(views[0].name, "view_000");
  EXPECT_EQ(views[1].name, "view_001");
  ASSERT_TRUE(views[0].X_BaseTool.has_value());
  EXPECT_TRUE(views[0].X_BaseTool->isApprox(SamplePose(), 1e-12));
  EXPECT_FALSE(views[1].X_BaseTool.has_value());

  const std::vector<GrayImage> loaded = LoadSequence(views[0], 3);
  ASSERT_EQ(loaded.size(), 3u);
  for (std::size_t i = 0; i < loaded.size(); ++i) EXPECT_EQ(loaded[i].pixels, images[i].pixels);
  EXPECT_EQ(LoadWhiteImage(views[0]).pixels, images[0].pixels);
  EXPECT_THROW(LoadSequence(views[0], 4), std::invalid_argument);
}

TEST_F(CalibrationWorkflowTest, SessionNamesStayInsideTheStore) {
  const CaptureStore store((dir_ / "sessions").string());
  EXPECT_TRUE(IsValidSessionName("run_1-a"));
  EXPECT_FALSE(IsValidSessionName("../escape"));
  EXPECT_FALSE(IsValidSessionName(""));
  EXPECT_FALSE(IsValidSessionName(std::string(65, 'a')));
  EXPECT_THROW(store.AddView("../escape", SampleSequence(), std::nullopt), std::invalid_argument);
  EXPECT_FALSE(fs::exists(dir_ / "escape"));
  EXPECT_THROW(store.SessionViews("never_captured"), NotFoundError);
}

TEST_F(CalibrationWorkflowTest, PoseFilesRoundTripAndMalformedOnesAreErrors) {
  WritePoseFile(dir_ / "pose.txt", SamplePose());
  const std::optional<Isometry3d> X = ReadPoseFile(dir_ / "pose.txt");
  ASSERT_TRUE(X.has_value());
  EXPECT_TRUE(X->isApprox(SamplePose(), 1e-12));
  EXPECT_FALSE(ReadPoseFile(dir_ / "missing.txt").has_value());
  std::ofstream(dir_ / "short.txt") << "1 2 3\n";
  EXPECT_THROW(ReadPoseFile(dir_ / "short.txt"), std::runtime_error);
  std::ofstream(dir_ / "scaled.txt") << "0 0 0 0 0 0 2\n";
  EXPECT_THROW(ReadPoseFile(dir_ / "scaled.txt"), std::runtime_error);
}

TEST_F(CalibrationWorkflowTest, ImageDirectoriesListFilesOrFolders) {
  WriteGrayImage((dir_ / "b.png").string(), GrayImage(4, 4, 0));
  WriteGrayImage((dir_ / "a.png").string(), GrayImage(4, 4, 0));
  std::ofstream(dir_ / "notes.txt") << "not an image\n";
  fs::create_directories(dir_ / "pose_1");
  WritePoseFile(dir_ / "pose_1" / "X_base_tool.txt", SamplePose());

  const std::vector<StoredView> files = ImageDirectoryViews(dir_, ViewLayout::kImageFiles);
  ASSERT_EQ(files.size(), 2u);
  EXPECT_EQ(files[0].name, "a.png");
  EXPECT_EQ(files[1].name, "b.png");
  const std::vector<StoredView> folders = ImageDirectoryViews(dir_, ViewLayout::kSequenceFolders);
  ASSERT_EQ(folders.size(), 1u);
  EXPECT_EQ(folders[0].name, "pose_1");
  EXPECT_TRUE(folders[0].X_BaseTool.has_value());
}

// --- Workflows ------------------------------------------------------------------------------

TEST_F(CalibrationWorkflowTest, CameraFromTheOpenCvSampleImages) {
  CalibrationState current;
  current.X_ToolCamera = SamplePose();
  const CalibrationWorkflow workflow({});
  const CalibrationRun run = workflow.Camera(
      [](ViewLayout layout) {
        EXPECT_EQ(layout, ViewLayout::kImageFiles);
        return ImageDirectoryViews(SampleImagesDir(), layout);
      },
      ChessboardSpec{9, 6, 0.025}, current);
  EXPECT_EQ(run.views_used, 13);
  EXPECT_TRUE(run.skipped.empty());
  EXPECT_EQ(run.per_view_error_px.size(), 13u);
  EXPECT_GT(run.rms_reprojection_error_px, 0.0);
  EXPECT_LT(run.rms_reprojection_error_px, 0.5);
  ASSERT_TRUE(run.state.camera.has_value());
  EXPECT_EQ(run.state.camera->width, 640u);
  EXPECT_TRUE(run.state.camera_calibrated);
  EXPECT_FALSE(run.state.hand_eye_calibrated);
  ASSERT_TRUE(run.state.X_ToolCamera.has_value());  // The other values are kept.
  EXPECT_TRUE(run.state.X_ToolCamera->isApprox(SamplePose()));
  ASSERT_EQ(run.intrinsics_files.size(), 1u);
  EXPECT_EQ(run.intrinsics_files[0].first, CalibrationKind::kCameraIntrinsics);
  EXPECT_FALSE(run.pose_file.has_value());
}

TEST_F(CalibrationWorkflowTest, TooFewBoardsIsAFailedPreconditionAndSkippedViewsAreReported) {
  WriteGrayImage((dir_ / "blank.png").string(), GrayImage(640, 480, 128));
  std::vector<StoredView> views = {{"blank.png", dir_ / "blank.png", {}}};
  for (const char* name : {"left01.jpg", "left02.jpg"}) {
    views.push_back({name, SampleImagesDir() / name, {}});
  }
  std::vector<std::string> reported;
  CalibrationWorkflowOptions options;
  options.on_view_skipped = [&](const std::string& calibration, const SkippedView& view) {
    reported.push_back(calibration + " / " + view.name + " / " + view.reason);
  };
  const CalibrationWorkflow workflow(options);
  try {
    workflow.Camera(FixedViews(views), ChessboardSpec{9, 6, 0.025}, CalibrationState());
    FAIL() << "expected an error";
  } catch (const PreconditionError& e) {
    EXPECT_NE(std::string(e.what()).find("at least 3"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("got 2 of 3"), std::string::npos) << e.what();
  }
  EXPECT_EQ(reported,
            std::vector<std::string>{"camera calibration / blank.png / chessboard not found"});
}

TEST_F(CalibrationWorkflowTest, TheStateIsCheckedBeforeTheViewsAreListed) {
  const CalibrationWorkflow workflow({});
  bool listed = false;
  const ViewSource source = [&](ViewLayout) {
    listed = true;
    return std::vector<StoredView>();
  };
  EXPECT_THROW(workflow.HandEye(source, ChessboardSpec(), CalibrationState()), PreconditionError);
  EXPECT_THROW(workflow.Projector(source, ChessboardSpec(), CalibrationState(), nullptr),
               PreconditionError);
  EXPECT_FALSE(listed);
}

TEST_F(CalibrationWorkflowTest, ProjectorPatternsFollowTheProjectorIntrinsics) {
  CalibrationState state;
  EXPECT_THROW(ProjectorPatterns(nullptr, state), PreconditionError);
  state.projector = CameraIntrinsics();
  state.projector->width = 456;
  state.projector->height = 570;
  const PatternSequence patterns = ProjectorPatterns(nullptr, state);
  EXPECT_EQ(patterns.projector_width(), 456);
  EXPECT_EQ(patterns.projector_height(), 570);
  EXPECT_FALSE(MakeScanPipeline(state));  // No camera, no X_CameraProjector.
}

TEST_F(CalibrationWorkflowTest, ARunIsStoredAndItsPoseIsTheStoredOne) {
  const CalibrationStore store((dir_ / "calibration").string(), "");
  CalibrationRun empty;
  EXPECT_THROW(SaveCalibrationRun(store, &empty), std::invalid_argument);

  CalibrationRun run;
  run.state.X_ToolCamera = SamplePose();
  run.state.hand_eye_calibrated = true;
  run.pose_file.emplace(CalibrationKind::kHandEye, PoseFile{SamplePose(), {"", 0.001, "m"}});
  const std::string path = SaveCalibrationRun(store, &run);
  EXPECT_EQ(path, store.PathOf(CalibrationKind::kHandEye));
  ASSERT_TRUE(run.state.X_ToolCamera.has_value());
  EXPECT_TRUE(run.state.X_ToolCamera->isApprox(SamplePose(), 1e-9));
  const CalibrationState loaded = store.Load();
  ASSERT_TRUE(loaded.X_ToolCamera.has_value());
  EXPECT_TRUE(loaded.X_ToolCamera->matrix() == run.state.X_ToolCamera->matrix());
  EXPECT_TRUE(loaded.hand_eye_calibrated);
}

TEST_F(CalibrationWorkflowTest, OptionsOutOfRangeAreRefused) {
  CalibrationWorkflowOptions options;
  options.min_views = 2;
  EXPECT_THROW(CalibrationWorkflow{options}, std::invalid_argument);
  options = CalibrationWorkflowOptions();
  options.max_depth_m = options.min_depth_m;
  EXPECT_THROW(CalibrationWorkflow{options}, std::invalid_argument);
}

}  // namespace
}  // namespace picking::scanner
