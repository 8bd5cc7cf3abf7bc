#include "libs/world/ray_scene.h"

#include <embree3/rtcore.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>
#include <string>

#include "libs/world/mesh_utils.h"

namespace picking::world {
namespace {

void CheckRay(bool committed, const char* who, const Eigen::Vector3d& origin,
              const Eigen::Vector3d& direction) {
  if (!committed) throw std::logic_error(std::string(who) + " before Commit");
  if (!origin.allFinite() || !direction.allFinite() || !(direction.norm() > 0.0)) {
    throw std::invalid_argument(std::string(who) + ": ray origin or direction not finite or zero");
  }
}

}  // namespace

struct RayScene::Impl {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
  bool committed = false;
  HitDistance distance = HitDistance::kSingle;
  std::vector<int> object_of_geometry;                // Embree geometry id -> object id
  std::vector<std::vector<Eigen::Vector3d>> normals;  // per geometry, per triangle
  // HitDistance::kDouble only, per geometry: the placed vertices and the triangles.
  std::vector<std::vector<Eigen::Vector3d>> vertices;
  std::vector<std::vector<std::array<std::uint32_t, 3>>> triangles;

  // Nearest surface in (t_min, t_max] along origin + t * d (d unit) into *rh; false if none.
  bool Intersect(const Eigen::Vector3d& origin, const Eigen::Vector3d& d, double t_min,
                 double t_max, RTCRayHit* rh) const {
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    rh->ray.org_x = static_cast<float>(origin.x());
    rh->ray.org_y = static_cast<float>(origin.y());
    rh->ray.org_z = static_cast<float>(origin.z());
    rh->ray.dir_x = static_cast<float>(d.x());
    rh->ray.dir_y = static_cast<float>(d.y());
    rh->ray.dir_z = static_cast<float>(d.z());
    rh->ray.tnear = static_cast<float>(t_min);
    rh->ray.tfar = static_cast<float>(std::min<double>(t_max, std::numeric_limits<float>::max()));
    rh->ray.mask = 0xFFFFFFFFu;
    rh->ray.flags = 0;
    rh->ray.time = 0.0f;
    rh->hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh->hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(scene, &context, rh);
    return rh->hit.geomID != RTC_INVALID_GEOMETRY_ID;
  }

  // The distance to the plane of the hit triangle in double precision (Moller-Trumbore's);
  // Embree's when the ray runs along the triangle's plane.
  double DoubleDistance(const RTCRayHit& rh, const Eigen::Vector3d& origin,
                        const Eigen::Vector3d& d) const {
    const auto& v = vertices[rh.hit.geomID];
    const auto& tri = triangles[rh.hit.geomID][rh.hit.primID];
    const Eigen::Vector3d& a = v[tri[0]];
    const Eigen::Vector3d e1 = v[tri[1]] - a;
    const Eigen::Vector3d e2 = v[tri[2]] - a;
    const Eigen::Vector3d p = d.cross(e2);
    const double det = e1.dot(p);
    if (std::abs(det) < 1e-15) return rh.ray.tfar;
    const Eigen::Vector3d q = (origin - a).cross(e1);
    return e2.dot(q) * (1.0 / det);
  }

  RayHit Hit(const RTCRayHit& rh, const Eigen::Vector3d& origin, const Eigen::Vector3d& d) const {
    RayHit hit;
    hit.distance_m = distance == HitDistance::kDouble ? DoubleDistance(rh, origin, d) : rh.ray.tfar;
    hit.object_id = object_of_geometry[rh.hit.geomID];
    hit.triangle = rh.hit.primID;
    hit.p_BaseHit = origin + hit.distance_m * d;
    hit.n_Base = normals[rh.hit.geomID][rh.hit.primID];
    return hit;
  }
};

RayScene::RayScene(HitDistance distance) : impl_(std::make_unique<Impl>()) {
  impl_->distance = distance;
  impl_->device = rtcNewDevice("threads=1");
  if (impl_->device == nullptr) {
    throw std::runtime_error("RayScene: rtcNewDevice failed (error " +
                             std::to_string(rtcGetDeviceError(nullptr)) + ")");
  }
  impl_->scene = rtcNewScene(impl_->device);
  rtcSetSceneFlags(impl_->scene, RTC_SCENE_FLAG_ROBUST);
}

RayScene::~RayScene() {
  if (impl_->scene != nullptr) rtcReleaseScene(impl_->scene);
  if (impl_->device != nullptr) rtcReleaseDevice(impl_->device);
}

void RayScene::Add(int object_id, const TriangleMesh& mesh, const Eigen::Isometry3d& X_BaseObject) {
  if (impl_->committed) throw std::logic_error("RayScene::Add after Commit");
  if (!X_BaseObject.matrix().allFinite()) {
    throw std::invalid_argument("RayScene::Add: pose of '" + mesh.name + "' is not finite");
  }
  Validate(mesh);
  if (mesh.empty()) return;
  RTCGeometry geom = rtcNewGeometry(impl_->device, RTC_GEOMETRY_TYPE_TRIANGLE);
  auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(
      geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), mesh.vertices.size()));
  const Eigen::Isometry3f X = X_BaseObject.cast<float>();
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    const Eigen::Vector3f p = X * mesh.vertices[i];
    vb[3 * i] = p.x();
    vb[3 * i + 1] = p.y();
    vb[3 * i + 2] = p.z();
  }
  auto* ib = static_cast<unsigned*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0,
                                                            RTC_FORMAT_UINT3, 3 * sizeof(unsigned),
                                                            mesh.triangles.size()));
  std::vector<Eigen::Vector3d> normals(mesh.triangles.size());
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    for (int k = 0; k < 3; ++k) ib[3 * t + k] = mesh.triangles[t][k];
    normals[t] = X_BaseObject.linear() * FaceNormal(mesh, t).cast<double>();
  }
  rtcCommitGeometry(geom);
  const unsigned id = rtcAttachGeometry(impl_->scene, geom);
  rtcReleaseGeometry(geom);
  if (impl_->object_of_geometry.size() <= id) {
    impl_->object_of_geometry.resize(id + 1, -1);
    impl_->normals.resize(id + 1);
    impl_->vertices.resize(id + 1);
    impl_->triangles.resize(id + 1);
  }
  impl_->object_of_geometry[id] = object_id;
  impl_->normals[id] = std::move(normals);
  if (impl_->distance == HitDistance::kDouble) {
    std::vector<Eigen::Vector3d> vertices(mesh.vertices.size());
    for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
      vertices[i] = X_BaseObject * mesh.vertices[i].cast<double>();
    }
    impl_->vertices[id] = std::move(vertices);
    impl_->triangles[id] = mesh.triangles;
  }
}

void RayScene::Commit() {
  if (impl_->committed) return;
  rtcCommitScene(impl_->scene);
  impl_->committed = true;
}

std::optional<RayHit> RayScene::Cast(const Eigen::Vector3d& p_BaseOrigin,
                                     const Eigen::Vector3d& direction_Base, double t_max,
                                     int ignore_object_id, double t_min) const {
  CheckRay(impl_->committed, "RayScene::Cast", p_BaseOrigin, direction_Base);
  const Eigen::Vector3d d = direction_Base.normalized();
  double start = t_min;
  for (int guard = 0; guard < 64; ++guard) {
    RTCRayHit rh;
    if (!impl_->Intersect(p_BaseOrigin, d, start, t_max, &rh)) return std::nullopt;
    const int object = impl_->object_of_geometry[rh.hit.geomID];
    if (object == ignore_object_id && ignore_object_id != -1) {
      start = std::nextafter(rh.ray.tfar, std::numeric_limits<float>::max());
      continue;
    }
    return impl_->Hit(rh, p_BaseOrigin, d);
  }
  return std::nullopt;
}

std::vector<RayHit> RayScene::CastAll(const Eigen::Vector3d& p_BaseOrigin,
                                      const Eigen::Vector3d& direction_Base, double t_max,
                                      double t_min) const {
  CheckRay(impl_->committed, "RayScene::CastAll", p_BaseOrigin, direction_Base);
  const Eigen::Vector3d d = direction_Base.normalized();
  std::vector<RayHit> hits;
  // Nearest hit, then the nearest beyond it: each step passes at least one surface, and the
  // distances only grow (the last float, FLT_MAX, ends the loop).
  double start = t_min;
  RTCRayHit rh;
  while (impl_->Intersect(p_BaseOrigin, d, start, t_max, &rh)) {
    hits.push_back(impl_->Hit(rh, p_BaseOrigin, d));
    if (!(rh.ray.tfar < std::numeric_limits<float>::max())) break;
    start = std::nextafter(rh.ray.tfar, std::numeric_limits<float>::max());
  }
  return hits;
}

}  // namespace picking::world
