#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "services/scanner/core/camera_backend.h"

namespace picking::scanner {

/// Reads an image file (PNG, JPEG, ...) as 8-bit grayscale; colour images are converted.
/// Throws CameraError naming the file when it cannot be read or is not 8-bit.
GrayImage ReadGrayImage(const std::string& path);

/// Writes `image` as a PNG file. Throws CameraError naming the file on failure.
void WriteGrayImage(const std::string& path, const GrayImage& image);

/// A camera that plays back the PNG (or PGM) images of a folder, sorted by file name. Each capture
/// returns the next images. A frame's id is the number its file name ends with when every
/// name ends with one (frame_0041.png: 41), so a recording with a missing frame replays as
/// a dropped frame; otherwise the image index. Used to re-run the scanner on recorded
/// captures.
class ReplayCamera final : public CameraBackend {
 public:
  /// Loads every *.png and *.pgm of `folder`. Throws CameraError when the folder does not
  /// exist, holds no image, an image cannot be read, or the images differ in size (naming the
  /// file).
  explicit ReplayCamera(const std::string& folder);

  void Configure(const CameraSettings& settings) override;
  /// Returns the next `count` images. Throws std::invalid_argument for count <= 0,
  /// CameraTimeoutError when fewer than `count` images are left (nothing is consumed then),
  /// and DroppedFrameError when their frame ids are not consecutive (they are consumed, as
  /// a camera's frames would be).
  std::vector<Frame> Capture(int count) override;
  std::uint32_t width() const override { return width_; }
  std::uint32_t height() const override { return height_; }

  /// Number of images in the folder and the index of the next one to be returned.
  std::size_t image_count() const { return images_.size(); }
  std::size_t next_index() const { return next_; }
  const std::vector<std::string>& files() const { return files_; }
  /// Starts the playback from the first image again.
  void Rewind() { next_ = 0; }

 private:
  std::vector<std::string> files_;
  std::vector<GrayImage> images_;
  std::vector<std::uint64_t> frame_ids_;
  std::uint32_t width_ = 0;
  std::uint32_t height_ = 0;
  std::size_t next_ = 0;
};

}  // namespace picking::scanner
