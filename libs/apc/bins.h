#pragma once

#include <string>
#include <string_view>

namespace picking::apc {

/// Number of bins of the APC shelf: bin_A (top left) .. bin_L (bottom right), row-major.
constexpr int kNumBins = 12;

/// Name of bin `index` (0..11): "bin_A".."bin_L". Throws std::out_of_range otherwise.
std::string BinName(int index);

/// Index (0..11) of a bin name "bin_A".."bin_L". Throws std::invalid_argument naming the
/// input when it is not a bin name.
int BinIndex(std::string_view name);

/// True for "bin_A".."bin_L" exactly.
bool IsBinName(std::string_view name);

}  // namespace picking::apc
