#include "services/planner/core/time_optimal.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

// Kunz & Stilman's time-optimal path parametrisation, in five stages:
//   1. path building   (straight segments and circular blends),
//   2. limit curves    (acceleration and velocity limit curves, path acceleration bounds),
//   3. switching points,
//   4. integration     (forward, backward, splicing),
//   5. sampling.
//
// The phase plane is stored as (s, x = s_dot^2): a piece of constant path acceleration u is a
// straight line there (dx/ds = 2u), so the profile is a chain of such intervals and the
// intersections of two of them are exact. Intervals never straddle a segment junction.

namespace picking::planner {
namespace {

using ur10::kNumJoints;

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kPi = 3.14159265358979323846;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
// Consecutive segment directions closer than this (|d1 - d0|) are one straight stretch: the
// velocity kink left is below rounding.
constexpr double kCollinearTolerance = 1e-11;
// A blend of a smaller radius, rad, becomes a stop at its corner (a near reversal).
constexpr double kMinBlendRadiusRad = 1e-4;
// A phase-plane step (and the velocity-curve scan) on a blend covers at most this fraction of
// its radius, which keeps the in-step margins near 2e-4 of the limits (trajectories 0.06 %
// longer than at half the step on the benchmark's random walks, and the law 20 % faster).
constexpr double kBlendStepPerRadius = 0.04;
// Blends are planned this far (relative) inside the limits: a reserve for rounding in the
// in-step bounds.
constexpr double kBlendSlack = 1e-6;
// Near a limit curve a step on a blend is halved down to this fraction of the regular step;
// integration stops where not even that is feasible (which locates the curve).
constexpr double kMinStepFraction = 1.0 / 64.0;
// A switching point must allow a first step of this fraction of the regular step each way.
constexpr double kProbeStepFraction = 1.0 / 8.0;
// A regular sample closer to the end than this fraction of a period is left out.
constexpr double kEndSampleMinGap = 0.01;
// Most samples returned (4 GB of them).
constexpr double kMaxSamples = 2e7;

struct Limits {
  JointVector v;     // rad/s
  JointVector v_sq;  // (rad/s)^2
  JointVector a;     // rad/s^2
};

Limits MakeLimits(const TimeOptimalOptions& options, double scale) {
  Limits limits;
  limits.v = options.max_velocity_rad_s * scale;
  limits.v_sq = limits.v.cwiseProduct(limits.v);
  limits.a = options.max_acceleration_rad_s2 * scale;
  return limits;
}

void Validate(const std::vector<JointVector>& waypoints, const TimeOptimalOptions& options) {
  auto fail = [](const std::string& message) {
    throw std::invalid_argument("TimeParametrizeTimeOptimal: " + message);
  };
  if (waypoints.empty()) fail("no waypoints");
  for (std::size_t i = 0; i < waypoints.size(); ++i) {
    if (!waypoints[i].allFinite()) fail("waypoint " + std::to_string(i) + " is not finite");
  }
  for (int j = 0; j < kNumJoints; ++j) {
    const double v = options.max_velocity_rad_s[j];
    const double a = options.max_acceleration_rad_s2[j];
    if (!(std::isfinite(v) && v > 0.0)) {
      fail(std::string("max_velocity_rad_s of ") + ur10::kJointNames[j] +
           " must be finite and > 0, got " + std::to_string(v));
    }
    if (!(std::isfinite(a) && a > 0.0)) {
      fail(std::string("max_acceleration_rad_s2 of ") + ur10::kJointNames[j] +
           " must be finite and > 0, got " + std::to_string(a));
    }
  }
  if (!(std::isfinite(options.max_deviation_rad) && options.max_deviation_rad >= 0.0)) {
    fail("max_deviation_rad must be finite and >= 0, got " +
         std::to_string(options.max_deviation_rad));
  }
  if (!(options.sample_period_s >= 1e-6 && options.sample_period_s <= 1.0)) {
    fail("sample_period_s must be in [1e-6, 1] s, got " + std::to_string(options.sample_period_s));
  }
  if (!(options.integration_step_s >= 1e-6 && options.integration_step_s <= 0.1)) {
    fail("integration_step_s must be in [1e-6, 0.1] s, got " +
         std::to_string(options.integration_step_s));
  }
  if (options.point_speed_rate) {
    if (!(std::isfinite(options.max_point_speed) && options.max_point_speed > 0.0)) {
      fail("max_point_speed must be finite and > 0 with a point_speed_rate, got " +
           std::to_string(options.max_point_speed));
    }
    if (!(options.point_speed_step_rad >= 1e-4 && options.point_speed_step_rad <= 1.0)) {
      fail("point_speed_step_rad must be in [1e-4, 1] rad, got " +
           std::to_string(options.point_speed_step_rad));
    }
  }
}

// ---------------------------------------------------------------------------------------
// Stage 1: path building.

// A straight line q(s) = p0 + s d0, or a circular arc
// q(s) = p0 + r sin(s/r) d0 + r (1 - cos(s/r)) n, s in [0, length] (joint-space arc length).
// The arc form needs no centre, so it stays exact for huge radii (shallow corners).
struct Segment {
  bool is_arc = false;
  double length = 0.0;
  JointVector p0 = JointVector::Zero();
  JointVector d0 = JointVector::Zero();   // unit start tangent
  JointVector n = JointVector::Zero();    // arc: unit normal towards the centre
  JointVector rho = JointVector::Zero();  // arc: amplitude sqrt(d0_i^2 + n_i^2) of joint i
  double radius = 0.0;                    // arc
  double angle = 0.0;                     // arc: turned angle, rad
  double line_accel = 0.0;                // line: largest path acceleration
  double line_x = 0.0;                    // line: largest s_dot^2
  // arc: squared joint speed limits on it (the blend limits, lowered where a point speed bound
  // asks for it: TimeOptimalOptions::point_speed_rate).
  JointVector v_sq = JointVector::Zero();
};

JointVector Position(const Segment& seg, double s) {
  if (!seg.is_arc) return seg.p0 + s * seg.d0;
  const double theta = s / seg.radius;
  const double half = std::sin(0.5 * theta);
  return seg.p0 + (seg.radius * std::sin(theta)) * seg.d0 +
         (2.0 * seg.radius * half * half) * seg.n;
}

// dq/ds and d2q/ds2 at s.
void Tangents(const Segment& seg, double s, JointVector* dq, JointVector* ddq) {
  if (!seg.is_arc) {
    *dq = seg.d0;
    ddq->setZero();
    return;
  }
  const double theta = s / seg.radius;
  const double c = std::cos(theta);
  const double sn = std::sin(theta);
  *dq = c * seg.d0 + sn * seg.n;
  *ddq = (c * seg.n - sn * seg.d0) / seg.radius;
}

Segment MakeLine(const JointVector& from, const JointVector& direction, double length,
                 const Limits& exact) {
  Segment seg;
  seg.p0 = from;
  seg.d0 = direction;
  seg.length = length;
  seg.line_accel = kInf;
  seg.line_x = kInf;
  for (int i = 0; i < kNumJoints; ++i) {
    const double d = std::abs(direction[i]);
    if (d == 0.0) continue;
    seg.line_accel = std::min(seg.line_accel, exact.a[i] / d);
    seg.line_x = std::min(seg.line_x, exact.v_sq[i] / (d * d));
  }
  return seg;
}

// The blend at `corner` between the segments from `prev` and to `next`; false if there is
// none (no deviation allowed, or a radius below kMinBlendRadiusRad). *t is the distance of the
// blend's ends from the corner, *deviation its distance from the corner.
bool MakeBlend(const JointVector& prev, const JointVector& corner, const JointVector& next,
               double max_deviation, Segment* arc, double* t, double* deviation) {
  const double l0 = (corner - prev).norm();
  const double l1 = (next - corner).norm();
  const JointVector d0 = (corner - prev) / l0;
  const JointVector d1 = (next - corner) / l1;
  const double sin_half = 0.5 * (d1 - d0).norm();  // of the turned angle
  const double cos_half = 0.5 * (d1 + d0).norm();
  if (!(max_deviation > 0.0) || !(sin_half > 0.0)) return false;
  // deviation = t (1 - cos_half) / sin_half = t sin_half / (1 + cos_half) <= max_deviation.
  const double t_blend =
      std::min({0.5 * l0, 0.5 * l1, max_deviation * (1.0 + cos_half) / sin_half});
  const double radius = t_blend * cos_half / sin_half;
  if (!(radius >= kMinBlendRadiusRad)) return false;
  *t = t_blend;
  JointVector n = (d1 - d0) + (2.0 * sin_half * sin_half) * d0;  // d1 - cos(angle) d0
  n -= n.dot(d0) * d0;
  n.normalize();
  arc->is_arc = true;
  arc->p0 = corner - *t * d0;
  arc->d0 = d0;
  arc->n = n;
  arc->radius = radius;
  arc->angle = 2.0 * std::atan2(sin_half, cos_half);
  arc->length = arc->angle * radius;
  for (int i = 0; i < kNumJoints; ++i) arc->rho[i] = std::hypot(d0[i], n[i]);
  *deviation = *t * sin_half / (1.0 + cos_half);
  return true;
}

// The waypoints without exact repeats and without the waypoints inside straight stretches.
std::vector<JointVector> Corners(const std::vector<JointVector>& waypoints) {
  std::vector<JointVector> corners = {waypoints.front()};
  for (std::size_t i = 1; i < waypoints.size(); ++i) {
    if (waypoints[i] == corners.back()) continue;
    if (corners.size() >= 2) {
      const JointVector d0 = (corners.back() - corners[corners.size() - 2]).normalized();
      const JointVector d1 = (waypoints[i] - corners.back()).normalized();
      if ((d1 - d0).norm() < kCollinearTolerance) {
        corners.back() = waypoints[i];
        continue;
      }
    }
    corners.push_back(waypoints[i]);
  }
  return corners;
}

double MinLimitX(const Segment& arc, const Limits& limits);  // stage 2

// Whether passing a blend is faster than stopping at its corner (an estimate). Against
// cruising at speed V on a side (A the line's path acceleration), stopping at the corner costs
// V / (2 A); slowing down to the blend's lowest speed w at the blend's end, t before the
// corner, costs (V - w)^2 / (2 A V), and the blend takes angle * radius / w instead of 2 t / V.
// V is the line's speed limit or what a rest-to-rest move over the segment reaches.
bool BlendPaysOff(const Segment& arc, double t, const Segment& line_in, double length_in,
                  const Segment& line_out, double length_out, const Limits& blend_limits) {
  double loss = 0.0;  // blending minus stopping, s
  double w = std::sqrt(MinLimitX(arc, blend_limits));
  for (const auto& [line, length] : {std::pair{&line_in, length_in}, {&line_out, length_out}}) {
    const double a = line->line_accel;
    const double v = std::min(std::sqrt(line->line_x), std::sqrt(a * length));
    w = std::min(w, v);
    loss += (v - w) * (v - w) / (2.0 * a * v) - v / (2.0 * a) - t / v;
  }
  return loss + arc.angle * arc.radius / w <= 0.0;
}

struct Path {
  std::vector<std::vector<Segment>> pieces;  // rest-to-rest pieces
  int num_blends = 0;
  int num_stops = 0;
  double max_blend_deviation_rad = 0.0;
};

// Pieces of lines and blends between the stops. Every piece starts and ends with a line.
Path BuildPath(const std::vector<JointVector>& corners, double max_deviation, const Limits& exact,
               const Limits& blend_limits) {
  Path path;
  const std::size_t m = corners.size() - 1;
  std::vector<double> t(m + 1, 0.0);
  std::vector<Segment> arcs(m + 1);
  std::vector<double> deviations(m + 1, 0.0);
  for (std::size_t i = 1; i < m; ++i) {
    if (!MakeBlend(corners[i - 1], corners[i], corners[i + 1], max_deviation, &arcs[i], &t[i],
                   &deviations[i])) {
      continue;
    }
    arcs[i].v_sq = blend_limits.v_sq;
    const JointVector d1 = (corners[i + 1] - corners[i]).normalized();
    if (!BlendPaysOff(arcs[i], t[i], MakeLine(corners[i - 1], arcs[i].d0, 1.0, exact),
                      (corners[i] - corners[i - 1]).norm(), MakeLine(corners[i], d1, 1.0, exact),
                      (corners[i + 1] - corners[i]).norm(), blend_limits)) {
      t[i] = 0.0;
    }
  }
  std::vector<Segment> piece;
  for (std::size_t i = 1; i <= m; ++i) {
    const double l = (corners[i] - corners[i - 1]).norm();
    const JointVector direction = (corners[i] - corners[i - 1]) / l;
    const JointVector start =
        t[i - 1] > 0.0 ? JointVector(corners[i - 1] + t[i - 1] * direction) : corners[i - 1];
    const double length = l - t[i - 1] - t[i];
    if (length > 0.0) piece.push_back(MakeLine(start, direction, length, exact));
    if (i < m && t[i] > 0.0) {
      piece.push_back(arcs[i]);
      ++path.num_blends;
      path.max_blend_deviation_rad = std::max(path.max_blend_deviation_rad, deviations[i]);
    } else {
      path.pieces.push_back(std::move(piece));
      piece.clear();
      if (i < m) ++path.num_stops;
    }
  }
  return path;
}

double PointSpeedFactor(const Segment& seg, const TimeOptimalOptions& options);  // stage 2b

// Duration of the rest-to-rest motion that stops at every corner: per segment a trapezoid
// (or triangle) of the path parameter limited by the tightest joint (and the point speed
// bound, if any).
double StopEverywhereDuration(const std::vector<JointVector>& corners, const Limits& exact,
                              const TimeOptimalOptions& options) {
  double duration = 0.0;
  for (std::size_t i = 1; i < corners.size(); ++i) {
    const JointVector delta = corners[i] - corners[i - 1];
    const double length = delta.norm();
    if (!(length > 0.0)) continue;
    Segment line = MakeLine(corners[i - 1], delta / length, length, exact);
    if (options.point_speed_rate) line.line_x *= PointSpeedFactor(line, options);
    const double v = std::sqrt(line.line_x);  // path speed and acceleration, rad/s, rad/s^2
    const double a = line.line_accel;
    duration += v * v / a >= length ? 2.0 * std::sqrt(length / a) : length / v + v / a;
  }
  return duration;
}

// ---------------------------------------------------------------------------------------
// Stage 2: limit curves. At a path point with derivatives dq, ddq and x = s_dot^2, joint i
// moves at dq_i s_dot and accelerates at dq_i u + ddq_i x for a path acceleration u.

// The acceleration limit curve: the largest x at which some u keeps every joint within its
// acceleration limit (pairwise condition of Kunz & Stilman, eq. 19).
double AccelerationLimitX(const JointVector& dq, const JointVector& ddq, const Limits& limits) {
  // Per joint once: its curvature ratio ddq/dq and its acceleration reach a/|dq|.
  std::array<double, kNumJoints> ratio{}, reach{};
  for (int i = 0; i < kNumJoints; ++i) {
    if (dq[i] == 0.0) continue;
    ratio[i] = ddq[i] / dq[i];
    reach[i] = limits.a[i] / std::abs(dq[i]);
  }
  double x = kInf;
  for (int i = 0; i < kNumJoints; ++i) {
    if (dq[i] == 0.0) {
      if (ddq[i] != 0.0) x = std::min(x, limits.a[i] / std::abs(ddq[i]));
      continue;
    }
    for (int j = i + 1; j < kNumJoints; ++j) {
      if (dq[j] == 0.0) continue;
      const double a_ij = std::abs(ratio[i] - ratio[j]);
      if (a_ij > 0.0) x = std::min(x, (reach[i] + reach[j]) / a_ij);
    }
  }
  return x;
}

// The velocity limit curve: the largest x within every joint's speed limit; *active is the
// joint that sets it.
double VelocityLimitX(const JointVector& dq, const JointVector& v_sq, int* active = nullptr) {
  double x = kInf;
  for (int i = 0; i < kNumJoints; ++i) {
    const double w = dq[i] * dq[i];
    if (w > 0.0 && v_sq[i] / w < x) {
      x = v_sq[i] / w;
      if (active) *active = i;
    }
  }
  return x;
}

double LimitX(const Segment& seg, double s, const Limits& limits) {
  if (!seg.is_arc) return seg.line_x;
  JointVector dq, ddq;
  Tangents(seg, s, &dq, &ddq);
  return std::min(AccelerationLimitX(dq, ddq, limits), VelocityLimitX(dq, seg.v_sq));
}

double AccelerationLimitXAt(const Segment& seg, double s, const Limits& limits) {
  if (!seg.is_arc) return kInf;
  JointVector dq, ddq;
  Tangents(seg, s, &dq, &ddq);
  return AccelerationLimitX(dq, ddq, limits);
}

// Angles on an arc where some joint's speed (kinks of the acceleration limit curve) or some
// joint's dq/ds (extrema of the velocity limit curve) is zero, in (0, angle).
std::vector<double> ArcCriticalAngles(const Segment& arc, bool speed_zeros, bool tangent_extrema) {
  std::vector<double> angles;
  for (int i = 0; i < kNumJoints; ++i) {
    if (arc.rho[i] == 0.0) continue;
    // dq_i = cos(th) d0_i + sin(th) n_i = 0; ddq_i = 0 where -sin(th) d0_i + cos(th) n_i = 0.
    for (int kind = 0; kind < 2; ++kind) {
      if ((kind == 0 && !speed_zeros) || (kind == 1 && !tangent_extrema)) continue;
      double theta = kind == 0 ? std::atan2(-arc.d0[i], arc.n[i]) : std::atan2(arc.n[i], arc.d0[i]);
      if (theta < 0.0) theta += kPi;
      if (theta > 0.0 && theta < arc.angle) angles.push_back(theta);
    }
  }
  std::sort(angles.begin(), angles.end());
  return angles;
}

// Smallest limit curve value over an arc: at its ends, the kinks of the acceleration limit
// curve (concave in between) and the minima of the velocity limit curve.
double MinLimitX(const Segment& arc, const Limits& limits) {
  double x = std::min(LimitX(arc, 0.0, limits), LimitX(arc, arc.length, limits));
  for (double theta : ArcCriticalAngles(arc, true, true)) {
    x = std::min(x, LimitX(arc, theta * arc.radius, limits));
  }
  return x;
}

using JointArray = Eigen::Array<double, kNumJoints, 1>;

// The limits at one end of a step as bounds on its path acceleration u: at that end
// x = x_known + k u, joint i accelerates at c_i u + d_i with c = dq + k ddq, d = ddq x_known,
// and its squared speed is x dq_i^2.
struct StepEnd {
  JointArray inv_c;
  JointArray d;
  JointArray inv_dq_sq;
  double x_known = 0.0;
  double k = 0.0;
};

StepEnd MakeStepEnd(const JointVector& dq, const JointVector& ddq, double x_known, double k) {
  StepEnd end;
  end.inv_c = (dq + k * ddq).array().inverse();
  end.d = ddq.array() * x_known;
  end.inv_dq_sq = dq.array().square().inverse();
  end.x_known = x_known;
  end.k = k;
  return end;
}

// Narrows [*lo, *hi] to the u within the acceleration limits a_max and squared speed limits
// v_sq_max at `end`, and with x >= 0 there; an empty result has lo > hi. A joint with c_i = 0
// gets inv_c_i = inf, which yields no bound if |d_i| <= a_max_i and an empty interval
// otherwise.
void NarrowBounds(const StepEnd& end, const JointArray& a_max, const JointArray& v_sq_max,
                  double* lo, double* hi) {
  if ((a_max < 0.0).any()) {
    *lo = kInf;
    *hi = -kInf;
    return;
  }
  const JointArray b1 = (-a_max - end.d) * end.inv_c;
  const JointArray b2 = (a_max - end.d) * end.inv_c;
  *lo = std::max(*lo, b1.min(b2).maxCoeff());
  *hi = std::min(*hi, b1.max(b2).minCoeff());
  const double x_max = (v_sq_max * end.inv_dq_sq).minCoeff();
  if (end.k == 0.0) {
    if (end.x_known > x_max) {
      *lo = kInf;
      *hi = -kInf;
    }
  } else if (end.k > 0.0) {
    *hi = std::min(*hi, (x_max - end.x_known) / end.k);
    *lo = std::max(*lo, -end.x_known / end.k);
  } else {
    *lo = std::max(*lo, (x_max - end.x_known) / end.k);
    *hi = std::min(*hi, -end.x_known / end.k);
  }
}

// The interval of path accelerations u at a point with derivatives dq, ddq and x = s_dot^2
// (acceleration limits only).
void PathAccelerationBounds(const JointVector& dq, const JointVector& ddq, double x,
                            const Limits& limits, double* lo, double* hi) {
  *lo = -kInf;
  *hi = kInf;
  const JointArray no_speed_limit = JointArray::Constant(kInf);
  NarrowBounds(MakeStepEnd(dq, ddq, x, 0.0), limits.a.array(), no_speed_limit, lo, hi);
}

// Stage 2b: the point speed bound. The factor (<= 1) on the squared joint speed limits of
// `seg` that keeps the point within options.max_point_speed at every sample: the smallest
// (bound / rate)^2 over the joint speed limit curve's x there.
double PointSpeedFactor(const Segment& seg, const TimeOptimalOptions& options) {
  const int n =
      std::max(2, static_cast<int>(std::ceil(seg.length / options.point_speed_step_rad)) + 1);
  double factor = 1.0;
  JointVector dq, ddq;
  for (int k = 0; k < n; ++k) {
    const double s = seg.length * k / (n - 1);
    Tangents(seg, s, &dq, &ddq);
    const double rate = options.point_speed_rate(Position(seg, s), dq);
    if (!std::isfinite(rate) || rate < 0.0) {
      throw std::invalid_argument(
          "TimeParametrizeTimeOptimal: point_speed_rate returned a negative or non-finite rate");
    }
    if (rate == 0.0) continue;
    const double x_point = (options.max_point_speed / rate) * (options.max_point_speed / rate);
    const double x_speed = seg.is_arc ? VelocityLimitX(dq, seg.v_sq) : seg.line_x;
    if (std::isfinite(x_speed)) factor = std::min(factor, x_point / x_speed);
  }
  return factor;
}

// Lowers each segment's speed limits by its PointSpeedFactor. A blend takes no higher factor
// than the segment after it, so that the speed limit curve never drops where a blend ends
// (where a line or blend begins, a drop is a switching point candidate like any junction).
void BoundPointSpeed(const TimeOptimalOptions& options, Path* path) {
  for (std::vector<Segment>& piece : path->pieces) {
    std::vector<double> factor(piece.size());
    for (std::size_t k = 0; k < piece.size(); ++k) factor[k] = PointSpeedFactor(piece[k], options);
    for (std::size_t k = piece.size(); k-- > 1;) {
      if (piece[k - 1].is_arc) factor[k - 1] = std::min(factor[k - 1], factor[k]);
    }
    for (std::size_t k = 0; k < piece.size(); ++k) {
      if (piece[k].is_arc) {
        piece[k].v_sq *= factor[k];
      } else {
        piece[k].line_x *= factor[k];
      }
    }
  }
}

// ---------------------------------------------------------------------------------------
// Stages 3 and 4: switching points and integration, per rest-to-rest piece.

// A piece of constant path acceleration u on segment `seg` from local position s0 (x0) to s1
// (x1), x1 = x0 + 2 u (s1 - s0).
struct Interval {
  int seg = 0;
  double s0 = 0.0, s1 = 0.0;
  double x0 = 0.0, x1 = 0.0;
  double u = 0.0;
};

double ValueAt(const Interval& iv, double s) { return iv.x0 + 2.0 * iv.u * (s - iv.s0); }

struct PathPos {
  int seg = 0;
  double s = 0.0;
};

bool Before(const PathPos& a, const PathPos& b) {
  return a.seg < b.seg || (a.seg == b.seg && a.s < b.s);
}

class PhasePlane final {
 public:
  PhasePlane(const std::vector<Segment>& segments, const Limits& exact, const Limits& blend,
             double step_s);
  // The time-optimal profile from rest at the start to rest at the end.
  std::vector<Interval> Solve();
  int num_switching_points() const { return num_switching_points_; }

 private:
  // Stage 3.
  void CollectCandidates();
  bool NextSwitchingPoint(const PathPos& after, double x_after, PathPos* pos, double* x);
  double SwitchingPointX(const PathPos& pos) const;
  bool NextVelocitySwitchingPoint(const PathPos& from, const PathPos& to, PathPos* found) const;
  bool FollowInfeasible(const Segment& seg, double s) const;
  // Stage 4.
  double StepLength(const Segment& seg, double x) const;
  double ForwardFar(const Segment& seg, double s, double x) const;
  double BackwardFar(const Segment& seg, double s, double x) const;
  bool StepFeasible(int seg, double s, double x, bool forward) const;
  // The step length fraction and path acceleration of the previous step of an integration.
  struct StepState {
    double fraction = 1.0;
    double u = std::numeric_limits<double>::quiet_NaN();
  };
  bool ArcStep(const Segment& seg, double s_known, double x_known, double s_far, bool forward,
               double u_hint, double* u) const;
  bool ArcStepAdaptive(const Segment& seg, double s, double x, bool forward, StepState* state,
                       double* far) const;
  void TangentsAt(const Segment& seg, double s, JointVector* dq, JointVector* ddq) const;
  bool IntegrateForward();
  void ForwardOnLine(int seg, double s, double x);
  void IntegrateBackwardFrom(const PathPos& pos, double x);
  bool IntegrateBackward(const PathPos& pos, double x, bool commit);
  bool BackwardStep(const PathPos& cur, double x, StepState* state, Interval* iv) const;
  void Splice(int j, double s_cross, Interval iv, const std::vector<Interval>& back);
  PathPos EndPos() const;
  double EndX() const { return profile_.empty() ? 0.0 : profile_.back().x1; }
  void Push(int seg, double s0, double s1, double x0, double u, double x1);

  const std::vector<Segment>& segs_;
  const Limits& exact_;
  const Limits& blend_;
  double step_s_;
  double accel_scale_;
  std::vector<Interval> profile_;
  std::vector<PathPos> candidates_;  // junctions and minima of the acceleration limit curve
  std::size_t next_candidate_ = 0;
  int num_switching_points_ = 0;
  // The last few path derivatives evaluated (steps and bisections revisit the same points).
  struct CachedTangents {
    const Segment* seg = nullptr;
    double s = 0.0;
    JointVector dq, ddq;
  };
  mutable std::array<CachedTangents, 4> tangent_cache_;
  mutable std::size_t tangent_next_ = 0;
};

PhasePlane::PhasePlane(const std::vector<Segment>& segments, const Limits& exact,
                       const Limits& blend, double step_s)
    : segs_(segments),
      exact_(exact),
      blend_(blend),
      step_s_(step_s),
      accel_scale_(exact.a.maxCoeff()) {
  CollectCandidates();
}

// Stage 3: the acceleration switching point candidates of Kunz & Stilman: every segment
// junction (the curvature jumps there), and on blends the points where a joint's speed is
// zero and the acceleration limit curve has a local minimum (it is concave in between).
void PhasePlane::CollectCandidates() {
  for (int k = 0; k < static_cast<int>(segs_.size()); ++k) {
    const Segment& seg = segs_[k];
    if (k > 0) candidates_.push_back({k, 0.0});
    if (!seg.is_arc) continue;
    for (double theta : ArcCriticalAngles(seg, true, false)) {
      const double s = theta * seg.radius;
      const double eps = 1e-6 * seg.radius;
      if (s - eps <= 0.0 || s + eps >= seg.length) continue;
      const double x = AccelerationLimitXAt(seg, s, blend_);
      JointVector dq, ddq;
      Tangents(seg, s, &dq, &ddq);
      if (AccelerationLimitXAt(seg, s - eps, blend_) > x &&
          AccelerationLimitXAt(seg, s + eps, blend_) > x && x <= VelocityLimitX(dq, seg.v_sq)) {
        candidates_.push_back({k, s});
      }
    }
  }
}

void PhasePlane::TangentsAt(const Segment& seg, double s, JointVector* dq, JointVector* ddq) const {
  for (const CachedTangents& c : tangent_cache_) {
    if (c.seg == &seg && c.s == s) {
      *dq = c.dq;
      *ddq = c.ddq;
      return;
    }
  }
  CachedTangents& c = tangent_cache_[tangent_next_];
  tangent_next_ = (tangent_next_ + 1) % tangent_cache_.size();
  Tangents(seg, s, &c.dq, &c.ddq);
  c.seg = &seg;
  c.s = s;
  *dq = c.dq;
  *ddq = c.ddq;
}

// One step of constant path acceleration on an arc between local positions s_known (where
// x = x_known) and s_far. *u is the largest feasible u (forward) or the smallest (backward).
// Feasible means within the limits everywhere in the step, not just at its ends: a function f
// of s deviates from its chord between the ends by at most F h^2 lambda (1 - lambda) / 2,
// F = max |f''|, lambda the fraction of the step. On the arc |d^k q_i / ds^k| <= rho_i / r^(k-1),
// so the joint acceleration g = dq u + ddq x has |g''| <= rho (5|u| / r^2 + x / r^3): the ends
// keep F h^2 / 8 from the acceleration limits. The squared joint speed w = x dq^2 has
// |w''| <= rho^2 (8|u| / r + 4x / r^2) =: W, and stays below v^2 iff the slacks e of the ends
// satisfy sqrt(e_known) + sqrt(e_far) >= sqrt(W h^2 / 2): the slack the known end has is used,
// so that following the velocity limit curve does not force shorter and shorter steps.
bool PhasePlane::ArcStep(const Segment& seg, double s_known, double x_known, double s_far,
                         bool forward, double u_hint, double* u) const {
  const double h = std::abs(s_far - s_known);
  if (!(h > 0.0)) return false;
  const double k = forward ? 2.0 * h : -2.0 * h;
  JointVector dq, ddq;
  TangentsAt(seg, s_known, &dq, &ddq);
  const StepEnd known = MakeStepEnd(dq, ddq, x_known, 0.0);
  const JointArray slack_known_v = seg.v_sq.array() - x_known * dq.array().square();
  TangentsAt(seg, s_far, &dq, &ddq);
  const StepEnd far = MakeStepEnd(dq, ddq, x_known, k);
  const JointArray a = blend_.a.array();
  const JointArray v_sq = seg.v_sq.array();
  double lo = -kInf, hi = kInf;
  // The margins depend on |u| and the largest x of the step: bound both from the previous
  // step's u or else from the step without margins, and widen the bounds if the step with
  // margins exceeds them.
  double u_step = u_hint;
  if (!std::isfinite(u_hint)) {
    NarrowBounds(known, a, v_sq, &lo, &hi);
    NarrowBounds(far, a, v_sq, &lo, &hi);
    if (!(lo <= hi) || !std::isfinite(forward ? hi : lo)) return false;
    u_step = forward ? hi : lo;
  }
  const double hr_sq = (h / seg.radius) * (h / seg.radius);
  const JointArray rho = seg.rho.array();
  const JointArray sqrt_slack_known = slack_known_v.max(0.0).sqrt();
  for (int attempt = 0; attempt < 4; ++attempt) {
    const double u_bound = 1.25 * std::abs(u_step) + 1e-9;
    const double x_bound = 1.25 * std::max(x_known, x_known + k * u_step) + 1e-12;
    const JointArray a_max = a - rho * ((5.0 * u_bound + x_bound / seg.radius) * hr_sq / 8.0);
    const JointArray bulge_v =
        rho.square() * ((4.0 * u_bound * seg.radius + 2.0 * x_bound) * hr_sq);
    const JointArray v_sq_far = v_sq - (bulge_v.sqrt() - sqrt_slack_known).max(0.0).square();
    lo = -kInf;
    hi = kInf;
    NarrowBounds(known, a_max, v_sq, &lo, &hi);
    NarrowBounds(far, a_max, v_sq_far, &lo, &hi);
    if (!(lo <= hi)) {
      // Margins from a hint may be too wide: retry from the step without margins.
      if (attempt == 0 && std::isfinite(u_hint))
        return ArcStep(seg, s_known, x_known, s_far, forward, kNaN, u);
      return false;
    }
    u_step = forward ? hi : lo;
    if (!std::isfinite(u_step)) return false;
    if (std::abs(u_step) <= u_bound && x_known + k * u_step <= x_bound) {
      *u = u_step;
      return true;
    }
  }
  return false;
}

double PhasePlane::StepLength(const Segment& seg, double x) const {
  const double h = std::sqrt(x) * step_s_ + 0.5 * accel_scale_ * step_s_ * step_s_;
  return std::min(h, kBlendStepPerRadius * seg.radius);
}

double PhasePlane::ForwardFar(const Segment& seg, double s, double x) const {
  const double h = StepLength(seg, x);
  return seg.length - s <= 1.5 * h ? seg.length : s + h;
}

double PhasePlane::BackwardFar(const Segment& seg, double s, double x) const {
  const double h = StepLength(seg, x);
  return s <= 1.5 * h ? 0.0 : s - h;
}

// A step from (s, x) of *fraction of the regular step, halved until it is feasible and
// doubled again after each success: near a limit curve the halving locates where the curve is
// met, to kMinStepFraction of a step. False if not even that short a step is feasible.
bool PhasePlane::ArcStepAdaptive(const Segment& seg, double s, double x, bool forward,
                                 StepState* state, double* far) const {
  const double full = forward ? ForwardFar(seg, s, x) : BackwardFar(seg, s, x);
  while (state->fraction >= kMinStepFraction) {
    *far = state->fraction >= 1.0 ? full : s + state->fraction * (full - s);
    if (ArcStep(seg, s, x, *far, forward, state->u, &state->u)) {
      state->fraction = std::min(1.0, 2.0 * state->fraction);
      return true;
    }
    state->fraction *= 0.5;
  }
  return false;
}

// Whether a first step forward (backward) from (s, x) on segment `seg` is feasible.
bool PhasePlane::StepFeasible(int seg_index, double s, double x, bool forward) const {
  const Segment& seg = segs_[seg_index];
  if (!seg.is_arc) return x <= seg.line_x;
  double u;
  const double full = forward ? ForwardFar(seg, s, x) : BackwardFar(seg, s, x);
  return ArcStep(seg, s, x, s + kProbeStepFraction * (full - s), forward, kNaN, &u);
}

// The largest x at a switching point candidate from which both a forward step (on the
// segment after it) and a backward step (on the segment before it) are feasible, by bisection
// below the limit curves. Where Kunz & Stilman's slope test would reject the candidate this
// gives a lower point, which the later switching points then cut away if it is not binding.
double PhasePlane::SwitchingPointX(const PathPos& pos) const {
  const bool junction = pos.s == 0.0 && pos.seg > 0;
  const int left = junction ? pos.seg - 1 : pos.seg;
  const double s_left = junction ? segs_[left].length : pos.s;
  const double x_upper =
      std::min(LimitX(segs_[left], s_left, blend_), LimitX(segs_[pos.seg], pos.s, blend_));
  auto feasible = [&](double x) {
    return StepFeasible(pos.seg, pos.s, x, true) && StepFeasible(left, s_left, x, false);
  };
  if (feasible(x_upper)) return x_upper;
  double lo = 0.0, hi = x_upper;
  for (const double gap : {1e-6, 1e-4, 1e-2, 0.1, 0.5}) {
    const double x = x_upper * (1.0 - gap);
    if (feasible(x)) {
      lo = x;
      break;
    }
    hi = x;
  }
  for (int it = 0; it < 16; ++it) {
    const double mid = 0.5 * (lo + hi);
    (feasible(mid) ? lo : hi) = mid;
  }
  return lo;
}

// Whether the velocity limit curve falls faster than the largest deceleration can follow at s
// (the phase slope of maximal deceleration is above the curve's slope).
bool PhasePlane::FollowInfeasible(const Segment& seg, double s) const {
  JointVector dq, ddq;
  Tangents(seg, s, &dq, &ddq);
  int i = 0;
  const double x = VelocityLimitX(dq, seg.v_sq, &i);
  // Following x = v_i^2 / dq_i^2 needs u = x' / 2 = -v_i^2 ddq_i / dq_i^3.
  const double u_follow = -seg.v_sq[i] * ddq[i] / (dq[i] * dq[i] * dq[i]);
  double lo, hi;
  PathAccelerationBounds(dq, ddq, x, blend_, &lo, &hi);
  return u_follow < lo;
}

// Stage 3: the first point in [from, to) on a blend where the velocity limit curve becomes
// followable again after a stretch where it is not (Kunz & Stilman's velocity switching
// point): a scan at kBlendStepPerRadius of the radius, then bisection.
bool PhasePlane::NextVelocitySwitchingPoint(const PathPos& from, const PathPos& to,
                                            PathPos* found) const {
  for (int k = from.seg; k <= to.seg && k < static_cast<int>(segs_.size()); ++k) {
    const Segment& seg = segs_[k];
    if (!seg.is_arc) continue;
    const double a = k == from.seg ? from.s : 0.0;
    const double b = k == to.seg ? to.s : seg.length;
    if (!(a < b)) continue;
    const int n = static_cast<int>(std::ceil((b - a) / (kBlendStepPerRadius * seg.radius)));
    double s_prev = a;
    bool infeasible_prev = FollowInfeasible(seg, a);
    for (int i = 1; i <= n; ++i) {
      const double s = i == n ? b : a + (b - a) * i / n;
      const bool infeasible = FollowInfeasible(seg, s);
      if (infeasible_prev && !infeasible) {
        double lo = s_prev, hi = s;
        for (int it = 0; it < 60 && hi - lo > 1e-12 * seg.radius; ++it) {
          const double mid = 0.5 * (lo + hi);
          (FollowInfeasible(seg, mid) ? lo : hi) = mid;
        }
        JointVector dq, ddq;
        Tangents(seg, hi, &dq, &ddq);
        if (VelocityLimitX(dq, seg.v_sq) <= AccelerationLimitX(dq, ddq, blend_)) {
          *found = {k, hi};
          return true;
        }
      }
      infeasible_prev = infeasible;
      s_prev = s;
    }
  }
  return false;
}

// Stage 3: the next switching point at or after the point where forward integration stopped
// (acceleration candidates and velocity switching points, whichever comes first).
bool PhasePlane::NextSwitchingPoint(const PathPos& after, double x_after, PathPos* pos, double* x) {
  while (next_candidate_ < candidates_.size() && Before(candidates_[next_candidate_], after)) {
    ++next_candidate_;
  }
  PathPos to{static_cast<int>(segs_.size()) - 1, segs_.back().length};
  double x_acc = 0.0;
  bool have_acc = false;
  for (std::size_t i = next_candidate_; i < candidates_.size(); ++i) {
    const PathPos& c = candidates_[i];
    const double xc = SwitchingPointX(c);
    if (!Before(after, c) && xc >= x_after) continue;  // at the stop point, not below it
    to = c;
    x_acc = xc;
    have_acc = true;
    break;
  }
  PathPos velocity;
  if (NextVelocitySwitchingPoint(after, to, &velocity)) {
    *pos = velocity;
    *x = SwitchingPointX(velocity);
    return true;
  }
  if (!have_acc) return false;
  *pos = to;
  *x = x_acc;
  return true;
}

PathPos PhasePlane::EndPos() const {
  if (profile_.empty()) return {0, 0.0};
  const Interval& last = profile_.back();
  if (last.s1 >= segs_[last.seg].length && last.seg + 1 < static_cast<int>(segs_.size())) {
    return {last.seg + 1, 0.0};
  }
  return {last.seg, last.s1};
}

void PhasePlane::Push(int seg, double s0, double s1, double x0, double u, double x1) {
  profile_.push_back({seg, s0, s1, x0, std::max(0.0, x1), u});
}

// Stage 4: forward integration on a line in closed form: the largest path acceleration up to
// the velocity limit, then the limit.
void PhasePlane::ForwardOnLine(int k, double s, double x) {
  const Segment& seg = segs_[k];
  const double a = seg.line_accel;
  const double x_max = seg.line_x;
  if (x < x_max) {
    const double s_reach = s + (x_max - x) / (2.0 * a);
    if (s_reach < seg.length) {
      Push(k, s, s_reach, x, a, x_max);
      Push(k, s_reach, seg.length, x_max, 0.0, x_max);
    } else {
      Push(k, s, seg.length, x, a, std::min(x_max, x + 2.0 * a * (seg.length - s)));
    }
  } else {
    Push(k, s, seg.length, x_max, 0.0, x_max);
  }
}

// Stage 4: forward integration at the largest path acceleration from the end of the profile.
// True if it reached the end of the piece; false where it meets a limit curve (located by
// bisection of the step length).
bool PhasePlane::IntegrateForward() {
  PathPos p = EndPos();
  double x = EndX();
  StepState state;
  const int n = static_cast<int>(segs_.size());
  while (true) {
    const Segment& seg = segs_[p.seg];
    if (p.s >= seg.length) {
      if (p.seg + 1 >= n) return true;
      p = {p.seg + 1, 0.0};
      continue;
    }
    if (!seg.is_arc) {
      if (x > seg.line_x) {
        if (x > seg.line_x * (1.0 + 1e-9)) return false;
        x = seg.line_x;
        if (!profile_.empty()) profile_.back().x1 = x;
      }
      ForwardOnLine(p.seg, p.s, x);
      p.s = seg.length;
      x = profile_.back().x1;
      continue;
    }
    double far;
    if (!ArcStepAdaptive(seg, p.s, x, true, &state, &far)) return false;
    Push(p.seg, p.s, far, x, state.u, x + 2.0 * state.u * (far - p.s));
    p.s = far;
    x = profile_.back().x1;
  }
}

// One backward interval ending at (cur, x) on cur.seg: closed form on a line, one step of the
// largest deceleration on an arc. False if the step meets a limit curve.
bool PhasePlane::BackwardStep(const PathPos& cur, double x, StepState* state, Interval* iv) const {
  const Segment& seg = segs_[cur.seg];
  if (!seg.is_arc) {
    const double a = seg.line_accel;
    const double x_max = seg.line_x;
    if (x >= x_max) {
      *iv = {cur.seg, 0.0, cur.s, x_max, x_max, 0.0};
    } else {
      const double s_reach = cur.s - (x_max - x) / (2.0 * a);
      *iv = s_reach > 0.0
                ? Interval{cur.seg, s_reach, cur.s, x_max, x, -a}
                : Interval{cur.seg, 0.0, cur.s, std::min(x_max, x + 2.0 * a * cur.s), x, -a};
    }
    return true;
  }
  double far;
  if (!ArcStepAdaptive(seg, cur.s, x, false, state, &far)) return false;
  *iv = {cur.seg, far, cur.s, std::max(0.0, x - 2.0 * state->u * (cur.s - far)), x, state->u};
  return true;
}

// Backward integration from the switching point (pos, x); if it meets a limit curve before
// the forward profile, the switching point is too high (Kunz & Stilman's validity test fails
// there, or a switching point between it and the profile was passed over by the discrete
// forward integration): it is lowered, by bisection, to the highest point whose backward
// curve reaches the profile.
void PhasePlane::IntegrateBackwardFrom(const PathPos& pos, double x) {
  if (IntegrateBackward(pos, x, true)) return;
  double lo = 0.0, hi = x;
  for (int it = 0; it < 50 && hi - lo > 1e-10 * x; ++it) {
    const double mid = 0.5 * (lo + hi);
    (IntegrateBackward(pos, mid, false) ? lo : hi) = mid;
  }
  if (!IntegrateBackward(pos, lo, true)) {
    throw std::logic_error("TimeParametrizeTimeOptimal: backward integration met a limit curve");
  }
}

// Stage 4: backward integration at the largest deceleration from the switching point (pos, x)
// until it meets the forward profile; if `commit`, the profile is cut there and continued by
// it. False if it meets a limit curve first.
bool PhasePlane::IntegrateBackward(const PathPos& pos, double x, bool commit) {
  std::vector<Interval> back;  // right to left
  // The end of the forward profile, as a point of the last interval's segment and (at a
  // junction) of the next one.
  const PathPos f_end = EndPos();
  const PathPos f_end_raw =
      profile_.empty() ? f_end : PathPos{profile_.back().seg, profile_.back().s1};
  const double x_f_end = EndX();
  int j = static_cast<int>(profile_.size()) - 1;
  bool end_checked = false;
  StepState state;
  PathPos cur = pos;
  double x_cur = x;
  while (true) {
    if (cur.s <= 0.0) {
      if (cur.seg == 0) break;
      cur = {cur.seg - 1, segs_[cur.seg - 1].length};
    }
    Interval iv;
    if (!BackwardStep(cur, x_cur, &state, &iv)) return false;
    for (const PathPos& e : {f_end, f_end_raw}) {
      if (end_checked || e.seg != iv.seg || e.s < iv.s0 || e.s > iv.s1) continue;
      end_checked = true;
      // Passing above the end of the forward profile (where that met a limit curve): the
      // switching point is too high.
      if (ValueAt(iv, e.s) > x_f_end) return false;
    }
    for (; j >= 0; --j) {
      const Interval& f = profile_[j];
      if (f.seg > iv.seg || (f.seg == iv.seg && f.s0 > iv.s1)) continue;
      if (f.seg < iv.seg) break;
      const double l = std::max(f.s0, iv.s0);
      const double r = std::min(f.s1, iv.s1);
      if (l <= r) {
        const double d_l = ValueAt(iv, l) - ValueAt(f, l);
        const double d_r = ValueAt(iv, r) - ValueAt(f, r);
        if (d_l >= 0.0 && d_r <= 0.0) {
          const double s_cross = d_r < d_l ? r - (r - l) * d_r / (d_r - d_l) : r;
          if (commit) Splice(j, std::clamp(s_cross, l, r), iv, back);
          return true;
        }
      }
      if (f.s0 < iv.s0) break;
    }
    back.push_back(iv);
    cur = {iv.seg, iv.s0};
    x_cur = iv.x0;
  }
  return false;  // reached the start of the piece without meeting the profile
}

void PhasePlane::Splice(int j, double s_cross, Interval iv, const std::vector<Interval>& back) {
  Interval& f = profile_[j];
  const double x_cross = std::min(ValueAt(f, s_cross), ValueAt(iv, s_cross));
  f.s1 = s_cross;
  f.x1 = std::max(0.0, x_cross);
  profile_.resize(j + 1);
  iv.s0 = s_cross;
  iv.x0 = std::max(0.0, x_cross);
  profile_.push_back(iv);
  profile_.insert(profile_.end(), back.rbegin(), back.rend());
}

// Stages 3 and 4 together, as in Kunz & Stilman's reference implementation: integrate forward
// until a limit curve, find the next switching point, integrate backward from it to the
// profile, continue forward from it; finally integrate backward from the end at rest.
std::vector<Interval> PhasePlane::Solve() {
  profile_.clear();
  while (!IntegrateForward()) {
    PathPos pos;
    double x;
    if (!NextSwitchingPoint(EndPos(), EndX(), &pos, &x)) break;
    ++num_switching_points_;
    IntegrateBackwardFrom(pos, x);
  }
  if (!IntegrateBackward({static_cast<int>(segs_.size()) - 1, segs_.back().length}, 0.0, true)) {
    throw std::logic_error("TimeParametrizeTimeOptimal: backward integration from the end failed");
  }
  std::vector<Interval> profile;
  profile.reserve(profile_.size());
  for (const Interval& iv : profile_) {
    if (iv.s1 > iv.s0) profile.push_back(iv);
  }
  // A broken invariant is a bug: check every interval at its ends (no margins).
  for (const Interval& iv : profile) {
    const Segment& seg = segs_[iv.seg];
    for (const auto& [s, x] : {std::pair{iv.s0, iv.x0}, std::pair{iv.s1, iv.x1}}) {
      JointVector dq, ddq;
      Tangents(seg, s, &dq, &ddq);
      for (int i = 0; i < kNumJoints; ++i) {
        const double tol = 1.0 + 1e-9;
        if (std::abs(dq[i] * iv.u + ddq[i] * x) > exact_.a[i] * tol ||
            x * dq[i] * dq[i] > exact_.v_sq[i] * tol || !std::isfinite(x)) {
          throw std::logic_error("TimeParametrizeTimeOptimal: profile exceeds the limits");
        }
      }
    }
  }
  return profile;
}

// ---------------------------------------------------------------------------------------
// Stage 5: sampling.

struct TimedInterval {
  const Segment* seg = nullptr;
  Interval iv;
  double t0 = 0.0;   // start time, s
  double t1 = 0.0;   // end time, s
  double sd0 = 0.0;  // s_dot at s0
};

std::vector<TimedInterval> Timing(const Path& path,
                                  const std::vector<std::vector<Interval>>& profiles) {
  std::vector<TimedInterval> timed;
  double t = 0.0;
  for (std::size_t p = 0; p < profiles.size(); ++p) {
    for (const Interval& iv : profiles[p]) {
      const double sd0 = std::sqrt(iv.x0);
      const double dt = 2.0 * (iv.s1 - iv.s0) / (sd0 + std::sqrt(iv.x1));
      if (!std::isfinite(dt)) {
        throw std::logic_error("TimeParametrizeTimeOptimal: interval at rest at both ends");
      }
      timed.push_back({&path.pieces[p][iv.seg], iv, t, t + dt, sd0});
      t = timed.back().t1;
    }
  }
  return timed;
}

// The sample at time_s within `ti`, appended to `samples`: built in place from its values
// (no default values written first) and, on an arc, with one sine and cosine; the sampling
// of a long trajectory is bound by writing its samples.
void AppendSample(const TimedInterval& ti, double time_s, std::vector<TrajectorySample>* samples) {
  const double tau = std::clamp(time_s - ti.t0, 0.0, ti.t1 - ti.t0);
  const Interval& iv = ti.iv;
  const Segment& seg = *ti.seg;
  const double s = std::clamp(iv.s0 + ti.sd0 * tau + 0.5 * iv.u * tau * tau, iv.s0, iv.s1);
  const double sd = std::max(0.0, ti.sd0 + iv.u * tau);
  if (!seg.is_arc) {
    samples->push_back({time_s, seg.p0 + s * seg.d0, seg.d0 * sd, seg.d0 * iv.u});
    return;
  }
  const double theta = s / seg.radius;
  const double c = std::cos(theta);
  const double sn = std::sin(theta);
  // 1 - cos(theta) without cancellation for small angles (huge radii, shallow corners).
  const double one_minus_c = c > 0.0 ? sn * sn / (1.0 + c) : 1.0 - c;
  const JointVector dq = c * seg.d0 + sn * seg.n;
  const JointVector ddq = (c * seg.n - sn * seg.d0) / seg.radius;
  samples->push_back({time_s,
                      seg.p0 + (seg.radius * sn) * seg.d0 + (seg.radius * one_minus_c) * seg.n,
                      dq * sd, dq * iv.u + ddq * (sd * sd)});
}

std::vector<TrajectorySample> Sample(const std::vector<TimedInterval>& timed, double period_s,
                                     const JointVector& q_end) {
  std::vector<TrajectorySample> samples;
  const double duration = timed.back().t1;
  if (duration / period_s > kMaxSamples) {
    throw std::invalid_argument("TimeParametrizeTimeOptimal: the trajectory takes " +
                                std::to_string(duration) + " s, more than " +
                                std::to_string(static_cast<long>(kMaxSamples)) +
                                " samples at sample_period_s = " + std::to_string(period_s) +
                                " s; sample it less often or split the path");
  }
  samples.reserve(static_cast<std::size_t>(duration / period_s) + 2);
  std::size_t i = 0;
  for (long k = 0;; ++k) {
    const double t = k * period_s;
    if (k > 0 && t > duration - kEndSampleMinGap * period_s) break;
    while (i + 1 < timed.size() && t >= timed[i].t1) ++i;
    AppendSample(timed[i], t, &samples);
  }
  AppendSample(timed.back(), duration, &samples);
  samples.back().q_rad = q_end;
  samples.back().qd_rad_s.setZero();
  return samples;
}

TimeOptimalResult Parametrize(const std::vector<JointVector>& corners, const JointVector& q_end,
                              const TimeOptimalOptions& options, double max_deviation) {
  const Limits exact = MakeLimits(options, 1.0);
  const Limits blend = MakeLimits(options, 1.0 - kBlendSlack);
  Path path = BuildPath(corners, max_deviation, exact, blend);
  if (options.point_speed_rate) BoundPointSpeed(options, &path);
  TimeOptimalResult result;
  result.num_blends = path.num_blends;
  result.num_stops = path.num_stops;
  result.max_blend_deviation_rad = path.max_blend_deviation_rad;
  std::vector<std::vector<Interval>> profiles;
  for (const auto& piece : path.pieces) {
    PhasePlane plane(piece, exact, blend, options.integration_step_s);
    profiles.push_back(plane.Solve());
    result.num_switching_points += plane.num_switching_points();
    result.num_phase_plane_intervals += static_cast<int>(profiles.back().size());
  }
  const std::vector<TimedInterval> timed = Timing(path, profiles);
  result.samples = Sample(timed, options.sample_period_s, q_end);
  result.duration_s = timed.back().t1;
  return result;
}

double PointSegmentDistance(const JointVector& p, const JointVector& a, const JointVector& b) {
  const JointVector ab = b - a;
  const double len_sq = ab.squaredNorm();
  const double t = len_sq > 0.0 ? std::clamp((p - a).dot(ab) / len_sq, 0.0, 1.0) : 0.0;
  return (p - (a + t * ab)).norm();
}

}  // namespace

TimeOptimalResult TimeParametrizeTimeOptimal(const std::vector<JointVector>& waypoints_rad,
                                             const TimeOptimalOptions& options) {
  Validate(waypoints_rad, options);
  const std::vector<JointVector> corners = Corners(waypoints_rad);
  if (corners.size() == 1) {
    TimeOptimalResult result;
    TrajectorySample only;
    only.q_rad = waypoints_rad.back();
    result.samples.push_back(only);
    return result;
  }
  TimeOptimalResult result =
      Parametrize(corners, waypoints_rad.back(), options, options.max_deviation_rad);
  // Stopping at every corner can beat blends that must be passed slowly.
  if (result.num_blends > 0 &&
      result.duration_s > StopEverywhereDuration(corners, MakeLimits(options, 1.0), options)) {
    result = Parametrize(corners, waypoints_rad.back(), options, 0.0);
  }
  return result;
}

double MaxDistanceFromPolyline(const std::vector<TrajectorySample>& samples,
                               const std::vector<JointVector>& waypoints_rad) {
  if (samples.empty() || waypoints_rad.empty()) return 0.0;
  // Exact, with pruning: the distance to a segment changes by at most the distance the sample
  // moved since it was last computed, so a segment is only measured again once that bound
  // could beat the nearest one so far.
  const std::size_t m = std::max<std::size_t>(1, waypoints_rad.size() - 1);
  auto distance = [&](const JointVector& q, std::size_t j) {
    return waypoints_rad.size() == 1
               ? (q - waypoints_rad[0]).norm()
               : PointSegmentDistance(q, waypoints_rad[j], waypoints_rad[j + 1]);
  };
  std::vector<double> known(m, 0.0), travel_then(m, -kInf);
  double travel = 0.0, worst = 0.0;
  std::size_t nearest = 0;
  for (std::size_t k = 0; k < samples.size(); ++k) {
    if (k > 0) travel += (samples[k].q_rad - samples[k - 1].q_rad).norm();
    double best = distance(samples[k].q_rad, nearest);
    known[nearest] = best;
    travel_then[nearest] = travel;
    for (std::size_t j = 0; j < m; ++j) {
      if (j == nearest || known[j] - (travel - travel_then[j]) >= best) continue;
      known[j] = distance(samples[k].q_rad, j);
      travel_then[j] = travel;
      if (known[j] < best) {
        best = known[j];
        nearest = j;
      }
    }
    worst = std::max(worst, best);
  }
  return worst;
}

std::vector<int> PolylineSegmentOfSamples(const std::vector<TrajectorySample>& samples,
                                          const std::vector<JointVector>& waypoints_rad,
                                          double tolerance_rad) {
  std::vector<int> segment(samples.size(), -1);
  if (waypoints_rad.size() < 2) return segment;
  // How many segments past the last one found a sample may lie: the blends at the corners
  // between may swallow short segments whole.
  constexpr std::size_t kLookAhead = 8;
  const std::size_t m = waypoints_rad.size() - 1;
  std::size_t last = 0;
  for (std::size_t k = 0; k < samples.size(); ++k) {
    for (std::size_t j = last; j < std::min(m, last + kLookAhead); ++j) {
      if (PointSegmentDistance(samples[k].q_rad, waypoints_rad[j], waypoints_rad[j + 1]) <=
          tolerance_rad) {
        segment[k] = static_cast<int>(j);
        last = j;
        break;
      }
    }
  }
  return segment;
}

}  // namespace picking::planner
