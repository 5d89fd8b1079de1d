// Scene files of `hrt run` (TOML, read with toml++; spec: docs/scene-format.md).
// The trace a session writes is hrt/trace.h.
//
// load_run_config parses and checks the whole file before anything runs:
// every key is known (a typo is an error, not a silent default), every value
// has the right type, unit range and finiteness, paths are resolved against
// the scene file's folder. Device-dependent defaults (coupling gains from the
// device's limits) are left negative here (coupling_from_device) and filled by
// the caller once the device is open (default_coupling, hrt/session.h).
#pragma once

#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "hrt/device.h"
#include "hrt/files.h"
#include "hrt/device_loop.h"
#include "hrt/scene.h"
#include "hrt/session.h"
#include "hrt/trace.h"

namespace hrt {

// "FILE: KEY: what is wrong" (key dotted, e.g. object[1].position; "" for the
// file as a whole: unreadable or not TOML, with its line and column).
struct SceneFileError : std::runtime_error {
  std::string file, key;
  SceneFileError(const std::string& f, const std::string& k, const std::string& what);
};

struct ObjectConfig {
  std::string name;        // unique; default "object<i>"
  std::string bundle;      // resolved path of the bundle directory
  Pose pose;               // initial pose (meters, quaternion x y z w normalized)
  std::string trajectory;  // objects B only: kinematic trajectory CSV ("" = static)
};

struct DeviceConfig {
  std::string type = "scripted";  // scripted | udp | plugin | virtual
  std::string trajectory;         // scripted: the trajectory CSV (resolved)
  std::string trajectory_prefix;  // scripted: column prefix ("device_" replays a trace)
  UdpOptions udp;                 // udp
  std::string plugin;             // plugin: shared library path (resolved)
  std::string plugin_config;      // plugin: passed to its create()
  // virtual: the handle's pose until the application moves it; left out of
  // the file, the pose whose target is the probe's initial pose.
  Pose start;
  bool start_set = false;
  DeviceInfo info;  // limits (scripted and udp; a plugin reports its own)
  // Keys of `info` the file set explicitly (a plugin's own figures are then overridden).
  bool max_force_set = false, max_torque_set = false, max_stiffness_set = false, max_angular_stiffness_set = false,
       dof_actuated_set = false;
};

// Limits on what a session allocates and writes (docs/scene-format.md,
// "Limits"), each checked before anything is allocated: with every value the
// reader accepts, `hrt run` and `hrt query` stay under 1 GiB of memory.
// The grid resolution is bounded by kMaxResolution (hrt/depth.h).
// Device-log rows (112 bytes each, preallocated): 224 MB.
constexpr size_t kMaxLogCapacity = 2'000'000;
// Real-time period errors kept for the jitter summary (8 bytes each): the
// first 4,194,304 ticks (70 min at 1 kHz).
constexpr size_t kMaxJitterSamples = size_t{1} << 22;
struct RunConfig {
  std::string file;                   // the scene file
  std::vector<ObjectConfig> objects;  // [0] = the probe
  SceneOptions scene;                 // force model (k, N, steps, shortcut, heights), collision margin
  SessionOptions session;             // density, gravity, friction, materials, coupling
  bool coupling_from_device = true;   // gains not given: default_coupling(device, probe)
  DeviceLoopOptions loop;             // period, watchdog, soft start, rate limits, multirate, workspace map
  DeviceConfig device;
  double duration = 1.0;   // s of session time
  bool lockstep = false;   // fixed step, no wall clock (reproducible)
  int sim_every = 1;       // lockstep: one simulation frame every sim_every device periods
  double max_step = 0.02;  // real-time: longest h one frame integrates, s
  // The depth backend (hrt/depth_backend.h, hrt/gl_depth.h): cpu | gl | auto
  // (parse_backend_choice); the GL backend's max search: compute | occlusion,
  // and the occlusion search's passes (1..23).
  std::string backend = "cpu";
  std::string gl_search = "compute";
  int occlusion_steps = 16;
  TraceConfig trace;
  // Where duration came from ("run.duration" or "--duration"), and whether
  // the file set [loop] log_capacity (else it is sized to the session).
  std::string duration_key = "run.duration";
  bool log_capacity_set = false;
};

// Throws SceneFileError.
RunConfig load_run_config(const std::string& path);

// Command-line overrides of a scene file (`hrt run`'s flags). Paths are
// relative to the working directory.
struct RunOverrides {
  std::optional<double> duration;  // --duration
  std::optional<bool> lockstep;    // --lockstep (true) / --realtime (false)
  bool sched_fifo = false;         // --sched-fifo
  std::string trace, device_log;   // --trace, --device-log ("" = the file's)
};
// Applies the overrides, then check_run_limits. Throws SceneFileError whose
// key is the flag ("--duration") when a flag's value is the problem.
void apply_overrides(RunConfig& config, const RunOverrides& overrides);
// The limits that depend on several keys (the sizes they imply: device-log
// rows for duration / period, ...) and the defaults that depend on the mode
// (the trace rate). load_run_config calls it; so does apply_overrides, since
// a flag can change what a checked file implies.
void check_run_limits(RunConfig& config);
// Every output (trace, device log) against every input of the session (the
// scene file, trajectories, the plugin, every file of every bundle) by
// identity and resolved path. Throws OutputOverwritesInput (hrt/files.h);
// nothing is written.
void check_run_outputs(const RunConfig& config);
// A device's limits (a plugin's own figures, or the scene's) within the
// ranges of the scene file's [device] keys; throws DeviceError naming
// `source` and the limit.
void check_device_limits(const DeviceInfo& info, const std::string& source);

}  // namespace hrt
