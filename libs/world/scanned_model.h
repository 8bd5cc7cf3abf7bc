#pragma once

#include <Eigen/Geometry>

#include <string>

#include "libs/world/mesh.h"

namespace picking::world {

/// Options of ReconstructScannedModel. Defaults suit the APC 2016 scanned models (dense,
/// about 0.5 mm point spacing).
struct ScanReconstructionOptions {
  double voxel_m = 0.002;          ///< Voxel grid downsampling leaf before meshing.
  int normal_neighbours = 20;      ///< k of the k-nearest-neighbour normal estimation.
  double search_radius_m = 0.012;  ///< Greedy projection triangulation: maximal edge length.
  double mu = 2.5;                 ///< Greedy projection: neighbour distance multiplier.
  int max_nearest_neighbours = 100;
};

/// A surface mesh built from a coloured scanned point cloud.
struct ScannedModel {
  /// The mesh in its item frame: origin at the centre of its bounding box, principal axes
  /// sorted so x is the longest extent, y the middle and z the shortest (right-handed).
  /// Vertex colours come from the scan; vertex_albedo is their luma in [0, 1].
  TriangleMesh mesh;
  /// Pose of the item frame in the frame of the scan file (maps item-frame points to the
  /// original model coordinates), for tools that use the raw point cloud.
  Eigen::Isometry3d X_ScanItem = Eigen::Isometry3d::Identity();
};

/// Reconstructs a mesh from a point cloud PLY (x y z, optional red green blue): voxel grid
/// downsampling, normals by PCA over k neighbours oriented away from the centroid,
/// pcl::GreedyProjectionTriangulation, triangles wound to agree with the vertex normals, and the
/// principal-axes item frame. Throws std::runtime_error naming the file if it cannot be read
/// or gives no triangles.
ScannedModel ReconstructScannedModel(const std::string& ply_path,
                                     const ScanReconstructionOptions& options = {});

/// As ReconstructScannedModel, through a disk cache: `<cache_dir>/<stem>.v<kVersion>-<key>.ply`
/// where the key hashes the source file's bytes and the options, so a changed scan, changed
/// options or a new reconstruction version rebuilds it. The cache holds the mesh in the scan
/// frame; the item frame is recomputed on loading (deterministic). The file is written
/// atomically (temporary file and rename), so concurrent processes are safe. An empty
/// `cache_dir` uses DefaultModelCacheDir().
ScannedModel LoadScannedModelCached(const std::string& ply_path, std::string cache_dir = "",
                                    const ScanReconstructionOptions& options = {});

/// `$PICKING_CACHE_DIR/models` when set, else `<system temp dir>/picking-cache/models`.
std::string DefaultModelCacheDir();

/// Version of the reconstruction written into cache file names.
constexpr int kScannedModelCacheVersion = 1;

}  // namespace picking::world
