// The GL backend of the depth query (hrt/gl_depth.h) against the CPU
// backend, the reference. Run on whatever context this machine
// gives (in CI Mesa's llvmpipe).
//
// Bounds, fixed here before measuring:
//   compute reduction  the backends run the same arithmetic (src/gl/shaders
//     repeat src/depth/raster.cpp), so a height differs only by float32
//     rounding of the atlas lookup (a bilinear blend and a 3-term dot of
//     float32 positions: at most 4 float ulps of the largest atlas
//     coordinate |p|max, 4 x 2^-24 |p|max) and of double sums (nothing at
//     this scale). delta = max (h_A - h_B) then differs by at most the sum
//     for A and B: kHeightUlps x 2^-24 x (|p|max_A + |p|max_B), kHeightUlps = 8.
//   occlusion search   the search brackets delta in an interval of width
//     one depth quantum q = 2 R / 2^steps (GlDepthBackend::quantum) and
//     reports its midpoint: |delta_gl - delta_cpu| <= q / 2 + the bound
//     above; we allow q.
//   gradient           d delta / d x by central differences over 2 step:
//     its error is at most 2 x (delta bound) / (2 step) = bound / step, and
//     the force -k delta grad delta then differs by at most
//     k (|delta| bound_grad + |grad| bound_delta).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "depth/internal.h"
#include "hrt/depth_backend.h"
#include "hrt/gl_depth.h"
#include "env_guard.h"
#include "hrt/scene.h"
#include "synthetic.h"

namespace fs = std::filesystem;

namespace {

constexpr double kHeightUlps = 8.0;

std::string golden(const char* name) { return std::string(HRT_SOURCE_DIR) + "/../tests/golden/" + name; }

double max_atlas_radius(const hrt::Model& m) {
  double r = 0;
  for (size_t k = 0; k + 3 < m.atlas.rgba.size(); k += 4)
    if (m.atlas.rgba[k + 3] > 0)
      r = std::max(
          r, std::sqrt(double(m.atlas.rgba[k]) * m.atlas.rgba[k] + double(m.atlas.rgba[k + 1]) * m.atlas.rgba[k + 1] +
                       double(m.atlas.rgba[k + 2]) * m.atlas.rgba[k + 2]));
  return r;
}

hrt::Pose random_pose(std::mt19937_64& rng, const hrt::Vec3& centre, double dist) {
  std::normal_distribution<double> g(0.0, 1.0);
  hrt::Vec3 d(g(rng), g(rng), g(rng));
  d.normalize();
  hrt::Pose p;
  p.position = centre + dist * d;
  p.rotation = Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized();
  return p;
}

struct Frame {
  std::vector<hrt::DepthJob> jobs;
  std::vector<hrt::ContactPatch> patches;
};

// Contact patches of A against B at random poses around B, from the real
// collision and clustering stages; `want` frames with at least one patch.
std::vector<Frame> contact_frames(const hrt::Model& A, const hrt::Model& B, const hrt::SceneOptions& so, int want,
                                  uint64_t seed) {
  hrt::Scene scene({&A, &B}, so);
  hrt::State st(scene);
  std::mt19937_64 rng(seed);
  hrt::Vec3 lo = hrt::Vec3::Constant(1e300), hi = -lo, alo = lo, ahi = hi;
  for (const hrt::Vec3& p : B.vertices) lo = lo.cwiseMin(p), hi = hi.cwiseMax(p);
  for (const hrt::Vec3& p : A.vertices) alo = alo.cwiseMin(p), ahi = ahi.cwiseMax(p);
  const hrt::Vec3 c = 0.5 * (lo + hi);
  const double rb = 0.5 * (hi - lo).norm(), ra = 0.5 * (ahi - alo).norm();
  std::vector<Frame> out;
  std::uniform_real_distribution<double> f(0.55, 0.8);
  for (int tries = 0; tries < 4000 && static_cast<int>(out.size()) < want; ++tries) {
    st.poses[0] = random_pose(rng, c - 0.5 * (alo + ahi), f(rng) * (ra + rb));
    st.poses[1] = hrt::Pose{};
    hrt::frame(scene, st);
    if (st.num_patches == 0) continue;
    Frame fr;
    fr.patches.assign(st.patches.begin(), st.patches.begin() + st.num_patches);
    for (const hrt::ContactPatch& p : fr.patches)
      fr.jobs.push_back(hrt::DepthJob{&A, &B, st.poses[0], st.poses[1], nullptr});
    for (size_t k = 0; k < fr.jobs.size(); ++k) fr.jobs[k].patch = &fr.patches[k];
    out.push_back(std::move(fr));
  }
  return out;
}

struct Compare {
  int configs = 0, covered_both = 0, coverage_mismatch = 0, patches = 0;
  double worst = 0, worst_ratio = 0;
};

// Every configuration's delta of every patch within `bound(job)`.
template <class Bound>
Compare compare_frames(const std::vector<Frame>& frames, hrt::DepthBackend& gl, const hrt::ForceOptions& opt,
                       Bound bound) {
  hrt::CpuDepthBackend cpu;
  Compare r;
  for (const Frame& fr : frames) {
    const int n = static_cast<int>(fr.jobs.size());
    std::vector<hrt::DepthGradient> gc(n), gg(n);
    cpu.evaluate(fr.jobs.data(), n, opt, gc.data());
    gl.evaluate(fr.jobs.data(), n, opt, gg.data());
    for (int k = 0; k < n; ++k) {
      ++r.patches;
      const double b = bound(k, *fr.jobs[k].a, *fr.jobs[k].b);
      for (int c = 0; c < 11; ++c) {
        ++r.configs;
        const double dc = gc[k].delta_at[c], dg = gg[k].delta_at[c];
        const bool cc = std::isfinite(dc), cg = std::isfinite(dg);
        if (cc != cg) {
          ++r.coverage_mismatch;
          ADD_FAILURE() << "patch " << k << " config " << c << ": covered cpu " << cc << " gl " << cg << " (cpu " << dc
                        << ", gl " << dg << ")";
          continue;
        }
        if (!cc) continue;
        ++r.covered_both;
        const double e = std::abs(dg - dc);
        r.worst = std::max(r.worst, e);
        r.worst_ratio = std::max(r.worst_ratio, e / b);
        EXPECT_LE(e, b) << "patch " << k << " config " << c << ": cpu " << dc << " gl " << dg << " N "
                        << fr.jobs[k].patch->window.resolution;
      }
      EXPECT_EQ(gc[k].covered, gg[k].covered);
      EXPECT_EQ(gc[k].region_texels, gg[k].region_texels) << "patch " << k;
    }
  }
  return r;
}

// The golden pair most tests use, and the compute bound for it.
struct Golden {
  hrt::Model a, b;
  double bound;
  Golden(const char* na, const char* nb)
      : a(hrt::load_bundle(golden(na))),
        b(hrt::load_bundle(golden(nb))),
        bound(kHeightUlps * std::ldexp(1.0, -24) * (max_atlas_radius(a) + max_atlas_radius(b))) {}
};

struct GlFixture : ::testing::Test {
  static std::unique_ptr<hrt::gl::Context> ctx;
  static void SetUpTestSuite() { ctx = hrt::gl::Context::create(); }
  static void TearDownTestSuite() { ctx.reset(); }
};
std::unique_ptr<hrt::gl::Context> GlFixture::ctx;

}  // namespace

TEST_F(GlFixture, ComputeReductionEqualsCpuOnGoldenBundlesAtRandomPoses) {
  const Golden g("pebble.hbundle", "bumpy_blob.hbundle");
  const hrt::Model &A = g.a, &B = g.b;
  hrt::SceneOptions so;
  const auto frames = contact_frames(A, B, so, 24, 7);
  ASSERT_GE(frames.size(), 12u);
  hrt::gl::GlDepthBackend gl(*ctx, {&A, &B});
  const double bound = g.bound;
  const Compare r =
      compare_frames(frames, gl, so.force, [&](int, const hrt::Model&, const hrt::Model&) { return bound; });
  std::printf(
      "compute: %d patches, %d configurations covered by both, worst |gl - cpu| %.3g m (%.3g of the bound %.3g)\n",
      r.patches, r.covered_both, r.worst, r.worst_ratio, bound);
  EXPECT_GT(r.covered_both, 100);
}

namespace {

// Triangles of the frames' patches on the surface mode's fixed-point path
// (lateral bound above the tolerance), so that a test shows it ran there.
int surface_path_triangles(const std::vector<Frame>& frames, const hrt::ForceOptions& opt) {
  int n = 0;
  for (const Frame& fr : frames)
    for (const hrt::DepthJob& j : fr.jobs) {
      const hrt::ContactPatch& p = *j.patch;
      for (int side = 0; side < 2; ++side) {
        const hrt::Model& M = side ? *j.b : *j.a;
        const hrt::Pose& pose = side ? j.pose_b : j.pose_a;
        if (!M.surface.ready) continue;
        const hrt::PlacementParams pp = hrt::placement_params(M, pose.iso(), p.n, p.u, p.v, p.window, 0, opt.heights);
        for (uint32_t f : side ? p.tris_b : p.tris_a)
          if (pp.surface && M.surface.lateral_bound(f, pp.nobj) / p.window.cell > pp.tol) ++n;
      }
    }
  return n;
}

}  // namespace

TEST_F(GlFixture, OcclusionSearchWithinOneDepthQuantum) {
  const Golden g("pebble.hbundle", "bumpy_blob.hbundle");
  const hrt::Model &A = g.a, &B = g.b;
  hrt::SceneOptions so;
  const auto frames = contact_frames(A, B, so, 16, 11);
  ASSERT_GE(frames.size(), 8u);
  for (int steps : {16, 23}) {
    hrt::gl::GlDepthOptions go;
    go.search = hrt::gl::MaxSearch::occlusion;
    go.occlusion_steps = steps;
    hrt::gl::GlDepthBackend gl(*ctx, {&A, &B}, go);
    const double hb = g.bound;
    double worst_q = 0;
    const Compare r = compare_frames(frames, gl, so.force, [&](int k, const hrt::Model&, const hrt::Model&) {
      const double q = gl.quantum(k);
      EXPECT_GT(q, 0.0);
      worst_q = std::max(worst_q, q);
      return q + hb;
    });
    std::printf(
        "occlusion, %d steps: %d configurations, worst |gl - cpu| %.3g m (%.3g of the bound), largest quantum %.3g m, "
        "%d queries in the last frame, %d round trip(s)\n",
        steps, r.covered_both, r.worst, r.worst_ratio, worst_q, gl.stats().occlusion_queries, gl.stats().round_trips);
    EXPECT_EQ(gl.stats().round_trips, 1);
    EXPECT_GT(r.covered_both, 50);
  }
}

namespace {

// GL against CPU for golden pair (na, nb) in height mode `mode`, on `want`
// contact frames from seed `seed`, with the fixed compute bound.
struct ModeRun {
  Compare r;
  hrt::gl::GlDepthStats stats;  // of the last frame
  double bound = 0;
};
ModeRun compare_mode(hrt::gl::Context& ctx, const char* na, const char* nb, hrt::HeightMode mode, int want,
                     uint64_t seed, size_t at_least) {
  const Golden g(na, nb);
  hrt::SceneOptions so;
  so.force.heights = mode;
  const auto frames = contact_frames(g.a, g.b, so, want, seed);
  EXPECT_GE(frames.size(), at_least);
  hrt::gl::GlDepthBackend gl(ctx, {&g.a, &g.b});
  ModeRun m;
  m.bound = g.bound;
  m.r = compare_frames(frames, gl, so.force, [&](int, const hrt::Model&, const hrt::Model&) { return m.bound; });
  m.stats = gl.stats();
  return m;
}

}  // namespace

TEST_F(GlFixture, CoarseHeightsEqualCpu) {
  // --heights coarse: every configuration of A rasterized (no seeds), the
  // literal Eq. 8.
  const ModeRun m = compare_mode(*ctx, "pebble.hbundle", "ridged_box.hbundle", hrt::HeightMode::coarse, 12, 3, 6);
  std::printf("coarse: %d configurations, worst %.3g m (bound %.3g), %d tiles in the last frame\n", m.r.covered_both,
              m.r.worst, m.bound, m.stats.tiles);
  EXPECT_GT(m.r.covered_both, 50);
}

TEST_F(GlFixture, SurfacePathIsExercisedAndEqualsCpu) {
  const Golden g("bumpy_blob.hbundle", "ridged_box.hbundle");
  const hrt::Model &A = g.a, &B = g.b;
  hrt::SceneOptions so;
  const auto frames = contact_frames(A, B, so, 16, 5);
  ASSERT_GE(frames.size(), 8u);
  const int fixed_point = surface_path_triangles(frames, so.force);
  hrt::gl::GlDepthBackend gl(*ctx, {&A, &B});
  const double bound = g.bound;
  const Compare r =
      compare_frames(frames, gl, so.force, [&](int, const hrt::Model&, const hrt::Model&) { return bound; });
  std::printf("surface path: %d triangles on the fixed point, %d configurations, worst %.3g m (bound %.3g)\n",
              fixed_point, r.covered_both, r.worst, bound);
  EXPECT_GT(fixed_point, 0);
}

TEST_F(GlFixture, MeshHeightsEqualCpu) {
  // heights = mesh: every atlas quad of the faces in reach, one point each
  // (mesh.vert / mesh.geom / mesh.frag), against raster_triangle_mesh; the
  // whole-texel translations are shifts of A0 on both. Same bound: the quad
  // corners are the same float32 atlas texels, projected in double.
  for (const auto& names :
       {std::pair{"pebble.hbundle", "bumpy_blob.hbundle"}, std::pair{"bumpy_blob.hbundle", "ridged_box.hbundle"}}) {
    const ModeRun m = compare_mode(*ctx, names.first, names.second, hrt::HeightMode::mesh, 8, 13, 4);
    std::printf(
        "mesh heights, %s on %s: %d patches, %d configurations, worst %.3g m (bound %.3g), %lld quads in "
        "the last frame\n",
        names.first, names.second, m.r.patches, m.r.covered_both, m.r.worst, m.bound,
        static_cast<long long>(m.stats.mesh_quads));
    EXPECT_GT(m.r.covered_both, 30);
    // Drawn by the mesh program, not the face raster.
    EXPECT_GT(m.stats.mesh_quads, 1000);
  }
}

TEST_F(GlFixture, ManyPatchesInOneFrameEqualOneAtATime) {
  // Patches of several frames and of different window sizes in one call
  // (tiled together, and over several batches with a small render target)
  // give what each gives alone.
  const Golden g("pebble.hbundle", "bumpy_blob.hbundle");
  const hrt::Model &A = g.a, &B = g.b;
  hrt::SceneOptions so;
  auto frames = contact_frames(A, B, so, 10, 21);
  ASSERT_GE(frames.size(), 6u);
  std::vector<hrt::ContactPatch> patches;
  std::vector<hrt::DepthJob> jobs;
  int sizes[] = {50, 17, 64, 33, 128, 8};
  for (size_t f = 0; f < frames.size(); ++f)
    for (size_t k = 0; k < frames[f].jobs.size(); ++k) {
      hrt::ContactPatch p = frames[f].patches[k];
      // A different lattice over the same region: N changes, the window's side stays.
      const int N = sizes[patches.size() % 6];
      const double side = p.window.cell * p.window.resolution;
      p.window.cell = side / N;
      p.window.resolution = N;
      patches.push_back(p);
      jobs.push_back(frames[f].jobs[k]);
    }
  for (size_t k = 0; k < jobs.size(); ++k) jobs[k].patch = &patches[k];
  const int n = static_cast<int>(jobs.size());
  for (int target : {1024, 256}) {
    hrt::gl::GlDepthOptions go;
    go.target_size = target;
    hrt::gl::GlDepthBackend gl(*ctx, {&A, &B}, go);
    std::vector<hrt::DepthGradient> all(n), one(1);
    gl.evaluate(jobs.data(), n, so.force, all.data());
    const int batches = gl.stats().batches;
    int compared = 0;
    for (int k = 0; k < n; ++k) {
      gl.evaluate(&jobs[k], 1, so.force, one.data());
      for (int c = 0; c < 11; ++c) {
        EXPECT_EQ(std::isfinite(all[k].delta_at[c]), std::isfinite(one[0].delta_at[c]));
        if (std::isfinite(all[k].delta_at[c])) {
          EXPECT_EQ(all[k].delta_at[c], one[0].delta_at[c]) << "patch " << k << " N " << patches[k].window.resolution;
          ++compared;
        }
      }
      EXPECT_EQ(all[k].region_texels, one[0].region_texels);
    }
    std::printf("tiling, %d x %d target: %d patches in %d batch(es), %d configurations equal to one-at-a-time\n",
                target, target, n, batches, compared);
    if (target == 256) EXPECT_GT(batches, 1);
    EXPECT_GT(compared, 5 * n);
  }
}

TEST(GlSelect, GlWithoutAContextFailsNamingItAndAutoFallsBack) {
  const Golden g("pebble.hbundle", "bumpy_blob.hbundle");
  const hrt::Model &A = g.a, &B = g.b;
  hrt::SceneOptions so;
  EnvGuard env("HRT_EGL_PLATFORM", "no-such-platform");
  try {
    hrt::gl::select_backend(hrt::BackendChoice::gl, {&A, &B}, so);
    ADD_FAILURE() << "gl without a context did not fail";
  } catch (const hrt::gl::GlError& e) {
    EXPECT_NE(std::string(e.what()).find("HRT_EGL_PLATFORM"), std::string::npos) << e.what();
  }
  hrt::gl::BackendSelection s = hrt::gl::select_backend(hrt::BackendChoice::automatic, {&A, &B}, so);
  ASSERT_TRUE(s.backend);
  EXPECT_STREQ(s.backend->name(), "cpu");
  EXPECT_NE(s.message.find("no GL context"), std::string::npos) << s.message;
}

TEST(GlSelect, AutoNeverChoosesASoftwareRendererAndItsProbeSaysWhy) {
  const Golden g("pebble.hbundle", "bumpy_blob.hbundle");
  const hrt::Model &A = g.a, &B = g.b;
  hrt::SceneOptions so;
  hrt::gl::BackendSelection s = hrt::gl::select_backend(hrt::BackendChoice::automatic, {&A, &B}, so);
  ASSERT_TRUE(s.backend);
  std::printf("%s\n", s.message.c_str());
  auto ctx = hrt::gl::Context::create();
  if (!ctx->info().hardware) {
    EXPECT_STREQ(s.backend->name(), "cpu");
    EXPECT_NE(s.message.find("software renderer"), std::string::npos) << s.message;
    // The probe itself, forced on the software renderer: it times both and
    // keeps the faster (on llvmpipe, the CPU).
    EnvGuard env("HRT_GL_PROBE", "always");
    ctx.reset();
    hrt::gl::BackendSelection p = hrt::gl::select_backend(hrt::BackendChoice::automatic, {&A, &B}, so);
    std::printf("%s\n", p.message.c_str());
    EXPECT_NE(p.message.find("probe"), std::string::npos) << p.message;
  }
}

TEST_F(GlFixture, ShortcutIsRefusedWithAClearMessage) {
  const Golden g("pebble.hbundle", "bumpy_blob.hbundle");
  const hrt::Model &A = g.a, &B = g.b;
  hrt::SceneOptions so;
  const auto frames = contact_frames(A, B, so, 1, 7);
  ASSERT_EQ(frames.size(), 1u);
  hrt::gl::GlDepthBackend gl(*ctx, {&A, &B});
  hrt::ForceOptions opt = so.force;
  opt.shortcut = true;
  std::vector<hrt::DepthGradient> out(frames[0].jobs.size());
  EXPECT_THROW(gl.evaluate(frames[0].jobs.data(), 1, opt, out.data()), std::invalid_argument);
}
