// The device force loop (hrt/device_loop.h): the workspace map against poses
// computed by hand, every safety rule of tick() (watchdog, NaN guard, clamps,
// rate limit, soft start, clutch, torque policy), the multirate model in
// closed form, no allocation in tick(), the triple buffer under two threads
// and the thread mode on the real clock.
//
// Most tests drive tick() in lockstep with a ManualClock set to i * 1 ms
// (never accumulated, so times are exact to the last bit of i * 1e-3).
// Tolerances: 1e-12 where the value is a handful of double operations on
// numbers of order 1 (rounding is ~1e-16 per operation); 1e-9 where a ramp
// factor 1 - x / T is evaluated at a time x that carries the rounding of a
// difference of session times (~1e-16 s / 1e-2 s = 1e-14, times |W| < 10).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <thread>
#include <vector>

#include "hrt/device_loop.h"
#include "synthetic.h"  // hrt::synth::allocation_count: the binary's operator new counts

namespace {

using Eigen::AngleAxisd;
using Eigen::Quaterniond;
using hrt::DeviceCommand;
using hrt::DeviceInfo;
using hrt::DeviceLoop;
using hrt::DeviceLoopOptions;
using hrt::DeviceSample;
using hrt::DeviceTarget;
using hrt::Mat6;
using hrt::Pose;
using hrt::Vec3;
using hrt::Vec6;
using hrt::WorkspaceMap;

const double kPi = 3.14159265358979323846;
double deg(double d) { return d * kPi / 180.0; }

Vec6 vec6(double a, double b, double c, double d, double e, double f) {
  Vec6 v;
  v << a, b, c, d, e, f;
  return v;
}

Pose pose(const Vec3& p, const Quaterniond& q = Quaterniond::Identity()) {
  Pose r;
  r.position = p;
  r.rotation = q;
  return r;
}

// A device whose pose the test sets and which records what it was given,
// into storage reserved up front (so it allocates nothing on the device thread).
class TestDevice : public hrt::Device {
 public:
  explicit TestDevice(size_t capacity = 1 << 14) { written.reserve(capacity); }
  const DeviceInfo& info() const override { return info_; }
  bool read(double, DeviceSample& out) noexcept override {
    if (!ok) return false;
    out = sample;
    return true;
  }
  void write(double, const Vec6& w) noexcept override {
    last = w;
    ++writes;
    if (written.size() < written.capacity()) written.push_back(w);
  }

  DeviceInfo info_;     // defaults: 10 N, 0.5 N m, 6 DoF
  DeviceSample sample;  // what read() returns
  bool ok = true;       // false: read() fails
  Vec6 last = Vec6::Zero();
  size_t writes = 0;
  std::vector<Vec6> written;
};

// A lockstep loop on a ManualClock; tick(i) runs the period at t = i ms.
struct Rig {
  explicit Rig(const DeviceLoopOptions& o, const DeviceInfo& info = DeviceInfo{}) {
    dev.info_ = info;
    loop = std::make_unique<DeviceLoop>(dev, o, clock, 4096);
  }
  const Vec6& tick(long i) {
    clock.set(static_cast<double>(i) * 1e-3);
    loop->tick();
    return dev.last;
  }
  DeviceTarget target() {
    DeviceTarget t;
    loop->target(t);
    return t;
  }
  TestDevice dev;
  hrt::ManualClock clock;
  std::unique_ptr<DeviceLoop> loop;
};

DeviceCommand command(const Vec6& w, const Pose& ref = Pose{}, const Mat6& K = Mat6::Zero()) {
  DeviceCommand c;
  c.valid = true;
  c.wrench = w;
  c.target_ref = ref;
  c.stiffness = K;
  return c;
}

// Options with no ramps or limits in the way of the rule a test looks at.
DeviceLoopOptions plain() {
  DeviceLoopOptions o;
  o.soft_start = 0.0;
  o.watchdog = 10.0;
  o.max_force_rate = 1e9;
  o.max_torque_rate = 1e9;
  return o;
}

::testing::AssertionResult vec_near(const Vec6& a, const Vec6& b, double tol) {
  const double err = (a - b).cwiseAbs().maxCoeff();
  if (err <= tol) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "off by " << err << " > " << tol << "\n got  " << a.transpose() << "\n want "
                                       << b.transpose();
}
#define EXPECT_VEC_NEAR(a, b, tol) EXPECT_TRUE(vec_near((a), (b), (tol)))

}  // namespace

// ---------------------------------------------------------------------------
// Workspace map
// ---------------------------------------------------------------------------

// Scale 2, offset rotated 30 degrees about z, grasp 5 cm along the probe's z
// and turned 90 degrees about x; every number below written out by hand.
// hrt/clock.h: a SessionClock reads the monotonic clock less its value at
// construction, so a session starts at t = 0 and t follows the steady clock.
TEST(Clock, SessionClockStartsAtZeroAndFollowsTheMonotonicClock) {
  const hrt::SteadyClock steady;
  const double s0 = steady.now();
  const hrt::SessionClock session;
  const double t0 = session.now();
  EXPECT_GE(t0, 0.0);
  EXPECT_LT(t0, 0.5);  // the construction and one read, whatever the machine's load
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  const double s1 = steady.now(), t1 = session.now();
  EXPECT_GE(t1 - t0, 0.020);
  // Both read CLOCK_MONOTONIC: the session's elapsed time is the steady clock's,
  // less what passed before the session clock was made.
  EXPECT_LE(t1, steady.now() - s0);
  EXPECT_GE(t1, s1 - s0 - 0.5);
  hrt::ManualClock manual;
  manual.set(1.25);
  manual.advance(0.001);
  EXPECT_EQ(manual.now(), 1.25 + 0.001);
}

TEST(WorkspaceMap, ScaleOffsetAndGraspAgainstPosesComputedByHand) {
  const double c = std::sqrt(3.0) / 2, s = 0.5;  // cos, sin 30 degrees
  WorkspaceMap m;
  m.scale = 2.0;
  m.offset = pose(Vec3(0.1, -0.2, 0.3), Quaterniond(AngleAxisd(deg(30), Vec3::UnitZ())));
  m.grasp = pose(Vec3(0, 0, 0.05), Quaterniond(AngleAxisd(deg(90), Vec3::UnitX())));

  // Device handle at (0.01, 0.02, -0.03), not rotated.
  //   handle = Rz30 (2 p) + offset = (0.02 c - 0.04 s + 0.1, 0.02 s + 0.04 c - 0.2, -0.06 + 0.3)
  //   target rotation = Rz30 Rx(-90) = [[c, 0, -s], [s, 0, c], [0, -1, 0]]
  //   target position = handle - target rotation (0, 0, 0.05) = handle - (-0.05 s, 0.05 c, 0)
  const Pose t = m.to_scene(pose(Vec3(0.01, 0.02, -0.03)));
  const Vec3 want_p(0.02 * c - 0.04 * s + 0.1 + 0.05 * s, 0.02 * s + 0.04 * c - 0.2 - 0.05 * c, 0.24);
  hrt::Mat3 want_R;
  want_R << c, 0, -s, s, 0, c, 0, -1, 0;
  EXPECT_LE((t.position - want_p).cwiseAbs().maxCoeff(), 1e-12) << t.position.transpose();
  EXPECT_LE((t.rotation.toRotationMatrix() - want_R).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_NEAR(t.position.x(), 0.1223205080756888, 1e-12);  // the same, as digits
  EXPECT_NEAR(t.position.y(), -0.1986602540378444, 1e-12);

  // A rotated handle (20 degrees about y): the target's rotation is
  // Rz30 Ry20 Rx(-90), and undoing the map by hand returns the device pose:
  //   handle = target grasp, p_dev = Rz30^-1 (p_handle - offset) / 2, q_dev = Rz30^-1 q_handle.
  const Quaterniond q_dev(AngleAxisd(deg(20), Vec3::UnitY()));
  const Pose dev = pose(Vec3(-0.04, 0.015, 0.07), q_dev);
  const Pose t2 = m.to_scene(dev);
  const Quaterniond want_q =
      Quaterniond(AngleAxisd(deg(30), Vec3::UnitZ())) * q_dev * Quaterniond(AngleAxisd(deg(-90), Vec3::UnitX()));
  EXPECT_NEAR(std::abs(t2.rotation.dot(want_q)), 1.0, 1e-12);
  const Vec3 p_handle = t2.position + t2.rotation * m.grasp.position;
  const Quaterniond q_handle = t2.rotation * m.grasp.rotation;
  const Vec3 p_back = m.offset.rotation.conjugate() * (p_handle - m.offset.position) / 2.0;
  const Quaterniond q_back = m.offset.rotation.conjugate() * q_handle;
  EXPECT_LE((p_back - dev.position).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_NEAR(std::abs(q_back.dot(q_dev)), 1.0, 1e-12);
  // to_device is that inverse: the hand computation above, and to_scene(to_device(t)) = t.
  const Pose d2 = m.to_device(t2);
  EXPECT_LE((d2.position - dev.position).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_NEAR(std::abs(d2.rotation.dot(q_dev)), 1.0, 1e-12);
  const Pose t3 = m.to_scene(m.to_device(t));
  EXPECT_LE((t3.position - t.position).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_NEAR(std::abs(t3.rotation.dot(t.rotation)), 1.0, 1e-12);
}

// Wrenches go back by the inverse of the offset's rotation and keep their
// magnitude whatever the scale: Rz(-30) (1, 0, 0) = (c, -s, 0), Rz(-30) (0, 2, 0) = (2 s, 2 c, 0).
TEST(WorkspaceMap, WrenchToDeviceRotatesByTheInverseOffsetRotation) {
  const double c = std::sqrt(3.0) / 2, s = 0.5;
  WorkspaceMap m;
  m.scale = 2.0;
  m.offset = pose(Vec3(0.1, -0.2, 0.3), Quaterniond(AngleAxisd(deg(30), Vec3::UnitZ())));
  m.grasp = pose(Vec3(0, 0, 0.05), Quaterniond(AngleAxisd(deg(90), Vec3::UnitX())));
  EXPECT_VEC_NEAR(m.wrench_to_device(vec6(1, 0, 0, 0, 2, 0)), vec6(c, -s, 0, 2 * s, 2 * c, 0), 1e-12);
}

// ---------------------------------------------------------------------------
// Watchdog
// ---------------------------------------------------------------------------

// Commands every 10 ms, then none (the simulation paused): the output is
// untouched up to the watchdog time (50 ms), falls linearly to zero over the
// ramp (10 ms), stays zero, the stall is counted once; publishing again
// soft-starts it back (100 ms); a second stall is a second event. The wrench
// is small enough that the default rate limits (1 N, 0.05 N m per tick)
// never shape a ramp (checked: rate_limited stays 0).
TEST(DeviceLoop, WatchdogRampsToZeroAfterAnExplicitTimeAndRecovers) {
  DeviceLoopOptions o;
  o.watchdog = 0.05;
  o.watchdog_ramp = 0.01;
  o.soft_start = 0.1;
  o.multirate = false;
  Rig rig(o);
  const Vec6 W0 = vec6(2, -1, 0.5, 0.1, 0, -0.05);
  for (long i = 0; i <= 300; ++i) {
    if (i % 10 == 0) rig.loop->publish(command(W0));
    const Vec6 out = rig.tick(i);
    if (i >= 100) EXPECT_VEC_NEAR(out, W0, 1e-12) << "i = " << i;
  }
  // Last command at 300 ms.
  for (long i = 301; i < 500; ++i) {
    const Vec6 out = rig.tick(i);
    if (i <= 350) {
      EXPECT_VEC_NEAR(out, W0, 1e-9) << "changed before the watchdog time, i = " << i;
    } else if (i <= 360) {
      EXPECT_VEC_NEAR(out, W0 * (1.0 - (i - 350) / 10.0), 1e-9) << "i = " << i;
    } else {
      EXPECT_EQ(out, Vec6::Zero()) << "i = " << i;
    }
  }
  EXPECT_EQ(rig.loop->stats().watchdog_events, 1u);

  // Recovery at 500 ms: back in over soft_start from zero.
  for (long i = 500; i <= 800; ++i) {
    if (i % 10 == 0) rig.loop->publish(command(W0));
    const Vec6 out = rig.tick(i);
    EXPECT_VEC_NEAR(out, W0 * std::min(1.0, (i - 500) / 100.0), 1e-9) << "i = " << i;
  }
  EXPECT_EQ(rig.loop->stats().watchdog_events, 1u);
  for (long i = 801; i <= 900; ++i) rig.tick(i);
  EXPECT_EQ(rig.tick(901), Vec6::Zero());
  EXPECT_EQ(rig.loop->stats().watchdog_events, 2u);
  EXPECT_EQ(rig.loop->stats().rate_limited, 0u);
  EXPECT_EQ(rig.loop->stats().commands, 31u + 31u);
}

// watchdog = -1: max(50 ms, 5 x the median of the last 64 publication
// periods). Every 2 ms: 5 x 2 = 10 ms, so 50 ms. Then every 20 ms with one
// 60 ms gap among them: 100 ms, from the median (the mean of the last 64
// would give 103 ms, their maximum 300 ms) of the last 64 only (with the
// 2 ms periods still counted it would be 50 ms again). Each is checked on
// both sides: unchanged at the watchdog time, at 80 % 2 ms after it.
TEST(DeviceLoop, DefaultWatchdogIsFiveMediansOfTheLast64PeriodsOrFiftyMs) {
  DeviceLoopOptions o;
  o.watchdog = -1.0;
  o.watchdog_ramp = 0.01;
  o.soft_start = 0.1;
  o.multirate = false;
  Rig rig(o);
  const Vec6 W0 = vec6(1, 0.5, -0.5, 0.05, 0.05, 0);
  auto check_stall = [&](long last, long wd_ms) {
    for (long i = last + 1; i <= last + wd_ms; ++i) {
      const Vec6 out = rig.tick(i);
      EXPECT_VEC_NEAR(out, W0, 1e-9) << "changed before the watchdog (" << wd_ms << " ms), i = " << i;
    }
    rig.tick(last + wd_ms + 1);
    EXPECT_VEC_NEAR(rig.tick(last + wd_ms + 2), 0.8 * W0, 1e-6) << "watchdog " << wd_ms << " ms";
    for (long i = last + wd_ms + 3; i <= last + wd_ms + 10; ++i) rig.tick(i);
    EXPECT_LE(rig.dev.last.cwiseAbs().maxCoeff(), 1e-9);
    EXPECT_EQ(rig.tick(last + wd_ms + 11), Vec6::Zero());
  };

  for (long i = 0; i <= 300; ++i) {
    if (i % 2 == 0) rig.loop->publish(command(W0));
    rig.tick(i);
  }
  check_stall(300, 50);
  EXPECT_EQ(rig.loop->stats().watchdog_events, 1u);

  long i = 400, last = 0;
  for (int k = 0; k < 72; ++k) {
    const long at = 400 + 20 * k;
    for (; i < at; ++i) rig.tick(i);
    // A 60 ms gap, late enough that the ring holds only 20 ms periods by
    // then (earlier, the 2 ms ones would still make the watchdog 50 ms and
    // the gap a stall of its own).
    if (k != 60 && k != 61) {
      rig.loop->publish(command(W0));
      last = at;
    }
    rig.tick(i++);
  }
  check_stall(last, 100);
  EXPECT_EQ(rig.loop->stats().watchdog_events, 2u);
  EXPECT_EQ(rig.loop->stats().rate_limited, 0u);
}

// ---------------------------------------------------------------------------
// NaN guard
// ---------------------------------------------------------------------------

// Commands with NaN or Inf in the wrench, the stiffness or the reference pose
// are dropped (the last good one keeps being evaluated), and a finite
// command whose W0 - K d overflows to inf keeps the previous output: nothing
// non-finite is ever written, and each is counted.
TEST(DeviceLoop, NonFiniteCommandsAndOutputsNeverReachTheDevice) {
  Rig rig(plain());
  rig.dev.sample.pose = pose(Vec3(0.5, 0.002, 0));  // 0.5 m from the reference (for the overflow)
  Mat6 K = 100.0 * Mat6::Identity();
  const Vec6 W0 = vec6(55, 0.5, 0, 0.05, 0, 0);
  const double nan = std::numeric_limits<double>::quiet_NaN(), inf = std::numeric_limits<double>::infinity();
  // d = (0.5, 0.002, 0, 0, 0, 0): output (55 - 50, 0.5 - 0.2, 0, 0.05, 0, 0).
  const Vec6 good_out = vec6(5, 0.3, 0, 0.05, 0, 0);

  std::vector<DeviceCommand> bad;
  bad.push_back(command(vec6(nan, 0, 0, 0, 0, 0), Pose{}, K));
  Mat6 Kinf = K;
  Kinf(3, 4) = inf;
  bad.push_back(command(W0, Pose{}, Kinf));
  bad.push_back(command(W0, pose(Vec3(nan, 0, 0)), K));
  bad.push_back(command(vec6(0, 0, 0, 0, 0, -inf), Pose{}, K));
  DeviceCommand zero_q = command(W0, Pose{}, K);
  zero_q.target_ref.rotation.coeffs().setZero();  // normalizes to NaN
  bad.push_back(zero_q);

  long i = 0;
  rig.loop->publish(command(W0, Pose{}, K));
  for (; i < 10; ++i) EXPECT_VEC_NEAR(rig.tick(i), good_out, 1e-12);
  for (const DeviceCommand& c : bad) {
    rig.loop->publish(c);
    for (int k = 0; k < 10; ++k, ++i) EXPECT_VEC_NEAR(rig.tick(i), good_out, 1e-12) << "i = " << i;
  }
  EXPECT_EQ(rig.loop->stats().non_finite, bad.size());

  // Finite numbers whose product overflows: K(0, 0) d_x = -1e308 * 0.5, so
  // W0_x - K d = 1.7e308 + 0.5e308 = inf.
  Mat6 Kover = Mat6::Zero();
  Kover(0, 0) = -1e308;
  rig.loop->publish(command(vec6(1.7e308, 0, 0, 0, 0, 0), Pose{}, Kover));
  for (int k = 0; k < 10; ++k, ++i) EXPECT_VEC_NEAR(rig.tick(i), good_out, 1e-12) << "i = " << i;
  EXPECT_EQ(rig.loop->stats().non_finite, bad.size() + 10);
  EXPECT_EQ(rig.loop->stats().commands, bad.size() + 2);

  for (const Vec6& w : rig.dev.written) ASSERT_TRUE(w.allFinite()) << w.transpose();
  EXPECT_EQ(rig.dev.written.size(), static_cast<size_t>(i));
}

// ---------------------------------------------------------------------------
// Clamps, rate limit, soft start
// ---------------------------------------------------------------------------

// |F| = 50 N and |T| = 5 N m against a 10 N, 0.5 N m device: scaled to the
// limits along the same direction, counted on each tick; below the limits
// nothing is touched or counted.
TEST(DeviceLoop, ForcesAndTorquesAboveTheLimitsAreClampedByNorm) {
  Rig rig(plain());
  rig.loop->publish(command(vec6(30, 40, 0, 0, 3, -4)));
  for (long i = 0; i < 20; ++i) EXPECT_VEC_NEAR(rig.tick(i), vec6(6, 8, 0, 0, 0.3, -0.4), 1e-12);
  EXPECT_EQ(rig.loop->stats().force_clamps, 20u);
  EXPECT_EQ(rig.loop->stats().torque_clamps, 20u);
  rig.loop->publish(command(vec6(3, 4, 0, 0, 0.2, 0.2)));
  for (long i = 20; i < 30; ++i) EXPECT_VEC_NEAR(rig.tick(i), vec6(3, 4, 0, 0, 0.2, 0.2), 1e-12);
  EXPECT_EQ(rig.loop->stats().force_clamps, 20u);
  EXPECT_EQ(rig.loop->stats().torque_clamps, 20u);
}

// A step from 0 to 8 N and 0.4 N m, then a reversal to -6 N, -0.3 N m, then
// zero, with the default rates (10 N / 10 ms, 0.5 N m / 10 ms: 1 N and
// 0.05 N m per tick): no tick changes by more, and each follows the
// rate-limited step exactly (so the limit is not stricter than asked
// either). An explicit 200 N/s gives 0.2 N per tick.
TEST(DeviceLoop, RateLimitHoldsOnEveryTickOfAStep) {
  DeviceLoopOptions o = plain();
  o.max_force_rate = -1;
  o.max_torque_rate = -1;
  Rig rig(o);
  long i = 0;
  Vec6 prev = Vec6::Zero();
  auto step_to = [&](double F, double T, int ticks) {
    rig.loop->publish(command(vec6(F, 0, 0, 0, T, 0)));
    const Vec6 start = prev;
    for (int j = 0; j < ticks; ++j, ++i) {
      const Vec6 out = rig.tick(i);
      EXPECT_LE((out.head<3>() - prev.head<3>()).norm(), 1.0 + 1e-12) << "i = " << i;
      EXPECT_LE((out.tail<3>() - prev.tail<3>()).norm(), 0.05 + 1e-12) << "i = " << i;
      const double f = start[0] + std::copysign(std::min(std::abs(F - start[0]), 1.0 * (j + 1)), F - start[0]);
      const double t = start[4] + std::copysign(std::min(std::abs(T - start[4]), 0.05 * (j + 1)), T - start[4]);
      EXPECT_VEC_NEAR(out, vec6(f, 0, 0, 0, t, 0), 1e-12) << "i = " << i;
      prev = out;
    }
  };
  step_to(8, 0.4, 12);
  EXPECT_GE(rig.loop->stats().rate_limited, 7u);  // 7 or 8: the last step is exactly 1 N
  EXPECT_LE(rig.loop->stats().rate_limited, 8u);
  step_to(-6, -0.3, 20);
  step_to(0, 0, 10);
  EXPECT_EQ(prev, Vec6::Zero());

  o.max_force_rate = 200;  // N/s
  Rig slow(o);
  slow.loop->publish(command(vec6(0, 2, 0, 0, 0, 0)));
  for (long k = 0; k < 15; ++k)
    EXPECT_VEC_NEAR(slow.tick(k), vec6(0, std::min(2.0, 0.2 * (k + 1)), 0, 0, 0, 0), 1e-12) << "k = " << k;
}

// soft_start = 0.2 s, first valid command at 50 ms: zero before it, then
// W0 (t - 0.05) / 0.2 on every tick until 250 ms, W0 after.
TEST(DeviceLoop, SoftStartRampsLinearlyFromTheFirstCommand) {
  DeviceLoopOptions o = plain();
  o.soft_start = 0.2;
  o.max_force_rate = -1;
  o.max_torque_rate = -1;
  Rig rig(o);
  const Vec6 W0 = vec6(1, 2, -2, 0.1, 0, 0);
  for (long i = 0; i <= 300; ++i) {
    if (i >= 50) rig.loop->publish(command(W0));
    const Vec6 out = rig.tick(i);
    EXPECT_VEC_NEAR(out, W0 * std::clamp((i - 50) / 200.0, 0.0, 1.0), 1e-12) << "i = " << i;
  }
  EXPECT_EQ(rig.loop->stats().rate_limited, 0u);
}

// ---------------------------------------------------------------------------
// Multirate
// ---------------------------------------------------------------------------

// The simulation computed (W0, K_eff) at the target of device pose P0; the
// device has since moved by dp = (3, -2, 1) mm and turned 0.05 rad about
// (1, 2, 2) / 3 (device frame). Through a map of scale 1.5 and an offset
// turned 30 degrees about z, d in the scene is (Rz30 1.5 dp, Rz30 0.05 axis),
// and the device gets Rz30^-1 applied to W0 - K_eff d; with multirate off,
// Rz30^-1 W0. Tolerance 1e-10: K_eff entries up to 500 times rounding of
// the composed rotations (~1e-15). The K_eff d term is ~2 N, far above it.
TEST(DeviceLoop, MultirateEvaluatesW0MinusKeffDAndHoldsW0WhenOff) {
  DeviceLoopOptions o = plain();
  o.map.scale = 1.5;
  const Quaterniond Ro(AngleAxisd(deg(30), Vec3::UnitZ()));
  o.map.offset = pose(Vec3(0.2, 0, 0), Ro);
  const Pose P0 = pose(Vec3(0.01, 0.02, 0.03), Quaterniond(AngleAxisd(deg(10), Vec3::UnitX())));
  const Vec3 dp(0.003, -0.002, 0.001), axis = Vec3(1, 2, 2) / 3.0;
  const Pose P1 = pose(P0.position + dp, Quaterniond(AngleAxisd(0.05, axis)) * P0.rotation);

  Mat6 K = Mat6::Zero();
  K.topLeftCorner<3, 3>() << 500, 50, 0, 50, 300, 20, 0, 20, 400;
  K.bottomRightCorner<3, 3>() << 2, 0.1, 0, 0.1, 1.5, 0, 0, 0, 1;
  K.topRightCorner<3, 3>() << 5, 0, 0, 0, -3, 0, 0, 0, 2;
  K.bottomLeftCorner<3, 3>() = K.topRightCorner<3, 3>().transpose();
  const Vec6 W0 = vec6(1, -0.5, 2, 0.05, 0.02, -0.1);
  const Pose ref = o.map.to_scene(P0);

  Vec6 d;
  d.head<3>() = Ro * (1.5 * dp);
  d.tail<3>() = Ro * (0.05 * axis);
  const Vec6 W = W0 - K * d;
  ASSERT_GT((K * d).head<3>().norm(), 0.5);
  auto to_device = [&](const Vec6& w) {
    Vec6 r;
    r.head<3>() = Ro.conjugate() * w.head<3>();
    r.tail<3>() = Ro.conjugate() * w.tail<3>();
    return r;
  };

  Rig rig(o);
  rig.dev.sample.pose = P1;
  rig.loop->publish(command(W0, ref, K));
  EXPECT_VEC_NEAR(rig.tick(0), to_device(W), 1e-10);
  rig.dev.sample.pose = P0;  // back at the reference: W0
  EXPECT_VEC_NEAR(rig.tick(1), to_device(W0), 1e-10);

  o.multirate = false;
  Rig hold(o);
  hold.dev.sample.pose = P1;
  hold.loop->publish(command(W0, ref, K));
  EXPECT_VEC_NEAR(hold.tick(0), to_device(W0), 1e-10);
}

// ---------------------------------------------------------------------------
// Clutch
// ---------------------------------------------------------------------------

// Held from 200 ms to 300 ms while the hand moves 1 cm and turns the handle
// 40 degrees about z: the target stays where it was, the output ramps to zero
// over watchdog_ramp (10 ms). On release the target is still there (no
// jump); moving on moves it by the map's new rotation (Rz(-40): the device's
// base is now turned against the scene) times the scale, and the output
// soft-starts again, rotated by Rz40 into the device's new frame.
TEST(DeviceLoop, ClutchFreezesTheTargetRampsOutAndReindexesOnRelease) {
  DeviceLoopOptions o;
  o.watchdog = 10.0;
  o.watchdog_ramp = 0.01;
  o.soft_start = 0.1;
  o.multirate = false;
  o.map.scale = 2.0;
  o.map.grasp = pose(Vec3(0, 0, 0.05), Quaterniond(AngleAxisd(deg(90), Vec3::UnitX())));
  Rig rig(o);
  const Vec6 W0 = vec6(1, 0.5, 0, 0, 0, 0.1);
  const Vec3 p0(0.01, 0, 0);
  rig.dev.sample.pose = pose(p0);
  auto expect_pose = [](const Pose& a, const Pose& b, const char* what, long i) {
    EXPECT_LE((a.position - b.position).cwiseAbs().maxCoeff(), 1e-12) << what << ", i = " << i;
    EXPECT_NEAR(std::abs(a.rotation.dot(b.rotation)), 1.0, 1e-12) << what << ", i = " << i;
  };

  for (long i = 0; i < 200; ++i) {
    rig.loop->publish(command(W0));
    rig.tick(i);
  }
  const Pose T0 = rig.target().target;
  EXPECT_VEC_NEAR(rig.dev.last, W0, 1e-12);

  for (long i = 200; i < 300; ++i) {
    rig.dev.sample.clutch = true;
    const double a = (i - 200) / 100.0;
    rig.dev.sample.pose = pose(p0 + a * Vec3(0.01, 0.01, 0), Quaterniond(AngleAxisd(deg(40) * a, Vec3::UnitZ())));
    rig.loop->publish(command(W0));
    const Vec6 out = rig.tick(i);
    const DeviceTarget t = rig.target();
    EXPECT_TRUE(t.clutched);
    expect_pose(t.target, T0, "target moved while clutched", i);
    EXPECT_VEC_NEAR(out, W0 * std::max(0.0, 1.0 - (i - 200) / 10.0), 1e-9) << "i = " << i;
  }

  const Quaterniond q2(AngleAxisd(deg(40), Vec3::UnitZ()));
  const Vec3 p2 = p0 + Vec3(0.01, 0.01, 0);
  for (long i = 300; i <= 420; ++i) {
    rig.dev.sample.clutch = false;
    const Vec3 dp2 = (i - 300) * Vec3(0, 1e-4, -0.5e-4);
    rig.dev.sample.pose = pose(p2 + dp2, q2);
    rig.loop->publish(command(W0));
    const Vec6 out = rig.tick(i);
    const DeviceTarget t = rig.target();
    EXPECT_FALSE(t.clutched);
    Pose want = T0;
    want.position += q2.conjugate() * (2.0 * dp2);
    expect_pose(t.target, want, "target after release", i);
    Vec6 w = W0;
    w.head<3>() = q2 * W0.head<3>();
    w.tail<3>() = q2 * W0.tail<3>();
    EXPECT_VEC_NEAR(out, w * std::min(1.0, (i - 300) / 100.0), 1e-9) << "i = " << i;
  }
}

// ---------------------------------------------------------------------------
// Torque policy, read failures, log
// ---------------------------------------------------------------------------

// A 3-DoF device (force only) gets the force and a zero torque; the same
// command on a 6-DoF device keeps its torque.
TEST(DeviceLoop, ThreeDofDeviceGetsTheForceOnly) {
  const Vec6 W0 = vec6(1, 2, 3, 0.3, -0.2, 0.1);
  DeviceInfo three;
  three.dof_actuated = 3;
  Rig rig(plain(), three);
  rig.loop->publish(command(W0));
  EXPECT_VEC_NEAR(rig.tick(0), vec6(1, 2, 3, 0, 0, 0), 1e-12);
  EXPECT_EQ(rig.dev.last.tail<3>(), Vec3::Zero());
  EXPECT_EQ(rig.loop->stats().torque_clamps, 0u);

  Rig six(plain());
  six.loop->publish(command(W0));
  EXPECT_VEC_NEAR(six.tick(0), W0, 1e-12);
}

// No pose yet: no target and no force, even with a command. A failed read
// or a pose with NaN holds the last good pose (the target does not move),
// and both are counted.
TEST(DeviceLoop, ReadFailuresHoldTheLastPose) {
  Rig rig(plain());
  rig.loop->publish(command(vec6(1, 0, 0, 0, 0, 0)));
  rig.dev.ok = false;
  EXPECT_EQ(rig.tick(0), Vec6::Zero());
  EXPECT_FALSE(rig.target().valid);
  rig.dev.ok = true;
  rig.dev.sample.pose = pose(Vec3(0.01, 0.02, 0.03));
  rig.tick(1);
  EXPECT_TRUE(rig.target().valid);
  EXPECT_EQ(rig.target().target.position, Vec3(0.01, 0.02, 0.03));
  rig.dev.sample.pose = pose(Vec3(0.5, 0.5, 0.5));
  rig.dev.ok = false;
  rig.tick(2);
  EXPECT_EQ(rig.target().target.position, Vec3(0.01, 0.02, 0.03));
  rig.dev.ok = true;
  rig.dev.sample.pose.position.x() = std::numeric_limits<double>::quiet_NaN();
  rig.tick(3);
  EXPECT_EQ(rig.target().target.position, Vec3(0.01, 0.02, 0.03));
  EXPECT_EQ(rig.loop->stats().read_failures, 3u);
  rig.dev.sample.pose = pose(Vec3(0.02, 0, 0));
  rig.tick(4);
  EXPECT_EQ(rig.target().target.position, Vec3(0.02, 0, 0));
}

// The log keeps log_capacity rows (time, target, written wrench) and
// counts the ticks beyond.
TEST(DeviceLoop, LogKeepsItsCapacityAndCountsTheRest) {
  DeviceLoopOptions o = plain();
  o.log_capacity = 5;
  Rig rig(o);
  rig.dev.sample.pose = pose(Vec3(0, 0, 0.1));
  for (long i = 0; i < 8; ++i) {
    rig.loop->publish(command(vec6(0.1 * i, 0, 0, 0, 0, 0)));
    rig.tick(i);
  }
  ASSERT_EQ(rig.loop->log_size(), 5u);
  EXPECT_EQ(rig.loop->stats().log_overflow, 3u);
  for (size_t k = 0; k < 5; ++k) {
    const hrt::DeviceLogRow& r = rig.loop->log()[k];
    EXPECT_DOUBLE_EQ(r.t, k * 1e-3);
    EXPECT_EQ(r.target.position, Vec3(0, 0, 0.1));
    EXPECT_VEC_NEAR(r.output, rig.dev.written[k], 0.0);
  }
}

// ---------------------------------------------------------------------------
// No allocation in tick()
// ---------------------------------------------------------------------------

// 1000 ticks after a warm-up through every branch (moving pose, clutch
// presses and releases, read failures, NaN commands, a watchdog stall and
// recovery, the log) allocate nothing. The hrt_tests binary's global
// operator new is replaced by a counting one (tests/synthetic.cpp; it counts
// every thread, and this test runs no other); the counter is checked to see
// an allocation first, so the test cannot pass by counting nothing.
TEST(DeviceLoop, TickAllocatesNothing) {
  const uint64_t before = hrt::synth::allocation_count();
  static void* volatile sink;  // volatile: the compiler may not elide this allocation
  sink = ::operator new(64);
  ::operator delete(sink);
  ASSERT_GT(hrt::synth::allocation_count(), before) << "the replaced operator new does not count";

  DeviceLoopOptions o;
  o.log_capacity = 2000;
  o.soft_start = 0.05;
  Rig rig(o);
  Mat6 K = 200.0 * Mat6::Identity();
  const DeviceCommand good = command(vec6(2, 0, 1, 0.1, 0, 0), Pose{}, K);
  DeviceCommand bad = good;
  bad.wrench[2] = std::numeric_limits<double>::quiet_NaN();
  DeviceTarget t;
  auto period = [&](long i) {
    const double a = 1e-3 * static_cast<double>(i);
    rig.dev.sample.pose =
        pose(0.01 * Vec3(std::sin(a), std::cos(a), 0), Quaterniond(AngleAxisd(0.3 * a, Vec3::UnitZ())));
    rig.dev.sample.clutch = (i / 150) % 3 == 2;
    rig.dev.ok = i % 97 != 5;
    const bool stalled = i >= 600 && i < 720;
    if (!stalled && i % 7 == 0) rig.loop->publish(i % 50 == 0 ? bad : good);
    rig.tick(i);
    rig.loop->target(t);
  };
  for (long i = 0; i < 200; ++i) period(i);
  const uint64_t start = hrt::synth::allocation_count();
  for (long i = 200; i < 1200; ++i) period(i);
  EXPECT_EQ(hrt::synth::allocation_count() - start, 0u);
  const hrt::DeviceLoopStats& st = rig.loop->stats();
  EXPECT_GT(st.non_finite, 0u);
  EXPECT_GT(st.read_failures, 0u);
  EXPECT_GT(st.watchdog_events, 0u);
  EXPECT_EQ(rig.loop->log_size(), 1200u);
}

// ---------------------------------------------------------------------------
// TripleBuffer
// ---------------------------------------------------------------------------

// A writer publishes 1e6 structs whose 16 fields all equal a counter; the
// reader checks every front() it sees: all fields equal (no torn read) and
// never smaller than the last one, and it ends on the last value (nothing is
// lost at the end).
TEST(TripleBuffer, TwoThreadsSeeConsistentNonDecreasingValues) {
  struct Payload {
    std::array<uint64_t, 16> v{};
  };
  hrt::TripleBuffer<Payload> tb;
  constexpr uint64_t N = 1000000;
  std::atomic<bool> done{false};
  std::thread writer([&] {
    for (uint64_t i = 1; i <= N; ++i) {
      tb.back().v.fill(i);
      tb.publish();
    }
    done.store(true);
  });
  uint64_t last = 0, updates = 0, torn = 0, backwards = 0;
  for (;;) {
    // Read `done` first: once it is true every publish happened before, so
    // an update() that then finds nothing new means all were seen.
    const bool finished = done.load();
    if (tb.update()) {
      ++updates;
      const Payload& f = tb.front();
      const uint64_t x = f.v[0];
      for (uint64_t e : f.v) torn += e != x;
      torn += f.v[0] != x;  // still the same after the scan
      backwards += x < last;
      last = x;
    } else if (finished) {
      break;
    }
  }
  writer.join();
  EXPECT_EQ(torn, 0u);
  EXPECT_EQ(backwards, 0u);
  EXPECT_EQ(last, N);
  EXPECT_GE(updates, 1u);
}

// ---------------------------------------------------------------------------
// Thread mode
// ---------------------------------------------------------------------------

// The real thing on SteadyClock: ~200 ms at 1 kHz. The tick count is a
// sanity range (100..300: it runs at about the period, not a speed
// assertion on a shared 2-core machine); stop() ramps the output down and
// the last wrench written is exactly zero, one write after the last tick;
// period_error has one entry per tick.
TEST(DeviceLoop, ThreadModeRunsAtAboutThePeriodAndStopsAtZero) {
  TestDevice dev;
  hrt::SteadyClock clock;
  DeviceLoopOptions o;
  o.soft_start = 0.02;
  DeviceLoop loop(dev, o, clock);
  loop.start();
  EXPECT_TRUE(loop.running());
  const auto t0 = std::chrono::steady_clock::now();
  while (std::chrono::steady_clock::now() - t0 < std::chrono::milliseconds(200)) {
    loop.publish(command(vec6(1, 0, 0, 0, 0, 0)));
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  loop.stop();
  EXPECT_FALSE(loop.running());
  const hrt::DeviceLoopStats& st = loop.stats();
  EXPECT_GE(st.ticks, 100u);
  EXPECT_LE(st.ticks, 300u);
  EXPECT_EQ(dev.last, Vec6::Zero());
  EXPECT_EQ(dev.writes, st.ticks + 1);
  EXPECT_EQ(st.period_error.size(), st.ticks);
  double peak = 0;
  for (const Vec6& w : dev.written) peak = std::max(peak, w.norm());
  EXPECT_GT(peak, 0.5) << "the output never came up, so 'zero at the end' says nothing";
  // The stop ramp is counted in ticks (watchdog_ramp / period = 10 of them),
  // so whatever the scheduler did, the last writes (the ramp and the final
  // zero) step by at most 1 N / 10 (the rate limit alone would allow 1 N).
  ASSERT_GE(dev.written.size(), 12u);
  for (size_t k = dev.written.size() - 11; k < dev.written.size(); ++k)
    EXPECT_LE((dev.written[k] - dev.written[k - 1]).norm(), 0.1 + 1e-9)
        << "write " << k << " of " << dev.written.size();
  const hrt::JitterSummary j = hrt::summarize_jitter(st);
  EXPECT_EQ(j.samples, st.ticks);
  EXPECT_LE(j.p50, j.p99);
  EXPECT_LE(j.p99, j.max);
}

// p50 and p99 interpolate between order statistics, max is the largest.
TEST(DeviceLoop, JitterSummaryPercentiles) {
  hrt::DeviceLoopStats st;
  EXPECT_EQ(hrt::summarize_jitter(st).samples, 0u);
  st.period_error = {5e-6, 1e-6, 3e-6, 2e-6, 4e-6};
  const hrt::JitterSummary j = hrt::summarize_jitter(st);
  EXPECT_EQ(j.samples, 5u);
  EXPECT_DOUBLE_EQ(j.p50, 3e-6);
  EXPECT_NEAR(j.p99, 4.96e-6, 1e-18);  // 4e-6 + 0.96 (5e-6 - 4e-6), to rounding (1 ulp ~ 1e-21)
  EXPECT_DOUBLE_EQ(j.max, 5e-6);
}

// ---------------------------------------------------------------------------
// The output bound: |F| <= envelope x max_force, |T| <= envelope x max_torque
// at every tick, whatever the command, and never above by rounding
// ---------------------------------------------------------------------------

namespace {

// The largest of the norms a reader may compute: the plain sum of squares in
// two orders, hypot, and Eigen's stable norm.
double worst_norm(const Vec3& v) {
  const double a = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  const double b = std::sqrt(v[2] * v[2] + v[1] * v[1] + v[0] * v[0]);
  const double c = std::hypot(v[0], std::hypot(v[1], v[2]));
  return std::max({a, b, c, v.norm(), v.stableNorm()});
}

}  // namespace

// A command 25 times the force limit and 20 times the torque limit, turning
// every tick: during the soft start (0.5 s) the output is at most s(t) x the
// limit, s(t) = (t - t0) / 0.5 from the first command at t0 = 20 ms, and it
// rides that bound (the rate limit, 1 N per tick, is above the ramp's slope
// of 8 mN per tick). The same after a watchdog stall and its recovery (the
// ramp restarts from the level it left), and down the watchdog ramp, where
// the rate limit would let the output fall slower than the bound.
// The stall scenario of the two envelope tests below (1 ms ticks i): commands
// far above a 4 N / 0.05 N m limit turning slowly (a = 0.01 i), published from
// 20 ms on except from 0.9 to 1.1 s (a stall); a soft start of 0.5 s, a
// 50 ms watchdog ramping out over 10 ms. stall_envelope is the bound's factor
// at tick i (level: the factor the stall left, updated at tick 1099).
bool stall_publishing(long i) { return i >= 20 && (i < 900 || i >= 1100); }
DeviceCommand stall_command(double a) {
  return command(vec6(100 * std::cos(a), 100 * std::sin(a), -30, std::sin(a), 0.2, std::cos(a)));
}
double stall_envelope(long i, double& level) {
  const double t = static_cast<double>(i) * 1e-3;
  if (i < 20) return 0;
  if (i < 900 + 50) return std::clamp((t - 0.02) / 0.5, 0.0, 1.0);  // soft start, held until the watchdog
  if (i < 1100) {  // last command at 899 ms: stalled at 949 ms, ramped out by 959 ms
    const double e = std::clamp(1.0 - (t - 0.899 - 0.05) / 0.01, 0.0, 1.0);
    if (i == 1099) level = e;
    return e;
  }
  return std::clamp((t - 1.1) / 0.5 + level, 0.0, 1.0);  // recovery from the level it had: a soft start
}

TEST(DeviceLoop, OutputNeverExceedsTheEnvelopeTimesTheLimit) {
  DeviceLoopOptions o;
  o.soft_start = 0.5;
  o.watchdog = 0.05;
  o.watchdog_ramp = 0.01;
  o.multirate = false;
  DeviceInfo info;
  info.max_force = 4.0;
  info.max_torque = 0.05;
  Rig rig(o, info);
  double worst_f = -1, worst_t = -1;  // largest |F| - bound, |T| - bound
  double level_at_stall = 0;
  for (long i = 0; i <= 2000; ++i) {
    const double a = 0.01 * static_cast<double>(i);  // turning slowly enough for the rate limit
    if (stall_publishing(i)) rig.loop->publish(stall_command(a));
    const Vec6 out = rig.tick(i);
    const double t = static_cast<double>(i) * 1e-3;
    const double envelope = stall_envelope(i, level_at_stall);
    worst_f = std::max(worst_f, worst_norm(out.head<3>()) - envelope * 4.0 * (1 + 1e-12));
    worst_t = std::max(worst_t, worst_norm(out.tail<3>()) - envelope * 0.05 * (1 + 1e-12));
    EXPECT_LE(worst_norm(out.head<3>()), envelope * 4.0 * (1 + 1e-12)) << "i = " << i;
    EXPECT_LE(worst_norm(out.tail<3>()), envelope * 0.05 * (1 + 1e-12)) << "i = " << i;
    // Not vacuous: the output rides the bound once the rate limit has caught up.
    if (i >= 40 && i < 900) EXPECT_GT(out.head<3>().norm(), envelope * 4.0 * 0.999) << "i = " << i;
  }
  EXPECT_GE(rig.loop->stats().watchdog_events, 1u);
  // The ramps are evaluated from session times i * 1e-3, whose differences
  // carry ~1e-16 s of rounding: 1e-12 of the limit covers them.
  EXPECT_LE(worst_f, 0.0);
  EXPECT_LE(worst_t, 0.0);
}

// The same envelope with the virtual device (the viewer's handle) moved on
// every tick, as a mouse drag does, and the simulation stalling from 0.9 to
// 1.1 s: soft start, clamp, watchdog ramp and recovery bound every wrench it
// is given, and the target follows the handle through the workspace map.
TEST(DeviceLoop, AVirtualDeviceDraggedEveryTickGetsTheSameBounds) {
  DeviceLoopOptions o;
  o.soft_start = 0.5;
  o.watchdog = 0.05;
  o.watchdog_ramp = 0.01;
  o.multirate = false;
  o.map.scale = 1.5;
  o.map.offset = pose(Vec3(0.01, 0.0, -0.02), Quaterniond(AngleAxisd(deg(20), Vec3::UnitZ())));
  DeviceInfo info;
  info.max_force = 4.0;
  info.max_torque = 0.05;
  hrt::VirtualDevice dev(Pose{}, info);
  hrt::ManualClock clock;
  DeviceLoop loop(dev, o, clock, 4096);
  double level_at_stall = 0;
  for (long i = 0; i <= 2000; ++i) {
    const double a = 0.01 * static_cast<double>(i);
    const Pose handle = pose(Vec3(0.02 * std::sin(a), 0.01 * std::cos(a), 0.001 * i * 1e-3),
                             Quaterniond(AngleAxisd(0.3 * std::sin(a), Vec3(0.3, 0.4, 0.5).normalized())));
    ASSERT_TRUE(dev.set_pose(handle));
    if (stall_publishing(i)) loop.publish(stall_command(a));
    clock.set(static_cast<double>(i) * 1e-3);
    loop.tick();
    const Vec6 out = dev.last_wrench();
    const double t = static_cast<double>(i) * 1e-3;
    const double envelope = stall_envelope(i, level_at_stall);
    ASSERT_LE(worst_norm(out.head<3>()), envelope * 4.0 * (1 + 1e-12)) << "i = " << i;
    ASSERT_LE(worst_norm(out.tail<3>()), envelope * 0.05 * (1 + 1e-12)) << "i = " << i;
    if (i >= 40 && i < 900) EXPECT_GT(out.head<3>().norm(), envelope * 4.0 * 0.999) << "i = " << i;
    DeviceTarget tg;
    ASSERT_TRUE(loop.target(tg));
    const Pose want = o.map.to_scene(handle);
    EXPECT_LE((tg.target.position - want.position).norm(), 1e-15) << "i = " << i;
  }
  EXPECT_GE(loop.stats().watchdog_events, 1u);
}

// 20,000 commands far above a 5 N limit, in directions spread over the
// sphere and with magnitudes from 5 N to 1e6 N: every written force's norm,
// computed in every way a reader might, is <= 5 exactly (no 1-ulp overshoot).
TEST(DeviceLoop, TheClampNeverExceedsTheLimitByRounding) {
  DeviceLoopOptions o = plain();
  DeviceInfo info;
  info.max_force = 5.0;
  info.max_torque = 0.3;
  Rig rig(o, info);
  uint64_t state = 12345;
  auto uniform = [&state]() {  // xorshift64*: reproducible, no <random> distribution differences
    state ^= state >> 12, state ^= state << 25, state ^= state >> 27;
    return static_cast<double>((state * 2685821657736338717ull) >> 11) * 0x1.0p-53;
  };
  double worst_f = 0, worst_t = 0;
  long clamped = 0;
  for (long i = 0; i < 20000; ++i) {
    const double z = 2 * uniform() - 1, phi = 2 * kPi * uniform(), r = std::sqrt(1 - z * z);
    const double mag = 5.0 * std::pow(2e5, uniform());
    const Vec3 d(r * std::cos(phi), r * std::sin(phi), z);
    rig.loop->publish(
        command(vec6(mag * d[0], mag * d[1], mag * d[2], 0.3 * mag * d[1], 0.3 * mag * d[2], 0.3 * mag * d[0])));
    const Vec6 out = rig.tick(i);
    worst_f = std::max(worst_f, worst_norm(out.head<3>()));
    worst_t = std::max(worst_t, worst_norm(out.tail<3>()));
    clamped += out.head<3>().norm() > 4.999 ? 1 : 0;
  }
  EXPECT_LE(worst_f, 5.0);
  EXPECT_LE(worst_t, 0.3);
  EXPECT_GT(clamped, 19000);
}
