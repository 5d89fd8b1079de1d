// Device plugins (hrt/device_plugin.h, docs/device-plugins.md): the example
// plugin (runtime/plugins/example) loads, reports its info, reads poses on
// its circle and receives writes; broken plugins (runtime/tests/plugins) and
// a missing library are refused with a DeviceError naming the file.
#include <gtest/gtest.h>

#include <dlfcn.h>

#include <cmath>
#include <string>

#include "hrt/device.h"

namespace {

using hrt::PluginDevice;

std::string load_error(const std::string& path, const std::string& config = "") {
  try {
    PluginDevice dev(path, config);
  } catch (const hrt::DeviceError& e) {
    return e.what();
  }
  return "(no error)";
}

// The example's test hook, from the library PluginDevice loaded (RTLD_NOLOAD:
// the same instance, not a second copy).
long last_wrench(double w[6], double* t) {
  void* lib = dlopen(HRT_EXAMPLE_PLUGIN, RTLD_NOW | RTLD_NOLOAD);
  EXPECT_NE(lib, nullptr) << "the example plugin is not loaded";
  if (!lib) return -1;
  auto fn = reinterpret_cast<long (*)(double*, double*)>(dlsym(lib, "hrt_example_last_wrench"));
  EXPECT_NE(fn, nullptr);
  const long n = fn ? fn(w, t) : -1;
  dlclose(lib);
  return n;
}

}  // namespace

TEST(PluginDevice, LoadsTheExampleAndReportsItsInfo) {
  PluginDevice dev(HRT_EXAMPLE_PLUGIN, "path=circle radius=0.04 period=2 z=0.01 max_force=7 name=bench");
  const hrt::DeviceInfo& info = dev.info();
  EXPECT_EQ(info.name, "bench");
  EXPECT_EQ(info.dof_sensed, 6);
  EXPECT_EQ(info.dof_actuated, 6);
  EXPECT_DOUBLE_EQ(info.max_force, 7.0);
  EXPECT_DOUBLE_EQ(info.max_torque, 0.2);
  EXPECT_DOUBLE_EQ(info.max_stiffness, 1500.0);
  EXPECT_DOUBLE_EQ(info.max_angular_stiffness, hrt::DeviceInfo().max_angular_stiffness);  // not set: the default
  EXPECT_TRUE(info.workspace.isApprox(hrt::Vec3(0.05, 0.05, 0.02)));
}

// Poses on the example's circle (radius 0.04 m, one turn per 2 s, turning
// about z with it): at t = 0.5 s a quarter turn, at (0, 0.04, 0.01).
TEST(PluginDevice, ReadsPosesBetweenOpenAndClose) {
  PluginDevice dev(HRT_EXAMPLE_PLUGIN, "radius=0.04 period=2 z=0.01 clutch_after=1");
  hrt::DeviceSample s;
  EXPECT_FALSE(dev.read(0.5, s));  // not open yet
  dev.open();
  ASSERT_TRUE(dev.read(0.5, s));
  EXPECT_NEAR(s.pose.position.x(), 0.0, 1e-15);
  EXPECT_NEAR(s.pose.position.y(), 0.04, 1e-15);
  EXPECT_NEAR(s.pose.position.z(), 0.01, 1e-15);
  EXPECT_NEAR(s.pose.rotation.angularDistance(Eigen::Quaterniond(Eigen::AngleAxisd(M_PI / 2, hrt::Vec3::UnitZ()))),
              0.0, 1e-12);
  EXPECT_FALSE(s.clutch);
  ASSERT_TRUE(dev.read(1.25, s));
  EXPECT_NEAR(s.pose.position.x(), 0.04 * std::cos(1.25 * M_PI), 1e-15);
  EXPECT_NEAR(s.pose.position.y(), 0.04 * std::sin(1.25 * M_PI), 1e-15);
  EXPECT_TRUE(s.clutch);
  dev.close();
  EXPECT_FALSE(dev.read(0.5, s));
}

TEST(PluginDevice, WritesReachThePlugin) {
  PluginDevice dev(HRT_EXAMPLE_PLUGIN, "path=line");
  double w[6], t = 0;
  hrt::Vec6 wrench;
  wrench << 1.0, -2.0, 3.0, 0.1, -0.2, 0.3;
  dev.write(0.1, wrench);  // before open: not passed on
  const long before = last_wrench(w, &t);
  dev.open();
  dev.write(0.75, wrench);
  ASSERT_EQ(last_wrench(w, &t), before + 1);
  EXPECT_EQ(t, 0.75);
  for (int i = 0; i < 6; ++i) EXPECT_EQ(w[i], wrench[i]) << i;
  dev.write(0.76, 2 * wrench);
  ASSERT_EQ(last_wrench(w, &t), before + 2);
  EXPECT_EQ(w[2], 6.0);
  dev.close();
  dev.write(0.77, wrench);
  EXPECT_EQ(last_wrench(w, &t), before + 2);
}

// Every refusal is one line starting with "plugin PATH: " and says what is wrong.
TEST(PluginDevice, BrokenPluginsAreRefusedNamingTheFile) {
  struct Case {
    std::string path, config, what;
  };
  const Case cases[] = {
      {"/nonexistent/hrt_plugin.so", "", ": cannot load: /nonexistent/hrt_plugin.so: cannot open shared object file"},
      {HRT_TEST_PLUGIN_NO_ENTRY, "", ": no entry symbol hrt_device_plugin_v1 ("},
      {HRT_TEST_PLUGIN_WRONG_ABI, "", ": plugin ABI version 99, this runtime needs 1"},
      {HRT_TEST_PLUGIN_NULL_READ, "", ": required function 'read' is NULL"},
      {HRT_TEST_PLUGIN_CREATE_FAILS, "", ": create failed: no device on the bus second line"},
      {HRT_EXAMPLE_PLUGIN, "radius=0.1 colour=red", ": create failed: example: unknown config key 'colour'"},
      {HRT_EXAMPLE_PLUGIN, "period=-1", ": create failed: example: bad value '-1' for period"},
  };
  for (const Case& c : cases) {
    const std::string msg = load_error(c.path, c.config);
    EXPECT_EQ(msg.rfind("plugin " + c.path + c.what, 0), 0u) << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
  }
  // A refused plugin is unloaded again; the good one still loads after them.
  EXPECT_EQ(dlopen(HRT_TEST_PLUGIN_WRONG_ABI, RTLD_NOW | RTLD_NOLOAD), nullptr);
  PluginDevice ok(HRT_EXAMPLE_PLUGIN, "");
  EXPECT_EQ(ok.info().name, "example");
}
