#include "services/scanner/core/decoder.h"

#include "services/scanner/core/band_pool.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <stdexcept>
#include <string>

namespace picking::scanner {
namespace {

// Pixels per band: the band's outputs (5 bytes per pixel) stay in L2 while the 44 input
// images stream through once each.
constexpr int kPixelsPerBand = 16384;

struct SpanInputs {
  std::array<const std::uint8_t*, 2 + 4 * PatternSequence::kMaxBits> src;
};

// Decodes n consecutive pixels. Every loop is branch-free over bytes / 16-bit words so that
// GCC and Clang vectorise it at -O2 -ftree-vectorize / -O3.
std::size_t DecodeSpan(const SpanInputs& in, int n, int column_bits, int row_bits,
                       std::uint8_t min_contrast, std::uint8_t min_bit_contrast,
                       std::uint16_t projector_width, std::uint16_t projector_height,
                       std::uint16_t* __restrict column, std::uint16_t* __restrict row,
                       std::uint8_t* __restrict valid) {
  {
    const std::uint8_t* __restrict white = in.src[0];
    const std::uint8_t* __restrict black = in.src[1];
    for (int i = 0; i < n; ++i) {
      const std::uint8_t w = white[i];
      const std::uint8_t b = black[i];
      const std::uint8_t contrast = static_cast<std::uint8_t>(w > b ? w - b : 0);
      valid[i] = contrast >= min_contrast;
      column[i] = 0;
      row[i] = 0;
    }
  }
  const auto accumulate = [&](int first_image, int bits, std::uint16_t* __restrict code) {
    for (int bit = 0; bit < bits; ++bit) {
      const std::uint8_t* __restrict pattern = in.src[first_image + 2 * bit];
      const std::uint8_t* __restrict inverse = in.src[first_image + 2 * bit + 1];
      for (int i = 0; i < n; ++i) {
        const std::uint8_t p = pattern[i];
        const std::uint8_t q = inverse[i];
        const std::uint8_t hi = p > q ? p : q;
        const std::uint8_t lo = p > q ? q : p;
        const std::uint8_t difference = static_cast<std::uint8_t>(hi - lo);
        valid[i] &= static_cast<std::uint8_t>(difference >= min_bit_contrast);
        code[i] = static_cast<std::uint16_t>((code[i] << 1) | (p > q ? 1 : 0));
      }
    }
  };
  accumulate(2, column_bits, column);
  accumulate(2 + 2 * column_bits, row_bits, row);

  std::size_t count = 0;
  for (int i = 0; i < n; ++i) {
    std::uint16_t c = column[i];
    c ^= c >> 1;
    c ^= c >> 2;
    c ^= c >> 4;
    c ^= c >> 8;
    std::uint16_t r = row[i];
    r ^= r >> 1;
    r ^= r >> 2;
    r ^= r >> 4;
    r ^= r >> 8;
    const std::uint8_t ok = valid[i] & static_cast<std::uint8_t>(c < projector_width) &
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
