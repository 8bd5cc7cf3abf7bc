#include "services/detector/core/appearance.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <stdexcept>
#include <string>

namespace picking::detector {

void AppearanceOptions::Validate() const {
  if (!(min_cos > 0.0f && min_cos <= 1.0f)) {
    throw std::invalid_argument("AppearanceOptions: min_cos must be in (0, 1], got " +
                                std::to_string(min_cos));
  }
  if (!(min_albedo_stddev >= 0.0f) || !std::isfinite(min_albedo_stddev)) {
    throw std::invalid_argument("AppearanceOptions: min_albedo_stddev must be >= 0, got " +
                                std::to_string(min_albedo_stddev));
  }
  if (!(min_intensity_rel_stddev >= 0.0f) || !std::isfinite(min_intensity_rel_stddev)) {
    throw std::invalid_argument("AppearanceOptions: min_intensity_rel_stddev must be >= 0, got " +
                                std::to_string(min_intensity_rel_stddev));
  }
  if (!(min_sample_cos >= 0.0f && min_sample_cos < 1.0f)) {
    throw std::invalid_argument("AppearanceOptions: min_sample_cos must be in [0, 1), got " +
                                std::to_string(min_sample_cos));
  }
  if (min_patch_points < 2) {
    throw std::invalid_argument("AppearanceOptions: min_patch_points must be >= 2, got " +
                                std::to_string(min_patch_points));
  }
  if (min_points < 3) {
    throw std::invalid_argument("AppearanceOptions: min_points must be >= 3, got " +
                                std::to_string(min_points));
  }
}

namespace {

// |cos| of the angle between `n` and the ray from `p` to the viewpoint, and the squared
// range; cos is 1 at the viewpoint itself (no direction to judge).
struct Incidence {
  float cos = 1.0f;
  float range_sq = 0.0f;
};

Incidence IncidenceAt(const Eigen::Vector3f& p, const Eigen::Vector3f& n,
                      const Eigen::Vector3f& viewpoint) {
  const Eigen::Vector3f ray = viewpoint - p;
  Incidence out;
  out.range_sq = ray.squaredNorm();
  if (out.range_sq > 0.0f) out.cos = std::abs(n.dot(ray)) / std::sqrt(out.range_sq);
  return out;
}

float Compensate(float intensity, const Incidence& incidence, float min_cos) {
  if (!(incidence.range_sq > 0.0f)) return intensity;
  return intensity * incidence.range_sq / std::max(incidence.cos, min_cos);
}

}  // namespace

float ShadingCompensatedIntensity(float intensity, const Eigen::Vector3f& p,
                                  const Eigen::Vector3f& n, const Eigen::Vector3f& viewpoint,
                                  float min_cos) {
  return Compensate(intensity, IncidenceAt(p, n, viewpoint), min_cos);
}

std::optional<float> AppearanceSample(float intensity, const Eigen::Vector3f& p,
                                      const Eigen::Vector3f& n, const Eigen::Vector3f& viewpoint,
                                      const AppearanceOptions& options) {
  if (!std::isfinite(intensity)) return std::nullopt;
  if (options.screened_per_view) return intensity;
  const Incidence incidence = IncidenceAt(p, n, viewpoint);
  if (incidence.cos < options.min_sample_cos) return std::nullopt;
  return Compensate(intensity, incidence, options.min_cos);
}

std::optional<float> CompensatedViewIntensity(float intensity, const Eigen::Vector3f& p,
                                              const Eigen::Vector3f& n,
                                              const Eigen::Vector3f& viewpoint,
                                              const AppearanceOptions& options) {
  if (!std::isfinite(intensity) || !n.allFinite()) return std::nullopt;
  const Incidence own = IncidenceAt(p, n, viewpoint);
  if (own.cos < options.min_sample_cos) return std::nullopt;
  return Compensate(intensity, own, options.min_cos);
}

namespace {
// SurfacePatch's labels: 0 to kSurfacePatches - 1.
constexpr std::size_t kSurfacePatches = 26;
}  // namespace

std::uint8_t SurfacePatch(const Eigen::Vector3f& n_Model) {
  if (!n_Model.allFinite()) return 255;
  // The 26 directions (x, y, z) in {-1, 0, 1}^3 \ 0, normalised, in a fixed order.
  static const std::array<Eigen::Vector3f, kSurfacePatches> kDirections = [] {
    std::array<Eigen::Vector3f, kSurfacePatches> d;
    std::size_t k = 0;
    for (int x = -1; x <= 1; ++x) {
      for (int y = -1; y <= 1; ++y) {
        for (int z = -1; z <= 1; ++z) {
          if (x != 0 || y != 0 || z != 0) d[k++] = Eigen::Vector3f(x, y, z).normalized();
        }
      }
    }
    return d;
  }();
  std::uint8_t best = 0;
  for (std::uint8_t k = 1; k < kDirections.size(); ++k) {
    if (n_Model.dot(kDirections[k]) > n_Model.dot(kDirections[best])) best = k;
  }
  return best;
}

namespace {

// CorrelateAppearance pooled over surface patches (see its comment).
AppearanceScore CorrelatePatchContrasts(const std::vector<float>& albedo,
                                        const std::vector<float>& intensity,
                                        const std::vector<std::uint8_t>& patches,
                                        const AppearanceOptions& options) {
  struct Patch {
    int n = 0;
    double sa = 0.0, si = 0.0, saa = 0.0;
  };
  // Other labels (255: no normal) are left out.
  std::array<Patch, kSurfacePatches> patch{};
  const auto usable = [&](std::size_t k) {
    return std::isfinite(albedo[k]) && std::isfinite(intensity[k]) && patches[k] < kSurfacePatches;
  };
  for (std::size_t k = 0; k < albedo.size(); ++k) {
    if (!usable(k)) continue;
    Patch& p = patch[patches[k]];
    ++p.n;
    p.sa += albedo[k];
    p.si += intensity[k];
    p.saa += static_cast<double>(albedo[k]) * albedo[k];
  }
  std::array<bool, kSurfacePatches> kept{};
  for (std::size_t g = 0; g < patch.size(); ++g) {
    const Patch& p = patch[g];
    if (p.n < options.min_patch_points) continue;
    const double mean_a = p.sa / p.n;
    const double var_a = std::max(0.0, p.saa / p.n - mean_a * mean_a);
    kept[g] = std::sqrt(var_a) >= options.min_albedo_stddev && mean_a > 0.0 && p.si > 0.0;
  }
  // A patch's print is carried by the points whose albedo differs from its mean: the
  // participation ratio (sum x^2)^2 / sum x^4 of its relative contrasts counts them. A few
  // dark points on a plain face (a corner of a block, a border's remnant) are left out: a
  // millimetre's misregistration flips what they say.
  std::array<double, kSurfacePatches> px2{}, px4{};
  for (std::size_t k = 0; k < albedo.size(); ++k) {
    if (!usable(k) || !kept[patches[k]]) continue;
    const Patch& p = patch[patches[k]];
    const double x = albedo[k] / (p.sa / p.n) - 1.0;
    px2[patches[k]] += x * x;
    px4[patches[k]] += x * x * x * x;
  }
  for (std::size_t g = 0; g < patch.size(); ++g) {
    if (kept[g] && !(px4[g] > 0.0 && px2[g] * px2[g] / px4[g] >= options.min_patch_points)) {
      kept[g] = false;
    }
  }
  AppearanceScore out;
  double sxx = 0.0, syy = 0.0, sxy = 0.0, saa = 0.0, sx4 = 0.0;
  for (std::size_t k = 0; k < albedo.size(); ++k) {
    if (!usable(k) || !kept[patches[k]]) continue;
    const Patch& p = patch[patches[k]];
    const double mean_a = p.sa / p.n, mean_i = p.si / p.n;
    const double x = albedo[k] / mean_a - 1.0, y = intensity[k] / mean_i - 1.0;
    sxx += x * x;
    sx4 += x * x * x * x;
    syy += y * y;
    sxy += x * y;
    saa += (albedo[k] - mean_a) * (albedo[k] - mean_a);
    ++out.points;
  }
  if (out.points < options.min_points) return out;
  const double n = static_cast<double>(out.points);
  out.albedo_stddev = std::sqrt(saa / n);
  if (sx4 > 0.0) out.contrast_points = sxx * sxx / sx4;
  // With min_albedo_stddev 0 a kept patch may be uniform: no contrast, no evidence.
  if (!(sxx > 0.0) || !(syy > 0.0)) return out;
  if (std::sqrt(syy / n) < options.min_intensity_rel_stddev) return out;
  out.defined = true;
  out.correlation = std::clamp(sxy / std::sqrt(sxx * syy), -1.0, 1.0);
  return out;
}

}  // namespace

AppearanceScore CorrelateAppearance(const std::vector<float>& albedo,
                                    const std::vector<float>& intensity,
                                    const AppearanceOptions& options,
                                    const std::vector<std::uint8_t>* patches) {
  options.Validate();
  if (albedo.size() != intensity.size()) {
    throw std::invalid_argument("CorrelateAppearance: " + std::to_string(albedo.size()) +
                                " albedo values for " + std::to_string(intensity.size()) +
                                " intensities");
  }
  if (patches != nullptr && patches->size() != albedo.size()) {
    throw std::invalid_argument("CorrelateAppearance: " + std::to_string(patches->size()) +
                                " patch labels for " + std::to_string(albedo.size()) + " pairs");
  }
  if (patches != nullptr && options.patch_contrast) {
    return CorrelatePatchContrasts(albedo, intensity, *patches, options);
  }
  AppearanceScore out;
  const auto usable = [&](std::size_t k) {
    return std::isfinite(albedo[k]) && std::isfinite(intensity[k]);
  };
  for (std::size_t k = 0; k < albedo.size(); ++k) out.points += usable(k) ? 1 : 0;
  if (out.points < options.min_points) return out;
  const double n = static_cast<double>(out.points);
  double ma = 0.0, mi = 0.0;
  for (std::size_t k = 0; k < albedo.size(); ++k) {
    if (!usable(k)) continue;
    ma += albedo[k];
    mi += intensity[k];
  }
  ma /= n;
  mi /= n;
  double saa = 0.0, sii = 0.0, sai = 0.0, sa4 = 0.0;
  for (std::size_t k = 0; k < albedo.size(); ++k) {
    if (!usable(k)) continue;
    const double a = albedo[k] - ma, i = intensity[k] - mi;
    saa += a * a;
    sa4 += a * a * a * a;
    sii += i * i;
    sai += a * i;
  }
  out.albedo_stddev = std::sqrt(saa / n);
  if (sa4 > 0.0) out.contrast_points = saa * saa / sa4;
  const double intensity_stddev = std::sqrt(sii / n);
  if (out.albedo_stddev < options.min_albedo_stddev) return out;
  if (!(mi > 0.0) || intensity_stddev < options.min_intensity_rel_stddev * mi) return out;
  out.defined = true;
  out.correlation = std::clamp(sai / std::sqrt(saa * sii), -1.0, 1.0);
  return out;
}

geometry::PointCloud SampleTexturedMeshSurface(const world::TriangleMesh& mesh, double spacing_m,
                                               std::uint32_t seed) {
  if (mesh.empty()) throw std::invalid_argument("SampleTexturedMeshSurface: mesh has no triangles");
  if (!(spacing_m > 0.0)) {
    throw std::invalid_argument("SampleTexturedMeshSurface: spacing_m must be > 0");
  }
  if (!mesh.vertex_albedo.empty() && mesh.vertex_albedo.size() != mesh.vertices.size()) {
    throw std::invalid_argument("SampleTexturedMeshSurface: vertex_albedo has " +
                                std::to_string(mesh.vertex_albedo.size()) + " entries for " +
                                std::to_string(mesh.vertices.size()) + " vertices");
  }
  // SampleMeshSurface (templates.h) is this sampling without the albedo channel.
  std::vector<double> cumulative;
  double total = 0.0;
  for (std::size_t k = 0; k < mesh.triangles.size(); ++k) {
    const auto& tri = mesh.triangles[k];
    for (std::uint32_t idx : tri) {
      if (idx >= mesh.vertices.size()) {
        throw std::invalid_argument("SampleTexturedMeshSurface: triangle " + std::to_string(k) +
                                    " has vertex index " + std::to_string(idx) + " out of range");
      }
    }
    const Eigen::Vector3d a = mesh.vertices[tri[0]].cast<double>();
    const Eigen::Vector3d b = mesh.vertices[tri[1]].cast<double>();
    const Eigen::Vector3d c = mesh.vertices[tri[2]].cast<double>();
    total += 0.5 * (b - a).cross(c - a).norm();
    cumulative.push_back(total);
  }
  if (!(total > 0.0)) throw std::invalid_argument("SampleTexturedMeshSurface: mesh has zero area");
  const std::size_t count = static_cast<std::size_t>(std::ceil(total / (spacing_m * spacing_m)));
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  geometry::PointCloud out;
  out.points.reserve(count);
  out.normals.reserve(count);
  out.intensities.reserve(count);
  for (std::size_t i = 0; i < count; ++i) {
    const double pick = uniform(rng) * total;
    const std::size_t k = std::min<std::size_t>(
        std::lower_bound(cumulative.begin(), cumulative.end(), pick) - cumulative.begin(),
        cumulative.size() - 1);
    const auto& tri = mesh.triangles[k];
    const Eigen::Vector3d a = mesh.vertices[tri[0]].cast<double>();
    const Eigen::Vector3d b = mesh.vertices[tri[1]].cast<double>();
    const Eigen::Vector3d c = mesh.vertices[tri[2]].cast<double>();
    double s = uniform(rng), t = uniform(rng);
    if (s + t > 1.0) {
      s = 1.0 - s;
      t = 1.0 - t;
    }
    const Eigen::Vector3d n = (b - a).cross(c - a);
    if (n.norm() < 1e-15) continue;
    out.points.push_back((a + s * (b - a) + t * (c - a)).cast<float>());
    out.normals.push_back(n.normalized().cast<float>());
    float albedo = mesh.albedo;
    if (!mesh.vertex_albedo.empty()) {
      albedo = static_cast<float>((1.0 - s - t) * mesh.vertex_albedo[tri[0]] +
                                  s * mesh.vertex_albedo[tri[1]] + t * mesh.vertex_albedo[tri[2]]);
    }
    out.intensities.push_back(std::clamp(albedo, 0.0f, 1.0f));
  }
  out.width = static_cast<std::uint32_t>(out.points.size());
  out.height = 1;
  return out;
}

float ColorLuma(const std::array<std::uint8_t, 3>& rgb) {
  return (0.299f * rgb[0] + 0.587f * rgb[1] + 0.114f * rgb[2]) / 255.0f;
}

void IntensitiesFromColors(geometry::PointCloud* cloud) {
  if (cloud->has_intensities() || !cloud->has_colors()) return;
  cloud->intensities.resize(cloud->colors.size());
  for (std::size_t i = 0; i < cloud->colors.size(); ++i) {
    cloud->intensities[i] = ColorLuma(cloud->colors[i]);
  }
}

}  // namespace picking::detector
