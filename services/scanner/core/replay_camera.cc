#include "services/scanner/core/replay_camera.h"

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <stdexcept>

namespace picking::scanner {

GrayImage ReadGrayImage(const std::string& path) {
  const cv::Mat raw = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (raw.empty()) throw CameraError("cannot read image '" + path + "'");
  if (raw.depth() != CV_8U) {
    throw CameraError("image '" + path + "' is not 8-bit (OpenCV depth " +
                      std::to_string(raw.depth()) + ")");
  }
  cv::Mat gray;
  switch (raw.channels()) {
    case 1:
      gray = raw;
      break;
    case 3:
      cv::cvtColor(raw, gray, cv::COLOR_BGR2GRAY);
      break;
    case 4:
      cv::cvtColor(raw, gray, cv::COLOR_BGRA2GRAY);
      break;
    default:
      throw CameraError("image '" + path + "' has " + std::to_string(raw.channels()) + " channels");
  }
  GrayImage image(static_cast<std::uint32_t>(gray.cols), static_cast<std::uint32_t>(gray.rows));
  for (int y = 0; y < gray.rows; ++y) {
    std::copy(gray.ptr<std::uint8_t>(y), gray.ptr<std::uint8_t>(y) + gray.cols,
              image.pixels.begin() + static_cast<std::ptrdiff_t>(y) * gray.cols);
  }
  return image;
}

void WriteGrayImage(const std::string& path, const GrayImage& image) {
  if (image.pixels.size() != static_cast<std::size_t>(image.width) * image.height ||
      image.empty()) {
    throw CameraError("cannot write '" + path + "': image is empty or malformed");
  }
  const cv::Mat mat(static_cast<int>(image.height), static_cast<int>(image.width), CV_8UC1,
                    const_cast<std::uint8_t*>(image.pixels.data()));
  bool ok = false;
  try {
    ok = cv::imwrite(path, mat);
  } catch (const cv::Exception& e) {
    throw CameraError("cannot write '" + path + "': " + e.what());
  }
  if (!ok) throw CameraError("cannot write '" + path + "'");
}

ReplayCamera::ReplayCamera(const std::string& folder) {
  namespace fs = std::filesystem;
  std::error_code error;
  if (!fs::is_directory(folder, error)) {
    throw CameraError("replay folder '" + folder + "' does not exist or is not a folder");
  }
  for (const auto& entry : fs::directory_iterator(folder)) {
    if (!entry.is_regular_file()) continue;
    std::string extension = entry.path().extension().string();
    std::transform(extension.begin(), extension.end(), extension.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    if (extension == ".png" || extension == ".pgm") files_.push_back(entry.path().string());
  }
  if (files_.empty()) {
    throw CameraError("replay folder '" + folder + "' holds no PNG or PGM image");
  }
  std::sort(files_.begin(), files_.end());
  for (const std::string& file : files_) {
    GrayImage image = ReadGrayImage(file);
    if (images_.empty()) {
      width_ = image.width;
      height_ = image.height;
    } else if (image.width != width_ || image.height != height_) {
      throw CameraError("replay image '" + file + "' is " + std::to_string(image.width) + " x " +
                        std::to_string(image.height) + " but '" + files_.front() + "' is " +
                        std::to_string(width_) + " x " + std::to_string(height_));
    }
    images_.push_back(std::move(image));
  }
  // Frame ids: the number each file name ends with when every name has one (a recording
  // that lost a frame then replays the loss), else the image index.
  for (const std::string& file : files_) {
    const std::string stem = fs::path(file).stem().string();
    std::size_t digits = 0;
    while (digits < stem.size() && digits < 18 &&
           std::isdigit(static_cast<unsigned char>(stem[stem.size() - 1 - digits]))) {
      ++digits;
    }
    if (digits == 0) {
      frame_ids_.clear();
      break;
    }
    frame_ids_.push_back(std::stoull(stem.substr(stem.size() - digits)));
  }
  if (frame_ids_.empty()) {
    for (std::size_t i = 0; i < files_.size(); ++i) frame_ids_.push_back(i);
  }
}

void ReplayCamera::Configure(const CameraSettings& settings) { ValidateCameraSettings(settings); }

std::vector<Frame> ReplayCamera::Capture(int count) {
  if (count <= 0) {
    throw std::invalid_argument("ReplayCamera::Capture: count must be > 0, got " +
                                std::to_string(count));
  }
  if (next_ + static_cast<std::size_t>(count) > images_.size()) {
    throw CameraTimeoutError("replay camera: " + std::to_string(count) + " frames requested but " +
                             std::to_string(images_.size() - next_) + " of " +
                             std::to_string(images_.size()) + " images are left");
  }
  std::vector<Frame> frames;
  frames.reserve(static_cast<std::size_t>(count));
  for (int i = 0; i < count; ++i) {
    Frame frame;
    frame.image = images_[next_];
    frame.frame_id = frame_ids_[next_];
    frames.push_back(std::move(frame));
    ++next_;
  }
  CheckConsecutiveFrameIds(frames);
  return frames;
}

}  // namespace picking::scanner
