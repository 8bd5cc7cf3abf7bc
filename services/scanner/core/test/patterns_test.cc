#include "services/scanner/core/patterns.h"

#include <gtest/gtest.h>

#include <set>
#include <stdexcept>

namespace picking::scanner {
namespace {

TEST(PatternsTest, DefaultsMatchTheLightCrafter) {
  const PatternSequence patterns;
  EXPECT_EQ(patterns.projector_width(), 912);
  EXPECT_EQ(patterns.projector_height(), 1140);
  EXPECT_EQ(patterns.column_bits(), 10);
  EXPECT_EQ(patterns.row_bits(), 11);
  EXPECT_EQ(patterns.num_images(), 44);
}

TEST(PatternsTest, GrayDecodeInvertsEncodeForEveryColumnAndRow) {
  const PatternSequence patterns;
  for (int c = 0; c < patterns.projector_width(); ++c) {
    ASSERT_EQ(GrayDecode(GrayEncode(c)), static_cast<std::uint32_t>(c));
  }
  for (int r = 0; r < patterns.projector_height(); ++r) {
    ASSERT_EQ(GrayDecode(GrayEncode(r)), static_cast<std::uint32_t>(r));
  }
  for (std::uint32_t v : {0u, 1u, 65535u, 0x12345678u, 0xffffffffu}) {
    EXPECT_EQ(GrayDecode(GrayEncode(v)), v);
  }
}

TEST(PatternsTest, NeighbouringCodesDifferInOneBit) {
  for (std::uint32_t v = 0; v < 4096; ++v) {
    EXPECT_EQ(__builtin_popcount(GrayEncode(v) ^ GrayEncode(v + 1)), 1);
  }
}

// Reads every column's and row's code back from the rendered images, as a decoder would.
TEST(PatternsTest, RenderedImagesEncodeEveryColumnAndRow) {
  const PatternSequence patterns(40, 23);  // 6 column bits, 5 row bits.
  ASSERT_EQ(patterns.column_bits(), 6);
  ASSERT_EQ(patterns.row_bits(), 5);
  std::vector<std::vector<std::uint8_t>> images;
  for (int i = 0; i < patterns.num_images(); ++i) images.push_back(patterns.Render(i));
  std::set<std::pair<int, int>> seen;
  for (int r = 0; r < 23; ++r) {
    for (int c = 0; c < 40; ++c) {
      const int at = r * 40 + c;
      EXPECT_EQ(images[PatternSequence::kWhiteIndex][at], 255);
      EXPECT_EQ(images[PatternSequence::kBlackIndex][at], 0);
      std::uint32_t column_gray = 0;
      for (int b = 0; b < 6; ++b) {
        const int p = images[patterns.ColumnImageIndex(b, false)][at];
        const int q = images[patterns.ColumnImageIndex(b, true)][at];
        ASSERT_EQ(p + q, 255);
        column_gray = (column_gray << 1) | (p > q ? 1 : 0);
      }
      std::uint32_t row_gray = 0;
      for (int b = 0; b < 5; ++b) {
        const int p = images[patterns.RowImageIndex(b, false)][at];
        const int q = images[patterns.RowImageIndex(b, true)][at];
        ASSERT_EQ(p + q, 255);
        row_gray = (row_gray << 1) | (p > q ? 1 : 0);
      }
      EXPECT_EQ(GrayDecode(column_gray), static_cast<std::uint32_t>(c));
      EXPECT_EQ(GrayDecode(row_gray), static_cast<std::uint32_t>(r));
      seen.insert({c, r});
    }
  }
  EXPECT_EQ(seen.size(), 40u * 23u);
}

TEST(PatternsTest, OrderIsWhiteBlackThenColumnPairsThenRowPairs) {
  const PatternSequence patterns;
  EXPECT_EQ(patterns.Describe(0).kind, PatternImage::Kind::kWhite);
  EXPECT_EQ(patterns.Describe(1).kind, PatternImage::Kind::kBlack);
  for (int b = 0; b < 10; ++b) {
    EXPECT_EQ(patterns.ColumnImageIndex(b, false), 2 + 2 * b);
    EXPECT_EQ(patterns.ColumnImageIndex(b, true), 3 + 2 * b);
    const PatternImage d = patterns.Describe(3 + 2 * b);
    EXPECT_EQ(d.kind, PatternImage::Kind::kColumnBit);
    EXPECT_EQ(d.bit, b);
    EXPECT_TRUE(d.inverse);
  }
  for (int b = 0; b < 11; ++b) {
    EXPECT_EQ(patterns.RowImageIndex(b, false), 22 + 2 * b);
    const PatternImage d = patterns.Describe(22 + 2 * b);
    EXPECT_EQ(d.kind, PatternImage::Kind::kRowBit);
    EXPECT_EQ(d.bit, b);
    EXPECT_FALSE(d.inverse);
  }
  // The most significant column bit splits the code range in half.
  EXPECT_FALSE(patterns.IsLit(2, 511, 0));
  EXPECT_TRUE(patterns.IsLit(2, 512, 0));
}

TEST(PatternsTest, ExplicitBitCountsAndBadInput) {
  const PatternSequence wide(912, 1140, 12, 11);
  EXPECT_EQ(wide.column_bits(), 12);
  EXPECT_EQ(wide.num_images(), 2 + 2 * 23);
  EXPECT_THROW(PatternSequence(912, 1140, 9, 11), std::invalid_argument);   // 512 < 912
  EXPECT_THROW(PatternSequence(912, 1140, 10, 10), std::invalid_argument);  // 1024 < 1140
  EXPECT_THROW(PatternSequence(1, 1140), std::invalid_argument);
  EXPECT_THROW(PatternSequence(912, 1140, 17, 11), std::invalid_argument);
  EXPECT_THROW(PatternSequence(912, 1140, -1, 11), std::invalid_argument);
  const PatternSequence patterns;
  EXPECT_THROW(patterns.Describe(44), std::out_of_range);
  EXPECT_THROW(patterns.Describe(-1), std::out_of_range);
  EXPECT_THROW(patterns.ColumnImageIndex(10, false), std::out_of_range);
  EXPECT_THROW(patterns.RowImageIndex(11, true), std::out_of_range);
  EXPECT_FALSE(patterns.IsLit(0, 912, 0));
}

}  // namespace
}  // namespace picking::scanner
