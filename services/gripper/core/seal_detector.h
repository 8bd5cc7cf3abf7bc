#pragma once

namespace picking::gripper {

/// Thresholds of the seal decision, kPa of gauge vacuum.
struct SealOptions {
  /// The cup counts as sealed (an item attached) once the vacuum rises to this level.
  double attach_kpa = 15.0;
  /// A sealed cup counts as open again only once the vacuum falls below this level, so a
  /// reading that hovers around one threshold does not flicker. Must be below attach_kpa.
  double release_kpa = 10.0;
};

/// Decides "item attached" from the vacuum level with hysteresis: attached when the level
/// reaches `attach_kpa`, detached when it falls below `release_kpa` or the pump is off.
class SealDetector final {
 public:
  /// Throws std::invalid_argument unless 0 <= release_kpa < attach_kpa, both finite.
  explicit SealDetector(const SealOptions& options = {});

  /// Feeds one reading and returns the decision.
  bool Update(bool vacuum_on, double vacuum_kpa);

  bool attached() const { return attached_; }
  void Reset() { attached_ = false; }
  const SealOptions& options() const { return options_; }

 private:
  SealOptions options_;
  bool attached_ = false;
};

}  // namespace picking::gripper
