// libFuzzer target of the readers of `hrt run`'s text inputs: the TOML scene
// file (hrt::load_run_config, docs/scene-format.md) and the CSV trajectory
// (hrt::Trajectory::load_csv, docs/trajectory-format.md).
//
// Input: byte 0 selects the reader, the rest is the file, written as it is.
//
//   byte 0 bit 0 = 0   TOML scene:     <dir>/scene.toml -> load_run_config
//   byte 0 bit 0 = 1   CSV trajectory: <dir>/input.csv  -> Trajectory::load_csv,
//                      prefix "device_" when bit 1 is set, else ""
//   other bits are ignored (kept for later); an empty input is rejected.
//
// <dir> is a private folder made once per process (/dev/shm/hrt_fuzz_scene.<n>,
// else $TMPDIR or /tmp; HRT_FUZZ_TMPDIR= overrides) holding the fixed entries
// a scene may name by relative path (the scene's folder is <dir>). <n> is the
// lowest slot no live process holds (a flock on <dir>/.lock), not the pid: the
// paths in messages, and so the run of a fixed -seed, are the same each time.
// The folder holds:
//
//   a.hbundle/, b.hbundle/   empty folders (the scene reader only checks that
//                            a bundle is a folder; it does not load it)
//   traj.csv                 a small valid trajectory
//   plugin.so                a regular file (the reader only checks that)
//
// Accepted outcomes: a RunConfig / Trajectory that passes the checks below,
// or an exception of a documented class: hrt::SceneFileError,
// hrt::TrajectoryError, hrt::InputFileError (one of its four kinds). Its
// message must be one line: no '\n' and no byte below 0x20 (a value from the
// file copied raw into a message). Anything else -- another exception (also
// std::filesystem::filesystem_error or std::bad_alloc), a crash, an ASan/UBSan
// report, a leak, a timeout, running out of memory -- is a finding, and the
// target calls __builtin_trap().
//
// Checks of a RunConfig that loaded (docs/scene-format.md): at least two
// objects, unique non-empty names, each bundle an existing folder, every
// quaternion (objects, workspace offset and grasp) unit within 1e-9 and every
// position finite and within 10^4 m; no trajectory on the probe and each
// object trajectory a regular file; duration, max_step, period (<= 0.1 s),
// stiffnesses, density, scale, fade_time finite and > 0; integers in their
// ranges; coupling gains all given (> 0 / >= 0) or all -1; friction
// coefficients >= 0 with mu_dynamic <= mu_static; the device's type one of
// the three with its path (scripted: trajectory, plugin: plugin) a regular
// file, dof 3 or 6, limits > 0, ports 0..65535; lockstep only with a
// scripted device. Of a Trajectory: at least one sample, as many poses as
// times, times finite and strictly increasing, finite positions, unit
// quaternions (within 1e-9) each on the hemisphere of its predecessor; then
// sample() and velocity() run at every sample, between samples and outside
// (ASan/UBSan watch them).
//
// Environment:
//   HRT_FUZZ_TMPDIR     parent of the per-process folder
//   HRT_FUZZ_MESSAGES=0 do not trap on a message spanning lines or holding
//                       control bytes (to look past a known one in long runs)
//   HRT_FUZZ_STRICT=1   also: the message starts with the input's path
//                       (SceneFileError::file is it), is at most 4096 bytes
//                       and has no DEL byte; no path or name of a loaded
//                       scene holds a NUL byte; sample() / velocity() of a
//                       loaded trajectory are finite with a unit quaternion
//                       (not part of the CI verdict)
//   HRT_FUZZ_VERBOSE=1  one line per input on stderr: how it ended
#include <dirent.h>
#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <limits>
#include <set>
#include <string>
#include <typeinfo>

#include "hrt/files.h"
#include "hrt/run_config.h"
#include "hrt/trajectory.h"

namespace {

std::string g_root;   // per-process folder, removed at exit
std::string g_scene;  // g_root + "/scene.toml"
std::string g_csv;    // g_root + "/input.csv"
bool g_messages = true;
bool g_strict = false;
bool g_verbose = false;

// Any finding: say what, then trap (libFuzzer saves the input as crash-*).
[[noreturn]] void finding(const char* what, const std::string& detail) {
  std::fprintf(stderr, "\nhrt_fuzz_scene: FINDING: %s: %s\n", what, detail.c_str());
  std::fflush(stderr);
  __builtin_trap();
}

// A message for our own output: control bytes as \xHH, at most 400 chars.
std::string show(const std::string& s) {
  std::string out;
  for (unsigned char c : s) {
    if (out.size() >= 400) {
      out += "...";
      break;
    }
    if (c < 0x20 || c == 0x7f) {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\x%02x", c);
      out += buf;
    } else {
      out += static_cast<char>(c);
    }
  }
  return out;
}

void remove_tree(const std::string& dir) {
  if (DIR* d = ::opendir(dir.c_str())) {
    while (dirent* e = ::readdir(d)) {
      const std::string name = e->d_name;
      if (name == "." || name == "..") continue;
      const std::string p = dir + "/" + name;
      struct stat st{};
      if (::lstat(p.c_str(), &st) == 0 && S_ISDIR(st.st_mode)) {
        remove_tree(p);
      } else {
        ::unlink(p.c_str());
      }
    }
    ::closedir(d);
  }
  ::rmdir(dir.c_str());
}

void cleanup() {
  if (!g_root.empty()) remove_tree(g_root);
}

// Removes everything in `dir` but its .lock file.
void empty_folder(const std::string& dir) {
  if (DIR* d = ::opendir(dir.c_str())) {
    while (dirent* e = ::readdir(d)) {
      const std::string name = e->d_name;
      if (name == "." || name == ".." || name == ".lock") continue;
      const std::string p = dir + "/" + name;
      struct stat st{};
      if (::lstat(p.c_str(), &st) == 0 && S_ISDIR(st.st_mode)) {
        remove_tree(p);
      } else {
        ::unlink(p.c_str());
      }
    }
    ::closedir(d);
  }
}

// Claims parent/hrt_fuzz_scene.<n> for this process, n the lowest slot whose
// .lock no live process holds (a folder left by a crashed process is taken
// over and emptied; one being set up, without its .lock yet, is skipped).
// The lock stays held, by a descriptor not inherited across exec, until exit.
std::string claim_folder(const std::string& parent) {
  for (int n = 0; n < 1000; ++n) {
    const std::string dir = parent + "/hrt_fuzz_scene." + std::to_string(n);
    const bool made = ::mkdir(dir.c_str(), 0700) == 0;
    if (!made && errno != EEXIST) break;
    const int fd = ::open((dir + "/.lock").c_str(), O_RDWR | O_CLOEXEC | (made ? O_CREAT : 0), 0600);
    if (fd < 0) continue;
    if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
      ::close(fd);
      continue;  // a live process holds it
    }
    empty_folder(dir);
    return dir;  // fd stays open: the lock lasts as long as the process
  }
  std::fprintf(stderr, "hrt_fuzz_scene: no free folder hrt_fuzz_scene.<n> in %s\n", parent.c_str());
  std::exit(1);
}

bool writable_dir(const char* p) { return p && *p && ::access(p, W_OK | X_OK) == 0; }

void write_file(const std::string& path, const uint8_t* data, size_t size) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) finding("harness", "cannot write " + path + ": " + std::strerror(errno));
  size_t done = 0;
  while (done < size) {
    const ssize_t n = ::write(fd, data + done, size - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) finding("harness", "short write to " + path + ": " + std::strerror(errno));
    done += static_cast<size_t>(n);
  }
  ::close(fd);
}

void write_text(const std::string& path, const char* text) {
  write_file(path, reinterpret_cast<const uint8_t*>(text), std::strlen(text));
}

bool is_dir(const std::string& p) {
  struct stat st{};
  return ::stat(p.c_str(), &st) == 0 && S_ISDIR(st.st_mode);
}

bool is_regular(const std::string& p) {
  struct stat st{};
  return ::stat(p.c_str(), &st) == 0 && S_ISREG(st.st_mode);
}

// ---------------------------------------------------------------------------
// Errors: a documented class, one line.

void check_message(const char* cls, const std::string& what, const std::string& path) {
  if (g_messages) {
    for (unsigned char c : what)
      if (c < 0x20) finding(cls, "message spans lines or holds a control byte: \"" + show(what) + "\"");
  }
  if (g_strict) {
    if (what.rfind(path + ": ", 0) != 0) finding(cls, "message does not start with the input's path: " + show(what));
    if (what.size() > 4096) finding(cls, "message of " + std::to_string(what.size()) + " bytes");
    if (what.find('\x7f') != std::string::npos) finding(cls, "message holds a DEL byte: " + show(what));
  }
  if (g_verbose) std::fprintf(stderr, "hrt_fuzz_scene: rejected (%s): %s\n", cls, show(what).c_str());
}

// ---------------------------------------------------------------------------
// Invariants of a RunConfig that loaded.

void require(bool ok, const std::string& what) {
  if (!ok) finding("scene accepted", what);
}

bool finite_pos(double x) { return std::isfinite(x) && x > 0; }
bool finite_nonneg(double x) { return std::isfinite(x) && x >= 0; }

void check_unit(const hrt::Pose& p, const std::string& what) {
  require(p.rotation.coeffs().allFinite() && std::abs(p.rotation.norm() - 1.0) <= 1e-9,
          what + ": quaternion not unit within 1e-9");
  require(p.position.allFinite() && p.position.norm() <= 1e4 * (1 + 1e-12), what + ": position not finite or > 1e4 m");
}

void check_config(const hrt::RunConfig& c) {
  require(c.file == g_scene, "RunConfig::file is not the scene's path");
  require(c.objects.size() >= 2, "fewer than two objects");
  std::set<std::string> names;
  for (size_t i = 0; i < c.objects.size(); ++i) {
    const hrt::ObjectConfig& o = c.objects[i];
    const std::string at = "object[" + std::to_string(i) + "]";
    require(!o.name.empty(), at + ": empty name");
    require(names.insert(o.name).second, at + ": duplicate name");
    require(is_dir(o.bundle), at + ": bundle is not a folder: " + show(o.bundle));
    check_unit(o.pose, at);
    require(i > 0 || o.trajectory.empty(), "the probe has a trajectory");
    require(o.trajectory.empty() || is_regular(o.trajectory), at + ": trajectory is not a regular file");
  }
  require(finite_pos(c.duration), "duration not finite and > 0");
  require(finite_pos(c.max_step), "max_step not finite and > 0");
  require(c.sim_every >= 1 && c.sim_every <= 1000000, "sim_every out of range");
  require(c.backend == "cpu" || c.backend == "gl" || c.backend == "auto", "backend " + show(c.backend));
  require(c.gl_search == "compute" || c.gl_search == "occlusion", "gl_search " + show(c.gl_search));
  require(c.occlusion_steps >= 1 && c.occlusion_steps <= 23, "occlusion_steps out of range");

  const hrt::ForceOptions& f = c.scene.force;
  require(finite_pos(f.stiffness), "force.stiffness");
  require(f.resolution >= 8 && f.resolution <= 4096, "force.resolution");
  require(finite_nonneg(f.lin_step) && finite_nonneg(f.ang_step), "force steps");
  require(!(f.shortcut && c.backend == "gl"), "shortcut with backend gl");
  require(c.scene.collision.margin == -1.0 || finite_nonneg(c.scene.collision.margin), "force.margin");
  require(c.scene.cluster.max_patches >= 1 && c.scene.cluster.max_patches <= 4096, "force.max_patches");
  require(c.scene.cluster.max_resolution >= 8 && c.scene.cluster.max_resolution <= 4096, "force.max_resolution");
  require(!c.scene.cluster.auto_resolution || c.scene.cluster.max_resolution >= f.resolution,
          "auto_resolution with max_resolution < resolution");

  const hrt::SessionOptions& s = c.session;
  require(finite_pos(s.fade_time), "force.fade_time");
  require(finite_pos(s.density), "probe.density");
  require(s.gravity.allFinite(), "probe.gravity");
  const hrt::Coupling& k = s.coupling;
  const bool unset = k.k_lin == -1.0 && k.b_lin == -1.0 && k.k_ang == -1.0 && k.b_ang == -1.0;
  const bool given = finite_pos(k.k_lin) && finite_nonneg(k.b_lin) && finite_pos(k.k_ang) && finite_nonneg(k.b_ang);
  require(unset || given, "coupling gains neither all given nor all unset");
  require(!c.coupling_from_device || unset, "coupling_from_device with gains given");
  auto check_material = [&](const hrt::Material& m, const std::string& what) {
    require(m.stiffness == 0.0 || finite_pos(m.stiffness), what + ": stiffness");
    require(finite_nonneg(m.mu_static) && finite_nonneg(m.mu_dynamic) && m.mu_dynamic <= m.mu_static,
            what + ": friction coefficients");
  };
  check_material(s.material, "friction");
  require(s.materials.empty() || s.materials.size() == c.objects.size(), "materials not one per object");
  bool any_mu = s.material.mu_static > 0;
  for (size_t i = 0; i < s.materials.size(); ++i) {
    check_material(s.materials[i], "material of object " + std::to_string(i));
    any_mu = any_mu || s.materials[i].mu_static > 0;
  }
  require(!s.friction || any_mu, "friction on without a mu_static > 0");

  const hrt::DeviceLoopOptions& l = c.loop;
  require(finite_pos(l.map.scale), "workspace.scale");
  check_unit(l.map.offset, "workspace.offset");
  check_unit(l.map.grasp, "workspace.grasp");
  require(finite_pos(l.period) && l.period <= 0.1, "loop.period");
  require(l.watchdog == -1.0 || finite_pos(l.watchdog), "loop.watchdog");
  require(finite_pos(l.watchdog_ramp), "loop.watchdog_ramp");
  require(finite_nonneg(l.soft_start), "loop.soft_start");
  require(l.max_force_rate == -1.0 || finite_pos(l.max_force_rate), "loop.max_force_rate");
  require(l.max_torque_rate == -1.0 || finite_pos(l.max_torque_rate), "loop.max_torque_rate");
  require(l.realtime_priority >= 1 && l.realtime_priority <= 99, "loop.priority");
  require(l.log_capacity <= 10000000, "loop.log_capacity");

  const hrt::DeviceConfig& d = c.device;
  require(d.type == "scripted" || d.type == "udp" || d.type == "plugin", "device.type " + show(d.type));
  if (d.type == "scripted") require(is_regular(d.trajectory), "scripted device without a trajectory file");
  if (d.type == "plugin") require(is_regular(d.plugin), "plugin device without a plugin file");
  if (d.type != "scripted") require(d.trajectory.empty(), "trajectory on a non-scripted device");
  if (d.type != "plugin") require(d.plugin.empty(), "plugin path on a non-plugin device");
  require(!c.lockstep || d.type == "scripted", "lockstep without a scripted device");
  const hrt::UdpOptions& u = d.udp;
  require(u.port >= 0 && u.port <= 65535 && u.reply_port >= 0 && u.reply_port <= 65535 && u.display_port >= 0 &&
              u.display_port <= 65535,
          "udp port out of range");
  require(finite_pos(u.display_rate_hz), "device.display_rate");
  const hrt::DeviceInfo& info = d.info;
  require(!info.name.empty(), "empty device name");
  require((info.dof_sensed == 3 || info.dof_sensed == 6) && (info.dof_actuated == 3 || info.dof_actuated == 6),
          "device dof not 3 or 6");
  require(finite_pos(info.workspace.x()) && finite_pos(info.workspace.y()) && finite_pos(info.workspace.z()),
          "device.workspace");
  require(finite_pos(info.max_force) && finite_pos(info.max_torque) && finite_pos(info.max_stiffness) &&
              finite_pos(info.max_angular_stiffness),
          "device limits");
  // (trace.path vs device_log and the inputs: checked after reading, by
  // hrt::InputFiles, exit 6 -- not the reader's contract.)
  if (g_strict) {
    // A path or name with a NUL byte is cut short where the OS sees it
    // (c_str()), so what is opened is not what the file said.
    auto no_nul = [](const std::string& v, const std::string& what) {
      if (v.find('\0') != std::string::npos) finding("scene accepted (strict)", what + " holds a NUL byte: " + show(v));
    };
    for (size_t i = 0; i < c.objects.size(); ++i) {
      const std::string at = "object[" + std::to_string(i) + "]";
      no_nul(c.objects[i].name, at + ".name");
      no_nul(c.objects[i].bundle, at + ".bundle");
      no_nul(c.objects[i].trajectory, at + ".trajectory");
    }
    no_nul(d.trajectory, "device.trajectory");
    no_nul(d.trajectory_prefix, "device.trajectory_prefix");
    no_nul(d.plugin, "device.plugin");
    no_nul(d.plugin_config, "device.config");
    no_nul(info.name, "device.name");
    no_nul(c.trace.path, "trace.path");
    no_nul(c.trace.device_log, "trace.device_log");
  }
  if (g_verbose)
    std::fprintf(stderr, "hrt_fuzz_scene: scene loaded: %zu objects, device %s, duration %.6g s, period %.6g s\n",
                 c.objects.size(), d.type.c_str(), c.duration, l.period);
}

// ---------------------------------------------------------------------------
// Invariants of a Trajectory that loaded.

void check_trajectory(const hrt::Trajectory& t) {
  auto fail = [](const std::string& what) { finding("trajectory accepted", what); };
  const auto& times = t.times();
  const auto& poses = t.poses();
  if (times.empty() || t.empty() || t.size() != times.size()) fail("no samples, or size() disagrees");
  if (poses.size() != times.size()) fail("poses and times differ in number");
  for (size_t i = 0; i < times.size(); ++i) {
    if (!std::isfinite(times[i])) fail("time " + std::to_string(i) + " not finite");
    if (i > 0 && !(times[i] > times[i - 1])) fail("times not strictly increasing at " + std::to_string(i));
    if (!poses[i].position.allFinite()) fail("position " + std::to_string(i) + " not finite");
    if (!poses[i].rotation.coeffs().allFinite() || std::abs(poses[i].rotation.norm() - 1.0) > 1e-9)
      fail("quaternion " + std::to_string(i) + " not unit within 1e-9");
    if (i > 0 && poses[i].rotation.coeffs().dot(poses[i - 1].rotation.coeffs()) < 0)
      fail("quaternion " + std::to_string(i) + " not on its predecessor's hemisphere");
  }
  if (t.start_time() != times.front() || t.end_time() != times.back()) fail("start_time / end_time");

  // sample() and velocity() across the whole range (the segment cache and the
  // binary search), forwards, then at a few odd times.
  auto probe = [&](double x) {
    const hrt::Pose p = t.sample(x);
    const hrt::Vec6 v = t.velocity(x);
    if (g_strict &&
        !(p.position.allFinite() && p.rotation.coeffs().allFinite() && std::abs(p.rotation.norm() - 1.0) <= 1e-6))
      fail("sample(" + std::to_string(x) + ") not a finite pose with a unit quaternion");
    if (g_strict && !v.allFinite()) fail("velocity(" + std::to_string(x) + ") not finite");
  };
  const size_t n = times.size();
  const size_t stride = n > 256 ? n / 256 : 1;
  for (size_t i = 0; i < n; i += stride) {
    probe(times[i]);
    if (i + 1 < n) probe(times[i] + 0.5 * (times[i + 1] - times[i]));
  }
  const double odd[] = {times.front() - 1.0,
                        times.back() + 1.0,
                        std::nan(""),
                        -std::numeric_limits<double>::infinity(),
                        std::numeric_limits<double>::infinity(),
                        0.5 * (times.front() + times.back())};
  for (double x : odd) probe(x);
  if (g_verbose)
    std::fprintf(stderr, "hrt_fuzz_scene: trajectory loaded: %zu samples, %.17g .. %.17g s\n", n, times.front(),
                 times.back());
}

// ---------------------------------------------------------------------------

int one_input(const uint8_t* data, size_t size) {
  if (size < 1) return -1;  // no selector byte: keep out of the corpus
  const uint8_t sel = data[0];
  const bool csv = (sel & 1) != 0;
  const std::string& path = csv ? g_csv : g_scene;
  write_file(path, data + 1, size - 1);
  if (!csv) {
    try {
      const hrt::RunConfig c = hrt::load_run_config(path);
      check_config(c);
    } catch (const hrt::SceneFileError& e) {
      check_message("SceneFileError", e.what(), path);
      if (g_strict && e.file != path) finding("SceneFileError", "file member is not the scene's path: " + show(e.file));
    } catch (const hrt::InputFileError& e) {
      const int kind = static_cast<int>(e.kind);
      if (kind < static_cast<int>(hrt::InputFileError::Kind::missing) ||
          kind > static_cast<int>(hrt::InputFileError::Kind::unreadable))
        finding("InputFileError", "undocumented kind " + std::to_string(kind));
      check_message("InputFileError", e.what(), path);
    }
  } else {
    const std::string prefix = (sel & 2) ? "device_" : "";
    try {
      const hrt::Trajectory t = hrt::Trajectory::load_csv(path, prefix);
      check_trajectory(t);
    } catch (const hrt::TrajectoryError& e) {
      check_message("TrajectoryError", e.what(), path);
    } catch (const hrt::InputFileError& e) {
      const int kind = static_cast<int>(e.kind);
      if (kind < static_cast<int>(hrt::InputFileError::Kind::missing) ||
          kind > static_cast<int>(hrt::InputFileError::Kind::unreadable))
        finding("InputFileError", "undocumented kind " + std::to_string(kind));
      check_message("InputFileError", e.what(), path);
    }
  }
  return 0;
}

bool env_on(const char* name, bool def) {
  const char* v = std::getenv(name);
  if (!v || !*v) return def;
  return std::strcmp(v, "0") != 0;
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  const char* env = std::getenv("HRT_FUZZ_TMPDIR");
  std::string parent;
  if (writable_dir(env))
    parent = env;
  else if (writable_dir("/dev/shm"))
    parent = "/dev/shm";
  else if (writable_dir(std::getenv("TMPDIR")))
    parent = std::getenv("TMPDIR");
  else
    parent = "/tmp";
  g_root = claim_folder(parent);
  if (::mkdir((g_root + "/a.hbundle").c_str(), 0700) != 0 || ::mkdir((g_root + "/b.hbundle").c_str(), 0700) != 0) {
    std::fprintf(stderr, "hrt_fuzz_scene: cannot create %s: %s\n", g_root.c_str(), std::strerror(errno));
    std::exit(1);
  }
  std::atexit(cleanup);
  write_text(g_root + "/traj.csv",
             "t,x,y,z,qx,qy,qz,qw\n"
             "0,0,0,0.02,0,0,0,1\n"
             "1,0.05,0,0.02,0,0,0.3826834,0.9238795\n"
             "2,0.1,0,0.02,0,0,0.7071068,0.7071068\n");
  write_text(g_root + "/plugin.so", "not a shared library: the scene reader only checks that it is a file\n");
  g_scene = g_root + "/scene.toml";
  g_csv = g_root + "/input.csv";
  g_messages = env_on("HRT_FUZZ_MESSAGES", true);
  g_strict = env_on("HRT_FUZZ_STRICT", false);
  g_verbose = env_on("HRT_FUZZ_VERBOSE", false);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    return one_input(data, size);
  } catch (const std::exception& e) {
    finding("unexpected exception", std::string(typeid(e).name()) + ": " + show(e.what()));
  } catch (...) {
    finding("unexpected exception", "not derived from std::exception");
  }
}
