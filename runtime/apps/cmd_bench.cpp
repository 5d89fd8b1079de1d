// `hrt bench --a A.hbundle --b B.hbundle --pose-a ... [--pose-b ...]
//  [--settle DX DY DZ --settle-depth D] [--path DX DY DZ] [--frames F]
//  [--resolutions 32,50,64,128] [--copies 1,2,4,...,16]
//  [--backend cpu|gl|auto [--gl-search ...]] [--json]`
//
// Times haptic frames (Sec. 3.3: collision, clustering, texture force) of a
// probe A moving against B, the way the paper measured a file scraping a CAD
// part (Sec. 6.4, Fig. 9): A travels back and forth along a path (one new pose
// per frame, `--frames` poses from --pose-a to --pose-a + --path), the first
// pass is a warm-up, the medians are over the following `--passes` - 1
// passes. Reported per grid resolution N:
//   - the scraping path itself (real contacts: pairs and patches as they come),
//     with the per-pair collision and per-patch force costs;
//   - the same frames binned by their number of patches;
//   - scenes with K copies of B spread along the path (each copy sees A at a
//     different point of the path), so the patch count grows with K while every
//     patch stays a real one.
// --settle first moves A from --pose-a along a direction until its deepest
// patch penetrates by --settle-depth (bisection), so a script does not need to
// know the exact contact height of two baked bundles.
// With --backend gl (or auto choosing gl) the depth runs on the GL backend,
// profiled (GlDepthOptions::profile: a wait after each stage, so the split
// adds up to the stage's cost), and a fourth table gives the medians of its
// split (upload, draw, resolve, reduce, read-back, total) and round trips
// per N and patch count, on the path and for the copies.
// The CPU backend runs the patches of a frame on --threads threads (all
// hardware threads by default); the machine, the threads (and the GL
// renderer) are printed with the table.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "commands.h"
#include "finite_json.h"
#include "hrt/scene.h"
#include "scene_cli.h"

namespace hrt_cli {
namespace {

struct BenchOptions {
  std::string a, b;
  std::vector<double> pose_a;
  std::vector<double> pose_b{0, 0, 0, 0, 0, 0, 1};
  std::vector<double> settle;         // direction (3) or empty
  double settle_depth = 5e-5;         // m
  std::vector<double> path{0, 0, 0};  // total translation of A along the sweep, m
  int frames = 500;                   // poses along the path (one frame each)
  int passes = 3;                     // back-and-forth passes; the first is a warm-up
  std::vector<int> resolutions{32, 50, 64, 128};
  std::vector<int> copies{1, 2, 4, 7, 8, 12, 16};
  // The lists as given (comma-separated, possibly over several arguments);
  // split here, not by CLI11, which silently drops empty items ("32,,64").
  std::vector<std::string> resolutions_arg, copies_arg;
  SceneFlags scene;
  bool json = false;
};

// Upper bounds of the sweep's size (frames x passes records are kept).
constexpr int kMaxFrames = 1000000;
constexpr int kMaxPasses = 100;
// --settle-depth: a penetration of more than 1 m is not a contact.
constexpr double kMaxSettleDepth = 1.0;

// NaN = no sample (printed "nan" in the tables, null in --json).
double median(std::vector<double> v) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

std::string machine_name() {
  std::ifstream in("/proc/cpuinfo");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("model name", 0) == 0) {
      auto p = line.find(':');
      if (p != std::string::npos) return line.substr(p + 2);
    }
  }
  return "unknown CPU";
}

hrt::Pose translated(const hrt::Pose& p, const hrt::Vec3& d) {
  hrt::Pose q = p;
  q.position += d;
  return q;
}

// Deepest covered patch of one fresh frame (-inf when there is none).
double deepest(const hrt::Scene& scene, const std::vector<hrt::Pose>& poses) {
  hrt::State st(scene);
  st.poses = poses;
  hrt::frame(scene, st);
  double d = -std::numeric_limits<double>::infinity();
  for (int k = 0; k < st.num_patches; ++k)
    if (st.patches[static_cast<size_t>(k)].covered) d = std::max(d, st.patches[static_cast<size_t>(k)].delta);
  return d;
}

// Moves A from `start` along `dir` until its deepest patch reaches `depth`.
hrt::Pose settle(const hrt::Scene& scene, const hrt::Pose& start, const hrt::Pose& pose_b, hrt::Vec3 dir,
                 double depth) {
  dir.normalize();
  auto f = [&](double s) { return deepest(scene, {translated(start, s * dir), pose_b}); };
  if (f(0.0) >= depth)
    throw Exit(kUsage, "--settle: A already penetrates deeper than --settle-depth at --pose-a; start it farther out");
  const double travel = scene.model(0).quality.bbox_diagonal + scene.model(1).quality.bbox_diagonal +
                        (start.position - pose_b.position).norm();
  const double h = std::max(0.25 * scene.tolerance(1), 1e-6);
  double lo = 0.0, hi = -1.0;
  for (double s = h; s <= travel; s += h) {
    if (f(s) >= depth) {
      hi = s;
      break;
    }
    lo = s;
  }
  if (hi < 0) throw Exit(kUsage, "--settle: A never reached B along the --settle direction");
  for (int it = 0; it < 60 && hi - lo > 1e-12; ++it) {
    const double mid = 0.5 * (lo + hi);
    (f(mid) >= depth ? hi : lo) = mid;
  }
  return translated(start, hi * dir);
}

// The GL backend's split of one frame (GlDepthStats, profiled).
struct GlSplit {
  double upload, draw, resolve, reduce, readback, total;
  int round_trips;
};

struct FrameRecord {
  double collision, clustering, force, total;
  int pairs, patches;
  bool has_gl;  // the GL backend evaluated this frame (it had patches)
  GlSplit gl;
};

// Runs the sweep: `passes` back-and-forth passes of `frames` poses; records
// every frame after the first pass. `backend` (non-null: the GL one) runs
// the depth and its stats are recorded per frame.
std::vector<FrameRecord> sweep(const hrt::Scene& scene, const std::vector<hrt::Pose>& base, const hrt::Vec3& path,
                               int frames, int passes, hrt::gl::GlDepthBackend* backend, hrt::Warnings* warnings) {
  hrt::State st(scene);
  st.depth_backend = backend;
  st.poses = base;
  std::vector<FrameRecord> out;
  out.reserve(static_cast<size_t>(frames) * static_cast<size_t>(std::max(passes - 1, 1)));
  for (int pass = 0; pass < passes; ++pass) {
    for (int f = 0; f < frames; ++f) {
      const double t = frames > 1 ? static_cast<double>(f) / (frames - 1) : 0.0;
      const double s = (pass % 2 == 0) ? t : 1.0 - t;  // back and forth: consecutive poses stay close
      st.poses[0] = translated(base[0], s * path);
      frame_or_usage(scene, st);
      if (pass == 0 && passes > 1) continue;
      FrameRecord r{st.timings.collision_us,
                    st.timings.clustering_us,
                    st.timings.force_us,
                    st.timings.total_us,
                    st.num_pairs,
                    st.num_patches,
                    false,
                    {}};
      // frame() calls the backend only for a frame with patches: otherwise
      // its stats are still the previous frame's.
      if (backend && st.num_patches > 0) {
        const hrt::gl::GlDepthStats& g = backend->stats();
        r.has_gl = true;
        r.gl = {g.upload_us, g.draw_us, g.resolve_us, g.reduce_us, g.readback_us, g.total_us, g.round_trips};
      }
      out.push_back(r);
    }
  }
  if (warnings) *warnings = st.warnings;
  return out;
}

// The scraping path's sweeps and the copies table's, as functions of their
// own, never inlined: examples/bench_speed.py counts the instructions of one
// kind with callgrind --toggle-collect=*path_sweep* (or *copies_sweep*).
[[gnu::noinline]] std::vector<FrameRecord> path_sweep(const hrt::Scene& scene, const std::vector<hrt::Pose>& base,
                                                      const hrt::Vec3& path, int frames, int passes,
                                                      hrt::gl::GlDepthBackend* backend, hrt::Warnings* warnings) {
  return sweep(scene, base, path, frames, passes, backend, warnings);
}
[[gnu::noinline]] std::vector<FrameRecord> copies_sweep(const hrt::Scene& scene, const std::vector<hrt::Pose>& base,
                                                        const hrt::Vec3& path, int frames, int passes,
                                                        hrt::gl::GlDepthBackend* backend) {
  return sweep(scene, base, path, frames, passes, backend, nullptr);
}

struct Summary {
  double collision, clustering, force, total, per_pair, per_patch;
  double pairs_med, patches_med;
  int pairs_min, pairs_max, patches_min, patches_max;
  long long pairs_total, patches_total;  // over the recorded frames (instructions per patch from callgrind)
  size_t frames;
};

Summary summarize(const std::vector<FrameRecord>& r) {
  std::vector<double> c, k, f, t, pp, pf, np, nk;
  Summary s{};
  s.pairs_min = s.patches_min = std::numeric_limits<int>::max();
  s.pairs_max = s.patches_max = 0;
  for (const FrameRecord& x : r) {
    c.push_back(x.collision);
    k.push_back(x.clustering);
    f.push_back(x.force);
    t.push_back(x.total);
    if (x.pairs > 0) pp.push_back(x.collision / x.pairs);
    if (x.patches > 0) pf.push_back(x.force / x.patches);
    np.push_back(x.pairs);
    nk.push_back(x.patches);
    s.pairs_min = std::min(s.pairs_min, x.pairs);
    s.pairs_max = std::max(s.pairs_max, x.pairs);
    s.patches_min = std::min(s.patches_min, x.patches);
    s.patches_max = std::max(s.patches_max, x.patches);
    s.pairs_total += x.pairs;
    s.patches_total += x.patches;
  }
  s.collision = median(c);
  s.clustering = median(k);
  s.force = median(f);
  s.total = median(t);
  s.per_pair = median(pp);
  s.per_patch = median(pf);
  s.pairs_med = median(np);
  s.patches_med = median(nk);
  s.frames = r.size();
  return s;
}

// A median in --json: null when there was no sample (NaN), explicitly, so the
// output's finiteness check below flags only real non-finite values.
nlohmann::json num_or_null(double x) { return std::isnan(x) ? nlohmann::json(nullptr) : nlohmann::json(x); }

nlohmann::json summary_json(const Summary& s) {
  return {{"frames", s.frames},
          {"collision_us", num_or_null(s.collision)},
          {"clustering_us", num_or_null(s.clustering)},
          {"force_us", num_or_null(s.force)},
          {"total_us", num_or_null(s.total)},
          {"collision_per_pair_us", num_or_null(s.per_pair)},
          {"force_per_patch_us", num_or_null(s.per_patch)},
          {"pairs", {{"min", s.pairs_min}, {"median", s.pairs_med}, {"max", s.pairs_max}, {"total", s.pairs_total}}},
          {"patches",
           {{"min", s.patches_min}, {"median", s.patches_med}, {"max", s.patches_max}, {"total", s.patches_total}}}};
}

// Medians of the GL split over the frames the backend evaluated.
struct GlSummary {
  size_t frames = 0;
  double upload, draw, resolve, reduce, readback, total, round_trips;
};

template <typename Pred>
GlSummary summarize_gl(const std::vector<FrameRecord>& r, Pred keep) {
  std::vector<double> u, d, rs, rd, rb, t, rt;
  for (const FrameRecord& x : r) {
    if (!x.has_gl || !keep(x)) continue;
    u.push_back(x.gl.upload);
    d.push_back(x.gl.draw);
    rs.push_back(x.gl.resolve);
    rd.push_back(x.gl.reduce);
    rb.push_back(x.gl.readback);
    t.push_back(x.gl.total);
    rt.push_back(x.gl.round_trips);
  }
  return {t.size(), median(u), median(d), median(rs), median(rd), median(rb), median(t), median(rt)};
}
GlSummary summarize_gl(const std::vector<FrameRecord>& r) {
  return summarize_gl(r, [](const FrameRecord&) { return true; });
}

nlohmann::json gl_summary_json(const GlSummary& g) {
  return {{"frames", g.frames},
          {"upload_us", num_or_null(g.upload)},
          {"draw_us", num_or_null(g.draw)},
          {"resolve_us", num_or_null(g.resolve)},
          {"reduce_us", num_or_null(g.reduce)},
          {"readback_us", num_or_null(g.readback)},
          {"total_us", num_or_null(g.total)},
          {"round_trips", num_or_null(g.round_trips)}};
}

// One row of the GL split table.
void print_gl_row(const std::string& scene, int n, const std::string& patches, const GlSummary& g) {
  std::printf("%-8s %5d %8s %7zu %9.1f %9.1f %9.1f %9.1f %10.1f %9.1f %6.0f\n", scene.c_str(), n, patches.c_str(),
              g.frames, g.upload, g.draw, g.resolve, g.reduce, g.readback, g.total, g.round_trips);
}

std::string pose_args(const hrt::Pose& p) {
  char buf[256];
  const Eigen::Quaterniond& q = p.rotation;
  std::snprintf(buf, sizeof buf, "%.9g %.9g %.9g %.9g %.9g %.9g %.9g", p.position.x(), p.position.y(), p.position.z(),
                q.x(), q.y(), q.z(), q.w());
  return buf;
}

// "32,50,64" (and "32 50,64" over several arguments) -> integers; every item
// a strict decimal integer.
std::vector<int> int_list(const std::vector<std::string>& args, const std::string& flag) {
  std::vector<int> out;
  for (const std::string& a : args) {
    size_t start = 0;
    for (;;) {
      const size_t comma = a.find(',', start);
      const std::string item = a.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
      const std::string err = integer_error(item);
      if (!err.empty()) throw Exit(kUsage, flag + ": " + err + " in '" + a + "'");
      out.push_back(std::stoi(item));
      if (comma == std::string::npos) break;
      start = comma + 1;
    }
  }
  return out;
}

// The flags' values, checked (after CLI11's own checks).
void check_bench_options(BenchOptions& o) {
  o.scene.check_backend_flags();
  if (!o.resolutions_arg.empty()) o.resolutions = int_list(o.resolutions_arg, "--resolutions");
  if (!o.copies_arg.empty()) o.copies = int_list(o.copies_arg, "--copies");
  if (o.a.empty() || o.b.empty())
    throw Exit(kUsage,
               "bench needs --a and --b bundles in contact (examples/bench_runtime.sh bakes a rasp and a CAD part "
               "and runs it)");
  if (o.pose_a.empty()) throw Exit(kUsage, "bench needs --pose-a x y z qx qy qz qw");
  for (int n : o.resolutions)
    if (n < 8 || n > hrt::kMaxResolution)
      throw Exit(kUsage, "--resolutions: each N must be between 8 and " + std::to_string(hrt::kMaxResolution));
  for (int k : o.copies)
    if (k < 1 || k > 256) throw Exit(kUsage, "--copies: each count must be between 1 and 256");
  if (o.frames < 1 || o.passes < 1) throw Exit(kUsage, "--frames and --passes must be at least 1");
  if (o.frames > kMaxFrames) throw Exit(kUsage, "--frames: at most " + std::to_string(kMaxFrames));
  if (o.passes > kMaxPasses) throw Exit(kUsage, "--passes: at most " + std::to_string(kMaxPasses));
  if (!o.settle.empty() && o.settle.size() != 3) throw Exit(kUsage, "--settle: expected 3 numbers");
  if (o.path.size() != 3) throw Exit(kUsage, "--path: expected 3 numbers");
  if (!(hrt::Vec3(o.path[0], o.path[1], o.path[2]).stableNorm() <= kMaxPosition))
    throw Exit(kUsage, "--path: its length must be at most " + fmt_g(kMaxPosition) + " m");
  if (!(o.settle_depth > 0 && o.settle_depth <= kMaxSettleDepth))
    throw Exit(kUsage,
               "--settle-depth: must be in (0, " + fmt_g(kMaxSettleDepth) + "] m, got " + fmt_g(o.settle_depth));
}

// The GL split of one (K, N), printed after the copies table.
struct CopiesGl {
  int k, n;
  double patches_med;
  GlSummary gl;
};

// The machine, the models, the poses and the path (JSON), printed as the
// header of the tables.
nlohmann::json bench_header(const BenchOptions& o, const hrt::Model& A, const hrt::Model& B,
                            const hrt::SceneOptions& so, const CliBackend& backend, const hrt::Pose& pose_a,
                            const hrt::Pose& pose_b, const hrt::Vec3& path) {
  nlohmann::json js;
  const std::string machine = machine_name();
  const unsigned cores = std::thread::hardware_concurrency();
  const int threads_used = backend.gl ? 1 : hrt::resolve_threads(so.threads);
  js["machine"] = {{"cpu", machine}, {"cores", cores}, {"threads_used", threads_used}, {"compiler", __VERSION__}};
  // Only with the GL backend: the CPU output stays as it was.
  if (backend.gl) {
    const hrt::gl::GlDepthOptions& g = backend.gl->options();
    js["machine"]["backend"] = "gl";
    js["machine"]["renderer"] = backend.renderer();
    js["machine"]["gl_platform"] = backend.selection.context->info().platform;
    js["machine"]["gl_search"] = g.search == hrt::gl::MaxSearch::occlusion ? "occlusion" : "compute";
    js["machine"]["occlusion_steps"] = g.occlusion_steps;
  }
  js["a"] = {{"bundle", A.path}, {"pieces", A.pieces.size()}, {"triangles", A.faces.size()}};
  js["b"] = {{"bundle", B.path}, {"pieces", B.pieces.size()}, {"triangles", B.faces.size()}};
  js["pose_a"] = pose_args(pose_a);
  js["pose_b"] = pose_args(pose_b);
  js["path"] = {path.x(), path.y(), path.z()};
  js["frames_per_pass"] = o.frames;
  js["passes"] = o.passes;

  if (!o.json) {
    std::printf("hrt bench: A = %s (%zu pieces, %zu triangles), B = %s (%zu pieces, %zu triangles)\n", A.path.c_str(),
                A.pieces.size(), A.faces.size(), B.path.c_str(), B.pieces.size(), B.faces.size());
    std::printf("machine    %s, %u logical cores, %d thread%s used; %s%s\n", machine.c_str(), cores, threads_used,
                threads_used == 1 ? "" : "s", "compiler " __VERSION__,
                backend.gl ? ("; depth backend " + backend.describe() + ", profiled").c_str() : "");
    std::printf("pose A     --pose-a %s   (B: --pose-b %s)\n", pose_args(pose_a).c_str(), pose_args(pose_b).c_str());
    std::printf(
        "path       A moves by (%.4g, %.4g, %.4g) m over %d frames, back and forth, %d passes (first = warm-up)\n\n",
        path.x(), path.y(), path.z(), o.frames, o.passes);
  }

  return js;
}

// 1. The scraping path, per N (records: each N's frames).
nlohmann::json bench_path(const BenchOptions& o, const hrt::Model& A, const hrt::Model& B, hrt::SceneOptions& so,
                          const CliBackend& backend, const hrt::Pose& pose_a, const hrt::Pose& pose_b,
                          const hrt::Vec3& path, std::map<int, std::vector<FrameRecord>>& records) {
  nlohmann::json jpath = nlohmann::json::array();
  if (!o.json) {
    std::printf("Scraping path: median per frame (us)\n");
    std::printf("%5s %7s %9s %11s %9s %9s %10s %11s %8s %8s\n", "N", "pairs", "patches", "collision", "cluster",
                "force", "total", "coll/pair", "force/pt", "rate kHz");
  }
  for (int n : o.resolutions) {
    so.force.resolution = n;
    const auto scene = make_scene({&A, &B}, so);
    hrt::Warnings w;
    records[n] = path_sweep(*scene, {pose_a, pose_b}, path, o.frames, o.passes, backend.gl, &w);
    const Summary s = summarize(records[n]);
    nlohmann::json j = summary_json(s);
    j["resolution"] = n;
    j["tolerance"] = scene->tolerance(1);
    j["warnings"] = {{"undersampled_patches", w.depth.undersampled_patches},
                     {"uncovered_configurations", w.depth.uncovered_configurations},
                     {"patches_dropped", w.patches_dropped},
                     {"fcl_failures", w.fcl_failures},
                     {"fallback_normals", w.fallback_normals},
                     {"refused_patches", w.refused_patches},
                     {"clamped_patches", w.clamped_patches}};
    if (backend.gl) j["gl"] = gl_summary_json(summarize_gl(records[n]));
    jpath.push_back(j);
    if (!o.json) {
      char pairs[32], patches[32];
      std::snprintf(pairs, sizeof pairs, "%.0f", s.pairs_med);
      std::snprintf(patches, sizeof patches, "%d-%d", s.patches_min, s.patches_max);
      std::printf("%5d %7s %9s %11.1f %9.1f %9.1f %10.1f %11.2f %8.1f %8.2f%s\n", n, pairs, patches, s.collision,
                  s.clustering, s.force, s.total, s.per_pair, s.per_patch, 1e3 / s.total,
                  w.refused_patches || w.clamped_patches
                      ? ("   (" + std::to_string(w.refused_patches) + " refused, " + std::to_string(w.clamped_patches) +
                         " clamped patch-frames)")
                            .c_str()
                      : "");
    }
  }
  return jpath;
}

// 2. The same frames binned by patch count.
nlohmann::json bench_by_patch_count(const BenchOptions& o, const CliBackend& backend,
                                    std::map<int, std::vector<FrameRecord>>& records) {
  std::map<int, std::map<int, std::vector<double>>> bins;  // patches -> N -> totals
  std::map<int, std::map<int, std::vector<double>>> bins_force;
  for (const auto& [n, rec] : records)
    for (const FrameRecord& r : rec) {
      bins[r.patches][n].push_back(r.total);
      bins_force[r.patches][n].push_back(r.force);
    }
  nlohmann::json jbins = nlohmann::json::array();
  if (!o.json) {
    std::printf("\nScraping path by patch count: median total (texture force) per frame, us\n%8s %7s", "patches",
                "frames");
    for (int n : o.resolutions) std::printf("  %18s", ("N = " + std::to_string(n)).c_str());
    std::printf("\n");
  }
  for (const auto& [k, per_n] : bins) {
    nlohmann::json jb = {{"patches", k}};
    const size_t nframes = per_n.begin()->second.size();
    jb["frames"] = nframes;
    if (!o.json) std::printf("%8d %7zu", k, nframes);
    for (int n : o.resolutions) {
      auto it = per_n.find(n);
      const double tot = it == per_n.end() ? NAN : median(it->second);
      const double frc = it == per_n.end() ? NAN : median(bins_force[k][n]);
      jb["total_us"][std::to_string(n)] = num_or_null(tot);
      jb["force_us"][std::to_string(n)] = num_or_null(frc);
      if (backend.gl && it != per_n.end()) {
        const int patches = k;
        jb["gl"][std::to_string(n)] =
            gl_summary_json(summarize_gl(records[n], [patches](const FrameRecord& r) { return r.patches == patches; }));
      }
      if (!o.json) std::printf("  %8.1f (%7.1f)", tot, frc);
    }
    if (!o.json) std::printf("\n");
    jbins.push_back(jb);
  }
  return jbins;
}

// 3. K copies of B spread along the path.
nlohmann::json bench_copies(const BenchOptions& o, const hrt::Model& A, const hrt::Model& B, hrt::SceneOptions& so,
                            const CliBackend& backend, const hrt::Pose& pose_a, const hrt::Pose& pose_b,
                            const hrt::Vec3& path, std::vector<CopiesGl>& copies_gl) {
  nlohmann::json jcopies = nlohmann::json::array();
  if (!o.json) {
    std::printf("\nK copies of B along the path: median total (texture force) per frame, us\n%4s %7s %8s", "K", "pairs",
                "patches");
    for (int n : o.resolutions) std::printf("  %18s", ("N = " + std::to_string(n)).c_str());
    std::printf("\n");
  }
  const int copy_frames = std::max(1, o.frames / 5);
  for (int k : o.copies) {
    std::vector<const hrt::Model*> objects{&A};
    std::vector<hrt::Pose> base{pose_a};
    for (int c = 0; c < k; ++c) {
      objects.push_back(&B);
      // Copy c sees A as if A were at the fraction c / k of the path.
      base.push_back(translated(pose_b, -(static_cast<double>(c) / k) * path));
    }
    nlohmann::json jk = {{"copies", k}};
    std::string line;
    Summary first{};
    bool have_first = false;
    for (int n : o.resolutions) {
      so.force.resolution = n;
      const auto scene = make_scene(objects, so);
      const std::vector<FrameRecord> rec =
          copies_sweep(*scene, base, path / std::max(1, k), copy_frames, o.passes, backend.gl);
      const Summary s = summarize(rec);
      if (!have_first) {
        first = s;
        have_first = true;
      }
      jk["results"][std::to_string(n)] = summary_json(s);
      if (backend.gl) {
        const GlSummary g = summarize_gl(rec);
        jk["results"][std::to_string(n)]["gl"] = gl_summary_json(g);
        copies_gl.push_back({k, n, s.patches_med, g});
      }
      char cell[64];
      std::snprintf(cell, sizeof cell, "  %8.1f (%7.1f)", s.total, s.force);
      line += cell;
    }
    jcopies.push_back(jk);
    if (!o.json) std::printf("%4d %7.0f %8.0f%s\n", k, first.pairs_med, first.patches_med, line.c_str());
  }
  return jcopies;
}

// 4. The GL backend's split (profiled), per N and patch count.
void print_gl_split(const BenchOptions& o, const CliBackend& backend, std::map<int, std::vector<FrameRecord>>& records,
                    const std::vector<CopiesGl>& copies_gl) {
  if (backend.gl && !o.json) {
    std::printf("\nGL depth backend split: median per frame with patches, us (profiled: a wait after each stage)\n");
    std::printf("%-8s %5s %8s %7s %9s %9s %9s %9s %10s %9s %6s\n", "scene", "N", "patches", "frames", "upload", "draw",
                "resolve", "reduce", "read-back", "total", "trips");
    for (int n : o.resolutions) {
      std::set<int> counts;
      for (const FrameRecord& r : records[n])
        if (r.has_gl) counts.insert(r.patches);
      for (const int p : counts) {
        print_gl_row("path", n, std::to_string(p),
                     summarize_gl(records[n], [p](const FrameRecord& r) { return r.patches == p; }));
      }
    }
    for (const CopiesGl& c : copies_gl) {
      char patches[32];
      std::snprintf(patches, sizeof patches, "%.0f", c.patches_med);
      print_gl_row("K = " + std::to_string(c.k), c.n, patches, c.gl);
    }
  }
}

void run_bench(BenchOptions o) {
  check_bench_options(o);
  hrt::Pose pose_a = parse_pose(o.pose_a, "--pose-a");
  const hrt::Pose pose_b = parse_pose(o.pose_b, "--pose-b");
  const hrt::Vec3 path(o.path[0], o.path[1], o.path[2]);

  const auto models = load_models({o.a, o.b}, o.scene.verify_hashes);
  const hrt::Model& A = *models[0];
  const hrt::Model& B = *models[1];
  hrt::SceneOptions so = o.scene.scene_options();

  // The depth backend, for every scene below (they all hold A and copies of
  // B, the models it was made for). auto's probe runs at the first N timed.
  // --settle stays on the CPU code: it places A, it is not timed.
  hrt::SceneOptions probe_options = so;
  probe_options.force.resolution = o.resolutions.front();
  const CliBackend backend = select_depth_backend(o.scene, {&A, &B}, probe_options, true, true);

  if (!o.settle.empty()) {
    const hrt::Vec3 dir(o.settle[0], o.settle[1], o.settle[2]);
    if (!(dir.norm() > 0)) throw Exit(kUsage, "--settle: the direction must not be zero");
    so.force.resolution = hrt::kDefaultResolution;
    const auto scene = make_scene({&A, &B}, so);
    pose_a = settle(*scene, pose_a, pose_b, dir, o.settle_depth);
  }

  nlohmann::json js = bench_header(o, A, B, so, backend, pose_a, pose_b, path);
  std::map<int, std::vector<FrameRecord>> records;
  js["path_results"] = bench_path(o, A, B, so, backend, pose_a, pose_b, path, records);
  js["by_patch_count"] = bench_by_patch_count(o, backend, records);
  std::vector<CopiesGl> copies_gl;
  js["copies"] = bench_copies(o, A, B, so, backend, pose_a, pose_b, path, copies_gl);
  print_gl_split(o, backend, records, copies_gl);
  if (o.json) {
    const std::string bad = first_non_finite(js);
    if (!bad.empty())
      throw Exit(kInternal, "internal error: non-finite value at '" + bad + "' of the result (please report)");
    std::printf("%s\n", js.dump(2, ' ', false, nlohmann::json::error_handler_t::replace).c_str());
  }
}

}  // namespace

void register_bench(CLI::App& app) {
  auto o = std::make_shared<BenchOptions>();
  o->scene.max_patches = 128;  // the K-copies scenes hold many patches
  CLI::App* cmd = app.add_subcommand("bench",
                                     "Time haptic frames (collision, clustering, texture force) of a probe "
                                     "scraping an object, per grid resolution and patch count");
  cmd->add_option("--a", o->a, "probe bundle A (e.g. a rasp)");
  cmd->add_option("--b", o->b, "object bundle B (e.g. a CAD part)");
  cmd->add_option("--pose-a", o->pose_a, "start pose of A: x y z qx qy qz qw")->expected(7)->check(RealNumber());
  cmd->add_option("--pose-b", o->pose_b, "pose of B: x y z qx qy qz qw")
      ->expected(7)
      ->check(RealNumber())
      ->capture_default_str();
  cmd->add_option("--settle", o->settle, "first move A from --pose-a along this direction until it penetrates B")
      ->expected(3)
      ->check(RealNumber());
  cmd->add_option("--settle-depth", o->settle_depth, "deepest patch penetration to settle at, m (at most 1)")
      ->check(RealNumber())
      ->capture_default_str();
  cmd->add_option("--path", o->path, "translation of A over one pass of the sweep, m (length at most 1e4)")
      ->expected(3)
      ->check(RealNumber())
      ->capture_default_str();
  cmd->add_option("--frames", o->frames, "poses (one frame each) per pass along the path (at most 1e6)")
      ->check(Integer())
      ->capture_default_str();
  cmd->add_option("--passes", o->passes, "back-and-forth passes; the first is a warm-up (at most 100)")
      ->check(Integer())
      ->capture_default_str();
  cmd->add_option("--resolutions", o->resolutions_arg, "grid resolutions N to time (comma-separated)")
      ->default_str("32,50,64,128");
  cmd->add_option("--copies", o->copies_arg, "numbers K of copies of B for the patch-count table (comma-separated)")
      ->default_str("1,2,4,7,8,12,16");
  o->scene.add_to(cmd, false);
  cmd->add_flag("--json", o->json, "print the results as JSON");
  cmd->callback([o]() { run_bench(*o); });
}

}  // namespace hrt_cli
