// Haptic devices behind one small interface.
//
// A Device reads the pose of its handle and displays a wrench. Implementations:
//   ScriptedDevice  plays a trajectory file (hrt/trajectory.h), for tests,
//                   experiments and replaying a trace's device poses;
//   UdpDevice       a device driven by another process or machine over UDP
//                   (docs/udp-protocol.md), which also publishes the poses of
//                   the scene's objects at display rate;
//   PluginDevice    a shared library implementing the C interface of
//                   hrt/device_plugin.h, loaded with dlopen, so a lab wraps a
//                   vendor SDK without rebuilding the runtime;
//   VirtualDevice   a handle moved by the application (set_pose): the mouse
//                   of a viewer, a script, a test. What it is given passes
//                   through the same coupling and device loop as a real
//                   device's pose, and the wrench the loop writes to it is
//                   bounded the same way.
//
// Frames and units: the device reports its handle's pose in its own base
// frame (meters, unit quaternion); the wrench it is given is in that same
// frame (force N, torque N m). WorkspaceMap (hrt/device_loop.h) maps between
// the device frame and the scene.
//
// Threads: open()/close() run on the thread that owns the device (they may
// allocate, block, print); read() and write() run on the device thread every
// period and must not allocate, lock, block or log.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>

#include "hrt/math.h"
#include "hrt/trajectory.h"

namespace hrt {

struct DeviceInfo {
  std::string name = "device";
  int dof_sensed = 6;                    // 6: position and orientation; 3: position only (orientation reads identity)
  int dof_actuated = 6;                  // 6: force and torque; 3: force only (the torque is not displayed)
  Vec3 workspace = Vec3::Constant(0.1);  // half extents of the handle's workspace box, device frame, m
  double max_force = 10.0;               // N, continuous
  double max_torque = 0.5;               // N m (ignored when dof_actuated == 3)
  double max_stiffness = 2000.0;         // N/m the device renders stably at 1 kHz
  double max_angular_stiffness = 5.0;    // N m/rad
};

struct DeviceSample {
  Pose pose;             // handle pose, device frame
  bool clutch = false;   // the clutch (re-index) button is held
  uint32_t buttons = 0;  // other buttons, bit per button
};

struct DeviceError : std::runtime_error {
  using std::runtime_error::runtime_error;  // one line: what and which device/file/port
};

class Device {
 public:
  virtual ~Device() = default;
  virtual const DeviceInfo& info() const = 0;
  // Before the device thread starts / after it stopped. Throws DeviceError.
  virtual void open() {}
  virtual void close() {}
  // Device thread, once per period, t = session time (s). Fills `out` with
  // the latest pose and returns true, or returns false when the device has
  // no valid pose (yet): the loop holds the previous one.
  virtual bool read(double t, DeviceSample& out) noexcept = 0;
  // Device thread, once per period: the wrench to display (device frame,
  // already clamped to the limits, finite).
  virtual void write(double t, const Vec6& wrench) noexcept = 0;
  // Simulation thread, at display rate: the scene's object poses (world),
  // for devices that forward them to a visual display (UdpDevice). Default:
  // ignored. May be called concurrently with read()/write().
  virtual void publish_poses(double /*t*/, const Pose* /*poses*/, int /*count*/) noexcept {}
  // A device that failed for good (a plugin call that ran past its
  // deadline): one line saying which device and which call; "" while it
  // works. Once it is non-empty, read() returns false and write() does
  // nothing: the session must end (hrt run: exit 5). Any thread but the
  // device thread; may allocate.
  virtual std::string fault() const { return {}; }
};

// Plays a trajectory (hrt/trajectory.h) at session time; records nothing.
// The last written wrench is kept for tests (last_wrench()).
class ScriptedDevice : public Device {
 public:
  ScriptedDevice(Trajectory trajectory, DeviceInfo info);
  const DeviceInfo& info() const override { return info_; }
  bool read(double t, DeviceSample& out) noexcept override;
  void write(double t, const Vec6& wrench) noexcept override;
  Vec6 last_wrench() const { return last_; }
  const Trajectory& trajectory() const { return trajectory_; }

 private:
  Trajectory trajectory_;
  DeviceInfo info_;
  Vec6 last_ = Vec6::Zero();
};

// A handle the application moves (`[device] type = "virtual"`): read()
// returns the pose last given to set_pose() (the start pose before any),
// write() keeps the wrench for last_wrench(). Deterministic in lockstep: a
// pose set between two Runner::step() calls is read by every tick of the
// next step. set_pose() (one thread at a time) and last_wrench() may run on
// any thread while the device thread calls read() and write(): a sequence
// lock, so read() never sees half of a pose, and never waits: a writer found
// mid-store on 64 tries in a row leaves the previous pose for that tick.
class VirtualDevice : public Device {
 public:
  VirtualDevice(Pose start, DeviceInfo info);
  const DeviceInfo& info() const override { return info_; }
  bool read(double t, DeviceSample& out) noexcept override;
  void write(double t, const Vec6& wrench) noexcept override;
  // The handle's pose in the device frame (normalized here; a non-finite
  // pose or a zero quaternion is ignored and returns false) and the clutch.
  bool set_pose(const Pose& pose, bool clutch = false) noexcept;
  Vec6 last_wrench() const noexcept;

 private:
  static constexpr int kWords = 8;  // x y z qx qy qz qw clutch
  static constexpr int kReadAttempts = 64;
  std::atomic<uint64_t> seq_{0};
  std::atomic<double> pose_[kWords];
  std::atomic<double> wrench_[6];
  DeviceSample last_;  // device thread: the last pose read
  DeviceInfo info_;
};

// Options of the UDP bridge (docs/udp-protocol.md).
struct UdpOptions {
  std::string bind_address = "127.0.0.1";  // loopback unless told otherwise
  int port = 47800;                        // device pose packets arrive here; 0 = any free port
  // Where wrench packets go: "" = the address and port of the last valid pose packet.
  std::string reply_address;
  int reply_port = 0;
  // Display: object pose packets at display_rate_hz to display_address:display_port
  // (display_port 0 = off).
  std::string display_address = "127.0.0.1";
  int display_port = 0;
  double display_rate_hz = 60.0;
};

struct UdpCounters {
  uint64_t received = 0, accepted = 0;
  uint64_t bad_size = 0, bad_magic = 0, bad_version = 0, bad_type = 0, non_finite = 0, out_of_order = 0;
  uint64_t sent_wrenches = 0, sent_display = 0, send_errors = 0;
};

class UdpDevice : public Device {
 public:
  UdpDevice(UdpOptions options, DeviceInfo info);
  ~UdpDevice() override;
  const DeviceInfo& info() const override { return info_; }
  void open() override;  // binds; throws DeviceError ("udp: cannot bind 127.0.0.1:47800: ...")
  void close() override;
  bool read(double t, DeviceSample& out) noexcept override;  // drains the socket (non-blocking)
  void write(double t, const Vec6& wrench) noexcept override;
  void publish_poses(double t, const Pose* poses, int count) noexcept override;
  int bound_port() const;        // after open()
  UdpCounters counters() const;  // snapshot (atomics)

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  DeviceInfo info_;
};

// Deadlines of the calls into a device plugin (docs/device-plugins.md,
// "Deadlines"). A call still running at its deadline is a stall: the
// PluginDevice is faulted for good (fault()). read() and write() get 50
// periods of the 1 kHz loop: far beyond any working device's call, short
// enough that the loop notices a stuck one while the user still holds the
// handle; open() gets the time a device needs to find its hardware and
// calibrate.
constexpr int kPluginReadDeadlineMs = 50;
constexpr int kPluginWriteDeadlineMs = 50;
constexpr int kPluginCallDeadlineMs = 5000;   // create, info, close, destroy
constexpr int kPluginOpenDeadlineMs = 30000;  // open (calibration)

// A device from a plugin (hrt/device_plugin.h). `config` is passed to the
// plugin's create() verbatim (the scene file's device.plugin_config).
//
// The file is checked before dlopen (a regular file within kMaxPluginBytes,
// a 64-bit ELF file of this machine whose headers and segments all lie
// within the file), so a truncated or foreign file is refused with a
// DeviceError instead of crashing the loader. A path without a slash names a
// file in the working directory (dlopen's library search is not used: the
// file loaded is the file checked).
//
// Every call into the plugin runs on one worker thread owned by the device;
// the caller waits for it with the deadline above. A call that misses it
// stalls the device for good: fault() names the plugin and the call, read()
// returns false at once and write() does nothing, the plugin's close() and
// destroy() are never called, the worker is detached (not joined), the
// library stays loaded and the device's internal state is leaked (the stuck
// call may still return into it). A stall in the constructor or open()
// throws DeviceError with fault()'s line.
class PluginDevice : public Device {
 public:
  PluginDevice(const std::string& library_path, const std::string& config);
  ~PluginDevice() override;
  const DeviceInfo& info() const override { return info_; }
  void open() override;
  void close() override;
  bool read(double t, DeviceSample& out) noexcept override;
  void write(double t, const Vec6& wrench) noexcept override;
  // "plugin PATH: read() did not return within 50 ms (stalled); the plugin is
  // no longer called", or "" while no call stalled.
  std::string fault() const override;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  DeviceInfo info_;
};

}  // namespace hrt
