// Scene files of `hrt run` (TOML, read with toml++; spec: docs/scene-format.md)
// and the trace `hrt run` writes (CSV; spec: docs/trace-format.md).
//
// load_run_config parses and checks the whole file before anything runs:
// every key is known (a typo is an error, not a silent default), every value
// has the right type, unit range and finiteness, paths are resolved against
// the scene file's folder. Device-dependent defaults (coupling gains from the
// device's limits) are left negative here (coupling_from_device) and filled by
// the caller once the device is open (default_coupling, hrt/session.h).
#pragma once

#include <cstdio>
#include <stdexcept>
#include <string>
#include <vector>

#include "hrt/device.h"
#include "hrt/device_loop.h"
#include "hrt/scene.h"
#include "hrt/session.h"

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
  std::string type = "scripted";  // scripted | udp | plugin
  std::string trajectory;         // scripted: the trajectory CSV (resolved)
  std::string trajectory_prefix;  // scripted: column prefix ("device_" replays a trace)
  UdpOptions udp;                 // udp
  std::string plugin;             // plugin: shared library path (resolved)
  std::string plugin_config;      // plugin: passed to its create()
  DeviceInfo info;                // limits (scripted and udp; a plugin reports its own)
  // Keys of `info` the file set explicitly (a plugin's own figures are then overridden).
  bool max_force_set = false, max_torque_set = false, max_stiffness_set = false,
       max_angular_stiffness_set = false, dof_actuated_set = false;
};

struct TraceConfig {
  std::string path;         // "" = no trace
  std::string device_log;   // per-device-tick CSV ("" = none)
};

struct RunConfig {
  std::string file;                   // the scene file
  std::vector<ObjectConfig> objects;  // [0] = the probe
  SceneOptions scene;                 // force model (k, N, steps, shortcut, heights), collision margin
  SessionOptions session;             // density, gravity, friction, materials, coupling
  bool coupling_from_device = true;   // gains not given: default_coupling(device, probe)
  DeviceLoopOptions loop;             // period, watchdog, soft start, rate limits, multirate, workspace map
  DeviceConfig device;
  double duration = 1.0;              // s of session time
  bool lockstep = false;              // fixed step, no wall clock (reproducible)
  int sim_every = 1;                  // lockstep: one simulation frame every sim_every device periods
  double max_step = 0.02;             // real-time: longest h one frame integrates, s
  // The depth backend (hrt/depth_backend.h, hrt/gl_depth.h): cpu | gl | auto
  // (parse_backend_choice); the GL backend's max search: compute | occlusion,
  // and the occlusion search's passes (1..23).
  std::string backend = "cpu";
  std::string gl_search = "compute";
  int occlusion_steps = 16;
  TraceConfig trace;
};

// Throws SceneFileError.
RunConfig load_run_config(const std::string& path);

// Trace writer (docs/trace-format.md): one row per simulation frame. Writes
// to PATH.partial and renames to PATH on close(), so a crash never leaves a
// trace that looks complete. Throws std::runtime_error("PATH: ...") on I/O errors.
struct TraceRow {
  const SessionFrame* frame = nullptr;
  const DeviceTarget* device = nullptr;  // device pose and the wrench last written to it
};

class TraceWriter {
 public:
  TraceWriter() = default;
  ~TraceWriter();  // an unclosed writer removes its .partial file
  void open(const std::string& path, const RunConfig& config);
  void row(const TraceRow& r);
  void close();
  bool is_open() const { return file_ != nullptr; }

 private:
  std::string path_, partial_;
  std::FILE* file_ = nullptr;
};

// Per-tick device log (DeviceLoop::log), same conventions; written at the end.
void write_device_log(const std::string& path, const DeviceLoop& loop);

}  // namespace hrt
