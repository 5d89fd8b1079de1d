/* An example hrt device plugin (hrt/device_plugin.h, docs/device-plugins.md):
 * a virtual handle that moves on a circle or a line and remembers the wrench
 * it is given. Built as the MODULE library hrt_example_device.so by
 * runtime/CMakeLists.txt and loaded by runtime/tests/test_plugin_device.cpp;
 * a starting point for wrapping a real SDK (examples/plugins/ has a skeleton
 * for Force Dimension's DHD).
 *
 * Config string: space-separated key=value pairs, all optional:
 *   path=circle|line|still  circle: radius r in the xy plane, turning about z
 *                           with it; line: x = r sin(2 pi t / period); default circle
 *   radius=R                m, default 0.05
 *   period=T                s, default 2
 *   z=Z                     m, height of the path, default 0
 *   clutch_after=S          s: the clutch reads held from t >= S on (default never)
 *   max_force=F             N, reported in info (default 5)
 *   name=NAME               reported in info (default "example")
 * An unknown key or a malformed value makes create() fail with a message.
 *
 * Test hook: hrt_example_last_wrench() (exported besides the entry point)
 * returns how many wrenches any instance was written and copies the last one
 * and its time, so a test can check that writes reach the plugin. A real
 * plugin does not need it.
 */
#define _POSIX_C_SOURCE 200809L /* strdup, strtok_r */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hrt/device_plugin.h"

typedef struct example_device {
  int path; /* 0 circle, 1 line, 2 still */
  double radius, period, z, clutch_after, max_force;
  char name[64];
  int opened;
} example_device;

/* Written on the device thread, read by the test after the fact: the test
 * reads only once the device loop (or its own calls) stopped. */
static double g_last_wrench[6];
static double g_last_time;
static long g_writes;

static const double kPi = 3.14159265358979323846;

static int parse_double(const char* s, double* out) {
  char* end = NULL;
  double v = strtod(s, &end);
  if (end == s || *end != '\0' || !isfinite(v)) return 0;
  *out = v;
  return 1;
}

static void* example_create(const char* config, char* error, size_t error_size) {
  example_device* d = (example_device*)calloc(1, sizeof *d);
  char* copy = strdup(config ? config : "");
  char* save = NULL;
  if (!d || !copy) {
    snprintf(error, error_size, "example: out of memory");
    free(d);
    free(copy);
    return NULL;
  }
  d->path = 0;
  d->radius = 0.05;
  d->period = 2.0;
  d->clutch_after = INFINITY;
  d->max_force = 5.0;
  snprintf(d->name, sizeof d->name, "example");
  for (char* tok = strtok_r(copy, " \t", &save); tok; tok = strtok_r(NULL, " \t", &save)) {
    char* eq = strchr(tok, '=');
    int ok = 0;
    if (eq) {
      *eq = '\0';
      const char* key = tok;
      const char* val = eq + 1;
      if (strcmp(key, "path") == 0) {
        ok = 1;
        if (strcmp(val, "circle") == 0)
          d->path = 0;
        else if (strcmp(val, "line") == 0)
          d->path = 1;
        else if (strcmp(val, "still") == 0)
          d->path = 2;
        else
          ok = 0;
      } else if (strcmp(key, "radius") == 0) {
        ok = parse_double(val, &d->radius) && d->radius >= 0;
      } else if (strcmp(key, "period") == 0) {
        ok = parse_double(val, &d->period) && d->period > 0;
      } else if (strcmp(key, "z") == 0) {
        ok = parse_double(val, &d->z);
      } else if (strcmp(key, "clutch_after") == 0) {
        ok = parse_double(val, &d->clutch_after);
      } else if (strcmp(key, "max_force") == 0) {
        ok = parse_double(val, &d->max_force) && d->max_force > 0;
      } else if (strcmp(key, "name") == 0) {
        ok = val[0] != '\0';
        snprintf(d->name, sizeof d->name, "%s", val);
      } else {
        snprintf(error, error_size,
                 "example: unknown config key '%s' (path, radius, period, z, clutch_after, "
                 "max_force, name)",
                 key);
        free(copy);
        free(d);
        return NULL;
      }
      if (!ok) {
        snprintf(error, error_size, "example: bad value '%s' for %s", val, key);
        free(copy);
        free(d);
        return NULL;
      }
    } else {
      snprintf(error, error_size, "example: '%s' is not key=value", tok);
      free(copy);
      free(d);
      return NULL;
    }
  }
  free(copy);
  return d;
}

static void example_destroy(void* handle) { free(handle); }

static int example_info(void* handle, hrt_device_info* out, char* error, size_t error_size) {
  (void)error;
  (void)error_size;
  const example_device* d = (const example_device*)handle;
  snprintf(out->name, sizeof out->name, "%s", d->name);
  out->dof_sensed = 6;
  out->dof_actuated = 6;
  out->workspace[0] = out->workspace[1] = d->radius + 0.01;
  out->workspace[2] = fabs(d->z) + 0.01;
  out->max_force = d->max_force;
  out->max_torque = 0.2;
  out->max_stiffness = 1500.0;
  /* max_angular_stiffness: the runtime's default is kept. */
  return 0;
}

static int example_open(void* handle, char* error, size_t error_size) {
  (void)error;
  (void)error_size;
  ((example_device*)handle)->opened = 1;
  return 0;
}

static void example_close(void* handle) { ((example_device*)handle)->opened = 0; }

/* Device thread: arithmetic only, no allocation, no locks, no I/O. */
static int example_read(void* handle, double t, double pose[7], uint32_t* buttons, int* clutch) {
  const example_device* d = (const example_device*)handle;
  if (!d->opened) return 0;
  const double a = 2.0 * kPi * t / d->period;
  pose[3] = pose[4] = 0.0;
  pose[5] = 0.0;
  pose[6] = 1.0;
  if (d->path == 0) {
    pose[0] = d->radius * cos(a);
    pose[1] = d->radius * sin(a);
    pose[5] = sin(a / 2);
    pose[6] = cos(a / 2);
  } else if (d->path == 1) {
    pose[0] = d->radius * sin(a);
    pose[1] = 0.0;
  } else {
    pose[0] = pose[1] = 0.0;
  }
  pose[2] = d->z;
  *buttons = 0;
  *clutch = t >= d->clutch_after;
  return 1;
}

static void example_write(void* handle, double t, const double wrench[6]) {
  (void)handle;
  memcpy(g_last_wrench, wrench, sizeof g_last_wrench);
  g_last_time = t;
  ++g_writes;
}

static const hrt_device_plugin kTable = {
    HRT_DEVICE_PLUGIN_ABI, sizeof(hrt_device_plugin),
    example_create,        example_destroy,
    example_info,          example_open,
    example_close,         example_read,
    example_write,
};

HRT_PLUGIN_EXPORT const hrt_device_plugin* hrt_device_plugin_v1(void) { return &kTable; }

HRT_PLUGIN_EXPORT long hrt_example_last_wrench(double wrench[6], double* t) {
  memcpy(wrench, g_last_wrench, sizeof g_last_wrench);
  *t = g_last_time;
  return g_writes;
}
