// `hrt run SCENE.toml [--duration S] [--lockstep | --realtime] [--sched-fifo]
//  [--backend cpu|gl|auto] [--trace PATH] [--device-log PATH] [--json] [--quiet]`
//
// A haptic session: loads the scene file (docs/scene-format.md), then
// hrt::Runner (hrt/runner.h) loads its bundles and trajectories, opens the
// device and runs the simulation (hrt::Session) against the device loop
// (hrt::DeviceLoop):
//   lockstep  one thread, a ManualClock: every device period one tick(), and
//             every sim_every periods one simulation frame of h = sim_every x
//             period; every trace column but the wall-clock *_us timings
//             reproduces to the bit (tests, experiments);
//   real time the device loop in its own thread at a fixed period (absolute
//             deadlines), the simulation in this thread as fast as it can,
//             each frame integrating the wall time since the previous one
//             (at most max_step).
// Writes the trace (docs/trace-format.md) and prints a summary: frames,
// rates, device-loop jitter (real time), clamps, watchdog events. Ctrl-C (or
// SIGTERM) stops cleanly: the device ramps to zero, the trace is written,
// exit 130.
//
// The depth backend ([run] backend, --backend) is made on this thread, which
// is also the one that runs every simulation frame (Session::step) in both
// modes: the GL context is current here, and the device loop's thread never
// touches GL (it only ticks the device).
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "commands.h"
#include "finite_json.h"
#include "hrt/device.h"
#include "hrt/device_loop.h"
#include "hrt/run_config.h"
#include "hrt/scene.h"
#include "hrt/runner.h"
#include "hrt/session.h"
#include "scene_cli.h"

namespace hrt_cli {
namespace {

std::atomic<bool> g_stop{false};
extern "C" void on_signal(int) { g_stop.store(true); }

struct RunFlags {
  std::string scene;
  double duration = -1;
  bool lockstep = false, realtime = false, json = false, quiet = false, sched_fifo = false;
  std::string trace, device_log;
  std::string backend;  // "" = the scene file's run.backend
  int threads = -1;     // -1 = the scene file's run.threads
};

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const size_t i = std::min(v.size() - 1, static_cast<size_t>(std::ceil(q * static_cast<double>(v.size())) - 1));
  return v[i];
}

// The scene file with the flags applied, checked as the file's keys are (and
// what they imply with the file's other keys: a --duration sizes the device log).
hrt::RunConfig load_config(const RunFlags& f) {
  hrt::RunConfig cfg;
  try {
    cfg = hrt::load_run_config(f.scene);
  } catch (const hrt::SceneFileError& e) {
    throw Exit(kScene, std::string("error: ") + e.what());
  }
  hrt::RunOverrides overrides;
  if (f.duration >= 0) overrides.duration = f.duration;
  if (f.lockstep) overrides.lockstep = true;
  if (f.realtime) overrides.lockstep = false;
  overrides.sched_fifo = f.sched_fifo;
  overrides.trace = f.trace;
  overrides.device_log = f.device_log;
  try {
    hrt::apply_overrides(cfg, overrides);
  } catch (const hrt::SceneFileError& e) {
    // A flag's value is a usage error; a limit the file's own keys break is the scene's.
    throw Exit(e.key.rfind("--", 0) == 0 ? kUsage : kScene, std::string("error: ") + e.what());
  }
  // No output may be an input (the scene, a trajectory, the plugin, a
  // bundle's file), whichever way its path came in; checked before anything
  // is opened or written.
  try {
    hrt::check_run_outputs(cfg);
  } catch (const hrt::OutputOverwritesInput& e) {
    throw Exit(kOutput, std::string("error: ") + e.what());
  }
  if (cfg.lockstep && cfg.device.type != "scripted" && cfg.device.type != "virtual")
    throw Exit(kUsage, "--lockstep needs a scripted or virtual device (" + cfg.file + " has device.type = \"" +
                           cfg.device.type + "\"); see hrt run --help");
  return cfg;
}

// The backend choice (--backend over the file's run.backend) and where it
// comes from, for the messages.
struct BackendPick {
  hrt::BackendChoice choice = hrt::BackendChoice::cpu;
  std::string source;
  bool from_file = true;
};

BackendPick apply_backend_flags(const RunFlags& f, hrt::RunConfig& cfg) {
  BackendPick pick;
  pick.source = cfg.file + ": run.backend = \"" + cfg.backend + "\"";
  if (!f.backend.empty()) {
    cfg.backend = f.backend;
    pick.source = "--backend " + f.backend;
    pick.from_file = false;
    // The file checks this pair for its own backend (force.shortcut); an
    // override needs the same check.
    if (cfg.backend == "gl" && cfg.scene.force.shortcut)
      throw Exit(kUsage,
                 "--backend gl: " + cfg.file +
                     " sets [force] shortcut = true, which only the CPU backend implements; see hrt run --help");
  }
  if (f.threads >= 0) cfg.scene.threads = f.threads;
  if (!hrt::parse_backend_choice(cfg.backend, pick.choice))  // both readers checked it already
    throw Exit(kUsage, pick.source + ": not a backend (cpu, gl, auto)");
  return pick;
}

// Bundles, the scene, trajectories of kinematic objects (hrt::Runner).
std::unique_ptr<hrt::Runner> make_runner(const hrt::RunConfig& cfg) {
  try {
    return std::make_unique<hrt::Runner>(cfg);
  } catch (const hrt::TrajectoryError& e) {
    throw Exit(kScene, std::string("error: ") + e.what());
  } catch (const std::invalid_argument& e) {
    throw Exit(kScene, "error: " + cfg.file + ": " + e.what());
  }
}

// The depth backend for the scene's models, before the device is opened
// (a GL failure, exit 7, then leaves no port bound).
CliBackend make_backend(const hrt::Runner& runner, const hrt::RunConfig& cfg, const BackendPick& pick, bool quiet) {
  std::vector<const hrt::Model*> ptrs;
  for (const hrt::Model& m : runner.models()) ptrs.push_back(&m);
  hrt::gl::GlDepthOptions gl_options;
  gl_options.search = cfg.gl_search == "occlusion" ? hrt::gl::MaxSearch::occlusion : hrt::gl::MaxSearch::compute;
  gl_options.occlusion_steps = cfg.occlusion_steps;
  return select_depth_backend(pick.choice, pick.source, gl_options, ptrs, cfg.scene, !quiet);
}

// The device and its limits, the session and the device loop.
void open_runner(hrt::Runner& runner, const hrt::RunConfig& cfg) {
  try {
    runner.open();
  } catch (const hrt::TrajectoryError& e) {
    throw Exit(kScene, std::string("error: ") + e.what());
  } catch (const hrt::DeviceError& e) {
    throw Exit(kDevice, std::string("error: ") + e.what());
  } catch (const std::invalid_argument& e) {
    throw Exit(kScene, "error: " + cfg.file + ": " + e.what());
  }
}

// What the summary counts of the frames, as they come.
struct FrameStats {
  uint64_t frames = 0, max_patches = 0, refused = 0, fading = 0;
  double frame_us_sum = 0;
  std::vector<double> frame_us;
  std::vector<double> gl_total_us;  // the GL backend's total per frame with patches

  explicit FrameStats(bool gl) {
    frame_us.reserve(1 << 16);
    if (gl) gl_total_us.reserve(1 << 16);
  }
  void add(const hrt::SessionFrame& fr, const CliBackend& backend, const hrt::Session& session) {
    ++frames;
    max_patches = std::max<uint64_t>(max_patches, static_cast<uint64_t>(fr.patches));
    refused += static_cast<uint64_t>(fr.refused);
    fading += static_cast<uint64_t>(fr.fading);
    const double us = fr.timings.total_us + fr.dynamics_us;
    frame_us_sum += us;
    if (frame_us.size() < frame_us.capacity()) frame_us.push_back(us);
    // frame() calls the backend only for a frame with patches.
    if (backend.gl && session.state().num_patches > 0 && gl_total_us.size() < gl_total_us.capacity())
      gl_total_us.push_back(backend.gl->stats().total_us);
  }
};

// A backend that refuses the scene's options (std::invalid_argument from
// DepthBackend::evaluate) or fails on the GPU (GlError) stops the session
// as Ctrl-C does (the device ramps to zero), then ends with one line. A
// device that failed for good (a plugin call past its deadline) ends the
// session the same way, then with exit 5 and its one line. Returns the
// error line ("" when none) and sets `code`.
std::string run_session(hrt::Runner& runner, const std::function<bool(const hrt::SessionFrame&)>& record,
                        const CliBackend& backend, const BackendPick& pick, int& code) {
  code = kOk;
  try {
    runner.run(record, &g_stop);
  } catch (const std::invalid_argument& e) {
    if (!backend.gl) throw;  // the CPU code inline never throws it: a bug
    code = pick.from_file ? kScene : kUsage;
    return "error: " + pick.source + ": the " + backend.name() + " backend refused the scene's options: " + e.what();
  } catch (const hrt::gl::GlError& e) {
    code = kGl;
    return "error: " + pick.source + ": " + e.what();
  }
  return std::string();
}

// The trace (closed: renamed from its .partial file) and the device log.
void write_outputs(hrt::TraceWriter& trace, const std::string& trace_error, const hrt::RunConfig& cfg,
                   const hrt::DeviceLoop& loop) {
  if (trace.is_open()) {
    try {
      if (!trace_error.empty()) throw std::runtime_error(trace_error);
      trace.close();
    } catch (const std::runtime_error& e) {
      throw Exit(kOutput, std::string("error: ") + e.what());
    }
  }
  if (!cfg.trace.device_log.empty()) {
    try {
      hrt::write_device_log(cfg.trace.device_log, loop);
    } catch (const std::runtime_error& e) {
      throw Exit(kOutput, std::string("error: ") + e.what());
    }
  }
}

// The trace is written (what the session did up to the fault); a signal
// that came first is the reason the session ended. The process ends here
// with _Exit: a normal exit would run the plugin library's own shutdown
// code (its destructors, an SDK's atexit handlers) while its call is still
// stuck on the worker thread, and could hang on that very call.
[[noreturn]] void exit_on_device_fault(const std::string& device_fault, bool interrupted) {
  std::fprintf(stderr, "hrt: %s\n",
               interrupted ? "interrupted; the device was ramped to zero and the trace written"
                           : ("error: " + device_fault).c_str());
  std::fflush(stdout);
  std::fflush(stderr);
  std::_Exit(interrupted ? kInterrupted : kDevice);
}

// What the summary reads, besides the configuration.
struct RunResult {
  const hrt::RunConfig& cfg;
  hrt::Runner& runner;  // non-const for device() (a UdpDevice's counters)
  const CliBackend& backend;
  const FrameStats& stats;
  const hrt::TraceWriter& trace;
  double wall_s = 0;
  bool interrupted = false;
};

nlohmann::json simulation_json(const RunResult& r) {
  const hrt::RunConfig& cfg = r.cfg;
  const FrameStats& s = r.stats;
  const int every = std::max(1, cfg.sim_every);
  const double wall_s = r.wall_s;
  return {{"rate_hz", cfg.lockstep ? 1.0 / (every * cfg.loop.period) : (wall_s > 0 ? s.frames / wall_s : 0.0)},
          {"achieved_rate_hz", cfg.lockstep ? 1.0 / (every * cfg.loop.period) : (wall_s > 0 ? s.frames / wall_s : 0.0)},
          {"compute_rate_hz", s.frame_us_sum > 0 ? 1e6 * s.frames / s.frame_us_sum : 0.0},
          {"frame_us_median", median(s.frame_us)},
          {"frame_us_p99", percentile(s.frame_us, 0.99)},
          {"period_ms_median", 1e3 * median(r.runner.frame_periods())},
          {"max_patches", s.max_patches},
          {"refused_patch_frames", s.refused},
          {"fading_patch_frames", s.fading}};
}

// Achieved rates: what ran per second of wall time (real time), next to
// the nominal ones; in lockstep the session time is the clock.
double achieved_tick_hz(const RunResult& r) {
  const hrt::RunConfig& cfg = r.cfg;
  return cfg.lockstep ? 1.0 / cfg.loop.period
                      : (r.wall_s > 0 ? static_cast<double>(r.runner.loop().stats().ticks) / r.wall_s : 0.0);
}

nlohmann::json device_loop_json(const RunResult& r) {
  const hrt::RunConfig& cfg = r.cfg;
  const hrt::DeviceLoopStats& st = r.runner.loop().stats();
  nlohmann::json dl = {{"ticks", st.ticks},
                       {"period_s", cfg.loop.period},
                       {"nominal_rate_hz", 1.0 / cfg.loop.period},
                       {"achieved_rate_hz", achieved_tick_hz(r)},
                       {"missed_deadlines", st.missed_deadlines},
                       {"force_clamps", st.force_clamps},
                       {"torque_clamps", st.torque_clamps},
                       {"rate_limited", st.rate_limited},
                       {"non_finite", st.non_finite},
                       {"watchdog_events", st.watchdog_events},
                       {"read_failures", st.read_failures},
                       {"commands", st.commands},
                       {"multirate", cfg.loop.multirate}};
  if (!cfg.lockstep) {
    const hrt::JitterSummary js = hrt::summarize_jitter(st);
    dl["jitter_us"] = {{"p50", 1e6 * js.p50}, {"p99", 1e6 * js.p99}, {"max", 1e6 * js.max}, {"samples", js.samples}};
    dl["sched_fifo"] = st.realtime;
  }
  return dl;
}

nlohmann::json backend_json(const RunResult& r) {
  const hrt::RunConfig& cfg = r.cfg;
  const CliBackend& backend = r.backend;
  nlohmann::json jb = {{"choice", cfg.backend},
                       {"name", backend.name()},
                       {"message", backend.selection.message},
                       {"threads", backend.gl ? 1 : hrt::resolve_threads(cfg.scene.threads)}};
  if (backend.gl) {
    const hrt::gl::GlDepthStats& gs = backend.gl->stats();
    const hrt::gl::ContextInfo& gi = backend.selection.context->info();
    const std::vector<double>& gl_total_us = r.stats.gl_total_us;
    jb["renderer"] = gi.renderer;
    jb["platform"] = gi.platform;
    jb["hardware"] = gi.hardware;
    jb["search"] = cfg.gl_search;
    jb["occlusion_steps"] = cfg.occlusion_steps;
    jb["frames_evaluated"] = gl_total_us.size();
    jb["total_us_median"] = median(gl_total_us);
    jb["total_us_p99"] = percentile(gl_total_us, 0.99);
    jb["buffer_growths"] = gs.buffer_growths;
    // Of the last frame with patches (frame() calls the backend only then).
    jb["last_frame"] = {{"total_us", gs.total_us},
                        {"readback_us", gs.readback_us},
                        {"batches", gs.batches},
                        {"round_trips", gs.round_trips},
                        {"tiles", gs.tiles},
                        {"mesh_quads", gs.mesh_quads},
                        {"occlusion_queries", gs.occlusion_queries}};
  }
  return jb;
}

nlohmann::json summary_json(const RunResult& r) {
  const hrt::RunConfig& cfg = r.cfg;
  const hrt::DeviceInfo& info = r.runner.device_info();
  const hrt::State& state = r.runner.session().state();
  nlohmann::json j;
  j["scene"] = cfg.file;
  j["mode"] = cfg.lockstep ? "lockstep" : "realtime";
  j["device"] = {{"name", info.name}, {"type", cfg.device.type}, {"dof_actuated", info.dof_actuated}};
  j["duration_s"] = cfg.lockstep ? static_cast<double>(r.runner.ticks_total()) * cfg.loop.period : r.wall_s;
  j["wall_s"] = r.wall_s;
  j["frames"] = r.stats.frames;
  j["simulation"] = simulation_json(r);
  j["device_loop"] = device_loop_json(r);
  j["warnings"] = {{"refused_patches", state.warnings.refused_patches},
                   {"clamped_patches", state.warnings.clamped_patches},
                   {"patches_dropped", state.warnings.patches_dropped},
                   {"undersampled_patches", state.warnings.depth.undersampled_patches},
                   {"deep_fallbacks", state.warnings.deep_fallbacks},
                   {"deep_fallback_patches", state.warnings.deep_fallback_patches}};
  if (auto* udp = dynamic_cast<hrt::UdpDevice*>(&r.runner.device())) {
    const hrt::UdpCounters c = udp->counters();
    j["udp"] = {{"port", udp->bound_port()},        {"received", c.received},        {"accepted", c.accepted},
                {"bad_size", c.bad_size},           {"bad_magic", c.bad_magic},      {"bad_version", c.bad_version},
                {"bad_type", c.bad_type},           {"non_finite", c.non_finite},    {"out_of_order", c.out_of_order},
                {"sent_wrenches", c.sent_wrenches}, {"sent_display", c.sent_display}};
  }
  j["backend"] = backend_json(r);
  j["trace"] = cfg.trace.path;
  j["trace_rows"] = r.trace.rows();
  j["trace_truncated"] = r.trace.truncated();
  j["interrupted"] = r.interrupted;
  return j;
}

void print_summary(const RunResult& r, const nlohmann::json& j) {
  const hrt::RunConfig& cfg = r.cfg;
  const FrameStats& s = r.stats;
  const hrt::DeviceLoopStats& st = r.runner.loop().stats();
  const hrt::State& state = r.runner.session().state();
  const nlohmann::json& dl = j["device_loop"];
  const double wall_s = r.wall_s;
  std::printf("hrt run %s: %s, %llu frames in %.3f s of session time (%s, %.3f s wall)\n", cfg.file.c_str(),
              cfg.lockstep ? "lockstep" : "real time", static_cast<unsigned long long>(s.frames),
              j["duration_s"].get<double>(), r.runner.device_info().name.c_str(), wall_s);
  std::printf(
      "  simulation: %.0f Hz%s; frame compute median %.1f us, p99 %.1f us (%.0f Hz if alone); up to %llu patches\n",
      j["simulation"]["rate_hz"].get<double>(), cfg.lockstep ? "" : " achieved", median(s.frame_us),
      percentile(s.frame_us, 0.99), j["simulation"]["compute_rate_hz"].get<double>(),
      static_cast<unsigned long long>(s.max_patches));
  if (cfg.lockstep)
    std::printf("  device loop: %llu ticks at %.0f Hz (lockstep), multirate %s",
                static_cast<unsigned long long>(st.ticks), 1.0 / cfg.loop.period, cfg.loop.multirate ? "on" : "off");
  else
    std::printf("  device loop: %llu ticks in %.3f s: %.0f Hz achieved of %.0f Hz, %llu missed deadlines, multirate %s",
                static_cast<unsigned long long>(st.ticks), wall_s, achieved_tick_hz(r), 1.0 / cfg.loop.period,
                static_cast<unsigned long long>(st.missed_deadlines), cfg.loop.multirate ? "on" : "off");
  if (!cfg.lockstep)
    std::printf("; period error p50 %.1f us, p99 %.1f us, max %.1f us (SCHED_FIFO %s)",
                dl["jitter_us"]["p50"].get<double>(), dl["jitter_us"]["p99"].get<double>(),
                dl["jitter_us"]["max"].get<double>(), st.realtime ? "on" : "off");
  std::printf(
      "\n  safety: %llu force clamps, %llu torque clamps, %llu rate-limited, %llu non-finite dropped, "
      "%llu watchdog events, %llu refused patches, %llu deep fallbacks\n",
      static_cast<unsigned long long>(st.force_clamps), static_cast<unsigned long long>(st.torque_clamps),
      static_cast<unsigned long long>(st.rate_limited), static_cast<unsigned long long>(st.non_finite),
      static_cast<unsigned long long>(st.watchdog_events),
      static_cast<unsigned long long>(state.warnings.refused_patches),
      static_cast<unsigned long long>(state.warnings.deep_fallbacks));
  // What the two counters mean, once, where they are not zero (a new user reads
  // "refused" as an error; it is the safety rule working).
  if (state.warnings.refused_patches > 0)
    std::printf(
        "    refused: patch-frames whose normal or depth the convex pieces contradict (an edge-on or "
        "wrong-way normal, heights that are not this contact's); they gave no force, by design "
        "(docs/hrt-query-json.md, `refused`)\n");
  if (state.warnings.deep_fallbacks > 0)
    std::printf(
        "    deep fallbacks: frames where the probe was deeper than a patch's force can be trusted; a "
        "penalty along the pieces' penetration pushed it out instead\n");
  if (r.backend.gl)
    std::printf("  depth backend: %s; GL total median %.1f us, p99 %.1f us over %zu frames with patches\n",
                r.backend.describe().c_str(), median(s.gl_total_us), percentile(s.gl_total_us, 0.99),
                s.gl_total_us.size());
  if (!cfg.trace.path.empty()) std::printf("  trace: %s\n", cfg.trace.path.c_str());
}

int run(const RunFlags& f) {
  hrt::RunConfig cfg = load_config(f);
  const BackendPick pick = apply_backend_flags(f, cfg);
  std::unique_ptr<hrt::Runner> runner = make_runner(cfg);
  // The session inside the runner points at the backend: runner_reset ends the runner first.
  const CliBackend backend = make_backend(*runner, cfg, pick, f.quiet);
  struct RunnerReset {  // the session (inside the runner) goes before the backend it points at
    std::unique_ptr<hrt::Runner>& r;
    ~RunnerReset() { r.reset(); }
  } runner_reset{runner};

  open_runner(*runner, cfg);
  runner->set_depth_backend(backend.for_state());
  const hrt::Session& session = runner->session();

  hrt::TraceWriter trace;
  try {
    if (!cfg.trace.path.empty()) trace.open(cfg.trace.path, cfg.trace);
  } catch (const std::runtime_error& e) {
    throw Exit(kOutput, std::string("error: ") + e.what());
  }

  g_stop.store(false);
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);

  FrameStats stats(backend.gl != nullptr);
  const auto wall0 = std::chrono::steady_clock::now();
  std::string trace_error;
  auto record = [&](const hrt::SessionFrame& fr) {
    stats.add(fr, backend, session);
    if (trace.is_open() && trace_error.empty()) {
      try {
        trace.row(hrt::TraceRow{&fr, &runner->target()});
      } catch (const std::runtime_error& e) {
        trace_error = e.what();
      }
    }
    return true;
  };
  int step_error_code = kOk;
  const std::string step_error = run_session(*runner, record, backend, pick, step_error_code);
  const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  const bool interrupted = g_stop.load();
  const std::string device_fault = runner->device().fault();
  std::signal(SIGINT, SIG_DFL);
  std::signal(SIGTERM, SIG_DFL);
  // No trace of a session that did not run its scene (the writer's
  // destructor removes the .partial file).
  if (!step_error.empty()) throw Exit(step_error_code, step_error);

  write_outputs(trace, trace_error, cfg, runner->loop());
  if (!device_fault.empty()) exit_on_device_fault(device_fault, interrupted);
  if (trace.truncated())
    std::fprintf(stderr,
                 "hrt: warning: %s: the trace stopped at %llu rows, %llu bytes: [trace] max_bytes (%llu); "
                 "the session ran on\n",
                 cfg.trace.path.c_str(), static_cast<unsigned long long>(trace.rows()),
                 static_cast<unsigned long long>(trace.bytes()), static_cast<unsigned long long>(cfg.trace.max_bytes));

  const RunResult result{cfg, *runner, backend, stats, trace, wall_s, interrupted};
  const nlohmann::json j = summary_json(result);
  if (!first_non_finite(j).empty()) throw Exit(kInternal, "internal error: non-finite value in the summary");
  if (f.json)
    std::printf("%s\n", j.dump(2).c_str());
  else if (!f.quiet)
    print_summary(result, j);
  if (interrupted) {
    std::fprintf(stderr, "hrt: interrupted; the device was ramped to zero and the trace written\n");
    return kInterrupted;
  }
  return kOk;
}

}  // namespace

void register_run(CLI::App& app) {
  auto f = std::make_shared<RunFlags>();
  CLI::App* sub = app.add_subcommand("run", "Run a haptic session from a scene file (docs/scene-format.md)");
  sub->add_option("scene", f->scene, "Scene file (TOML)")->required();
  sub->add_option("--duration", f->duration, "Session time to run, s (overrides run.duration)")
      ->check(CLI::Validator(
          [](std::string& v) {
            try {
              size_t used = 0;
              const double d = std::stod(v, &used);
              if (used == v.size() && std::isfinite(d) && d > 0) return std::string();
            } catch (const std::exception&) {
            }
            return "'" + v + "' is not a positive number of seconds";
          },
          "SECONDS > 0"));
  sub->add_flag("--lockstep", f->lockstep, "Fixed step, no wall clock (overrides run.lockstep)");
  sub->add_flag("--realtime", f->realtime, "Device thread at its period, simulation as fast as it can");
  sub->add_option("--trace", f->trace, "Trace CSV (overrides trace.path; docs/trace-format.md)");
  sub->add_option("--device-log", f->device_log, "Per-device-tick CSV (overrides trace.device_log)");
  sub->add_flag("--sched-fifo", f->sched_fifo,
                "Ask for SCHED_FIFO for the device thread (overrides loop.realtime; falls back and says so)");
  sub->add_option("--backend", f->backend,
                  "Where the penetration depth runs (overrides run.backend): cpu, gl (exit 7 without a usable "
                  "OpenGL 4.5 context), auto (gl only on a hardware renderer that beats the cpu in a short probe)")
      ->check(CLI::IsMember({"cpu", "gl", "auto"}));
  sub->add_option("--threads", f->threads,
                  "Threads of the CPU backend, the contact patches of a frame in parallel (overrides run.threads; "
                  "0: every hardware thread; the results do not depend on it)")
      ->check(CLI::Range(0, hrt::kMaxThreads));
  sub->add_flag("--json", f->json, "Print the summary as JSON");
  sub->add_flag("--quiet", f->quiet, "Print nothing on success");
  sub->callback([f]() {
    if (f->lockstep && f->realtime)
      throw Exit(kUsage, "--lockstep and --realtime exclude each other; see hrt run --help");
    const int rc = run(*f);
    if (rc != kOk) throw Exit(rc, "");
  });
}

}  // namespace hrt_cli
