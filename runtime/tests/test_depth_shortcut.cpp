// The paper's Sec. 5.2 shortcut (h_A at +-du, +-dv, +-dtheta_n resampled
// from h_A(0) instead of rasterized again) against full re-rasterization of
// A at every configuration, plus the bookkeeping of compute_depth_gradient:
// config_motion, steps, one-sided differences, warnings, and the equality of
// the inlined atlas sampling with Atlas::sample.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "depth/internal.h"
#include "hrt/depth.h"
#include "hrt/force.h"
#include "synthetic.h"

namespace hrt {
namespace {

constexpr double kPi = 3.14159265358979323846;

struct Scene {
  synth::SynthBlock A, B;
  Pose pa, pb;
  ContactPatch patch;
  double hess = 0;  // bound on |second derivative| of h_A in the plane (1/m)
};

// Gratings at 23 degrees offset by 0.2 lambda (A large, covering the window),
// or a small A (3 mm) whose footprint ends inside the window, so that the
// border of the shortcut's h_A(0) matters. Randomly rotated scene.
Scene make_scene(bool small_a, int seed) {
  const double a = 1e-4, lam = 2e-3, phi = 23 * kPi / 180, kk = 2 * kPi / lam;
  const synth::BlockSpec sb = synth::sine_grating_spec(a, lam, phi);
  Scene S;
  S.B = synth::make_block(sb);
  synth::BlockSpec sa = sb;
  sa.face_up = false;
  sa.thickness = 4e-3;
  if (small_a) {
    sa.size_x = sa.size_y = 3e-3;
    sa.subdiv = 3;
    sa.atlas_size = 256;
  }
  S.A = synth::make_block(sa);
  S.hess = a * kk * kk;
  const Vec3 m(std::cos(phi), std::sin(phi), 0);
  S.pa = synth::make_pose(Vec3(1e-4, -2e-4, 0.6 * a) + 0.2 * lam * m,
                          Eigen::Quaterniond(Eigen::AngleAxisd(0.1, Vec3::UnitZ())));
  S.pb = synth::make_pose(Vec3::Zero());
  S.patch = synth::make_patch(Vec3(0, 0, -1), Vec3(1, 0.3, 0), Vec3(2e-4, 1e-4, 0), lam / 40, 50, S.A.face_tris,
                              S.B.face_tris);
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  Eigen::Isometry3d Q = Eigen::Isometry3d::Identity();
  Q.linear() = Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
  Q.translation() = Vec3(0.02, 0.01, -0.03);
  synth::transform_scene(Q, S.pa, S.pb, S.patch);
  return S;
}

TEST(DepthShortcut, AgreesWithFullRerasterization) {
  for (bool small_a : {false, true}) {
    for (int seed : {1, 2, 3}) {
      Scene S = make_scene(small_a, seed);
      DepthScratch scratch;
      scratch.reserve(50);
      // The shortcut against the full re-rasterization of the same heights:
      // the literal Eq. 8 ones, which both rasterize triangle by triangle
      // (the surface mode's full path re-solves from seeds instead; that is
      // checked against re-rasterization in SeededResolveMatchesRasterization).
      ForceOptions full, sc;
      full.heights = sc.heights = HeightMode::coarse;
      sc.shortcut = true;
      const DepthGradient gf = compute_depth_gradient(S.A.model, S.pa, S.B.model, S.pb, S.patch, full, scratch);
      const DepthGradient gs = compute_depth_gradient(S.A.model, S.pa, S.B.model, S.pb, S.patch, sc, scratch);
      ASSERT_TRUE(gf.covered);
      ASSERT_TRUE(gs.covered);
      ASSERT_EQ(gf.lin_step, S.patch.window.cell);  // default: one grid texel
      ASSERT_EQ(gf.ang_step, gs.ang_step);
      // delta(0) and the tilts (rendered in both modes) are identical.
      for (int c : {0, 5, 6, 7, 8}) EXPECT_EQ(gf.delta_at[c], gs.delta_at[c]) << "config " << c;
      // One-texel shifts are exact: equal up to the rounding of the
      // projected corner coordinates (heights ~1e-4 m, 1e-15 relative).
      for (int c = 1; c <= 4; ++c) EXPECT_NEAR(gf.delta_at[c], gs.delta_at[c], 1e-15) << "config " << c;
      // n-rotations: bilinear resampling of the exact samples of h_A: off by
      // at most (|h_uu| + |h_vv|) cell^2 / 8 <= hess cell^2 / 4 per texel,
      // hence in delta; the derivative by that over dtheta.
      const double cell = S.patch.window.cell;
      const double e_rot = S.hess * cell * cell / 4;
      for (int c : {9, 10}) EXPECT_NEAR(gf.delta_at[c], gs.delta_at[c], e_rot) << "config " << c;
      EXPECT_NEAR(gf.grad[5], gs.grad[5], e_rot / gf.ang_step);
      for (int i = 0; i < 5; ++i) EXPECT_NEAR(gf.grad[i], gs.grad[i], 1e-15 / cell) << "grad " << i;
      // Not vacuous: the n-rotation changes delta by much more than e_rot.
      EXPECT_GT(std::abs(gf.delta_at[9] - gf.delta_at[10]), 3 * e_rot);
    }
  }
}

// The surface mode's perturbed configurations are re-solved from the seeds of
// configuration 0 (resolve_heights) rather than rasterized again. Both are
// fixed points that project within the lateral tolerance e = kLateralTolerance
// * min(cell, texel) of the texel centre, on the same reconstructed surface,
// so two heights of one texel differ by at most 2 e s (s the surface's slope
// along n: the sine grating's a k, times 1.05 for the tilt of n by the random
// pose not being exactly the face normal, none here) plus float rounding of
// the products (1e-9 m at these 1e-2 m coordinates); delta inherits it.
// Coverage: where A's whole footprint lies inside B's and inside the window
// (small_a == false has A as large as B, true a 3 mm A), every texel the
// maximum can come from is covered in both.
TEST(DepthShortcut, SeededResolveMatchesRasterization) {
  for (bool small_a : {false, true}) {
    for (int seed : {1, 2, 3}) {
      Scene S = make_scene(small_a, seed);
      DepthScratch scratch;
      scratch.reserve(50);
      ForceOptions opt;  // surface mode, full path (seeded)
      const DepthGradient g = compute_depth_gradient(S.A.model, S.pa, S.B.model, S.pb, S.patch, opt, scratch);
      ASSERT_TRUE(g.covered);
      const double cell = S.patch.window.cell;
      const double e = kLateralTolerance * std::min(cell, S.A.model.quality.texel_size);
      const double slope = S.hess / (2 * kPi / 2e-3);  // a k
      const double bound = 2 * e * slope * 1.05 + 1e-9;
      const Vec3 c_a = S.pa.iso() * S.A.model.mass.center_of_mass;
      double worst = 0;
      for (int c = 1; c < static_cast<int>(Config::count); ++c) {
        const Eigen::Isometry3d T =
            config_motion(static_cast<Config>(c), S.patch, c_a, g.lin_step, g.ang_step) * S.pa.iso();
        bool cov = false;
        const double d = directional_depth(S.A.model, T, S.B.model, S.pb.iso(), S.patch, scratch, &cov);
        ASSERT_TRUE(cov);
        EXPECT_NEAR(g.delta_at[c], d, bound) << "config " << c;
        worst = std::max(worst, std::abs(g.delta_at[c] - d));
      }
      // Not vacuous: the configurations differ from configuration 0 by far more.
      EXPECT_GT(std::abs(g.delta_at[1] - g.delta_at[2]), 20 * bound);
      std::printf("seeded vs rasterized (small_a %d, seed %d): worst %.3g m, bound %.3g m\n", small_a, seed, worst,
                  bound);
    }
  }
}

// A translation step that is not a whole number of texels: the shortcut
// interpolates linearly between two shifts: error <= hess (s cell)^2 / 8.
TEST(DepthShortcut, FractionalStepInterpolates) {
  Scene S = make_scene(false, 4);
  DepthScratch scratch;
  scratch.reserve(50);
  ForceOptions full, sc;
  full.lin_step = sc.lin_step = 1.5 * S.patch.window.cell;
  sc.shortcut = true;
  const DepthGradient gf = compute_depth_gradient(S.A.model, S.pa, S.B.model, S.pb, S.patch, full, scratch);
  const DepthGradient gs = compute_depth_gradient(S.A.model, S.pa, S.B.model, S.pb, S.patch, sc, scratch);
  const double cell = S.patch.window.cell;
  const double e = S.hess * cell * cell / 8;
  for (int c = 1; c <= 4; ++c) EXPECT_NEAR(gf.delta_at[c], gs.delta_at[c], e) << "config " << c;
  EXPECT_GT(std::abs(gf.delta_at[1] - gf.delta_at[2]), 3 * e);
}

// config_motion: translations along u, v; rotations about u, v, n through c.
TEST(DepthShortcut, ConfigMotionsAreAboutTheCentreOfMass) {
  ContactPatch p = synth::make_patch(Vec3(0.2, -0.3, 0.9), Vec3(1, 0, 0), Vec3::Zero(), 1e-4, 10, {}, {});
  const Vec3 c(0.1, 0.2, 0.3);
  const double dl = 2e-4, da = 0.01;
  EXPECT_TRUE((config_motion(Config::plus_u, p, c, dl, da).translation() - dl * p.u).norm() < 1e-15);
  EXPECT_TRUE((config_motion(Config::minus_v, p, c, dl, da).translation() + dl * p.v).norm() < 1e-15);
  for (Config k : {Config::plus_theta_u, Config::minus_theta_v, Config::plus_theta_n}) {
    const Eigen::Isometry3d M = config_motion(k, p, c, dl, da);
    EXPECT_LT((M * c - c).norm(), 1e-15);  // c is fixed
    const Vec3 axis = k == Config::plus_theta_u ? p.u : k == Config::minus_theta_v ? -p.v : p.n;
    const Eigen::AngleAxisd aa(M.linear());
    EXPECT_NEAR(aa.angle(), da, 1e-12);
    EXPECT_LT((aa.axis() - axis).norm(), 1e-9);
  }
  // The default angle moves no window point by more than one texel.
  const double th = default_ang_step(p, c);
  for (int k = 0; k < 4; ++k) {
    const Vec3 corner = p.window.origin + ((k & 1) ? 1e-3 : 0.0) * p.u + ((k & 2) ? 1e-3 : 0.0) * p.v;
    EXPECT_LE(2 * std::sin(th / 2) * (corner - c).norm(), p.window.cell * (1 + 1e-12));
  }
}

TEST(DepthShortcut, UndersamplingWarnsOncePerPatchLifetime) {
  synth::BlockSpec sb;  // 20 mm over 504 atlas texels: min wavelength ~0.08 mm
  const auto B = synth::make_block(sb);
  synth::BlockSpec sa = sb;
  sa.face_up = false;
  const auto A = synth::make_block(sa);
  const double lam = std::min(A.model.quality.min_wavelength, B.model.quality.min_wavelength);
  ContactPatch fine =
      synth::make_patch(Vec3(0, 0, -1), Vec3::UnitX(), Vec3::Zero(), 0.5 * lam, 16, A.face_tris, B.face_tris);
  ContactPatch coarse =
      synth::make_patch(Vec3(0, 0, -1), Vec3::UnitX(), Vec3::Zero(), 0.51 * lam, 16, A.face_tris, B.face_tris);
  EXPECT_FALSE(grid_undersamples(A.model, B.model, fine.window));
  EXPECT_TRUE(grid_undersamples(A.model, B.model, coarse.window));
  DepthScratch scratch;
  scratch.reserve(16);
  DepthWarnings w;
  bool warned = false;
  Pose pa = synth::make_pose(Vec3(0, 0, -1e-5)), pb;
  for (int frame = 0; frame < 5; ++frame)
    compute_patch_wrench(A.model, pa, B.model, pb, coarse, ForceOptions{}, scratch, &w, &warned);
  EXPECT_EQ(w.undersampled_patches, 1u);
  EXPECT_TRUE(warned);
  bool warned2 = false;  // a new patch
  compute_patch_wrench(A.model, pa, B.model, pb, coarse, ForceOptions{}, scratch, &w, &warned2);
  compute_patch_wrench(A.model, pa, B.model, pb, fine, ForceOptions{}, scratch, &w, nullptr);
  EXPECT_EQ(w.undersampled_patches, 2u);
}

// A window half off A: the configurations that shift A away lose nothing
// (the window is padded in practice); where a configuration has no texel
// covered by both, the difference becomes one-sided.
TEST(DepthShortcut, OneSidedDifferenceWhenAConfigurationIsUncovered) {
  synth::BlockSpec sb;
  const auto B = synth::make_block(sb);
  synth::BlockSpec sa;
  sa.size_x = sa.size_y = 1e-3;
  sa.thickness = 5e-4;  // c_A close to the face: the rotations keep texel column 9 covered
  sa.face_up = false;
  sa.subdiv = 1;
  const auto A = synth::make_block(sa);
  // A's footprint [-0.5, 0.5] mm; a window of 10 texels of 0.1 mm whose
  // last column of texel centres (x = -0.45 mm) is the only one over A:
  // moving A by +1 texel along u uncovers everything.
  const double cell = 1e-4;
  ContactPatch p = synth::make_patch(Vec3(0, 0, -1), Vec3::UnitX(), Vec3::Zero(), cell, 10, A.face_tris, B.face_tris);
  p.window.origin.x() = -0.45e-3 - 9.5 * cell;  // texel 9's centre at x = -0.45 mm
  Pose pa = synth::make_pose(Vec3(0, 0, -1e-5)), pb;
  DepthScratch scratch;
  scratch.reserve(10);
  for (bool shortcut : {false, true}) {
    ForceOptions o;
    o.shortcut = shortcut;
    const DepthGradient g = compute_depth_gradient(A.model, pa, B.model, pb, p, o, scratch);
    ASSERT_TRUE(g.covered);
    EXPECT_NEAR(g.delta, 1e-5, 1e-11);
    EXPECT_EQ(g.delta_at[static_cast<int>(Config::plus_u)], -std::numeric_limits<double>::infinity());
    EXPECT_NEAR(g.delta_at[static_cast<int>(Config::minus_u)], 1e-5, 1e-11);
    EXPECT_EQ(g.uncovered_configurations, 1);
    EXPECT_NEAR(g.grad[0], 0.0, 1e-9);  // (delta(0) - delta(-du)) / du, flat plates
  }
}

// The rasterizer's inlined bilinear lookup and its UV interpolation against
// an independent path: a plate with a random atlas, tilted n, rotated pose;
// each texel's height against n . Atlas::sample (the loader's
// implementation of the spec's convention) at UVs found by projecting the
// texel centre onto each triangle. Tolerance 1e-8 m: Atlas::sample takes
// float UVs (6e-8 relative: 4e-6 texel of a 64-texel atlas whose values vary
// by up to 2e-3 m per texel).
TEST(DepthShortcut, RasterizerSamplesLikeAtlasSample) {
  synth::BlockSpec sb;
  sb.atlas_size = 64;
  sb.subdiv = 1;
  auto B = synth::make_block(sb);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> U(-1e-3f, 1e-3f);
  for (float& x : B.model.atlas.rgba) x += U(rng);
  const int N = 40;
  ContactPatch p = synth::make_patch(Vec3(0.3, 0.2, -1), Vec3::UnitX(), Vec3(1e-3, -2e-3, 0), 2e-4, N, {}, B.face_tris);
  const Pose pb =
      synth::make_pose(Vec3(0, 0, 0), Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Vec3(1, 2, 3).normalized())));
  std::vector<double> h(static_cast<size_t>(N) * N);
  // The literal Eq. 8 (the noise above makes the atlas jump between texels,
  // which the surface mode would rightly refuse to interpolate across).
  rasterize_heights(B.model, pb.iso(), B.face_tris, p.n, p.u, p.v, p.window, 0, false, h.data(), HeightMode::coarse);
  // Reference: for each texel centre, find the face triangle under it (ray
  // along n in the object frame) and interpolate its UVs barycentrically.
  const Eigen::Isometry3d T = pb.iso();
  int checked = 0;
  for (int j = 0; j < N; ++j)
    for (int i = 0; i < N; ++i) {
      const Vec3 x = p.window.origin + (i + 0.5) * p.window.cell * p.u + (j + 0.5) * p.window.cell * p.v;
      for (uint32_t f : B.face_tris) {
        Vec3 P[3];
        for (int c = 0; c < 3; ++c) P[c] = T * B.model.vertices[B.model.faces[f][c]];
        // Project onto the plane orthogonal to n and solve for barycentrics.
        Eigen::Matrix2d M;
        const Vec3 e1 = P[1] - P[0], e2 = P[2] - P[0], r = x - P[0];
        M << e1.dot(p.u), e2.dot(p.u), e1.dot(p.v), e2.dot(p.v);
        const Eigen::Vector2d b = M.inverse() * Eigen::Vector2d(r.dot(p.u), r.dot(p.v));
        if (b.x() < 1e-9 || b.y() < 1e-9 || b.x() + b.y() > 1 - 1e-9) continue;
        const auto& uv = B.model.uvs[f];
        const Vec2f t = (1 - b.x() - b.y()) * uv[0] + b.x() * uv[1] + b.y() * uv[2];
        const Eigen::Vector3f s = B.model.atlas.sample(t.x(), t.y());
        const double ref = p.n.dot(T * s.cast<double>() - p.window.origin);
        EXPECT_NEAR(h[static_cast<size_t>(j) * N + i], ref, 1e-8) << i << "," << j;
        ++checked;
        break;
      }
    }
  EXPECT_GT(checked, N * N / 2);
}

}  // namespace
}  // namespace hrt

namespace hrt {
namespace {

// "Nothing allocates in compute_patch_wrench once scratch is reserved":
// counted through the test binary's operator new (synthetic.cpp).
TEST(DepthShortcut, NoAllocationOnceScratchIsReserved) {
  Scene S = make_scene(true, 6);
  DepthScratch scratch;
  scratch.reserve(64);
  DepthWarnings w;
  for (bool sc : {false, true}) {
    ForceOptions o;
    o.shortcut = sc;
    ContactPatch p = S.patch;
    const uint64_t before = synth::allocation_count();
    for (int frame = 0; frame < 5; ++frame) {
      compute_patch_wrench(S.A.model, S.pa, S.B.model, S.pb, p, o, scratch, &w, nullptr);
      (void)directional_depth(S.A.model, S.pa.iso(), S.B.model, S.pb.iso(), p, scratch);
    }
    EXPECT_EQ(synth::allocation_count(), before) << "shortcut " << sc;
    EXPECT_TRUE(p.covered);
  }
  // Not vacuous: the counter does count.
  const uint64_t before = synth::allocation_count();
  std::vector<int> v(10);
  EXPECT_GT(synth::allocation_count(), before);
}

}  // namespace
}  // namespace hrt
