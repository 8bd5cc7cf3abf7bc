#include "services/simulator/core/renderer.h"

#include <embree3/rtcore.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <mutex>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <thread>
#include <utility>

namespace picking::simulator {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
// Rows per work item of the parallel loops: small enough to balance two to a few dozen
// threads, large enough to keep scheduling overhead negligible.
constexpr int kRowsPerBlock = 8;

int ResolveThreads(int requested) {
  if (requested > 0) return requested;
  const unsigned hw = std::thread::hardware_concurrency();
  return hw == 0 ? 1 : static_cast<int>(hw);
}

// Calls f(i) for i in [0, n) on `threads` threads (the caller's included), items taken in
// order from a shared counter. `f` must not throw.
template <class F>
void ParallelFor(int n, int threads, const F& f) {
  threads = std::min(threads, n);
  if (threads <= 1) {
    for (int i = 0; i < n; ++i) f(i);
    return;
  }
  std::atomic<int> next{0};
  auto worker = [&]() {
    for (int i = next.fetch_add(1); i < n; i = next.fetch_add(1)) f(i);
  };
  std::vector<std::thread> pool;
  pool.reserve(threads - 1);
  for (int t = 1; t < threads; ++t) pool.emplace_back(worker);
  worker();
  for (auto& th : pool) th.join();
}

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
  float albedo = 0.0f;
  Eigen::Isometry3d X_BaseObject = Eigen::Isometry3d::Identity();
  unsigned geom_id = RTC_INVALID_GEOMETRY_ID;

  float AlbedoAt(unsigned prim, float u, float v) const {
    if (vertex_albedo.empty()) return albedo;
    const auto& tri = triangles[prim];
    return (1.0f - u - v) * vertex_albedo[tri[0]] + u * vertex_albedo[tri[1]] +
           v * vertex_albedo[tri[2]];
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
  ObjectData data;
  data.vertices_object = mesh->vertices;
  data.triangles = mesh->triangles;
  data.vertex_albedo = mesh->vertex_albedo;
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
  // Standard normal approximated by the sum of four 16-bit uniforms (Irwin-Hall, n = 4):
  // exact mean and variance, tails cut at 3.5 sigma, ample for sensor noise and ~10x
  // cheaper than Box-Muller.
  float Normal() {
    const std::uint64_t r = Next();
    const float sum =
        static_cast<float>((r & 0xFFFF) + ((r >> 16) & 0xFFFF) + ((r >> 32) & 0xFFFF) + (r >> 48));
    constexpr float kMean = 4.0f * 32767.5f;
    // Variance of one discrete uniform on 0..65535 is (65536^2 - 1) / 12.
    constexpr float kInvSigma = 1.0f / 37837.23f;  // 1 / sqrt(4 * (65536^2 - 1) / 12)
    return (sum - kMean) * kInvSigma;
  }
};

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

// Separable Gaussian blur with clamped borders of a width x height float image.
std::vector<float> Blur(const std::vector<float>& in, int width, int height, double sigma,
                        int threads) {
  const int radius = std::max(1, static_cast<int>(std::ceil(3.0 * sigma)));
  std::vector<float> kernel(2 * radius + 1);
  double sum = 0.0;
  for (int k = -radius; k <= radius; ++k) {
    kernel[k + radius] = static_cast<float>(std::exp(-0.5 * k * k / (sigma * sigma)));
    sum += kernel[k + radius];
  }
  for (float& w : kernel) w = static_cast<float>(w / sum);
  std::vector<float> tmp(in.size()), out(in.size());
  const int blocks = (height + kRowsPerBlock - 1) / kRowsPerBlock;
  ParallelFor(blocks, threads, [&](int b) {
    for (int y = b * kRowsPerBlock; y < std::min(height, (b + 1) * kRowsPerBlock); ++y) {
      const float* row = &in[std::size_t(y) * width];
      for (int x = 0; x < width; ++x) {
        float acc = 0.0f;
        for (int k = -radius; k <= radius; ++k) {
          acc += kernel[k + radius] * row[std::clamp(x + k, 0, width - 1)];
        }
        tmp[std::size_t(y) * width + x] = acc;
      }
    }
  });
  ParallelFor(blocks, threads, [&](int b) {
    for (int y = b * kRowsPerBlock; y < std::min(height, (b + 1) * kRowsPerBlock); ++y) {
      for (int x = 0; x < width; ++x) {
        float acc = 0.0f;
        for (int k = -radius; k <= radius; ++k) {
          acc +=
              kernel[k + radius] * tmp[std::size_t(std::clamp(y + k, 0, height - 1)) * width + x];
        }
        out[std::size_t(y) * width + x] = acc;
      }
    }
  });
  return out;
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

// Shading of the camera rows [row_begin, row_end) of one frame.
template <class Light>
void ShadeRows(const ScanGeometry& g, const Light& light, const RenderOptions& o,
               std::uint64_t frame, int row_begin, int row_end, GrayImage* out) {
  const float ambient_dn = static_cast<float>(255.0 * o.exposure * o.ambient);
  const float read_var = static_cast<float>(o.read_noise_dn * o.read_noise_dn);
  const float shot_scale =
      o.electrons_per_dn > 0.0 ? static_cast<float>(1.0 / o.electrons_per_dn) : 0.0f;
  const bool noisy = read_var > 0.0f || shot_scale > 0.0f;
  const bool linear = o.camera_gamma == 1.0;
  const double inv_gamma = 1.0 / o.camera_gamma;
  const bool bilinear = o.sampling == ProjectorSampling::kBilinear;
  const int pw = g.projector_width;
  const int ph = g.projector_height;
  for (int y = row_begin; y < row_end; ++y) {
    SplitMix64 rng{RowSeed(o.seed, frame, y)};
    const std::size_t row_start = std::size_t(y) * g.width;
    std::uint8_t* dst = &out->pixels[row_start];
    for (int x = 0; x < g.width; ++x) {
      const std::size_t i = row_start + x;
      float s = ambient_dn * g.albedo[i];
      if (g.illumination[i] == Illumination::kLit) {
        const float u = g.projector_uv[i].x();
        const float v = g.projector_uv[i].y();
        float l;
        if (bilinear) {
          const float fu = std::floor(u);
          const float fv = std::floor(v);
          const float au = u - fu;
          const float av = v - fv;
          const int u0 = std::clamp(static_cast<int>(fu), 0, pw - 1);
          const int u1 = std::clamp(static_cast<int>(fu) + 1, 0, pw - 1);
          const int v0 = std::clamp(static_cast<int>(fv), 0, ph - 1);
          const int v1 = std::clamp(static_cast<int>(fv) + 1, 0, ph - 1);
          const std::size_t r0 = std::size_t(v0) * pw;
          const std::size_t r1 = std::size_t(v1) * pw;
          const float top = light[r0 + u0] + au * (light[r0 + u1] - light[r0 + u0]);
          const float bottom = light[r1 + u0] + au * (light[r1 + u1] - light[r1 + u0]);
          l = top + av * (bottom - top);
        } else {
          const int ui = std::clamp(static_cast<int>(std::lround(u)), 0, pw - 1);
          const int vi = std::clamp(static_cast<int>(std::lround(v)), 0, ph - 1);
          l = light[std::size_t(vi) * pw + ui];
        }
        s += g.gain[i] * l;
      }
      if (noisy) {
        const float var = read_var + shot_scale * std::max(s, 0.0f);
        s += std::sqrt(var) * rng.Normal();
      }
      s = std::max(s, 0.0f);
      if (!linear) s = static_cast<float>(255.0 * std::pow(s / 255.0, inv_gamma));
      dst[x] = static_cast<std::uint8_t>(std::min(255.0f, s + 0.5f));
    }
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

void CheckFinite(double value, const char* field) {
  if (!std::isfinite(value)) {
    throw std::invalid_argument(std::string(field) + " is not finite");
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
  const int threads = ResolveThreads(options.num_threads);
  const auto rays = impl_->Rays(pose.camera, threads);

  ScanGeometry g;
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
  g.illumination.assign(n, Illumination::kNoSurface);
  g.projector_uv.assign(n, Eigen::Vector2f::Constant(kNaN));
  g.gain.assign(n, 0.0f);

  const Eigen::Matrix3d R_BC = pose.X_BaseCamera.linear();
  const Eigen::Vector3d p_BC = pose.X_BaseCamera.translation();
  const Eigen::Isometry3d X_PB = pose.X_BaseProjector.inverse();
  const Eigen::Vector3d p_BP = pose.X_BaseProjector.translation();
  const double ref2 = options.reference_distance_m * options.reference_distance_m;
  const double eps = options.shadow_epsilon_m;
  const Impl& impl = *impl_;
  RTCScene scene = impl.scene;

  const int blocks = (g.height + kRowsPerBlock - 1) / kRowsPerBlock;
  ParallelFor(blocks, threads, [&](int b) {
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    for (int y = b * kRowsPerBlock; y < std::min(g.height, (b + 1) * kRowsPerBlock); ++y) {
      for (int x = 0; x < g.width; ++x) {
        const std::size_t i = std::size_t(y) * g.width + x;
        const Eigen::Vector3d d_C = (*rays)[i].cast<double>();
        const Eigen::Vector3d d_B = R_BC * d_C;
        RTCRayHit rh;
        rh.ray.org_x = static_cast<float>(p_BC.x());
        rh.ray.org_y = static_cast<float>(p_BC.y());
        rh.ray.org_z = static_cast<float>(p_BC.z());
        rh.ray.dir_x = static_cast<float>(d_B.x());
        rh.ray.dir_y = static_cast<float>(d_B.y());
        rh.ray.dir_z = static_cast<float>(d_B.z());
        rh.ray.tnear = 0.0f;
        rh.ray.tfar = std::numeric_limits<float>::infinity();
        rh.ray.time = 0.0f;
        rh.ray.mask = 0xFFFFFFFFu;
        rh.ray.id = 0;
        rh.ray.flags = 0;
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
        rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(scene, &context, &rh);
        if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) continue;

        const double t = rh.ray.tfar;
        const Eigen::Vector3d p_BX = p_BC + t * d_B;
        Eigen::Vector3d n_B(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z);
        n_B.normalize();
        if (n_B.dot(d_B) > 0.0) n_B = -n_B;  // Toward the camera.
        const std::int32_t object_index = impl.object_of_geometry[rh.hit.geomID];
        const float albedo = impl.objects[object_index].AlbedoAt(rh.hit.primID, rh.hit.u, rh.hit.v);
        const Eigen::Vector3d p_CX = t * d_C;
        g.depth_m[i] = static_cast<float>(p_CX.z());
        g.points_camera[i] = p_CX.cast<float>();
        g.normals_camera[i] = (R_BC.transpose() * n_B).cast<float>();
        g.object_index[i] = object_index;
        g.albedo[i] = albedo;

        const std::optional<Eigen::Vector2d> uv = pose.projector.Project(X_PB * p_BX);
        if (!uv || !pose.projector.Contains(*uv)) {
          g.illumination[i] = Illumination::kOutsideProjector;
          continue;
        }
        const Eigen::Vector3d to_projector = p_BP - p_BX;
        const double r = to_projector.norm();
        const Eigen::Vector3d l_B = to_projector / r;
        const double cos_theta = n_B.dot(l_B);
        if (cos_theta <= 0.0) {
          g.illumination[i] = Illumination::kFacingAway;
          continue;
        }
        RTCRay shadow;
        const Eigen::Vector3d origin = p_BX + eps * n_B;
        shadow.org_x = static_cast<float>(origin.x());
        shadow.org_y = static_cast<float>(origin.y());
        shadow.org_z = static_cast<float>(origin.z());
        shadow.dir_x = static_cast<float>(l_B.x());
        shadow.dir_y = static_cast<float>(l_B.y());
        shadow.dir_z = static_cast<float>(l_B.z());
        shadow.tnear = 0.0f;
        shadow.tfar = static_cast<float>(std::max(0.0, r - eps));
        shadow.time = 0.0f;
        shadow.mask = 0xFFFFFFFFu;
        shadow.id = 0;
        shadow.flags = 0;
        rtcOccluded1(scene, &context, &shadow);
        if (shadow.tfar < 0.0f) {  // Embree sets tfar to -inf when occluded.
          g.illumination[i] = Illumination::kShadowed;
          continue;
        }
        g.illumination[i] = Illumination::kLit;
        g.projector_uv[i] = uv->cast<float>();
        const double falloff = options.inverse_square_falloff ? ref2 / (r * r) : 1.0;
        g.gain[i] = static_cast<float>(albedo * cos_theta * falloff);
      }
    }
  });
  return g;
}

// ---------------------------------------------------------------------------------------
// Shading

std::vector<GrayImage> RenderSequence(const ScanGeometry& geometry,
                                      const std::vector<GrayImage>& projector_images,
                                      const RenderOptions& options) {
  options.Validate();
  CheckGeometry(geometry);
  for (std::size_t k = 0; k < projector_images.size(); ++k) {
    CheckProjectorImage(geometry, projector_images[k], k);
  }
  const int threads = ResolveThreads(options.num_threads);
  const int blocks = (geometry.height + kRowsPerBlock - 1) / kRowsPerBlock;
  const int frames = static_cast<int>(projector_images.size());
  std::vector<GrayImage> out(frames, GrayImage(geometry.width, geometry.height));
  const std::vector<float> lut = LightTable(options);

  if (options.projector_blur_sigma_px <= 0.0) {
    // One pass over (frame, row block) items keeps both threads busy across frame borders.
    ParallelFor(frames * blocks, threads, [&](int item) {
      const int f = item / blocks;
      const int b = item % blocks;
      const LutLight light{projector_images[f].pixels.data(), lut.data()};
      ShadeRows(geometry, light, options, static_cast<std::uint64_t>(f), b * kRowsPerBlock,
                std::min(geometry.height, (b + 1) * kRowsPerBlock), &out[f]);
    });
    return out;
  }
  for (int f = 0; f < frames; ++f) {
    const GrayImage& image = projector_images[f];
    std::vector<float> light(image.pixels.size());
    for (std::size_t i = 0; i < light.size(); ++i) light[i] = lut[image.pixels[i]];
    light = Blur(light, image.width, image.height, options.projector_blur_sigma_px, threads);
    const FloatLight source{light.data()};
    ParallelFor(blocks, threads, [&](int b) {
      ShadeRows(geometry, source, options, static_cast<std::uint64_t>(f), b * kRowsPerBlock,
                std::min(geometry.height, (b + 1) * kRowsPerBlock), &out[f]);
    });
  }
  return out;
}

GrayImage RenderImage(const ScanGeometry& geometry, const GrayImage& projector_image,
                      const RenderOptions& options, std::uint64_t frame_index) {
  options.Validate();
  CheckGeometry(geometry);
  CheckProjectorImage(geometry, projector_image, 0);
  const int threads = ResolveThreads(options.num_threads);
  const int blocks = (geometry.height + kRowsPerBlock - 1) / kRowsPerBlock;
  GrayImage out(geometry.width, geometry.height);
  const std::vector<float> lut = LightTable(options);
  std::vector<float> blurred;
  if (options.projector_blur_sigma_px > 0.0) {
    blurred.resize(projector_image.pixels.size());
    for (std::size_t i = 0; i < blurred.size(); ++i) blurred[i] = lut[projector_image.pixels[i]];
    blurred = Blur(blurred, projector_image.width, projector_image.height,
                   options.projector_blur_sigma_px, threads);
  }
  ParallelFor(blocks, threads, [&](int b) {
    const int row_begin = b * kRowsPerBlock;
    const int row_end = std::min(geometry.height, (b + 1) * kRowsPerBlock);
    if (blurred.empty()) {
      ShadeRows(geometry, LutLight{projector_image.pixels.data(), lut.data()}, options, frame_index,
                row_begin, row_end, &out);
    } else {
      ShadeRows(geometry, FloatLight{blurred.data()}, options, frame_index, row_begin, row_end,
                &out);
    }
  });
  return out;
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
