#include "services/planner/core/time_optimal.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "libs/ur10/kinematics.h"
#include "libs/ur10/ur10_model.h"
#include "services/robot/core/trajectory.h"

namespace picking::planner {
namespace {

const ur10::Ur10Model& Model() {
  static const ur10::Ur10Model model =
      ur10::Ur10Model::Load(std::string(PICKING_DATA_DIR) + "/ur10");
  return model;
}

// The real UR10 limits: 2.09, 2.09, 3.14, 3.14, 3.14, 3.14 rad/s and 2.5 rad/s^2.
TimeOptimalOptions Ur10Options(double max_deviation_rad = 0.01, double period_s = 0.001) {
  TimeOptimalOptions options;
  options.max_velocity_rad_s = Model().max_velocity_rad_s();
  options.max_acceleration_rad_s2 = Model().max_acceleration_rad_s2();
  options.max_deviation_rad = max_deviation_rad;
  options.sample_period_s = period_s;
  return options;
}

TEST(TimeOptimalTest, Ur10LimitsAreTheRealOnes) {
  const JointVector v = Ur10Options().max_velocity_rad_s;
  const JointVector a = Ur10Options().max_acceleration_rad_s2;
  for (int j = 0; j < 6; ++j) {
    EXPECT_NEAR(v[j], j < 2 ? 2.0944 : 3.1416, 1e-3) << j;
    EXPECT_DOUBLE_EQ(a[j], 2.5) << j;
  }
}

double RobotDuration(const std::vector<JointVector>& waypoints, const TimeOptimalOptions& o) {
  robot::TimeParametrizationOptions options;
  options.max_velocity_rad_s = o.max_velocity_rad_s;
  options.max_acceleration_rad_s2 = o.max_acceleration_rad_s2;
  options.sample_rate_hz = 1.0 / o.sample_period_s;
  return robot::TimeParametrizePath(waypoints, options).duration_s();
}

// Rest-to-rest time of a straight move within the limits: a trapezoid (or triangle) of the
// path parameter, limited by the joint with the tightest limit relative to its displacement.
double TrapezoidDuration(const JointVector& delta, const TimeOptimalOptions& o) {
  double v = std::numeric_limits<double>::infinity(), a = v;
  for (int j = 0; j < 6; ++j) {
    if (delta[j] == 0.0) continue;
    v = std::min(v, o.max_velocity_rad_s[j] / std::abs(delta[j]));
    a = std::min(a, o.max_acceleration_rad_s2[j] / std::abs(delta[j]));
  }
  return v * v >= a ? 2.0 / std::sqrt(a) : v / a + 1.0 / v;
}

double PointSegmentDistance(const JointVector& p, const JointVector& a, const JointVector& b) {
  const JointVector ab = b - a;
  const double t =
      ab.squaredNorm() > 0.0 ? std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0) : 0.0;
  return (p - (a + t * ab)).norm();
}

// Every property the planner relies on. Tolerances: 1e-9 relative on the limits, plus for
// the finite differences what rounding of the samples costs: a position is exact to a few
// ulp of |q| and of v_max * t (the sample time's own rounding, t = k * period), so a first
// difference over h is off by up to 2 eps_q / h and a second difference by 4 eps_q / (h0 h1).
void ExpectValid(const std::vector<JointVector>& waypoints, const TimeOptimalOptions& o,
                 const TimeOptimalResult& r, const std::string& what) {
  SCOPED_TRACE(what);
  ASSERT_TRUE(r.ok);
  ASSERT_GE(r.samples.size(), 1u);
  const auto& s = r.samples;
  EXPECT_EQ(s.front().time_s, 0.0);
  EXPECT_EQ(s.front().q_rad, waypoints.front());
  EXPECT_EQ(s.front().qd_rad_s, JointVector::Zero());
  EXPECT_EQ(s.back().q_rad, waypoints.back());
  EXPECT_EQ(s.back().qd_rad_s, JointVector::Zero());
  EXPECT_DOUBLE_EQ(s.back().time_s, r.duration_s);
  const JointVector v = o.max_velocity_rad_s;
  const JointVector a = o.max_acceleration_rad_s2;
  const double rel = 1.0 + 1e-9;
  double q_abs = 0.0;
  for (const auto& w : waypoints) q_abs = std::max(q_abs, w.cwiseAbs().maxCoeff());
  const double eps_q = 4.0 * DBL_EPSILON * (q_abs + 1.0 + v.maxCoeff() * r.duration_s);
  int bad_reported = 0, bad_velocity = 0, bad_acceleration = 0, bad_spacing = 0;
  double worst_v = 0.0, worst_a = 0.0;  // finite differences relative to the limit
  for (std::size_t i = 0; i < s.size(); ++i) {
    for (int j = 0; j < 6; ++j) {
      if (std::abs(s[i].qd_rad_s[j]) > v[j] * rel) ++bad_reported;
      if (std::abs(s[i].qdd_rad_s2[j]) > a[j] * rel) ++bad_reported;
    }
    if (i == 0) continue;
    const double h0 = s[i].time_s - s[i - 1].time_s;
    // The last gap is in [0.01, 1.01] periods (a sample too close to the end is left out).
    if (!(h0 >= 0.01 * o.sample_period_s * (1.0 - 1e-9) &&
          h0 <= 1.01 * o.sample_period_s * (1.0 + 1e-9))) {
      ++bad_spacing;
    }
    if (i + 1 < s.size() && std::abs(h0 - o.sample_period_s) > 1e-9) ++bad_spacing;
    const JointVector v0 = (s[i].q_rad - s[i - 1].q_rad) / h0;
    for (int j = 0; j < 6; ++j) {
      worst_v = std::max(worst_v, std::abs(v0[j]) / v[j]);
      if (std::abs(v0[j]) > v[j] * rel + 2.0 * eps_q / h0) ++bad_velocity;
    }
    if (i + 1 == s.size()) continue;
    const double h1 = s[i + 1].time_s - s[i].time_s;
    const JointVector v1 = (s[i + 1].q_rad - s[i].q_rad) / h1;
    const JointVector acc = 2.0 * (v1 - v0) / (h0 + h1);
    for (int j = 0; j < 6; ++j) {
      worst_a = std::max(worst_a, std::abs(acc[j]) / a[j]);
      if (std::abs(acc[j]) > a[j] * rel + 4.0 * eps_q / (h0 * h1)) ++bad_acceleration;
    }
  }
  EXPECT_EQ(bad_reported, 0);
  EXPECT_EQ(bad_velocity, 0) << "worst |fd velocity| / limit " << worst_v;
  EXPECT_EQ(bad_acceleration, 0) << "worst |fd acceleration| / limit " << worst_a;
  EXPECT_EQ(bad_spacing, 0);
  // On the blended path: within the deviation bound of the polyline and of every waypoint.
  // The motion between two samples h apart is within |a| h^2 / 8 of their chord.
  EXPECT_LE(r.max_blend_deviation_rad, o.max_deviation_rad * rel);
  EXPECT_LE(MaxDistanceFromPolyline(s, waypoints), o.max_deviation_rad + 1e-9);
  const double sagitta = a.norm() * o.sample_period_s * o.sample_period_s / 8.0;
  // Chord k (samples k - 1, k) is at least |q_i - w| - (travel_k - travel_i) from w: skip
  // the chords that cannot come closer than the nearest so far.
  std::vector<double> travel(s.size(), 0.0);
  for (std::size_t i = 1; i < s.size(); ++i) {
    travel[i] = travel[i - 1] + (s[i].q_rad - s[i - 1].q_rad).norm();
  }
  for (std::size_t w = 1; w + 1 < waypoints.size(); ++w) {
    double d = std::numeric_limits<double>::infinity();
    for (std::size_t k = 1; k < s.size();) {
      const double reach = (s[k - 1].q_rad - waypoints[w]).norm() - d;
      if (reach > 0.0 && travel[k] - travel[k - 1] < reach) {
        const auto next = std::lower_bound(travel.begin() + k, travel.end(), travel[k - 1] + reach);
        k = std::max<std::size_t>(k + 1, next - travel.begin());
        continue;
      }
      d = std::min(d, PointSegmentDistance(waypoints[w], s[k - 1].q_rad, s[k].q_rad));
      ++k;
    }
    EXPECT_LE(d, o.max_deviation_rad + sagitta + 1e-12) << "waypoint " << w;
  }
}

std::vector<JointVector> RandomUr10Path(std::mt19937* rng, int n) {
  const JointVector lo = Model().min_position_rad();
  const JointVector hi = Model().max_position_rad();
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::vector<JointVector> path(n);
  for (auto& q : path) {
    for (int j = 0; j < 6; ++j) q[j] = lo[j] + (hi[j] - lo[j]) * unit(*rng);
  }
  return path;
}

// A smooth joint path in small steps with shallow corners, like the IK samples of a
// cartesian move: a random walk whose direction turns a little at every step.
std::vector<JointVector> SmoothPath(std::mt19937* rng, int n, double step_rad) {
  std::normal_distribution<double> normal(0.0, 1.0);
  std::vector<JointVector> path = {JointVector::Zero()};
  JointVector direction = JointVector::NullaryExpr([&] { return normal(*rng); }).normalized();
  for (int i = 1; i < n; ++i) {
    const JointVector turn = JointVector::NullaryExpr([&] { return normal(*rng); });
    direction = (direction + 0.15 * turn).normalized();
    path.push_back(path.back() + step_rad * direction);
  }
  return path;
}

TEST(TimeOptimalTest, RandomUr10PathsStayWithinTheLimits) {
  std::mt19937 rng(20160701);
  std::uniform_int_distribution<int> count(2, 100);
  for (int trial = 0; trial < 8; ++trial) {
    const int n = trial == 0 ? 100 : count(rng);
    const auto path = RandomUr10Path(&rng, n);
    // Large blends also exercise the velocity limit curve's switching points.
    for (const double deviation : {0.01, 0.2, 1.0}) {
      const TimeOptimalOptions o = Ur10Options(deviation);
      const TimeOptimalResult r = TimeParametrizeTimeOptimal(path, o);
      const std::string what = "trial " + std::to_string(trial) + ", " + std::to_string(n) +
                               " waypoints, deviation " + std::to_string(deviation);
      ExpectValid(path, o, r, what);
      EXPECT_LE(r.duration_s, RobotDuration(path, o) * (1.0 + 1e-12)) << what;
    }
  }
}

TEST(TimeOptimalTest, SmoothPathsStayWithinTheLimitsAndBeatStoppingAtCorners) {
  std::mt19937 rng(42);
  std::uniform_int_distribution<int> count(2, 100);
  for (int trial = 0; trial < 20; ++trial) {
    const int n = trial == 0 ? 100 : count(rng);
    const double step = trial % 2 == 0 ? 0.02 : 0.1;
    const auto path = SmoothPath(&rng, n, step);
    const TimeOptimalOptions o = Ur10Options(0.01);
    const TimeOptimalResult r = TimeParametrizeTimeOptimal(path, o);
    const std::string what = "trial " + std::to_string(trial) + ", " + std::to_string(n) +
                             " waypoints of " + std::to_string(step) + " rad";
    ExpectValid(path, o, r, what);
    const double robot = RobotDuration(path, o);
    EXPECT_LE(r.duration_s, robot * (1.0 + 1e-12)) << what;
    // Shallow corners: blends keep the speed up where the polyline stops at every corner.
    if (n >= 10) {
      EXPECT_LT(r.duration_s, 0.6 * robot) << what;
    }
  }
}

// A point 0.35 m out along the flange's z axis (where a suction cup's lip is), base frame.
Eigen::Vector3d LipPosition(const JointVector& q) {
  static const ur10::Ur10Kinematics kinematics(Model());
  return kinematics.ForwardKinematics(q) * Eigen::Vector3d(0.0, 0.0, 0.35);
}

// The lip's largest speed between consecutive samples, m/s.
double MaxLipSpeed(const TimeOptimalResult& r) {
  double worst = 0.0;
  for (std::size_t i = 1; i < r.samples.size(); ++i) {
    const double h = r.samples[i].time_s - r.samples[i - 1].time_s;
    if (h <= 0.0) continue;
    worst = std::max(
        worst, (LipPosition(r.samples[i].q_rad) - LipPosition(r.samples[i - 1].q_rad)).norm() / h);
  }
  return worst;
}

TEST(TimeOptimalTest, APointSpeedBoundSlowsOnlyWhereThePointMovesFast) {
  constexpr double kBound = 0.45;  // m/s
  std::mt19937 rng(2016);
  double bounded_total = 0.0, uniform_total = 0.0;
  for (int trial = 0; trial < 12; ++trial) {
    const bool smooth = trial % 2 == 1;
    const auto path = smooth ? SmoothPath(&rng, 60, 0.05) : RandomUr10Path(&rng, 6);
    const std::string what = "trial " + std::to_string(trial);
    TimeOptimalOptions o = Ur10Options(trial % 4 < 2 ? 0.01 : 0.2);
    o.max_point_speed = kBound;
    o.point_speed_rate = [](const JointVector& q, const JointVector& dq_ds) {
      constexpr double kStep = 1e-6;
      return (LipPosition(q + kStep * dq_ds) - LipPosition(q)).norm() / kStep;
    };
    const TimeOptimalResult bounded = TimeParametrizeTimeOptimal(path, o);
    ExpectValid(path, o, bounded, what);
    // Sampled every 0.02 rad of the path, the bound holds between samples within a few %.
    EXPECT_LE(MaxLipSpeed(bounded), 1.03 * kBound) << what;
    // The old way: the unbounded timing slowed as a whole (speeds by k, accelerations by k^2).
    TimeOptimalOptions plain = Ur10Options(o.max_deviation_rad);
    const double k = std::min(1.0, kBound / MaxLipSpeed(TimeParametrizeTimeOptimal(path, plain)));
    plain.max_velocity_rad_s *= k;
    plain.max_acceleration_rad_s2 *= k * k;
    const double uniform = TimeParametrizeTimeOptimal(path, plain).duration_s;
    EXPECT_LE(bounded.duration_s, uniform * 1.001) << what;
    bounded_total += bounded.duration_s;
    uniform_total += uniform;
  }
  EXPECT_LT(bounded_total, 0.7 * uniform_total);
  std::printf("point speed bound: %.1f s in all, %.1f s slowed as a whole\n", bounded_total,
              uniform_total);
}

TEST(TimeOptimalTest, StraightMoveIsTheAnalyticTrapezoid) {
  const TimeOptimalOptions o = Ur10Options();
  const JointVector a = (JointVector() << 0.1, -0.5, 0.3, 1.0, -2.0, 0.0).finished();
  for (const JointVector& delta :
       {JointVector((JointVector() << 3.0, 1.0, 0, 0, 0, 0).finished()),
        JointVector((JointVector() << 0.05, 0.02, 0.1, 0, 0, 0).finished()),
        JointVector((JointVector() << 0, 0, 0, 0, 0, 6.0).finished())}) {
    const JointVector b = a + delta;
    const TimeOptimalResult r = TimeParametrizeTimeOptimal({a, b}, o);
    ExpectValid({a, b}, o, r, "straight");
    EXPECT_NEAR(r.duration_s, TrapezoidDuration(delta, o), 1e-12);
    EXPECT_NEAR(r.duration_s, RobotDuration({a, b}, o), 1e-9);
    // Waypoints along the line, repeated ones included, change nothing.
    const TimeOptimalResult r3 =
        TimeParametrizeTimeOptimal({a, a, a + 0.25 * delta, a + 0.7 * delta, b, b}, o);
    ExpectValid({a, a, a + 0.25 * delta, a + 0.7 * delta, b, b}, o, r3, "collinear");
    EXPECT_NEAR(r3.duration_s, r.duration_s, 1e-9);
    EXPECT_EQ(r3.num_blends + r3.num_stops, 0);
  }
}

TEST(TimeOptimalTest, ZeroDeviationStopsAtEveryCornerLikeTheRobot) {
  std::mt19937 rng(7);
  for (int trial = 0; trial < 5; ++trial) {
    const auto path = RandomUr10Path(&rng, 8);
    const TimeOptimalOptions o = Ur10Options(0.0);
    const TimeOptimalResult r = TimeParametrizeTimeOptimal(path, o);
    ExpectValid(path, o, r, "deviation 0");
    EXPECT_EQ(r.num_blends, 0);
    EXPECT_EQ(r.num_stops, 6);
    EXPECT_NEAR(r.duration_s, RobotDuration(path, o), 1e-9);
    EXPECT_LE(MaxDistanceFromPolyline(r.samples, path), 1e-12);
  }
}

TEST(TimeOptimalTest, SharpReversalStops) {
  const TimeOptimalOptions o = Ur10Options(0.05);
  const JointVector a = JointVector::Zero();
  const JointVector b = JointVector::Constant(0.5);
  const JointVector c = b - 0.4 * (b - a) + JointVector::Unit(2) * 1e-3;  // back, nearly
  const TimeOptimalResult r = TimeParametrizeTimeOptimal({a, b, c}, o);
  ExpectValid({a, b, c}, o, r, "reversal");
  EXPECT_EQ(r.num_stops, 1);
  EXPECT_LE(r.duration_s, RobotDuration({a, b, c}, o) * (1.0 + 1e-12));
}

TEST(TimeOptimalTest, RightAngleIsBlendedWithinTheDeviation) {
  const TimeOptimalOptions o = Ur10Options(0.05);
  const JointVector a = JointVector::Zero();
  const JointVector b = JointVector::Constant(0.5);
  const JointVector d = b + JointVector::Unit(0) * 0.5 - JointVector::Unit(1) * 0.5;
  ASSERT_NEAR((b - a).dot(d - b), 0.0, 1e-15);
  const TimeOptimalResult r = TimeParametrizeTimeOptimal({a, b, d}, o);
  ExpectValid({a, b, d}, o, r, "right angle");
  EXPECT_EQ(r.num_blends, 1);
  EXPECT_EQ(r.num_stops, 0);
  EXPECT_LT(r.duration_s, RobotDuration({a, b, d}, o));
  // The blend's middle is 0.05 rad from the corner and 0.05 cos(45 deg) from both segments.
  EXPECT_NEAR(r.max_blend_deviation_rad, 0.05, 1e-12);
  // The distance to the polyline has a kink there: the samples see it to within a step.
  double step = 0.0;
  for (std::size_t i = 1; i < r.samples.size(); ++i) {
    step = std::max(step, (r.samples[i].q_rad - r.samples[i - 1].q_rad).norm());
  }
  const double distance = MaxDistanceFromPolyline(r.samples, {a, b, d});
  EXPECT_LE(distance, 0.05 * std::sqrt(0.5) + 1e-12);
  EXPECT_GE(distance, 0.05 * std::sqrt(0.5) - step);
}

// The samples of a blended corner: on the first segment, then off both in the blend, then on
// the second; the planner re-checks only the steps that do not stay on one segment.
TEST(TimeOptimalTest, EachSampleKnowsTheSegmentItLiesOn) {
  const TimeOptimalOptions o = Ur10Options(0.05);
  const JointVector a = JointVector::Zero();
  const JointVector b = JointVector::Constant(0.5);
  const JointVector d = b + JointVector::Unit(0) * 0.5 - JointVector::Unit(1) * 0.5;
  const TimeOptimalResult r = TimeParametrizeTimeOptimal({a, b, d}, o);
  const std::vector<int> segment = PolylineSegmentOfSamples(r.samples, {a, b, d}, 1e-9);
  ASSERT_EQ(segment.size(), r.samples.size());
  EXPECT_EQ(segment.front(), 0);
  EXPECT_EQ(segment.back(), 1);
  // In order: 0s, then -1s (the blend), then 1s; and -1 exactly where a sample is off both.
  int phase = 0, blended = 0;
  for (std::size_t i = 0; i < segment.size(); ++i) {
    const double off = std::min(PointSegmentDistance(r.samples[i].q_rad, a, b),
                                PointSegmentDistance(r.samples[i].q_rad, b, d));
    EXPECT_EQ(segment[i]<0, off> 1e-9) << i;
    const int p = segment[i] == 0 ? 0 : segment[i] < 0 ? 1 : 2;
    EXPECT_GE(p, phase) << i;
    phase = p;
    blended += segment[i] < 0;
  }
  EXPECT_GT(blended, 0);
  // A straight move lies on its one segment throughout; no polyline, no segment.
  const TimeOptimalResult straight = TimeParametrizeTimeOptimal({a, b}, o);
  for (int s : PolylineSegmentOfSamples(straight.samples, {a, b}, 1e-9)) EXPECT_EQ(s, 0);
  for (int s : PolylineSegmentOfSamples(straight.samples, {a}, 1e-9)) EXPECT_EQ(s, -1);
}

TEST(TimeOptimalTest, MaxDistanceFromPolylineIsTheBruteForceOne) {
  std::mt19937 rng(5);
  std::normal_distribution<double> normal(0.0, 1.0);
  for (int trial = 0; trial < 20; ++trial) {
    std::vector<JointVector> polyline(1 + trial % 7);
    for (auto& w : polyline) w = JointVector::NullaryExpr([&] { return normal(rng); });
    std::vector<TrajectorySample> samples(200);
    JointVector q = JointVector::Zero();
    for (auto& sample : samples) {
      q += 0.05 * JointVector::NullaryExpr([&] { return normal(rng); });
      sample.q_rad = q;
    }
    double expected = 0.0;
    for (const auto& sample : samples) {
      double d = (sample.q_rad - polyline[0]).norm();
      for (std::size_t i = 1; i < polyline.size(); ++i) {
        d = std::min(d, PointSegmentDistance(sample.q_rad, polyline[i - 1], polyline[i]));
      }
      expected = std::max(expected, d);
    }
    EXPECT_NEAR(MaxDistanceFromPolyline(samples, polyline), expected, 1e-12) << trial;
  }
  EXPECT_EQ(MaxDistanceFromPolyline({}, {JointVector::Zero()}), 0.0);
}

TEST(TimeOptimalTest, ScaledDownLimits) {
  // As the planner's speed_fraction does: every limit a tenth.
  std::mt19937 rng(11);
  const auto path = SmoothPath(&rng, 40, 0.05);
  TimeOptimalOptions o = Ur10Options(0.02);
  o.max_velocity_rad_s *= 0.1;
  o.max_acceleration_rad_s2 *= 0.1;
  const TimeOptimalResult slow = TimeParametrizeTimeOptimal(path, o);
  ExpectValid(path, o, slow, "a tenth");
  const TimeOptimalResult fast = TimeParametrizeTimeOptimal(path, Ur10Options(0.02));
  // Limits scaled by c scale the time-optimal duration by 1 / sqrt(c) to 1 / c.
  EXPECT_GT(slow.duration_s, std::sqrt(10.0) * fast.duration_s * 0.999);
  EXPECT_LT(slow.duration_s, 10.0 * fast.duration_s * 1.001);
}

TEST(TimeOptimalTest, SingleAndRepeatedWaypoints) {
  const TimeOptimalOptions o = Ur10Options();
  const JointVector q = (JointVector() << 0.1, 0.2, 0.3, 0.4, 0.5, 0.6).finished();
  for (const auto& path : {std::vector<JointVector>{q}, std::vector<JointVector>{q, q, q}}) {
    const TimeOptimalResult r = TimeParametrizeTimeOptimal(path, o);
    ASSERT_TRUE(r.ok);
    ASSERT_EQ(r.samples.size(), 1u);
    EXPECT_EQ(r.samples[0].q_rad, q);
    EXPECT_EQ(r.samples[0].qd_rad_s, JointVector::Zero());
    EXPECT_EQ(r.duration_s, 0.0);
  }
  // Repeats inside a path with corners.
  const JointVector p = q + JointVector::Unit(0) * 0.4;
  const JointVector e = p + JointVector::Unit(1) * 0.3;
  const std::vector<JointVector> path = {q, q, p, p, p, e, e};
  const TimeOptimalResult r = TimeParametrizeTimeOptimal(path, o);
  ExpectValid(path, o, r, "repeats");
  const TimeOptimalResult plain = TimeParametrizeTimeOptimal({q, p, e}, o);
  EXPECT_NEAR(r.duration_s, plain.duration_s, 1e-12);
  EXPECT_EQ(r.num_blends, 1);
}

TEST(TimeOptimalTest, ControllerRateSamples) {
  std::mt19937 rng(3);
  const auto path = SmoothPath(&rng, 30, 0.05);
  const TimeOptimalOptions o = Ur10Options(0.01, 0.008);
  const TimeOptimalResult r = TimeParametrizeTimeOptimal(path, o);
  ExpectValid(path, o, r, "125 Hz");
  for (std::size_t i = 0; i + 1 < r.samples.size(); ++i) {
    EXPECT_DOUBLE_EQ(r.samples[i].time_s, i * 0.008);
  }
  const double last_gap = r.samples.back().time_s - r.samples[r.samples.size() - 2].time_s;
  EXPECT_GE(last_gap, 0.01 * 0.008);
  // Finer integration steps change the duration only a little.
  TimeOptimalOptions fine = o;
  fine.integration_step_s = 0.0002;
  const TimeOptimalResult rf = TimeParametrizeTimeOptimal(path, fine);
  ExpectValid(path, fine, rf, "fine steps");
  EXPECT_NEAR(rf.duration_s, r.duration_s, 0.01 * r.duration_s);
}

TEST(TimeOptimalTest, RejectsBadInput) {
  const TimeOptimalOptions o = Ur10Options();
  const JointVector q = JointVector::Zero();
  const JointVector p = JointVector::Ones();
  EXPECT_THROW(TimeParametrizeTimeOptimal({}, o), std::invalid_argument);
  JointVector nan = q;
  nan[3] = std::nan("");
  EXPECT_THROW(TimeParametrizeTimeOptimal({q, nan}, o), std::invalid_argument);
  JointVector inf = q;
  inf[0] = std::numeric_limits<double>::infinity();
  EXPECT_THROW(TimeParametrizeTimeOptimal({inf}, o), std::invalid_argument);
  auto with = [&](auto mutate) {
    TimeOptimalOptions bad = o;
    mutate(&bad);
    return bad;
  };
  const std::vector<TimeOptimalOptions> bad_options = {
      with([](TimeOptimalOptions* b) { b->max_velocity_rad_s[2] = 0.0; }),
      with([](TimeOptimalOptions* b) { b->max_velocity_rad_s[0] = -1.0; }),
      with([](TimeOptimalOptions* b) { b->max_velocity_rad_s[5] = std::nan(""); }),
      with([](TimeOptimalOptions* b) { b->max_acceleration_rad_s2[1] = 0.0; }),
      with([](TimeOptimalOptions* b) {
        b->max_acceleration_rad_s2[4] = std::numeric_limits<double>::infinity();
      }),
      with([](TimeOptimalOptions* b) { b->max_deviation_rad = -0.01; }),
      with([](TimeOptimalOptions* b) { b->max_deviation_rad = std::nan(""); }),
      with([](TimeOptimalOptions* b) { b->sample_period_s = 0.0; }),
      with([](TimeOptimalOptions* b) { b->sample_period_s = -0.008; }),
      with([](TimeOptimalOptions* b) { b->sample_period_s = std::nan(""); }),
      with([](TimeOptimalOptions* b) { b->integration_step_s = 0.0; }),
  };
  for (std::size_t i = 0; i < bad_options.size(); ++i) {
    EXPECT_THROW(TimeParametrizeTimeOptimal({q, p}, bad_options[i]), std::invalid_argument) << i;
  }
  // 100 rad of joint 0 take about 50 s: more than 2e7 samples at 1 us.
  TimeOptimalOptions tiny_period = o;
  tiny_period.sample_period_s = 1e-6;
  EXPECT_THROW(TimeParametrizeTimeOptimal({q, JointVector::Unit(0) * 100.0}, tiny_period),
               std::invalid_argument);
  try {
    TimeParametrizeTimeOptimal({q, p}, bad_options[0]);
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("elbow_joint"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace picking::planner
