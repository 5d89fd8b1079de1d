// Directional penetration depth (Eq. 8-9), its gradient (Eq. 7) and the
// wrench (Eq. 5-6) against closed forms on synthetic textured blocks whose
// relief is known analytically (synthetic.h).
//
// Scene convention of these tests: B lies below with its textured face up,
// A (the probe) above with its textured face down; n = -z (from A into B),
// so h = n . p = -z and h_A - h_B = z_B(top of B) - z_A(bottom of A) is the
// overlap. The window is centred on the contact, u = x, v = n x u = -y.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "hrt/depth.h"
#include "hrt/force.h"
#include "synthetic.h"

namespace hrt {
namespace {

using synth::BlockSpec;
using synth::Profile;
constexpr double kPi = 3.14159265358979323846;
constexpr double k = 1000.0;  // N/m

Eigen::Isometry3d random_rotation(std::mt19937& rng) {
  std::normal_distribution<double> g(0.0, 1.0);
  Eigen::Quaterniond q(g(rng), g(rng), g(rng), g(rng));
  q.normalize();
  Eigen::Isometry3d Q = Eigen::Isometry3d::Identity();
  Q.linear() = q.toRotationMatrix();
  std::uniform_real_distribution<double> t(-0.05, 0.05);
  Q.translation() = Vec3(t(rng), t(rng), t(rng));
  return Q;
}

ForceOptions opts(bool shortcut = false) {
  ForceOptions o;
  o.stiffness = k;
  o.shortcut = shortcut;
  return o;
}

// ---------------------------------------------------------------------------
// Two flat textured plates: delta = overlap of the atlas surfaces (not of
// the coarse faces: both atlases are displaced from their coarse faces),
// F = -k delta n, no tangential force, no torque; in randomly rotated scenes.
TEST(DepthAnalytic, FlatPlatesDeltaIsOverlapAndForceIsNormal) {
  BlockSpec sb;  // 20 mm plate, textured face up, atlas 0.1 mm above its coarse face
  sb.relief.offset = 1e-4;
  const auto B = synth::make_block(sb);
  BlockSpec sa;  // 4 mm plate, textured face down, atlas 0.05 mm below its coarse face
  sa.size_x = sa.size_y = 4e-3;
  sa.thickness = 2e-3;
  sa.face_up = false;
  sa.subdiv = 2;
  sa.relief.offset = -5e-5;
  const auto A = synth::make_block(sa);

  const double overlap = 3e-5;
  // bottom of A (world z) = zA - 5e-5; top of B = 1e-4.
  const double zA = 1e-4 + 5e-5 - overlap;
  std::mt19937 rng(7);
  for (int trial = 0; trial < 6; ++trial) {
    Pose pa = synth::make_pose(Vec3(0, 0, zA)), pb = synth::make_pose(Vec3::Zero());
    // 32 texels of 0.2 mm: A's 4 mm footprint edges fall on texel edges,
    // symmetric about A's centre of mass (so that the flat-on-flat tilt
    // derivatives, which have a kink at 0, cancel exactly).
    ContactPatch patch =
        synth::make_patch(Vec3(0, 0, -1), Vec3::UnitX(), Vec3(0, 0, 1e-4), 2e-4, 32, A.face_tris, B.face_tris);
    if (trial > 0) synth::transform_scene(random_rotation(rng), pa, pb, patch);
    for (bool sc : {false, true}) {
      DepthScratch scratch;
      scratch.reserve(32);
      compute_patch_wrench(A.model, pa, B.model, pb, patch, opts(sc), scratch);
      ASSERT_TRUE(patch.covered);
      // float32 atlas positions (|p| <= 0.02 m: rounding <= 1.2e-9 m) are the only error.
      EXPECT_NEAR(patch.delta, overlap, 2e-9) << "trial " << trial;
      const double Fn = k * overlap;
      EXPECT_NEAR((patch.force + Fn * patch.n).norm(), 0.0, 1e-6 * Fn) << "trial " << trial;
      EXPECT_NEAR(patch.force.dot(patch.n), -k * patch.delta, 1e-12 * Fn);  // Eq. 5, F_n = -k delta
      // Torque: relative to Fn times the window size (6.4 mm).
      EXPECT_LT(patch.torque.norm(), 1e-6 * Fn * 6.4e-3) << "trial " << trial;
    }
  }
}

// Several layers under one texel: with both faces of each block in the
// triangle lists, A must keep its deepest point along n (its textured face,
// below its back face) and B its first (its top face, above its bottom).
TEST(DepthAnalytic, KeepsDeepestLayerOfAAndFirstLayerOfB) {
  BlockSpec sb;
  sb.relief.offset = 1e-4;
  const auto B = synth::make_block(sb);
  BlockSpec sa;
  sa.size_x = sa.size_y = 4e-3;
  sa.thickness = 2e-3;
  sa.face_up = false;
  sa.relief.offset = -5e-5;
  const auto A = synth::make_block(sa);
  const double overlap = 3e-5;
  Pose pa = synth::make_pose(Vec3(0, 0, 1e-4 + 5e-5 - overlap)), pb;
  std::vector<uint32_t> ta = A.face_tris, tb = B.back_tris;
  ta.insert(ta.end(), A.back_tris.begin(), A.back_tris.end());
  tb.insert(tb.end(), B.face_tris.begin(), B.face_tris.end());
  ContactPatch patch = synth::make_patch(Vec3(0, 0, -1), Vec3::UnitX(), Vec3::Zero(), 2e-4, 32, ta, tb);
  for (bool sc : {false, true}) {
    DepthScratch scratch;
    scratch.reserve(32);
    compute_patch_wrench(A.model, pa, B.model, pb, patch, opts(sc), scratch);
    EXPECT_NEAR(patch.delta, overlap, 2e-9);
    EXPECT_NEAR(directional_depth(A.model, pa.iso(), B.model, pb.iso(), patch, scratch), overlap, 2e-9);
  }
}

TEST(DepthAnalytic, SeparatedPatchGivesNoForceAndUncoveredPatchIsFlagged) {
  BlockSpec sb;
  const auto B = synth::make_block(sb);
  BlockSpec sa;
  sa.size_x = sa.size_y = 4e-3;
  sa.face_up = false;
  const auto A = synth::make_block(sa);
  DepthScratch scratch;
  scratch.reserve(32);
  // A 0.1 mm above B: delta = -1e-4, reported, but U = k max(delta, 0)^2 / 2 = 0.
  Pose pa = synth::make_pose(Vec3(0, 0, 1e-4)), pb;
  ContactPatch patch =
      synth::make_patch(Vec3(0, 0, -1), Vec3::UnitX(), Vec3::Zero(), 2e-4, 32, A.face_tris, B.face_tris);
  compute_patch_wrench(A.model, pa, B.model, pb, patch, opts(), scratch);
  EXPECT_TRUE(patch.covered);
  EXPECT_NEAR(patch.delta, -1e-4, 2e-9);
  EXPECT_EQ(patch.force, Vec3::Zero());
  EXPECT_EQ(patch.torque, Vec3::Zero());
  // Window 10 mm beside A: nothing covered by both.
  ContactPatch away =
      synth::make_patch(Vec3(0, 0, -1), Vec3::UnitX(), Vec3(0.01, 0, 0), 2e-4, 32, A.face_tris, B.face_tris);
  compute_patch_wrench(A.model, pa, B.model, pb, away, opts(), scratch);
  EXPECT_FALSE(away.covered);
  EXPECT_EQ(away.force, Vec3::Zero());
  bool cov = true;
  const double d = directional_depth(A.model, pa.iso(), B.model, pb.iso(), away, scratch, &cov);
  EXPECT_FALSE(cov);
  EXPECT_EQ(d, -std::numeric_limits<double>::infinity());
}

// ---------------------------------------------------------------------------
// A small flat plate (0.5 mm) on the rising flank of a sinusoidal grating
// z_B = a sin(k x): delta(x_c) = a sin(k (x_c + w/2)) - z_A (the plate's
// right edge is the highest point of B under it), d delta / du = a k cos(...),
// d delta / dv = 0 (v runs along the ridges).
TEST(DepthAnalytic, FlatPlateOnSinusoidalGrating) {
  const double a = 1e-4, lam = 2e-3, kk = 2 * kPi / lam, w = 5e-4, cell = 5e-5;
  BlockSpec sb;
  sb.atlas_size = 1024;
  sb.subdiv = 8;
  sb.relief.profile = Profile::sine;
  sb.relief.amplitude = a;
  sb.relief.wavelength = lam;
  const auto B = synth::make_block(sb);
  BlockSpec sa;
  sa.size_x = sa.size_y = w;
  sa.thickness = 5e-4;
  sa.face_up = false;
  sa.subdiv = 1;
  const auto A = synth::make_block(sa);
  const double eps_atlas = synth::relief_interp_error(B);

  // Plate centred at x_c = 0: footprint [-w/2, w/2] = [-lambda/8, lambda/8],
  // on texel edges (window of 32 x 0.05 mm centred on it). z_A: delta ~ a/2.
  const double zA = a * std::sin(kPi / 4) - 0.5 * a;
  for (bool sc : {false, true}) {
    Pose pa = synth::make_pose(Vec3(0, 0, zA)), pb;
    ContactPatch patch =
        synth::make_patch(Vec3(0, 0, -1), Vec3::UnitX(), Vec3::Zero(), cell, 32, A.face_tris, B.face_tris);
    DepthScratch scratch;
    scratch.reserve(32);
    compute_patch_wrench(A.model, pa, B.model, pb, patch, opts(sc), scratch);
    ASSERT_TRUE(patch.covered);

    // (1) The closed form of the sampled problem: the highest texel centre of
    // the footprint is x_r = w/2 - cell/2; the central difference with a
    // one-texel step moves the footprint by exactly one texel. Only the
    // atlas interpolation differs.
    const double xr = w / 2 - cell / 2;
    EXPECT_NEAR(patch.delta, a * std::sin(kk * xr) - zA, eps_atlas + 1e-10);
    const double g_lat = a * (std::sin(kk * (xr + cell)) - std::sin(kk * (xr - cell))) / (2 * cell);
    EXPECT_NEAR(patch.grad[0], g_lat, eps_atlas / cell + 1e-6);
    // (2) The continuous closed form, within the sampling error: the edge is
    // cell/2 away from x_r (|f'| cell/2 on delta, |f''| cell/2 + |f'''| cell^2/6
    // on the derivative).
    const double d_c = a * std::sin(kk * w / 2) - zA, g_c = a * kk * std::cos(kk * w / 2);
    EXPECT_NEAR(patch.delta, d_c, a * kk * cell / 2 + eps_atlas);
    EXPECT_NEAR(patch.grad[0], g_c, a * kk * kk * cell / 2 + a * kk * kk * kk * cell * cell / 6 + eps_atlas / cell);
    EXPECT_GT(patch.grad[0], 0.5 * g_c);  // not vacuous: g_c = 0.22
    // Along the ridges nothing changes.
    EXPECT_NEAR(patch.grad[1], 0.0, 1e-9);
    // Eq. 5: F_u = -k delta d delta/du < 0: the plate is pushed away from the crest.
    EXPECT_NEAR(patch.force.x(), -k * patch.delta * patch.grad[0], 1e-12);
    EXPECT_LT(patch.force.x(), 0.0);
    EXPECT_NEAR(patch.force.z(), k * patch.delta, 1e-12);  // along -n = +z
  }
}

// ---------------------------------------------------------------------------
// Two identical gratings facing each other, A offset by s along the ridge
// normal from the nested position with clearance g:
//   delta(s) = max_x [a sin(k x) - a sin(k (x - s))] - g = 2a |sin(pi s / lambda)| - g,
//   d delta / ds = a k cos(pi s / lambda) sign(s).
struct Gratings {
  double a = 1e-4, lam = 2e-3, g = 5e-5;
  synth::SynthBlock A, B;
  Gratings(double angle, int atlas = 1024) {
    BlockSpec sb;
    sb.atlas_size = atlas;
    sb.subdiv = 8;
    sb.relief.profile = Profile::sine;
    sb.relief.amplitude = a;
    sb.relief.wavelength = lam;
    sb.relief.angle = angle;
    B = synth::make_block(sb);
    BlockSpec sa = sb;
    sa.face_up = false;
    sa.thickness = 2e-3;
    A = synth::make_block(sa);
  }
  double closed(double s) const { return 2 * a * std::abs(std::sin(kPi * s / lam)) - g; }
  double closed_ds(double s) const { return a * 2 * kPi / lam * std::cos(kPi * s / lam) * (s > 0 ? 1 : -1); }
};

TEST(DepthAnalytic, NestedGratingsOffsetAlongRidgeNormal) {
  Gratings G(0.0);
  const double cell = G.lam / 40, kk = 2 * kPi / G.lam;
  const int N = 50;
  const double eps_atlas = 2 * synth::relief_interp_error(G.B);
  for (double sl : {0.1, 0.2, 0.3, 0.45, -0.2, -0.35, 0.04}) {
    const double s = sl * G.lam;
    Pose pa = synth::make_pose(Vec3(s, 0, G.g)), pb;
    ContactPatch patch =
        synth::make_patch(Vec3(0, 0, -1), Vec3::UnitX(), Vec3::Zero(), cell, N, G.A.face_tris, G.B.face_tris);
    DepthScratch scratch;
    scratch.reserve(N);
    compute_patch_wrench(G.A.model, pa, G.B.model, pb, patch, opts(), scratch);
    ASSERT_TRUE(patch.covered);
    // (1) The sampled closed form: the max over the texel centres x_i (the
    // window's columns) of the exact difference; the derivative as the
    // runtime's central difference of it. Only the atlas error remains.
    const double x0 = patch.window.origin.x();
    auto lattice = [&](double ss) {
      double m = -1e9;
      for (int i = 0; i < N; ++i) {
        const double x = x0 + (i + 0.5) * cell;
        m = std::max(m, G.a * std::sin(kk * x) - G.a * std::sin(kk * (x - ss)));
      }
      return m - G.g;
    };
    EXPECT_NEAR(patch.delta, lattice(s), eps_atlas + 1e-10) << "s/lambda " << sl;
    EXPECT_NEAR(patch.grad[0], (lattice(s + cell) - lattice(s - cell)) / (2 * cell), eps_atlas / cell + 1e-6)
        << "s/lambda " << sl;
    // (2) The continuous closed form: samples lie within cell/2 of the crest
    // of the difference (amplitude D = 2a|sin(pi s/lambda)|): delta is low by
    // at most D (1 - cos(k cell / 2)); the derivative's error adds that twice
    // over 2 cell and the central difference's truncation |f'''| cell^2 / 6.
    const double D = 2 * G.a * std::abs(std::sin(kPi * s / G.lam));
    const double samp = D * (1 - std::cos(kk * cell / 2));
    EXPECT_NEAR(patch.delta, G.closed(s), samp + eps_atlas) << "s/lambda " << sl;
    const double ds_tol = samp / cell + G.a * kk * kk * kk / 8 * cell * cell / 6 + eps_atlas / cell;
    EXPECT_NEAR(patch.grad[0], G.closed_ds(s), ds_tol) << "s/lambda " << sl;
    EXPECT_NEAR(patch.grad[1], 0.0, 1e-9);
    if (G.closed(s) > 0) {
      EXPECT_NEAR(patch.force.x(), -k * patch.delta * patch.grad[0], 1e-12);
      // Pushed back towards the nested position.
      EXPECT_LT(patch.force.x() * s, 0.0);
    } else {
      EXPECT_EQ(patch.force, Vec3::Zero());
    }
  }
}

// Largest gap (m) between the phases m . x_i mod lambda of the window's texel
// centres: a sinusoid along m is sampled within gap/2 of its crest.
double largest_phase_gap(const ContactPatch& p, const Vec3& m, double lam) {
  std::vector<double> ph;
  const int N = p.window.resolution;
  for (int j = 0; j < N; ++j)
    for (int i = 0; i < N; ++i) {
      const Vec3 x = p.window.origin + (i + 0.5) * p.window.cell * p.u + (j + 0.5) * p.window.cell * p.v;
      const double t = m.dot(x) / lam;
      ph.push_back((t - std::floor(t)) * lam);
    }
  std::sort(ph.begin(), ph.end());
  double gap = ph.front() + lam - ph.back();
  for (size_t i = 1; i < ph.size(); ++i) gap = std::max(gap, ph[i] - ph[i - 1]);
  return gap;
}

// The same pair rotated in the plane: the tangential force follows the
// ridge normal m (the derivative along the ridges is zero), and its size is
// the closed form's, at several angles that are not lattice-aligned.
TEST(DepthAnalytic, RotatedGratingForceFollowsRidgeNormal) {
  for (double deg : {23.0, 60.0, 135.0, -40.0}) {
    const double phi = deg * kPi / 180;
    Gratings G(phi);
    const double cell = G.lam / 40, kk = 2 * kPi / G.lam;
    const int N = 50;
    const double eps_atlas = 2 * synth::relief_interp_error(G.B);
    const Vec3 m(std::cos(phi), std::sin(phi), 0);
    for (double sl : {0.15, -0.3}) {
      const double s = sl * G.lam;
      Pose pa = synth::make_pose(Vec3(0, 0, G.g) + s * m), pb;
      ContactPatch patch =
          synth::make_patch(Vec3(0, 0, -1), Vec3::UnitX(), Vec3::Zero(), cell, N, G.A.face_tris, G.B.face_tris);
      DepthScratch scratch;
      scratch.reserve(N);
      compute_patch_wrench(G.A.model, pa, G.B.model, pb, patch, opts(), scratch);
      ASSERT_TRUE(patch.covered);
      const double D = 2 * G.a * std::abs(std::sin(kPi * s / G.lam));
      // Sampling bound from the actual phase coverage of the lattice.
      const double gap = largest_phase_gap(patch, m, G.lam);
      const double samp = D * (1 - std::cos(kk * gap / 2));
      EXPECT_NEAR(patch.delta, G.closed(s), samp + eps_atlas) << deg << " deg";
      // Tangential force = -k delta (d delta/ds) m; each of g_u, g_v is a
      // central difference of two delta's, each low by at most samp.
      const Vec3 Ft = patch.force - patch.force.dot(patch.n) * patch.n;
      const Vec3 expect = -k * patch.delta * G.closed_ds(s) * m;
      const double g_tol = (samp + eps_atlas) / cell + G.a * kk * kk * kk * cell * cell / 6;
      EXPECT_LT((Ft - expect).norm(), k * patch.delta * g_tol * std::sqrt(2.0)) << deg << " deg";
      // Direction: the component along the ridges is within the same bound.
      const Vec3 t = patch.n.cross(m).normalized();
      EXPECT_LT(std::abs(Ft.dot(t)), k * patch.delta * g_tol * std::sqrt(2.0)) << deg << " deg";
      EXPECT_GT(Ft.norm(), 0.5 * expect.norm());
    }
  }
}

// The mesh heights' whole-texel translations are shifts of configuration
// 0's bordered map (a translation by m texels moves every quad, and so every
// texel's square maximum, by exactly m texels). Independent check: delta at
// A moved by +-lin_step along u and v, each computed from scratch as a
// configuration 0, equals the shifted configurations 1-4 (rounding of the
// placement offsets only: 1e-12 m), and Eq. 7's u and v components are their
// central differences; on a grating at 23 degrees, where both are nonzero.
TEST(DepthAnalytic, MeshHeightsTranslationsAreShiftsAndGiveTheGradient) {
  const double phi = 23.0 * kPi / 180;
  Gratings G(phi);
  const double cell = G.lam / 40;
  const int N = 50;
  const Vec3 m(std::cos(phi), std::sin(phi), 0);
  ForceOptions o = opts();
  o.heights = HeightMode::mesh;
  for (double sl : {0.15, -0.3}) {
    const Pose pa = synth::make_pose(Vec3(0, 0, G.g) + sl * G.lam * m), pb;
    const ContactPatch patch =
        synth::make_patch(Vec3(0, 0, -1), Vec3::UnitX(), Vec3::Zero(), cell, N, G.A.face_tris, G.B.face_tris);
    DepthScratch scratch;
    const DepthGradient g = compute_depth_gradient(G.A.model, pa, G.B.model, pb, patch, o, scratch);
    ASSERT_TRUE(g.covered);
    EXPECT_EQ(g.uncovered_configurations, 0);
    const double du = g.lin_step;
    ASSERT_NEAR(du, cell, 1e-15);  // one texel: the shifts are taken
    const Vec3 dirs[4] = {patch.u, -patch.u, patch.v, -patch.v};
    double d[4];
    for (int c = 0; c < 4; ++c) {
      Pose moved = pa;
      moved.position += du * dirs[c];
      d[c] = compute_depth_gradient(G.A.model, moved, G.B.model, pb, patch, o, scratch).delta_at[0];
      EXPECT_NEAR(g.delta_at[1 + c], d[c], 1e-12) << "configuration " << 1 + c << ", s/lambda " << sl;
    }
    EXPECT_NEAR(g.grad[0], (d[0] - d[1]) / (2 * du), 2e-12 / du);
    EXPECT_NEAR(g.grad[1], (d[2] - d[3]) / (2 * du), 2e-12 / du);
    // Not vacuous: the grating's slope shows in both components.
    EXPECT_GT(std::abs(g.grad[0]), 0.05);
    EXPECT_GT(std::abs(g.grad[1]), 0.02);
  }
}

}  // namespace
}  // namespace hrt
