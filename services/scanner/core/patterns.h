#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace picking::scanner {

/// Reflected binary Gray code of `value`.
constexpr std::uint32_t GrayEncode(std::uint32_t value) { return value ^ (value >> 1); }

/// Inverse of GrayEncode (prefix XOR from the most significant bit).
constexpr std::uint32_t GrayDecode(std::uint32_t gray) {
  gray ^= gray >> 16;
  gray ^= gray >> 8;
  gray ^= gray >> 4;
  gray ^= gray >> 2;
  gray ^= gray >> 1;
  return gray;
}

/// What one image of the pattern sequence shows.
struct PatternImage {
  enum class Kind { kWhite, kBlack, kColumnBit, kRowBit };
  Kind kind = Kind::kWhite;
  int bit = 0;           ///< For bit patterns: 0 is the most significant bit.
  bool inverse = false;  ///< For bit patterns: true for the inverted image of the pair.
};

/// The binary Gray-code pattern sequence projected by the scanner.
///
/// Order: all-white, all-black, then for each column bit (most significant first) the
/// pattern and its inverse, then the row bits likewise. With the LightCrafter 4500's
/// 912 x 1140 mirrors that is 10 column bits and 11 row bits: 2 + 2 * (10 + 11) = 44 images.
///
/// In the pattern of column bit b (b = 0 the most significant), projector column c is lit
/// iff bit (column_bits - 1 - b) of GrayEncode(c) is 1; the inverse image is the complement.
/// Rows likewise. Columns index the projector's x (u) axis, rows its y (v) axis.
class PatternSequence final {
 public:
  static constexpr int kDefaultProjectorWidth = 912;
  static constexpr int kDefaultProjectorHeight = 1140;
  static constexpr int kWhiteIndex = 0;
  static constexpr int kBlackIndex = 1;
  static constexpr int kMaxBits = 16;

  /// @param projector_width number of projector columns, >= 2.
  /// @param projector_height number of projector rows, >= 2.
  /// @param column_bits bits coding the columns; 0 derives ceil(log2(width)).
  /// @param row_bits bits coding the rows; 0 derives ceil(log2(height)).
  /// @throws std::invalid_argument if a size is below 2, a bit count is negative or above
  ///   kMaxBits, or 2^bits cannot number every column (row).
  explicit PatternSequence(int projector_width = kDefaultProjectorWidth,
                           int projector_height = kDefaultProjectorHeight, int column_bits = 0,
                           int row_bits = 0);

  int projector_width() const { return projector_width_; }
  int projector_height() const { return projector_height_; }
  int column_bits() const { return column_bits_; }
  int row_bits() const { return row_bits_; }
  /// 2 + 2 * (column_bits + row_bits).
  int num_images() const { return 2 + 2 * (column_bits_ + row_bits_); }

  /// Index in the sequence of column bit `bit` (0 = MSB), or of its inverse.
  /// @throws std::out_of_range for a bit outside [0, column_bits).
  int ColumnImageIndex(int bit, bool inverse) const;
  /// Index in the sequence of row bit `bit` (0 = MSB), or of its inverse.
  /// @throws std::out_of_range for a bit outside [0, row_bits).
  int RowImageIndex(int bit, bool inverse) const;

  /// What image `index` shows. @throws std::out_of_range for an index outside the sequence.
  PatternImage Describe(int index) const;

  /// Whether projector pixel (column, row) is lit in image `index`. Pixels outside the
  /// projector are not lit. @throws std::out_of_range for an index outside the sequence.
  bool IsLit(int index, int column, int row) const;

  /// Renders image `index` as projector_width x projector_height 8-bit pixels, row-major,
  /// lit = 255, dark = 0. @throws std::out_of_range for an index outside the sequence.
  std::vector<std::uint8_t> Render(int index) const;

 private:
  int projector_width_;
  int projector_height_;
  int column_bits_;
  int row_bits_;
};

}  // namespace picking::scanner
