#include "services/scanner/core/decoder.h"

#include "services/scanner/core/band_pool.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

namespace picking::scanner {
namespace {

// Pixels per band: the band's outputs (5 bytes per pixel) stay in L1/L2 while the 44 input
// images stream through once each.
constexpr int kPixelsPerBand = 32768;

struct SpanInputs {
  std::array<const std::uint8_t*, 2 + 4 * PatternSequence::kMaxBits> src;
};

// On x86-64 with GCC, the kernel is also compiled for AVX2 (twice the bytes per
// instruction) and the best version is chosen when the program loads.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
#define PICKING_DECODER_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define PICKING_DECODER_CLONES
#endif

// Accumulates one Gray-code bit of n pixels into `code` and keeps in `min_difference` the
// smallest |pattern - inverse| seen. Byte-wide and branch-free; every pointer is restrict so
// that the compiler vectorises without run-time alias checks.
inline void AccumulateBit(const std::uint8_t* __restrict pattern,
                          const std::uint8_t* __restrict inverse, int n,
                          std::uint8_t* __restrict code, std::uint8_t* __restrict min_difference) {
  for (int i = 0; i < n; ++i) {
    const std::uint8_t p = pattern[i];
    const std::uint8_t q = inverse[i];
    const std::uint8_t p_minus_q = static_cast<std::uint8_t>(p > q ? p - q : 0);  // Saturating.
    const std::uint8_t q_minus_p = static_cast<std::uint8_t>(q > p ? q - p : 0);
    const std::uint8_t difference = p_minus_q | q_minus_p;
    min_difference[i] = min_difference[i] < difference ? min_difference[i] : difference;
    code[i] = static_cast<std::uint8_t>((code[i] << 1) | (p_minus_q != 0 ? 1 : 0));
  }
}

inline void AccumulateBits(const SpanInputs& in, int first_image, int bits, int n,
                           std::uint8_t* code, std::uint8_t* min_difference) {
  for (int bit = 0; bit < bits; ++bit) {
    AccumulateBit(in.src[first_image + 2 * bit], in.src[first_image + 2 * bit + 1], n, code,
                  min_difference);
  }
}

// Decodes n <= kPixelsPerBand consecutive pixels: codes are gathered a byte at a time (the
// first up to 8 bits of each direction, then the rest), the validity test is one minimum
// over all bit differences, and gray -> binary is a prefix XOR on 16-bit words at the end.
PICKING_DECODER_CLONES std::size_t DecodeSpan(
    const SpanInputs& in, int n, int column_bits, int row_bits, std::uint8_t min_contrast,
    std::uint8_t min_bit_contrast, std::uint16_t projector_width, std::uint16_t projector_height,
    std::uint16_t* __restrict column, std::uint16_t* __restrict row,
    std::uint8_t* __restrict valid) {
  // Scratch rows at different offsets modulo 4 KiB, so that their loads and stores do not
  // falsely alias each other (or the page-aligned input images) in the store buffer.
  constexpr int kStagger = 64 * 5;
  alignas(64) std::uint8_t scratch[5 * (kPixelsPerBand + kStagger)];
  std::uint8_t* __restrict min_difference = scratch + 1 * kStagger;
  std::uint8_t* __restrict column_high = min_difference + kPixelsPerBand + kStagger;
  std::uint8_t* __restrict column_low = column_high + kPixelsPerBand + kStagger;
  std::uint8_t* __restrict row_high = column_low + kPixelsPerBand + kStagger;
  std::uint8_t* __restrict row_low = row_high + kPixelsPerBand + kStagger;
  {
    const std::uint8_t* __restrict white = in.src[0];
    const std::uint8_t* __restrict black = in.src[1];
    for (int i = 0; i < n; ++i) {
      const std::uint8_t w = white[i];
      const std::uint8_t b = black[i];
      const std::uint8_t contrast = static_cast<std::uint8_t>(w > b ? w - b : 0);
      valid[i] = contrast >= min_contrast;
      min_difference[i] = 255;
      column_high[i] = 0;
      column_low[i] = 0;
      row_high[i] = 0;
      row_low[i] = 0;
    }
  }
  const int column_high_bits = column_bits < 8 ? column_bits : 8;
  const int row_high_bits = row_bits < 8 ? row_bits : 8;
  const int column_first = 2;
  const int row_first = 2 + 2 * column_bits;
  AccumulateBits(in, column_first, column_high_bits, n, column_high, min_difference);
  AccumulateBits(in, column_first + 2 * column_high_bits, column_bits - column_high_bits, n,
                 column_low, min_difference);
  AccumulateBits(in, row_first, row_high_bits, n, row_high, min_difference);
  AccumulateBits(in, row_first + 2 * row_high_bits, row_bits - row_high_bits, n, row_low,
                 min_difference);

  const int column_low_bits = column_bits - column_high_bits;
  const int row_low_bits = row_bits - row_high_bits;
  std::size_t count = 0;
  for (int i = 0; i < n; ++i) {
    std::uint16_t c =
        static_cast<std::uint16_t>((column_high[i] << column_low_bits) | column_low[i]);
    c ^= c >> 1;
    c ^= c >> 2;
    c ^= c >> 4;
    c ^= c >> 8;
    std::uint16_t r = static_cast<std::uint16_t>((row_high[i] << row_low_bits) | row_low[i]);
    r ^= r >> 1;
    r ^= r >> 2;
    r ^= r >> 4;
    r ^= r >> 8;
    const std::uint8_t ok = valid[i] &
                            static_cast<std::uint8_t>(min_difference[i] >= min_bit_contrast) &
                            static_cast<std::uint8_t>(c < projector_width) &
                            static_cast<std::uint8_t>(r < projector_height);
    const std::uint16_t mask = static_cast<std::uint16_t>(-static_cast<int>(ok));
    column[i] = c & mask;
    row[i] = r & mask;
    valid[i] = ok;
    count += ok;
  }
  return count;
}

void Require(bool ok, const std::string& what, const char* who = "GrayCodeDecoder") {
  if (!ok) throw std::invalid_argument(std::string(who) + ": " + what);
}

// Checks that `images` is a capture of `patterns` (count, data, sizes, strides) and returns
// whether every image is contiguous (stride == width).
bool CheckCapture(const PatternSequence& patterns, const std::vector<ImageView>& images,
                  const char* who) {
  const int num_images = patterns.num_images();
  Require(static_cast<int>(images.size()) == num_images,
          "expected " + std::to_string(num_images) + " images (white, black, " +
              std::to_string(patterns.column_bits()) + " column and " +
              std::to_string(patterns.row_bits()) + " row bit pairs), got " +
              std::to_string(images.size()),
          who);
  const int width = images[0].width;
  const int height = images[0].height;
  bool contiguous = true;
  for (int i = 0; i < num_images; ++i) {
    const ImageView& image = images[i];
    const std::string name = "image " + std::to_string(i);
    Require(image.data != nullptr, name + " has no data", who);
    Require(
        image.width > 0 && image.height > 0,
        name + " has size " + std::to_string(image.width) + " x " + std::to_string(image.height),
        who);
    Require(image.width == width && image.height == height,
            name + " is " + std::to_string(image.width) + " x " + std::to_string(image.height) +
                " but image 0 is " + std::to_string(width) + " x " + std::to_string(height),
            who);
    Require(image.stride_bytes >= image.width,
            name + " has stride " + std::to_string(image.stride_bytes) + " below its width " +
                std::to_string(image.width),
            who);
    contiguous = contiguous && image.stride_bytes == image.width;
  }
  return contiguous;
}

}  // namespace

GrayCodeDecoder::GrayCodeDecoder(const PatternSequence& patterns, const DecoderOptions& options)
    : patterns_(patterns), options_(options) {
  Require(options.min_contrast >= 0 && options.min_contrast <= 255,
          "options.min_contrast must be in [0, 255], got " + std::to_string(options.min_contrast));
  Require(options.min_bit_contrast >= 0 && options.min_bit_contrast <= 255,
          "options.min_bit_contrast must be in [0, 255], got " +
              std::to_string(options.min_bit_contrast));
  Require(options.num_threads >= 0,
          "options.num_threads must not be negative, got " + std::to_string(options.num_threads));
  pool_ = std::make_unique<BandPool>(options.num_threads);
}

GrayCodeDecoder::~GrayCodeDecoder() = default;

CorrespondenceMap GrayCodeDecoder::Decode(const std::vector<ImageView>& images) const {
  CorrespondenceMap map;
  Decode(images, &map);
  return map;
}

void GrayCodeDecoder::Decode(const std::vector<ImageView>& images, CorrespondenceMap* map) const {
  Require(map != nullptr, "output map is null");
  const int num_images = patterns_.num_images();
  const bool contiguous = CheckCapture(patterns_, images, "GrayCodeDecoder");
  const int width = images[0].width;
  const int height = images[0].height;

  const std::size_t num_pixels = static_cast<std::size_t>(width) * height;
  map->width = width;
  map->height = height;
  map->column.resize(num_pixels);
  map->row.resize(num_pixels);
  map->valid.resize(num_pixels);
  map->column_subpixel.clear();
  map->row_subpixel.clear();

  const int rows_per_band = std::max(1, kPixelsPerBand / width);
  const int num_bands = (height + rows_per_band - 1) / rows_per_band;
  std::atomic<std::size_t> num_valid{0};
  const int column_bits = patterns_.column_bits();
  const int row_bits = patterns_.row_bits();
  const auto min_contrast = static_cast<std::uint8_t>(options_.min_contrast);
  const auto min_bit_contrast = static_cast<std::uint8_t>(options_.min_bit_contrast);
  const auto projector_width =
      static_cast<std::uint16_t>(std::min(patterns_.projector_width(), 65535));
  const auto projector_height =
      static_cast<std::uint16_t>(std::min(patterns_.projector_height(), 65535));

  pool_->Run(num_bands, [&](int band) {
    const int y0 = band * rows_per_band;
    const int y1 = std::min(height, y0 + rows_per_band);
    std::size_t count = 0;
    // Contiguous images: the band is one span; otherwise one span per row.
    const int span_rows = contiguous ? y1 - y0 : 1;
    for (int y = y0; y < y1; y += span_rows) {
      SpanInputs in;
      for (int i = 0; i < num_images; ++i) in.src[i] = images[i].row(y);
      const std::size_t offset = static_cast<std::size_t>(y) * width;
      count +=
          DecodeSpan(in, span_rows * width, column_bits, row_bits, min_contrast, min_bit_contrast,
                     projector_width, projector_height, map->column.data() + offset,
                     map->row.data() + offset, map->valid.data() + offset);
    }
    num_valid.fetch_add(count, std::memory_order_relaxed);
  });
  map->num_valid = num_valid.load();
}

namespace {

constexpr int kRefineRowsPerBand = 16;
// Camera columns whose rows are refined together: the strip is scanned row by row (row-major
// reads of the map and the captures), with one line scan per column.
constexpr int kRefineColumnsPerStrip = 64;

// Where a line of pixels (a camera row or column) changes: after pixel `boundary` either
// the code steps by one (a knot: projector coordinate `value` = c + 0.5 is seen at sub-pixel
// position `t` along the line, and the next valid pixel is `next`, past a short gap of
// invalid pixels if there is one) or the line breaks (a long stretch of invalid pixels
// begins or ends, or the code jumps by more than one).
struct LineEvent {
  int boundary;
  int next;
  bool knot;
  float t;
  float value;
};

inline int LowestSetBit(unsigned value) {
#if defined(__GNUC__)
  return __builtin_ctz(value);
#else
  int bit = 0;
  while (!(value & 1u)) {
    value >>= 1;
    ++bit;
  }
  return bit;
#endif
}

// Asks for the cache line at `address` ahead of its use. The line scans read the Gray-code
// captures only where a stripe edge is (irregularly, so the hardware prefetchers miss most of
// it); the finest bits have edges nearly everywhere, so their lines ahead are requested.
inline void Prefetch(const void* address) {
#if defined(__GNUC__)
  __builtin_prefetch(address);
#else
  (void)address;
#endif
}

// Bits (from the least significant) whose lines the scans prefetch.
constexpr int kPrefetchBits = 6;
// How far ahead: bytes along a camera row, rows down a strip.
constexpr int kPrefetchAheadBytes = 256;
constexpr int kPrefetchAheadRows = 6;

// One line of pixels (a camera row or a camera column) in the map: pixel i's code, valid
// flag and output coordinate are at element i * step.
struct LineView {
  const std::uint16_t* code;
  const std::uint8_t* valid;
  float* out;
  std::ptrdiff_t step;
};

// Writes the continuous coordinate of the pixels of one run, (before.boundary, e.boundary]
// (from pixel 0 without `before`): linear between the knots around the run, extrapolated
// with the neighbouring run's slope (from `before2` and `before`, or `e` and `after`) where
// the run has a knot on one side only, clamped to its code +- 0.5; NaN for invalid pixels and
// runs that cannot be refined. Calls unrefined(i) for every valid pixel i left NaN.
template <typename Unrefined>
inline void FinishRun(const LineEvent* before2, const LineEvent* before, const LineEvent& e,
                      const LineEvent* after, const LineView& line, const Unrefined& unrefined) {
  const float kNaN = std::numeric_limits<float>::quiet_NaN();
  const std::ptrdiff_t step = line.step;
  const int first = before != nullptr ? before->boundary + 1 : 0;
  const int first_valid = before != nullptr ? before->next : 0;
  const int last = e.boundary;
  bool ok = false;
  float t0 = 0.0f;
  float v0 = 0.0f;
  float slope = 0.0f;
  float c = 0.0f;
  // A run is valid if its first valid pixel (before.next) is; it may contain bridged gaps.
  if (first_valid <= last && line.valid[first_valid * step]) {
    c = line.code[first_valid * step];
    const bool left = before != nullptr && before->knot;
    const bool right = e.knot;
    // Value v0 at position t0 and slope per pixel, from two knots.
    const auto from_knots = [&](const LineEvent& a, const LineEvent& b, const LineEvent& anchor) {
      const float dt = b.t - a.t;
      if (!(dt > 1e-3f) || a.value == b.value) return false;
      slope = (b.value - a.value) / dt;
      t0 = anchor.t;
      v0 = anchor.value;
      return true;
    };
    if (left && right) {
      ok = from_knots(*before, e, *before);
    } else if (left && before2 != nullptr && before2->knot) {
      // Extrapolate past the last knot with the neighbouring run's slope; moving into the
      // run must move towards its code.
      ok = from_knots(*before2, *before, *before) && (slope > 0.0f) == (c > v0);
    } else if (right && after != nullptr && after->knot) {
      // Likewise before the first knot, moving backwards.
      ok = from_knots(e, *after, e) && (slope < 0.0f) == (c > v0);
    }
  }
  if (!ok) {
    for (int i = first; i <= last; ++i) {
      line.out[i * step] = kNaN;
      if (line.valid[i * step]) unrefined(i);
    }
    return;
  }
  const float low = c - 0.5f;
  const float high = c + 0.5f;
  for (int i = first; i <= last; ++i) {
    const float v = v0 + slope * (static_cast<float>(i) - t0);
    line.out[i * step] = !line.valid[i * step] ? kNaN : (v < low ? low : (v > high ? high : v));
  }
}

// The refinement of one line as a single scan: fed its valid pixels in order
// (ScanValidPixel) and closed with FinishLine. Up to max_gap invalid pixels between two
// valid ones are bridged (pixels straddling a stripe edge often fail the decoder's
// bit-contrast test); longer stretches and jumps of more than one code break the line. Each
// run is written (FinishRun) as soon as the event after its closing event is known, so only
// the last three events are kept and a scan that visits the lines of a strip row by row
// writes recent rows only.
struct LineScan {
  int last = -1;                    // The last valid pixel so far, -1 before the first.
  int last_code = 0;                // Its code.
  int count = 0;                    // Events so far.
  std::array<LineEvent, 3> recent;  // Events count - 3, count - 2, count - 1.
};

template <typename Unrefined>
inline void PushEvent(const LineEvent& event, const LineView& line, LineScan* scan,
                      const Unrefined& unrefined) {
  const int m = scan->count;
  if (m >= 1) {
    FinishRun(m >= 3 ? &scan->recent[0] : nullptr, m >= 2 ? &scan->recent[1] : nullptr,
              scan->recent[2], &event, line, unrefined);
  }
  scan->recent[0] = scan->recent[1];
  scan->recent[1] = scan->recent[2];
  scan->recent[2] = event;
  scan->count = m + 1;
}

template <typename Unrefined>
inline void PushBreak(int boundary, const LineView& line, LineScan* scan,
                      const Unrefined& unrefined) {
  PushEvent(LineEvent{boundary, boundary + 1, false, 0.0f, 0.0f}, line, scan, unrefined);
}

// Feeds valid pixel p with code `code` into `scan`; returns 1 if that makes a knot.
// diff(i, bit) is pattern - inverse at pixel i of the line for Gray-code bit `bit` of the
// value (0 = least significant); it is read only at the pixels from the previous valid
// pixel to p.
template <typename Diff, typename Unrefined>
inline int ScanValidPixel(int p, int code, int max_gap, const Diff& diff, const LineView& line,
                          LineScan* scan, const Unrefined& unrefined) {
  const int previous = scan->last;
  const int previous_code = scan->last_code;
  scan->last = p;
  scan->last_code = code;
  if (previous < 0) {  // The first valid pixel: a break before it, unless it starts the line.
    if (p > 0) PushBreak(p - 1, line, scan, unrefined);
    return 0;
  }
  const int gap = p - previous - 1;
  if (gap > max_gap) {  // A stretch of invalid pixels that is not bridged.
    PushBreak(previous, line, scan, unrefined);
    PushBreak(p - 1, line, scan, unrefined);
    return 0;
  }
  if (previous_code == code) return 0;  // The run goes on (over the gap, if any).
  if (previous_code - code != 1 && code - previous_code != 1) {
    PushBreak(previous, line, scan, unrefined);
    if (gap > 0) PushBreak(p - 1, line, scan, unrefined);
    return 0;
  }
  // c and c + 1 differ in exactly one Gray-code bit: the lowest set bit of c + 1. Its
  // (pattern - inverse) changes sign between the two pixels; the edge is where it crosses
  // zero (the middle of the first and last crossing if noise makes several in a gap).
  const int bit = LowestSetBit(static_cast<unsigned>(std::max(previous_code, code)));
  const LineEvent knot{previous, p, true, 0.0f, 0.5f * static_cast<float>(previous_code + code)};
  if (gap == 0) {  // Neighbours (most knots): one crossing or none, chosen without a branch.
    const int d0 = diff(previous, bit);
    const int d1 = diff(p, bit);
    const float denominator = static_cast<float>(d0 - d1);  // Not 0 if the sign changes.
    const float fraction = static_cast<float>(d0) / (denominator != 0.0f ? denominator : 1.0f);
    const float crossing = static_cast<float>(previous) + std::min(1.0f, std::max(0.0f, fraction));
    const float middle = 0.5f * static_cast<float>(previous + p);
    PushEvent(LineEvent{previous, p, true, (d0 > 0) != (d1 > 0) ? crossing : middle, knot.value},
              line, scan, unrefined);
    return 1;
  }
  float first = -1.0f;
  float last = -1.0f;
  int d0 = diff(previous, bit);
  for (int m = previous; m < p; ++m) {
    const int d1 = diff(m + 1, bit);
    if ((d0 > 0) != (d1 > 0)) {
      const float denominator = static_cast<float>(d0 - d1);
      const float fraction = denominator != 0.0f ? static_cast<float>(d0) / denominator : 0.5f;
      const float t = static_cast<float>(m) + std::min(1.0f, std::max(0.0f, fraction));
      if (first < 0.0f) first = t;
      last = t;
    }
    d0 = d1;
  }
  // Without a sign change (captures other than the decoded ones) the gap's middle.
  const float t = first < 0.0f ? 0.5f * static_cast<float>(previous + p) : 0.5f * (first + last);
  PushEvent(LineEvent{previous, p, true, t, knot.value}, line, scan, unrefined);
  return 1;
}

// Closes the scan of a line of n pixels: the last events, then the last run.
template <typename Unrefined>
inline void FinishLine(int n, const LineView& line, LineScan* scan, const Unrefined& unrefined) {
  if (scan->last >= 0 && scan->last < n - 1) PushBreak(scan->last, line, scan, unrefined);
  PushBreak(n - 1, line, scan, unrefined);
  const int m = scan->count;
  FinishRun(m >= 3 ? &scan->recent[0] : nullptr, m >= 2 ? &scan->recent[1] : nullptr,
            scan->recent[2], nullptr, line, unrefined);
}

// The coordinate of a valid pixel that its line could not refine, from the refined pixels up
// to two pixels away across the line (value[-d * step], value[d * step]; `before` and
// `after` pixels exist on each side) whose codes differ from its own by at most one:
// interpolated between the nearest on each side, or the nearest on one side. NaN if there
// are none or the result is inconsistent with the pixel's code.
inline float FillAcross(const float* value, const std::uint16_t* code, std::ptrdiff_t step,
                        int before, int after) {
  const int c = *code;
  float v_before = 0.0f;
  float v_after = 0.0f;
  int d_before = 0;
  int d_after = 0;
  for (int d = 1; d <= std::min(2, before) && d_before == 0; ++d) {
    const float v = value[-d * step];
    if (!std::isnan(v) && std::abs(code[-d * step] - c) <= 1) {
      v_before = v;
      d_before = d;
    }
  }
  for (int d = 1; d <= std::min(2, after) && d_after == 0; ++d) {
    const float v = value[d * step];
    if (!std::isnan(v) && std::abs(code[d * step] - c) <= 1) {
      v_after = v;
      d_after = d;
    }
  }
  float v;
  if (d_before > 0 && d_after > 0) {
    v = (v_before * d_after + v_after * d_before) / static_cast<float>(d_before + d_after);
  } else if (d_before > 0) {
    v = v_before;
  } else if (d_after > 0) {
    v = v_after;
  } else {
    return std::numeric_limits<float>::quiet_NaN();
  }
  const float cf = static_cast<float>(c);
  if (!(std::abs(v - cf) <= 0.75f)) return std::numeric_limits<float>::quiet_NaN();
  return std::min(cf + 0.5f, std::max(cf - 0.5f, v));
}

// out[i] = code[i] where valid, NaN elsewhere (the integer rows when rows are not refined).
PICKING_DECODER_CLONES void IntegerCoordinates(int n, const std::uint16_t* __restrict code,
                                               const std::uint8_t* __restrict valid,
                                               float* __restrict out) {
  // The NaN is or-ed in as bits: a select between floats is not vectorised here.
  constexpr std::uint32_t kNaNBits = 0x7fc00000u;
  for (int i = 0; i < n; ++i) {
    const float value = static_cast<float>(code[i]);
    std::uint32_t bits;
    std::memcpy(&bits, &value, sizeof(float));
    const std::uint32_t invalid = 0u - static_cast<std::uint32_t>(valid[i] == 0);
    bits = (bits & ~invalid) | (kNaNBits & invalid);
    std::memcpy(&out[i], &bits, sizeof(float));
  }
}

// Valid pixels that a line left NaN, by global pixel index, and what filling across the
// line gives them.
struct Candidates {
  std::vector<std::size_t> pixels;
  std::vector<float> fills;
};

// The name that SubpixelRefiner's errors begin with.
const char* const kRefinerName = "SubpixelRefiner";

// Bands of kRefineRowsPerBand camera rows covering `height` rows.
inline int NumRefineBands(int height) {
  return (height + kRefineRowsPerBand - 1) / kRefineRowsPerBand;
}

// Validation stage, second half: every valid pixel's column (row) is inside the projector.
// The bands are checked in parallel; only if one fails is the map searched for the first
// offending pixel, to name it.
void CheckInsideProjector(const PatternSequence& patterns, const CorrespondenceMap& map,
                          BandPool* pool) {
  const int width = map.width;
  const int height = map.height;
  const std::size_t n = static_cast<std::size_t>(width) * height;
  const int projector_width = patterns.projector_width();
  const int projector_height = patterns.projector_height();
  const int num_bands = NumRefineBands(height);
  const std::uint16_t* column = map.column.data();
  const std::uint16_t* row = map.row.data();
  const std::uint8_t* valid = map.valid.data();
  std::atomic<int> outside{0};
  pool->Run(num_bands, [&](int band) {
    const std::size_t i0 = static_cast<std::size_t>(band) * kRefineRowsPerBand * width;
    const std::size_t i1 =
        static_cast<std::size_t>(std::min(height, (band + 1) * kRefineRowsPerBand)) * width;
    int local = 0;
    for (std::size_t i = i0; i < i1; ++i) {
      local |= valid[i] & ((column[i] >= projector_width) | (row[i] >= projector_height));
    }
    if (local) outside.store(1, std::memory_order_relaxed);
  });
  if (outside.load()) {
    for (std::size_t i = 0; i < n; ++i) {
      Require(!valid[i] || (column[i] < projector_width && row[i] < projector_height),
              "valid pixel " + std::to_string(i) + " has correspondence (" +
                  std::to_string(column[i]) + ", " + std::to_string(row[i]) + ") outside the " +
                  std::to_string(projector_width) + " x " + std::to_string(projector_height) +
                  " projector",
              kRefinerName);
    }
  }
}

// Validation stage: the map, the captures and the map's codes, before anything is written.
void CheckRefineInputs(const PatternSequence& patterns, const std::vector<ImageView>& images,
                       const CorrespondenceMap* map, BandPool* pool) {
  Require(map != nullptr, "map is null", kRefinerName);
  CheckCapture(patterns, images, kRefinerName);
  const int width = images[0].width;
  const int height = images[0].height;
  Require(map->width == width && map->height == height,
          "map is " + std::to_string(map->width) + " x " + std::to_string(map->height) +
              " but the images are " + std::to_string(width) + " x " + std::to_string(height),
          kRefinerName);
  const std::size_t n = static_cast<std::size_t>(width) * height;
  Require(map->column.size() == n && map->row.size() == n && map->valid.size() == n,
          "map buffers are not width * height = " + std::to_string(n) + " long", kRefinerName);
  CheckInsideProjector(patterns, *map, pool);
}

// What the stages of the refinement share: sizes, options, the map's buffers and the
// captures of every Gray-code bit.
struct RefineContext {
  int width = 0;
  int height = 0;
  int num_bands = 0;
  int num_strips = 0;
  int column_bits = 0;
  int row_bits = 0;
  int max_gap = 0;
  bool refine_rows = false;
  const std::uint16_t* column_code = nullptr;
  const std::uint16_t* row_code = nullptr;
  const std::uint8_t* valid = nullptr;
  float* column_subpixel = nullptr;
  float* row_subpixel = nullptr;
  // Pattern and inverse image of each bit, indexed by the bit's place in the value (0 = LSB).
  std::array<const ImageView*, PatternSequence::kMaxBits> column_pattern{};
  std::array<const ImageView*, PatternSequence::kMaxBits> column_inverse{};
  std::array<const ImageView*, PatternSequence::kMaxBits> row_pattern{};
  std::array<const ImageView*, PatternSequence::kMaxBits> row_inverse{};
};

// Setup stage: sizes the sub-pixel maps and gathers the bands, strips, buffers and the
// captures of each bit.
RefineContext PrepareRefinement(const PatternSequence& patterns, const RefinementOptions& options,
                                const std::vector<ImageView>& images, CorrespondenceMap* map) {
  RefineContext ctx;
  ctx.width = images[0].width;
  ctx.height = images[0].height;
  const std::size_t n = static_cast<std::size_t>(ctx.width) * ctx.height;
  map->column_subpixel.resize(n);
  map->row_subpixel.resize(n);
  ctx.column_bits = patterns.column_bits();
  ctx.row_bits = patterns.row_bits();
  for (int b = 0; b < ctx.column_bits; ++b) {
    ctx.column_pattern[ctx.column_bits - 1 - b] = &images[patterns.ColumnImageIndex(b, false)];
    ctx.column_inverse[ctx.column_bits - 1 - b] = &images[patterns.ColumnImageIndex(b, true)];
  }
  for (int b = 0; b < ctx.row_bits; ++b) {
    ctx.row_pattern[ctx.row_bits - 1 - b] = &images[patterns.RowImageIndex(b, false)];
    ctx.row_inverse[ctx.row_bits - 1 - b] = &images[patterns.RowImageIndex(b, true)];
  }
  ctx.max_gap = options.max_gap_px;
  ctx.refine_rows = options.refine_rows;
  ctx.num_bands = NumRefineBands(ctx.height);
  ctx.num_strips =
      ctx.refine_rows ? (ctx.width + kRefineColumnsPerStrip - 1) / kRefineColumnsPerStrip : 0;
  ctx.column_code = map->column.data();
  ctx.row_code = map->row.data();
  ctx.valid = map->valid.data();
  ctx.column_subpixel = map->column_subpixel.data();
  ctx.row_subpixel = map->row_subpixel.data();
  return ctx;
}

// What the line scans count, added to by every task.
struct ScanCounters {
  std::atomic<std::size_t> column_knots{0};
  std::atomic<std::size_t> row_knots{0};
  std::atomic<std::size_t> total_valid{0};
};

// Column kernel: refines the columns of one band of camera rows, along the rows.
void RefineBandColumns(const RefineContext& ctx, int band, Candidates* band_candidates,
                       ScanCounters* counters) {
  const int width = ctx.width;
  const int height = ctx.height;
  const int column_bits = ctx.column_bits;
  const int max_gap = ctx.max_gap;
  const bool refine_rows = ctx.refine_rows;
  const auto& column_pattern = ctx.column_pattern;
  const auto& column_inverse = ctx.column_inverse;
  const std::uint16_t* column_code = ctx.column_code;
  const std::uint16_t* row_code = ctx.row_code;
  const std::uint8_t* valid = ctx.valid;
  float* column_subpixel = ctx.column_subpixel;
  float* row_subpixel = ctx.row_subpixel;
  std::vector<std::size_t>& candidates = band_candidates->pixels;
  std::size_t knots = 0;
  std::size_t count = 0;
  const int y1 = std::min(height, (band + 1) * kRefineRowsPerBand);
  for (int y = band * kRefineRowsPerBand; y < y1; ++y) {
    const std::size_t offset = static_cast<std::size_t>(y) * width;
    std::array<const std::uint8_t*, PatternSequence::kMaxBits> pattern{};
    std::array<const std::uint8_t*, PatternSequence::kMaxBits> inverse{};
    for (int b = 0; b < column_bits; ++b) {
      pattern[b] = column_pattern[b]->row(y);
      inverse[b] = column_inverse[b]->row(y);
    }
    const auto diff = [&](int x, int bit) {
      return static_cast<int>(pattern[bit][x]) - static_cast<int>(inverse[bit][x]);
    };
    const LineView line{column_code + offset, valid + offset, column_subpixel + offset, 1};
    const auto unrefined = [&](int x) { candidates.push_back(offset + x); };
    LineScan scan;
    // Along a row every bit has edges every 2^(bit + 1) projector columns: all are read.
    const int prefetch_bits = column_bits;
    for (int x = 0; x < width; ++x) {
      if ((x & 63) == 0) {
        for (int b = 0; b < prefetch_bits; ++b) {
          Prefetch(pattern[b] + x + kPrefetchAheadBytes);
          Prefetch(inverse[b] + x + kPrefetchAheadBytes);
        }
      }
      if (!line.valid[x]) continue;
      ++count;
      knots += ScanValidPixel(x, line.code[x], max_gap, diff, line, &scan, unrefined);
    }
    FinishLine(width, line, &scan, unrefined);
    if (!refine_rows) {
      IntegerCoordinates(width, row_code + offset, valid + offset, row_subpixel + offset);
    }
  }
  counters->column_knots.fetch_add(knots, std::memory_order_relaxed);
  counters->total_valid.fetch_add(count, std::memory_order_relaxed);
}

// Row kernel: refines the rows of one strip of camera columns, along the columns.
void RefineStripRows(const RefineContext& ctx, int strip, Candidates* strip_candidates,
                     ScanCounters* counters) {
  const int width = ctx.width;
  const int height = ctx.height;
  const int row_bits = ctx.row_bits;
  const int max_gap = ctx.max_gap;
  const auto& row_pattern = ctx.row_pattern;
  const auto& row_inverse = ctx.row_inverse;
  const std::uint16_t* row_code = ctx.row_code;
  const std::uint8_t* valid = ctx.valid;
  float* row_subpixel = ctx.row_subpixel;
  // A strip of columns, scanned row by row with one line scan per column: the map and the
  // captures are read row-major, and runs are written within a few rows of the scan.
  const int x0 = strip * kRefineColumnsPerStrip;
  const int x1 = std::min(width, x0 + kRefineColumnsPerStrip);
  const int strip_width = x1 - x0;
  std::vector<std::size_t>& candidates = strip_candidates->pixels;
  std::array<LineScan, kRefineColumnsPerStrip> scans{};
  std::size_t knots = 0;
  std::array<const std::uint8_t*, PatternSequence::kMaxBits> pattern{};
  std::array<const std::uint8_t*, PatternSequence::kMaxBits> inverse{};
  std::array<std::ptrdiff_t, PatternSequence::kMaxBits> pattern_stride{};
  std::array<std::ptrdiff_t, PatternSequence::kMaxBits> inverse_stride{};
  for (int b = 0; b < row_bits; ++b) {
    pattern[b] = row_pattern[b]->data + x0;
    inverse[b] = row_inverse[b]->data + x0;
    pattern_stride[b] = row_pattern[b]->stride_bytes;
    inverse_stride[b] = row_inverse[b]->stride_bytes;
  }
  const auto column_line = [&](int j) {
    return LineView{row_code + x0 + j, valid + x0 + j, row_subpixel + x0 + j, width};
  };
  const int prefetch_bits = std::min(kPrefetchBits, row_bits);
  for (int y = 0; y < height; ++y) {
    if (y + kPrefetchAheadRows < height) {
      for (int b = 0; b < prefetch_bits; ++b) {
        const std::uint8_t* p = pattern[b] + (y + kPrefetchAheadRows) * pattern_stride[b];
        const std::uint8_t* q = inverse[b] + (y + kPrefetchAheadRows) * inverse_stride[b];
        Prefetch(p);
        Prefetch(p + strip_width - 1);
        Prefetch(q);
        Prefetch(q + strip_width - 1);
      }
    }
    const std::size_t offset = static_cast<std::size_t>(y) * width + x0;
    const std::uint16_t* code = row_code + offset;
    const std::uint8_t* line_valid = valid + offset;
    for (int j = 0; j < strip_width; ++j) {
      if (!line_valid[j]) continue;
      const auto diff = [&](int yy, int bit) {
        return static_cast<int>(pattern[bit][yy * pattern_stride[bit] + j]) -
               static_cast<int>(inverse[bit][yy * inverse_stride[bit] + j]);
      };
      const auto unrefined = [&](int yy) {
        candidates.push_back(static_cast<std::size_t>(yy) * width + x0 + j);
      };
      knots += ScanValidPixel(y, code[j], max_gap, diff, column_line(j), &scans[j], unrefined);
    }
  }
  for (int j = 0; j < strip_width; ++j) {
    FinishLine(height, column_line(j), &scans[j], [&](int yy) {
      candidates.push_back(static_cast<std::size_t>(yy) * width + x0 + j);
    });
  }
  counters->row_knots.fetch_add(knots, std::memory_order_relaxed);
}

// Line-scan stage: runs the column kernel on every band and the row kernel on every strip.
void ScanLines(const RefineContext& ctx, BandPool* pool, std::vector<Candidates>* column_candidates,
               std::vector<Candidates>* row_candidates, ScanCounters* counters) {
  const int num_strips = ctx.num_strips;
  // Rows along camera columns (tasks [0, num_strips), the larger ones, first so that the
  // bands even out the threads' load at the end) and columns along camera rows (tasks
  // [num_strips, num_strips + num_bands)): independent, so one job.
  pool->Run(ctx.num_bands + num_strips, [&](int task) {
    if (task >= num_strips) {
      const int band = task - num_strips;
      RefineBandColumns(ctx, band, &(*column_candidates)[band], counters);
      return;
    }
    RefineStripRows(ctx, task, &(*row_candidates)[task], counters);
  });
}

// Fill stage, first half: what the pixels across the line give the candidates: columns from
// the pixels above and below, rows from the pixels left and right, all decided before any is
// written, so that fills do not feed each other.
void ComputeFills(const RefineContext& ctx, BandPool* pool,
                  std::vector<Candidates>* column_candidates,
                  std::vector<Candidates>* row_candidates) {
  const int width = ctx.width;
  const int height = ctx.height;
  const int num_bands = ctx.num_bands;
  const std::uint16_t* column_code = ctx.column_code;
  const std::uint16_t* row_code = ctx.row_code;
  const float* column_subpixel = ctx.column_subpixel;
  const float* row_subpixel = ctx.row_subpixel;
  pool->Run(num_bands + ctx.num_strips, [&](int task) {
    if (task < num_bands) {
      Candidates& c = (*column_candidates)[task];
      c.fills.resize(c.pixels.size());
      for (std::size_t k = 0; k < c.pixels.size(); ++k) {
        const std::size_t i = c.pixels[k];
        const int y = static_cast<int>(i / width);
        c.fills[k] = FillAcross(column_subpixel + i, column_code + i, width, y, height - 1 - y);
      }
    } else {
      Candidates& c = (*row_candidates)[task - num_bands];
      c.fills.resize(c.pixels.size());
      for (std::size_t k = 0; k < c.pixels.size(); ++k) {
        const std::size_t i = c.pixels[k];
        const int x = static_cast<int>(i % width);
        c.fills[k] = FillAcross(row_subpixel + i, row_code + i, 1, x, width - 1 - x);
      }
    }
  });
}

// Fill stage, second half: writes the fills found; returns how many.
std::size_t ApplyFills(const RefineContext& ctx, const std::vector<Candidates>& column_candidates,
                       const std::vector<Candidates>& row_candidates) {
  std::size_t filled = 0;
  const auto apply = [&](const std::vector<Candidates>& lists, float* values) {
    for (const Candidates& c : lists) {
      for (std::size_t k = 0; k < c.pixels.size(); ++k) {
        if (std::isnan(c.fills[k])) continue;
        values[c.pixels[k]] = c.fills[k];
        ++filled;
      }
    }
  };
  apply(column_candidates, ctx.column_subpixel);
  apply(row_candidates, ctx.row_subpixel);
  return filled;
}

// Settle stage: rejects (or keeps at their integer codes) the candidates still without a
// coordinate; returns how many there were.
std::size_t SettleUnrefined(const RefineContext& ctx, bool reject,
                            const std::vector<Candidates>& column_candidates,
                            const std::vector<Candidates>& row_candidates, CorrespondenceMap* map) {
  float* column_subpixel = ctx.column_subpixel;
  float* row_subpixel = ctx.row_subpixel;
  // The candidates still without a coordinate cannot be refined (a pixel may be a candidate
  // of both lists; it is handled at its first appearance).
  const float kNaN = std::numeric_limits<float>::quiet_NaN();
  std::size_t unrefined = 0;
  const auto settle = [&](const std::vector<Candidates>& lists) {
    for (const Candidates& c : lists) {
      for (const std::size_t i : c.pixels) {
        if (!map->valid[i]) continue;
        const bool column_ok = !std::isnan(column_subpixel[i]);
        const bool row_ok = !std::isnan(row_subpixel[i]);
        if (column_ok && row_ok) continue;
        ++unrefined;
        if (reject) {
          map->valid[i] = 0;
          map->column[i] = 0;
          map->row[i] = 0;
          column_subpixel[i] = kNaN;
          row_subpixel[i] = kNaN;
        } else {
          if (!column_ok) column_subpixel[i] = map->column[i];
          if (!row_ok) row_subpixel[i] = map->row[i];
        }
      }
    }
  };
  settle(column_candidates);
  settle(row_candidates);
  return unrefined;
}

// Result stage: the statistics, and the map's valid count after rejections.
RefinementResult GatherResult(const ScanCounters& counters, std::size_t filled,
                              std::size_t unrefined, bool reject, CorrespondenceMap* map) {
  RefinementResult result;
  result.num_refined = counters.total_valid.load() - unrefined;
  result.num_column_transitions = counters.column_knots.load();
  result.num_row_transitions = counters.row_knots.load();
  result.num_filled_across = filled;
  if (reject) {
    result.num_rejected = unrefined;
    map->num_valid = result.num_refined;
  } else {
    result.num_kept_integer = unrefined;
  }
  return result;
}

}  // namespace

SubpixelRefiner::SubpixelRefiner(const PatternSequence& patterns, const RefinementOptions& options)
    : patterns_(patterns), options_(options) {
  Require(options.num_threads >= 0,
          "options.num_threads must not be negative, got " + std::to_string(options.num_threads),
          "SubpixelRefiner");
  Require(options.max_gap_px >= 0 && options.max_gap_px <= 16,
          "options.max_gap_px must be in [0, 16], got " + std::to_string(options.max_gap_px),
          "SubpixelRefiner");
  pool_ = std::make_unique<BandPool>(options.num_threads);
}

SubpixelRefiner::~SubpixelRefiner() = default;

RefinementResult SubpixelRefiner::Refine(const std::vector<ImageView>& images,
                                         CorrespondenceMap* map) const {
  CheckRefineInputs(patterns_, images, map, pool_.get());
  const RefineContext ctx = PrepareRefinement(patterns_, options_, images, map);
  // Valid pixels left NaN: columns per band of rows, rows per strip of columns.
  std::vector<Candidates> column_candidates(ctx.num_bands);
  std::vector<Candidates> row_candidates(ctx.num_strips);
  ScanCounters counters;
  ScanLines(ctx, pool_.get(), &column_candidates, &row_candidates, &counters);
  ComputeFills(ctx, pool_.get(), &column_candidates, &row_candidates);
  const std::size_t filled = ApplyFills(ctx, column_candidates, row_candidates);
  const bool reject = options_.reject_unrefined;
  const std::size_t unrefined =
      SettleUnrefined(ctx, reject, column_candidates, row_candidates, map);
  return GatherResult(counters, filled, unrefined, reject, map);
}

}  // namespace picking::scanner
