// The SubpixelRefiner against a plain reference implementation of the refinement as it is
// specified in decoder.h: every camera row and every camera column refined on its own, one
// pixel after the other, then the fills across lines and the final validity pass. The
// refiner (row-major strips, candidate lists, thread pool) must give bit-identical maps and
// counts for every option combination, thread count and image stride.

#include "services/scanner/core/decoder.h"
#include "services/scanner/core/synthetic_capture.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <utility>
#include <vector>

namespace picking::scanner {
namespace {

struct Event {
  int boundary;
  int next;
  bool knot;
  float t;
  float value;
};

int LowestSetBit(unsigned value) {
  int bit = 0;
  while (!(value & 1u)) {
    value >>= 1;
    ++bit;
  }
  return bit;
}

// One line of n pixels; pixel i at element i * step; diff(i, bit) = pattern - inverse.
template <typename Diff>
std::size_t ReferenceLine(int n, const std::uint16_t* code, const std::uint8_t* valid,
                          std::ptrdiff_t step, int max_gap, const Diff& diff, float* out) {
  const float kNaN = std::numeric_limits<float>::quiet_NaN();
  std::vector<Event> e;
  std::size_t num_knots = 0;
  const auto push_break = [&](int boundary) {
    e.push_back(Event{boundary, boundary + 1, false, 0.0f, 0.0f});
  };
  for (int i = 0; i + 1 < n; ++i) {
    const bool va = valid[i * step] != 0;
    const bool vb = valid[(i + 1) * step] != 0;
    if (!va && !vb) continue;
    if (!va) {
      push_break(i);
      continue;
    }
    int k = i + 1;
    if (!vb) {
      while (k < n && k - i - 1 <= max_gap && !valid[k * step]) ++k;
      if (k >= n || k - i - 1 > max_gap) {
        push_break(i);
        continue;
      }
    }
    const int ca = code[i * step];
    const int cb = code[k * step];
    if (ca == cb) {
      i = k - 1;
      continue;
    }
    if (std::abs(ca - cb) != 1) {
      push_break(i);
      continue;
    }
    const int bit = LowestSetBit(static_cast<unsigned>(std::max(ca, cb)));
    float first = -1.0f;
    float last = -1.0f;
    for (int m = i; m < k; ++m) {
      const int d0 = diff(m, bit);
      const int d1 = diff(m + 1, bit);
      if ((d0 > 0) != (d1 > 0)) {
        const float denominator = static_cast<float>(d0 - d1);
        const float fraction = denominator != 0.0f ? static_cast<float>(d0) / denominator : 0.5f;
        const float t = static_cast<float>(m) + std::min(1.0f, std::max(0.0f, fraction));
        if (first < 0.0f) first = t;
        last = t;
      }
    }
    const float t = first < 0.0f ? 0.5f * static_cast<float>(i + k) : 0.5f * (first + last);
    e.push_back(Event{i, k, true, t, 0.5f * static_cast<float>(ca + cb)});
    ++num_knots;
    i = k - 1;
  }
  push_break(n - 1);

  const int m = static_cast<int>(e.size());
  for (int j = 0; j < m; ++j) {
    const int first = j == 0 ? 0 : e[j - 1].boundary + 1;
    const int first_valid = j == 0 ? 0 : e[j - 1].next;
    const int last = e[j].boundary;
    bool ok = false;
    float t0 = 0.0f;
    float v0 = 0.0f;
    float slope = 0.0f;
    float c = 0.0f;
    const auto from_knots = [&](const Event& a, const Event& b, const Event& anchor) {
      const float dt = b.t - a.t;
      if (!(dt > 1e-3f) || a.value == b.value) return false;
      slope = (b.value - a.value) / dt;
      t0 = anchor.t;
      v0 = anchor.value;
      return true;
    };
    if (first_valid <= last && valid[first_valid * step]) {
      c = code[first_valid * step];
      const bool left = j > 0 && e[j - 1].knot;
      const bool right = e[j].knot;
      if (left && right) {
        ok = from_knots(e[j - 1], e[j], e[j - 1]);
      } else if (left && j >= 2 && e[j - 2].knot) {
        ok = from_knots(e[j - 2], e[j - 1], e[j - 1]) && (slope > 0.0f) == (c > v0);
      } else if (right && j + 1 < m && e[j + 1].knot) {
        ok = from_knots(e[j], e[j + 1], e[j]) && (slope < 0.0f) == (c > v0);
      }
    }
    for (int i = first; i <= last; ++i) {
      if (!ok || !valid[i * step]) {
        out[i * step] = kNaN;
      } else {
        const float v = v0 + slope * (static_cast<float>(i) - t0);
        out[i * step] = std::min(c + 0.5f, std::max(c - 0.5f, v));
      }
    }
  }
  return num_knots;
}

float ReferenceFill(const float* value, const std::uint16_t* code, std::ptrdiff_t step, int before,
                    int after) {
  const int c = *code;
  int d_before = 0;
  int d_after = 0;
  float v_before = 0.0f;
  float v_after = 0.0f;
  for (int d = 1; d <= std::min(2, before) && d_before == 0; ++d) {
    if (!std::isnan(value[-d * step]) && std::abs(code[-d * step] - c) <= 1) {
      v_before = value[-d * step];
      d_before = d;
    }
  }
  for (int d = 1; d <= std::min(2, after) && d_after == 0; ++d) {
    if (!std::isnan(value[d * step]) && std::abs(code[d * step] - c) <= 1) {
      v_after = value[d * step];
      d_after = d;
    }
  }
  float v;
  if (d_before > 0 && d_after > 0) {
    v = (v_before * d_after + v_after * d_before) / static_cast<float>(d_before + d_after);
  } else if (d_before > 0) {
    v = v_before;
  } else if (d_after > 0) {
    v = v_after;
  } else {
    return std::numeric_limits<float>::quiet_NaN();
  }
  const float cf = static_cast<float>(c);
  if (!(std::abs(v - cf) <= 0.75f)) return std::numeric_limits<float>::quiet_NaN();
  return std::min(cf + 0.5f, std::max(cf - 0.5f, v));
}

RefinementResult ReferenceRefine(const PatternSequence& patterns,
                                 const std::vector<ImageView>& images,
                                 const RefinementOptions& options, CorrespondenceMap* map) {
  const int w = map->width;
  const int h = map->height;
  const std::size_t n = static_cast<std::size_t>(w) * h;
  map->column_subpixel.assign(n, 0.0f);
  map->row_subpixel.assign(n, 0.0f);
  const int column_bits = patterns.column_bits();
  const int row_bits = patterns.row_bits();
  const auto pixel = [&](int image, int x, int y) {
    return static_cast<int>(images[image].row(y)[x]);
  };
  RefinementResult result;
  for (int y = 0; y < h; ++y) {
    const std::size_t o = static_cast<std::size_t>(y) * w;
    const auto diff = [&](int x, int bit) {
      const int b = column_bits - 1 - bit;
      return pixel(patterns.ColumnImageIndex(b, false), x, y) -
             pixel(patterns.ColumnImageIndex(b, true), x, y);
    };
    result.num_column_transitions +=
        ReferenceLine(w, map->column.data() + o, map->valid.data() + o, 1, options.max_gap_px, diff,
                      map->column_subpixel.data() + o);
  }
  for (int x = 0; x < w && !options.refine_rows; ++x) {
    // Integer rows: the row of every valid pixel, nothing to fill.
    for (int y = 0; y < h; ++y) {
      const std::size_t i = static_cast<std::size_t>(y) * w + x;
      map->row_subpixel[i] =
          map->valid[i] ? static_cast<float>(map->row[i]) : std::numeric_limits<float>::quiet_NaN();
    }
  }
  for (int x = 0; x < w && options.refine_rows; ++x) {
    const auto diff = [&](int y, int bit) {
      const int b = row_bits - 1 - bit;
      return pixel(patterns.RowImageIndex(b, false), x, y) -
             pixel(patterns.RowImageIndex(b, true), x, y);
    };
    result.num_row_transitions +=
        ReferenceLine(h, map->row.data() + x, map->valid.data() + x, w, options.max_gap_px, diff,
                      map->row_subpixel.data() + x);
  }
  std::vector<std::pair<std::size_t, float>> fills;
  for (std::size_t i = 0; i < n; ++i) {
    if (!map->valid[i] || !std::isnan(map->column_subpixel[i])) continue;
    const int y = static_cast<int>(i / w);
    const float v =
        ReferenceFill(map->column_subpixel.data() + i, map->column.data() + i, w, y, h - 1 - y);
    if (!std::isnan(v)) fills.emplace_back(i, v);
  }
  for (const auto& [i, v] : fills) map->column_subpixel[i] = v;
  result.num_filled_across = fills.size();
  fills.clear();
  for (std::size_t i = 0; i < n; ++i) {
    if (!map->valid[i] || !std::isnan(map->row_subpixel[i])) continue;
    const int x = static_cast<int>(i % w);
    const float v =
        ReferenceFill(map->row_subpixel.data() + i, map->row.data() + i, 1, x, w - 1 - x);
    if (!std::isnan(v)) fills.emplace_back(i, v);
  }
  for (const auto& [i, v] : fills) map->row_subpixel[i] = v;
  result.num_filled_across += fills.size();
  std::size_t unrefined = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (!map->valid[i]) continue;
    const bool column_ok = !std::isnan(map->column_subpixel[i]);
    const bool row_ok = !std::isnan(map->row_subpixel[i]);
    if (column_ok && row_ok) {
      ++result.num_refined;
      continue;
    }
    ++unrefined;
    if (options.reject_unrefined) {
      map->valid[i] = 0;
      map->column[i] = 0;
      map->row[i] = 0;
      map->column_subpixel[i] = std::numeric_limits<float>::quiet_NaN();
      map->row_subpixel[i] = std::numeric_limits<float>::quiet_NaN();
    } else {
      if (!column_ok) map->column_subpixel[i] = map->column[i];
      if (!row_ok) map->row_subpixel[i] = map->row[i];
    }
  }
  if (options.reject_unrefined) {
    result.num_rejected = unrefined;
    map->num_valid = result.num_refined;
  } else {
    result.num_kept_integer = unrefined;
  }
  return result;
}

// Equal floats, or both NaN.
bool Same(float a, float b) { return a == b || (std::isnan(a) && std::isnan(b)); }

struct Scene {
  ScannerRig rig = MakeExampleRig(640, 480);
  PatternSequence patterns;
  SyntheticCapture capture;
  Scene() {
    SyntheticScene scene;
    SyntheticPlane plane;
    plane.normal = Eigen::Vector3d(0.3, -0.15, 1.0).normalized();
    plane.offset_m = plane.normal.dot(Eigen::Vector3d(0, 0, 0.9));
    scene.planes.push_back(plane);
    SyntheticSphere sphere;
    sphere.center_m = Eigen::Vector3d(0.02, -0.02, 0.75);
    sphere.radius_m = 0.07;
    scene.spheres.push_back(sphere);
    SyntheticCaptureOptions options;
    options.blur_sigma_px = 0.6;
    options.noise_sigma = 3.0;
    options.gamma = 1.3;
    options.ambient_level = 25.0;
    options.samples_per_axis = 3;
    options.seed = 7;
    capture = RenderSyntheticCapture(rig, patterns, scene, options);
  }
};

const Scene& GetScene() {
  static const Scene* scene = new Scene();
  return *scene;
}

void ExpectSameAsReference(const std::vector<ImageView>& views, const DecoderOptions& decoding,
                           const RefinementOptions& options) {
  const Scene& s = GetScene();
  const CorrespondenceMap decoded = GrayCodeDecoder(s.patterns, decoding).Decode(views);
  ASSERT_GT(decoded.num_valid, 0u);
  CorrespondenceMap expected = decoded;
  const RefinementResult want = ReferenceRefine(s.patterns, views, options, &expected);
  CorrespondenceMap actual = decoded;
  const RefinementResult got = SubpixelRefiner(s.patterns, options).Refine(views, &actual);
  EXPECT_EQ(got.num_refined, want.num_refined);
  EXPECT_EQ(got.num_rejected, want.num_rejected);
  EXPECT_EQ(got.num_kept_integer, want.num_kept_integer);
  EXPECT_EQ(got.num_column_transitions, want.num_column_transitions);
  EXPECT_EQ(got.num_row_transitions, want.num_row_transitions);
  EXPECT_EQ(got.num_filled_across, want.num_filled_across);
  EXPECT_GT(want.num_column_transitions, 10000u);
  EXPECT_GT(want.num_filled_across + want.num_rejected + want.num_kept_integer, 0u);
  EXPECT_EQ(actual.num_valid, expected.num_valid);
  EXPECT_TRUE(actual.valid == expected.valid);
  EXPECT_TRUE(actual.column == expected.column);
  EXPECT_TRUE(actual.row == expected.row);
  std::size_t column_mismatches = 0;
  std::size_t row_mismatches = 0;
  for (std::size_t i = 0; i < expected.valid.size(); ++i) {
    column_mismatches += !Same(actual.column_subpixel[i], expected.column_subpixel[i]);
    row_mismatches += !Same(actual.row_subpixel[i], expected.row_subpixel[i]);
  }
  EXPECT_EQ(column_mismatches, 0u);
  EXPECT_EQ(row_mismatches, 0u);
}

TEST(DecoderRefinementReferenceTest, DefaultOptionsOnTwoThreads) {
  RefinementOptions options;
  options.num_threads = 2;
  ExpectSameAsReference(GetScene().capture.views(), DecoderOptions{}, options);
}

TEST(DecoderRefinementReferenceTest, KeepUnrefinedOnOneThread) {
  RefinementOptions options;
  options.reject_unrefined = false;
  options.num_threads = 1;
  ExpectSameAsReference(GetScene().capture.views(), DecoderOptions{}, options);
}

TEST(DecoderRefinementReferenceTest, NoGapsAndLongGaps) {
  DecoderOptions no_bit_test;
  no_bit_test.min_bit_contrast = 0;
  for (const int gap : {0, 1, 5, 16}) {
    SCOPED_TRACE(gap);
    RefinementOptions options;
    options.max_gap_px = gap;
    options.num_threads = 3;
    ExpectSameAsReference(GetScene().capture.views(), DecoderOptions{}, options);
    ExpectSameAsReference(GetScene().capture.views(), no_bit_test, options);
  }
}

TEST(DecoderRefinementReferenceTest, IntegerRows) {
  for (const bool reject : {true, false}) {
    SCOPED_TRACE(reject);
    RefinementOptions options;
    options.refine_rows = false;
    options.reject_unrefined = reject;
    options.num_threads = 2;
    ExpectSameAsReference(GetScene().capture.views(), DecoderOptions{}, options);
  }
}

TEST(DecoderRefinementReferenceTest, PaddedRows) {
  // The same captures with 40 bytes of padding after every row.
  const SyntheticCapture& capture = GetScene().capture;
  const int stride = capture.width + 40;
  std::vector<std::vector<std::uint8_t>> padded(capture.images.size());
  std::vector<ImageView> views;
  for (std::size_t k = 0; k < capture.images.size(); ++k) {
    padded[k].assign(static_cast<std::size_t>(stride) * capture.height, 99);
    for (int y = 0; y < capture.height; ++y) {
      std::memcpy(padded[k].data() + static_cast<std::size_t>(y) * stride,
                  capture.images[k].data() + static_cast<std::size_t>(y) * capture.width,
                  capture.width);
    }
    views.push_back(ImageView{padded[k].data(), capture.width, capture.height, stride});
  }
  RefinementOptions options;
  options.num_threads = 2;
  ExpectSameAsReference(views, DecoderOptions{}, options);
}

}  // namespace
}  // namespace picking::scanner
