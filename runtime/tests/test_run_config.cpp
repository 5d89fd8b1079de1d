// Scene files of `hrt run` (docs/scene-format.md) and the trace writer
// (docs/trace-format.md).
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "hrt/run_config.h"
#include "hrt/trajectory.h"
#include "trace_spec.h"

namespace {

namespace fs = std::filesystem;

void write_text(const fs::path& p, const std::string& text) {
  std::ofstream out(p, std::ios::binary);
  out << text;
  ASSERT_TRUE(out.good()) << p;
}

std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// Two objects and no device.
const std::string kObjects =
    "[[object]]\nbundle = \"models/probe.hbundle\"\n[[object]]\nbundle = \"models/plate.hbundle\"\n";

const char* kTrajectory = "t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n1,0.01,0,0,0,0,0,1\n";

// A folder with two (empty) bundle folders and trajectories: the loader
// checks that they exist but does not load them.
class RunConfig : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::path(::testing::TempDir()) / ("hrt_run_config_" + std::to_string(::getpid()) + "_" +
                                             ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "models" / "probe.hbundle");
    fs::create_directories(dir_ / "models" / "plate.hbundle");
    fs::create_directories(dir_ / "models" / "cup.hbundle");
    fs::create_directories(dir_ / "out");
    write_text(dir_ / "slide.csv", kTrajectory);
    write_text(dir_ / "models" / "cup_path.csv", kTrajectory);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string scene(const std::string& text, const std::string& name = "scene.toml") {
    const fs::path p = dir_ / name;
    write_text(p, text);
    return p.string();
  }
  std::string file(const std::string& rel) const { return (dir_ / rel).lexically_normal().string(); }

  // The smallest valid scene, with `extra` appended.
  static std::string minimal(const std::string& extra = "") {
    return "[[object]]\nbundle = \"models/probe.hbundle\"\n"
           "[[object]]\nbundle = \"models/plate.hbundle\"\n"
           "[device]\ntrajectory = \"slide.csv\"\n" +
           extra;
  }

  // Loads `text` and expects a SceneFileError for `key` whose message
  // contains `fragment`; the message is one line "FILE: KEY: ...".
  void expect_error(const std::string& text, const std::string& key, const std::string& fragment) {
    const std::string path = scene(text);
    try {
      hrt::load_run_config(path);
      ADD_FAILURE() << "no error for key " << key << " in:\n" << text;
    } catch (const hrt::SceneFileError& e) {
      const std::string what = e.what();
      EXPECT_EQ(e.file, path);
      EXPECT_EQ(e.key, key) << what;
      const std::string prefix = path + ": " + (key.empty() ? "" : key + ": ");
      EXPECT_EQ(what.rfind(prefix, 0), 0u) << what;
      EXPECT_NE(what.find(fragment), std::string::npos) << what;
      EXPECT_EQ(what.find('\n'), std::string::npos) << what;
    }
  }

  fs::path dir_;
};

TEST_F(RunConfig, FullSceneParsesToItsValues) {
  const std::string text = R"(
[run]
duration = 2.5
lockstep = true
sim_every = 4
max_step = 0.01
backend = "cpu"

[[object]]
name = "block"
bundle = "models/probe.hbundle"
position = [0.0, 0.01, 0.02]
orientation = [0.0, 0.0, 0.70710678118654752, 0.70710678118654752]

[[object]]
name = "plate"
bundle = "models/plate.hbundle"

[[object]]
name = "cup"
bundle = "models/cup.hbundle"
position = [1, 2, 3]
trajectory = "models/cup_path.csv"

[force]
stiffness = 2500
resolution = 64
lin_step = 1e-4
ang_step = 2e-3
shortcut = true
heights = "coarse"
margin = 0.0005
max_patches = 8
auto_resolution = true
max_resolution = 96
fade_time = 0.05

[probe]
density = 1200.0
gravity = [0, 0, -9.81]

[coupling]
enabled = true
k_lin = 1500.0
b_lin = 4.0
k_ang = 3.0
b_ang = 0.01

[friction]
enabled = true
mu_static = 0.4
mu_dynamic = 0.3

[[material]]
object = "cup"
stiffness = 1800.0
mu_static = 0.6

[workspace]
scale = 2.0
offset_position = [0.1, 0.2, 0.3]
offset_orientation = [0, 0, 1, 0]
grasp_position = [0, 0, 0.05]
grasp_orientation = [1, 0, 0, 0]

[device]
type = "scripted"
trajectory = "slide.csv"
trajectory_prefix = "device_"
name = "phantom"
dof_actuated = 3
dof_sensed = 6
workspace = [0.08, 0.06, 0.04]
max_force = 8.0
max_torque = 0.3
max_stiffness = 2500.0
max_angular_stiffness = 4.0

[loop]
period = 0.0005
watchdog = 0.1
watchdog_ramp = 0.02
soft_start = 0.25
max_force_rate = 500.0
max_torque_rate = 20.0
multirate = false
realtime = true
priority = 70
log_capacity = 1000

[trace]
path = "out/trace.csv"
device_log = "out/device.csv"
)";
  const std::string path = scene(text);
  const hrt::RunConfig c = hrt::load_run_config(path);
  EXPECT_EQ(c.file, path);
  EXPECT_DOUBLE_EQ(c.duration, 2.5);
  EXPECT_TRUE(c.lockstep);
  EXPECT_EQ(c.sim_every, 4);
  EXPECT_DOUBLE_EQ(c.max_step, 0.01);
  EXPECT_EQ(c.backend, "cpu");

  ASSERT_EQ(c.objects.size(), 3u);
  EXPECT_EQ(c.objects[0].name, "block");
  EXPECT_EQ(c.objects[0].bundle, file("models/probe.hbundle"));
  EXPECT_TRUE(c.objects[0].pose.position.isApprox(hrt::Vec3(0.0, 0.01, 0.02)));
  EXPECT_NEAR(c.objects[0].pose.rotation.z(), std::sqrt(0.5), 1e-15);
  EXPECT_NEAR(c.objects[0].pose.rotation.w(), std::sqrt(0.5), 1e-15);
  EXPECT_NEAR(c.objects[0].pose.rotation.x(), 0.0, 0.0);
  EXPECT_EQ(c.objects[0].trajectory, "");
  EXPECT_EQ(c.objects[1].name, "plate");
  EXPECT_EQ(c.objects[1].trajectory, "");
  EXPECT_EQ(c.objects[2].name, "cup");
  EXPECT_EQ(c.objects[2].pose.position, hrt::Vec3(1, 2, 3));
  EXPECT_EQ(c.objects[2].trajectory, file("models/cup_path.csv"));

  EXPECT_DOUBLE_EQ(c.scene.force.stiffness, 2500.0);
  EXPECT_EQ(c.scene.force.resolution, 64);
  EXPECT_DOUBLE_EQ(c.scene.force.lin_step, 1e-4);
  EXPECT_DOUBLE_EQ(c.scene.force.ang_step, 2e-3);
  EXPECT_TRUE(c.scene.force.shortcut);
  EXPECT_EQ(c.scene.force.heights, hrt::HeightMode::coarse);
  EXPECT_DOUBLE_EQ(c.scene.collision.margin, 0.0005);
  EXPECT_EQ(c.scene.cluster.max_patches, 8);
  EXPECT_TRUE(c.scene.cluster.auto_resolution);
  EXPECT_EQ(c.scene.cluster.max_resolution, 96);
  EXPECT_DOUBLE_EQ(c.session.fade_time, 0.05);

  EXPECT_DOUBLE_EQ(c.session.density, 1200.0);
  EXPECT_EQ(c.session.gravity, hrt::Vec3(0, 0, -9.81));
  EXPECT_TRUE(c.session.coupling_enabled);
  EXPECT_FALSE(c.coupling_from_device);
  EXPECT_DOUBLE_EQ(c.session.coupling.k_lin, 1500.0);
  EXPECT_DOUBLE_EQ(c.session.coupling.b_lin, 4.0);
  EXPECT_DOUBLE_EQ(c.session.coupling.k_ang, 3.0);
  EXPECT_DOUBLE_EQ(c.session.coupling.b_ang, 0.01);

  EXPECT_TRUE(c.session.friction);
  EXPECT_DOUBLE_EQ(c.session.material.stiffness, 0.0);  // 0: the scene's k
  EXPECT_DOUBLE_EQ(c.session.material.mu_static, 0.4);
  EXPECT_DOUBLE_EQ(c.session.material.mu_dynamic, 0.3);
  ASSERT_EQ(c.session.materials.size(), 3u);
  // plate: no [[material]], the default; cup: its own k and mu_s, the rest inherited.
  EXPECT_DOUBLE_EQ(c.session.materials[1].stiffness, 0.0);
  EXPECT_DOUBLE_EQ(c.session.materials[1].mu_static, 0.4);
  EXPECT_DOUBLE_EQ(c.session.materials[2].stiffness, 1800.0);
  EXPECT_DOUBLE_EQ(c.session.materials[2].mu_static, 0.6);
  EXPECT_DOUBLE_EQ(c.session.materials[2].mu_dynamic, 0.3);

  EXPECT_DOUBLE_EQ(c.loop.map.scale, 2.0);
  EXPECT_EQ(c.loop.map.offset.position, hrt::Vec3(0.1, 0.2, 0.3));
  EXPECT_DOUBLE_EQ(c.loop.map.offset.rotation.z(), 1.0);
  EXPECT_EQ(c.loop.map.grasp.position, hrt::Vec3(0, 0, 0.05));
  EXPECT_DOUBLE_EQ(c.loop.map.grasp.rotation.x(), 1.0);

  EXPECT_EQ(c.device.type, "scripted");
  EXPECT_EQ(c.device.trajectory, file("slide.csv"));
  EXPECT_EQ(c.device.trajectory_prefix, "device_");
  EXPECT_EQ(c.device.info.name, "phantom");
  EXPECT_EQ(c.device.info.dof_actuated, 3);
  EXPECT_EQ(c.device.info.dof_sensed, 6);
  EXPECT_EQ(c.device.info.workspace, hrt::Vec3(0.08, 0.06, 0.04));
  EXPECT_DOUBLE_EQ(c.device.info.max_force, 8.0);
  EXPECT_DOUBLE_EQ(c.device.info.max_torque, 0.3);
  EXPECT_DOUBLE_EQ(c.device.info.max_stiffness, 2500.0);
  EXPECT_DOUBLE_EQ(c.device.info.max_angular_stiffness, 4.0);
  EXPECT_TRUE(c.device.max_force_set && c.device.max_torque_set && c.device.max_stiffness_set &&
              c.device.max_angular_stiffness_set && c.device.dof_actuated_set);
  // The session's device-side stiffness caps are the device's limits.
  EXPECT_DOUBLE_EQ(c.session.max_device_stiffness, 2500.0);
  EXPECT_DOUBLE_EQ(c.session.max_device_angular_stiffness, 4.0);

  EXPECT_DOUBLE_EQ(c.loop.period, 0.0005);
  EXPECT_DOUBLE_EQ(c.loop.watchdog, 0.1);
  EXPECT_DOUBLE_EQ(c.loop.watchdog_ramp, 0.02);
  EXPECT_DOUBLE_EQ(c.loop.soft_start, 0.25);
  EXPECT_DOUBLE_EQ(c.loop.max_force_rate, 500.0);
  EXPECT_DOUBLE_EQ(c.loop.max_torque_rate, 20.0);
  EXPECT_FALSE(c.loop.multirate);
  EXPECT_TRUE(c.loop.realtime);
  EXPECT_EQ(c.loop.realtime_priority, 70);
  EXPECT_EQ(c.loop.log_capacity, 1000u);

  EXPECT_EQ(c.trace.path, file("out/trace.csv"));
  EXPECT_EQ(c.trace.device_log, file("out/device.csv"));
}

TEST_F(RunConfig, DefaultsOfAMinimalScene) {
  const hrt::RunConfig c = hrt::load_run_config(scene(minimal()));
  const hrt::RunConfig d;  // the struct's own defaults
  const hrt::SessionOptions so;
  const hrt::DeviceLoopOptions lo;
  const hrt::DeviceInfo di;
  EXPECT_EQ(c.duration, d.duration);
  EXPECT_FALSE(c.lockstep);
  EXPECT_EQ(c.sim_every, 1);
  EXPECT_EQ(c.max_step, d.max_step);
  EXPECT_EQ(c.backend, "cpu");
  ASSERT_EQ(c.objects.size(), 2u);
  EXPECT_EQ(c.objects[0].name, "object0");
  EXPECT_EQ(c.objects[1].name, "object1");
  EXPECT_EQ(c.objects[1].pose.position, hrt::Vec3::Zero());
  EXPECT_EQ(c.objects[1].pose.rotation.coeffs(), Eigen::Quaterniond::Identity().coeffs());
  EXPECT_EQ(c.scene.force.stiffness, hrt::kDefaultStiffness);
  EXPECT_EQ(c.scene.force.resolution, hrt::kDefaultResolution);
  EXPECT_EQ(c.scene.force.heights, hrt::HeightMode::surface);
  EXPECT_FALSE(c.scene.force.shortcut);
  EXPECT_LT(c.scene.collision.margin, 0.0);  // automatic
  EXPECT_EQ(c.session.density, so.density);
  EXPECT_EQ(c.session.gravity, hrt::Vec3::Zero());
  EXPECT_TRUE(c.session.coupling_enabled);
  EXPECT_TRUE(c.coupling_from_device);
  EXPECT_LT(c.session.coupling.k_lin, 0.0);  // left for default_coupling
  EXPECT_FALSE(c.session.friction);
  EXPECT_TRUE(c.session.materials.empty());
  EXPECT_EQ(c.session.fade_time, so.fade_time);
  EXPECT_EQ(c.loop.period, lo.period);
  EXPECT_LT(c.loop.watchdog, 0.0);  // automatic
  EXPECT_EQ(c.loop.soft_start, lo.soft_start);
  EXPECT_LT(c.loop.max_force_rate, 0.0);
  EXPECT_TRUE(c.loop.multirate);
  EXPECT_EQ(c.loop.log_capacity, 0u);
  EXPECT_EQ(c.loop.map.scale, 1.0);
  EXPECT_EQ(c.device.type, "scripted");
  EXPECT_EQ(c.device.trajectory_prefix, "");
  EXPECT_FALSE(c.device.max_force_set || c.device.max_torque_set || c.device.max_stiffness_set ||
               c.device.max_angular_stiffness_set || c.device.dof_actuated_set);
  EXPECT_EQ(c.device.info.max_force, di.max_force);
  EXPECT_EQ(c.device.info.dof_actuated, 6);
  EXPECT_EQ(c.session.max_device_stiffness, di.max_stiffness);
  EXPECT_EQ(c.trace.path, "");
  EXPECT_EQ(c.trace.device_log, "");
}

TEST_F(RunConfig, DisabledCouplingNeedsNoGainsAndDeviceLogSizesItself) {
  const hrt::RunConfig c = hrt::load_run_config(
      scene(minimal("[coupling]\nenabled = false\n[run]\nduration = 2\n[trace]\ndevice_log = \"out/d.csv\"\n")));
  EXPECT_FALSE(c.session.coupling_enabled);
  EXPECT_FALSE(c.coupling_from_device);
  // The whole session: (2 s + the 10 ms stop ramp) / 1 ms + 1.
  EXPECT_EQ(c.loop.log_capacity, 2011u);
}

TEST_F(RunConfig, UdpAndPluginDevices) {
  const hrt::RunConfig u = hrt::load_run_config(
      scene(kObjects +
            "[device]\ntype = \"udp\"\nbind = \"0.0.0.0\"\nport = 0\nreply_address = \"10.0.0.2\"\nreply_port = 9000\n"
            "display_port = 47801\ndisplay_rate = 30\nmax_force = 3\n"));
  EXPECT_EQ(u.device.type, "udp");
  EXPECT_EQ(u.device.udp.bind_address, "0.0.0.0");
  EXPECT_EQ(u.device.udp.port, 0);
  EXPECT_EQ(u.device.udp.reply_address, "10.0.0.2");
  EXPECT_EQ(u.device.udp.reply_port, 9000);
  EXPECT_EQ(u.device.udp.display_address, "127.0.0.1");
  EXPECT_EQ(u.device.udp.display_port, 47801);
  EXPECT_EQ(u.device.udp.display_rate_hz, 30.0);
  EXPECT_EQ(u.device.info.max_force, 3.0);

  write_text(dir_ / "libdev.so", "not really a library: the loader only checks that it exists");
  const hrt::RunConfig p = hrt::load_run_config(scene(
      kObjects + "[device]\ntype = \"plugin\"\nplugin = \"libdev.so\"\nconfig = \"serial=42\"\nmax_stiffness = 900\n"));
  EXPECT_EQ(p.device.plugin, file("libdev.so"));
  EXPECT_EQ(p.device.plugin_config, "serial=42");
  EXPECT_TRUE(p.device.max_stiffness_set);
  EXPECT_FALSE(p.device.max_force_set);
}

TEST_F(RunConfig, RelativePathsResolveAgainstTheSceneFolder) {
  fs::create_directories(dir_ / "scenes" / "deep");
  write_text(dir_ / "scenes" / "deep" / "local.csv", kTrajectory);
  const std::string text =
      "[[object]]\nbundle = \"../../models/probe.hbundle\"\n"
      "[[object]]\nbundle = \"" +
      (dir_ / "models" / "plate.hbundle").string() +
      "\"\n"  // absolute stays
      "[device]\ntrajectory = \"local.csv\"\n"
      "[trace]\npath = \"../../out/t.csv\"\n";
  const std::string path = scene(text, "scenes/deep/s.toml");
  // From another working directory: the paths must not depend on it.
  const fs::path cwd = fs::current_path();
  fs::current_path(dir_ / "out");
  hrt::RunConfig c;
  try {
    c = hrt::load_run_config(path);
  } catch (...) {
    fs::current_path(cwd);
    throw;
  }
  fs::current_path(cwd);
  EXPECT_EQ(c.objects[0].bundle, file("models/probe.hbundle"));
  EXPECT_EQ(c.objects[1].bundle, file("models/plate.hbundle"));
  EXPECT_EQ(c.device.trajectory, file("scenes/deep/local.csv"));
  EXPECT_EQ(c.trace.path, file("out/t.csv"));
}

TEST_F(RunConfig, UnknownKeysAreErrorsWithTheLikelyKey) {
  expect_error(minimal("[force]\nstifness = 10\n"), "force.stifness", "did you mean \"stiffness\"?");
  expect_error(minimal("[run]\ngravity = [0, 0, -9.81]\n"), "run.gravity", "it belongs in [probe]");
  expect_error(minimal("[forces]\nstiffness = 10\n"), "forces", "unknown table (did you mean [force]?)");
  expect_error(minimal("[[objects]]\nbundle = \"x\"\n"), "objects", "did you mean [[object]]?");
  expect_error("[[object]]\nbundle = \"models/probe.hbundle\"\nbundel = 1\n" + kObjects, "object[0].bundel",
               "did you mean \"bundle\"?");
  expect_error(minimal("[trace]\nzzz = 1\n"), "trace.zzz", "unknown key (line");
  expect_error("object = 3\n", "object", "expected an array of tables [[object]], got an integer");
  expect_error("run = 3\n" + minimal(), "run", "expected a table [run], got an integer");
  expect_error("duration = 3\n" + minimal(), "duration", "unknown key (it belongs in [run])");
}

TEST_F(RunConfig, WrongTypesAreErrors) {
  expect_error(minimal("[force]\nresolution = 50.0\n"), "force.resolution", "expected an integer, got a float");
  expect_error(minimal("[force]\nstiffness = \"1000\"\n"), "force.stiffness", "expected a number, got a string");
  expect_error(minimal("[force]\nshortcut = 1\n"), "force.shortcut", "expected true or false, got an integer");
  expect_error(minimal("[run]\nduration = 1979-05-27\n"), "run.duration", "expected a number, got a date");
  expect_error(minimal("[probe]\ngravity = [0, 0]\n"), "probe.gravity", "expected an array of 3 numbers");
  expect_error(minimal("[probe]\ngravity = [0, 0, \"g\"]\n"), "probe.gravity", "element 2 is a string");
  expect_error(minimal("[probe]\ngravity = 9.81\n"), "probe.gravity", "got a float");
  expect_error("[[object]]\nbundle = \"models/probe.hbundle\"\n[[object]]\nbundle = 7\n", "object[1].bundle",
               "expected a string, got an integer");
  // Integers are numbers: accepted where a float is expected.
  EXPECT_EQ(hrt::load_run_config(scene(minimal("[force]\nstiffness = 1500\n"))).scene.force.stiffness, 1500.0);
}

TEST_F(RunConfig, NonFiniteValuesAreErrors) {
  expect_error(minimal("[force]\nstiffness = inf\n"), "force.stiffness", "must be finite");
  expect_error(minimal("[run]\nduration = nan\n"), "run.duration", "must be finite");
  expect_error(minimal("[probe]\ngravity = [0, -inf, 0]\n"), "probe.gravity", "element 1 must be finite");
  expect_error(minimal("[workspace]\noffset_orientation = [0, 0, nan, 1]\n"), "workspace.offset_orientation",
               "must be finite");
}

TEST_F(RunConfig, OutOfRangeValuesAreErrors) {
  expect_error(minimal("[force]\nstiffness = -5\n"), "force.stiffness", "must be between 1 and 1e+07 N/m, got -5");
  expect_error(minimal("[force]\nstiffness = 0\n"), "force.stiffness", "must be between");
  expect_error(minimal("[force]\nresolution = 4\n"), "force.resolution", "between 8 and 1024");
  expect_error(minimal("[force]\nlin_step = -1e-3\n"), "force.lin_step", "must be between 0 and 0.1 m");
  expect_error(minimal("[force]\nauto_resolution = true\nresolution = 64\nmax_resolution = 32\n"),
               "force.max_resolution", "at least the resolution");
  expect_error(minimal("[run]\nduration = 0\n"), "run.duration", "must be between 0.001 and 86400 s");
  expect_error(minimal("[run]\nsim_every = 0\n"), "run.sim_every", "between 1 and");
  expect_error(minimal("[run]\nbackend = \"vulkan\"\n"), "run.backend", "must be one of \"cpu\", \"gl\", \"auto\"");
  expect_error(minimal("[run]\nbackend = \"gl\"\ngl_search = \"fast\"\n"), "run.gl_search",
               "must be one of \"compute\", \"occlusion\"");
  expect_error(minimal("[run]\nbackend = \"gl\"\ngl_search = \"occlusion\"\nocclusion_steps = 24\n"),
               "run.occlusion_steps", "between 1 and 23");
  expect_error(minimal("[run]\nbackend = \"gl\"\ngl_search = \"occlusion\"\nocclusion_steps = 0\n"),
               "run.occlusion_steps", "between 1 and 23");
  expect_error(minimal("[force]\nheights = \"fine\"\n"), "force.heights", "\"surface\", \"coarse\"");
  expect_error(minimal("[probe]\ndensity = 0\n"), "probe.density", "must be between 1 and 100000 kg/m^3");
  expect_error(minimal("[workspace]\nscale = -2\n"), "workspace.scale", "must be between 0.001 and 1000");
  expect_error(minimal("[loop]\nperiod = 0\n"), "loop.period", "must be between 0.0001 and 0.1 s");
  expect_error(minimal("[loop]\nperiod = 0.5\n"), "loop.period", "must be between 0.0001 and 0.1 s");
  expect_error(minimal("[loop]\npriority = 100\n"), "loop.priority", "between 1 and 99");
  expect_error(minimal("[loop]\nlog_capacity = -1\n"), "loop.log_capacity", "between 0 and");
  expect_error(minimal("[friction]\nmu_static = 0.5\nmu_dynamic = 0.6\n"), "friction.mu_dynamic",
               "must not exceed mu_static");
  expect_error(minimal("[friction]\nmu_static = -0.1\n"), "friction.mu_static", "must be between 0 and 10");
  expect_error(minimal("[friction]\nenabled = true\n"), "friction.enabled", "no mu_static > 0");
  expect_error(kObjects + "[device]\ntrajectory = \"slide.csv\"\nmax_force = 0\n", "device.max_force",
               "must be between 0.001 and 1000 N");
  expect_error(kObjects + "[device]\ntrajectory = \"slide.csv\"\ndof_actuated = 5\n", "device.dof_actuated",
               "must be 3 or 6");
  expect_error(kObjects + "[device]\ntype = \"udp\"\nport = 70000\n", "device.port", "between 0 and 65535");
  expect_error(kObjects + "[device]\ntype = \"udp\"\nbind = \"localhost\"\n", "device.bind", "not an IPv4 address");
  expect_error(minimal("[[object]]\nbundle = \"models/cup.hbundle\"\nposition = [0, 0, 2e4]\n"), "object[2].position",
               "m from the origin");
}

TEST_F(RunConfig, BadQuaternionsAreErrors) {
  expect_error(minimal("[[object]]\nbundle = \"models/cup.hbundle\"\norientation = [0, 0, 0, 0]\n"),
               "object[2].orientation", "norm 0");
  // Not normalised by its author: probably not a rotation (or w first).
  expect_error(minimal("[[object]]\nbundle = \"models/cup.hbundle\"\norientation = [0, 0, 1, 1]\n"),
               "object[2].orientation", "expected a unit quaternion");
  expect_error(minimal("[workspace]\ngrasp_orientation = [0, 0, 1]\n"), "workspace.grasp_orientation",
               "expected an array of 4 numbers [x, y, z, w]");
  // Within the tolerance it is accepted and normalised.
  const hrt::RunConfig c = hrt::load_run_config(
      scene(minimal("[[object]]\nbundle = \"models/cup.hbundle\"\norientation = [0, 0, 0.7071, 0.7071]\n")));
  EXPECT_NEAR(c.objects[2].pose.rotation.norm(), 1.0, 1e-15);
}

TEST_F(RunConfig, ObjectErrors) {
  expect_error("[[object]]\nname = \"a\"\n[[object]]\nbundle = \"models/plate.hbundle\"\n", "object[0].bundle",
               "missing: every object needs the path of its bundle");
  expect_error(minimal("[[object]]\nbundle = \"models/nothere.hbundle\"\n"), "object[2].bundle",
               "no bundle folder at " + file("models/nothere.hbundle"));
  expect_error(minimal("[[object]]\nname = \"object1\"\nbundle = \"models/cup.hbundle\"\n"), "object[2].name",
               "\"object1\" is also the name of object[1]");
  expect_error(
      "[[object]]\nbundle = \"models/probe.hbundle\"\ntrajectory = \"slide.csv\"\n"
      "[[object]]\nbundle = \"models/plate.hbundle\"\n[device]\ntrajectory = \"slide.csv\"\n",
      "object[0].trajectory", "is the probe");
  expect_error(minimal("[[object]]\nbundle = \"models/cup.hbundle\"\ntrajectory = \"nope.csv\"\n"),
               "object[2].trajectory", "no such file");
  expect_error("[[object]]\nbundle = \"models/probe.hbundle\"\n[device]\ntrajectory = \"slide.csv\"\n", "object",
               "at least two [[object]]");
  expect_error("", "object", "at least two [[object]]");
}

TEST_F(RunConfig, MaterialErrors) {
  const std::string named =
      "[[object]]\nname = \"block\"\nbundle = \"models/probe.hbundle\"\n"
      "[[object]]\nname = \"plate\"\nbundle = \"models/plate.hbundle\"\n"
      "[device]\ntrajectory = \"slide.csv\"\n";
  expect_error(named + "[[material]]\nobject = \"plat\"\nstiffness = 10\n", "material[0].object",
               "no object is named \"plat\" (did you mean \"plate\"?)");
  expect_error(named + "[[material]]\nobject = \"block\"\n", "material[0].object", "is the probe");
  expect_error(named + "[[material]]\nstiffness = 10\n", "material[0].object", "missing");
  expect_error(named + "[[material]]\nobject = \"plate\"\n[[material]]\nobject = \"plate\"\n", "material[1].object",
               "already has material[0]");
  expect_error(named + "[[material]]\nobject = \"plate\"\nstiffness = 0\n", "material[0].stiffness",
               "must be between 1 and");
  // The pair's mu_static below the inherited mu_dynamic names the key it set.
  expect_error(
      named + "[friction]\nmu_static = 0.5\nmu_dynamic = 0.4\n[[material]]\nobject = \"plate\"\nmu_static = 0.3\n",
      "material[0].mu_static", "must not exceed mu_static (0.3)");
  expect_error(named + "[[material]]\nobject = \"plate\"\nfriction = 0.3\n", "material[0].friction", "unknown key");
}

TEST_F(RunConfig, DeviceAndRunConsistencyErrors) {
  const std::string objects = kObjects;
  expect_error(objects, "device.trajectory", "a scripted device needs a trajectory");
  expect_error(objects + "[device]\ntrajectory = \"slide.csv\"\nport = 47800\n", "device.port",
               "only for type = \"udp\" (this device is \"scripted\")");
  expect_error(objects + "[device]\ntype = \"udp\"\ntrajectory = \"slide.csv\"\n", "device.trajectory",
               "only for type = \"scripted\"");
  expect_error(objects + "[device]\ntype = \"plugin\"\n", "device.plugin", "missing");
  expect_error(objects + "[device]\ntype = \"plugin\"\nplugin = \"x.so\"\nname = \"n\"\n", "device.name",
               "reports its own");
  expect_error(objects + "[device]\ntype = \"haptic\"\n", "device.type", "must be one of");
  expect_error(objects + "[run]\nlockstep = true\n[device]\ntype = \"udp\"\n", "run.lockstep",
               "needs a scripted or virtual device");
  expect_error(objects + "[device]\ntype = \"udp\"\nreply_address = \"10.0.0.2\"\n", "device.reply_address",
               "needs a reply_port");
  expect_error(minimal("[coupling]\nk_lin = 100\nb_lin = 1\nk_ang = 1\n"), "coupling.b_ang", "give all four gains");
  expect_error(minimal("[trace]\npath = \"nofolder/a.csv\"\n"), "trace.path", "does not exist");
  expect_error(minimal("[trace]\npath = \"\"\n"), "trace.path", "empty path");
  expect_error(minimal("[trace]\ndevice_log = \"out/d.csv\"\n[loop]\nlog_capacity = 0\n"), "loop.log_capacity",
               "nothing would be logged");
}

// [run] backend, gl_search, occlusion_steps: the three choices,
// and the GL settings refused where no GL backend runs (as a udp key on a
// scripted device), the shortcut refused with the GL backend.
TEST_F(RunConfig, DepthBackendKeys) {
  hrt::RunConfig c = hrt::load_run_config(scene(minimal()));
  EXPECT_EQ(c.backend, "cpu");
  EXPECT_EQ(c.gl_search, "compute");
  EXPECT_EQ(c.occlusion_steps, 16);
  c = hrt::load_run_config(scene(minimal("[run]\nbackend = \"auto\"\n")));
  EXPECT_EQ(c.backend, "auto");
  c = hrt::load_run_config(
      scene(minimal("[run]\nbackend = \"gl\"\ngl_search = \"occlusion\"\nocclusion_steps = 12\n")));
  EXPECT_EQ(c.backend, "gl");
  EXPECT_EQ(c.gl_search, "occlusion");
  EXPECT_EQ(c.occlusion_steps, 12);
  hrt::BackendChoice choice = hrt::BackendChoice::cpu;
  EXPECT_TRUE(hrt::parse_backend_choice(c.backend, choice));
  EXPECT_EQ(choice, hrt::BackendChoice::gl);
  // auto may pick the shortcut's CPU backend: allowed.
  c = hrt::load_run_config(scene(minimal("[run]\nbackend = \"auto\"\n[force]\nshortcut = true\n")));
  EXPECT_TRUE(c.scene.force.shortcut);

  expect_error(minimal("[run]\ngl_search = \"compute\"\n"), "run.gl_search", "only with backend = \"gl\" or \"auto\"");
  expect_error(minimal("[run]\nbackend = \"gl\"\nocclusion_steps = 8\n"), "run.occlusion_steps",
               "only with gl_search = \"occlusion\"");
  expect_error(minimal("[run]\nbackend = \"cpu\"\nocclusion_steps = 8\n"), "run.occlusion_steps",
               "only with gl_search = \"occlusion\"");
  expect_error(minimal("[run]\nbackend = \"gl\"\ngl_search = \"occlusion\"\nocclusion_steps = 8.0\n"),
               "run.occlusion_steps", "expected an integer, got a float");
  expect_error(minimal("[run]\nbackend = \"gl\"\n[force]\nshortcut = true\n"), "force.shortcut",
               "implemented by the CPU backend only");
}

TEST_F(RunConfig, TomlSyntaxErrorsGiveTheLine) {
  const std::string path = scene("[run]\nduration = 1.0\nlockstep = \n");
  try {
    hrt::load_run_config(path);
    FAIL() << "no error";
  } catch (const hrt::SceneFileError& e) {
    const std::string what = e.what();
    EXPECT_EQ(e.key, "");
    EXPECT_EQ(what.rfind(path + ": line 3, column ", 0), 0u) << what;
    EXPECT_EQ(what.find('\n'), std::string::npos) << what;
  }
  // Errors of values give their line too.
  expect_error(minimal("\n\n[force]\nstiffness = -1\n"), "force.stiffness", "(line 10)");
  // A table defined twice is a TOML error (not a merge).
  expect_error(minimal("[device]\nname = \"again\"\n"), "", "line 7, column");
}

TEST_F(RunConfig, UnreadableFileIsAnError) {
  const std::string missing = (dir_ / "none.toml").string();
  try {
    hrt::load_run_config(missing);
    FAIL() << "no error";
  } catch (const hrt::SceneFileError& e) {
    EXPECT_EQ(std::string(e.what()), missing + ": no such file");
  }
}

// ---------------------------------------------------------------------------
// Trace (docs/trace-format.md)
// ---------------------------------------------------------------------------

std::vector<std::string> spec_columns(const std::string& heading) { return hrt_test::trace_spec_columns(heading); }

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::string cur;
  for (char c : s) {
    if (c == sep) {
      out.push_back(cur);
      cur.clear();
    } else {
      cur += c;
    }
  }
  out.push_back(cur);
  return out;
}

class Trace : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::path(::testing::TempDir()) / ("hrt_trace_" + std::to_string(::getpid()) + "_" +
                                             ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

// Values that a fixed number of digits (%.6g, %.15g) would not round-trip.
hrt::SessionFrame sample_frame(double s) {
  hrt::SessionFrame f;
  f.t = 0.1 * s;
  f.h = 1.0 / 3.0;
  f.frame = 12345678901234ull;
  f.target.position = hrt::Vec3(1.0 / 7.0, -2.0 / 3.0, 1e-300) * s;
  f.target.rotation = Eigen::Quaterniond(0.9, 0.1, -0.2, 0.3).normalized();
  f.probe.position = hrt::Vec3(M_PI, -M_E, 5e-324);
  f.probe.rotation = Eigen::Quaterniond(std::sqrt(0.5), 0.0, std::sqrt(0.5), 0.0);
  for (int i = 0; i < 6; ++i) {
    f.contact[i] = (i + 1) / 11.0 * s;
    f.friction[i] = -(i + 1) / 13.0;
    f.coupling[i] = (i + 1) * 1e17 + 1.0 / 3.0;
    f.device[i] = std::nextafter(1.0, 2.0) * (i + 1);
  }
  f.patches = 7;
  f.sticking = 3;
  f.slipping = 2;
  f.refused = 1;
  f.fading = 4;
  f.kinetic = 1.0 / 9.0;
  f.coupling_energy = 2.0 / 9.0;
  f.contact_energy = 4.0 / 9.0;
  f.gravity_energy = -8.0 / 9.0;
  f.friction_energy = 1e-20 / 3.0;
  f.timings.collision_us = 12.5;
  f.timings.clustering_us = 0.3;
  f.timings.force_us = 101.25;
  f.timings.total_us = 120.0;
  f.dynamics_us = 7.75;
  return f;
}

TEST_F(Trace, HeaderIsTheSpecsColumnList) {
  const std::vector<std::string> spec = spec_columns("## Trace columns");
  ASSERT_GT(spec.size(), 40u);
  hrt::TraceWriter w;
  const std::string path = (dir_ / "t.csv").string();
  w.open(path, hrt::TraceConfig{});
  w.close();
  const std::string text = read_text(path);
  ASSERT_FALSE(text.empty());
  ASSERT_EQ(text.back(), '\n');
  EXPECT_EQ(split(text.substr(0, text.size() - 1), ','), spec);
  // A trace is a trajectory of its device poses (prefix device_).
  for (const char* c : {"t", "device_x", "device_y", "device_z", "device_qx", "device_qy", "device_qz", "device_qw"})
    EXPECT_NE(std::find(spec.begin(), spec.end(), c), spec.end()) << c;
}

TEST_F(Trace, ValuesRoundTripInTheSpecsColumns) {
  const std::vector<std::string> cols = spec_columns("## Trace columns");
  const std::string path = (dir_ / "t.csv").string();
  const hrt::SessionFrame f1 = sample_frame(1.0), f2 = sample_frame(-3.0);
  hrt::DeviceTarget d;
  d.time = 0.0999999999999;
  d.clutched = true;
  d.device.position = hrt::Vec3(0.1, 0.2, 0.3);
  d.device.rotation = Eigen::Quaterniond(0.5, 0.5, -0.5, 0.5);
  for (int i = 0; i < 6; ++i) d.output[i] = -0.1 * (i + 1) / 3.0;
  {
    hrt::TraceWriter w;
    w.open(path, hrt::TraceConfig{});
    w.row(hrt::TraceRow{&f1, &d});
    w.row(hrt::TraceRow{&f2, &d});
    w.close();
  }
  std::istringstream lines(read_text(path));
  std::string line;
  std::getline(lines, line);
  ASSERT_EQ(split(line, ','), cols);
  std::vector<std::vector<double>> rows;
  while (std::getline(lines, line)) {
    std::vector<double> r;
    for (const std::string& s : split(line, ',')) {
      char* end = nullptr;
      r.push_back(std::strtod(s.c_str(), &end));
      EXPECT_EQ(*end, '\0') << s;
    }
    ASSERT_EQ(r.size(), cols.size());
    rows.push_back(r);
  }
  ASSERT_EQ(rows.size(), 2u);
  auto at = [&](int row, const std::string& name) {
    const auto it = std::find(cols.begin(), cols.end(), name);
    EXPECT_NE(it, cols.end()) << name;
    return it == cols.end() ? std::nan("") : rows[static_cast<size_t>(row)][static_cast<size_t>(it - cols.begin())];
  };
  const char* xyz[] = {"x", "y", "z"};
  const char* wr[] = {"fx", "fy", "fz", "tx", "ty", "tz"};
  for (int r = 0; r < 2; ++r) {
    const hrt::SessionFrame& f = r == 0 ? f1 : f2;
    // Bit-exact: EXPECT_EQ on doubles.
    EXPECT_EQ(at(r, "t"), f.t);
    EXPECT_EQ(at(r, "h"), f.h);
    EXPECT_EQ(at(r, "frame"), static_cast<double>(f.frame));
    EXPECT_EQ(at(r, "device_t"), d.time);
    EXPECT_EQ(at(r, "clutched"), 1.0);
    for (int i = 0; i < 3; ++i) {
      EXPECT_EQ(at(r, std::string("device_") + xyz[i]), d.device.position[i]);
      EXPECT_EQ(at(r, std::string("target_") + xyz[i]), f.target.position[i]);
      EXPECT_EQ(at(r, std::string("probe_") + xyz[i]), f.probe.position[i]);
    }
    EXPECT_EQ(at(r, "device_qx"), d.device.rotation.x());
    EXPECT_EQ(at(r, "device_qw"), d.device.rotation.w());
    EXPECT_EQ(at(r, "target_qy"), f.target.rotation.y());
    EXPECT_EQ(at(r, "target_qz"), f.target.rotation.z());
    EXPECT_EQ(at(r, "probe_qy"), f.probe.rotation.y());
    EXPECT_EQ(at(r, "probe_qw"), f.probe.rotation.w());
    for (int i = 0; i < 6; ++i) {
      EXPECT_EQ(at(r, wr[i]), d.output[i]) << wr[i];
      EXPECT_EQ(at(r, std::string("contact_") + wr[i]), f.contact[i]);
      EXPECT_EQ(at(r, std::string("friction_") + wr[i]), f.friction[i]);
      EXPECT_EQ(at(r, std::string("coupling_") + wr[i]), f.coupling[i]);
      EXPECT_EQ(at(r, std::string("command_") + wr[i]), f.device[i]);
    }
    EXPECT_EQ(at(r, "patches"), 7.0);
    EXPECT_EQ(at(r, "sticking"), 3.0);
    EXPECT_EQ(at(r, "slipping"), 2.0);
    EXPECT_EQ(at(r, "refused"), 1.0);
    EXPECT_EQ(at(r, "fading"), 4.0);
    EXPECT_EQ(at(r, "kinetic_j"), f.kinetic);
    EXPECT_EQ(at(r, "coupling_j"), f.coupling_energy);
    EXPECT_EQ(at(r, "contact_j"), f.contact_energy);
    EXPECT_EQ(at(r, "gravity_j"), f.gravity_energy);
    EXPECT_EQ(at(r, "friction_j"), f.friction_energy);
    EXPECT_EQ(at(r, "collision_us"), 12.5);
    EXPECT_EQ(at(r, "clustering_us"), 0.3);
    EXPECT_EQ(at(r, "force_us"), 101.25);
    EXPECT_EQ(at(r, "frame_us"), 120.0);
    EXPECT_EQ(at(r, "dynamics_us"), 7.75);
    EXPECT_EQ(at(r, "total_us"), 127.75);
  }
  // The frame number is written as an integer, not in exponent form.
  EXPECT_NE(read_text(path).find(",12345678901234,"), std::string::npos);
}

// docs/trajectory-format.md: a trace is a trajectory of its device poses
// with the prefix "device_", so a recorded session replays exactly.
TEST_F(Trace, ReplaysAsADeviceTrajectory) {
  const std::string path = (dir_ / "t.csv").string();
  std::vector<hrt::Pose> poses;
  {
    hrt::TraceWriter w;
    w.open(path, hrt::TraceConfig{});
    hrt::SessionFrame f = sample_frame(1.0);
    hrt::DeviceTarget d;
    for (int i = 0; i < 4; ++i) {
      f.t = 1e-3 * (i + 1) / 3.0;
      d.device.position = hrt::Vec3(0.01 * i + 1.0 / 3.0, -0.02 * i, 1e-3 / 7.0);
      d.device.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(0.1 * i + 0.05, hrt::Vec3(1, 2, 3).normalized()));
      poses.push_back(d.device);
      w.row(hrt::TraceRow{&f, &d});
    }
    w.close();
  }
  const hrt::Trajectory t = hrt::Trajectory::load_csv(path, "device_");
  ASSERT_EQ(t.size(), 4u);
  for (size_t i = 0; i < 4; ++i) {
    EXPECT_EQ(t.times()[i], 1e-3 * static_cast<double>(i + 1) / 3.0);
    EXPECT_EQ(t.poses()[i].position, poses[i].position);
    // The reader normalises (a unit quaternion stays within rounding).
    EXPECT_LT((t.poses()[i].rotation.coeffs() - poses[i].rotation.coeffs()).norm(), 1e-15);
  }
}

TEST_F(Trace, NoFileAtThePathUntilClose) {
  const fs::path path = dir_ / "t.csv", partial = dir_ / "t.csv.partial";
  const hrt::SessionFrame f = sample_frame(1.0);
  const hrt::DeviceTarget d;
  hrt::TraceWriter w;
  EXPECT_FALSE(w.is_open());
  w.open(path.string(), hrt::TraceConfig{});
  EXPECT_TRUE(w.is_open());
  w.row(hrt::TraceRow{&f, &d});
  EXPECT_FALSE(fs::exists(path));
  EXPECT_TRUE(fs::exists(partial));
  w.close();
  EXPECT_FALSE(w.is_open());
  EXPECT_TRUE(fs::exists(path));
  EXPECT_FALSE(fs::exists(partial));
  const std::string text = read_text(path);
  EXPECT_EQ(std::count(text.begin(), text.end(), '\n'), 2);
}

TEST_F(Trace, AnUnclosedWriterRemovesItsPartial) {
  const fs::path path = dir_ / "t.csv", partial = dir_ / "t.csv.partial";
  const hrt::SessionFrame f = sample_frame(1.0);
  const hrt::DeviceTarget d;
  {
    hrt::TraceWriter w;
    w.open(path.string(), hrt::TraceConfig{});
    w.row(hrt::TraceRow{&f, &d});
    ASSERT_TRUE(fs::exists(partial));
  }
  EXPECT_FALSE(fs::exists(partial));
  EXPECT_FALSE(fs::exists(path));
}

TEST_F(Trace, IoErrorsNameThePath) {
  const std::string path = (dir_ / "no_such_folder" / "t.csv").string();
  hrt::TraceWriter w;
  try {
    w.open(path, hrt::TraceConfig{});
    FAIL() << "no error";
  } catch (const std::runtime_error& e) {
    EXPECT_EQ(std::string(e.what()).rfind(path + ": ", 0), 0u) << e.what();
  }
  EXPECT_FALSE(w.is_open());
  // PATH exists and is not a regular file (a device such as /dev/null, a
  // folder): open() refuses it, rather than renaming over it at close().
  for (const std::string special : {std::string("/dev/null"), dir_.string()}) {
    hrt::TraceWriter w3;
    try {
      w3.open(special, hrt::TraceConfig{});
      FAIL() << special << ": no error";
    } catch (const std::runtime_error& e) {
      EXPECT_EQ(std::string(e.what()).rfind(special + ": exists and is not a regular file", 0), 0u) << e.what();
    }
    EXPECT_FALSE(fs::exists(special + ".partial"));
  }
  // The rename fails (PATH became a non-empty folder while the trace was
  // written): close() says so and leaves neither the partial nor anything at
  // PATH but the folder.
  const fs::path folder = dir_ / "taken.csv";
  hrt::TraceWriter w2;
  w2.open(folder.string(), hrt::TraceConfig{});
  fs::create_directories(folder / "inside");
  try {
    w2.close();
    FAIL() << "no error";
  } catch (const std::runtime_error& e) {
    EXPECT_EQ(std::string(e.what()).rfind(folder.string() + ": cannot rename", 0), 0u) << e.what();
  }
  EXPECT_FALSE(fs::exists(folder.string() + ".partial"));
  EXPECT_FALSE(w2.is_open());
}

}  // namespace

// Ranges grounded in devices and physics (docs/scene-format.md, "Ranges"):
// the absurd values a fuzzer or a unit slip produces are refused by key.
TEST_F(RunConfig, MeaninglessValuesAreRefusedWithTheirRange) {
  expect_error(kObjects + "[device]\ntrajectory = \"slide.csv\"\nmax_stiffness = 1e308\n", "device.max_stiffness",
               "must be between 1 and 1e+06 N/m, got 1e+308 (1 mm must give at least 1 mN)");
  expect_error(kObjects + "[device]\ntrajectory = \"slide.csv\"\nmax_stiffness = 0.5\n", "device.max_stiffness",
               "between 1 and");
  expect_error(minimal("[loop]\nperiod = 1e-9\n"), "loop.period", "between 0.0001 and 0.1 s");
  expect_error(minimal("[loop]\nlog_capacity = 10000000\n"), "loop.log_capacity", "between 0 and 2000000");
  expect_error(minimal("[run]\nduration = 3e5\n"), "run.duration", "between 0.001 and 86400 s");
  expect_error(minimal("[trace]\nmax_bytes = 10\n"), "trace.max_bytes", "between 1e+06 and 1e+12 bytes");
  expect_error(minimal("[probe]\ngravity = [0, 0, -1e4]\n"), "probe.gravity", "at most 1000 m/s^2");
}

// The device log is sized to the session, never more: a capacity of two
// million for a 0.2 s session allocates 201 rows. A --duration checks the
// same limit as the file's duration, naming the flag.
TEST_F(RunConfig, OverridesAreCheckedAndTheLogIsSizedToTheSession) {
  hrt::RunConfig c = hrt::load_run_config(
      scene(minimal("[run]\nduration = 0.2\n[loop]\nlog_capacity = 2000000\n[trace]\ndevice_log = \"out/d.csv\"\n")));
  EXPECT_EQ(c.loop.log_capacity, 211u);  // (0.2 + 0.01) / 1e-3 + 1
  hrt::RunConfig d = hrt::load_run_config(scene(minimal("[trace]\ndevice_log = \"out/d.csv\"\n")));
  hrt::RunOverrides o;
  o.duration = 20000.0;
  try {
    hrt::apply_overrides(d, o);
    ADD_FAILURE() << "--duration 20000 with a whole-session device log was accepted";
  } catch (const hrt::SceneFileError& e) {
    EXPECT_EQ(e.key, "--duration");
    EXPECT_NE(std::string(e.what()).find("more than the limit of 2000000"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("log_capacity"), std::string::npos) << e.what();
  }
  o.duration = 1e6;
  EXPECT_THROW(hrt::apply_overrides(d, o), hrt::SceneFileError);
  o.duration = 2.0;
  hrt::apply_overrides(d, o);
  EXPECT_EQ(d.loop.log_capacity, 2011u);
  // The real-time trace rate by default, every frame in lockstep.
  EXPECT_EQ(d.trace.rate, hrt::kDefaultRealtimeTraceRate);
  o.lockstep = true;
  hrt::apply_overrides(d, o);
  EXPECT_EQ(d.trace.rate, 0.0);
}

// No output may be an input: by path, by a symbolic or hard link, from the
// file or a flag; the two outputs may not be one file.
TEST_F(RunConfig, OutputsMayNotBeInputs) {
  auto expect_refused = [&](const hrt::RunConfig& c, const std::string& fragment) {
    try {
      hrt::check_run_outputs(c);
      ADD_FAILURE() << "accepted; wanted: " << fragment;
    } catch (const hrt::OutputOverwritesInput& e) {
      EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
    }
  };
  const std::string path = scene(minimal("[trace]\npath = \"out/trace.csv\"\n"));
  hrt::RunConfig c = hrt::load_run_config(path);
  hrt::check_run_outputs(c);  // fine as it is
  hrt::RunConfig t = c;
  t.trace.path = file("slide.csv");
  expect_refused(t, "is the device's trajectory");
  t.trace.path = path;
  expect_refused(t, "is the scene file");
  t.trace.path = file("models/plate.hbundle");
  expect_refused(t, "bundle of object");
  fs::create_symlink(file("slide.csv"), file("link.csv"));
  t.trace.path = file("link.csv");
  expect_refused(t, "is the device's trajectory");
  fs::create_hard_link(file("slide.csv"), file("hard.csv"));
  t.trace.path = file("hard.csv");
  expect_refused(t, "is the device's trajectory");
  t = c;
  t.trace.device_log = file("out/trace.csv");
  expect_refused(t, "the trace");
  t = c;
  t.trace.device_log = file("out/../slide.csv");
  t.trace.device_log_key = "--device-log";
  expect_refused(t, "(--device-log): is the device's trajectory");
}

// Inputs that are not regular files are named, never read; a scene over its
// size limit is refused before it is read; values in messages are cut and
// escaped.
TEST_F(RunConfig, NonRegularAndHugeInputsAndRawBytesInMessages) {
  const fs::path fifo = dir_ / "fifo";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  try {
    hrt::load_run_config(fifo.string());
    ADD_FAILURE() << "a FIFO scene was read";
  } catch (const hrt::SceneFileError& e) {
    EXPECT_NE(std::string(e.what()).find("is a FIFO, not a regular file"), std::string::npos) << e.what();
  }
  expect_error(minimal("[[object]]\nbundle = \"models/cup.hbundle\"\ntrajectory = \"fifo\"\n"), "object[2].trajectory",
               "is a FIFO");
  try {
    hrt::load_run_config("/dev/zero");
    ADD_FAILURE() << "/dev/zero was read";
  } catch (const hrt::SceneFileError& e) {
    EXPECT_NE(std::string(e.what()).find("is a character device"), std::string::npos) << e.what();
  }
  expect_error(std::string(hrt::kMaxSceneFileBytes + 1, '#'), "", "more than the limit of 1048576 bytes");
  const std::string big(100000, 'x');
  const std::string nul = std::string("ab") + '\0' + "\x1b[31m";
  for (const std::string& v : {big, nul}) {
    const std::string path =
        scene(minimal("[run]\nbackend = \"" + (v == nul ? std::string("ab\\u0000\\u001b[31m") : v) + "\"\n"));
    try {
      hrt::load_run_config(path);
      ADD_FAILURE();
    } catch (const hrt::SceneFileError& e) {
      const std::string what = e.what();
      EXPECT_LT(what.size(), 800u) << what.size();
      for (char ch : what) EXPECT_GE(static_cast<unsigned char>(ch), 0x20) << what;
      if (v == nul) EXPECT_NE(what.find("ab\\x00\\x1b[31m"), std::string::npos) << what;
    }
  }
}

// A key with a unit added gets its "did you mean" too.
TEST_F(RunConfig, KeyWithAUnitSuffixGetsASuggestion) {
  expect_error(kObjects + "[device]\ntype = \"udp\"\ndisplay_rate_hz = 60\n", "device.display_rate_hz",
               "unknown key (did you mean \"display_rate\"?)");
}

// A NUL inside a path (TOML's \u0000) would make the system open a shorter path than the one named.
TEST_F(RunConfig, PathsWithANulAreRefused) {
  expect_error(minimal("[trace]\npath = \"out/a\\u0000b.csv\"\n"), "trace.path", "NUL");
}
