// hrt/runner.h: a device session as `hrt run` drives it, for applications
// that embed the runtime (docs/embedding.md, "Sessions").
//
// A Runner takes a scene file's configuration (hrt/run_config.h), loads its
// bundles and the kinematic objects' trajectories, builds the scene, opens
// the device with the file's limits, and runs the simulation (hrt::Session)
// against the device loop (hrt::DeviceLoop):
//   lockstep  (RunConfig::lockstep, a scripted device) one thread and a
//             manual clock: every device period one tick, every sim_every
//             periods one simulation frame of sim_every periods; every
//             result reproduces to the bit. step() runs to the next frame.
//   real time the device loop on its own thread at a fixed period, the
//             simulation on the caller's thread as fast as it can, each frame
//             integrating the wall time since the previous one (at most
//             max_step). run() until the duration, a stop flag, or a device
//             fault; the device ramps to zero at the end.
// `hrt run` is a client of this class: it adds the flags, the depth backend
// choice, the trace file and the printed summary.
#pragma once

#include <atomic>
#include <cstddef>
#include <functional>
#include <memory>
#include <vector>

#include "hrt/depth_backend.h"
#include "hrt/device.h"
#include "hrt/device_loop.h"
#include "hrt/model.h"
#include "hrt/run_config.h"
#include "hrt/scene.h"
#include "hrt/session.h"

namespace hrt {

class Runner {
 public:
  // cfg: a scene file read by load_run_config (with apply_overrides and
  // check_run_outputs where the caller has overrides and outputs). Loads the
  // bundles and the trajectories and builds the scene; opens nothing.
  // Throws BundleError, TrajectoryError, and std::invalid_argument for
  // options the scene rejects (the message does not name the file).
  explicit Runner(RunConfig cfg);
  ~Runner();  // stops the device loop (the device ramps to zero) and closes the device
  Runner(const Runner&) = delete;
  Runner& operator=(const Runner&) = delete;

  // Opens the device (DeviceError), checks its limits against the scene
  // (DeviceError), and builds the session (std::invalid_argument) and the
  // device loop. A lockstep configuration needs a scripted device
  // (std::invalid_argument otherwise).
  void open();
  bool is_open() const;

  // Where the depth query runs (non-owning; nullptr: the CPU code inline).
  // Before or after open(); the backend must outlive the Runner.
  void set_depth_backend(DepthBackend* backend);

  // Lockstep: ticks the device loop until the next simulation frame and
  // returns it (valid until the next call), or nullptr once the scene's
  // duration has run or the device has faulted (device().fault()). Throws
  // what Session::step throws (a backend refusing the options, GlError).
  const SessionFrame* step();
  // Either mode, until the end of the duration, `stop` becoming true,
  // on_frame returning false, or a device fault. In real time the device
  // loop runs on its own thread and is stopped (ramped to zero) before run
  // returns or rethrows. on_frame (optional) sees each frame.
  void run(const std::function<bool(const SessionFrame&)>& on_frame = {}, const std::atomic<bool>* stop = nullptr);

  const RunConfig& config() const;
  const std::vector<Model>& models() const;
  const Scene& scene() const;
  // After open():
  Session& session();
  const Session& session() const;
  Device& device();  // as opened (fault(), a UdpDevice's counters)
  // The device as a VirtualDevice (`[device] type = "virtual"`: set_pose()),
  // or nullptr for the other kinds.
  VirtualDevice* virtual_device();
  const DeviceInfo& device_info() const;  // the limits in force (a plugin's own, overridden by the file)
  const DeviceLoop& loop() const;
  const DeviceTarget& target() const;  // the device target of the last frame
  // Device ticks of the whole duration (lockstep: duration / period, rounded).
  size_t ticks_total() const;
  // Real time: the wall time between successive frames (s), for the summary.
  const std::vector<double>& frame_periods() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace hrt
