#include "libs/apc/bins.h"

#include <gtest/gtest.h>

#include <stdexcept>

namespace picking::apc {
namespace {

TEST(BinsTest, NamesAndIndicesAreInverse) {
  EXPECT_EQ(BinName(0), "bin_A");
  EXPECT_EQ(BinName(11), "bin_L");
  for (int i = 0; i < kNumBins; ++i) {
    EXPECT_TRUE(IsBinName(BinName(i)));
    EXPECT_EQ(BinIndex(BinName(i)), i);
  }
}

TEST(BinsTest, RejectsNonBins) {
  for (const char* name : {"bin_M", "bin_a", "bin_", "bin_AA", "tote", "", "Bin_A", "bin A"}) {
    EXPECT_FALSE(IsBinName(name)) << name;
    try {
      BinIndex(name);
      FAIL() << name;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(std::string("\"") + name + "\""), std::string::npos);
    }
  }
  EXPECT_THROW(BinName(-1), std::out_of_range);
  EXPECT_THROW(BinName(kNumBins), std::out_of_range);
}

}  // namespace
}  // namespace picking::apc
