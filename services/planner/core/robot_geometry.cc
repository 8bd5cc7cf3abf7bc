#include "services/planner/core/robot_geometry.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>
#include <stdexcept>

namespace picking::planner {
namespace {

struct SmallTriangle {
  std::array<Eigen::Vector3f, 3> v;
  Eigen::Vector3f centroid() const { return (v[0] + v[1] + v[2]) / 3.f; }
};

// Cuts every triangle of the mesh (mapped by X_BodyMesh) until no edge exceeds max_edge.
std::vector<SmallTriangle> Subdivide(const world::TriangleMesh& mesh,
                                     const Eigen::Isometry3d& X_BodyMesh, double max_edge) {
  const Eigen::Isometry3f X = X_BodyMesh.cast<float>();
  std::vector<SmallTriangle> out;
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3f a = X * mesh.vertices.at(t[0]), b = X * mesh.vertices.at(t[1]),
                          c = X * mesh.vertices.at(t[2]);
    const float longest = std::max({(b - a).norm(), (c - b).norm(), (a - c).norm()});
    const int n = std::max(1, static_cast<int>(std::ceil(longest / max_edge)));
    auto at = [&](int i, int j) {
      return Eigen::Vector3f(a + (b - a) * (float(i) / n) + (c - a) * (float(j) / n));
    };
    for (int i = 0; i < n; ++i) {
      for (int j = 0; j < n - i; ++j) {
        out.push_back({{at(i, j), at(i + 1, j), at(i, j + 1)}});
        if (i + j + 1 < n) out.push_back({{at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)}});
      }
    }
  }
  return out;
}

Sphere EnclosingSphere(const std::vector<SmallTriangle>& triangles,
                       const std::vector<std::size_t>& cluster) {
  Eigen::AlignedBox3f box;
  for (std::size_t i : cluster) {
    for (const auto& v : triangles[i].v) box.extend(v);
  }
  Sphere s;
  s.center_B = box.center();
  float r2 = 0.f;
  for (std::size_t i : cluster) {
    for (const auto& v : triangles[i].v) r2 = std::max(r2, (v - s.center_B).squaredNorm());
  }
  // One part in a million of slack for the float rounding of later transforms.
  s.radius_m = std::sqrt(r2) * (1.f + 1e-6f) + 1e-6f;
  return s;
}

// Orders spheres farthest first (each next one the farthest from those before it): a check
// that stops at the first hit then meets an obstacle that enters a block from any side
// after a few of its spheres, not after every sphere of the block's far side.
void SpreadOut(std::vector<Sphere>::iterator begin, std::vector<Sphere>::iterator end) {
  if (begin == end) return;
  std::vector<float> nearest_sq(static_cast<std::size_t>(end - begin),
                                std::numeric_limits<float>::infinity());
  for (auto placed = begin; placed + 1 != end; ++placed) {
    auto farthest = placed + 1;
    for (auto it = placed + 1; it != end; ++it) {
      float& d = nearest_sq[it - begin];
      d = std::min(d, (it->center_B - placed->center_B).squaredNorm());
      if (d > nearest_sq[farthest - begin]) farthest = it;
    }
    std::iter_swap(placed + 1, farthest);
    std::swap(nearest_sq[placed + 1 - begin], nearest_sq[farthest - begin]);
  }
}

// A coarse sphere for the cluster and, when its triangles spread over several cubes of
// fine_cell_m, one child per cube.
void AddSphere(const std::vector<SmallTriangle>& triangles, const std::vector<std::size_t>& cluster,
               const SphereFitOptions& options, SphereTree* tree) {
  Sphere coarse = EnclosingSphere(triangles, cluster);
  std::map<std::array<int, 3>, std::vector<std::size_t>> cells;
  for (std::size_t i : cluster) {
    const Eigen::Vector3f u = triangles[i].centroid() / static_cast<float>(options.fine_cell_m);
    cells[{int(std::floor(u.x())), int(std::floor(u.y())), int(std::floor(u.z()))}].push_back(i);
  }
  if (cells.size() > 1) {
    coarse.first_child = static_cast<std::uint32_t>(tree->fine.size());
    for (const auto& [cell, members] : cells)
      tree->fine.push_back(EnclosingSphere(triangles, members));
    coarse.num_children = static_cast<std::uint32_t>(cells.size());
  }
  tree->coarse.push_back(coarse);
}

// Splits a cluster of triangles (by centroid) along its longest extent while it is clearly
// longer than wide; each final cluster becomes one coarse sphere.
void SplitCluster(const std::vector<SmallTriangle>& triangles, std::vector<std::size_t> cluster,
                  const SphereFitOptions& options, double min_piece_m, int depth,
                  SphereTree* spheres) {
  Eigen::AlignedBox3f box;
  for (std::size_t i : cluster) box.extend(triangles[i].centroid());
  const Eigen::Vector3f e = box.sizes();
  int axis = 0;
  e.maxCoeff(&axis);
  std::array<float, 3> sorted = {e.x(), e.y(), e.z()};
  std::sort(sorted.begin(), sorted.end());
  const float e_max = sorted[2], e_mid = sorted[1];
  const double target = std::max(options.split_ratio * e_mid, min_piece_m);
  const int n = static_cast<int>(std::ceil(e_max / target));
  if (depth > 12 || cluster.size() < 2 || e_max <= 1.5f * e_mid || n <= 1) {
    AddSphere(triangles, cluster, options, spheres);
    return;
  }
  std::vector<std::vector<std::size_t>> pieces(n);
  for (std::size_t i : cluster) {
    const float u = (triangles[i].centroid()[axis] - box.min()[axis]) / e_max;
    pieces[std::clamp(static_cast<int>(u * n), 0, n - 1)].push_back(i);
  }
  for (auto& piece : pieces) {
    if (!piece.empty())
      SplitCluster(triangles, std::move(piece), options, min_piece_m, depth + 1, spheres);
  }
}

bool IsRigid(const Eigen::Isometry3d& X) {
  if (!X.matrix().allFinite()) return false;
  const Eigen::Matrix3d R = X.linear();
  return (R.transpose() * R - Eigen::Matrix3d::Identity()).norm() < 1e-6 &&
         std::abs(R.determinant() - 1.0) < 1e-6;
}

SphereTree FitWithMinPiece(const world::TriangleMesh& mesh, const Eigen::Isometry3d& X_BodyMesh,
                           const SphereFitOptions& options, double min_piece_m) {
  if (!(options.split_ratio > 0.0) || !(options.max_edge_m > 0.0) || !(options.fine_cell_m > 0.0)) {
    throw std::invalid_argument("FitSpheres: split_ratio, max_edge_m and fine_cell_m must be > 0");
  }
  const std::vector<SmallTriangle> triangles = Subdivide(mesh, X_BodyMesh, options.max_edge_m);
  SphereTree spheres;
  if (triangles.empty()) return spheres;
  std::vector<std::size_t> all(triangles.size());
  std::iota(all.begin(), all.end(), 0);
  SplitCluster(triangles, std::move(all), options, min_piece_m, 0, &spheres);
  return spheres;
}

}  // namespace

const char* BodyName(int body) {
  static constexpr const char* kNames[kNumBodies] = {"base",    "shoulder", "upper_arm",
                                                     "forearm", "wrist_1",  "wrist_2",
                                                     "wrist_3", "gripper",  "carried item"};
  return body >= 0 && body < kNumBodies ? kNames[body] : "unknown";
}

Sphere EnclosingSphereOf(const SphereTree& tree) {
  Sphere bound;
  bound.radius_m = -1.f;
  if (tree.coarse.empty()) return bound;
  Eigen::AlignedBox3f box;
  for (const Sphere& s : tree.coarse) box.extend(s.center_B);
  bound.center_B = box.center();
  bound.radius_m = 0.f;
  for (const Sphere& s : tree.coarse) {
    bound.radius_m = std::max(bound.radius_m, (s.center_B - bound.center_B).norm() + s.radius_m);
  }
  bound.radius_m = bound.radius_m * (1.f + 1e-6f) + 1e-6f;
  return bound;
}

SphereTree FitSpheres(const world::TriangleMesh& mesh, const Eigen::Isometry3d& X_BodyMesh,
                      const SphereFitOptions& options) {
  return FitWithMinPiece(mesh, X_BodyMesh, options, 0.04);
}

std::vector<Sphere> CylinderSpheres(double radius_m, double length_m) {
  std::vector<Sphere> spheres;
  if (!(radius_m > 0.0) || !(length_m > 0.0)) return spheres;
  const int n = std::max(1, static_cast<int>(std::ceil(length_m / radius_m)));
  const double slab = length_m / n;
  const float r = static_cast<float>(std::hypot(radius_m, 0.5 * slab) * (1.0 + 1e-6) + 1e-6);
  for (int i = 0; i < n; ++i) {
    spheres.push_back({Eigen::Vector3f(0.f, 0.f, static_cast<float>((i + 0.5) * slab)), r});
  }
  return spheres;
}

CarriedItem MakeCarriedItem(const std::string& name, const Eigen::AlignedBox3d& box_Item,
                            const Eigen::Isometry3d& X_TcpItem) {
  if (box_Item.isEmpty() || !box_Item.min().allFinite() || !box_Item.max().allFinite() ||
      (box_Item.sizes().array() <= 0.0).any()) {
    throw std::invalid_argument("carried item '" + name + "' needs a non-empty finite box");
  }
  if (!IsRigid(X_TcpItem)) {
    throw std::invalid_argument("carried item '" + name + "': X_TcpItem must be rigid");
  }
  CarriedItem item;
  item.name = name;
  item.box_Item = box_Item;
  item.X_TcpItem = X_TcpItem;
  // The box's surface layer as cubes of at most 1.5 cm, each in the sphere through its
  // corners (it sticks out of the box's faces by at most 0.37 of a cube's edge, 5.5 mm). Inner
  // cubes are left out: an obstacle meets the surface layer before it could lie inside (scan
  // voxels inside the item are cut out). The cubes are grouped in blocks of at most 4 x 4 x 4,
  // each block's a coarse sphere enclosing its cubes' spheres, so that only the blocks near
  // an obstacle have their cubes looked at.
  const Eigen::Vector3d size = box_Item.sizes();
  Eigen::Array3i n;
  for (int i = 0; i < 3; ++i) n[i] = std::max(1, static_cast<int>(std::ceil(size[i] / 0.015)));
  const Eigen::Vector3d cube = size.array() / n.cast<double>();
  const float cube_radius = static_cast<float>(0.5 * cube.norm() * (1.0 + 1e-6) + 1e-6);
  constexpr int kBlock = 4;
  const Eigen::Array3i blocks = (n + kBlock - 1) / kBlock;
  auto& tree = item.spheres_Item;
  for (int bi = 0; bi < blocks.x(); ++bi) {
    for (int bj = 0; bj < blocks.y(); ++bj) {
      for (int bk = 0; bk < blocks.z(); ++bk) {
        Sphere coarse;
        coarse.first_child = static_cast<std::uint32_t>(tree.fine.size());
        Eigen::AlignedBox3f block;
        for (int i = bi * kBlock; i < std::min(n.x(), (bi + 1) * kBlock); ++i) {
          for (int j = bj * kBlock; j < std::min(n.y(), (bj + 1) * kBlock); ++j) {
            for (int k = bk * kBlock; k < std::min(n.z(), (bk + 1) * kBlock); ++k) {
              const bool surface =
                  i == 0 || j == 0 || k == 0 || i == n.x() - 1 || j == n.y() - 1 || k == n.z() - 1;
              if (!surface) continue;
              const Eigen::Vector3f centre =
                  (box_Item.min() +
                   (Eigen::Vector3d(i, j, k).array() + 0.5).matrix().cwiseProduct(cube))
                      .cast<float>();
              tree.fine.push_back({centre, cube_radius, 0, 0});
              block.extend(centre);
            }
          }
        }
        coarse.num_children = static_cast<std::uint32_t>(tree.fine.size()) - coarse.first_child;
        if (coarse.num_children == 0) continue;
        SpreadOut(tree.fine.begin() + coarse.first_child, tree.fine.end());
        coarse.center_B = block.center();
        for (std::uint32_t c = 0; c < coarse.num_children; ++c) {
          const Sphere& child = tree.fine[coarse.first_child + c];
          coarse.radius_m =
              std::max(coarse.radius_m, (child.center_B - coarse.center_B).norm() + child.radius_m);
        }
        coarse.radius_m = coarse.radius_m * (1.f + 1e-6f) + 1e-6f;
        tree.coarse.push_back(coarse);
      }
    }
  }
  item.bound_Item = EnclosingSphereOf(item.spheres_Item);
  return item;
}

GripperGeometry GripperGeometry::FromCell(const world::GripperConfig& config,
                                          double head_angle_rad) {
  GripperGeometry g;
  g.X_ToolTcp = config.X_ToolTcp;
  g.tube_radius_m = config.tube_radius_m;
  g.cup_length_m = config.cup_length_m;
  g.head_length_m = config.head_length_m;
  g.max_head_angle_rad = config.max_head_angle_rad;
  return g.AtHeadAngle(head_angle_rad);
}

GripperGeometry GripperGeometry::AtHeadAngle(double angle_rad) const {
  if (const std::string problem = world::HeadAngleProblem(angle_rad, max_head_angle_rad);
      !problem.empty()) {
    throw std::invalid_argument("head angle " + problem);
  }
  GripperGeometry g = *this;
  g.head_angle_rad = angle_rad;
  if (head_length_m == 0.0 || angle_rad == head_angle_rad) return g;
  // The joint frame: z along the straight tube; the head turns about its x axis.
  const Eigen::Isometry3d X_ToolJoint =
      X_ToolTcp * Eigen::Translation3d(0.0, 0.0, -head_length_m) *
      Eigen::AngleAxisd(-head_angle_rad, Eigen::Vector3d::UnitX());
  g.X_ToolTcp = X_ToolJoint * Eigen::AngleAxisd(angle_rad, Eigen::Vector3d::UnitX()) *
                Eigen::Translation3d(0.0, 0.0, head_length_m);
  return g;
}

Eigen::Vector3d GripperGeometry::p_ToolJoint() const {
  return X_ToolTcp * Eigen::Vector3d(0.0, 0.0, -head_length_m);
}

bool GripperGeometry::bent() const {
  if (head_length_m == 0.0) return false;
  const Eigen::Vector3d p_J = p_ToolJoint();
  const Eigen::Vector3d z_Tcp = X_ToolTcp.linear().col(2);
  return p_J.norm() > 1e-9 && p_J.normalized().cross(z_Tcp).norm() > 1e-9;
}

namespace {

void ValidateGripper(const GripperGeometry& g) {
  if (!(g.tube_radius_m > 0.0) || !std::isfinite(g.tube_radius_m)) {
    throw std::invalid_argument("gripper tube radius must be finite and > 0");
  }
  if (!(g.cup_length_m >= 0.0) || !std::isfinite(g.cup_length_m)) {
    throw std::invalid_argument("gripper cup length must be finite and >= 0");
  }
  if (!IsRigid(g.X_ToolTcp)) {
    throw std::invalid_argument("gripper X_ToolTcp must be a finite rigid transform");
  }
  if (g.head_length_m != 0.0 &&
      !(g.head_length_m > g.cup_length_m && g.head_length_m < g.reach_m())) {
    throw std::invalid_argument("gripper head length must lie between the cup's and the tube's");
  }
}

}  // namespace

RobotGeometry::RobotGeometry(const ur10::Ur10Kinematics& kinematics, const GripperGeometry& gripper,
                             const SphereFitOptions& fit)
    : kinematics_(kinematics), gripper_(gripper) {
  ValidateGripper(gripper_);
  const ur10::Ur10Model& model = kinematics_.model();
  for (int i = 0; i < 7; ++i) {
    const auto link = static_cast<ur10::Link>(i);
    const world::TriangleMesh mesh = model.LoadCollisionMesh(link);
    link_meshes_[i] = world::TriangleMesh();
    link_meshes_[i].name = ur10::LinkName(link);
    const Eigen::Isometry3f X = model.X_LinkMesh(link).cast<float>();
    for (const auto& v : mesh.vertices) link_meshes_[i].vertices.push_back(X * v);
    link_meshes_[i].triangles = mesh.triangles;
    spheres_[i] = FitSpheres(mesh, model.X_LinkMesh(link), fit);
  }
  BuildGripper();
  ChooseSelfPairs();
}

RobotGeometry RobotGeometry::WithGripper(const GripperGeometry& gripper) const {
  ValidateGripper(gripper);
  RobotGeometry other = *this;
  other.gripper_ = gripper;
  other.BuildGripper();
  // The gripper's pairs chosen again for its new shape (a bent head reaches links the
  // straight tube never did); the links' pairs and tables stay.
  auto& pairs = other.self_pairs_;
  pairs.erase(std::remove_if(pairs.begin(), pairs.end(),
                             [](const auto& p) { return p.second == kBodyTool; }),
              pairs.end());
  std::vector<std::pair<int, int>> candidates;
  for (int a = 0; a + 2 <= kBodyTool && other.fcl_geometry_[kBodyTool]; ++a) {
    candidates.emplace_back(a, kBodyTool);
  }
  const auto first_item =
      std::find_if(pairs.begin(), pairs.end(), [](const auto& p) { return p.second == kBodyItem; });
  const auto chosen = other.SelectTouchingPairs(candidates);
  pairs.insert(first_item, chosen.begin(), chosen.end());
  return other;
}

std::size_t RobotGeometry::num_arm_spheres() const {
  std::size_t n = 0;
  for (const auto& s : spheres_) n += s.size();
  return n;
}

void RobotGeometry::ComputePoses(const JointVector& q_rad, const CarriedItem* carried,
                                 BodyPoses* X) const {
  const auto links = kinematics_.LinkFrames(q_rad);
  for (int i = 0; i < 7; ++i) (*X)[i] = links[i];
  (*X)[kBodyTool] = links[6] * kinematics_.model().X_Wrist3Tool();
  if (carried) (*X)[kBodyItem] = (*X)[kBodyTool] * gripper_.X_ToolTcp * carried->X_TcpItem;
}

// ChooseSelfPairs: self_collision.cc (it samples with FCL).

}  // namespace picking::planner
