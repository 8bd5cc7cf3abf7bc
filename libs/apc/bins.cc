#include "libs/apc/bins.h"

#include <stdexcept>

namespace picking::apc {

std::string BinName(int index) {
  if (index < 0 || index >= kNumBins) {
    throw std::out_of_range("bin index " + std::to_string(index) + " is outside 0.." +
                            std::to_string(kNumBins - 1));
  }
  return std::string("bin_") + static_cast<char>('A' + index);
}

bool IsBinName(std::string_view name) {
  return name.size() == 5 && name.substr(0, 4) == "bin_" && name[4] >= 'A' &&
         name[4] < 'A' + kNumBins;
}

int BinIndex(std::string_view name) {
  if (!IsBinName(name)) {
    throw std::invalid_argument("\"" + std::string(name) +
                                "\" is not a bin name (expected bin_A .. bin_L)");
  }
  return name[4] - 'A';
}

}  // namespace picking::apc
