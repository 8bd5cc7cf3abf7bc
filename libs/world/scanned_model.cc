#include "libs/world/scanned_model.h"

#include <pcl/common/centroid.h>
#include <pcl/features/normal_3d.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/point_types.h>
#include <pcl/search/kdtree.h>
#include <pcl/surface/gp3.h>

#include <Eigen/Eigenvalues>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <thread>

#include <unistd.h>

#include "libs/geometry/temp_path.h"
#include "libs/world/mesh_utils.h"
#include "libs/world/ply_mesh_io.h"

namespace picking::world {
namespace {

// Mesh in the scan frame.
TriangleMesh Reconstruct(const std::string& ply_path, const ScanReconstructionOptions& o) {
  const TriangleMesh points = ReadPly(ply_path);
  if (points.vertices.size() < 10) {
    throw std::runtime_error("scanned model '" + ply_path + "': too few points");
  }
  auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZRGB>>();
  cloud->reserve(points.vertices.size());
  for (std::size_t i = 0; i < points.vertices.size(); ++i) {
    pcl::PointXYZRGB p;
    p.x = points.vertices[i].x();
    p.y = points.vertices[i].y();
    p.z = points.vertices[i].z();
    if (!points.vertex_colors.empty()) {
      p.r = points.vertex_colors[i][0];
      p.g = points.vertex_colors[i][1];
      p.b = points.vertex_colors[i][2];
    } else {
      p.r = p.g = p.b = 160;
    }
    cloud->push_back(p);
  }
  auto down = std::make_shared<pcl::PointCloud<pcl::PointXYZRGB>>();
  pcl::VoxelGrid<pcl::PointXYZRGB> grid;
  grid.setInputCloud(cloud);
  const auto leaf = static_cast<float>(o.voxel_m);
  grid.setLeafSize(leaf, leaf, leaf);
  grid.filter(*down);

  auto normals = std::make_shared<pcl::PointCloud<pcl::Normal>>();
  pcl::NormalEstimation<pcl::PointXYZRGB, pcl::Normal> ne;
  auto tree = std::make_shared<pcl::search::KdTree<pcl::PointXYZRGB>>();
  ne.setInputCloud(down);
  ne.setSearchMethod(tree);
  ne.setKSearch(o.normal_neighbours);
  ne.compute(*normals);
  Eigen::Vector4f centroid;
  pcl::compute3DCentroid(*down, centroid);

  auto with_normals = std::make_shared<pcl::PointCloud<pcl::PointXYZRGBNormal>>();
  for (std::size_t i = 0; i < down->size(); ++i) {
    const auto& n = (*normals)[i];
    if (!std::isfinite(n.normal_x)) continue;
    pcl::PointXYZRGBNormal p;
    p.x = (*down)[i].x;
    p.y = (*down)[i].y;
    p.z = (*down)[i].z;
    p.rgb = (*down)[i].rgb;
    Eigen::Vector3f nv(n.normal_x, n.normal_y, n.normal_z);
    if (nv.dot(p.getVector3fMap() - centroid.head<3>()) < 0) nv = -nv;
    p.normal_x = nv.x();
    p.normal_y = nv.y();
    p.normal_z = nv.z();
    with_normals->push_back(p);
  }
  auto tree2 = std::make_shared<pcl::search::KdTree<pcl::PointXYZRGBNormal>>();
  tree2->setInputCloud(with_normals);
  pcl::GreedyProjectionTriangulation<pcl::PointXYZRGBNormal> gp3;
  gp3.setSearchRadius(o.search_radius_m);
  gp3.setMu(o.mu);
  gp3.setMaximumNearestNeighbors(o.max_nearest_neighbours);
  gp3.setMaximumSurfaceAngle(M_PI / 4);
  gp3.setMinimumAngle(M_PI / 18);
  gp3.setMaximumAngle(2 * M_PI / 3);
  gp3.setNormalConsistency(false);
  gp3.setInputCloud(with_normals);
  gp3.setSearchMethod(tree2);
  std::vector<pcl::Vertices> polygons;
  gp3.reconstruct(polygons);

  TriangleMesh mesh;
  mesh.name = std::filesystem::path(ply_path).stem().string();
  for (const auto& p : *with_normals) {
    mesh.vertices.emplace_back(p.x, p.y, p.z);
    mesh.vertex_colors.push_back({p.r, p.g, p.b});
  }
  for (const auto& poly : polygons) {
    if (poly.vertices.size() != 3) continue;
    std::array<std::uint32_t, 3> t = {static_cast<std::uint32_t>(poly.vertices[0]),
                                      static_cast<std::uint32_t>(poly.vertices[1]),
                                      static_cast<std::uint32_t>(poly.vertices[2])};
    const Eigen::Vector3f& a = mesh.vertices[t[0]];
    const Eigen::Vector3f face = (mesh.vertices[t[1]] - a).cross(mesh.vertices[t[2]] - a);
    Eigen::Vector3f normal_sum = Eigen::Vector3f::Zero();
    for (auto v : t) normal_sum += (*with_normals)[v].getNormalVector3fMap();
    if (face.dot(normal_sum) < 0) std::swap(t[1], t[2]);
    mesh.triangles.push_back(t);
  }
  if (mesh.triangles.empty()) {
    throw std::runtime_error("scanned model '" + ply_path + "': reconstruction gave no triangles");
  }
  return mesh;
}

// Item frame from the principal axes, and the mesh moved into it.
ScannedModel ToItemFrame(TriangleMesh mesh_scan) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& v : mesh_scan.vertices) mean += v.cast<double>();
  mean /= static_cast<double>(mesh_scan.vertices.size());
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const auto& v : mesh_scan.vertices) {
    const Eigen::Vector3d d = v.cast<double>() - mean;
    cov += d * d.transpose();
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
  // Eigenvalues ascending: columns 2, 1, 0 are the long, middle and short axes.
  Eigen::Matrix3d R;
  R.col(0) = eig.eigenvectors().col(2);
  R.col(1) = eig.eigenvectors().col(1);
  // Deterministic signs: the largest component of each axis positive.
  for (int c = 0; c < 2; ++c) {
    Eigen::Index k;
    R.col(c).cwiseAbs().maxCoeff(&k);
    if (R(k, c) < 0) R.col(c) = -R.col(c);
  }
  R.col(2) = R.col(0).cross(R.col(1));
  Eigen::Isometry3d X_ScanPca = Eigen::Isometry3d::Identity();
  X_ScanPca.linear() = R;
  X_ScanPca.translation() = mean;
  const Eigen::AlignedBox3d box = Bounds(mesh_scan, X_ScanPca.inverse());
  ScannedModel model;
  model.X_ScanItem = X_ScanPca * Eigen::Translation3d(box.center());
  model.mesh = Transformed(mesh_scan, model.X_ScanItem.inverse());
  model.mesh.vertex_albedo.clear();
  for (const auto& c : model.mesh.vertex_colors) {
    model.mesh.vertex_albedo.push_back((0.299f * c[0] + 0.587f * c[1] + 0.114f * c[2]) / 255.0f);
  }
  return model;
}

std::uint64_t Fnv1a(const std::string& bytes, std::uint64_t h = 1469598103934665603ull) {
  for (unsigned char c : bytes) {
    h ^= c;
    h *= 1099511628211ull;
  }
  return h;
}

}  // namespace

ScannedModel ReconstructScannedModel(const std::string& ply_path,
                                     const ScanReconstructionOptions& options) {
  return ToItemFrame(Reconstruct(ply_path, options));
}

std::string DefaultModelCacheDir() {
  const char* env = std::getenv("PICKING_CACHE_DIR");
  if (env != nullptr && *env != '\0') return (std::filesystem::path(env) / "models").string();
  return (std::filesystem::temp_directory_path() / "picking-cache" / "models").string();
}

ScannedModel LoadScannedModelCached(const std::string& ply_path, std::string cache_dir,
                                    const ScanReconstructionOptions& options) {
  if (cache_dir.empty()) cache_dir = DefaultModelCacheDir();
  std::ifstream in(ply_path, std::ios::binary);
  if (!in) throw std::runtime_error("scanned model '" + ply_path + "': cannot open");
  std::stringstream bytes;
  bytes << in.rdbuf();
  std::ostringstream opts;
  opts << options.voxel_m << ' ' << options.normal_neighbours << ' ' << options.search_radius_m
       << ' ' << options.mu << ' ' << options.max_nearest_neighbours;
  const std::uint64_t key = Fnv1a(opts.str(), Fnv1a(bytes.str()));
  char hex[17];
  std::snprintf(hex, sizeof(hex), "%016llx", static_cast<unsigned long long>(key));
  const std::filesystem::path cache =
      std::filesystem::path(cache_dir) /
      (std::filesystem::path(ply_path).stem().string() + ".v" +
       std::to_string(kScannedModelCacheVersion) + "-" + hex + ".ply");
  if (std::filesystem::is_regular_file(cache)) {
    try {
      TriangleMesh mesh = ReadPly(cache.string());
      if (!mesh.empty()) {
        mesh.name = std::filesystem::path(ply_path).stem().string();
        return ToItemFrame(std::move(mesh));
      }
    } catch (const std::runtime_error&) {
      // A damaged cache file is rebuilt below.
    }
  }
  TriangleMesh mesh_scan = Reconstruct(ply_path, options);
  std::filesystem::create_directories(cache_dir);
  const std::string tmp_name = geometry::TemporaryPathBeside(cache.string());
  WritePly(tmp_name, mesh_scan,
           "scanned model cache v" + std::to_string(kScannedModelCacheVersion));
  std::filesystem::rename(tmp_name, cache);
  return ToItemFrame(std::move(mesh_scan));
}

}  // namespace picking::world
