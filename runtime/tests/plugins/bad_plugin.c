/* Broken device plugins for runtime/tests/test_plugin_device.cpp: each build
 * (HRT_BAD_PLUGIN_CASE) breaks one rule of hrt/device_plugin.h, so the test
 * can check that PluginDevice refuses it with a message naming the library,
 * or stops calling it when it blocks.
 *   1  the table's abi_version is 99
 *   2  the table's read function is NULL
 *   3  no entry symbol at all (another symbol is exported instead)
 *   4  create() fails with a message
 *   5  read() returns a still pose (the origin) while t < 0.3 s of session
 *      time, then blocks forever; config "block_after=S" moves the 0.3 s
 *      (an end-to-end session runs a while before the stall)
 *   6  open() blocks forever; with config "block=info", info() blocks
 *      instead (after create: a stall inside the constructor)
 *   7  write() blocks forever from its 4th call on (kWritesBeforeBlocking)
 * The blocking calls wait in pause() with no way out: the test process ends
 * with them still stuck, as `hrt run` would.
 *
 * Test hook: hrt_bad_plugin_calls() (exported besides the entry point)
 * copies how many times each function was entered, so the test can check
 * that a stalled plugin is not called again (no close, no destroy). */
#define _POSIX_C_SOURCE 200809L /* pause */
#include <stddef.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "hrt/device_plugin.h"

#ifndef HRT_BAD_PLUGIN_CASE
#error "define HRT_BAD_PLUGIN_CASE"
#endif

#define CASE_BLOCKING_READ 5
#define CASE_BLOCKING_OPEN 6
#define CASE_BLOCKING_WRITE 7

enum { kWritesBeforeBlocking = 3 };

/* Entries per function: create, destroy, info, open, close, read, write.
 * Atomic: the runtime calls from its worker thread, the test reads from its
 * own. */
static long g_calls[7];
static int g_block_info;
static double g_block_after = 0.3;

static void count(int i) { __atomic_fetch_add(&g_calls[i], 1, __ATOMIC_SEQ_CST); }

static void block_forever(void) {
  for (;;) pause();
}

static void* bad_create(const char* config, char* error, size_t error_size) {
  count(0);
  g_block_info = HRT_BAD_PLUGIN_CASE == CASE_BLOCKING_OPEN && config && strcmp(config, "block=info") == 0;
  g_block_after = config && strncmp(config, "block_after=", 12) == 0 ? strtod(config + 12, NULL) : 0.3;
#if HRT_BAD_PLUGIN_CASE == 4
  const char msg[] = "no device on the bus\nsecond line";
  size_t i = 0;
  for (; i + 1 < error_size && i < sizeof msg - 1; ++i) error[i] = msg[i];
  if (error_size) error[i] = '\0';
  return NULL;
#else
  (void)error;
  (void)error_size;
  static int instance;
  return &instance;
#endif
}
static void bad_destroy(void* handle) {
  (void)handle;
  count(1);
}
static int bad_info(void* handle, hrt_device_info* out, char* error, size_t error_size) {
  (void)handle, (void)out, (void)error, (void)error_size;
  count(2);
  if (g_block_info) block_forever();
  return 0;
}
static int bad_open(void* handle, char* error, size_t error_size) {
  (void)handle, (void)error, (void)error_size;
  count(3);
#if HRT_BAD_PLUGIN_CASE == CASE_BLOCKING_OPEN
  block_forever();
#endif
  return 0;
}
static void bad_close(void* handle) {
  (void)handle;
  count(4);
}
static int bad_read(void* handle, double t, double pose[7], uint32_t* buttons, int* clutch) {
  (void)handle, (void)t, (void)pose, (void)buttons, (void)clutch;
  count(5);
#if HRT_BAD_PLUGIN_CASE == CASE_BLOCKING_READ
  if (t >= g_block_after) block_forever();
  for (int i = 0; i < 6; ++i) pose[i] = 0.0;
  pose[6] = 1.0;
  return 1;
#else
  return 0;
#endif
}
static void bad_write(void* handle, double t, const double wrench[6]) {
  (void)handle, (void)t, (void)wrench;
  count(6);
#if HRT_BAD_PLUGIN_CASE == CASE_BLOCKING_WRITE
  if (__atomic_load_n(&g_calls[6], __ATOMIC_SEQ_CST) > kWritesBeforeBlocking) block_forever();
#endif
}

static const hrt_device_plugin kTable = {
#if HRT_BAD_PLUGIN_CASE == 1
    99,
#else
    HRT_DEVICE_PLUGIN_ABI,
#endif
    sizeof(hrt_device_plugin),
    bad_create,
    bad_destroy,
    bad_info,
    bad_open,
    bad_close,
#if HRT_BAD_PLUGIN_CASE == 2
    NULL,
#else
    bad_read,
#endif
    bad_write,
};

#if HRT_BAD_PLUGIN_CASE == 3
HRT_PLUGIN_EXPORT const hrt_device_plugin* some_other_entry(void) { return &kTable; }
#else
HRT_PLUGIN_EXPORT const hrt_device_plugin* hrt_device_plugin_v1(void) { return &kTable; }
#endif

HRT_PLUGIN_EXPORT void hrt_bad_plugin_calls(long calls[7]) {
  for (int i = 0; i < 7; ++i) calls[i] = __atomic_load_n(&g_calls[i], __ATOMIC_SEQ_CST);
}
