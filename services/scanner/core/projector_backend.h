#pragma once

#include <cstdint>
#include <stdexcept>

namespace picking::scanner {

/// Timing and content of the structured-light sequence a projector shows: white, black, then
/// each Gray-code column bit (most significant first) and its inverse, then the row bits
/// likewise (the order services/scanner/core/patterns.h defines).
struct ProjectorSequenceSettings {
  std::uint32_t exposure_us = 8333;      ///< How long each pattern is shown, microseconds.
  std::uint32_t frame_period_us = 8333;  ///< Pattern-to-pattern period, >= exposure_us.
  int column_bits = 10;
  int row_bits = 11;
  bool trigger_camera = true;  ///< Pulse the camera trigger output at each pattern.

  int image_count() const { return 2 + 2 * (column_bits + row_bits); }
  /// Throws std::invalid_argument naming the field when a value is out of range.
  void Validate() const;
};

/// Any failure of a projector (not found, refused a command, communication error).
class ProjectorError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A pattern projector as the scanner uses it. Implementations: Dlpc350Projector (TI DLP
/// LightCrafter 4500 over USB HID) and the simulator's projector.
class ProjectorBackend {
 public:
  virtual ~ProjectorBackend() = default;

  /// Projector resolution in mirrors (columns x rows).
  virtual std::uint32_t width() const = 0;
  virtual std::uint32_t height() const = 0;

  /// Programs the pattern sequence; the projector is stopped afterwards. Throws
  /// std::invalid_argument for bad settings, ProjectorError when the device refuses them.
  virtual void LoadSequence(const ProjectorSequenceSettings& settings) = 0;
  /// Starts the loaded sequence once. Throws ProjectorError when nothing is loaded.
  virtual void Start() = 0;
  /// Stops the sequence (no effect when stopped).
  virtual void Stop() = 0;
};

}  // namespace picking::scanner
