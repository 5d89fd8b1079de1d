// `hrt query A.hbundle B.hbundle [more B bundles] --pose-a x y z qx qy qz qw
//  --pose-b ... [--resolution N] [--stiffness K] [--shortcut]
//  [--backend cpu|gl|auto] [--json]`:
// one haptic frame (collision -> clustering -> texture force, Sec. 3.3) for
// the given poses; prints the contact patches, the net wrench on the probe A,
// the opposite wrench on every B, per-stage timings and warning counters.
// A readable table by default; --json prints the stable layout of
// docs/hrt-query-json.md.
#include <algorithm>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "commands.h"
#include "finite_json.h"
#include "hrt/scene.h"
#include "scene_cli.h"

namespace hrt_cli {
namespace {

struct QueryOptions {
  std::vector<std::string> bundles;  // A, then one or more Bs
  std::vector<double> pose_a;        // 7 numbers
  std::vector<double> pose_b;        // 7 numbers per B, in order
  SceneFlags scene;
  int repeat = 1;  // frames run at the same poses; timings are their median
  bool json = false;
};

using Json = nlohmann::ordered_json;  // members in the documented order

// "+ 0.0" turns -0.0 into 0.0 (no "-0.0" in the output).
Json j3(const hrt::Vec3& v) { return Json::array({v.x() + 0.0, v.y() + 0.0, v.z() + 0.0}); }

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

// The GL backend's figures of the last frame (absent with the CPU backend).
// Query does not set GlDepthOptions::profile, so that its timings are those
// of a frame as a session runs it: total_us and readback_us are then the
// real costs, the other stages only the time to issue their commands (the
// GPU's work lands in whichever stage waits for it first); `hrt bench
// --backend gl` profiles the split.
Json gl_json(const CliBackend& backend) {
  const hrt::gl::GlDepthStats& s = backend.gl->stats();
  const hrt::gl::GlDepthOptions& g = backend.gl->options();
  const hrt::gl::ContextInfo& info = backend.selection.context->info();
  return {{"renderer", info.renderer},
          {"platform", info.platform},
          {"hardware", info.hardware},
          {"search", g.search == hrt::gl::MaxSearch::occlusion ? "occlusion" : "compute"},
          {"occlusion_steps", g.occlusion_steps},
          {"profiled", g.profile},
          {"upload_us", s.upload_us},
          {"draw_us", s.draw_us},
          {"resolve_us", s.resolve_us},
          {"reduce_us", s.reduce_us},
          {"readback_us", s.readback_us},
          {"total_us", s.total_us},
          {"batches", s.batches},
          {"round_trips", s.round_trips},
          {"tiles", s.tiles},
          {"mesh_quads", s.mesh_quads},
          {"occlusion_queries", s.occlusion_queries},
          {"buffer_growths", s.buffer_growths}};
}

Json query_json(const hrt::Scene& scene, const hrt::State& st, const QueryOptions& o, const CliBackend& backend,
                const hrt::StageTimings& t, const hrt::Warnings& w) {
  using json = Json;
  json objects = json::array();
  for (int i = 0; i < scene.size(); ++i) {
    const hrt::Model& m = scene.model(i);
    const hrt::Pose& p = st.poses[static_cast<size_t>(i)];
    const Eigen::Quaterniond& q = p.rotation;
    objects.push_back({{"index", i},
                       {"role", i == 0 ? "probe" : "object"},
                       {"bundle", m.path},
                       {"source", m.name},
                       {"position", j3(p.position)},
                       {"quaternion", {q.x(), q.y(), q.z(), q.w()}},
                       {"center_of_mass", j3(p.iso() * m.mass.center_of_mass)},
                       {"tolerance", i == 0 ? json(nullptr) : json(scene.tolerance(i))}});
  }
  const hrt::SceneOptions& so = scene.options();
  json contacts = json::array();
  for (int k = 0; k < st.num_patches; ++k) {
    const hrt::ContactPatch& c = st.patches[static_cast<size_t>(k)];
    contacts.push_back(
        {{"id", st.patch_ids[static_cast<size_t>(k)]},
         {"object_b", c.object_b},
         {"piece_pairs", c.piece_pairs},
         {"p_a", j3(c.p_a)},
         {"p_b", j3(c.p_b)},
         {"n", j3(c.n)},
         {"u", j3(c.u)},
         {"v", j3(c.v)},
         {"window", {{"origin", j3(c.window.origin)}, {"cell", c.window.cell}, {"resolution", c.window.resolution}}},
         {"tris_a", c.tris_a},
         {"tris_b", c.tris_b},
         {"covered", c.covered},
         {"delta", c.delta},
         {"grad",
          {c.grad[0] + 0.0, c.grad[1] + 0.0, c.grad[2] + 0.0, c.grad[3] + 0.0, c.grad[4] + 0.0, c.grad[5] + 0.0}},
         {"force", j3(c.force)},
         {"torque", j3(c.torque)},
         {"delta_bound", c.delta_bound},
         {"delta_force", c.delta_force},
         {"clamped", c.clamped},
         {"refused", c.refused},
         {"facing", c.facing}});
  }
  json wrench_b = json::array();
  for (int b = 1; b < scene.size(); ++b)
    wrench_b.push_back({{"object", b},
                        {"force", j3(st.wrench_b[static_cast<size_t>(b)].head<3>())},
                        {"torque", j3(st.wrench_b[static_cast<size_t>(b)].tail<3>())}});
  Json doc = {
      {"version", 1},
      {"units",
       {{"length", "m"}, {"force", "N"}, {"torque", "N m"}, {"stiffness", "N/m"}, {"angle", "rad"}, {"time", "us"}}},
      {"objects", objects},
      {"options",
       {{"resolution", so.force.resolution},
        {"stiffness", so.force.stiffness},
        {"lin_step", so.force.lin_step},
        {"ang_step", so.force.ang_step},
        {"shortcut", so.force.shortcut},
        {"heights", hrt::to_string(so.force.heights)},
        {"margin", so.collision.margin},
        {"max_patches", so.cluster.max_patches},
        {"auto_resolution", so.cluster.auto_resolution},
        {"max_resolution", so.cluster.max_resolution},
        {"backend", backend.name()},
        {"threads", backend.gl ? 1 : hrt::resolve_threads(so.threads)}}},
      {"pairs", st.num_pairs},
      {"contacts", contacts},
      {"force", j3(st.force)},
      {"torque", j3(st.torque)},
      {"wrench_b", wrench_b},
      {"timings_us",
       {{"collision", t.collision_us},
        {"clustering", t.clustering_us},
        {"force", t.force_us},
        {"total", t.total_us},
        {"frames", o.repeat}}},
      {"warnings",
       {{"fallback_normals", w.fallback_normals},
        {"fcl_failures", w.fcl_failures},
        {"pairs_grown", w.pairs_grown},
        {"patches_dropped", w.patches_dropped},
        {"empty_windows", w.empty_windows},
        {"undersampled_patches", w.depth.undersampled_patches},
        {"uncovered_configurations", w.depth.uncovered_configurations},
        {"refused_patches", w.refused_patches},
        {"clamped_patches", w.clamped_patches}}}};
  if (backend.gl) {
    doc["gl"] = gl_json(backend);
    // Per contact, the occlusion search's depth quantum (delta is within it
    // of the exact maximum; 0 for the compute reduction): patch k of the
    // frame is the backend's job k.
    Json q = Json::array();
    for (int k = 0; k < st.num_patches; ++k) q.push_back(backend.gl->quantum(k));
    doc["gl"]["depth_quantum"] = q;
  }
  return doc;
}

void print_table(const hrt::Scene& scene, const hrt::State& st, const QueryOptions& o, const CliBackend& backend,
                 const hrt::StageTimings& t, const hrt::Warnings& w) {
  const hrt::SceneOptions& so = scene.options();
  std::printf("probe A     %s (%s)\n", scene.model(0).path.c_str(), scene.model(0).name.c_str());
  for (int b = 1; b < scene.size(); ++b)
    std::printf("object %-4d %s (%s), tolerance %.4g mm\n", b, scene.model(b).path.c_str(), scene.model(b).name.c_str(),
                scene.tolerance(b) * 1e3);
  std::printf(
      "model       k = %g N/m, N = %d%s, steps %s, %s\n", so.force.stiffness, so.force.resolution,
      so.cluster.auto_resolution ? (" (auto, up to " + std::to_string(so.cluster.max_resolution) + ")").c_str() : "",
      so.force.lin_step > 0 || so.force.ang_step > 0 ? "explicit" : "one texel",
      so.force.shortcut ? "shortcut (Sec. 5.2)" : "full re-rasterization");
  std::printf("backend     %s\n", backend.describe().c_str());
  std::printf("contacts    %d piece pairs -> %d patches\n\n", st.num_pairs, st.num_patches);
  if (st.num_patches > 0) {
    std::printf("%3s %3s %5s %9s %12s %25s %25s %25s\n", "#", "B", "pairs", "tris A/B", "delta mm", "n (A into B)",
                "force on A (N)", "torque on A (N m)");
    for (int k = 0; k < st.num_patches; ++k) {
      const hrt::ContactPatch& c = st.patches[static_cast<size_t>(k)];
      char tris[32], delta[32];
      std::snprintf(tris, sizeof tris, "%zu/%zu", c.tris_a.size(), c.tris_b.size());
      if (c.covered)
        std::snprintf(delta, sizeof delta, "%.5f%s", c.delta * 1e3, c.refused ? " R" : c.clamped ? " C" : "");
      else
        std::snprintf(delta, sizeof delta, "uncovered%s", c.refused ? " R" : "");
      // "+ 0.0" prints -0 as 0.
      std::printf("%3d %3d %5d %9s %12s  (%6.3f,%6.3f,%6.3f)  (%7.3g,%7.3g,%7.3g)  (%7.3g,%7.3g,%7.3g)\n", k,
                  c.object_b, c.piece_pairs, tris, delta, c.n.x() + 0.0, c.n.y() + 0.0, c.n.z() + 0.0,
                  c.force.x() + 0.0, c.force.y() + 0.0, c.force.z() + 0.0, c.torque.x() + 0.0, c.torque.y() + 0.0,
                  c.torque.z() + 0.0);
    }
    std::printf("(R: refused, no force; C: clamped, the force of delta_bound; see docs/hrt-query-json.md)\n\n");
  }
  std::printf("net force on A    (%.6g, %.6g, %.6g) N, |F| = %.6g N\n", st.force.x(), st.force.y(), st.force.z(),
              st.force.norm());
  std::printf("net torque on A   (%.6g, %.6g, %.6g) N m about its centre of mass\n", st.torque.x(), st.torque.y(),
              st.torque.z());
  for (int b = 1; b < scene.size(); ++b) {
    const hrt::Vec6& wb = st.wrench_b[static_cast<size_t>(b)];
    std::printf("wrench on %-7d F (%.6g, %.6g, %.6g) N, T (%.6g, %.6g, %.6g) N m about its centre of mass\n", b, wb[0],
                wb[1], wb[2], wb[3], wb[4], wb[5]);
  }
  std::printf("timings (us)      collision %.1f, clustering %.1f, texture force %.1f, total %.1f%s\n", t.collision_us,
              t.clustering_us, t.force_us, t.total_us,
              o.repeat > 1 ? (" (median of " + std::to_string(o.repeat) + " frames)").c_str() : " (one frame)");
  if (backend.gl && st.num_patches > 0) {
    // Unprofiled (see gl_json): the total and the read-back only.
    const hrt::gl::GlDepthStats& g = backend.gl->stats();
    std::printf(
        "gl (us)           total %.1f, read-back %.1f; %d batch(es), %d round trip(s), %d tile(s), %d occlusion "
        "quer%s, %lld mesh quad(s) (last frame)\n",
        g.total_us, g.readback_us, g.batches, g.round_trips, g.tiles, g.occlusion_queries,
        g.occlusion_queries == 1 ? "y" : "ies", static_cast<long long>(g.mesh_quads));
  }
  const uint64_t any = w.fallback_normals + w.fcl_failures + w.pairs_grown + w.patches_dropped + w.empty_windows +
                       w.depth.undersampled_patches + w.depth.uncovered_configurations + w.refused_patches +
                       w.clamped_patches;
  if (any) {
    std::printf("warnings         ");
    if (w.refused_patches)
      std::printf(" %llu patch(es) refused (n disagrees with the pieces: no force);",
                  static_cast<unsigned long long>(w.refused_patches));
    if (w.clamped_patches)
      std::printf(" %llu patch(es) clamped to the pieces' depth bound;",
                  static_cast<unsigned long long>(w.clamped_patches));
    if (w.depth.undersampled_patches)
      std::printf(" %llu patch(es) with a grid texel coarser than half the shortest relief wavelength (Sec. 7.2);",
                  static_cast<unsigned long long>(w.depth.undersampled_patches));
    if (w.depth.uncovered_configurations)
      std::printf(" %llu finite-difference configuration(s) without a texel covered by both;",
                  static_cast<unsigned long long>(w.depth.uncovered_configurations));
    if (w.patches_dropped)
      std::printf(" %llu patch(es) dropped beyond --max-patches;", static_cast<unsigned long long>(w.patches_dropped));
    if (w.empty_windows)
      std::printf(" %llu patch(es) whose triangles do not overlap along n;",
                  static_cast<unsigned long long>(w.empty_windows));
    if (w.fallback_normals)
      std::printf(" %llu touching piece pair(s) (normal from face planes);",
                  static_cast<unsigned long long>(w.fallback_normals));
    if (w.fcl_failures)
      std::printf(" %llu piece pair(s) FCL failed on (skipped);", static_cast<unsigned long long>(w.fcl_failures));
    if (w.pairs_grown) std::printf(" pair buffer grown %llu time(s);", static_cast<unsigned long long>(w.pairs_grown));
    std::printf("\n");
  }
}

}  // namespace

void register_query(CLI::App& app) {
  auto o = std::make_shared<QueryOptions>();
  CLI::App* cmd = app.add_subcommand(
      "query", "One haptic frame between a probe A and other objects: contacts, penetration depth, force and torque");
  cmd->add_option("bundles", o->bundles, "A.hbundle (the probe) followed by one or more B bundles")
      ->required()
      ->expected(2, 1 << 16);
  cmd->add_option("--pose-a", o->pose_a, "pose of A: x y z qx qy qz qw (m, |x y z| <= 1e4, unit quaternion)")
      ->required()
      ->expected(7)
      ->check(RealNumber());
  cmd->add_option("--pose-b", o->pose_b, "pose of each B in order: x y z qx qy qz qw (repeat the flag per B)")
      ->required()
      ->expected(7)
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll)
      ->check(RealNumber());
  o->scene.add_to(cmd);
  cmd->add_option("--repeat", o->repeat, "run this many frames at the poses; timings are their median")
      ->capture_default_str()
      ->check(Integer())
      ->check(CLI::Range(1, 1000000));
  cmd->add_flag("--json", o->json, "print the result as JSON (layout: docs/hrt-query-json.md)");
  cmd->callback([o]() {
    o->scene.check_backend_flags();
    const size_t nb = o->bundles.size() - 1;
    if (o->pose_b.size() != 7 * nb)
      throw Exit(kUsage, "--pose-b: " + std::to_string(nb) + " B bundle(s) need " + std::to_string(nb) +
                             " --pose-b flag(s) of 7 numbers, got " + std::to_string(o->pose_b.size()) + " numbers");
    const hrt::Pose pose_a = parse_pose(o->pose_a, "--pose-a");
    std::vector<hrt::Pose> poses_b;
    for (size_t b = 0; b < nb; ++b)
      poses_b.push_back(parse_pose(std::vector<double>(o->pose_b.begin() + static_cast<long>(7 * b),
                                                       o->pose_b.begin() + static_cast<long>(7 * b + 7)),
                                   "--pose-b #" + std::to_string(b + 1)));
    const auto models = load_models(o->bundles, o->scene.verify_hashes);
    std::vector<const hrt::Model*> objects;
    for (const auto& m : models) objects.push_back(m.get());
    const auto scene = make_scene(objects, o->scene.scene_options());
    // Declared before the State, which points at it (and must go first).
    const CliBackend backend = select_depth_backend(o->scene, objects, scene->options(), false, true);
    hrt::State st(*scene);
    st.depth_backend = backend.for_state();
    st.poses[0] = pose_a;
    for (size_t b = 0; b < nb; ++b) st.poses[b + 1] = poses_b[b];

    frame_or_usage(*scene, st);
    const hrt::Warnings warnings = st.warnings;  // of the reported (first) frame
    std::vector<double> tc{st.timings.collision_us}, tk{st.timings.clustering_us}, tf{st.timings.force_us},
        tt{st.timings.total_us};
    // Repeats at the same poses track the same patches and give the same
    // results; only their timings are kept. The printed results are the
    // last frame's, identical to the first's.
    for (int r = 1; r < o->repeat; ++r) {
      frame_or_usage(*scene, st);
      tc.push_back(st.timings.collision_us);
      tk.push_back(st.timings.clustering_us);
      tf.push_back(st.timings.force_us);
      tt.push_back(st.timings.total_us);
    }
    hrt::StageTimings t;
    t.collision_us = median(tc);
    t.clustering_us = median(tk);
    t.force_us = median(tf);
    t.total_us = median(tt);
    // Both outputs print the same values: a NaN or infinity among them is a
    // bug upstream (nlohmann-json would print it as null), never a result.
    const Json doc = query_json(*scene, st, *o, backend, t, warnings);
    const std::string bad = first_non_finite(doc);
    if (!bad.empty())
      throw Exit(kInternal, "internal error: non-finite value at '" + bad + "' of the result (please report)");
    if (o->json) {
      std::printf("%s\n", doc.dump(2, ' ', false, Json::error_handler_t::replace).c_str());
    } else {
      print_table(*scene, st, *o, backend, t, warnings);
    }
  });
}

}  // namespace hrt_cli
