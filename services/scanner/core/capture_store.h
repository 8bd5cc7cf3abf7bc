#pragma once

#include <Eigen/Geometry>

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "services/scanner/core/camera_backend.h"

namespace picking::scanner {

/// What a session name may be: one path component of 1 to 64 letters, digits, '_' or '-'.
inline constexpr const char* kSessionNamePattern = "[A-Za-z0-9_-]{1,64}";

/// Whether `name` matches kSessionNamePattern (so it cannot leave the sessions folder).
bool IsValidSessionName(const std::string& name);

/// One stored calibration view: a folder holding one pattern sequence (or, for camera
/// calibration from an image directory, a single image file) and the flange pose at capture
/// time when it was recorded.
struct StoredView {
  std::string name;            ///< Folder or file name; error messages name the view by it.
  std::filesystem::path path;  ///< The view's folder, or its image file.
  std::optional<Eigen::Isometry3d> X_BaseTool;  ///< From the folder's X_base_tool.txt.
};

/// How the views of an image directory are laid out.
enum class ViewLayout {
  kImageFiles,       ///< One view per image file (.png, .jpg, .jpeg, .bmp, .pgm).
  kSequenceFolders,  ///< One view per subfolder, each a pattern sequence.
};

/// The views of an image directory in name order. A subfolder's pose is read from its
/// X_base_tool.txt when there is one.
/// @throws std::runtime_error when a pose file is malformed, std::filesystem::filesystem_error
///   when the directory cannot be listed.
std::vector<StoredView> ImageDirectoryViews(const std::filesystem::path& dir, ViewLayout layout);

/// The white image of a view: the view's image file, or img_00.png of its folder.
/// @throws CameraError when the image cannot be read.
GrayImage LoadWhiteImage(const StoredView& view);

/// The `count` images of a view's pattern sequence, its image files in name order.
/// @throws std::invalid_argument naming the view when it holds another number of images,
///   CameraError when an image cannot be read.
std::vector<GrayImage> LoadSequence(const StoredView& view, int count);

/// A pose as one line "x y z qx qy qz qw" (metres, unit quaternion), X_base_tool.txt's format.
/// @throws std::runtime_error when the file cannot be written.
void WritePoseFile(const std::filesystem::path& path, const Eigen::Isometry3d& X);

/// The pose of a file WritePoseFile wrote; nullopt when there is no such file.
/// @throws std::runtime_error naming the file when it is malformed or its quaternion not unit.
std::optional<Eigen::Isometry3d> ReadPoseFile(const std::filesystem::path& path);

/// Calibration captures on disk, one folder per session:
///   <dir>/<session>/view_NNN/img_MM.png   the view's sequence in pattern order
///   <dir>/<session>/view_NNN/X_base_tool.txt  the flange pose at capture time, if known
/// A view is written into a temporary folder and renamed into place, so a session never holds
/// a partial view.
class CaptureStore final {
 public:
  /// @param dir the sessions folder (created on the first AddView).
  explicit CaptureStore(std::string dir);

  const std::string& dir() const { return dir_; }

  /// Appends a view to `session` (created when new) and returns its index.
  /// @throws std::invalid_argument for a name not matching kSessionNamePattern,
  ///   std::runtime_error / std::filesystem::filesystem_error when the files cannot be written.
  int AddView(const std::string& session, const std::vector<GrayImage>& images,
              const std::optional<Eigen::Isometry3d>& X_BaseTool) const;

  /// The views of `session` in index order.
  /// @throws std::invalid_argument for a name not matching kSessionNamePattern,
  ///   picking::NotFoundError when the session does not exist, std::runtime_error when a
  ///   pose file is malformed.
  std::vector<StoredView> SessionViews(const std::string& session) const;

 private:
  std::filesystem::path SessionDir(const std::string& session) const;

  std::string dir_;
};

}  // namespace picking::scanner
