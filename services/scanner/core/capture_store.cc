#include "services/scanner/core/capture_store.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>
#include <iomanip>
#include <regex>
#include <sstream>
#include <stdexcept>

#include "libs/errors/errors.h"
#include "services/scanner/core/replay_camera.h"

namespace picking::scanner {
namespace {

namespace fs = std::filesystem;

constexpr const char* kPoseFileName = "X_base_tool.txt";

std::string ViewDirName(int index) {
  std::ostringstream s;
  s << "view_" << std::setw(3) << std::setfill('0') << index;
  return s.str();
}

std::string ImageFileName(int index) {
  std::ostringstream s;
  s << "img_" << std::setw(2) << std::setfill('0') << index << ".png";
  return s.str();
}

bool IsImageFile(const fs::path& p) {
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext == ".png" || ext == ".jpg" || ext == ".jpeg" || ext == ".bmp" || ext == ".pgm";
}

// The subfolders, or the image files, of `dir` in name order.
std::vector<fs::path> SortedEntries(const fs::path& dir, bool directories) {
  std::vector<fs::path> out;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (directories ? e.is_directory() : (e.is_regular_file() && IsImageFile(e.path()))) {
      out.push_back(e.path());
    }
  }
  std::sort(out.begin(), out.end());
  return out;
}

StoredView FolderView(const fs::path& folder) {
  return {folder.filename().string(), folder, ReadPoseFile(folder / kPoseFileName)};
}

}  // namespace

bool IsValidSessionName(const std::string& name) {
  static const std::regex kPattern(kSessionNamePattern);
  return std::regex_match(name, kPattern);
}

std::vector<StoredView> ImageDirectoryViews(const fs::path& dir, ViewLayout layout) {
  std::vector<StoredView> views;
  if (layout == ViewLayout::kSequenceFolders) {
    for (const auto& v : SortedEntries(dir, true)) views.push_back(FolderView(v));
  } else {
    for (const auto& f : SortedEntries(dir, false)) views.push_back({f.filename().string(), f, {}});
  }
  return views;
}

GrayImage LoadWhiteImage(const StoredView& view) {
  if (fs::is_directory(view.path)) return ReadGrayImage((view.path / ImageFileName(0)).string());
  return ReadGrayImage(view.path.string());
}

std::vector<GrayImage> LoadSequence(const StoredView& view, int count) {
  const std::vector<fs::path> files = SortedEntries(view.path, false);
  if (static_cast<int>(files.size()) != count) {
    throw std::invalid_argument("view " + view.name + " holds " + std::to_string(files.size()) +
                                " images, the sequence has " + std::to_string(count));
  }
  std::vector<GrayImage> images;
  for (const auto& f : files) images.push_back(ReadGrayImage(f.string()));
  return images;
}

void WritePoseFile(const fs::path& path, const Eigen::Isometry3d& X) {
  const Eigen::Quaterniond q(X.linear());
  std::ofstream out(path);
  // 17 digits: a double read back is the same double.
  out << std::setprecision(17) << X.translation().x() << ' ' << X.translation().y() << ' '
      << X.translation().z() << ' ' << q.x() << ' ' << q.y() << ' ' << q.z() << ' ' << q.w()
      << '\n';
  if (!out) throw std::runtime_error("cannot write " + path.string());
}

std::optional<Eigen::Isometry3d> ReadPoseFile(const fs::path& path) {
  std::ifstream in(path);
  if (!in) return std::nullopt;
  double v[7];
  for (double& x : v) {
    if (!(in >> x) || !std::isfinite(x)) {
      throw std::runtime_error(path.string() + ": malformed pose");
    }
  }
  const Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
  if (std::abs(q.norm() - 1.0) > 1e-3) {
    throw std::runtime_error(path.string() + ": quaternion not unit");
  }
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = q.normalized().toRotationMatrix();
  X.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
  return X;
}

CaptureStore::CaptureStore(std::string dir) : dir_(std::move(dir)) {}

fs::path CaptureStore::SessionDir(const std::string& session) const {
  // The name is checked here too, not only by callers: it becomes a path component.
  if (!IsValidSessionName(session)) {
    throw std::invalid_argument(std::string("a capture session's name must match ") +
                                kSessionNamePattern);
  }
  return fs::path(dir_) / session;
}

int CaptureStore::AddView(const std::string& session, const std::vector<GrayImage>& images,
                          const std::optional<Eigen::Isometry3d>& X_BaseTool) const {
  const fs::path dir = SessionDir(session);
  fs::create_directories(dir);
  const int index = static_cast<int>(SortedEntries(dir, true).size());
  const fs::path tmp = dir / (".tmp_" + ViewDirName(index));
  fs::remove_all(tmp);
  fs::create_directories(tmp);
  for (std::size_t i = 0; i < images.size(); ++i) {
    WriteGrayImage((tmp / ImageFileName(static_cast<int>(i))).string(), images[i]);
  }
  if (X_BaseTool) WritePoseFile(tmp / kPoseFileName, *X_BaseTool);
  fs::rename(tmp, dir / ViewDirName(index));
  return index;
}

std::vector<StoredView> CaptureStore::SessionViews(const std::string& session) const {
  const fs::path dir = SessionDir(session);
  if (!fs::is_directory(dir)) {
    throw NotFoundError("calibration session '" + session + "' does not exist");
  }
  std::vector<StoredView> views;
  for (const auto& v : SortedEntries(dir, true)) {
    // Skips a temporary folder a capture left behind when it was interrupted.
    if (v.filename().string().rfind("view_", 0) != 0) continue;
    views.push_back(FolderView(v));
  }
  return views;
}

}  // namespace picking::scanner
