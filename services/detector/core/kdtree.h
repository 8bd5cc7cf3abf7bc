#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <limits>
#include <vector>

namespace picking::detector {

/// A static 3-D k-d tree over a set of points for nearest-neighbour and radius queries.
///
/// The tree keeps its own copy of the points in tree order, so the input may be released
/// after construction. Indices returned by the queries refer to the input order. Queries are
/// const and thread-safe.
class KdTree final {
 public:
  /// Sentinel index returned when no neighbour is found.
  static constexpr std::int32_t kNone = -1;

  KdTree() = default;

  /// Builds the tree. Throws std::invalid_argument when a point is not finite.
  explicit KdTree(const std::vector<Eigen::Vector3f>& points, int leaf_size = 12);

  std::size_t size() const { return entries_.size(); }
  bool empty() const { return entries_.empty(); }

  /// Index of the nearest point with squared distance below `max_distance_sq` (metres^2),
  /// or kNone. `distance_sq` receives the squared distance when a point is found.
  std::int32_t Nearest(const Eigen::Vector3f& query, float* distance_sq = nullptr,
                       float max_distance_sq = std::numeric_limits<float>::infinity()) const;

  /// Appends to `indices` every point within `radius` (metres, inclusive) of `query`, in
  /// no particular order. Clears `indices` first.
  void RadiusSearch(const Eigen::Vector3f& query, float radius,
                    std::vector<std::int32_t>* indices) const;

 private:
  struct Node {
    float split = 0.0f;
    std::int32_t axis = -1;  // -1 for a leaf
    std::int32_t left = -1;
    std::int32_t right = -1;
    std::int32_t begin = 0;
    std::int32_t end = 0;
  };

  // A point with its input index, partitioned in place while building (nth_element's
  // comparisons read contiguous memory instead of following an index into the points) and
  // kept in tree order for cache-friendly leaves.
  struct Entry {
    Eigen::Vector3f p;
    std::int32_t index;
  };
  // Builds the subtree of entries_ [begin, end) in the cell [lo, hi].
  std::int32_t Build(std::int32_t begin, std::int32_t end, int leaf_size, Eigen::Vector3f lo,
                     Eigen::Vector3f hi);

  std::vector<Entry> entries_;  // tree order
  std::vector<Node> nodes_;
};

}  // namespace picking::detector
