#include "services/detector/core/kdtree.h"

#include <algorithm>
#include <numeric>
#include <stdexcept>
#include <string>

namespace picking::detector {

KdTree::KdTree(const std::vector<Eigen::Vector3f>& points, int leaf_size) {
  if (leaf_size < 1) throw std::invalid_argument("KdTree: leaf_size must be >= 1");
  if (points.size() > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max())) {
    throw std::invalid_argument("KdTree: too many points");
  }
  if (points.empty()) return;
  entries_.resize(points.size());
  Eigen::Vector3f lo = points.front();
  Eigen::Vector3f hi = lo;
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (!points[i].allFinite()) {
      throw std::invalid_argument("KdTree: point " + std::to_string(i) + " is not finite");
    }
    entries_[i] = {points[i], static_cast<std::int32_t>(i)};
    lo = lo.cwiseMin(points[i]);
    hi = hi.cwiseMax(points[i]);
  }
  nodes_.reserve(2 * points.size() / leaf_size + 2);
  Build(0, static_cast<std::int32_t>(points.size()), leaf_size, lo, hi);
}

std::int32_t KdTree::Build(std::int32_t begin, std::int32_t end, int leaf_size, Eigen::Vector3f lo,
                           Eigen::Vector3f hi) {
  const std::int32_t id = static_cast<std::int32_t>(nodes_.size());
  nodes_.emplace_back();
  nodes_[id].begin = begin;
  nodes_[id].end = end;
  if (end - begin <= leaf_size) return id;
  // Split the widest side of the cell (the parent's cell cut at its split: no pass over the
  // points to measure it) at the median point.
  int axis = 0;
  (hi - lo).maxCoeff(&axis);
  const std::int32_t mid = begin + (end - begin) / 2;
  std::nth_element(entries_.begin() + begin, entries_.begin() + mid, entries_.begin() + end,
                   [axis](const Entry& a, const Entry& b) { return a.p[axis] < b.p[axis]; });
  const float split = entries_[mid].p[axis];
  if (!(hi[axis] > lo[axis])) return id;  // a cell of one point: keep as a leaf
  Eigen::Vector3f left_hi = hi;
  left_hi[axis] = split;
  Eigen::Vector3f right_lo = lo;
  right_lo[axis] = split;
  const std::int32_t left = Build(begin, mid, leaf_size, lo, left_hi);
  const std::int32_t right = Build(mid, end, leaf_size, right_lo, hi);
  nodes_[id].axis = axis;
  nodes_[id].split = split;
  nodes_[id].left = left;
  nodes_[id].right = right;
  return id;
}

std::int32_t KdTree::Nearest(const Eigen::Vector3f& query, float* distance_sq,
                             float max_distance_sq) const {
  if (nodes_.empty()) return kNone;
  std::int32_t best = kNone;
  float best_d2 = max_distance_sq;
  // Explicit stack of (node, lower bound of the squared distance to its cell side).
  std::pair<std::int32_t, float> stack[64];
  int top = 0;
  stack[top++] = {0, 0.0f};
  while (top > 0) {
    const auto [id, bound] = stack[--top];
    if (bound >= best_d2) continue;
    const Node& node = nodes_[id];
    if (node.axis < 0) {
      for (std::int32_t i = node.begin; i < node.end; ++i) {
        const float d2 = (entries_[i].p - query).squaredNorm();
        if (d2 < best_d2) {
          best_d2 = d2;
          best = i;
        }
      }
      continue;
    }
    const float diff = query[node.axis] - node.split;
    const std::int32_t near = diff < 0.0f ? node.left : node.right;
    const std::int32_t far = diff < 0.0f ? node.right : node.left;
    stack[top++] = {far, diff * diff};
    stack[top++] = {near, 0.0f};
  }
  if (best == kNone) return kNone;
  if (distance_sq != nullptr) *distance_sq = best_d2;
  return entries_[best].index;
}

void KdTree::RadiusSearch(const Eigen::Vector3f& query, float radius,
                          std::vector<std::int32_t>* indices) const {
  indices->clear();
  if (nodes_.empty()) return;
  const float r2 = radius * radius;
  std::int32_t stack[64];
  int top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const Node& node = nodes_[stack[--top]];
    if (node.axis < 0) {
      for (std::int32_t i = node.begin; i < node.end; ++i) {
        if ((entries_[i].p - query).squaredNorm() <= r2) indices->push_back(entries_[i].index);
      }
      continue;
    }
    const float diff = query[node.axis] - node.split;
    if (diff - radius <= 0.0f) stack[top++] = node.left;
    if (diff + radius >= 0.0f) stack[top++] = node.right;
  }
}

}  // namespace picking::detector
