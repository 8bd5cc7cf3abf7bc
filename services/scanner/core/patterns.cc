#include "services/scanner/core/patterns.h"

#include <stdexcept>
#include <string>

namespace picking::scanner {
namespace {

int BitsFor(int count) {
  int bits = 0;
  while ((1 << bits) < count) ++bits;
  return bits;
}

int ResolveBits(const char* what, int size, int bits) {
  if (bits == 0) bits = BitsFor(size);
  if (bits < 0 || bits > PatternSequence::kMaxBits) {
    throw std::invalid_argument(std::string("PatternSequence: ") + what + " bits " +
                                std::to_string(bits) + " outside [1, " +
                                std::to_string(PatternSequence::kMaxBits) + "]");
  }
  if ((1 << bits) < size) {
    throw std::invalid_argument(std::string("PatternSequence: ") + std::to_string(bits) + " " +
                                what + " bits cannot number " + std::to_string(size) + " " + what +
                                "s");
  }
  return bits;
}

}  // namespace

PatternSequence::PatternSequence(int projector_width, int projector_height, int column_bits,
                                 int row_bits)
    : projector_width_(projector_width), projector_height_(projector_height) {
  if (projector_width < 2 || projector_height < 2) {
    throw std::invalid_argument("PatternSequence: projector size " +
                                std::to_string(projector_width) + " x " +
                                std::to_string(projector_height) + " must be at least 2 x 2");
  }
  column_bits_ = ResolveBits("column", projector_width, column_bits);
  row_bits_ = ResolveBits("row", projector_height, row_bits);
}

int PatternSequence::ColumnImageIndex(int bit, bool inverse) const {
  if (bit < 0 || bit >= column_bits_) {
    throw std::out_of_range("PatternSequence: column bit " + std::to_string(bit) + " outside [0, " +
                            std::to_string(column_bits_) + ")");
  }
  return 2 + 2 * bit + (inverse ? 1 : 0);
}

int PatternSequence::RowImageIndex(int bit, bool inverse) const {
  if (bit < 0 || bit >= row_bits_) {
    throw std::out_of_range("PatternSequence: row bit " + std::to_string(bit) + " outside [0, " +
                            std::to_string(row_bits_) + ")");
  }
  return 2 + 2 * column_bits_ + 2 * bit + (inverse ? 1 : 0);
}

PatternImage PatternSequence::Describe(int index) const {
  if (index < 0 || index >= num_images()) {
    throw std::out_of_range("PatternSequence: image index " + std::to_string(index) +
                            " outside [0, " + std::to_string(num_images()) + ")");
  }
  PatternImage image;
  if (index == kWhiteIndex) {
    image.kind = PatternImage::Kind::kWhite;
  } else if (index == kBlackIndex) {
    image.kind = PatternImage::Kind::kBlack;
  } else if (index < 2 + 2 * column_bits_) {
    image.kind = PatternImage::Kind::kColumnBit;
    image.bit = (index - 2) / 2;
    image.inverse = (index - 2) % 2 == 1;
  } else {
    image.kind = PatternImage::Kind::kRowBit;
    image.bit = (index - 2 - 2 * column_bits_) / 2;
    image.inverse = (index - 2 - 2 * column_bits_) % 2 == 1;
  }
  return image;
}

bool PatternSequence::IsLit(int index, int column, int row) const {
  const PatternImage image = Describe(index);
  if (column < 0 || row < 0 || column >= projector_width_ || row >= projector_height_) {
    return false;
  }
  switch (image.kind) {
    case PatternImage::Kind::kWhite:
      return true;
    case PatternImage::Kind::kBlack:
      return false;
    case PatternImage::Kind::kColumnBit: {
      const bool bit = (GrayEncode(column) >> (column_bits_ - 1 - image.bit)) & 1u;
      return bit != image.inverse;
    }
    case PatternImage::Kind::kRowBit: {
      const bool bit = (GrayEncode(row) >> (row_bits_ - 1 - image.bit)) & 1u;
      return bit != image.inverse;
    }
  }
  return false;
}

std::vector<std::uint8_t> PatternSequence::Render(int index) const {
  const PatternImage image = Describe(index);  // Validates the index.
  std::vector<std::uint8_t> pixels(static_cast<std::size_t>(projector_width_) * projector_height_);
  for (int row = 0; row < projector_height_; ++row) {
    for (int column = 0; column < projector_width_; ++column) {
      bool lit = false;
      switch (image.kind) {
        case PatternImage::Kind::kWhite:
          lit = true;
          break;
        case PatternImage::Kind::kBlack:
          break;
        case PatternImage::Kind::kColumnBit:
          lit = ((GrayEncode(column) >> (column_bits_ - 1 - image.bit)) & 1u) != image.inverse;
          break;
        case PatternImage::Kind::kRowBit:
          lit = ((GrayEncode(row) >> (row_bits_ - 1 - image.bit)) & 1u) != image.inverse;
          break;
      }
      pixels[static_cast<std::size_t>(row) * projector_width_ + column] = lit ? 255 : 0;
    }
  }
  return pixels;
}

}  // namespace picking::scanner
