/* Broken device plugins for runtime/tests/test_plugin_device.cpp: each build
 * (HRT_BAD_PLUGIN_CASE) breaks one rule of hrt/device_plugin.h, so the test
 * can check that PluginDevice refuses it with a message naming the library.
 *   1  the table's abi_version is 99
 *   2  the table's read function is NULL
 *   3  no entry symbol at all (another symbol is exported instead)
 *   4  create() fails with a message */
#include <stddef.h>

#include "hrt/device_plugin.h"

#ifndef HRT_BAD_PLUGIN_CASE
#error "define HRT_BAD_PLUGIN_CASE"
#endif

static void* bad_create(const char* config, char* error, size_t error_size) {
  (void)config;
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
static void bad_destroy(void* handle) { (void)handle; }
static int bad_info(void* handle, hrt_device_info* out, char* error, size_t error_size) {
  (void)handle, (void)out, (void)error, (void)error_size;
  return 0;
}
static int bad_read(void* handle, double t, double pose[7], uint32_t* buttons, int* clutch) {
  (void)handle, (void)t, (void)pose, (void)buttons, (void)clutch;
  return 0;
}
static void bad_write(void* handle, double t, const double wrench[6]) { (void)handle, (void)t, (void)wrench; }

static const hrt_device_plugin kTable = {
#if HRT_BAD_PLUGIN_CASE == 1
    99,
#else
    HRT_DEVICE_PLUGIN_ABI,
#endif
    sizeof(hrt_device_plugin), bad_create, bad_destroy, bad_info, NULL, NULL,
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
