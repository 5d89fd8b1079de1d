// An hrt device plugin for Force Dimension devices through the DHD SDK
// (omega.x, delta.x, sigma.x, lambda.x; a Novint Falcon with Force
// Dimension's driver). A documented skeleton: NOT compiled in this repository
// (the SDK is not installable here); see README.md next to it to build it.
//
// hrt's rules (runtime/include/hrt/device_plugin.h): read() and write() run on
// hrt's 1 kHz device thread and must not block. DHD calls are synchronous USB
// transfers, so they run on a servo thread of this plugin instead, and the
// two threads exchange the newest pose and wrench through seqlocks (atomics,
// no mutex): the servo thread never waits for hrt, and hrt never waits for
// USB. The servo loop runs as fast as the device allows (several kHz for
// omega/sigma, ~1 kHz for a Falcon); DHD's TimeGuard is left at its default.
//
// Config string (space-separated key=value, all optional):
//   device=N           open the N-th device (dhdOpenID), default: the first (dhdOpen)
//   gravity=on|off     DHD's own gravity compensation, default on
//   max_force=F        N, reported to hrt (default: 8 for omega-class devices)
//   max_torque=T       N m, reported (default 0.3; a device without an active
//                      wrist reports dof_actuated = 3 and the torque is dropped)
#include <dhdc.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>

#include "hrt/device_plugin.h"

namespace {

// Single-writer seqlock of N doubles: the writer bumps the counter to odd,
// writes, bumps to even; a reader retries while the counter is odd or moved.
// Lock-free for the reader and the writer alike.
template <int N>
struct SeqLock {
  std::atomic<unsigned> seq{0};
  std::atomic<double> v[N];
  SeqLock() {
    for (auto& x : v) x.store(0.0, std::memory_order_relaxed);
  }
  void store(const double* in) {
    const unsigned s = seq.load(std::memory_order_relaxed);
    seq.store(s + 1, std::memory_order_relaxed);
    std::atomic_thread_fence(std::memory_order_release);
    for (int i = 0; i < N; ++i) v[i].store(in[i], std::memory_order_relaxed);
    seq.store(s + 2, std::memory_order_release);
  }
  // false when the writer was mid-update (the caller keeps its last copy).
  bool load(double* out) const {
    const unsigned s0 = seq.load(std::memory_order_acquire);
    if (s0 & 1u) return false;
    for (int i = 0; i < N; ++i) out[i] = v[i].load(std::memory_order_relaxed);
    std::atomic_thread_fence(std::memory_order_acquire);
    return seq.load(std::memory_order_relaxed) == s0;
  }
};

struct DhdDevice {
  int index = -1;  // -1: the first device
  bool gravity = true;
  double max_force = 8.0, max_torque = 0.3;
  char id = -1;  // DHD's device id once open
  bool active_wrist = false;

  std::thread servo;
  std::atomic<bool> running{false};
  std::atomic<bool> have_pose{false};
  std::atomic<unsigned> buttons{0};
  SeqLock<7> pose;                              // x y z qx qy qz qw, written by the servo thread
  SeqLock<6> wrench;                            // fx fy fz tx ty tz, written by hrt's device thread
  double last_pose[7] = {0, 0, 0, 0, 0, 0, 1};  // hrt's thread only
};

// Rotation matrix (DHD's orientation frame) to a unit quaternion x y z w.
void matrix_to_quaternion(const double m[3][3], double q[4]) {
  const double tr = m[0][0] + m[1][1] + m[2][2];
  if (tr > 0) {
    const double s = 2.0 * std::sqrt(tr + 1.0);
    q[3] = 0.25 * s;
    q[0] = (m[2][1] - m[1][2]) / s;
    q[1] = (m[0][2] - m[2][0]) / s;
    q[2] = (m[1][0] - m[0][1]) / s;
  } else if (m[0][0] > m[1][1] && m[0][0] > m[2][2]) {
    const double s = 2.0 * std::sqrt(1.0 + m[0][0] - m[1][1] - m[2][2]);
    q[3] = (m[2][1] - m[1][2]) / s;
    q[0] = 0.25 * s;
    q[1] = (m[0][1] + m[1][0]) / s;
    q[2] = (m[0][2] + m[2][0]) / s;
  } else if (m[1][1] > m[2][2]) {
    const double s = 2.0 * std::sqrt(1.0 + m[1][1] - m[0][0] - m[2][2]);
    q[3] = (m[0][2] - m[2][0]) / s;
    q[0] = (m[0][1] + m[1][0]) / s;
    q[1] = 0.25 * s;
    q[2] = (m[1][2] + m[2][1]) / s;
  } else {
    const double s = 2.0 * std::sqrt(1.0 + m[2][2] - m[0][0] - m[1][1]);
    q[3] = (m[1][0] - m[0][1]) / s;
    q[0] = (m[0][2] + m[2][0]) / s;
    q[1] = (m[1][2] + m[2][1]) / s;
    q[2] = 0.25 * s;
  }
}

void servo_loop(DhdDevice* d) {
  double w[6] = {0, 0, 0, 0, 0, 0};
  while (d->running.load(std::memory_order_relaxed)) {
    double p[7], m[3][3];
    if (dhdGetPositionAndOrientationFrame(&p[0], &p[1], &p[2], m, d->id) >= 0) {
      matrix_to_quaternion(m, &p[3]);
      d->pose.store(p);
      d->buttons.store(static_cast<unsigned>(dhdGetButtonMask(d->id)), std::memory_order_relaxed);
      d->have_pose.store(true, std::memory_order_release);
    }
    d->wrench.load(w);  // keeps the previous wrench when hrt is mid-update
    // The torque goes to the wrist motors only on an active wrist.
    if (d->active_wrist)
      dhdSetForceAndTorque(w[0], w[1], w[2], w[3], w[4], w[5], d->id);
    else
      dhdSetForce(w[0], w[1], w[2], d->id);
  }
  dhdSetForceAndTorque(0, 0, 0, 0, 0, 0, d->id);
}

void set_error(char* error, size_t size, const std::string& s) { std::snprintf(error, size, "%s", s.c_str()); }

void* dhd_create(const char* config, char* error, size_t error_size) {
  auto* d = new DhdDevice;
  std::string cfg = config ? config : "";
  size_t pos = 0;
  while (pos < cfg.size()) {
    const size_t end = std::min(cfg.find(' ', pos), cfg.size());
    const std::string tok = cfg.substr(pos, end - pos);
    pos = end + 1;
    if (tok.empty()) continue;
    const size_t eq = tok.find('=');
    const std::string key = tok.substr(0, eq), val = eq == std::string::npos ? "" : tok.substr(eq + 1);
    char* e = nullptr;
    if (key == "device") {
      d->index = static_cast<int>(std::strtol(val.c_str(), &e, 10));
    } else if (key == "gravity" && (val == "on" || val == "off")) {
      d->gravity = val == "on";
      continue;
    } else if (key == "max_force") {
      d->max_force = std::strtod(val.c_str(), &e);
    } else if (key == "max_torque") {
      d->max_torque = std::strtod(val.c_str(), &e);
    }
    if (e == nullptr || e == val.c_str() || *e != '\0') {
      set_error(error, error_size,
                "dhd: bad config entry '" + tok + "' (device=N gravity=on|off max_force=F max_torque=T)");
      delete d;
      return nullptr;
    }
  }
  return d;
}

void dhd_destroy(void* h) { delete static_cast<DhdDevice*>(h); }

int dhd_info(void* h, hrt_device_info* out, char* error, size_t error_size) {
  (void)error, (void)error_size;
  auto* d = static_cast<DhdDevice*>(h);
  std::snprintf(out->name, sizeof out->name, "dhd");
  if (d->id >= 0) {
    // Known once open: the model and whether the wrist is sensed and actuated.
    std::snprintf(out->name, sizeof out->name, "%s", dhdGetSystemName(d->id));
    out->dof_sensed = dhdHasWrist(d->id) ? 6 : 3;
    out->dof_actuated = d->active_wrist ? 6 : 3;
  }
  out->max_force = d->max_force;
  out->max_torque = d->max_torque;
  // The omega.x workspace is about a 16 cm sphere; report its inscribed box.
  out->workspace[0] = out->workspace[1] = out->workspace[2] = 0.055;
  return 0;
}

int dhd_open(void* h, char* error, size_t error_size) {
  auto* d = static_cast<DhdDevice*>(h);
  const int id = d->index < 0 ? dhdOpen() : dhdOpenID(static_cast<char>(d->index));
  if (id < 0) {
    set_error(error, error_size, std::string("dhd: cannot open the device: ") + dhdErrorGetLastStr());
    return 1;
  }
  d->id = static_cast<char>(id);
  d->active_wrist = dhdHasActiveWrist(d->id);
  dhdSetGravityCompensation(d->gravity ? DHD_ON : DHD_OFF, d->id);
  // Devices that need calibration (sigma, some omegas) are calibrated with
  // Force Dimension's DRD library (drdOpen / drdAutoInit / drdStop) or their
  // "autoinit" tool before hrt starts; see README.md.
  if (dhdEnableForce(DHD_ON, d->id) < 0) {
    set_error(error, error_size, std::string("dhd: cannot enable forces: ") + dhdErrorGetLastStr());
    dhdClose(d->id);
    d->id = -1;
    return 1;
  }
  d->running.store(true);
  d->servo = std::thread(servo_loop, d);
  return 0;
}

void dhd_close(void* h) {
  auto* d = static_cast<DhdDevice*>(h);
  if (d->id < 0) return;
  d->running.store(false);
  if (d->servo.joinable()) d->servo.join();  // the loop zeroes the forces on its way out
  dhdEnableForce(DHD_OFF, d->id);
  dhdClose(d->id);
  d->id = -1;
  d->have_pose.store(false);
}

// hrt's device thread: copies only.
int dhd_read(void* h, double t, double pose[7], uint32_t* buttons, int* clutch) {
  (void)t;
  auto* d = static_cast<DhdDevice*>(h);
  if (!d->have_pose.load(std::memory_order_acquire)) return 0;
  d->pose.load(d->last_pose);  // mid-update: the previous pose, at most one servo tick old
  std::memcpy(pose, d->last_pose, sizeof d->last_pose);
  const unsigned b = d->buttons.load(std::memory_order_relaxed);
  // Button 0 (the centre button on omega/sigma) is the clutch; the others are buttons.
  *clutch = (b & 1u) != 0;
  *buttons = b >> 1;
  return 1;
}

void dhd_write(void* h, double t, const double wrench[6]) {
  (void)t;
  static_cast<DhdDevice*>(h)->wrench.store(wrench);
}

const hrt_device_plugin kTable = {HRT_DEVICE_PLUGIN_ABI,
                                  sizeof(hrt_device_plugin),
                                  dhd_create,
                                  dhd_destroy,
                                  dhd_info,
                                  dhd_open,
                                  dhd_close,
                                  dhd_read,
                                  dhd_write};

}  // namespace

extern "C" HRT_PLUGIN_EXPORT const hrt_device_plugin* hrt_device_plugin_v1(void) { return &kTable; }
