// Clocks of a session (seconds, monotonic). The device loop (hrt/device_loop.h)
// reads session time from one: its ticks, ramps, watchdog and log all use
// clock.now() as it is, so the simulation and the device agree on t.
//
//   lockstep, tests   ManualClock: the caller sets or advances it; nothing sleeps,
//                     so a session and its watchdog are reproducible.
//   real time         SessionClock: CLOCK_MONOTONIC less its value at construction
//                     (what `hrt run` and hrt::Runner use).
//   SteadyClock       CLOCK_MONOTONIC itself.
//
// The device thread's deadlines are on CLOCK_MONOTONIC whatever the clock.
#pragma once

#include <atomic>

namespace hrt {

// Injectable, so the watchdog and the ramps are tested without sleeping.
class Clock {
 public:
  virtual ~Clock() = default;
  virtual double now() const noexcept = 0;  // seconds, monotonic
};

class SteadyClock : public Clock {  // CLOCK_MONOTONIC
 public:
  double now() const noexcept override;
};

class SessionClock : public Clock {  // CLOCK_MONOTONIC since construction
 public:
  SessionClock() : t0_(base_.now()) {}
  double now() const noexcept override { return base_.now() - t0_; }

 private:
  SteadyClock base_;
  double t0_;
};

class ManualClock : public Clock {  // set by the caller (lockstep, tests)
 public:
  double now() const noexcept override { return t_.load(std::memory_order_acquire); }
  void set(double t) noexcept { t_.store(t, std::memory_order_release); }
  void advance(double dt) noexcept { set(now() + dt); }

 private:
  std::atomic<double> t_{0.0};
};

}  // namespace hrt
