// Planner speed figures beside their peers, in one run (benchmarks/RESULTS.md, "Planner"):
//   - scene build from a 1.3-million-point scan of a bin with the target's hull cut out,
//     against OctoMap's insertPointCloud (ray casting, and with `discretize`);
//   - state checks per second on one core, fast check against FCL, on the same states;
//   - exact validation of a whole pick's trajectories;
//   - PlanPick into and out of the bins of pick_layout_1..3 (median, p95);
//   - joint motions between named poses (roadmap), and the refusal of an infeasible pick.
// The scans are the simulator's ground-truth depth from the planner's scan poses.
//
// Arguments: `--picks-only` skips the scene, state-check and joint-motion figures (the pick
// figures and the infeasible refusal only); `--checks-only` gives the state checks only;
// `--layouts=1,2` plans those layouts only;
// `--all-failures` lists every grasp's failure of a target without a plan, not just the
// most advanced one; `--reach-oracle` says for each target without a plan how many grasp
// poses on its faces are free at all (FreeGraspPoses: 0 means no plan could end there);
// `--describe-bins` lists, for each target without a plan, every item of its bin as the
// simulator placed it (depth from the opening, across from the bin's right wall as the robot
// sees it, height over the floor: the bounds of its box, metres).
// pick_layout_3 is held out: the planner is developed on layouts 1 and 2 and the figures are given
// per layout.
#include <octomap/OcTree.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "libs/apc/task.h"
#include "libs/camera/pinhole_camera.h"
#include "libs/world/cell_config.h"
#include "libs/world/item_models.h"
#include "services/planner/core/motion_planner.h"
#include "services/simulator/core/renderer.h"
#include "services/simulator/core/sim_world.h"

namespace picking::planner {
namespace {

using Clock = std::chrono::steady_clock;

double Ms(Clock::time_point since) {
  return std::chrono::duration<double, std::milli>(Clock::now() - since).count();
}

double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<std::size_t>(p * (v.size() - 1) + 0.5))];
}

Deadline Far() { return Clock::now() + std::chrono::seconds(30); }

struct Setup {
  std::shared_ptr<ur10::Ur10Kinematics> kinematics;
  world::CellModel cell;
  std::shared_ptr<world::ItemModelLibrary> items;
  std::unique_ptr<MotionPlanner> planner;
  Eigen::Isometry3d X_ToolCamera = Eigen::Isometry3d(Eigen::Translation3d(-0.075, 0.06, 0.04));
};

const NamedPose& Named(const MotionPlanner& planner, const std::string& name) {
  for (const auto& p : planner.named_poses()) {
    if (p.name == name) return p;
  }
  throw std::runtime_error("no named pose " + name);
}

// The simulator's depth from a camera, as points in base.
std::vector<float> Scan(const simulator::StructuredLightRenderer& renderer,
                        const camera::PinholeCamera& camera,
                        const Eigen::Isometry3d& X_BaseCamera) {
  const simulator::DepthImage depth = renderer.RenderDepth(camera, X_BaseCamera);
  std::vector<float> xyz;
  xyz.reserve(depth.size() * 3);
  for (int v = 0; v < depth.height; ++v) {
    for (int u = 0; u < depth.width; ++u) {
      const float d = depth.at(u, v);
      if (!std::isfinite(d) || d <= 0.f) continue;
      const Eigen::Vector3d ray((u + 0.5 - camera.cx()) / camera.fx(),
                                (v + 0.5 - camera.cy()) / camera.fy(), 1.0);
      const Eigen::Vector3d p = X_BaseCamera * (ray * d);
      xyz.insert(xyz.end(), {float(p.x()), float(p.y()), float(p.z())});
    }
  }
  return xyz;
}

void SceneBuild(const Setup& s, const std::vector<float>& xyz, const std::string& bin,
                const std::string& item, const Eigen::Isometry3d& X_BaseItem,
                const Eigen::Vector3d& p_BaseSensor) {
  const std::size_t n = xyz.size() / 3;
  std::vector<double> ours;
  PlanningScene scene;
  for (int i = 0; i < 10; ++i) {
    const auto t = Clock::now();
    scene = s.planner->BuildScene(bin, xyz.data(), n, item, X_BaseItem);
    ours.push_back(Ms(t));
  }
  octomap::Pointcloud cloud;
  for (std::size_t i = 0; i < n; ++i) cloud.push_back(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
  const octomap::point3d origin(p_BaseSensor.x(), p_BaseSensor.y(), p_BaseSensor.z());
  std::vector<double> rays, discretized;
  for (int i = 0; i < 2; ++i) {
    octomap::OcTree tree(0.01);
    auto t = Clock::now();
    tree.insertPointCloud(cloud, origin, -1.0, false, false);
    rays.push_back(Ms(t));
    octomap::OcTree tree2(0.01);
    t = Clock::now();
    tree2.insertPointCloud(cloud, origin, -1.0, false, true);
    discretized.push_back(Ms(t));
  }
  std::printf("scene build, %zu points (%zu kept in the region, %zu cut), %zu voxels at 1 cm:\n", n,
              n - scene.stats.points_outside - scene.stats.points_invalid, scene.stats.points_cut,
              scene.stats.voxels_total);
  std::printf(
      "  ours (voxels, hull cut-out, distance grid, OctoMap): median %.1f ms, min %.1f ms\n",
      Percentile(ours, 0.5), Percentile(ours, 0.0));
  std::printf("  OctoMap insertPointCloud, ray casting:  median %.1f ms\n", Percentile(rays, 0.5));
  std::printf("  OctoMap insertPointCloud, discretize:   median %.1f ms\n",
              Percentile(discretized, 0.5));
}

void StateChecks(const Setup& s, const PlanningScene& scene, const std::string& bin) {
  const FastChecker fast(s.planner->robot(), s.planner->cell(), scene.obstacles.get());
  const ExactChecker exact(s.planner->robot(), s.planner->cell(), scene.obstacles.get());
  const ExactChecker fcl_only(s.planner->robot(), s.planner->cell(), scene.obstacles.get(),
                              /*sphere_broad_phase=*/false);
  // States with the tcp in and in front of the bin, the tool pointing in, tilted at random.
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> tilt(0.0, 0.3);
  const world::BinGeometry& geometry = s.cell.bin(bin);
  std::vector<JointVector> states;
  const JointVector seed = Named(*s.planner, "scan/" + bin + "/0").q_rad;
  while (states.size() < 200000) {
    Eigen::Vector3d p_S = geometry.inner_S.min() + geometry.inner_S.sizes().cwiseProduct(
                                                       Eigen::Vector3d(u(rng), u(rng), u(rng)));
    p_S.x() += 0.2 * u(rng);
    Eigen::Vector3d z = s.cell.config.X_BaseShelf.linear() * -Eigen::Vector3d::UnitX();
    z = (z + Eigen::Vector3d(tilt(rng), tilt(rng), tilt(rng))).normalized();
    const Eigen::Vector3d x = (Eigen::Vector3d::UnitZ().cross(z)).normalized();
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() << x, z.cross(x), z;
    X.translation() = s.cell.config.X_BaseShelf * p_S;
    const auto ik =
        s.kinematics->NearestSolution(X * s.planner->robot().gripper().X_ToolTcp.inverse(), seed);
    if (ik) states.push_back(ik->q_rad);
  }
  const CarriedItem item = MakeCarriedItem(
      "box",
      Eigen::AlignedBox3d(Eigen::Vector3d(-0.06, -0.05, -0.1), Eigen::Vector3d(0.06, 0.05, 0.0)),
      Eigen::Isometry3d::Identity());
  for (const CarriedItem* carried : {static_cast<const CarriedItem*>(nullptr), &item}) {
    int free = 0;
    auto t = Clock::now();
    for (const auto& q : states) free += fast.IsFree(q, carried);
    const double fast_ms = Ms(t);
    const std::size_t n_fcl = 5000;
    int fcl_free = 0;
    t = Clock::now();
    for (std::size_t i = 0; i < n_fcl; ++i)
      fcl_free += !fcl_only.Check(states[i], carried).in_collision;
    const double fcl_ms = Ms(t);
    const std::size_t n_exact = 50000;
    int exact_free = 0;
    t = Clock::now();
    for (std::size_t i = 0; i < n_exact; ++i)
      exact_free += !exact.Check(states[i], carried).in_collision;
    const double exact_ms = Ms(t);
    std::printf("state checks, arm + gripper%s, tcp in and before %s (%zu voxels):\n",
                carried ? " + carried item" : "", bin.c_str(),
                scene.obstacles->num_occupied_voxels);
    std::printf("  fast (sphere trees, distance grids): %.2f M states/s (%.1f%% free)\n",
                states.size() / fast_ms / 1e3, 100.0 * free / states.size());
    std::printf("  exact (spheres' broad phase, FCL):   %.0f states/s (%.1f%% free)\n",
                n_exact / exact_ms * 1e3, 100.0 * exact_free / n_exact);
    std::printf("  FCL on every pair (meshes, OcTree):  %.0f states/s (%.1f%% free)\n",
                n_fcl / fcl_ms * 1e3, 100.0 * fcl_free / n_fcl);
  }
}

struct BenchArgs {
  bool picks_only = false;
  bool checks_only = false;
  bool all_failures = false;
  bool reach_oracle = false;
  bool describe_bins = false;
  std::vector<int> layouts = {1, 2, 3};
  /// The gripper's head on a servo joint (0: the cell's gripper as described).
  double head_length_m = -1.0;
  double max_head_angle_deg = 90.0;
  /// The tube's length to the lip (0: the cell's).
  double tube_length_m = 0.0;
};

// What Picks measures, over every target tried.
struct PickFigures {
  std::vector<double> times, validation, validation_fcl, refusals, place_times, place_robot_s;
  std::map<std::string, std::vector<double>> stage_ms;  // per planned pick
  int tried = 0, planned = 0, placed = 0, sealed = 0;
  std::vector<std::pair<int, int>> per_layout;  // (planned, tried)
  std::map<std::string, int> no_seal;           // why a planned pick's cup does not seal
};

// Whether the planned pick's cup seals in the simulator: the arm at the descent's end, the
// head as planned, the guarded move run, and the simulator's seal test where it stops.
// Changes only the simulated arm.
std::string SealOfPlan(simulator::SimWorld* world, const PickPlan& plan) {
  world->SetHeadAngle(plan.head_angle_rad);
  world->SetJointPositions(plan.descend.samples.back().q_rad);
  const simulator::GuardedMoveResult pressed = world->GuardedMove(plan.guarded_distance_m);
  const world::SealMeasure seal = world->SealAt(world->X_BaseTcp());
  world->SetHeadAngle(0.0);
  if (!pressed.contact) return "the guarded move touches nothing";
  return seal.sealed ? "" : seal.reason;
}

// The simulated scan of `bin` from its three scan poses (points in base).
std::vector<float> ScanBin(const Setup& s, const simulator::StructuredLightRenderer& renderer,
                           const std::string& bin) {
  const camera::PinholeCamera camera(480, 384, 460.0, 460.0, 240.0, 192.0);
  std::vector<float> xyz;
  for (int k = 0; k < 3; ++k) {
    const JointVector q = Named(*s.planner, "scan/" + bin + "/" + std::to_string(k)).q_rad;
    const auto view = Scan(renderer, camera, s.kinematics->ForwardKinematics(q) * s.X_ToolCamera);
    xyz.insert(xyz.end(), view.begin(), view.end());
  }
  return xyz;
}

// Exact validation of the pick's three trajectories at every sample (PlanPick validates every
// 8th and the path's nodes), with and without the spheres' broad phase; the item hangs from
// the cup as it was at the grasp (the retreat's first sample).
void ValidateEverySample(const Setup& s, const PlanningScene& scene, const PickPlan& plan,
                         const CarriedItem& carried, PickFigures* f) {
  const ExactChecker exact(s.planner->robot(), s.planner->cell(), scene.obstacles.get());
  const ExactChecker fcl_only(s.planner->robot(), s.planner->cell(), scene.obstacles.get(),
                              /*sphere_broad_phase=*/false);
  for (const ExactChecker* checker : {&exact, &fcl_only}) {
    const auto v = Clock::now();
    for (const Trajectory* tr : {&plan.approach, &plan.descend, &plan.retreat}) {
      for (const auto& sample : tr->samples) {
        const CarriedItem* none = nullptr;
        checker->Check(sample.q_rad, tr == &plan.retreat ? &carried : none);
      }
    }
    (checker == &exact ? f->validation : f->validation_fcl).push_back(Ms(v));
  }
}

// On to the tote with the item, from the retreat's end.
void PlaceAfter(const Setup& s, const PickPlan& plan, const CarriedItem& carried,
                const std::string& label, PickFigures* f) {
  PlaceRequest place;
  place.item = carried.name;
  place.X_TcpItem = carried.X_TcpItem;
  place.container = "tote";
  place.start_rad = plan.retreat.samples.back().q_rad;
  place.head_angle_rad = plan.head_angle_rad;
  const auto p = Clock::now();
  try {
    const PlacePlan placed = s.planner->PlanPlace(place, Far());
    f->place_times.push_back(Ms(p));
    f->place_robot_s.push_back(placed.trajectory.duration_s());
    ++f->placed;
  } catch (const PlanFailedError& e) {
    std::printf("    no place: %s (%.0f ms): %s\n", label.c_str(), Ms(p), e.what());
  }
}

// Whether the arm can stand at the item at all: grasp poses on every face of the item's box
// that does not face down or into the bin (a 5 x 5 grid inset by the cup's radius), the cup
// along the face's normal or tilted by up to the grasps' 12 degrees, the head at 0..90
// degrees in 10-degree steps, the bent tube rolled about the approach in 30-degree steps,
// every IK solution, each checked by the fast check against the cell and the scan. A target
// none of whose poses is free has no grasp any plan could end at (a necessary condition:
// the motions in and out are not looked at). Returns the free poses found (0 = none).
int FreeGraspPoses(const Setup& s, const PlanningScene& scene, const std::string& bin,
                   const std::string& item, const Eigen::Isometry3d& X_BaseItem) {
  const GraspContainer container = ShelfBinContainer(s.cell, bin);
  const Eigen::Vector3d& o = container.opening_direction_Base;
  const Eigen::AlignedBox3d& box = s.items->Get(item)->box_I;
  const RobotGeometry& robot = s.planner->robot();
  const double cup_radius_m = robot.gripper().tube_radius_m;
  constexpr double kMaxTiltRad = 12.0 * M_PI / 180.0;
  std::vector<std::unique_ptr<RobotGeometry>> heads;
  std::vector<std::unique_ptr<FastChecker>> checkers;
  for (int deg = 0; deg <= 90; deg += 10) {
    heads.push_back(std::make_unique<RobotGeometry>(
        robot.WithGripper(robot.gripper().AtHeadAngle(deg * M_PI / 180.0))));
    checkers.push_back(
        std::make_unique<FastChecker>(*heads.back(), s.planner->cell(), scene.obstacles.get()));
  }
  int free = 0;
  for (int face = 0; face < 6; ++face) {
    const int axis = face / 2;
    const double sign = face % 2 ? 1.0 : -1.0;
    const Eigen::Vector3d n_Base = X_BaseItem.linear() * (sign * Eigen::Vector3d::Unit(axis));
    if (n_Base.z() < -0.2 || n_Base.dot(o) < -0.2) continue;  // facing down or into the bin
    const int u = (axis + 1) % 3, v = (axis + 2) % 3;
    if (std::min(box.sizes()[u], box.sizes()[v]) < 2.0 * cup_radius_m) continue;  // cup too big
    for (int i = 0; i < 25; ++i) {
      Eigen::Vector3d p_Item = box.center();
      p_Item[axis] = sign > 0 ? box.max()[axis] : box.min()[axis];
      const double half_u = std::max(0.0, box.sizes()[u] / 2 - cup_radius_m);
      const double half_v = std::max(0.0, box.sizes()[v] / 2 - cup_radius_m);
      p_Item[u] += half_u * ((i % 5) / 2.0 - 1.0);
      p_Item[v] += half_v * ((i / 5) / 2.0 - 1.0);
      const Eigen::Vector3d p_Base = X_BaseItem * p_Item;
      for (int tilt = 0; tilt < 5; ++tilt) {
        Eigen::Vector3d a = -n_Base;
        if (tilt > 0) {
          const Eigen::Vector3d t_axis =
              n_Base.unitOrthogonal().cross(n_Base) * (tilt % 2 ? 1.0 : -1.0);
          const Eigen::Vector3d axis_Base = tilt <= 2 ? t_axis : n_Base.cross(t_axis);
          a = Eigen::AngleAxisd(kMaxTiltRad, axis_Base.normalized()) * a;
        }
        for (std::size_t h = 0; h < heads.size(); ++h) {
          for (int roll = 0; roll < (h == 0 ? 1 : 12); ++roll) {
            Eigen::Matrix3d R;
            R.col(2) = a;
            R.col(1) = Eigen::AngleAxisd(roll * M_PI / 6.0, a) * a.unitOrthogonal();
            R.col(0) = R.col(1).cross(R.col(2));
            Eigen::Isometry3d X_BaseTcp = Eigen::Isometry3d::Identity();
            X_BaseTcp.linear() = R;
            X_BaseTcp.translation() = p_Base;
            const Eigen::Isometry3d X_BaseTool =
                X_BaseTcp * heads[h]->gripper().X_ToolTcp.inverse();
            for (const auto& solution : s.kinematics->Solve(X_BaseTool).solutions) {
              if (checkers[h]->IsFree(solution.q_rad)) ++free;
            }
          }
        }
      }
    }
  }
  return free;
}

// The items of a bin as placed (ground truth): the shelf-frame bounds of each item's box as
// depth behind the opening, across from the bin's -y wall and height over its floor. The
// target is starred.
void DescribeBin(const Setup& s, const std::string& bin, const std::string& target,
                 const std::vector<simulator::ItemState>& in_bin) {
  const world::BinGeometry& b = s.cell.bin(bin);
  const Eigen::Isometry3d X_ShelfBase = s.cell.config.X_BaseShelf.inverse();
  std::printf("      %s: %.2f m deep, %.2f m wide, %.2f m high\n", bin.c_str(), b.depth_m(),
              b.width_m(), b.height_m());
  for (const auto& state : in_bin) {
    const Eigen::AlignedBox3d& box_Item = s.items->Get(state.name)->box_I;
    Eigen::AlignedBox3d box_Shelf;
    for (int c = 0; c < 8; ++c) {
      box_Shelf.extend(X_ShelfBase * state.X_BaseItem *
                       box_Item.corner(static_cast<Eigen::AlignedBox3d::CornerType>(c)));
    }
    std::printf("      %s %-36s depth %.2f..%.2f, across %.2f..%.2f, height %.2f..%.2f\n",
                state.name == target ? "*" : " ", state.name.c_str(),
                b.opening_x_m - box_Shelf.max().x(), b.opening_x_m - box_Shelf.min().x(),
                box_Shelf.min().y() - b.inner_S.min().y(),
                box_Shelf.max().y() - b.inner_S.min().y(), box_Shelf.min().z() - b.floor_max_z_m,
                box_Shelf.max().z() - b.floor_max_z_m);
  }
}

// One target: its bin scanned, the pick planned, validated and carried on to the tote.
void PickOne(const Setup& s, simulator::SimWorld* world,
             const simulator::StructuredLightRenderer& renderer, int layout, const std::string& bin,
             const std::string& item, const std::vector<simulator::ItemState>& in_bin,
             const Eigen::Isometry3d& X_BaseItem, const BenchArgs& args, PickFigures* f) {
  const std::vector<float> xyz = ScanBin(s, renderer, bin);
  const PlanningScene scene =
      s.planner->BuildScene(bin, xyz.data(), xyz.size() / 3, item, X_BaseItem);
  PickRequest request;
  request.item = item;
  request.X_BaseItem = X_BaseItem;
  request.container = bin;
  request.start_rad = Named(*s.planner, "scan/" + bin + "/0").q_rad;
  ++f->tried;
  ++f->per_layout.back().second;
  const std::string label = "layout " + std::to_string(layout) + " " + bin + " " + item;
  const auto t = Clock::now();
  try {
    const PickPlan plan = s.planner->PlanPick(request, &scene, Far());
    f->times.push_back(Ms(t));
    for (const auto& [stage, seconds] : plan.stage_times_s) {
      f->stage_ms[stage].push_back(1e3 * seconds);
    }
    ++f->planned;
    ++f->per_layout.back().first;
    std::printf("  planned: %s: grasp '%s' in %.1f ms, %d grasps tried, %d search nodes\n",
                label.c_str(), plan.grasp.surface.c_str(), Ms(t), plan.grasps_tried,
                plan.nodes_expanded);
    const Eigen::Isometry3d X_grasp =
        s.planner->robot().X_BaseTcp(plan.retreat.samples.front().q_rad);
    const CarriedItem carried =
        MakeCarriedItem(item, s.items->Get(item)->box_I, X_grasp.inverse() * X_BaseItem);
    const std::string no_seal = SealOfPlan(world, plan);
    if (no_seal.empty()) {
      ++f->sealed;
    } else {
      ++f->no_seal[no_seal];
      std::printf("      the cup does not seal in the simulator: %s\n", no_seal.c_str());
    }
    ValidateEverySample(s, scene, plan, carried, f);
    PlaceAfter(s, plan, carried, label, f);
  } catch (const PlanFailedError& e) {
    f->refusals.push_back(Ms(t));
    std::printf("  no plan: %s (%.0f ms): %s\n", label.c_str(), Ms(t), e.what());
    if (args.describe_bins) DescribeBin(s, bin, item, in_bin);
    if (args.reach_oracle) {
      std::printf("      free grasp poses at all: %d\n",
                  FreeGraspPoses(s, scene, bin, item, X_BaseItem));
    }
    if (args.all_failures) {
      for (std::size_t i = 1; i < e.failures().size(); ++i) {
        std::printf("      also: [%s / %s] %s\n", FailureStageName(e.failures()[i].stage),
                    FailureKindName(e.failures()[i].kind), e.failures()[i].message.c_str());
      }
    }
  }
}

void PrintPickFigures(const PickFigures& f, const BenchArgs& args) {
  std::printf(
      "PlanPick (pre-grasp, descend, lift, retreat with the item, approach; timed and\n"
      "validated): %d of %d planned\n",
      f.planned, f.tried);
  for (std::size_t i = 0; i < args.layouts.size(); ++i) {
    std::printf("  pick_layout_%d%s: %d of %d planned\n", args.layouts[i],
                args.layouts[i] == 3 ? " (held out)" : "", f.per_layout[i].first,
                f.per_layout[i].second);
  }
  std::printf("  the cup seals in the simulator (guarded move, seal test) on %d of %d planned\n",
              f.sealed, f.planned);
  for (const auto& [reason, n] : f.no_seal) std::printf("    %d: %s\n", n, reason.c_str());
  std::printf("  planned: median %.1f ms, p95 %.1f ms, max %.1f ms\n", Percentile(f.times, 0.5),
              Percentile(f.times, 0.95), Percentile(f.times, 1.0));
  std::printf("  refused: median %.1f ms, p95 %.1f ms, max %.1f ms\n", Percentile(f.refusals, 0.5),
              Percentile(f.refusals, 0.95), Percentile(f.refusals, 1.0));
  std::printf("  where a planned pick's time goes (median, p95 ms):");
  for (const auto& [stage, ms] : f.stage_ms) {
    std::printf(" %s %.1f, %.1f;", stage.c_str(), Percentile(ms, 0.5), Percentile(ms, 0.95));
  }
  std::printf("\n");
  std::printf("PlanPlace from the retreat's end to the tote: %d of %d planned picks\n", f.placed,
              f.planned);
  std::printf("  placed: median %.1f ms, p95 %.1f ms, max %.1f ms\n",
              Percentile(f.place_times, 0.5), Percentile(f.place_times, 0.95),
              Percentile(f.place_times, 1.0));
  std::printf("  place motions (robot time): median %.1f s, p95 %.1f s, max %.1f s\n",
              Percentile(f.place_robot_s, 0.5), Percentile(f.place_robot_s, 0.95),
              Percentile(f.place_robot_s, 1.0));
  std::printf("exact validation of a pick's trajectories, every sample (8 ms apart):\n");
  std::printf("  ours (spheres' broad phase, FCL): median %.1f ms, p95 %.1f ms\n",
              Percentile(f.validation, 0.5), Percentile(f.validation, 0.95));
  std::printf("  FCL on every pair:                median %.1f ms, p95 %.1f ms\n",
              Percentile(f.validation_fcl, 0.5), Percentile(f.validation_fcl, 0.95));
}

void Picks(const Setup& s, simulator::SimWorld* world, const BenchArgs& args) {
  PickFigures f;
  for (const int layout : args.layouts) {
    f.per_layout.emplace_back(0, 0);
    const std::string path = std::string(PICKING_DATA_DIR) + "/apc2016/tasks/pick_layout_" +
                             std::to_string(layout) + ".json";
    const apc::Task task = apc::ReadTaskFile(path, s.items->catalogue());
    world->LoadTask(task, 7);
    const simulator::StructuredLightRenderer renderer(world->SceneMeshes());
    for (const auto& entry : task.work_order) {
      const auto in_bin = world->ItemsIn(entry.bin);
      const auto it = std::find_if(in_bin.begin(), in_bin.end(),
                                   [&](const auto& st) { return st.name == entry.item; });
      if (it == in_bin.end()) continue;
      PickOne(s, world, renderer, layout, entry.bin, entry.item, in_bin, it->X_BaseItem, args, &f);
    }
  }
  PrintPickFigures(f, args);
}

void JointMotions(const Setup& s) {
  const auto& named = s.planner->named_poses();
  std::mt19937 rng(5);
  std::vector<double> first, again;
  std::vector<std::pair<int, int>> pairs;
  for (int i = 0; i < 60; ++i) {
    pairs.emplace_back(std::uniform_int_distribution<int>(0, named.size() - 1)(rng),
                       std::uniform_int_distribution<int>(0, named.size() - 1)(rng));
  }
  int failed = 0;
  for (int round = 0; round < 2; ++round) {
    for (const auto& [a, b] : pairs) {
      if (a == b) continue;
      const auto t = Clock::now();
      try {
        s.planner->PlanJointMotion(named[a].q_rad, named[b].q_rad, 1.0, Far());
        (round == 0 ? first : again).push_back(Ms(t));
      } catch (const std::exception&) {
        failed += round == 0;
      }
    }
  }
  std::printf(
      "PlanJointMotion between named poses (paths planned at set-up; timed, validated), %zu "
      "pairs, %d failed:\n",
      first.size(), failed);
  std::printf("  first time: median %.2f ms, p95 %.2f ms; again (timed once): median %.2f ms\n",
              Percentile(first, 0.5), Percentile(first, 0.95), Percentile(again, 0.5));
  // From where a pick leaves the arm, off the named poses: the roadmap searched online.
  const FastChecker fast(s.planner->robot(), s.planner->cell(), nullptr);
  std::normal_distribution<double> off(0.0, 0.15);
  std::vector<double> online;
  int online_failed = 0;
  for (const auto& [a, b] : pairs) {
    if (a == b) continue;
    JointVector start = named[a].q_rad;
    for (int tries = 0; tries < 20; ++tries) {
      const JointVector q = named[a].q_rad + JointVector::NullaryExpr([&] { return off(rng); });
      if (s.kinematics->model().WithinPositionLimits(q) && fast.IsFree(q)) {
        start = q;
        break;
      }
    }
    const auto t = Clock::now();
    try {
      s.planner->PlanJointMotion(start, named[b].q_rad, 1.0, Far());
      online.push_back(Ms(t));
    } catch (const std::exception&) {
      ++online_failed;
    }
  }
  std::printf(
      "  from a start off the named poses (each joint 0.15 rad off, normal): median %.2f ms, "
      "p95 %.2f ms, %d failed\n",
      Percentile(online, 0.5), Percentile(online, 0.95), online_failed);
}

void Infeasible(const Setup& s) {
  const auto& d = s.cell.bin("bin_D");
  const auto& e = s.cell.bin("bin_E");
  Eigen::Isometry3d X_ShelfItem = Eigen::Isometry3d::Identity();
  X_ShelfItem.translation() =
      Eigen::Vector3d(d.opening_x_m - 0.2, 0.5 * (d.inner_S.max().y() + e.inner_S.min().y()),
                      d.floor_max_z_m + 0.05);
  PickRequest request;
  request.item = "dove_beauty_bar";
  request.X_BaseItem = s.cell.config.X_BaseShelf * X_ShelfItem;
  request.container = "bin_E";
  request.start_rad = Named(*s.planner, "scan/bin_E/0").q_rad;
  std::vector<double> times;
  for (int i = 0; i < 5; ++i) {
    const auto t = Clock::now();
    try {
      s.planner->PlanPick(request, nullptr, Far());
    } catch (const std::exception&) {
    }
    times.push_back(Ms(t));
  }
  std::printf("an infeasible pick (the item inside a shelf wall) refused in: median %.1f ms\n",
              Percentile(times, 0.5));
}

}  // namespace
}  // namespace picking::planner

int main(int argc, char** argv) {
  using namespace picking;
  using namespace picking::planner;
  BenchArgs args;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--picks-only") {
      args.picks_only = true;
    } else if (arg == "--checks-only") {
      args.checks_only = true;
    } else if (arg == "--all-failures") {
      args.all_failures = true;
    } else if (arg == "--reach-oracle") {
      args.reach_oracle = true;
    } else if (arg == "--describe-bins") {
      args.describe_bins = true;
    } else if (arg.rfind("--head-length-m=", 0) == 0) {
      args.head_length_m = std::stod(arg.substr(16));
    } else if (arg.rfind("--tube-length-m=", 0) == 0) {
      args.tube_length_m = std::stod(arg.substr(16));
    } else if (arg.rfind("--max-head-angle-deg=", 0) == 0) {
      args.max_head_angle_deg = std::stod(arg.substr(21));
    } else if (arg.rfind("--layouts=", 0) == 0) {
      args.layouts.clear();
      for (char c : arg.substr(10)) {
        if (c >= '1' && c <= '3') args.layouts.push_back(c - '0');
      }
    } else {
      std::fprintf(stderr,
                   "usage: %s [--picks-only | --checks-only] [--layouts=1,2,3] [--all-failures]\n"
                   "       [--reach-oracle] [--describe-bins]\n"
                   "       [--head-length-m=0.09 [--max-head-angle-deg=90]] [--tube-length-m=0.35]"
                   "  (the gripper; --head-length-m=0: straight)\n",
                   argv[0]);
      return 2;
    }
  }
  Setup s;
  s.kinematics =
      std::make_shared<ur10::Ur10Kinematics>(ur10::Ur10Model::Load(PICKING_DATA_DIR "/ur10"));
  world::CellConfig config = world::ReadCellConfig(PICKING_DATA_DIR "/cell/default_cell.yaml");
  if (args.head_length_m >= 0.0) {
    config.gripper.head_length_m = args.head_length_m;
    config.gripper.max_head_angle_rad =
        args.head_length_m > 0.0 ? args.max_head_angle_deg * M_PI / 180.0 : 0.0;
  }
  if (args.tube_length_m > 0.0) config.gripper.X_ToolTcp.translation().z() = args.tube_length_m;
  std::printf("gripper: %.3f m to the lip, a %.3f m head on a joint of +-%.0f deg\n",
              config.gripper.X_ToolTcp.translation().z(), config.gripper.head_length_m,
              config.gripper.max_head_angle_rad * 180.0 / M_PI);
  s.cell = world::LoadCellModel(config);
  apc::Catalogue catalogue = apc::Catalogue::FromCsvFile(apc::DefaultCataloguePath());
  auto grasps = std::make_shared<const GraspTable>(
      GraspTable::FromYamlFile(DefaultGraspTablePath(), catalogue));
  s.items = std::make_shared<world::ItemModelLibrary>(catalogue);
  const GripperGeometry gripper = GripperGeometry::FromCell(config.gripper);
  auto t = Clock::now();
  s.planner = std::make_unique<MotionPlanner>(*s.kinematics, s.cell, gripper, s.X_ToolCamera,
                                              grasps, s.items);
  std::printf(
      "planner set-up (grids, self-collision pairs and table, named poses, roadmap): %.0f ms\n",
      Ms(t));

  simulator::SimWorld world(s.cell, s.items, simulator::SimOptions{}, s.kinematics);
  if (args.picks_only) {
    Infeasible(s);
    Picks(s, &world, args);
    return 0;
  }
  const apc::Task task = apc::ReadTaskFile(
      std::string(PICKING_DATA_DIR) + "/apc2016/tasks/pick_layout_1.json", s.items->catalogue());
  world.LoadTask(task, 7);
  // A 1.3-million-point scan of bin_E: the middle view at 1420 x 920 pixels.
  const std::string bin = "bin_E";
  const auto in_bin = world.ItemsIn(bin);
  const simulator::StructuredLightRenderer renderer(world.SceneMeshes());
  const camera::PinholeCamera camera(1420, 920, 1100.0, 1100.0, 710.0, 460.0);
  const Eigen::Isometry3d X_BaseCamera =
      s.kinematics->ForwardKinematics(Named(*s.planner, "scan/" + bin + "/0").q_rad) *
      s.X_ToolCamera;
  const std::vector<float> xyz = Scan(renderer, camera, X_BaseCamera);
  if (!args.checks_only) {
    SceneBuild(s, xyz, bin, in_bin.front().name, in_bin.front().X_BaseItem,
               X_BaseCamera.translation());
  }
  const PlanningScene scene = s.planner->BuildScene(bin, xyz.data(), xyz.size() / 3,
                                                    in_bin.front().name, in_bin.front().X_BaseItem);
  StateChecks(s, scene, bin);
  if (args.checks_only) return 0;
  JointMotions(s);
  Infeasible(s);
  Picks(s, &world, args);
  return 0;
}
