/* Device plugins for hrt (docs/device-plugins.md): a shared library that
 * wraps a haptic device's SDK (OpenHaptics HD, Force Dimension DHD,
 * libnifalcon, ...) behind this C interface, loaded by `hrt run` with dlopen
 * ([device] type = "plugin", plugin = "path.so", config = "..."), so a lab
 * adds a device without rebuilding the runtime.
 *
 * A plugin exports one symbol, HRT_DEVICE_PLUGIN_ENTRY
 * ("hrt_device_plugin_v1"), a function returning a pointer to a static
 * function table whose abi_version is HRT_DEVICE_PLUGIN_ABI. The runtime
 * refuses a table of another ABI version, one shorter than this version's
 * (struct_size), or one with a required function missing.
 *
 * Frames and units (as hrt/device.h): the handle pose in the device's base
 * frame, meters and a unit quaternion; the wrench in the same frame, N and
 * N m. The runtime normalizes the quaternion; a pose with a non-finite value
 * or a zero quaternion counts as "no pose".
 *
 * Threads: every call into the plugin runs on one thread the runtime starts
 * for the device (its worker), one call at a time, never concurrently. The
 * runtime thread that makes the call waits for it with a deadline (hrt/device.h,
 * kPlugin*DeadlineMs):
 *   create, info, close, destroy  5 s: allocate, print, fail, but do not wait
 *                                 on the hardware for long;
 *   open                          30 s: find the device, calibrate, enable
 *                                 forces (the user may be asked to move the
 *                                 handle);
 *   read, write                   50 ms each, once per period each (1 kHz:
 *                                 read, then write), only between a
 *                                 successful open and close. They must return
 *                                 within a small part of the period and must
 *                                 not allocate, lock a mutex another thread
 *                                 may hold, block, sleep, print or log: the
 *                                 deadline is a last resort, not a budget. A
 *                                 device whose SDK runs its own servo thread
 *                                 (OpenHaptics' scheduler, DHD's own loop)
 *                                 exchanges data with it without locks
 *                                 (atomics, a double buffer).
 * A call still running at its deadline is a stall, and a stall is final: the
 * runtime never calls the plugin again (not even close or destroy), does not
 * wait for the stuck call (the worker is abandoned, the library stays
 * loaded), and the session ends as a device failure (`hrt run` exits 5
 * naming the plugin and the call). Nothing then reaches the device: its own
 * watchdog (SDK or firmware) must zero the force when writes stop arriving;
 * the runtime cannot, for a plugin it can no longer call.
 *
 * The entry function and the library's initializers run inside dlopen on the
 * loading thread, with no deadline: they only return the table and set up
 * constants; everything else belongs in create.
 *
 * Before dlopen the runtime checks the file: a regular file of at most
 * hrt::kMaxPluginBytes (hrt/files.h), a 64-bit ELF shared library of this
 * machine whose headers and segments all lie within the file (a truncated
 * copy would otherwise crash the loader with SIGBUS).
 *
 * Every string the runtime passes is valid for the duration of the call
 * only; strings the plugin returns (name, error messages) are copied at once.
 */
#ifndef HRT_DEVICE_PLUGIN_H
#define HRT_DEVICE_PLUGIN_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define HRT_DEVICE_PLUGIN_ABI 1
#define HRT_DEVICE_PLUGIN_ENTRY "hrt_device_plugin_v1"

#if defined(_WIN32)
#define HRT_PLUGIN_EXPORT __declspec(dllexport)
#else
#define HRT_PLUGIN_EXPORT __attribute__((visibility("default")))
#endif

/* What the device is and what it can display. The runtime fills the struct
 * with its defaults (hrt::DeviceInfo: "device", 6, 6, 0.1 m, 10 N, 0.5 N m,
 * 2000 N/m, 5 N m/rad) before calling info(); the plugin overwrites what it
 * knows. The scene file's explicit limits override the plugin's. */
typedef struct hrt_device_info {
  char name[64];                /* NUL-terminated (the runtime terminates it anyway) */
  int dof_sensed;               /* 6: position and orientation; 3: position only */
  int dof_actuated;             /* 6: force and torque; 3: force only */
  double workspace[3];          /* half extents of the workspace box, device frame, m */
  double max_force;             /* N, continuous */
  double max_torque;            /* N m */
  double max_stiffness;         /* N/m the device renders stably at 1 kHz */
  double max_angular_stiffness; /* N m/rad */
} hrt_device_info;

typedef struct hrt_device_plugin {
  uint32_t abi_version; /* HRT_DEVICE_PLUGIN_ABI */
  uint32_t struct_size; /* sizeof(hrt_device_plugin): later versions only append */

  /* A device instance from the scene file's config string (never NULL, may be
   * ""). NULL on failure, with a one-line message written into error[0 ..
   * error_size) (NUL-terminated). Does not touch the hardware yet. Required. */
  void* (*create)(const char* config, char* error, size_t error_size);
  /* Frees the instance (after close). Required. Not called after a stall. */
  void (*destroy)(void* handle);
  /* Fills *out (see hrt_device_info). 0 on success, nonzero with a message in
   * error on failure. Called after create and again after open (a device may
   * know its model only once opened). Required. */
  int (*info)(void* handle, hrt_device_info* out, char* error, size_t error_size);
  /* Opens and calibrates the device. 0 on success, nonzero with a message on
   * failure. Optional (NULL: nothing to open). The one call that may take
   * long: 30 s deadline. */
  int (*open)(void* handle, char* error, size_t error_size);
  /* Stops the device's forces and releases it. Optional. Not called after a
   * stall (a stuck call may hold what close needs). */
  void (*close)(void* handle);
  /* The latest handle pose at session time t (s): pose = x, y, z, qx, qy, qz,
   * qw; *buttons one bit per button, *clutch nonzero while the clutch (re-index)
   * button is held. Returns 1 when pose is valid, 0 when the device has no
   * pose (yet; the runtime holds the previous one), negative on a device
   * fault (also treated as no pose). Device thread, 50 ms deadline. Required. */
  int (*read)(void* handle, double t, double pose[7], uint32_t* buttons, int* clutch);
  /* Displays the wrench fx, fy, fz, tx, ty, tz (already clamped to the limits
   * and finite). Device thread, 50 ms deadline. Required. */
  void (*write)(void* handle, double t, const double wrench[6]);
} hrt_device_plugin;

/* The entry point every plugin exports under HRT_DEVICE_PLUGIN_ENTRY:
 *   HRT_PLUGIN_EXPORT const hrt_device_plugin* hrt_device_plugin_v1(void);
 * It returns a pointer to a table that lives as long as the library is loaded. */
typedef const hrt_device_plugin* (*hrt_device_plugin_entry_fn)(void);

#ifdef __cplusplus
}
#endif

#endif /* HRT_DEVICE_PLUGIN_H */
