// PluginDevice (hrt/device.h): a device from a shared library implementing
// hrt/device_plugin.h (docs/device-plugins.md), loaded with dlopen.
#include <dlfcn.h>

#include <cmath>
#include <cstring>
#include <string>

#include "hrt/device.h"
#include "hrt/device_plugin.h"

namespace hrt {
namespace {

constexpr size_t kErrorSize = 512;

// A plugin's message as one line: terminated, newlines folded, never empty.
std::string plugin_message(char* buf) {
  buf[kErrorSize - 1] = '\0';
  std::string s(buf);
  for (char& c : s)
    if (c == '\n' || c == '\r') c = ' ';
  return s.empty() ? "(no message)" : s;
}

std::string dl_message() {
  const char* e = dlerror();
  return e ? e : "(no dlerror message)";
}

DeviceInfo convert(const hrt_device_info& c, const std::string& what) {
  DeviceInfo info;
  info.name = std::string(c.name, strnlen(c.name, sizeof c.name));
  if (info.name.empty()) info.name = "plugin";
  auto dof = [&](const char* key, int v) {
    if (v != 3 && v != 6) throw DeviceError(what + ": info: " + key + " " + std::to_string(v) + " (3 or 6)");
    return v;
  };
  auto positive = [&](const char* key, double v) {
    if (!(std::isfinite(v) && v > 0)) throw DeviceError(what + ": info: " + key + " " + std::to_string(v) + " (finite, > 0)");
    return v;
  };
  info.dof_sensed = dof("dof_sensed", c.dof_sensed);
  info.dof_actuated = dof("dof_actuated", c.dof_actuated);
  for (int i = 0; i < 3; ++i) info.workspace[i] = positive("workspace", c.workspace[i]);
  info.max_force = positive("max_force", c.max_force);
  info.max_torque = positive("max_torque", c.max_torque);
  info.max_stiffness = positive("max_stiffness", c.max_stiffness);
  info.max_angular_stiffness = positive("max_angular_stiffness", c.max_angular_stiffness);
  return info;
}

}  // namespace

struct PluginDevice::Impl {
  std::string what;  // "plugin PATH", the prefix of every message
  void* library = nullptr;
  const hrt_device_plugin* table = nullptr;
  void* handle = nullptr;
  bool opened = false;

  DeviceInfo query_info() {
    const DeviceInfo defaults;
    hrt_device_info c{};
    std::strncpy(c.name, defaults.name.c_str(), sizeof c.name - 1);
    c.dof_sensed = defaults.dof_sensed;
    c.dof_actuated = defaults.dof_actuated;
    for (int i = 0; i < 3; ++i) c.workspace[i] = defaults.workspace[i];
    c.max_force = defaults.max_force;
    c.max_torque = defaults.max_torque;
    c.max_stiffness = defaults.max_stiffness;
    c.max_angular_stiffness = defaults.max_angular_stiffness;
    char err[kErrorSize] = {0};
    if (table->info(handle, &c, err, sizeof err) != 0) throw DeviceError(what + ": info failed: " + plugin_message(err));
    return convert(c, what);
  }

  void unload() noexcept {
    if (handle && table) table->destroy(handle);
    handle = nullptr;
    if (library) dlclose(library);
    library = nullptr;
    table = nullptr;
  }
};

PluginDevice::PluginDevice(const std::string& library_path, const std::string& config) : impl_(new Impl) {
  Impl& m = *impl_;
  m.what = "plugin " + library_path;
  // RTLD_NOW: a plugin built against a missing SDK symbol fails here, with the
  // symbol's name, instead of at its first call on the device thread.
  // RTLD_LOCAL: two plugins may both define helpers of the same name.
  m.library = dlopen(library_path.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (!m.library) throw DeviceError(m.what + ": cannot load: " + dl_message());
  try {
    dlerror();
    void* entry = dlsym(m.library, HRT_DEVICE_PLUGIN_ENTRY);
    if (!entry)
      throw DeviceError(m.what + ": no entry symbol " HRT_DEVICE_PLUGIN_ENTRY " (" + dl_message() +
                        "): not an hrt device plugin (hrt/device_plugin.h)");
    hrt_device_plugin_entry_fn fn;
    static_assert(sizeof fn == sizeof entry, "function and data pointers differ in size");
    std::memcpy(&fn, &entry, sizeof fn);
    m.table = fn();
    if (!m.table) throw DeviceError(m.what + ": " HRT_DEVICE_PLUGIN_ENTRY "() returned NULL");
    if (m.table->abi_version != HRT_DEVICE_PLUGIN_ABI)
      throw DeviceError(m.what + ": plugin ABI version " + std::to_string(m.table->abi_version) +
                        ", this runtime needs " + std::to_string(HRT_DEVICE_PLUGIN_ABI) +
                        " (rebuild the plugin against this hrt/device_plugin.h)");
    if (m.table->struct_size < sizeof(hrt_device_plugin))
      throw DeviceError(m.what + ": function table of " + std::to_string(m.table->struct_size) + " bytes, ABI " +
                        std::to_string(HRT_DEVICE_PLUGIN_ABI) + " needs " + std::to_string(sizeof(hrt_device_plugin)));
    const struct {
      const char* name;
      bool present;
    } required[] = {{"create", m.table->create != nullptr}, {"destroy", m.table->destroy != nullptr},
                    {"info", m.table->info != nullptr},     {"read", m.table->read != nullptr},
                    {"write", m.table->write != nullptr}};
    for (const auto& r : required)
      if (!r.present) throw DeviceError(m.what + ": required function '" + r.name + "' is NULL in its table");
    char err[kErrorSize] = {0};
    m.handle = m.table->create(config.c_str(), err, sizeof err);
    if (!m.handle) throw DeviceError(m.what + ": create failed: " + plugin_message(err));
    info_ = m.query_info();
  } catch (...) {
    m.unload();
    throw;
  }
}

PluginDevice::~PluginDevice() {
  close();
  impl_->unload();
}

void PluginDevice::open() {
  Impl& m = *impl_;
  if (m.opened) return;
  if (m.table->open) {
    char err[kErrorSize] = {0};
    if (m.table->open(m.handle, err, sizeof err) != 0) throw DeviceError(m.what + ": open failed: " + plugin_message(err));
  }
  m.opened = true;
  try {
    info_ = m.query_info();  // the model may be known only now
  } catch (...) {
    close();
    throw;
  }
}

void PluginDevice::close() {
  Impl& m = *impl_;
  if (!m.opened) return;
  if (m.table->close) m.table->close(m.handle);
  m.opened = false;
}

bool PluginDevice::read(double t, DeviceSample& out) noexcept {
  Impl& m = *impl_;
  if (!m.opened) return false;  // the interface promises read only between open and close
  double pose[7] = {0, 0, 0, 0, 0, 0, 1};
  uint32_t buttons = 0;
  int clutch = 0;
  if (m.table->read(m.handle, t, pose, &buttons, &clutch) <= 0) return false;
  for (double v : pose)
    if (!std::isfinite(v)) return false;
  Eigen::Quaterniond q(pose[6], pose[3], pose[4], pose[5]);
  const double norm = q.norm();
  if (norm < 1e-6) return false;
  out.pose.position = Vec3(pose[0], pose[1], pose[2]);
  out.pose.rotation = info_.dof_sensed == 3 ? Eigen::Quaterniond::Identity() : Eigen::Quaterniond(q.coeffs() / norm);
  out.buttons = buttons;
  out.clutch = clutch != 0;
  return true;
}

void PluginDevice::write(double t, const Vec6& wrench) noexcept {
  Impl& m = *impl_;
  if (!m.opened) return;
  const double w[6] = {wrench[0], wrench[1], wrench[2], wrench[3], wrench[4], wrench[5]};
  m.table->write(m.handle, t, w);
}

}  // namespace hrt
