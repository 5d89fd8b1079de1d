// The device force loop: a thread at a fixed 1 kHz
// period, asynchronous from the simulation (paper Sec. 6.1, 7.1), that maps
// the device into the scene, turns the simulation's latest command into a
// wrench every period, makes it safe and writes it to the device.
//
// Data flow (no locks; TripleBuffer below):
//   device thread:  Device::read -> clutch / WorkspaceMap -> DeviceTarget --> simulation
//   simulation:     Session::step(target) -> DeviceCommand ------------------> device thread
//   device thread:  command -> (multirate) W = W0 - K_eff d -> scene-to-device frame
//                   -> torque policy -> NaN guard -> clamp to the limits -> x envelope
//                   -> rate limit -> clamp to envelope x limits -> Device::write
//
// Multirate (Otaduy and Lin 2006): W0 is the wrench the device should feel
// at the target pose the simulation used (target_ref) and K_eff = K_c - K_c
// (K_c + K)^-1 K_c the contact stiffness K seen through the coupling K_c;
// between simulation frames the device evaluates W0 - K_eff d, d the twist
// (translation, rotation vector) from target_ref to the current target, in
// the scene frame. With multirate off it holds W0 (zero-order hold).
//
// The device thread never allocates, locks, logs or touches GL; tick() is
// the whole of one period and can be called directly (lockstep mode: a
// ManualClock and no thread), which is how the tests drive it.
//
// Session time (Device::read/write, DeviceTarget::time, the log, the ramps
// and the watchdog) is clock.now() as it is: give the loop a clock that reads
// session time (hrt/clock.h: a ManualClock in lockstep, a SessionClock in
// real time, as `hrt run` does), so the simulation and the device agree on
// t. The thread's deadlines are on CLOCK_MONOTONIC whatever the clock.
//
// The envelope is the product of three ramps in [0, 1], each linear in
// session time, and a fourth at stop(). It scales the device's limits, so
// that at every tick, whatever the simulation asks,
//   |F_out| <= envelope(t) x max_force   and   |T_out| <= envelope(t) x max_torque
// (the wrench is clamped to the limits, then scaled by the envelope; after
// the rate limit it is clamped to envelope x limits again, since the rate
// limit starts from the previous output, which may be above this tick's
// bound while a ramp goes down). Every clamp aims 8 ulp below its bound, so
// the norm of the written wrench, computed in double in any order, never
// exceeds the limit, not even by rounding. The ramps:
//   soft start  0 -> 1 over soft_start from the first valid command; after a
//               clutch release or a watchdog recovery it restarts from the
//               level the output had (s * w * c), so the output never steps;
//   watchdog w  1 -> 0 over watchdog_ramp once no command was accepted for
//               `watchdog` s;
//   clutch c    1 -> 0 over watchdog_ramp while the clutch is held;
//   stop        1 -> 0 over watchdog_ramp (counted in periods) after stop().
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <thread>
#include <vector>

#include "hrt/clock.h"
#include "hrt/device.h"
#include "hrt/math.h"

namespace hrt {

// ---------------------------------------------------------------------------
// TripleBuffer: one writer, one reader, wait-free, no allocation after
// construction. The writer fills back(), then publish(); the reader calls
// update() and reads front(), which stays stable until its next update().
// ---------------------------------------------------------------------------
template <class T>
class TripleBuffer {
 public:
  T& back() noexcept { return slots_[back_]; }
  void publish() noexcept {
    const uint8_t prev = middle_.exchange(static_cast<uint8_t>(back_ | kFresh), std::memory_order_acq_rel);
    back_ = prev & kIndex;
  }
  // True when a newer value was published since the last update().
  bool update() noexcept {
    if (!(middle_.load(std::memory_order_acquire) & kFresh)) return false;
    const uint8_t prev = middle_.exchange(front_, std::memory_order_acq_rel);
    front_ = prev & kIndex;
    return true;
  }
  const T& front() const noexcept { return slots_[front_]; }

 private:
  static constexpr uint8_t kFresh = 4, kIndex = 3;
  std::array<T, 3> slots_{};
  uint8_t back_ = 0, front_ = 1;
  std::atomic<uint8_t> middle_{2};
};

// ---------------------------------------------------------------------------
// Workspace mapping: device frame -> scene
//   scene position of the handle   = offset.rotation * (scale * p_device) + offset.position
//   scene orientation of the handle = offset.rotation * q_device
//   target pose of the probe's object frame = handle pose * grasp^-1
// grasp: the handle's pose in the probe's object frame (where the hand holds
// the probe). Wrenches go back by the inverse rotation (force and torque
// keep their magnitude: the user feels the scene's newtons; a scale s > 1
// makes the scene's stiffness k feel like k * s at the handle).
// ---------------------------------------------------------------------------
struct WorkspaceMap {
  double scale = 1.0;
  Pose offset;
  Pose grasp;
  Pose to_scene(const Pose& device) const;         // the probe target pose
  Pose to_device(const Pose& target) const;        // the inverse: the handle pose that makes `target`
  Vec6 wrench_to_device(const Vec6& scene) const;  // rotate force and torque into the device frame
};

// Device -> simulation (published by the device thread every period).
struct DeviceTarget {
  double time = 0.0;  // session time of the sample, s
  uint64_t tick = 0;
  Pose device;  // raw handle pose, device frame
  Pose target;  // probe target pose, scene (after clutch re-indexing)
  bool clutched = false;
  bool valid = false;          // a pose has been read
  Vec6 output = Vec6::Zero();  // the wrench last written to the device (device frame)
};

// Simulation -> device (published after each simulation frame).
struct DeviceCommand {
  double time = 0.0;  // session time of the frame, s
  uint64_t frame = 0;
  Pose target_ref;                // the target the frame was computed at
  Vec6 wrench = Vec6::Zero();     // wrench for the device at target_ref, scene frame (force N, torque N m)
  Mat6 stiffness = Mat6::Zero();  // K_eff, symmetric positive semi-definite: dW = -K_eff d
  bool valid = false;
};

struct DeviceLoopOptions {
  double period = 1e-3;  // s (1 kHz)
  // The watchdog: when the simulation has not published for `watchdog`
  // seconds the output ramps linearly to zero over `watchdog_ramp` seconds
  // (and back in over soft_start when it publishes again). watchdog < 0:
  // max(50 ms, 5 x the median of the last 64 publication periods).
  double watchdog = -1.0;
  double watchdog_ramp = 0.01;
  // Soft start: the output ramps in linearly over this time from the first
  // valid command (and after each clutch release and watchdog recovery), s.
  double soft_start = 0.5;
  // Rate limits, N/s and N m/s; < 0: max_force / 10 ms and max_torque / 10 ms
  // of the device (full force in ten periods).
  double max_force_rate = -1.0;
  double max_torque_rate = -1.0;
  bool multirate = true;  // false: zero-order hold of the command's wrench
  WorkspaceMap map;
  bool realtime = false;  // ask for SCHED_FIFO (falls back, says so in stats)
  int realtime_priority = 80;
  // Per-tick log (lockstep experiments, the multirate test): capacity in
  // ticks, preallocated; 0 = off. Ticks beyond it are not logged (counted).
  size_t log_capacity = 0;
};
// How tick() treats its inputs (the rules the tests check):
//   - Device::read false, or a pose with a non-finite number or a zero
//     quaternion: the previous sample (pose and clutch) is held, counted in
//     read_failures; before the first good pose the output is zero.
//   - Commands: every one update() returns is counted in `commands`; one with
//     valid == false is ignored; one with a non-finite number (or a zero
//     target_ref quaternion) is dropped and counted in non_finite; the loop
//     keeps evaluating the last accepted one. Only accepted commands feed the
//     watchdog (time since the last one, and the publication periods), so a
//     simulation that publishes only garbage is ramped out too.
//   - Clutch: on press the target freezes at to_scene(pose at the press);
//     on release the map's offset is changed so that to_scene(pose at the
//     release) is the frozen target (orientation included: the device's
//     base is rotated against the scene by what the hand turned while
//     clutched), and the soft start restarts.
//   - Torque policy: a device with dof_actuated < 6 (3: force only) gets a
//     zero torque.
//   - Limits: a device limit that is not finite and positive counts as 0.
//     The rate limit is per tick: |F - F_prev| <= max_force_rate * period
//     (likewise the torque), period = options.period; it yields to the
//     envelope bound above (a ramp down may fall faster than the rate limit).

struct DeviceLogRow {
  double t = 0.0;
  Pose target;                 // probe target, scene
  Vec6 output = Vec6::Zero();  // written wrench, device frame
};

struct DeviceLoopStats {
  uint64_t ticks = 0;
  uint64_t read_failures = 0;                    // Device::read returned false (pose held)
  uint64_t force_clamps = 0, torque_clamps = 0;  // ticks where |F| or |T| hit the limit
  uint64_t rate_limited = 0;                     // ticks where the rate limit bit
  uint64_t non_finite = 0;                       // commands or outputs with NaN/Inf (dropped: previous output kept)
  uint64_t watchdog_events = 0;                  // stalls detected (each counted once)
  uint64_t commands = 0;                         // commands received
  uint64_t log_overflow = 0;
  uint64_t missed_deadlines = 0;     // thread mode: periods skipped because a tick overran a whole period
  bool realtime = false;             // SCHED_FIFO granted
  std::vector<double> period_error;  // thread mode: |actual - deadline| per tick, s (preallocated)
};

class DeviceLoop {
 public:
  // `device` and `clock` must outlive the loop. Allocates everything here.
  DeviceLoop(Device& device, const DeviceLoopOptions& options, const Clock& clock, size_t max_ticks_recorded = 1 << 20);
  ~DeviceLoop();
  DeviceLoop(const DeviceLoop&) = delete;
  DeviceLoop& operator=(const DeviceLoop&) = delete;

  // Simulation side (one thread).
  void publish(const DeviceCommand& command) noexcept;
  // The latest target (returns false before the first valid pose).
  bool target(DeviceTarget& out) noexcept;

  // Device side: one period (read, map, compute, guard, write).
  void tick() noexcept;
  // Thread mode: a thread calling tick() at absolute deadlines of the
  // monotonic clock (clock_nanosleep TIMER_ABSTIME). stop() ramps the output
  // to zero over watchdog_ramp, writes zero, joins.
  // Each wake-up records |actual - deadline| in stats().period_error (until
  // max_ticks_recorded), so a thread-only run has one entry per tick. A wake-up
  // later than the next deadline drops the missed periods (the grid restarts
  // from now) instead of running a burst of ticks on one stale pose.
  // Without a thread (lockstep) stop() writes a zero wrench at once: there
  // is no one to tick the ramp. In both modes ticks after stop() (or a new
  // start()) soft-start the output again.
  void start();
  void stop();
  bool running() const { return running_.load(); }

  const DeviceLoopOptions& options() const { return options_; }
  const DeviceLoopStats& stats() const { return stats_; }  // read after stop() (or in lockstep)
  const std::vector<DeviceLogRow>& log() const { return log_; }
  size_t log_size() const { return log_size_; }

 private:
  struct Internal;
  Device& device_;
  DeviceLoopOptions options_;
  const Clock& clock_;
  DeviceLoopStats stats_;
  std::vector<DeviceLogRow> log_;
  size_t log_size_ = 0;
  TripleBuffer<DeviceCommand> commands_;
  TripleBuffer<DeviceTarget> targets_;
  std::unique_ptr<Internal> in_;
  std::thread thread_;
  std::atomic<bool> running_{false};
};

// Percentiles of DeviceLoopStats::period_error (s), for the summary of
// `hrt run` and the jitter figures of docs/guides/sessions.md: p50 and p99 interpolated
// linearly between order statistics (numpy's default), the maximum, and the
// number of samples (all 0 when there are none). Sorts a copy: call it after
// stop(), not on the device thread.
struct JitterSummary {
  double p50 = 0.0, p99 = 0.0, max = 0.0;
  size_t samples = 0;
};
JitterSummary summarize_jitter(const DeviceLoopStats& stats);

}  // namespace hrt
