// The 1 kHz device force loop: see hrt/device_loop.h (the spec is there).
//
// Everything the device thread touches is allocated in the constructor:
// Internal holds the loop's state in fixed-size members, the log and
// period_error are sized up front, and tick() only does fixed-size Eigen
// arithmetic (no heap temporaries), std::nth_element on a std::array and
// the two TripleBuffers.
#include "hrt/device_loop.h"
#include "hrt/dynamics.h"

#include <pthread.h>
#include <sys/prctl.h>
#include <sched.h>
#include <time.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <limits>

namespace hrt {

namespace {

// 1 -> 0 linearly over T from x = 0 (T <= 0: a step at x > 0).
double ramp_down(double x, double T) {
  if (!(T > 0)) return x > 0 ? 0.0 : 1.0;
  return std::clamp(1.0 - x / T, 0.0, 1.0);
}
// 0 -> 1 linearly over T from x = 0 (T <= 0: 1 from x = 0 on).
double ramp_up(double x, double T) {
  if (!(T > 0)) return x >= 0 ? 1.0 : 0.0;
  return std::clamp(x / T, 0.0, 1.0);
}

bool usable_rotation(const Eigen::Quaterniond& q) { return q.coeffs().allFinite() && q.coeffs().squaredNorm() > 1e-12; }
bool finite_pose(const Pose& p) { return p.position.allFinite() && usable_rotation(p.rotation); }

bool finite_command(const DeviceCommand& c) {
  return std::isfinite(c.time) && finite_pose(c.target_ref) && c.wrench.allFinite() && c.stiffness.allFinite();
}

// A device limit that is not a positive finite number displays nothing.
double limit(double v) { return std::isfinite(v) && v > 0 ? v : 0.0; }

// The norm without overflow: a finite 1e300 component must be scaled down
// to the limit along its direction, not squared into inf (which would zero
// the output by max / inf).
double safe_norm(const Vec3& v) {
  const double m = v.cwiseAbs().maxCoeff();
  if (!(m > 0)) return 0.0;
  return m * (v / m).norm();
}

// The norm a clamp aims at: `max` less 8 units in the last place. Scaling
// by max / n rounds, and a reader computing the norm in another order (the
// trace's numpy, a device SDK) rounds again, each by a few ulp: a vector
// clamped to exactly `max` could read 5.000000000000001 N against 5 N. With
// the margin every norm computed in double within 4 ulp of the true one is
// <= max. A relative 1.8e-15 is far below anything a device displays.
double clamp_target(double max) { return max * (1.0 - 8.0 * std::numeric_limits<double>::epsilon()); }

// Scales v to norm at most clamp_target(max); true when it did. Checked
// again after the scaling, with both the overflow-safe and the plain norm,
// and shrunk further until both hold (at most a few passes).
bool clamp_norm(Eigen::Ref<Vec3> v, double max) {
  const double target = clamp_target(max);
  const double n = safe_norm(v);
  if (!(n > target)) return false;
  if (!(target > 0)) {
    v.setZero();  // max == 0 (or a limit that is not a positive number): exactly zero
    return true;
  }
  v *= target / n;
  for (int pass = 0; pass < 8 && (safe_norm(v) > target || v.norm() > target); ++pass)
    v *= 1.0 - 4.0 * std::numeric_limits<double>::epsilon();
  return true;
}

// Moves `v` towards its new value by at most `step` from `prev`; true when it bit.
bool rate_limit(Eigen::Ref<Vec3> v, const Vec3& prev, double step) {
  const Vec3 d = v - prev;
  const double n = safe_norm(d);
  if (!(n > step)) return false;
  v = prev + d * (step / n);
  return true;
}

constexpr int64_t kNs = 1000000000;
int64_t to_ns(const timespec& t) { return static_cast<int64_t>(t.tv_sec) * kNs + t.tv_nsec; }
timespec from_ns(int64_t ns) {
  timespec t;
  t.tv_sec = static_cast<time_t>(ns / kNs);
  t.tv_nsec = static_cast<long>(ns % kNs);
  return t;
}
int64_t monotonic_ns() {
  timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return to_ns(t);
}

}  // namespace

double SteadyClock::now() const noexcept { return static_cast<double>(monotonic_ns()) * 1e-9; }

// ---------------------------------------------------------------------------
// WorkspaceMap
// ---------------------------------------------------------------------------
Pose WorkspaceMap::to_device(const Pose& target) const {
  // handle = target * grasp, then undo the offset and the scale.
  const Eigen::Quaterniond R = offset.rotation.normalized();
  const Eigen::Quaterniond q_target = target.rotation.normalized();
  const Eigen::Quaterniond q_handle = (q_target * grasp.rotation.normalized()).normalized();
  const Vec3 p_handle = target.position + q_target * grasp.position;
  Pose d;
  d.rotation = (R.conjugate() * q_handle).normalized();
  d.position = (R.conjugate() * (p_handle - offset.position)) / scale;
  return d;
}

Pose WorkspaceMap::to_scene(const Pose& device) const {
  const Eigen::Quaterniond R = offset.rotation.normalized();
  // Devices report quaternions that drift off unit length by rounding; the
  // target must be a rotation.
  const Eigen::Quaterniond q_handle = (R * device.rotation.normalized()).normalized();
  const Vec3 p_handle = R * (scale * device.position) + offset.position;
  // target = handle * grasp^-1
  const Eigen::Quaterniond qg = grasp.rotation.normalized();
  Pose t;
  t.rotation = (q_handle * qg.conjugate()).normalized();
  t.position = p_handle - t.rotation * grasp.position;
  return t;
}

Vec6 WorkspaceMap::wrench_to_device(const Vec6& scene) const {
  const Eigen::Quaterniond Rinv = offset.rotation.normalized().conjugate();
  Vec6 w;
  w.head<3>() = Rinv * scene.head<3>().eval();
  w.tail<3>() = Rinv * scene.tail<3>().eval();
  return w;
}

// ---------------------------------------------------------------------------
// DeviceLoop state
// ---------------------------------------------------------------------------
struct DeviceLoop::Internal {
  WorkspaceMap map;  // live map (the clutch re-indexes its offset)

  // Device.
  DeviceSample sample;  // last good sample
  bool have_pose = false;
  bool clutched = false;
  double t_clutch = 0.0;  // press time
  Pose frozen;            // target while clutched

  // Command.
  DeviceCommand cmd;  // last accepted command (rotations normalized)
  bool have_cmd = false;
  double t_pub = 0.0;      // when it was accepted (device clock)
  double t_soft = 0.0;     // soft start origin
  double watchdog = 0.05;  // current watchdog time, s
  bool stalled = false;    // a stall was detected since the last command

  // Publication periods for the default watchdog: a ring of the last 64.
  static constexpr size_t kPeriods = 64;
  std::array<double, kPeriods> periods{};
  size_t n_periods = 0, next_period = 0;

  // Output.
  Vec6 output = Vec6::Zero();  // last written (device frame)

  // Stop (thread mode): requested by stop(), seen by the device thread.
  std::atomic<bool> stop_request{false};
  bool stopping = false;
  uint64_t stop_ticks = 0;  // ticks since the stop was seen

  void push_period(double p) {
    periods[next_period] = p;
    next_period = (next_period + 1) % kPeriods;
    n_periods = std::min(n_periods + 1, kPeriods);
  }
  double median_period() const {
    if (n_periods == 0) return 0.0;
    std::array<double, kPeriods> tmp;
    std::copy(periods.begin(), periods.begin() + static_cast<std::ptrdiff_t>(n_periods), tmp.begin());
    const auto first = tmp.begin(), last = tmp.begin() + static_cast<std::ptrdiff_t>(n_periods);
    const auto mid = first + static_cast<std::ptrdiff_t>(n_periods / 2);
    std::nth_element(first, mid, last);
    if (n_periods % 2 == 1) return *mid;
    return 0.5 * (*mid + *std::max_element(first, mid));
  }

  double soft(double t, double soft_start) const { return ramp_up(t - t_soft, soft_start); }
  double watchdog_ramp(double t, double ramp) const { return ramp_down(t - t_pub - watchdog, ramp); }

  // Re-index on clutch release: choose the offset so that the map takes the
  // device pose `dev` to `target` (handle = target * grasp; offset rotation
  // R = q_handle q_dev^-1, offset position = p_handle - R (s p_dev)).
  void reindex(const Pose& dev, const Pose& target) {
    const Eigen::Quaterniond qg = map.grasp.rotation.normalized();
    const Eigen::Quaterniond q_handle = target.rotation * qg;
    const Vec3 p_handle = target.position + target.rotation * map.grasp.position;
    map.offset.rotation = (q_handle * dev.rotation.conjugate()).normalized();
    map.offset.position = p_handle - map.offset.rotation * (map.scale * dev.position);
  }

  static void thread_main(DeviceLoop& self);
};

DeviceLoop::DeviceLoop(Device& device, const DeviceLoopOptions& options, const Clock& clock, size_t max_ticks_recorded)
    : device_(device), options_(options), clock_(clock), in_(std::make_unique<Internal>()) {
  in_->map = options_.map;
  in_->watchdog = options_.watchdog >= 0 ? options_.watchdog : 0.05;
  // resize then clear: the capacity stays and its pages are touched now,
  // so the device thread takes no page faults on them either.
  stats_.period_error.resize(max_ticks_recorded);
  stats_.period_error.clear();
  log_.resize(options_.log_capacity);
}

DeviceLoop::~DeviceLoop() {
  if (thread_.joinable()) stop();
}

void DeviceLoop::publish(const DeviceCommand& command) noexcept {
  commands_.back() = command;
  commands_.publish();
}

bool DeviceLoop::target(DeviceTarget& out) noexcept {
  targets_.update();
  out = targets_.front();
  return out.valid;
}

void DeviceLoop::tick() noexcept {
  Internal& s = *in_;
  const DeviceLoopOptions& o = options_;
  const DeviceInfo& info = device_.info();
  const double t = clock_.now();

  // 1. The device pose: hold the last good one.
  {
    DeviceSample sample;
    if (device_.read(t, sample) && finite_pose(sample.pose)) {
      sample.pose.rotation.normalize();
      s.sample = sample;
      s.have_pose = true;
    } else {
      ++stats_.read_failures;
    }
  }

  // 2. Clutch.
  double clutch_ramp = 1.0;
  if (s.have_pose && s.sample.clutch) {
    if (!s.clutched) {
      s.clutched = true;
      s.t_clutch = t;
      s.frozen = s.map.to_scene(s.sample.pose);
    }
    clutch_ramp = ramp_down(t - s.t_clutch, o.watchdog_ramp);
  } else if (s.clutched) {
    // The level the output has now (soft start x clutch ramp at t) is where
    // the new soft start begins, so a short tap of the clutch does not step.
    const double level = s.soft(t, o.soft_start) * ramp_down(t - s.t_clutch, o.watchdog_ramp);
    s.clutched = false;
    s.reindex(s.sample.pose, s.frozen);
    if (s.have_cmd) s.t_soft = t - level * o.soft_start;
  }

  // 3. The probe's target in the scene.
  const Pose target = s.clutched ? s.frozen : (s.have_pose ? s.map.to_scene(s.sample.pose) : Pose{});

  // 4. Publish it to the simulation.
  {
    DeviceTarget& out = targets_.back();
    out.time = t;
    out.tick = stats_.ticks;
    out.device = s.sample.pose;
    out.target = target;
    out.clutched = s.clutched;
    out.valid = s.have_pose;
    out.output = s.output;
    targets_.publish();
  }

  // 5. The latest command. The watchdog is checked first, on the state
  // before this tick's command, so a stall that ends in this very tick is
  // still counted and the recovery starts from the output's level.
  if (s.have_cmd && !s.stalled && t - s.t_pub > s.watchdog) {
    s.stalled = true;
    ++stats_.watchdog_events;
  }
  if (commands_.update()) {
    ++stats_.commands;
    const DeviceCommand& c = commands_.front();
    if (!c.valid) {
      // Nothing computed yet on the simulation side: keep what we have.
    } else if (!finite_command(c)) {
      ++stats_.non_finite;
    } else {
      const double level = s.have_cmd ? s.soft(t, o.soft_start) * s.watchdog_ramp(t, o.watchdog_ramp) : 0.0;
      if (s.have_cmd) s.push_period(t - s.t_pub);
      if (!s.have_cmd)
        s.t_soft = t;  // first command: soft start from zero
      else if (s.stalled)
        s.t_soft = t - level * o.soft_start;  // recovery: back in from where the ramp left it
      s.cmd = c;
      s.cmd.target_ref.rotation.normalize();
      s.have_cmd = true;
      s.stalled = false;
      s.t_pub = t;
      s.watchdog = o.watchdog >= 0 ? o.watchdog : std::max(0.05, 5.0 * s.median_period());
    }
  }

  // Stop ramp (thread mode), counted in periods so it ends whatever the clock.
  double stop_ramp = 1.0;
  if (s.stop_request.load(std::memory_order_acquire)) {
    if (!s.stopping) {
      s.stopping = true;
      s.stop_ticks = 0;
    }
    stop_ramp = ramp_down(static_cast<double>(s.stop_ticks) * o.period, o.watchdog_ramp);
    ++s.stop_ticks;
  }

  // 6. The wrench in the scene: W0 - K_eff d (multirate) or W0 (hold).
  Vec6 w = Vec6::Zero();
  if (s.have_cmd && s.have_pose) {
    w = s.cmd.wrench;
    if (o.multirate) {
      Vec6 d;
      d.head<3>() = target.position - s.cmd.target_ref.position;
      d.tail<3>() = rotation_vector(target.rotation * s.cmd.target_ref.rotation.conjugate());
      w.noalias() -= s.cmd.stiffness * d;
    }
  }
  // The envelope: the product of the ramps, in [0, 1]. It scales the
  // device's limits, not the command: a probe that starts 10 mm inside asks
  // for far more than the limit, and scaling that request first would let
  // the output reach ramp x request (clamped only at the full limit) instead
  // of ramp x limit.
  const double envelope =
      (s.have_cmd && s.have_pose)
          ? std::clamp(s.soft(t, o.soft_start) * s.watchdog_ramp(t, o.watchdog_ramp) * clutch_ramp * stop_ramp, 0.0,
                       1.0)
          : 0.0;

  // 7. Into the device frame; torque policy.
  Vec6 out = s.map.wrench_to_device(w);
  if (info.dof_actuated < 6) out.tail<3>().setZero();

  // 8. NaN guard: a non-finite output (an overflow of K_eff d, say) is never
  // sent; the previous output, already safe, is kept (and bounded again
  // below by this tick's envelope).
  if (!out.allFinite()) {
    ++stats_.non_finite;
    out = s.output;
  }

  // 9. Clamp to the device's limits (norms, direction kept), then ramp: the
  // output is at most envelope x limit whatever the simulation asked.
  const double max_force = limit(info.max_force), max_torque = limit(info.max_torque);
  if (clamp_norm(out.head<3>(), max_force)) ++stats_.force_clamps;
  if (clamp_norm(out.tail<3>(), max_torque)) ++stats_.torque_clamps;
  out *= envelope;

  // 10. Rate limit (per tick; full force in ten periods by default).
  const double force_rate = o.max_force_rate >= 0 ? o.max_force_rate : max_force / 0.01;
  const double torque_rate = o.max_torque_rate >= 0 ? o.max_torque_rate : max_torque / 0.01;
  const bool limited_f = rate_limit(out.head<3>(), s.output.head<3>(), force_rate * o.period);
  const bool limited_t = rate_limit(out.tail<3>(), s.output.tail<3>(), torque_rate * o.period);
  if (limited_f || limited_t) ++stats_.rate_limited;

  // 11. The hard bound, last: |F| <= envelope x max_force and |T| <=
  // envelope x max_torque at every tick. The rate limit starts from the
  // previous output, which may be above this tick's bound while a ramp goes
  // down (watchdog, clutch, stop); the bound wins over the rate limit.
  clamp_norm(out.head<3>(), envelope * max_force);
  clamp_norm(out.tail<3>(), envelope * max_torque);

  // 12. Write, log, count.
  device_.write(t, out);
  s.output = out;
  if (log_size_ < log_.size()) {
    DeviceLogRow& row = log_[log_size_++];
    row.t = t;
    row.target = target;
    row.output = out;
  } else if (o.log_capacity > 0) {
    ++stats_.log_overflow;
  }
  ++stats_.ticks;
}

// ---------------------------------------------------------------------------
// Thread mode
// ---------------------------------------------------------------------------
void DeviceLoop::Internal::thread_main(DeviceLoop& self) {
  Internal& s = *self.in_;
  DeviceLoopStats& st = self.stats_;
  // Timer slack: a normal thread's sleeps may end up to 50 us late by
  // default (the kernel groups wake-ups); the device thread asks for 1 ns.
  // (SCHED_FIFO threads have none.)
  prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
  if (self.options_.realtime) {
    sched_param sp{};
    sp.sched_priority = self.options_.realtime_priority;
    st.realtime = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp) == 0;
  }
  const int64_t period_ns = std::max<int64_t>(1, std::llround(self.options_.period * 1e9));
  // The ramp is over after watchdog_ramp / period ticks; the rate limit may
  // need a little longer to reach zero. Give up waiting after a further
  // second (a zero rate limit would never get there); zero is written anyway.
  const double ticks_per_s = 1.0 / std::max(self.options_.period, 1e-9);
  const uint64_t max_stop_ticks =
      static_cast<uint64_t>(std::ceil((std::max(self.options_.watchdog_ramp, 0.0) + 1.0) * ticks_per_s)) + 1;
  const size_t capacity = st.period_error.capacity();

  int64_t deadline = monotonic_ns() + period_ns;
  for (;;) {
    const timespec ts = from_ns(deadline);
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
    const int64_t now = monotonic_ns();
    if (st.period_error.size() < capacity)  // within the reserve: never reallocates
      st.period_error.push_back(static_cast<double>(std::llabs(now - deadline)) * 1e-9);
    self.tick();
    if (s.stopping) {
      const bool ramped = static_cast<double>(s.stop_ticks) * self.options_.period >= self.options_.watchdog_ramp;
      if ((ramped && (s.output.array() == 0.0).all()) || s.stop_ticks >= max_stop_ticks) break;
    }
    deadline += period_ns;
    if (deadline <= now) {
      // Overran a whole period: the periods in between are missed (counted),
      // and the grid restarts from now.
      st.missed_deadlines += static_cast<uint64_t>((now - deadline) / period_ns) + 1;
      deadline = now + period_ns;
    }
  }

  // Zero, whatever the ramp and the rate limit left.
  const double t = self.clock_.now();
  s.output.setZero();
  self.device_.write(t, s.output);
  DeviceTarget& out = self.targets_.back();
  out = DeviceTarget{};
  out.time = t;
  out.tick = st.ticks;
  out.device = s.sample.pose;
  out.target = s.clutched ? s.frozen : (s.have_pose ? s.map.to_scene(s.sample.pose) : Pose{});
  out.clutched = s.clutched;
  out.valid = s.have_pose;
  self.targets_.publish();
}

void DeviceLoop::start() {
  if (thread_.joinable()) return;
  Internal& s = *in_;
  s.stop_request.store(false, std::memory_order_release);
  s.stopping = false;
  s.stop_ticks = 0;
  // After an earlier stop the output is zero: come back in softly.
  if (s.have_cmd) s.t_soft = clock_.now();
  running_.store(true);
  thread_ = std::thread([this] { Internal::thread_main(*this); });
}

void DeviceLoop::stop() {
  Internal& s = *in_;
  if (thread_.joinable()) {
    s.stop_request.store(true, std::memory_order_release);
    thread_.join();
    s.stop_request.store(false, std::memory_order_release);
    s.stopping = false;
    running_.store(false);
  } else {
    // Lockstep: no thread to ramp with; zero now.
    s.output.setZero();
    device_.write(clock_.now(), s.output);
  }
  if (s.have_cmd) s.t_soft = clock_.now();
}

JitterSummary summarize_jitter(const DeviceLoopStats& stats) {
  JitterSummary j;
  std::vector<double> v(stats.period_error);
  j.samples = v.size();
  if (v.empty()) return j;
  std::sort(v.begin(), v.end());
  const auto at = [&v](double q) {
    const double x = q * static_cast<double>(v.size() - 1);
    const size_t i = static_cast<size_t>(std::floor(x));
    if (i + 1 >= v.size()) return v.back();
    return v[i] + (x - static_cast<double>(i)) * (v[i + 1] - v[i]);
  };
  j.p50 = at(0.50);
  j.p99 = at(0.99);
  j.max = v.back();
  return j;
}

}  // namespace hrt
