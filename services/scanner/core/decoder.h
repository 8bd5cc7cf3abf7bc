#pragma once

#include "services/scanner/core/patterns.h"

#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

namespace picking::scanner {

class BandPool;

/// A read-only view of an 8-bit monochrome image owned elsewhere. Pixel (x, y) is at
/// data[y * stride_bytes + x].
struct ImageView {
  const std::uint8_t* data = nullptr;
  int width = 0;
  int height = 0;
  std::ptrdiff_t stride_bytes = 0;  ///< Bytes from one row to the next, >= width.

  const std::uint8_t* row(int y) const { return data + y * stride_bytes; }
};

/// Makes a view of a contiguous row-major image (stride == width).
inline ImageView MakeImageView(const std::uint8_t* data, int width, int height) {
  return ImageView{data, width, height, width};
}

/// Thresholds of the decoder, in 8-bit grey levels.
struct DecoderOptions {
  /// A pixel is decoded only if white - black >= min_contrast (shadows, dark and
  /// unlit surfaces fail this).
  int min_contrast = 16;
  /// Every bit needs |pattern - inverse| >= min_bit_contrast, otherwise the pixel is invalid
  /// (the same test as OpenCV's GrayCodePattern "white threshold", default 5 there too).
  int min_bit_contrast = 5;
  /// Threads including the caller; 0 uses std::thread::hardware_concurrency().
  int num_threads = 0;
};

/// Camera-to-projector correspondence: for every camera pixel the projector column and row
/// it sees, row-major camera_width x camera_height.
struct CorrespondenceMap {
  int width = 0;
  int height = 0;
  std::vector<std::uint16_t> column;  ///< Projector column, 0 where invalid.
  std::vector<std::uint16_t> row;     ///< Projector row, 0 where invalid.
  std::vector<std::uint8_t> valid;    ///< 1 where decoded, 0 elsewhere.
  std::size_t num_valid = 0;

  /// num_valid / (width * height), 0 for an empty map.
  double decoded_fraction() const {
    const std::size_t n = static_cast<std::size_t>(width) * height;
    return n == 0 ? 0.0 : static_cast<double>(num_valid) / static_cast<double>(n);
  }
};

/// Decodes the captured Gray-code sequence of a PatternSequence into a CorrespondenceMap.
///
/// Per pixel: the pixel is valid iff white - black >= min_contrast, every pattern/inverse
/// pair differs by at least min_bit_contrast, and the decoded column (row) is inside the
/// projector. Bit = pattern > inverse, gray -> binary by prefix XOR. The work is split into
/// bands of rows run on a BandPool; the per-pixel loops are branch-free so that the compiler
/// vectorises them. No allocation per pixel; Decode(images, &map) reuses map's buffers.
///
/// Decode may be called from several threads; calls are serialised.
class GrayCodeDecoder final {
 public:
  /// @throws std::invalid_argument if a threshold is outside [0, 255] or num_threads < 0.
  explicit GrayCodeDecoder(const PatternSequence& patterns, const DecoderOptions& options = {});
  ~GrayCodeDecoder();
  GrayCodeDecoder(const GrayCodeDecoder&) = delete;
  GrayCodeDecoder& operator=(const GrayCodeDecoder&) = delete;

  const PatternSequence& patterns() const { return patterns_; }
  const DecoderOptions& options() const { return options_; }

  /// Decodes `images` in the order of patterns() (images[0] white, images[1] black, ...).
  /// @throws std::invalid_argument naming the offending image if the count differs from
  ///   patterns().num_images(), an image has no data, a non-positive size, a size different
  ///   from images[0], or a stride below its width. The output is untouched then.
  CorrespondenceMap Decode(const std::vector<ImageView>& images) const;

  /// As above, writing into `map` and reusing its buffers. @throws as above.
  void Decode(const std::vector<ImageView>& images, CorrespondenceMap* map) const;

 private:
  PatternSequence patterns_;
  DecoderOptions options_;
  std::unique_ptr<BandPool> pool_;
};

}  // namespace picking::scanner
