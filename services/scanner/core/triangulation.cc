#include "services/scanner/core/triangulation.h"

#include "services/scanner/core/band_pool.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace picking::scanner {
namespace {

constexpr int kRowsPerBand = 16;
// Rows per task of the triangulation with normals (plus 2 * (step + 1) rows recomputed).
constexpr int kRowsPerChunk = 64;

void Require(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("Triangulator: " + what);
}

// On x86-64 with GCC the row kernels are also compiled for AVX2 (eight floats per
// instruction; no FMA, so both versions round identically) and the best version is chosen
// when the program loads.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
#define PICKING_TRIANGULATION_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define PICKING_TRIANGULATION_CLONES
#endif

// Asks the kernel to back the whole 2 MiB pages inside a large buffer with transparent huge
// pages (Linux, where the system leaves it to madvise). A fresh 1280 x 1024 cloud is ~37 MB
// of new memory per view; with 4 KiB pages its first writes cost ~9000 page faults, which on
// a virtual machine take longer than computing the cloud. Pages already touched are left
// as they are; failure (no THP support) changes nothing.
void AdviseHugePages(void* data, std::size_t bytes) {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
  constexpr std::uintptr_t kHugePage = std::uintptr_t{2} << 20;
  const auto begin = reinterpret_cast<std::uintptr_t>(data);
  const std::uintptr_t first = (begin + kHugePage - 1) & ~(kHugePage - 1);
  const std::uintptr_t last = (begin + bytes) & ~(kHugePage - 1);
  if (last > first) madvise(reinterpret_cast<void*>(first), last - first, MADV_HUGEPAGE);
#else
  (void)data;
  (void)bytes;
#endif
}

// Makes the pages of a buffer about to be written present in one system call (Linux 5.14+,
// MADV_POPULATE_WRITE) instead of one page fault per 4 KiB page at the first write; pages
// already present are left as they are and the contents never change. Called by each task
// for the rows it writes, so the kernel zeroes fresh memory on both threads. Failure (older
// kernels) changes nothing: the writes fault the pages in as before.
void PopulateForWrite(void* data, std::size_t bytes) {
#if defined(__linux__) && defined(MADV_POPULATE_WRITE)
  constexpr std::uintptr_t kPage = 4096;
  const auto begin = reinterpret_cast<std::uintptr_t>(data);
  const std::uintptr_t first = begin & ~(kPage - 1);
  const std::uintptr_t last = (begin + bytes + kPage - 1) & ~(kPage - 1);
  if (bytes > 0) madvise(reinterpret_cast<void*>(first), last - first, MADV_POPULATE_WRITE);
#else
  (void)data;
  (void)bytes;
#endif
}

// What became of a camera pixel of a row.
constexpr std::uint8_t kStatusPoint = 0;
constexpr std::uint8_t kStatusDepth = 1;     // Parallel rays, depth range or behind the projector.
constexpr std::uint8_t kStatusResidual = 2;  // The rays pass too far apart.
constexpr std::uint8_t kStatusInvalid = 3;   // No correspondence.

// Constants of the ray intersection shared by all pixels.
struct IntersectConstants {
  float ox, oy, oz;  // Projector centre in the camera frame.
  float min_depth;
  float max_depth;
  float residual_factor;  // (max residual / projector focal length)^2.
};

// Intersects n camera rays (x, y, 1) (ray_xy: x, y interleaved) with their projector rays
// (e: unit direction and -direction . centre, four floats per pixel; whatever finite values
// invalid pixels hold are computed with and discarded) in the least-squares sense and writes
// each point (x, y, z interleaved; NaN unless kept) and its status. Branch-free, so that the
// compiler vectorises it.
PICKING_TRIANGULATION_CLONES void IntersectRow(int n, const float* __restrict ray_xy,
                                               const float* __restrict e,
                                               const std::uint8_t* __restrict valid,
                                               const IntersectConstants& k, float* __restrict out,
                                               std::uint8_t* __restrict status) {
  const float kNaN = std::numeric_limits<float>::quiet_NaN();
  const float ox = k.ox;
  const float oy = k.oy;
  const float oz = k.oz;
  const float min_depth = k.min_depth;
  const float max_depth = k.max_depth;
  const float residual_factor = k.residual_factor;
  for (int i = 0; i < n; ++i) {
    // Closest point on the camera ray t d (d = (x, y, 1)) to the projector ray o + s e.
    const float rx = ray_xy[2 * i];
    const float ry = ray_xy[2 * i + 1];
    const float ex = e[4 * i];
    const float ey = e[4 * i + 1];
    const float ez = e[4 * i + 2];
    const float ew = e[4 * i + 3];  // e . (0 - o)
    const float dd = rx * rx + ry * ry + 1.0f;
    const float de = rx * ex + ry * ey + ez;
    const float dw = -(rx * ox + ry * oy + oz);  // d . (0 - o)
    const float denominator = dd - de * de;
    const float inverse = 1.0f / denominator;
    const float t = (de * ew - dw) * inverse;
    const float s = (dd * ew - de * dw) * inverse;
    const float px = t * rx;
    const float py = t * ry;
    const float gx = px - (ox + s * ex);
    const float gy = py - (oy + s * ey);
    const float gz = t - (oz + s * ez);
    const int depth_ok =
        (denominator > 1e-9f * dd) & (t >= min_depth) & (t <= max_depth) & (s > 0.0f);
    const int residual_ok = gx * gx + gy * gy + gz * gz <= residual_factor * s * s;
    const int is_valid = valid[i] != 0;
    // Invalid 3, else depth 1, else residual 2, else point 0 (arithmetic, not nested
    // selects, which the vectoriser does not take).
    const int inner = (1 - depth_ok) + depth_ok * 2 * (1 - residual_ok);
    const int st = inner + (1 - is_valid) * (3 - inner);
    const bool keep = st == kStatusPoint;
    out[3 * i] = keep ? px : kNaN;
    out[3 * i + 1] = keep ? py : kNaN;
    out[3 * i + 2] = keep ? t : kNaN;
    status[i] = static_cast<std::uint8_t>(st);
  }
}

// Counts of the statuses of n pixels: points, depth and residual rejections.
PICKING_TRIANGULATION_CLONES void CountStatuses(int n, const std::uint8_t* __restrict status,
                                                std::size_t* points, std::size_t* depth,
                                                std::size_t* residual) {
  int p = 0;
  int d = 0;
  int r = 0;
  for (int i = 0; i < n; ++i) {
    p += status[i] == kStatusPoint;
    d += status[i] == kStatusDepth;
    r += status[i] == kStatusResidual;
  }
  *points += p;
  *depth += d;
  *residual += r;
}

// The isolated-point test of the interior pixels [1, w - 1) of a row whose rows above and
// below exist (points x, y, z interleaved): flags[x] = 1 where the point exists and fewer
// than min_neighbors of its 8 neighbours are within `tolerance` in depth, else 0.
PICKING_TRIANGULATION_CLONES void IsolatedInterior(int w, const float* __restrict above,
                                                   const float* __restrict row,
                                                   const float* __restrict below, float tolerance,
                                                   int min_neighbors,
                                                   std::uint8_t* __restrict flags) {
  for (int x = 1; x + 1 < w; ++x) {
    const float z = row[3 * x + 2];
    // Comparisons with NaN are false, so missing neighbours do not count.
    const int neighbors = (std::abs(above[3 * x - 1] - z) <= tolerance) +
                          (std::abs(above[3 * x + 2] - z) <= tolerance) +
                          (std::abs(above[3 * x + 5] - z) <= tolerance) +
                          (std::abs(row[3 * x - 1] - z) <= tolerance) +
                          (std::abs(row[3 * x + 5] - z) <= tolerance) +
                          (std::abs(below[3 * x - 1] - z) <= tolerance) +
                          (std::abs(below[3 * x + 2] - z) <= tolerance) +
                          (std::abs(below[3 * x + 5] - z) <= tolerance);
    flags[x] = static_cast<std::uint8_t>((z == z) & (neighbors < min_neighbors));
  }
}

// Sets the points of a row flagged 1 to NaN (few are); returns how many.
int RemoveFlagged(int w, const std::uint8_t* flags, Eigen::Vector3f* points) {
  int removed = 0;
  for (int x = 0; x < w; ++x) {
    if (flags[x]) {
      points[x].setConstant(std::numeric_limits<float>::quiet_NaN());
      ++removed;
    }
  }
  return removed;
}

// Point, rejection, removal and normal counts of one task (or of all).
struct Counts {
  std::size_t points = 0;
  std::size_t residual = 0;
  std::size_t depth = 0;
  std::size_t removed = 0;
  std::size_t normals = 0;
};

// Gather stage: the sum of the counts of all tasks.
Counts SumCounts(const std::vector<Counts>& task_counts) {
  Counts total;
  for (const Counts& c : task_counts) {
    total.points += c.points;
    total.residual += c.residual;
    total.depth += c.depth;
    total.removed += c.removed;
    total.normals += c.normals;
  }
  return total;
}

// The projector ray table (row-major, unit direction in the camera frame and -direction .
// centre per projector pixel) and the offsets its bilinear interpolation needs.
struct ProjectorRayTable {
  const Eigen::Vector4f* rays;
  int width;        // Projector columns.
  int last_column;  // Last column and row an interpolation cell may start at.
  int last_row;
  std::ptrdiff_t down;   // Offset of the next projector row, 0 for a single row.
  std::ptrdiff_t right;  // Offset of the next projector column, 0 for a single column.
};

// Setup stage: the interpolation offsets of a width x height projector ray table.
ProjectorRayTable MakeProjectorRayTable(const std::vector<Eigen::Vector4f>& rays, int width,
                                        int height) {
  ProjectorRayTable table;
  table.rays = rays.data();
  table.width = width;
  table.last_column = std::max(0, width - 2);
  table.last_row = std::max(0, height - 2);
  table.down = height > 1 ? width : 0;
  table.right = width > 1 ? 1 : 0;
  return table;
}

// The projector ray of a sub-pixel correspondence, interpolated bilinearly between the rays
// of the four nearest mirror centres (the ray table is smooth; its curvature over one
// mirror is far below the noise).
inline Eigen::Vector4f InterpolatedRay(const ProjectorRayTable& table, float u, float v) {
  const int last_column = table.last_column;
  const int last_row = table.last_row;
  const std::ptrdiff_t down = table.down;
  const std::ptrdiff_t right = table.right;
  // Truncation: u in (-0.5, 0) gives u0 = 0 and a < 0, a short extrapolation.
  const int u0 = std::min(last_column, std::max(0, static_cast<int>(u)));
  const int v0 = std::min(last_row, std::max(0, static_cast<int>(v)));
  const float a = u - static_cast<float>(u0);
  const float b = v - static_cast<float>(v0);
  const Eigen::Vector4f* e00 = table.rays + static_cast<std::size_t>(v0) * table.width + u0;
  const Eigen::Vector4f top = e00[0] + a * (e00[right] - e00[0]);
  if (b == 0.0f) return top;  // An integer row (rows not refined): one table row.
  const Eigen::Vector4f bottom = e00[down] + a * (e00[down + right] - e00[down]);
  return top + b * (bottom - top);
}

static_assert(sizeof(Eigen::Vector3f) == 3 * sizeof(float) &&
                  sizeof(Eigen::Vector2f) == 2 * sizeof(float) &&
                  sizeof(Eigen::Vector4f) == 4 * sizeof(float),
              "the row kernels read points and rays as packed floats");

// What the row stages of one Run share: its inputs, its output cloud (sized) and the
// constants of the row kernels.
struct RowContext {
  const CorrespondenceMap& map;
  const ImageView* intensity;  // Null: no intensities.
  geometry::PointCloud& cloud;
  const Eigen::Vector2f* camera_rays;  // Camera ray (x, y, 1) per pixel.
  ProjectorRayTable projector_rays;
  IntersectConstants constants;
  int w;  // Camera width and height in pixels.
  int h;
  bool subpixel;  // map.has_subpixel().
  // The isolated-point test: whether it runs, the depth tolerance in metres, the minimum
  // number of neighbours within it.
  bool remove_isolated;
  float tolerance;
  int min_neighbors;
};

// Per-task buffers of one row: the projector rays of its pixels and their statuses.
struct RowScratch {
  std::vector<Eigen::Vector4f> rays;
  std::vector<std::uint8_t> status;
  std::vector<std::uint8_t> flags;
};

// Setup stage of a task: its row buffers for a camera row of w pixels.
RowScratch MakeRowScratch(int w) {
  RowScratch scratch;
  scratch.rays.assign(static_cast<std::size_t>(w), Eigen::Vector4f::Zero());
  scratch.status.resize(static_cast<std::size_t>(w));
  scratch.flags.resize(static_cast<std::size_t>(w));
  return scratch;
}

// Per-row kernel: camera row y into out[0, w), before the isolated-point test: the projector
// ray of every valid pixel is looked up (interpolated for sub-pixel correspondences), then
// all pixels are intersected by the vectorised kernel.
template <bool kSubpixel>
void TriangulateRow(const RowContext& ctx, int y, Eigen::Vector3f* out, RowScratch* scratch,
                    Counts* counts) {
  const CorrespondenceMap& map = ctx.map;
  const int w = ctx.w;
  const std::size_t row_start = static_cast<std::size_t>(y) * w;
  const std::uint8_t* valid = map.valid.data() + row_start;
  Eigen::Vector4f* rays = scratch->rays.data();
  if constexpr (kSubpixel) {
    const ProjectorRayTable& table = ctx.projector_rays;
    const float* u = map.column_subpixel.data() + row_start;
    const float* v = map.row_subpixel.data() + row_start;
    for (int x = 0; x < w; ++x) {
      if (valid[x]) rays[x] = InterpolatedRay(table, u[x], v[x]);
    }
  } else {
    const std::uint16_t* column = map.column.data() + row_start;
    const std::uint16_t* row = map.row.data() + row_start;
    const Eigen::Vector4f* table = ctx.projector_rays.rays;
    const int projector_width = ctx.projector_rays.width;
    for (int x = 0; x < w; ++x) {
      if (valid[x]) rays[x] = table[static_cast<std::size_t>(row[x]) * projector_width + column[x]];
    }
  }
  IntersectRow(w, ctx.camera_rays[row_start].data(), rays->data(), valid, ctx.constants,
               out->data(), scratch->status.data());
  CountStatuses(w, scratch->status.data(), &counts->points, &counts->depth, &counts->residual);
}

// Per-row kernel: camera row y into out[0, w), integer or sub-pixel as the map is.
void Triangulate(const RowContext& ctx, int y, Eigen::Vector3f* out, RowScratch* scratch,
                 Counts* counts) {
  if (ctx.subpixel) {
    TriangulateRow<true>(ctx, y, out, scratch, counts);
  } else {
    TriangulateRow<false>(ctx, y, out, scratch, counts);
  }
}

// Per-row kernel: the intensities (0-1) of camera row y, if there is an intensity image.
void CopyIntensities(const RowContext& ctx, int y) {
  const ImageView* intensity = ctx.intensity;
  if (intensity == nullptr) return;
  const int w = ctx.w;
  const std::uint8_t* src = intensity->row(y);
  float* dst = ctx.cloud.intensities.data() + static_cast<std::size_t>(y) * w;
  for (int x = 0; x < w; ++x) dst[x] = src[x] * (1.0f / 255.0f);
}

// Filtering kernel: the isolated-point test of a row from the unfiltered rows above and below
// (null outside the image): flags[x] = 1 for every point with fewer than min_neighbors of its
// 8 neighbours within the depth tolerance, 0 elsewhere.
void TestRow(const RowContext& ctx, const Eigen::Vector3f* above, const Eigen::Vector3f* row,
             const Eigen::Vector3f* below, std::uint8_t* flags) {
  const int w = ctx.w;
  const float tolerance = ctx.tolerance;
  const int min_neighbors = ctx.min_neighbors;
  const auto general = [&](int x) {
    const float z = row[x].z();
    int neighbors = 0;
    for (const Eigen::Vector3f* line : {above, row, below}) {
      if (line == nullptr) continue;
      for (int dx = -1; dx <= 1; ++dx) {
        const int xx = x + dx;
        if ((line == row && dx == 0) || xx < 0 || xx >= w) continue;
        neighbors += std::abs(line[xx].z() - z) <= tolerance;
      }
    }
    flags[x] = static_cast<std::uint8_t>(!std::isnan(z) && neighbors < min_neighbors);
  };
  if (above == nullptr || below == nullptr || w < 3) {
    for (int x = 0; x < w; ++x) general(x);
    return;
  }
  general(0);
  IsolatedInterior(w, above->data(), row->data(), below->data(), tolerance, min_neighbors, flags);
  general(w - 1);
}

// Setup stage of a task: rows [y0, y1) of the outputs are about to be written by it.
void PopulateRows(const RowContext& ctx, int y0, int y1) {
  geometry::PointCloud& cloud = ctx.cloud;
  const int w = ctx.w;
  const std::size_t i0 = static_cast<std::size_t>(y0) * w;
  const std::size_t count = static_cast<std::size_t>(y1 - y0) * w;
  PopulateForWrite(cloud.points.data() + i0, count * sizeof(Eigen::Vector3f));
  if (!cloud.normals.empty()) {
    PopulateForWrite(cloud.normals.data() + i0, count * sizeof(Eigen::Vector3f));
  }
}

// Filtering stage without normals: flags the isolated points of every band, then removes them.
void RemoveIsolatedInBands(const RowContext& ctx, BandPool& pool,
                           std::vector<Counts>* band_counts) {
  const float kNaN = std::numeric_limits<float>::quiet_NaN();
  geometry::PointCloud& cloud = ctx.cloud;
  const int w = ctx.w;
  const int h = ctx.h;
  const int num_bands = static_cast<int>(band_counts->size());
  // Decide from the unfiltered cloud, then remove, so the result does not depend on the
  // order in which bands run.
  std::vector<std::vector<std::size_t>> remove(num_bands);
  pool.Run(num_bands, [&](int band) {
    const Eigen::Vector3f* points = cloud.points.data();
    const auto row = [&](int y) { return points + static_cast<std::size_t>(y) * w; };
    std::vector<std::uint8_t> flags(static_cast<std::size_t>(w));
    const int y1 = std::min(h, (band + 1) * kRowsPerBand);
    for (int y = band * kRowsPerBand; y < y1; ++y) {
      const std::size_t row_start = static_cast<std::size_t>(y) * w;
      TestRow(ctx, y > 0 ? row(y - 1) : nullptr, row(y), y + 1 < h ? row(y + 1) : nullptr,
              flags.data());
      for (int x = 0; x < w; ++x) {
        if (flags[x]) remove[band].push_back(row_start + x);
      }
    }
  });
  for (int band = 0; band < num_bands; ++band) {
    for (const std::size_t i : remove[band]) cloud.points[i].setConstant(kNaN);
    (*band_counts)[band].removed = remove[band].size();
  }
}

// Kernel stage without normals: triangulates in bands of kRowsPerBand rows, then filters.
Counts TriangulateInBands(const RowContext& ctx, BandPool& pool) {
  geometry::PointCloud& cloud = ctx.cloud;
  const int w = ctx.w;
  const int h = ctx.h;
  const int num_bands = (h + kRowsPerBand - 1) / kRowsPerBand;
  std::vector<Counts> band_counts(num_bands);
  pool.Run(num_bands, [&](int band) {
    PopulateRows(ctx, band * kRowsPerBand, std::min(h, (band + 1) * kRowsPerBand));
    RowScratch scratch = MakeRowScratch(w);
    const int y1 = std::min(h, (band + 1) * kRowsPerBand);
    for (int y = band * kRowsPerBand; y < y1; ++y) {
      Triangulate(ctx, y, cloud.points.data() + static_cast<std::size_t>(y) * w, &scratch,
                  &band_counts[band]);
      CopyIntensities(ctx, y);
    }
  });
  if (ctx.remove_isolated) RemoveIsolatedInBands(ctx, pool, &band_counts);
  return SumCounts(band_counts);
}

// Per-chunk kernel with normals: triangulates, filters and estimates normals of one chunk.
//
// Each chunk of rows is streamed row by row, so that every row is tested and its normals
// computed while it and its neighbours are in cache. Row r is triangulated, row r - 1 tested
// (it needs rows r - 2 ... r unfiltered), row r - 2 filtered (its last reader has been
// tested) and the normals of row r - step - 2 computed (they need the filtered rows
// step above and below). A chunk also triangulates and filters the step + 1 rows on
// each side that its own rows depend on.
void StreamChunk(const RowContext& ctx, int chunk, int step, float max_jump, Counts* chunk_counts) {
  geometry::PointCloud& cloud = ctx.cloud;
  const int w = ctx.w;
  const int h = ctx.h;
  const bool remove_isolated = ctx.remove_isolated;
  const int ring_rows = 4;  // Removal flags of rows r - 2 and r - 1.
  const int a = chunk * kRowsPerChunk;
  const int b = std::min(h, a + kRowsPerChunk);
  const int first = std::max(0, a - step - 1);  // Rows triangulated: [first, end).
  const int end = std::min(h, b + step + 1);
  const int tested_first = std::max(0, a - step);  // Rows tested and filtered.
  const int tested_end = std::min(h, b + step);
  // The chunk's own rows are computed in place in the cloud (no other task writes or
  // reads them); the rows around it that it depends on go to a buffer of its own.
  std::vector<Eigen::Vector3f> halo(static_cast<std::size_t>(2 * (step + 1)) * w);
  std::vector<std::uint8_t> isolated(static_cast<std::size_t>(ring_rows) * w);
  PopulateRows(ctx, a, b);
  RowScratch scratch = MakeRowScratch(w);
  const auto row = [&](int y) {
    if (y >= a && y < b) return cloud.points.data() + static_cast<std::size_t>(y) * w;
    const int slot = y < a ? y - first : (a - first) + (y - b);
    return halo.data() + static_cast<std::size_t>(slot) * w;
  };
  const auto flags = [&](int y) {
    return isolated.data() + static_cast<std::size_t>(y % ring_rows) * w;
  };
  Counts& counts = *chunk_counts;
  for (int r = first; r <= b + step + 1; ++r) {
    if (r < end) {
      Counts row_counts;
      Triangulate(ctx, r, row(r), &scratch, &row_counts);
      if (r >= a && r < b) {
        CopyIntensities(ctx, r);
        counts.points += row_counts.points;
        counts.residual += row_counts.residual;
        counts.depth += row_counts.depth;
      }
    }
    const int q = r - 1;
    if (remove_isolated && q >= tested_first && q < tested_end) {
      TestRow(ctx, q > 0 ? row(q - 1) : nullptr, row(q), q + 1 < h ? row(q + 1) : nullptr,
              flags(q));
    }
    const int filtered = r - 2;
    if (remove_isolated && filtered >= tested_first && filtered < tested_end) {
      const int removed = RemoveFlagged(w, flags(filtered), row(filtered));
      if (filtered >= a && filtered < b) counts.removed += static_cast<std::size_t>(removed);
    }
    const int y = r - step - 2;
    if (y >= a && y < b) {
      const std::size_t row_start = static_cast<std::size_t>(y) * w;
      counts.normals += EstimateNormalsRow(y - step >= 0 ? row(y - step) : nullptr, row(y),
                                           y + step < h ? row(y + step) : nullptr, w, step,
                                           max_jump, cloud.normals.data() + row_start);
    }
  }
}

// Kernel stage with normals: streams the cloud in chunks of kRowsPerChunk rows (StreamChunk).
Counts TriangulateInChunksWithNormals(const RowContext& ctx, const NormalOptions& normal_options,
                                      BandPool& pool) {
  const int step = normal_options.step;
  const float max_jump = static_cast<float>(normal_options.max_depth_jump_m * step);
  const int num_chunks = (ctx.h + kRowsPerChunk - 1) / kRowsPerChunk;
  std::vector<Counts> chunk_counts(num_chunks);
  pool.Run(num_chunks,
           [&](int chunk) { StreamChunk(ctx, chunk, step, max_jump, &chunk_counts[chunk]); });
  return SumCounts(chunk_counts);
}

}  // namespace

Triangulator::Triangulator(const camera::PinholeCamera& camera,
                           const camera::PinholeCamera& projector,
                           const Eigen::Isometry3d& X_CameraProjector,
                           const TriangulationOptions& options)
    : camera_width_(camera.width()),
      camera_height_(camera.height()),
      projector_width_(projector.width()),
      projector_height_(projector.height()),
      options_(options) {
  Require(options.max_residual_projector_px >= 0,
          "options.max_residual_projector_px must not be negative");
  Require(options.min_depth_m > 0 && options.max_depth_m > options.min_depth_m,
          "options need 0 < min_depth_m < max_depth_m, got [" +
              std::to_string(options.min_depth_m) + ", " + std::to_string(options.max_depth_m) +
              "]");
  Require(options.min_neighbors >= 0 && options.min_neighbors <= 8,
          "options.min_neighbors must be in [0, 8], got " + std::to_string(options.min_neighbors));
  Require(options.neighbor_depth_tolerance_m >= 0,
          "options.neighbor_depth_tolerance_m must not be negative");
  Require(options.num_threads >= 0, "options.num_threads must not be negative");
  const Eigen::Matrix3d R = X_CameraProjector.linear();
  Require(X_CameraProjector.matrix().allFinite() &&
              (R * R.transpose() - Eigen::Matrix3d::Identity()).norm() < 1e-6 &&
              R.determinant() > 0,
          "X_CameraProjector must be a finite rigid transform");

  pool_ = std::make_unique<BandPool>(options.num_threads);
  projector_focal_px_ = static_cast<float>(std::min(projector.fx(), projector.fy()));
  const Eigen::Vector3d p_CameraProjector = X_CameraProjector.translation();
  p_CameraProjector_ = p_CameraProjector.cast<float>();
  rays_ = camera.ComputeRayTable().xy;

  const Eigen::Matrix3f R_CameraProjector = R.cast<float>();
  projector_rays_.resize(static_cast<std::size_t>(projector_width_) * projector_height_);
  pool_->Run(projector_height_, [&](int row) {
    for (int column = 0; column < projector_width_; ++column) {
      const Eigen::Vector3f e =
          (R_CameraProjector * projector.RayDirection(Eigen::Vector2d(column, row)).cast<float>())
              .normalized();
      projector_rays_[static_cast<std::size_t>(row) * projector_width_ + column] =
          Eigen::Vector4f(e.x(), e.y(), e.z(), -e.dot(p_CameraProjector_));
    }
  });
}

Triangulator::~Triangulator() = default;

TriangulationResult Triangulator::Run(const CorrespondenceMap& map,
                                      const ImageView* intensity) const {
  TriangulationResult result;
  Run(map, intensity, &result);
  return result;
}

void Triangulator::Run(const CorrespondenceMap& map, const ImageView* intensity,
                       TriangulationResult* result) const {
  RunImpl(map, intensity, nullptr, result, nullptr);
}

void Triangulator::Run(const CorrespondenceMap& map, const ImageView* intensity,
                       const NormalOptions& normal_options, TriangulationResult* result,
                       NormalResult* normal_result) const {
  CheckNormalOptions(normal_options, "Triangulator");
  Require(camera_height_ > 1, "normals need a camera with more than one row");
  RunImpl(map, intensity, &normal_options, result, normal_result);
}

void Triangulator::CheckInputSizes(const CorrespondenceMap& map, const ImageView* intensity) const {
  const std::size_t n = static_cast<std::size_t>(camera_width_) * camera_height_;
  Require(map.width == camera_width_ && map.height == camera_height_,
          "correspondence map is " + std::to_string(map.width) + " x " +
              std::to_string(map.height) + " but the camera is " + std::to_string(camera_width_) +
              " x " + std::to_string(camera_height_));
  Require(map.column.size() == n && map.row.size() == n && map.valid.size() == n,
          "correspondence map buffers are not width * height long");
  if (intensity != nullptr) {
    Require(intensity->data != nullptr && intensity->width == camera_width_ &&
                intensity->height == camera_height_ && intensity->stride_bytes >= camera_width_,
            "intensity image is " + std::to_string(intensity->width) + " x " +
                std::to_string(intensity->height) + " (or has no data / a short stride) but " +
                "the camera is " + std::to_string(camera_width_) + " x " +
                std::to_string(camera_height_));
  }
  if (map.has_subpixel()) {
    Require(map.column_subpixel.size() == n && map.row_subpixel.size() == n,
            "sub-pixel correspondence maps are not width * height long");
  }
}

void Triangulator::CheckCorrespondencesInside(const CorrespondenceMap& map) const {
  const std::size_t n = static_cast<std::size_t>(camera_width_) * camera_height_;
  const bool subpixel = map.has_subpixel();
  const int num_bands = (camera_height_ + kRowsPerBand - 1) / kRowsPerBand;
  // The projector image spans [-0.5, size - 0.5]; NaN fails the test too.
  const float max_u = static_cast<float>(projector_width_) - 0.5f;
  const float max_v = static_cast<float>(projector_height_) - 0.5f;
  const auto inside = [&](std::size_t i) {
    return map.column[i] < projector_width_ && map.row[i] < projector_height_ &&
           (!subpixel || (map.column_subpixel[i] >= -0.5f && map.column_subpixel[i] <= max_u &&
                          map.row_subpixel[i] >= -0.5f && map.row_subpixel[i] <= max_v));
  };
  // A branch-free pass over all pixels finds whether any is bad; only then are they
  // searched for the first one to name it.
  std::atomic<int> outside{0};
  const std::uint8_t* valid = map.valid.data();
  const std::uint16_t* column = map.column.data();
  const std::uint16_t* row = map.row.data();
  const float* u = map.column_subpixel.data();
  const float* v = map.row_subpixel.data();
  const int projector_width = projector_width_;
  const int projector_height = projector_height_;
  pool_->Run(num_bands, [&](int band) {
    const std::size_t i0 = static_cast<std::size_t>(band) * kRowsPerBand * camera_width_;
    const std::size_t i1 =
        static_cast<std::size_t>(std::min(camera_height_, (band + 1) * kRowsPerBand)) *
        camera_width_;
    int local = 0;
    for (std::size_t i = i0; i < i1; ++i) {
      local |= valid[i] & ((column[i] >= projector_width) | (row[i] >= projector_height));
    }
    if (subpixel) {
      for (std::size_t i = i0; i < i1; ++i) {
        local |=
            valid[i] & !((u[i] >= -0.5f) & (u[i] <= max_u) & (v[i] >= -0.5f) & (v[i] <= max_v));
      }
    }
    if (local) outside.store(1, std::memory_order_relaxed);
  });
  for (std::size_t i = 0; outside.load() && i < n; ++i) {
    if (!map.valid[i] || inside(i)) continue;
    if (map.column[i] >= projector_width_ || map.row[i] >= projector_height_) {
      Require(false, "correspondence (" + std::to_string(map.column[i]) + ", " +
                         std::to_string(map.row[i]) + ") at pixel " + std::to_string(i) +
                         " lies outside the " + std::to_string(projector_width_) + " x " +
                         std::to_string(projector_height_) + " projector");
    }
    Require(false, "sub-pixel correspondence (" + std::to_string(map.column_subpixel[i]) + ", " +
                       std::to_string(map.row_subpixel[i]) + ") at pixel " + std::to_string(i) +
                       " lies outside the " + std::to_string(projector_width_) + " x " +
                       std::to_string(projector_height_) + " projector");
  }
}

void Triangulator::SizeOutputs(const ImageView* intensity, bool with_normals,
                               geometry::PointCloud* cloud_out) const {
  const std::size_t n = static_cast<std::size_t>(camera_width_) * camera_height_;
  geometry::PointCloud& cloud = *cloud_out;
  cloud.width = static_cast<std::uint32_t>(camera_width_);
  cloud.height = static_cast<std::uint32_t>(camera_height_);
  cloud.frame_id = options_.frame_id;
  // Reserved and advised before the first write (resize zero-fills the intensities).
  cloud.points.reserve(n);
  AdviseHugePages(cloud.points.data(), n * sizeof(Eigen::Vector3f));
  cloud.points.resize(n);
  cloud.normals.clear();
  cloud.colors.clear();
  if (intensity != nullptr) {
    cloud.intensities.reserve(n);
    AdviseHugePages(cloud.intensities.data(), n * sizeof(float));
    PopulateForWrite(cloud.intensities.data(), n * sizeof(float));
    cloud.intensities.resize(n);
  } else {
    cloud.intensities.clear();
  }
  if (with_normals) {
    cloud.normals.reserve(n);
    AdviseHugePages(cloud.normals.data(), n * sizeof(Eigen::Vector3f));
    cloud.normals.resize(n);
  }
}

void Triangulator::RunImpl(const CorrespondenceMap& map, const ImageView* intensity,
                           const NormalOptions* normal_options, TriangulationResult* result,
                           NormalResult* normal_result) const {
  Require(result != nullptr, "result is null");
  CheckInputSizes(map, intensity);
  CheckCorrespondencesInside(map);
  SizeOutputs(intensity, normal_options != nullptr, &result->cloud);

  const float residual_scale =
      static_cast<float>(options_.max_residual_projector_px) / projector_focal_px_;
  // ray distance <= k * distance_from_projector / f
  const float residual_factor = residual_scale * residual_scale;
  const float min_depth = static_cast<float>(options_.min_depth_m);
  const float max_depth = static_cast<float>(options_.max_depth_m);
  const Eigen::Vector3f o = p_CameraProjector_;
  const RowContext ctx{
      map,
      intensity,
      result->cloud,
      rays_.data(),
      MakeProjectorRayTable(projector_rays_, projector_width_, projector_height_),
      IntersectConstants{o.x(), o.y(), o.z(), min_depth, max_depth, residual_factor},
      camera_width_,
      camera_height_,
      map.has_subpixel(),
      options_.remove_isolated && options_.min_neighbors > 0,
      static_cast<float>(options_.neighbor_depth_tolerance_m),
      options_.min_neighbors};

  Counts total;
  if (normal_options == nullptr) {
    total = TriangulateInBands(ctx, *pool_);
  } else {
    total = TriangulateInChunksWithNormals(ctx, *normal_options, *pool_);
    if (normal_result != nullptr) normal_result->num_normals = total.normals;
  }
  result->num_rejected_residual = total.residual;
  result->num_rejected_depth = total.depth;
  result->num_removed_isolated = total.removed;
  result->num_points = total.points - total.removed;
}

}  // namespace picking::scanner
