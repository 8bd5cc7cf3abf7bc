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
  /// Sub-pixel projector coordinates (u = column, v = row in projector pixels, mirror centres
  /// at integers), NaN where invalid. Filled by SubpixelRefiner; empty otherwise (the decoder
  /// clears them). Where valid, |column_subpixel - column| <= 0.5 and likewise for rows.
  std::vector<float> column_subpixel;
  std::vector<float> row_subpixel;

  /// True if the sub-pixel maps are present (SubpixelRefiner ran on this map).
  bool has_subpixel() const { return !column_subpixel.empty() || !row_subpixel.empty(); }

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

  /// As above, writing into `map` and reusing its buffers (the sub-pixel maps are cleared).
  /// @throws as above.
  void Decode(const std::vector<ImageView>& images, CorrespondenceMap* map) const;

 private:
  PatternSequence patterns_;
  DecoderOptions options_;
  std::unique_ptr<BandPool> pool_;
};

/// Options of the sub-pixel refinement.
struct RefinementOptions {
  /// A valid pixel whose column or row cannot be refined (its run of equal codes has no
  /// neighbouring transition to interpolate from or extrapolate with, e.g. a sliver between
  /// an occlusion edge and a shadow, or an isolated misdecoded pixel) is made invalid if
  /// true (and counted in RefinementResult::num_rejected); if false it keeps its integer
  /// column / row as its sub-pixel value.
  bool reject_unrefined = true;
  /// Gaps of up to this many invalid pixels along a line between two valid pixels whose
  /// codes are equal or differ by one are bridged: the run goes on, or the stripe edge is
  /// located inside the gap. Pixels straddling a stripe edge are often invalid (the edge's
  /// bit has pattern ~ inverse there); without bridging their neighbours could not be
  /// interpolated. Bridged pixels stay invalid. In [0, 16].
  int max_gap_px = 2;
  /// Refine the projector rows too (along camera columns). If false, row_subpixel is the
  /// integer row of every valid pixel (NaN elsewhere), a pixel counts as refined when its
  /// column is, and the refinement costs about half as much. With the baseline along the
  /// projector's columns (horizontal), the depth comes from the column: the row moves the
  /// projector ray along the column's light plane, which shifts the intersection with the
  /// camera ray only through the plane's curvature (projector distortion). On the benchmark
  /// scene (bench_scanner) the median depth error is 0.150 mm with integer rows against
  /// 0.145 mm with refined rows (1.26 mm with integer columns and rows).
  bool refine_rows = true;
  /// Threads including the caller; 0 uses std::thread::hardware_concurrency().
  int num_threads = 0;
};

/// What a refinement did.
struct RefinementResult {
  std::size_t num_refined = 0;             ///< Valid pixels with both coordinates refined.
  std::size_t num_rejected = 0;            ///< Valid pixels made invalid (reject_unrefined).
  std::size_t num_kept_integer = 0;        ///< Unrefined pixels kept (!reject_unrefined).
  std::size_t num_column_transitions = 0;  ///< Column edges located along camera rows.
  /// Row edges located along camera columns (0 unless RefinementOptions::refine_rows).
  std::size_t num_row_transitions = 0;
  /// Pixel coordinates that their line could not refine, taken from refined neighbours up to
  /// two pixels away across the line (a column from the pixels above and below, a row from
  /// those left and right), e.g. for pixels inside a stripe-edge line of invalid pixels.
  std::size_t num_filled_across = 0;
};

/// Sub-pixel refinement of a decoded CorrespondenceMap, an optional stage after
/// GrayCodeDecoder::Decode on the same captures.
///
/// Along every camera row, wherever two neighbouring valid pixels decode to projector
/// columns c and c + 1 (either order) the boundary between the two columns (at c + 0.5) is
/// located to a fraction of a camera pixel: exactly one Gray-code bit differs between c and
/// c + 1, and the zero crossing of (pattern - inverse) of that bit is found by linear
/// interpolation between the two pixels. Each valid pixel then gets a continuous column by
/// linear interpolation between the boundaries on its left and right; a run with a boundary
/// on one side only (at a shadow or an occlusion edge) is extrapolated with the slope of the
/// neighbouring run, clamped to c +- 0.5. Stretches of more than max_gap_px invalid pixels
/// and jumps of more than one column end the interpolation: nothing is interpolated across
/// them. A pixel that its row cannot refine (isolated between invalid pixels) takes its
/// column from refined pixels up to two rows above and below with a column within one of
/// its own; rows likewise from the left and right. Rows likewise along camera
/// columns with the row bits (unless RefinementOptions::refine_rows is false: rows then
/// stay integer). Work runs on a thread pool in bands of rows and in strips of
/// columns scanned row by row (row-major reads of the map and the captures), with per-task
/// state only (no allocation per pixel); the fills visit only the pixels left unrefined.
///
/// Refine may be called from several threads; calls are serialised.
class SubpixelRefiner final {
 public:
  /// @throws std::invalid_argument if options.num_threads < 0 or options.max_gap_px is
  ///   outside [0, 16].
  explicit SubpixelRefiner(const PatternSequence& patterns, const RefinementOptions& options = {});
  ~SubpixelRefiner();
  SubpixelRefiner(const SubpixelRefiner&) = delete;
  SubpixelRefiner& operator=(const SubpixelRefiner&) = delete;

  const PatternSequence& patterns() const { return patterns_; }
  const RefinementOptions& options() const { return options_; }

  /// Fills map->column_subpixel and map->row_subpixel from `images` (the captures `map`
  /// was decoded from, in the order of patterns()), and invalidates the pixels that cannot
  /// be refined if options().reject_unrefined (their column, row and sub-pixel values are
  /// then 0, 0, NaN and num_valid drops accordingly). Buffers of `map` are reused.
  /// @throws std::invalid_argument if `map` is null, the images are not a valid capture of
  ///   patterns() (count, data, equal sizes, strides), the map's size differs from the
  ///   images', its buffers are not width * height long, or a valid pixel's column (row) is
  ///   outside the projector. The map is untouched then.
  RefinementResult Refine(const std::vector<ImageView>& images, CorrespondenceMap* map) const;

 private:
  PatternSequence patterns_;
  RefinementOptions options_;
  std::unique_ptr<BandPool> pool_;
};

}  // namespace picking::scanner
