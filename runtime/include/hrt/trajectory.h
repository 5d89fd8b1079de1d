// Pose trajectories: the scripted device's input, the kinematic
// objects B of a scene, and the device poses of a recorded trace.
//
// File format (docs/trajectory-format.md): CSV with a header line naming at
// least the columns t, x, y, z, qx, qy, qz, qw (any order, other columns
// ignored, so a trace written by `hrt run` is a trajectory of its device
// poses when `prefix` is "device_"); seconds, meters, a unit quaternion x, y,
// z, w; times strictly increasing. Between samples the position is linear and
// the orientation is slerped; before the first and after the last sample the
// end pose is held.
#pragma once

#include <cstddef>
#include <stdexcept>
#include <string>
#include <vector>

#include "hrt/math.h"

namespace hrt {

// Limits of a trajectory file (docs/trajectory-format.md): at most this
// many samples (72 bytes each in memory, 144 MB; 33 min at 1 kHz), lines of
// at most this many bytes (a trace row is about 1.5 KB), and the file at
// most kMaxTrajectoryBytes (hrt/files.h).
constexpr size_t kMaxTrajectorySamples = 2'000'000;
constexpr size_t kMaxTrajectoryLine = 65536;
// Positions within this many metres of the origin along each axis (as a
// scene's and `hrt query --pose`'s).
constexpr double kMaxTrajectoryPosition = 1e4;

struct TrajectoryError : std::runtime_error {
  using std::runtime_error::runtime_error;  // "FILE: line L: what"
};

class Trajectory {
 public:
  Trajectory() = default;
  // Reads a CSV trajectory. `prefix` selects the columns `<prefix>x` ...
  // (`t` is always `t`, or `time`). Throws TrajectoryError naming the file,
  // the line and what is wrong (missing column, non-numeric or non-finite
  // value, zero quaternion, time not increasing, no rows).
  static Trajectory load_csv(const std::string& path, const std::string& prefix = "");
  // From samples in memory (tests, generators); same checks, message without file.
  static Trajectory from_samples(std::vector<double> times, std::vector<Pose> poses);

  bool empty() const { return times_.empty(); }
  size_t size() const { return times_.size(); }
  double start_time() const { return times_.empty() ? 0.0 : times_.front(); }
  double end_time() const { return times_.empty() ? 0.0 : times_.back(); }
  const std::vector<double>& times() const { return times_; }
  const std::vector<Pose>& poses() const { return poses_; }

  // The pose at time t. Never allocates; O(log n) (binary search), O(1)
  // when t advances (a cached segment, so the device thread can call it).
  Pose sample(double t) const;
  // Linear and angular velocity at t (world, m/s, rad/s): the segment's
  // finite difference (zero outside the samples).
  Vec6 velocity(double t) const;

 private:
  std::vector<double> times_;
  std::vector<Pose> poses_;
  mutable size_t hint_ = 0;
};

}  // namespace hrt
