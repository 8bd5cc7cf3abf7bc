#include "services/scanner/core/decoder.h"

#include "services/scanner/core/band_pool.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <stdexcept>
#include <string>

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

void Require(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("GrayCodeDecoder: " + what);
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
  Require(static_cast<int>(images.size()) == num_images,
          "expected " + std::to_string(num_images) + " images (white, black, " +
              std::to_string(patterns_.column_bits()) + " column and " +
              std::to_string(patterns_.row_bits()) + " row bit pairs), got " +
              std::to_string(images.size()));
  const int width = images[0].width;
  const int height = images[0].height;
  bool contiguous = true;
  for (int i = 0; i < num_images; ++i) {
    const ImageView& image = images[i];
    const std::string name = "image " + std::to_string(i);
    Require(image.data != nullptr, name + " has no data");
    Require(image.width > 0 && image.height > 0, name + " has size " + std::to_string(image.width) +
                                                     " x " + std::to_string(image.height));
    Require(image.width == width && image.height == height,
            name + " is " + std::to_string(image.width) + " x " + std::to_string(image.height) +
                " but image 0 is " + std::to_string(width) + " x " + std::to_string(height));
    Require(image.stride_bytes >= image.width,
            name + " has stride " + std::to_string(image.stride_bytes) + " below its width " +
                std::to_string(image.width));
    contiguous = contiguous && image.stride_bytes == image.width;
  }

  const std::size_t num_pixels = static_cast<std::size_t>(width) * height;
  map->width = width;
  map->height = height;
  map->column.resize(num_pixels);
  map->row.resize(num_pixels);
  map->valid.resize(num_pixels);

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

}  // namespace picking::scanner
