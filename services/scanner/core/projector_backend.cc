#include "services/scanner/core/projector_backend.h"

#include <string>

namespace picking::scanner {

void ProjectorSequenceSettings::Validate() const {
  if (exposure_us == 0) throw std::invalid_argument("ProjectorSequenceSettings.exposure_us is 0");
  if (frame_period_us < exposure_us) {
    throw std::invalid_argument("ProjectorSequenceSettings.frame_period_us (" +
                                std::to_string(frame_period_us) + ") is below exposure_us (" +
                                std::to_string(exposure_us) + ")");
  }
  if (column_bits < 1 || column_bits > 16) {
    throw std::invalid_argument("ProjectorSequenceSettings.column_bits must be in [1, 16], got " +
                                std::to_string(column_bits));
  }
  if (row_bits < 1 || row_bits > 16) {
    throw std::invalid_argument("ProjectorSequenceSettings.row_bits must be in [1, 16], got " +
                                std::to_string(row_bits));
  }
}

}  // namespace picking::scanner
