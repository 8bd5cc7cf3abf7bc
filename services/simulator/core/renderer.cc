#include "services/simulator/core/renderer.h"

#include <embree3/rtcore.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <mutex>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <utility>

#include "libs/parallel/parallel_for.h"

namespace picking::simulator {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
// Rows per work item of the parallel loops: small enough to balance two to a few dozen
// threads, large enough to keep scheduling overhead negligible.
constexpr int kRowsPerBlock = 8;
// Rays per Embree packet (rtcIntersect8).
constexpr int kLanes = 8;

// Every parallel loop here is parallel::ParallelFor over blocks of rows: threads started per
// call (the caller's included, thread 0), blocks taken in order from a shared counter.
using parallel::ParallelFor;
using parallel::ResolveThreads;

bool IsFinitePose(const Eigen::Isometry3d& X) {
  if (!X.matrix().allFinite()) return false;
  const Eigen::Matrix3d R = X.linear();
  return (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() < 1e-6 &&
         R.determinant() > 0.0;
}

std::string ObjectLabel(std::size_t index, const world::TriangleMesh* mesh) {
  std::ostringstream out;
  out << "StructuredLightRenderer: object " << index;
  if (mesh != nullptr && !mesh->name.empty()) out << " ('" << mesh->name << "')";
  return out.str();
}

// Mesh data the renderer keeps: the object-frame vertices (to re-pose) and the albedo.
struct ObjectData {
  std::vector<Eigen::Vector3f> vertices_object;
  std::vector<std::array<std::uint32_t, 3>> triangles;
  std::vector<float> vertex_albedo;
  std::vector<std::array<std::uint8_t, 3>> vertex_colors;
  float albedo = 0.0f;
  Eigen::Isometry3d X_BaseObject = Eigen::Isometry3d::Identity();
  unsigned geom_id = RTC_INVALID_GEOMETRY_ID;

  float AlbedoAt(unsigned prim, float u, float v) const {
    if (vertex_albedo.empty()) return albedo;
    const auto& tri = triangles[prim];
    return (1.0f - u - v) * vertex_albedo[tri[0]] + u * vertex_albedo[tri[1]] +
           v * vertex_albedo[tri[2]];
  }
  // RGB reflectance in [0, 1]: the vertex colours interpolated, or grey at the albedo.
  Eigen::Vector3f ColourAt(unsigned prim, float u, float v) const {
    if (vertex_colors.empty()) return Eigen::Vector3f::Constant(AlbedoAt(prim, u, v));
    const auto& tri = triangles[prim];
    auto colour = [&](int k) -> Eigen::Vector3f {
      const auto& c = vertex_colors[tri[k]];
      return Eigen::Vector3f(c[0], c[1], c[2]) / 255.0f;
    };
    return (1.0f - u - v) * colour(0) + u * colour(1) + v * colour(2);
  }
};

ObjectData CheckedCopy(std::size_t index, const SceneObject& object) {
  const world::TriangleMesh* mesh = object.mesh;
  const std::string label = ObjectLabel(index, mesh);
  if (mesh == nullptr) throw std::invalid_argument(label + ": mesh is null");
  if (!IsFinitePose(object.X_BaseObject)) {
    throw std::invalid_argument(label + ": X_BaseObject is not a finite rigid transform");
  }
  const std::size_t nv = mesh->vertices.size();
  for (std::size_t i = 0; i < nv; ++i) {
    if (!mesh->vertices[i].allFinite()) {
      throw std::invalid_argument(label + ": vertices[" + std::to_string(i) + "] is not finite");
    }
  }
  for (std::size_t t = 0; t < mesh->triangles.size(); ++t) {
    for (int k = 0; k < 3; ++k) {
      if (mesh->triangles[t][k] >= nv) {
        throw std::invalid_argument(label + ": triangles[" + std::to_string(t) + "][" +
                                    std::to_string(k) +
                                    "] = " + std::to_string(mesh->triangles[t][k]) +
                                    " is not below " + std::to_string(nv) + " vertices");
      }
    }
  }
  if (!mesh->vertex_albedo.empty() && mesh->vertex_albedo.size() != nv) {
    throw std::invalid_argument(label + ": vertex_albedo has " +
                                std::to_string(mesh->vertex_albedo.size()) + " entries for " +
                                std::to_string(nv) + " vertices");
  }
  for (std::size_t i = 0; i < mesh->vertex_albedo.size(); ++i) {
    const float a = mesh->vertex_albedo[i];
    if (!(a >= 0.0f && a <= 1.0f)) {
      throw std::invalid_argument(label + ": vertex_albedo[" + std::to_string(i) +
                                  "] is not in [0, 1]");
    }
  }
  if (!(mesh->albedo >= 0.0f && mesh->albedo <= 1.0f)) {
    throw std::invalid_argument(label + ": albedo is not in [0, 1]");
  }
  if (!mesh->vertex_colors.empty() && mesh->vertex_colors.size() != nv) {
    throw std::invalid_argument(label + ": vertex_colors has " +
                                std::to_string(mesh->vertex_colors.size()) + " entries for " +
                                std::to_string(nv) + " vertices");
  }
  ObjectData data;
  data.vertices_object = mesh->vertices;
  data.triangles = mesh->triangles;
  data.vertex_albedo = mesh->vertex_albedo;
  data.vertex_colors = mesh->vertex_colors;
  data.albedo = mesh->albedo;
  data.X_BaseObject = object.X_BaseObject;
  return data;
}

void WriteVertices(const ObjectData& object, float* out) {
  const Eigen::Matrix3f R = object.X_BaseObject.linear().cast<float>();
  const Eigen::Vector3f t = object.X_BaseObject.translation().cast<float>();
  for (std::size_t i = 0; i < object.vertices_object.size(); ++i) {
    const Eigen::Vector3f p = R * object.vertices_object[i] + t;
    out[3 * i + 0] = p.x();
    out[3 * i + 1] = p.y();
    out[3 * i + 2] = p.z();
  }
}

void ThrowOnDeviceError(RTCDevice device, const char* what) {
  const RTCError error = rtcGetDeviceError(device);
  if (error != RTC_ERROR_NONE) {
    throw std::runtime_error(std::string("StructuredLightRenderer: Embree error ") +
                             std::to_string(static_cast<int>(error)) + " in " + what);
  }
}

bool SameModel(const camera::PinholeCamera& a, const camera::PinholeCamera& b) {
  const camera::Distortion& da = a.distortion();
  const camera::Distortion& db = b.distortion();
  return a.width() == b.width() && a.height() == b.height() && a.fx() == b.fx() &&
         a.fy() == b.fy() && a.cx() == b.cx() && a.cy() == b.cy() && da.k1 == db.k1 &&
         da.k2 == db.k2 && da.p1 == db.p1 && da.p2 == db.p2 && da.k3 == db.k3;
}

// splitmix64: a small, fast, well-mixed generator; one stream per (seed, frame, row) keeps
// the noise independent of the thread schedule.
struct SplitMix64 {
  std::uint64_t state;
  std::uint64_t Next() {
    std::uint64_t z = (state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
};

// Inverse of the standard normal CDF: Acklam's rational approximation (relative error
// 1.2e-9) refined by one Halley step on erfc.
double InverseNormalCdf(double p) {
  static constexpr double a[] = {-3.969683028665376e+01, 2.209460984245205e+02,
                                 -2.759285104469687e+02, 1.383577518672690e+02,
                                 -3.066479806614716e+01, 2.506628277459239e+00};
  static constexpr double b[] = {-5.447609879822406e+01, 1.615858368580409e+02,
                                 -1.556989798598866e+02, 6.680131188771972e+01,
                                 -1.328068155288572e+01};
  static constexpr double c[] = {-7.784894002430293e-03, -3.223964580411365e-01,
                                 -2.400758277161838e+00, -2.549732539343734e+00,
                                 4.374664141464968e+00,  2.938163982698783e+00};
  static constexpr double d[] = {7.784695709041462e-03, 3.224671290700398e-01,
                                 2.445134137142996e+00, 3.754408661907416e+00};
  constexpr double kLow = 0.02425;
  double x;
  if (p < kLow) {
    const double q = std::sqrt(-2.0 * std::log(p));
    x = (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) /
        ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0);
  } else if (p <= 1.0 - kLow) {
    const double q = p - 0.5;
    const double r = q * q;
    x = (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q /
        (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0);
  } else {
    const double q = std::sqrt(-2.0 * std::log(1.0 - p));
    x = -(((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) /
        ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0);
  }
  const double e = 0.5 * std::erfc(-x / std::sqrt(2.0)) - p;
  constexpr double kSqrt2Pi = 2.5066282746310002;
  const double u = e * kSqrt2Pi * std::exp(0.5 * x * x);
  return x - u / (1.0 + 0.5 * x * u);
}

// Standard normal deviates drawn by a 16-bit index: the quantiles at (k + 0.5) / 65536,
// scaled to unit variance (tails reach 4.3 sigma). One 64-bit random number gives four
// deviates, which makes sensor noise cheap enough for 44 megapixel images per scan.
constexpr int kNormalTableBits = 16;
const std::vector<float>& NormalTable() {
  static const std::vector<float> table = [] {
    const int n = 1 << kNormalTableBits;
    std::vector<double> q(n);
    double sum2 = 0.0;
    for (int k = 0; k < n; ++k) {
      q[k] = InverseNormalCdf((k + 0.5) / n);
      sum2 += q[k] * q[k];
    }
    const double scale = 1.0 / std::sqrt(sum2 / n);
    std::vector<float> out(n);
    for (int k = 0; k < n; ++k) out[k] = static_cast<float>(q[k] * scale);
    return out;
  }();
  return table;
}

std::uint64_t RowSeed(std::uint64_t seed, std::uint64_t frame, int row) {
  SplitMix64 mix{seed};
  mix.state ^= mix.Next() + frame * 0xD1B54A32D192ED03ull;
  mix.state ^= mix.Next() + static_cast<std::uint64_t>(row) * 0x8CB92BA72F3D8DD7ull;
  return mix.Next();
}

// Projector light of a projected image as DN per unit gain, read through a 256-entry table
// or (when blurred) from a float image.
struct LutLight {
  const std::uint8_t* pixels;
  const float* lut;
  float operator[](std::size_t i) const { return lut[pixels[i]]; }
};
struct FloatLight {
  const float* pixels;
  float operator[](std::size_t i) const { return pixels[i]; }
};

// Separable Gaussian blur with clamped borders of the width x height float image `image`,
// in place; `tmp` is scratch of the same size (both reused across frames: fresh memory costs
// more in page faults than the blur itself).
void Blur(std::vector<float>* image, std::vector<float>* scratch, int width, int height,
          double sigma, int threads) {
  const int radius = std::max(1, static_cast<int>(std::ceil(3.0 * sigma)));
  std::vector<float> kernel(2 * radius + 1);
  double sum = 0.0;
  for (int k = -radius; k <= radius; ++k) {
    kernel[k + radius] = static_cast<float>(std::exp(-0.5 * k * k / (sigma * sigma)));
    sum += kernel[k + radius];
  }
  for (float& w : kernel) w = static_cast<float>(w / sum);
  std::vector<float>& in = *image;
  std::vector<float>& out = *image;
  std::vector<float>& tmp = *scratch;
  tmp.resize(in.size());
  const int blocks = (height + kRowsPerBlock - 1) / kRowsPerBlock;
  // Both passes run over contiguous rows with the tap loop outside, so they vectorise.
  ParallelFor(blocks, threads, [&](int b) {
    std::vector<float> padded(width + 2 * radius);
    for (int y = b * kRowsPerBlock; y < std::min(height, (b + 1) * kRowsPerBlock); ++y) {
      const float* row = &in[std::size_t(y) * width];
      for (int x = -radius; x < width + radius; ++x) {
        padded[x + radius] = row[std::clamp(x, 0, width - 1)];
      }
      float* dst = &tmp[std::size_t(y) * width];
      std::fill(dst, dst + width, 0.0f);
      for (int k = 0; k <= 2 * radius; ++k) {
        const float w = kernel[k];
        const float* src = &padded[k];
        for (int x = 0; x < width; ++x) dst[x] += w * src[x];
      }
    }
  });
  ParallelFor(blocks, threads, [&](int b) {
    for (int y = b * kRowsPerBlock; y < std::min(height, (b + 1) * kRowsPerBlock); ++y) {
      float* dst = &out[std::size_t(y) * width];
      std::fill(dst, dst + width, 0.0f);
      for (int k = -radius; k <= radius; ++k) {
        const float w = kernel[k + radius];
        const float* src = &tmp[std::size_t(std::clamp(y + k, 0, height - 1)) * width];
        for (int x = 0; x < width; ++x) dst[x] += w * src[x];
      }
    }
  });
}

void CheckGeometry(const ScanGeometry& g) {
  const std::size_t n = g.size();
  if (g.width <= 0 || g.height <= 0 || g.projector_width <= 0 || g.projector_height <= 0 ||
      g.albedo.size() != n || g.illumination.size() != n || g.projector_uv.size() != n ||
      g.gain.size() != n) {
    throw std::invalid_argument(
        "RenderImage: ScanGeometry is incomplete (sizes or per-pixel arrays); build it with "
        "StructuredLightRenderer::Prepare");
  }
}

void CheckProjectorImage(const ScanGeometry& g, const GrayImage& image, std::size_t index) {
  if (image.width != g.projector_width || image.height != g.projector_height ||
      image.pixels.size() != std::size_t(image.width) * image.height) {
    std::ostringstream out;
    out << "RenderImage: projector image " << index << " is " << image.width << " x "
        << image.height << " with " << image.pixels.size() << " pixels, expected "
        << g.projector_width << " x " << g.projector_height;
    throw std::invalid_argument(out.str());
  }
}

// Light of each projector value in DN per unit gain.
std::vector<float> LightTable(const RenderOptions& o) {
  std::vector<float> lut(256);
  for (int v = 0; v < 256; ++v) {
    lut[v] = static_cast<float>(255.0 * o.exposure * o.projector_brightness *
                                std::pow(v / 255.0, o.projector_gamma));
  }
  return lut;
}

// Where the surface of a camera pixel reads the projector image (index of the top-left
// bilinear neighbour, or -1 if unlit) and with which weights; shared by all frames.
struct PixelSample {
  std::int32_t index;
  float au;
  float av;
  float gain;
};

// Shading data of one block of camera rows, built per block so that it stays in cache while
// all frames are shaded and no image-sized table is allocated.
struct BlockTable {
  std::vector<PixelSample> samples;
  std::vector<float> ambient_dn;  // Ambient signal per pixel, DN.
  std::vector<float> scratch;     // 2 * width floats for ShadeRow.
};

// Offsets to the right and lower projector neighbours (0 for a 1-wide / 1-high projector).
std::size_t RightOffset(const ScanGeometry& g) { return g.projector_width > 1 ? 1 : 0; }
std::size_t DownOffset(const ScanGeometry& g) {
  return g.projector_height > 1 ? static_cast<std::size_t>(g.projector_width) : 0;
}

void FillBlockTable(const ScanGeometry& g, const RenderOptions& o, int row_begin, int row_end,
                    BlockTable* t) {
  const int pw = g.projector_width;
  const int ph = g.projector_height;
  const int u_last = pw - 1 - static_cast<int>(RightOffset(g));
  const int v_last = ph - 1 - (DownOffset(g) ? 1 : 0);
  const std::size_t begin = std::size_t(row_begin) * g.width;
  const std::size_t count = std::size_t(row_end - row_begin) * g.width;
  t->samples.resize(count);
  t->ambient_dn.resize(count);
  t->scratch.resize(2 * std::size_t(g.width));
  const float ambient_dn = static_cast<float>(255.0 * o.exposure * o.ambient);
  const bool bilinear = o.sampling == ProjectorSampling::kBilinear;
  for (std::size_t j = 0; j < count; ++j) {
    const std::size_t i = begin + j;
    t->ambient_dn[j] = ambient_dn * g.albedo[i];
    PixelSample& p = t->samples[j];
    p = {-1, 0.0f, 0.0f, 0.0f};
    if (g.illumination[i] != Illumination::kLit) continue;
    const float u = g.projector_uv[i].x();
    const float v = g.projector_uv[i].y();
    int u0, v0;
    if (bilinear) {
      // Clamp so that the four neighbours exist; the weights reproduce edge clamping.
      u0 = static_cast<int>(std::floor(u));
      v0 = static_cast<int>(std::floor(v));
      p.au = u - static_cast<float>(u0);
      p.av = v - static_cast<float>(v0);
      if (u0 < 0) {
        u0 = 0;
        p.au = 0.0f;
      } else if (u0 > u_last) {
        u0 = u_last;
        p.au = u_last < pw - 1 ? 1.0f : 0.0f;
      }
      if (v0 < 0) {
        v0 = 0;
        p.av = 0.0f;
      } else if (v0 > v_last) {
        v0 = v_last;
        p.av = v_last < ph - 1 ? 1.0f : 0.0f;
      }
    } else {
      u0 = std::clamp(static_cast<int>(std::lround(u)), 0, pw - 1);
      v0 = std::clamp(static_cast<int>(std::lround(v)), 0, ph - 1);
    }
    p.index = v0 * pw + u0;
    p.gain = g.gain[i];
  }
}

// Shades one camera row of one frame from its table entries.
template <bool kBilinear, class Light>
void ShadeRow(const PixelSample* samples, const float* ambient, std::size_t du, std::size_t dv,
              const Light& light, const RenderOptions& o, std::uint64_t frame, int y, int width,
              float* scratch, std::uint8_t* dst) {
  // Pass 1 (gathers, scalar): noise-free signal.
  float* signal = scratch;
  for (int x = 0; x < width; ++x) {
    const PixelSample& p = samples[x];
    float s = ambient[x];
    if (p.index >= 0) {
      const std::size_t k = static_cast<std::size_t>(p.index);
      float l;
      if constexpr (kBilinear) {
        const float l00 = light[k];
        const float l01 = light[k + du];
        const float l10 = light[k + dv];
        const float l11 = light[k + dv + du];
        const float top = l00 + p.au * (l01 - l00);
        const float bottom = l10 + p.au * (l11 - l10);
        l = top + p.av * (bottom - top);
      } else {
        l = light[k];
      }
      s += p.gain * l;
    }
    signal[x] = s;
  }
  Eigen::Map<Eigen::ArrayXf> s(signal, width);
  // Pass 2 (SIMD through Eigen): noise, response, quantisation.
  const float read_var = static_cast<float>(o.read_noise_dn * o.read_noise_dn);
  const float shot_scale =
      o.electrons_per_dn > 0.0 ? static_cast<float>(1.0 / o.electrons_per_dn) : 0.0f;
  if (read_var > 0.0f || shot_scale > 0.0f) {
    float* normal = scratch + width;
    const float* table = NormalTable().data();
    SplitMix64 rng{RowSeed(o.seed, frame, y)};
    for (int x = 0; x < width; x += 4) {
      std::uint64_t bits = rng.Next();
      for (int k = 0; k < 4 && x + k < width; ++k, bits >>= 16) {
        normal[x + k] = table[bits & 0xFFFF];
      }
    }
    const Eigen::Map<const Eigen::ArrayXf> n(normal, width);
    s += (read_var + shot_scale * s.max(0.0f)).sqrt() * n;
  }
  s = s.max(0.0f);
  if (o.camera_gamma != 1.0) s = 255.0f * (s * (1.0f / 255.0f)).pow(1.0f / float(o.camera_gamma));
  s = s.min(255.0f) + 0.5f;
  for (int x = 0; x < width; ++x) dst[x] = static_cast<std::uint8_t>(signal[x]);
}

// Shades rows [row_begin, row_end) of every frame; `lights[f]` is frame f's projector light,
// `frame_ids[f]` its noise stream and `out[f]` its image.
template <class Light>
void ShadeBlock(const ScanGeometry& g, const std::vector<Light>& lights,
                const std::vector<std::uint64_t>& frame_ids, const RenderOptions& o, int row_begin,
                int row_end, const std::vector<GrayImage*>& out, BlockTable* table) {
  FillBlockTable(g, o, row_begin, row_end, table);
  const std::size_t du = RightOffset(g);
  const std::size_t dv = DownOffset(g);
  // Frames in the inner loop: the block's table stays in cache across frames.
  for (std::size_t f = 0; f < lights.size(); ++f) {
    for (int y = row_begin; y < row_end; ++y) {
      const std::size_t offset = std::size_t(y - row_begin) * g.width;
      const PixelSample* samples = &table->samples[offset];
      const float* ambient = &table->ambient_dn[offset];
      std::uint8_t* dst = &out[f]->pixels[std::size_t(y) * g.width];
      if (o.sampling == ProjectorSampling::kBilinear) {
        ShadeRow<true>(samples, ambient, du, dv, lights[f], o, frame_ids[f], y, g.width,
                       table->scratch.data(), dst);
      } else {
        ShadeRow<false>(samples, ambient, du, dv, lights[f], o, frame_ids[f], y, g.width,
                        table->scratch.data(), dst);
      }
    }
  }
}

// Renders images[k] as frame first_frame + k into (*out)[k], reusing its buffers.
void Shade(const ScanGeometry& g, const std::vector<const GrayImage*>& images,
           std::uint64_t first_frame, const RenderOptions& o, std::vector<GrayImage>* out) {
  const int threads = ResolveThreads(o.num_threads);
  const int blocks = (g.height + kRowsPerBlock - 1) / kRowsPerBlock;
  const std::vector<float> lut = LightTable(o);
  out->resize(images.size());
  std::vector<GrayImage*> targets;
  for (GrayImage& image : *out) {
    if (image.width != g.width || image.height != g.height || image.pixels.size() != g.size()) {
      image = GrayImage(g.width, g.height);
    }
    targets.push_back(&image);
  }
  std::vector<BlockTable> tables(std::max(1, std::min(threads, blocks)));
  auto shade = [&](const auto& lights, const std::vector<std::uint64_t>& frame_ids,
                   const std::vector<GrayImage*>& target) {
    ParallelFor(blocks, threads, [&](int b, int worker) {
      ShadeBlock(g, lights, frame_ids, o, b * kRowsPerBlock,
                 std::min(g.height, (b + 1) * kRowsPerBlock), target, &tables[worker]);
    });
  };
  if (o.projector_blur_sigma_px <= 0.0) {
    std::vector<LutLight> lights;
    std::vector<std::uint64_t> frame_ids;
    for (std::size_t k = 0; k < images.size(); ++k) {
      lights.push_back({images[k]->pixels.data(), lut.data()});
      frame_ids.push_back(first_frame + k);
    }
    shade(lights, frame_ids, targets);
    return;
  }
  // Blurred light is a float image per frame: a few frames at a time bound the memory while
  // each block table still serves several frames.
  constexpr std::size_t kBlurChunk = 4;
  std::vector<std::vector<float>> light(std::min(kBlurChunk, images.size()));
  std::vector<float> scratch;
  for (std::size_t first = 0; first < images.size(); first += kBlurChunk) {
    const std::size_t count = std::min(kBlurChunk, images.size() - first);
    std::vector<FloatLight> lights;
    std::vector<std::uint64_t> frame_ids;
    std::vector<GrayImage*> chunk_targets;
    for (std::size_t c = 0; c < count; ++c) {
      const GrayImage& image = *images[first + c];
      std::vector<float>& l = light[c];
      l.resize(image.pixels.size());
      for (std::size_t i = 0; i < l.size(); ++i) l[i] = lut[image.pixels[i]];
      Blur(&l, &scratch, image.width, image.height, o.projector_blur_sigma_px, threads);
      lights.push_back({l.data()});
      frame_ids.push_back(first_frame + first + c);
      chunk_targets.push_back(targets[first + c]);
    }
    shade(lights, frame_ids, chunk_targets);
  }
}

void CheckFinite(double value, const char* field) {
  if (!std::isfinite(value)) {
    throw std::invalid_argument(std::string(field) + " is not finite");
  }
}

// Rejects a null output, non-rigid poses and out-of-range options of Prepare before
// anything is touched (so that *geometry stays unchanged on error).
void CheckPrepareArguments(const ScanPose& pose, const GeometryOptions& options,
                           const ScanGeometry* geometry) {
  if (geometry == nullptr) throw std::invalid_argument("Prepare: geometry is null");
  if (!IsFinitePose(pose.X_BaseCamera)) {
    throw std::invalid_argument("Prepare: X_BaseCamera is not a finite rigid transform");
  }
  if (!IsFinitePose(pose.X_BaseProjector)) {
    throw std::invalid_argument("Prepare: X_BaseProjector is not a finite rigid transform");
  }
  CheckFinite(options.reference_distance_m, "GeometryOptions.reference_distance_m");
  CheckFinite(options.shadow_epsilon_m, "GeometryOptions.shadow_epsilon_m");
  if (options.reference_distance_m <= 0.0) {
    throw std::invalid_argument("GeometryOptions.reference_distance_m must be positive");
  }
  if (options.shadow_epsilon_m < 0.0) {
    throw std::invalid_argument("GeometryOptions.shadow_epsilon_m must not be negative");
  }
  if (options.num_threads < 0) {
    throw std::invalid_argument("GeometryOptions.num_threads must not be negative");
  }
}

// Sizes g for the pose's camera and projector (reusing its buffers) and marks every pixel
// as seeing no surface: NaN geometry, no object, zero albedo and gain.
void ResetScanGeometry(const ScanPose& pose, const GeometryOptions& options,
                       ScanGeometry* geometry) {
  ScanGeometry& g = *geometry;
  g.width = pose.camera.width();
  g.height = pose.camera.height();
  g.projector_width = pose.projector.width();
  g.projector_height = pose.projector.height();
  const std::size_t n = g.size();
  g.depth_m.assign(n, kNaN);
  g.points_camera.assign(n, Eigen::Vector3f::Constant(kNaN));
  g.normals_camera.assign(n, Eigen::Vector3f::Constant(kNaN));
  g.object_index.assign(n, -1);
  g.albedo.assign(n, 0.0f);
  if (options.colour) {
    g.colour.assign(n, Eigen::Vector3f::Zero());
  } else {
    g.colour.clear();
  }
  g.illumination.assign(n, Illumination::kNoSurface);
  g.projector_uv.assign(n, Eigen::Vector2f::Constant(kNaN));
  g.gain.assign(n, 0.0f);
}

// What Prepare's camera ray packets are resolved against: the scan, the scene and the poses
// of camera C and projector P in the robot base frame B (metres).
struct PacketScene {
  const ScanPose& pose;
  const GeometryOptions& options;
  const std::vector<Eigen::Vector3f>& rays;  // Ray direction per camera pixel, frame C.
  const std::vector<ObjectData>& objects;
  const std::vector<std::int32_t>& object_of_geometry;  // Object index per Embree geomID.
  RTCScene scene;
  Eigen::Matrix3d R_BC;
  Eigen::Vector3d p_BC;
  Eigen::Isometry3d X_PB;
  Eigen::Vector3d p_BP;
  double ref2;  // Squared reference distance of the inverse-square falloff, m^2.
  double eps;   // Shadow ray start offset along the normal, m.
};

// Shadow rays from the hits of one camera packet toward the projector centre (valid lanes
// -1), with what shading a lane needs once it turns out unoccluded.
struct ShadowPacket {
  RTCRay8 rays;
  alignas(32) int valid[kLanes];
  double cos_theta[kLanes];    // Between the surface normal and the direction to the projector.
  double r_projector[kLanes];  // Distance from the hit to the projector centre, m.
  Eigen::Vector2d uv[kLanes];  // Projector pixel coordinates of the hit.
};

// First stage of a camera packet: writes each hit's surface (depth, point, normal, object,
// albedo) into *geometry, marks hits outside the projector image or facing away from it,
// and aims a shadow ray from each remaining hit at the projector centre.
void RecordHitsAndAimShadowRays(const PacketScene& context, std::size_t i0, int lanes,
                                const RTCRayHit8& packet, ScanGeometry* geometry,
                                ShadowPacket* shadow_packet) {
  const ScanPose& pose = context.pose;
  const Eigen::Matrix3d& R_BC = context.R_BC;
  const Eigen::Vector3d& p_BC = context.p_BC;
  const Eigen::Isometry3d& X_PB = context.X_PB;
  const Eigen::Vector3d& p_BP = context.p_BP;
  const double eps = context.eps;
  ScanGeometry& g = *geometry;
  RTCRay8& shadow = shadow_packet->rays;
  int* const shadow_valid = shadow_packet->valid;
  double* const cos_theta = shadow_packet->cos_theta;
  double* const r_projector = shadow_packet->r_projector;
  Eigen::Vector2d* const uv = shadow_packet->uv;
  Eigen::Vector3d p_BX[kLanes];
  Eigen::Vector3d n_B[kLanes];
  for (int k = 0; k < kLanes; ++k) {
    shadow_valid[k] = 0;
    shadow.tnear[k] = 0.0f;
    shadow.tfar[k] = 0.0f;
    shadow.time[k] = 0.0f;
    shadow.mask[k] = 0xFFFFFFFFu;
    shadow.id[k] = static_cast<unsigned>(k);
    shadow.flags[k] = 0;
    if (k >= lanes || packet.hit.geomID[k] == RTC_INVALID_GEOMETRY_ID) continue;
    const std::size_t i = i0 + k;
    const Eigen::Vector3d d_C = context.rays[i].cast<double>();
    const Eigen::Vector3d d_B = R_BC * d_C;
    const double t = packet.ray.tfar[k];
    p_BX[k] = p_BC + t * d_B;
    n_B[k] =
        Eigen::Vector3d(packet.hit.Ng_x[k], packet.hit.Ng_y[k], packet.hit.Ng_z[k]).normalized();
    if (n_B[k].dot(d_B) > 0.0) n_B[k] = -n_B[k];  // Toward the camera.
    const std::int32_t object_index = context.object_of_geometry[packet.hit.geomID[k]];
    const float albedo = context.objects[object_index].AlbedoAt(packet.hit.primID[k],
                                                                packet.hit.u[k], packet.hit.v[k]);
    const Eigen::Vector3d p_CX = t * d_C;
    g.depth_m[i] = static_cast<float>(p_CX.z());
    g.points_camera[i] = p_CX.cast<float>();
    g.normals_camera[i] = (R_BC.transpose() * n_B[k]).cast<float>();
    g.object_index[i] = object_index;
    g.albedo[i] = albedo;
    if (context.options.colour) {
      g.colour[i] = context.objects[object_index].ColourAt(packet.hit.primID[k], packet.hit.u[k],
                                                           packet.hit.v[k]);
    }

    const std::optional<Eigen::Vector2d> projected = pose.projector.Project(X_PB * p_BX[k]);
    if (!projected || !pose.projector.Contains(*projected)) {
      g.illumination[i] = Illumination::kOutsideProjector;
      continue;
    }
    uv[k] = *projected;
    const Eigen::Vector3d to_projector = p_BP - p_BX[k];
    r_projector[k] = to_projector.norm();
    const Eigen::Vector3d l_B = to_projector / r_projector[k];
    cos_theta[k] = n_B[k].dot(l_B);
    if (cos_theta[k] <= 0.0) {
      g.illumination[i] = Illumination::kFacingAway;
      continue;
    }
    const Eigen::Vector3d origin = p_BX[k] + eps * n_B[k];
    shadow_valid[k] = -1;
    shadow.org_x[k] = static_cast<float>(origin.x());
    shadow.org_y[k] = static_cast<float>(origin.y());
    shadow.org_z[k] = static_cast<float>(origin.z());
    shadow.dir_x[k] = static_cast<float>(l_B.x());
    shadow.dir_y[k] = static_cast<float>(l_B.y());
    shadow.dir_z[k] = static_cast<float>(l_B.z());
    shadow.tfar[k] = static_cast<float>(std::max(0.0, r_projector[k] - eps));
  }
}

// Last stage of a camera packet, after rtcOccluded8: marks occluded shadow rays' pixels
// shadowed and gives the others the projector coordinates and the gain (albedo, cosine,
// optional inverse-square falloff) they are lit with.
void ShadeUnoccludedHits(const PacketScene& context, std::size_t i0, const ShadowPacket& shadow,
                         ScanGeometry* geometry) {
  const GeometryOptions& options = context.options;
  const double ref2 = context.ref2;
  ScanGeometry& g = *geometry;
  for (int k = 0; k < kLanes; ++k) {
    if (shadow.valid[k] == 0) continue;
    const std::size_t i = i0 + k;
    if (shadow.rays.tfar[k] < 0.0f) {  // Embree sets tfar to -inf when occluded.
      g.illumination[i] = Illumination::kShadowed;
      continue;
    }
    g.illumination[i] = Illumination::kLit;
    g.projector_uv[i] = shadow.uv[k].cast<float>();
    const double r = shadow.r_projector[k];
    const double falloff = options.inverse_square_falloff ? ref2 / (r * r) : 1.0;
    g.gain[i] = static_cast<float>(g.albedo[i] * shadow.cos_theta[k] * falloff);
  }
}

}  // namespace

// ---------------------------------------------------------------------------------------
// GrayImage, RenderOptions

GrayImage::GrayImage(int w, int h, std::uint8_t fill) : width(w), height(h) {
  if (w < 0 || h < 0) {
    throw std::invalid_argument("GrayImage: width and height must not be negative");
  }
  pixels.assign(std::size_t(w) * h, fill);
}

void RenderOptions::Validate() const {
  auto fail = [](const std::string& field, const std::string& why) {
    throw std::invalid_argument("RenderOptions." + field + " " + why);
  };
  const std::pair<const char*, double> values[] = {
      {"ambient", ambient},
      {"projector_brightness", projector_brightness},
      {"exposure", exposure},
      {"projector_gamma", projector_gamma},
      {"camera_gamma", camera_gamma},
      {"read_noise_dn", read_noise_dn},
      {"electrons_per_dn", electrons_per_dn},
      {"projector_blur_sigma_px", projector_blur_sigma_px}};
  for (const auto& [name, value] : values) {
    if (!std::isfinite(value)) fail(name, "is not finite");
    if (value < 0.0) fail(name, "must not be negative");
  }
  if (projector_gamma <= 0.0) fail("projector_gamma", "must be positive");
  if (camera_gamma <= 0.0) fail("camera_gamma", "must be positive");
  if (num_threads < 0) fail("num_threads", "must not be negative");
}

// ---------------------------------------------------------------------------------------
// StructuredLightRenderer

struct StructuredLightRenderer::Impl {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
  std::vector<ObjectData> objects;
  std::vector<std::int32_t> object_of_geometry;
  std::size_t num_triangles = 0;

  // Camera ray directions per pixel (camera frame) of the last few lens models.
  struct RayTable {
    camera::PinholeCamera model;
    std::shared_ptr<const std::vector<Eigen::Vector3f>> directions;
  };
  mutable std::mutex ray_mutex;
  mutable std::vector<RayTable> ray_tables;

  ~Impl() {
    if (scene != nullptr) rtcReleaseScene(scene);
    if (device != nullptr) rtcReleaseDevice(device);
  }

  std::shared_ptr<const std::vector<Eigen::Vector3f>> Rays(const camera::PinholeCamera& model,
                                                           int threads) const {
    {
      std::lock_guard<std::mutex> lock(ray_mutex);
      for (const auto& table : ray_tables) {
        if (SameModel(table.model, model)) return table.directions;
      }
    }
    const int width = model.width();
    const int height = model.height();
    auto directions = std::make_shared<std::vector<Eigen::Vector3f>>(std::size_t(width) * height);
    const int blocks = (height + kRowsPerBlock - 1) / kRowsPerBlock;
    ParallelFor(blocks, threads, [&](int b) {
      for (int y = b * kRowsPerBlock; y < std::min(height, (b + 1) * kRowsPerBlock); ++y) {
        for (int x = 0; x < width; ++x) {
          (*directions)[std::size_t(y) * width + x] =
              model.RayDirection(Eigen::Vector2d(x, y)).cast<float>();
        }
      }
    });
    std::lock_guard<std::mutex> lock(ray_mutex);
    constexpr std::size_t kMaxTables = 4;
    if (ray_tables.size() >= kMaxTables) ray_tables.erase(ray_tables.begin());
    ray_tables.push_back({model, directions});
    return directions;
  }

  // Casts one ray per pixel centre of a width x height camera at X_BaseCamera (directions
  // `rays` in the camera frame, row-major), as packets of kLanes neighbouring pixels of a
  // row so that coherent rays traverse the BVH together, blocks of rows spread over
  // `threads`. Calls on_packet(i0, lanes, packet, context) for each packet: i0 the index of
  // its first pixel, lanes the number of pixels in it (<= kLanes, fewer at a row's end),
  // packet the hits (geomID RTC_INVALID_GEOMETRY_ID where none) and a coherent intersection
  // context for further rays of the packet. `on_packet` must not throw.
  template <class OnPacket>
  void CastCameraRays(const std::vector<Eigen::Vector3f>& rays, int width, int height,
                      const Eigen::Isometry3d& X_BaseCamera, int threads,
                      const OnPacket& on_packet) const {
    const Eigen::Matrix3d R_BC = X_BaseCamera.linear();
    const Eigen::Vector3d p_BC = X_BaseCamera.translation();
    const int blocks = (height + kRowsPerBlock - 1) / kRowsPerBlock;
    ParallelFor(blocks, threads, [&](int b) {
      RTCIntersectContext coherent;
      rtcInitIntersectContext(&coherent);
      coherent.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
      RTCRayHit8 packet;
      alignas(32) int valid[kLanes];
      for (int y = b * kRowsPerBlock; y < std::min(height, (b + 1) * kRowsPerBlock); ++y) {
        for (int x0 = 0; x0 < width; x0 += kLanes) {
          const std::size_t i0 = std::size_t(y) * width + x0;
          const int lanes = std::min(kLanes, width - x0);
          for (int k = 0; k < kLanes; ++k) {
            valid[k] = k < lanes ? -1 : 0;
            const Eigen::Vector3d d_B =
                k < lanes ? Eigen::Vector3d(R_BC * rays[i0 + k].cast<double>()) : R_BC.col(2);
            packet.ray.org_x[k] = static_cast<float>(p_BC.x());
            packet.ray.org_y[k] = static_cast<float>(p_BC.y());
            packet.ray.org_z[k] = static_cast<float>(p_BC.z());
            packet.ray.dir_x[k] = static_cast<float>(d_B.x());
            packet.ray.dir_y[k] = static_cast<float>(d_B.y());
            packet.ray.dir_z[k] = static_cast<float>(d_B.z());
            packet.ray.tnear[k] = 0.0f;
            packet.ray.tfar[k] = std::numeric_limits<float>::infinity();
            packet.ray.time[k] = 0.0f;
            packet.ray.mask[k] = 0xFFFFFFFFu;
            packet.ray.id[k] = static_cast<unsigned>(k);
            packet.ray.flags[k] = 0;
            packet.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
            packet.hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
          }
          rtcIntersect8(valid, scene, &coherent, &packet);
          on_packet(i0, lanes, packet, &coherent);
        }
      }
    });
  }
};

StructuredLightRenderer::StructuredLightRenderer(const std::vector<SceneObject>& objects)
    : impl_(std::make_unique<Impl>()) {
  impl_->device = rtcNewDevice(nullptr);
  if (impl_->device == nullptr) {
    throw std::runtime_error("StructuredLightRenderer: rtcNewDevice failed (error " +
                             std::to_string(static_cast<int>(rtcGetDeviceError(nullptr))) + ")");
  }
  SetObjects(objects);
}

StructuredLightRenderer::~StructuredLightRenderer() = default;

void StructuredLightRenderer::SetObjects(const std::vector<SceneObject>& objects) {
  std::vector<ObjectData> data;
  data.reserve(objects.size());
  for (std::size_t i = 0; i < objects.size(); ++i) data.push_back(CheckedCopy(i, objects[i]));

  RTCDevice device = impl_->device;
  RTCScene scene = rtcNewScene(device);
  // Robust traversal: rays through shared edges of adjacent triangles never slip through.
  rtcSetSceneFlags(scene, RTC_SCENE_FLAG_ROBUST);
  std::vector<std::int32_t> object_of_geometry;
  std::size_t num_triangles = 0;
  try {
    for (std::size_t i = 0; i < data.size(); ++i) {
      ObjectData& object = data[i];
      if (object.triangles.empty()) continue;
      RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
      auto* vertices = static_cast<float*>(
          rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                  3 * sizeof(float), object.vertices_object.size()));
      auto* indices = static_cast<unsigned*>(
          rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                  3 * sizeof(unsigned), object.triangles.size()));
      if (vertices == nullptr || indices == nullptr) {
        rtcReleaseGeometry(geom);
        ThrowOnDeviceError(device, "rtcSetNewGeometryBuffer");
        throw std::runtime_error("StructuredLightRenderer: Embree buffer allocation failed");
      }
      WriteVertices(object, vertices);
      for (std::size_t t = 0; t < object.triangles.size(); ++t) {
        for (int k = 0; k < 3; ++k) indices[3 * t + k] = object.triangles[t][k];
      }
      rtcCommitGeometry(geom);
      object.geom_id = rtcAttachGeometry(scene, geom);
      rtcReleaseGeometry(geom);
      if (object_of_geometry.size() <= object.geom_id) {
        object_of_geometry.resize(object.geom_id + 1, -1);
      }
      object_of_geometry[object.geom_id] = static_cast<std::int32_t>(i);
      num_triangles += object.triangles.size();
    }
    rtcCommitScene(scene);
    ThrowOnDeviceError(device, "rtcCommitScene");
  } catch (...) {
    rtcReleaseScene(scene);
    throw;
  }
  if (impl_->scene != nullptr) rtcReleaseScene(impl_->scene);
  impl_->scene = scene;
  impl_->objects = std::move(data);
  impl_->object_of_geometry = std::move(object_of_geometry);
  impl_->num_triangles = num_triangles;
}

void StructuredLightRenderer::SetObjectPose(std::size_t index,
                                            const Eigen::Isometry3d& X_BaseObject) {
  if (index >= impl_->objects.size()) {
    throw std::out_of_range("StructuredLightRenderer::SetObjectPose: object index " +
                            std::to_string(index) + " is not below " +
                            std::to_string(impl_->objects.size()));
  }
  if (!IsFinitePose(X_BaseObject)) {
    throw std::invalid_argument("StructuredLightRenderer::SetObjectPose: object " +
                                std::to_string(index) +
                                ": X_BaseObject is not a finite rigid transform");
  }
  ObjectData& object = impl_->objects[index];
  object.X_BaseObject = X_BaseObject;
  if (object.geom_id == RTC_INVALID_GEOMETRY_ID) return;
  RTCGeometry geom = rtcGetGeometry(impl_->scene, object.geom_id);
  auto* vertices = static_cast<float*>(rtcGetGeometryBufferData(geom, RTC_BUFFER_TYPE_VERTEX, 0));
  WriteVertices(object, vertices);
  rtcUpdateGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0);
  rtcCommitGeometry(geom);
  rtcCommitScene(impl_->scene);
  ThrowOnDeviceError(impl_->device, "SetObjectPose");
}

std::size_t StructuredLightRenderer::num_objects() const { return impl_->objects.size(); }

std::size_t StructuredLightRenderer::num_triangles() const { return impl_->num_triangles; }

ScanGeometry StructuredLightRenderer::Prepare(const ScanPose& pose,
                                              const GeometryOptions& options) const {
  ScanGeometry geometry;
  Prepare(pose, options, &geometry);
  return geometry;
}

void StructuredLightRenderer::Prepare(const ScanPose& pose, const GeometryOptions& options,
                                      ScanGeometry* geometry) const {
  CheckPrepareArguments(pose, options, geometry);
  const int threads = ResolveThreads(options.num_threads);
  const auto rays = impl_->Rays(pose.camera, threads);

  ScanGeometry& g = *geometry;
  ResetScanGeometry(pose, options, &g);

  const Impl& impl = *impl_;
  const PacketScene context{pose,
                            options,
                            *rays,
                            impl.objects,
                            impl.object_of_geometry,
                            impl.scene,
                            pose.X_BaseCamera.linear(),
                            pose.X_BaseCamera.translation(),
                            pose.X_BaseProjector.inverse(),
                            pose.X_BaseProjector.translation(),
                            options.reference_distance_m * options.reference_distance_m,
                            options.shadow_epsilon_m};

  impl.CastCameraRays(
      *rays, g.width, g.height, pose.X_BaseCamera, threads,
      [&](std::size_t i0, int lanes, const RTCRayHit8& packet, RTCIntersectContext* coherent) {
        // Shadow rays of the packet's hits, which all end at the projector centre, also
        // travel as one packet.
        ShadowPacket shadow;
        RecordHitsAndAimShadowRays(context, i0, lanes, packet, &g, &shadow);
        if (std::none_of(shadow.valid, shadow.valid + kLanes, [](int v) { return v != 0; })) {
          return;
        }
        rtcOccluded8(shadow.valid, context.scene, coherent, &shadow.rays);
        ShadeUnoccludedHits(context, i0, shadow, &g);
      });
}

DepthImage StructuredLightRenderer::RenderDepth(const camera::PinholeCamera& camera,
                                                const Eigen::Isometry3d& X_BaseCamera,
                                                int num_threads) const {
  if (!IsFinitePose(X_BaseCamera)) {
    throw std::invalid_argument("RenderDepth: X_BaseCamera is not a finite rigid transform");
  }
  if (num_threads < 0) {
    throw std::invalid_argument("RenderDepth: num_threads must not be negative");
  }
  const int threads = ResolveThreads(num_threads);
  const auto rays = impl_->Rays(camera, threads);
  DepthImage depth;
  depth.width = camera.width();
  depth.height = camera.height();
  depth.depth_m.assign(depth.size(), kNaN);
  impl_->CastCameraRays(
      *rays, depth.width, depth.height, X_BaseCamera, threads,
      [&](std::size_t i0, int lanes, const RTCRayHit8& packet, RTCIntersectContext*) {
        for (int k = 0; k < lanes; ++k) {
          if (packet.hit.geomID[k] == RTC_INVALID_GEOMETRY_ID) continue;
          // As Prepare computes ScanGeometry::depth_m, so that both agree to the bit.
          const double t = packet.ray.tfar[k];
          depth.depth_m[i0 + k] = static_cast<float>(t * (*rays)[i0 + k].cast<double>().z());
        }
      });
  return depth;
}

// ---------------------------------------------------------------------------------------
// Shading

std::vector<GrayImage> RenderSequence(const ScanGeometry& geometry,
                                      const std::vector<GrayImage>& projector_images,
                                      const RenderOptions& options) {
  options.Validate();
  CheckGeometry(geometry);
  std::vector<const GrayImage*> images;
  for (std::size_t k = 0; k < projector_images.size(); ++k) {
    CheckProjectorImage(geometry, projector_images[k], k);
    images.push_back(&projector_images[k]);
  }
  std::vector<GrayImage> out;
  Shade(geometry, images, 0, options, &out);
  return out;
}

void RenderSequence(const ScanGeometry& geometry, const std::vector<GrayImage>& projector_images,
                    const RenderOptions& options, std::vector<GrayImage>* camera_images,
                    std::uint64_t first_frame) {
  if (camera_images == nullptr) throw std::invalid_argument("RenderSequence: output is null");
  options.Validate();
  CheckGeometry(geometry);
  std::vector<const GrayImage*> images;
  for (std::size_t k = 0; k < projector_images.size(); ++k) {
    CheckProjectorImage(geometry, projector_images[k], k);
    images.push_back(&projector_images[k]);
  }
  Shade(geometry, images, first_frame, options, camera_images);
}

GrayImage RenderImage(const ScanGeometry& geometry, const GrayImage& projector_image,
                      const RenderOptions& options, std::uint64_t frame_index) {
  options.Validate();
  CheckGeometry(geometry);
  CheckProjectorImage(geometry, projector_image, 0);
  std::vector<GrayImage> out;
  Shade(geometry, {&projector_image}, frame_index, options, &out);
  return std::move(out[0]);
}

geometry::PointCloud GroundTruthCloud(const ScanGeometry& g) {
  geometry::PointCloud cloud;
  cloud.width = static_cast<std::uint32_t>(g.width);
  cloud.height = static_cast<std::uint32_t>(g.height);
  cloud.frame_id = "camera";
  cloud.points = g.points_camera;
  cloud.normals = g.normals_camera;
  cloud.intensities = g.albedo;
  return cloud;
}

}  // namespace picking::simulator
