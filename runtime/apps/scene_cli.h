// Command-line pieces shared by `hrt query` and `hrt bench`: the scene
// options as flags, the depth backend (`--backend`), pose parsing, bundle
// loading. Header-only, used by cmd_query.cpp and cmd_bench.cpp.
#pragma once

#include <cerrno>
#include <climits>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "commands.h"
#include "hrt/depth_backend.h"
#include "hrt/gl_depth.h"
#include "hrt/model.h"
#include "hrt/scene.h"

namespace hrt_cli {

// Strict number syntax for every numeric option. CLI11 2.1's own conversion
// reads "" as 0 and accepts hex, "nan", "inf" and out-of-range values, so
// each value's text is checked first: a decimal number, fully consumed,
// finite, nothing before or after it.
inline std::string real_number_error(const std::string& s) {
  if (s.empty()) return "empty value, expected a number";
  if (s.find_first_not_of("0123456789+-.eE") != std::string::npos) return "'" + s + "' is not a decimal number";
  errno = 0;
  char* end = nullptr;
  const double x = std::strtod(s.c_str(), &end);
  if (end != s.c_str() + s.size()) return "'" + s + "' is not a number";
  // ERANGE on underflow (1e-400 -> 0) is harmless; overflow is refused.
  if ((errno == ERANGE && std::fabs(x) >= 1.0) || !std::isfinite(x))
    return "'" + s + "' is out of the range of a double";
  return "";
}
inline std::string integer_error(const std::string& s) {
  if (s.empty()) return "empty value, expected an integer";
  const size_t digits = s[0] == '-' || s[0] == '+' ? 1 : 0;
  if (s.size() == digits || s.find_first_not_of("0123456789", digits) != std::string::npos)
    return "'" + s + "' is not a decimal integer";
  errno = 0;
  const long long v = std::strtoll(s.c_str(), nullptr, 10);
  if (errno == ERANGE || v < INT_MIN || v > INT_MAX) return "'" + s + "' is out of the range of an int";
  return "";
}
inline CLI::Validator RealNumber() {
  return CLI::Validator([](std::string& s) { return real_number_error(s); }, "NUMBER", "RealNumber");
}
inline CLI::Validator Integer() {
  return CLI::Validator([](std::string& s) { return integer_error(s); }, "INT", "Integer");
}

// Flags that set hrt::SceneOptions; defaults are SceneOptions' own.
struct SceneFlags {
  int resolution = hrt::kDefaultResolution;
  double stiffness = hrt::kDefaultStiffness;
  double lin_step = 0.0;
  double ang_step = 0.0;
  double margin = -1.0;
  bool shortcut = false;
  std::string heights = "surface";
  int max_patches = hrt::ClusterOptions{}.max_patches;
  bool auto_resolution = hrt::ClusterOptions{}.auto_resolution;
  int max_resolution = hrt::ClusterOptions{}.max_resolution;
  bool verify_hashes = true;
  // The depth backend (hrt/depth_backend.h, hrt/gl_depth.h).
  std::string backend = "cpu";
  std::string gl_search = "compute";
  int occlusion_steps = hrt::gl::GlDepthOptions{}.occlusion_steps;
  int threads = 0;  // SceneOptions::threads (0: every hardware thread)
  // Set by add_to: whether --gl-search / --occlusion-steps were given (a
  // value for a backend or search that does not use it is refused, as the
  // scene file refuses a key of another device type).
  const CLI::Option* gl_search_opt = nullptr;
  const CLI::Option* occlusion_steps_opt = nullptr;

  void add_to(CLI::App* cmd, bool with_resolution = true) {
    if (with_resolution)
      cmd->add_option("--resolution", resolution, "grid resolution N of each patch window (N x N texels)")
          ->check(Integer())
          ->capture_default_str();
    cmd->add_option("--stiffness", stiffness, "stiffness k of Eq. 3, N/m")->check(RealNumber())->capture_default_str();
    cmd->add_option("--lin-step", lin_step, "translation step of Eq. 7, m (0: one grid texel)")
        ->check(RealNumber())
        ->capture_default_str();
    cmd->add_option("--ang-step", ang_step, "rotation step of Eq. 7, rad (0: the matching angle, one texel)")
        ->check(RealNumber())
        ->capture_default_str();
    cmd->add_option("--margin", margin,
                    "m added to the contact tolerance (negative: 0.1% of the smaller bbox diagonal)")
        ->check(RealNumber())
        ->capture_default_str();
    cmd->add_flag("--shortcut", shortcut, "resample h_A(0) for the translated and n-rotated configurations (Sec. 5.2)");
    cmd->add_option("--heights", heights,
                    "surface: the reconstructed full surface on each texel column (parallax corrected); coarse: the "
                    "literal Eq. 8 of format 1.0 (n . f(q) at the coarse point q's column); mesh: the atlas quads "
                    "themselves, every face in reach at any angle, each texel the highest point over its square "
                    "(both backends)")
        ->check(CLI::IsMember({"surface", "coarse", "mesh"}))
        ->capture_default_str();
    cmd->add_option("--max-patches", max_patches, "most contact patches per frame")
        ->check(Integer())
        ->capture_default_str();
    cmd->add_flag("--auto-resolution", auto_resolution,
                  "per patch, raise N (up to --max-resolution) until the grid texel is <= 1/4 of the bundles' "
                  "min_wavelength");
    cmd->add_option("--max-resolution", max_resolution, "budget of --auto-resolution: largest N of a patch")
        ->check(Integer())
        ->capture_default_str();
    cmd->add_option("--threads", threads,
                    "threads of the CPU backend: the contact patches of a frame are evaluated in parallel (0: every "
                    "hardware thread; the results do not depend on it)")
        ->check(CLI::Range(0, hrt::kMaxThreads))
        ->capture_default_str();
    cmd->add_flag("!--no-verify-hashes", verify_hashes, "skip the SHA-256 checks of the bundles' files");
    cmd->add_option("--backend", backend,
                    "where the penetration depth runs: cpu (the reference); gl (the OpenGL 4.5 backend on a headless "
                    "EGL context, exit 7 when there is none); auto (gl only on a hardware renderer that beats the "
                    "cpu in a short probe, else cpu)")
        ->check(CLI::IsMember({"cpu", "gl", "auto"}))
        ->capture_default_str();
    gl_search_opt = cmd->add_option("--gl-search", gl_search,
                                    "the GL backend's max search: compute (a compute-shader reduction, exact) or "
                                    "occlusion (the paper's occlusion-query binary search, --occlusion-steps passes)")
                        ->check(CLI::IsMember({"compute", "occlusion"}))
                        ->capture_default_str();
    occlusion_steps_opt =
        cmd->add_option("--occlusion-steps", occlusion_steps,
                        "binary-search passes of --gl-search occlusion (1..23; delta within 2 R / 2^steps)")
            ->check(Integer())
            ->check(CLI::Range(1, 23))
            ->capture_default_str();
  }

  // The combinations of the backend flags that mean nothing (or that the GL
  // backend refuses): usage errors, before any bundle is loaded.
  void check_backend_flags() const {
    const bool may_use_gl = backend != "cpu";
    if (gl_search_opt && gl_search_opt->count() > 0 && !may_use_gl)
      throw Exit(kUsage, "--gl-search: only with --backend gl or auto (the backend is cpu)");
    if (occlusion_steps_opt && occlusion_steps_opt->count() > 0 && (!may_use_gl || gl_search != "occlusion"))
      throw Exit(kUsage, "--occlusion-steps: only with --gl-search occlusion (and --backend gl or auto)");
    // The GL backend implements full re-rasterization only (gl_depth.h); auto
    // then stays on the cpu (select_depth_backend).
    if (backend == "gl" && shortcut)
      throw Exit(kUsage,
                 "--shortcut: the Sec. 5.2 shortcut is implemented by the CPU backend only; drop --shortcut or use "
                 "--backend cpu");
  }

  hrt::gl::GlDepthOptions gl_options() const {
    hrt::gl::GlDepthOptions g;
    g.search = gl_search == "occlusion" ? hrt::gl::MaxSearch::occlusion : hrt::gl::MaxSearch::compute;
    g.occlusion_steps = occlusion_steps;
    return g;
  }

  hrt::SceneOptions scene_options() const {
    hrt::SceneOptions o;
    o.force.resolution = resolution;
    o.force.stiffness = stiffness;
    o.force.lin_step = lin_step;
    o.force.ang_step = ang_step;
    o.force.shortcut = shortcut;
    hrt::parse_height_mode(heights, o.force.heights);  // checked by the option's IsMember
    o.collision.margin = margin;
    o.cluster.max_patches = max_patches;
    o.cluster.auto_resolution = auto_resolution;
    o.cluster.max_resolution = max_resolution;
    o.threads = threads;
    return o;
  }
};

// The depth backend a command runs on. `selection` owns the GL context and
// the backend (BackendSelection destroys the backend before the context, as
// the GL objects need); it must outlive every State pointing at the backend:
// declare it before the State.
struct CliBackend {
  hrt::BackendChoice choice = hrt::BackendChoice::cpu;
  hrt::gl::BackendSelection selection;
  hrt::gl::GlDepthBackend* gl = nullptr;  // selection.backend when the GL backend was chosen

  // For State::depth_backend: the GL backend, or null for the CPU one. With
  // null, frame() runs the CPU depth code inline patch by patch: the path the
  // results were validated on (CpuDepthBackend computes the same numbers),
  // without the per-frame job tables and the virtual call.
  hrt::DepthBackend* for_state() const { return gl; }
  const char* name() const { return gl ? "gl" : "cpu"; }
  std::string renderer() const { return gl ? selection.context->info().renderer : std::string(); }
  // "cpu", or "gl on RENDERER (compute search)" / "(occlusion search, 16 steps)".
  std::string describe() const {
    if (!gl) return "cpu";
    const hrt::gl::GlDepthOptions& g = gl->options();
    return "gl on " + renderer() + " (" +
           (g.search == hrt::gl::MaxSearch::occlusion
                ? "occlusion search, " + std::to_string(g.occlusion_steps) + " steps"
                : std::string("compute search")) +
           ")";
  }
};

// Makes the backend `choice` names for `models` (every model the scene can
// evaluate) and `options` (auto's probe runs at options.force.resolution).
// `source` names where the choice came from in messages ("--backend gl",
// "scene.toml: run.backend = \"gl\""). Prints select_backend's one-line
// message on stderr when `announce` and the choice was not cpu (with cpu
// nothing was chosen, so there is nothing to say; the outputs name the
// backend anyway). A GL failure (no context, or one that lacks what the
// backend needs) ends the command with exit 7 and one line naming what is
// missing, as `hrt gl-info` does. The context is current on the calling
// thread: call this on the thread that runs the frames.
inline CliBackend select_depth_backend(hrt::BackendChoice choice, const std::string& source,
                                       const hrt::gl::GlDepthOptions& gl_options,
                                       const std::vector<const hrt::Model*>& models, const hrt::SceneOptions& options,
                                       bool announce) {
  CliBackend out;
  out.choice = choice;
  // gl with options only the CPU implements is refused earlier, by the
  // callers' checks (with the flag or key to blame); auto keeps to the cpu
  // for them inside select_backend.
  try {
    out.selection = hrt::gl::select_backend(choice, models, options, gl_options);
  } catch (const hrt::gl::GlError& e) {
    std::string what = e.what();
    for (char& c : what)
      if (c == '\n' || c == '\r') c = ' ';  // one line, whatever the driver said
    throw Exit(kGl, "error: " + source + ": " + what);
  }
  out.gl = dynamic_cast<hrt::gl::GlDepthBackend*>(out.selection.backend.get());
  if (announce && choice != hrt::BackendChoice::cpu) std::fprintf(stderr, "hrt: %s\n", out.selection.message.c_str());
  return out;
}

// SceneFlags' backend (query, bench): checked by check_backend_flags first.
// `profile`: GlDepthOptions::profile (the per-stage split of hrt bench).
inline CliBackend select_depth_backend(const SceneFlags& flags, const std::vector<const hrt::Model*>& models,
                                       const hrt::SceneOptions& options, bool profile, bool announce) {
  hrt::BackendChoice choice = hrt::BackendChoice::cpu;
  if (!hrt::parse_backend_choice(flags.backend, choice))  // CLI11 checked it already
    throw Exit(kUsage, "--backend: '" + flags.backend + "' is not a backend (cpu, gl, auto)");
  hrt::gl::GlDepthOptions g = flags.gl_options();
  g.profile = profile;
  return select_depth_backend(choice, "--backend " + flags.backend, g, models, options, announce);
}

// hrt::frame with a backend, its failures as one line: an option the
// backend refuses (std::invalid_argument from DepthBackend::evaluate) is a
// usage error, a GL error in the frame exits 7 as a missing context does.
// The CPU code inline throws neither.
inline void frame_or_usage(const hrt::Scene& scene, hrt::State& st) {
  try {
    hrt::frame(scene, st);
  } catch (const std::invalid_argument& e) {
    if (!st.depth_backend) throw;
    throw Exit(kUsage,
               std::string("--backend: the ") + st.depth_backend->name() + " backend refused the options: " + e.what());
  } catch (const hrt::gl::GlError& e) {
    throw Exit(kGl, std::string("error: --backend: the ") + (st.depth_backend ? st.depth_backend->name() : "cpu") +
                        " backend failed in a frame: " + e.what());
  }
}

// The supported range of positions (poses, bench paths): |p| <= 1e4 m. The
// models are parts of at most metres; far beyond this the contact
// computations lose all precision in double and overflow near 1e308 (a
// position of 5e307 printed null for the contact points in --json).
constexpr double kMaxPosition = 1e4;
// Tolerance on the norm of a pose's quaternion before it is normalised.
constexpr double kQuaternionTolerance = 1e-3;

inline std::string fmt_g(double x) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", x);
  return buf;
}

// A pose from 7 numbers x y z qx qy qz qw (m, unit quaternion in glTF order).
// The quaternion is normalised; one whose norm is far from 1 is refused
// (it is most likely in w x y z order or not a rotation).
inline hrt::Pose parse_pose(const std::vector<double>& v, const std::string& flag) {
  if (v.size() != 7)
    throw Exit(kUsage, flag + ": expected 7 numbers x y z qx qy qz qw, got " + std::to_string(v.size()));
  for (double x : v)
    if (!std::isfinite(x)) throw Exit(kUsage, flag + ": every number must be finite");
  const hrt::Vec3 position(v[0], v[1], v[2]);
  if (!(position.stableNorm() <= kMaxPosition))
    throw Exit(kUsage, flag + ": the position (" + fmt_g(v[0]) + ", " + fmt_g(v[1]) + ", " + fmt_g(v[2]) + ") is " +
                           fmt_g(position.stableNorm()) + " m from the origin; |position| must be at most " +
                           fmt_g(kMaxPosition) + " m");
  Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);  // Eigen's constructor takes w first
  const double norm = q.coeffs().stableNorm();   // no overflow to inf for 1e308
  if (!(std::abs(norm - 1.0) <= kQuaternionTolerance))
    throw Exit(kUsage, flag + ": the quaternion (qx qy qz qw) has norm " + fmt_g(norm) +
                           ", expected a unit quaternion (x, y, z, w order; norm within " +
                           fmt_g(kQuaternionTolerance) + " of 1)");
  hrt::Pose p;
  p.position = position;
  p.rotation = q.normalized();
  return p;
}

// Loads every bundle (BundleError propagates to main: exit code 3).
inline std::vector<std::unique_ptr<hrt::Model>> load_models(const std::vector<std::string>& paths, bool verify) {
  hrt::LoadOptions lo;
  lo.verify_hashes = verify;
  std::vector<std::unique_ptr<hrt::Model>> out;
  for (const std::string& p : paths) out.push_back(std::make_unique<hrt::Model>(hrt::load_bundle(p, lo)));
  return out;
}

// Builds the scene; bad options become a usage error.
inline std::unique_ptr<hrt::Scene> make_scene(const std::vector<const hrt::Model*>& objects,
                                              const hrt::SceneOptions& o) {
  try {
    return std::make_unique<hrt::Scene>(objects, o);
  } catch (const std::invalid_argument& e) {
    throw Exit(kUsage, e.what());
  }
}

}  // namespace hrt_cli
