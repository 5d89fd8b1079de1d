// Physical behaviour the paper reports (Sec. 6.3):
//  - Fig. 7: a ridged block translated parallel to the ridges of another
//    feels (almost) no force along the ridges: d delta / dx = 0 there.
//  - Fig. 8: rotating one of two interlocked striped blocks about n makes the
//    penetration depth grow with |theta| (the top block must rise), and the
//    torque about n opposes the rotation.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "hrt/depth.h"
#include "hrt/force.h"
#include "synthetic.h"

namespace hrt {
namespace {

constexpr double kPi = 3.14159265358979323846;

Eigen::Isometry3d random_frame(int seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  Eigen::Isometry3d Q = Eigen::Isometry3d::Identity();
  Q.linear() = Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
  Q.translation() = Vec3(g(rng), g(rng), g(rng)) * 0.01;
  return Q;
}

// Fig. 7. Both blocks carry trapezoidal ridges (a = 0.1 mm, lambda = 2 mm,
// flanks of f = 0.15 lambda) running along x. A (4 mm) is offset by
// s = 0.1 lambda across the ridges from the nested position: where both
// rising flanks overlap (a band 0.05 lambda wide) h_A - h_B is constant,
// 2a s / (f lambda) - g = 4a/3 - g = a/3 with g = a, and grows by the flank
// slope 2a / (f lambda) = 0.67 per unit of A's motion across the ridges, so
// the force across them is large (-0.67 F_n); along them it must vanish. The grid's u axis makes 17
// degrees with the ridges (no lattice alignment), the window is snapped to a
// lattice fixed in B as the clustering does, and the scene is rotated.
TEST(Physics, SlidingParallelToRidgesGivesNoForceAlongThem) {
  const double a = 1e-4, lam = 2e-3, s = 0.1 * lam, g = a;
  synth::BlockSpec sb;
  sb.atlas_size = 1024;
  sb.subdiv = 8;
  sb.relief.profile = synth::Profile::ridges;
  sb.relief.amplitude = a;
  sb.relief.wavelength = lam;
  sb.relief.flank = 0.15;
  sb.relief.angle = kPi / 2;  // ridge normal y: ridges along x
  const auto B = synth::make_block(sb);
  synth::BlockSpec sa = sb;
  sa.size_x = sa.size_y = 4e-3;
  sa.thickness = 3e-3;
  sa.face_up = false;
  sa.subdiv = 2;
  sa.atlas_size = 512;
  const auto A = synth::make_block(sa);

  const double phi = 17 * kPi / 180, cell = 1e-4;
  const int N = 64;
  const Vec3 u(std::cos(phi), std::sin(phi), 0);
  for (bool shortcut : {false, true}) {
    ForceOptions opt;
    opt.shortcut = shortcut;
    DepthScratch scratch;
    scratch.reserve(N);
    double worst = 0;
    for (int step = 0; step < 40; ++step) {
      const double x = -1e-3 + step * 0.0537e-3;  // not commensurate with the grid
      Pose pa = synth::make_pose(Vec3(x, s, g)), pb;
      // Window centre snapped to the (u, v) lattice of B's frame.
      const Vec3 vdir = Vec3(0, 0, -1).cross(u);
      const Vec3 c =
          std::round(Vec3(x, s, 0).dot(u) / cell) * cell * u + std::round(Vec3(x, s, 0).dot(vdir) / cell) * cell * vdir;
      ContactPatch patch = synth::make_patch(Vec3(0, 0, -1), u, c, cell, N, A.face_tris, B.face_tris);
      const Eigen::Isometry3d Q = random_frame(100 + step);
      synth::transform_scene(Q, pa, pb, patch);
      compute_patch_wrench(A.model, pa, B.model, pb, patch, opt, scratch);
      ASSERT_TRUE(patch.covered);
      // The band of the maximum is sampled (0.1 mm texels at 17 degrees to it):
      // only the atlas interpolation errors of the two kinked profiles remain.
      EXPECT_NEAR(patch.delta, 4 * a / 3 - g, 2 * synth::relief_interp_error(B) + 1e-9);
      ASSERT_GT(patch.delta, a / 4);
      const Vec3 ex = Q.linear() * Vec3::UnitX(), ey = Q.linear() * Vec3::UnitY();
      const double Fn = std::abs(patch.force.dot(patch.n));
      const double Fx = patch.force.dot(ex), Fy = patch.force.dot(ey);
      ASSERT_GT(Fn, 0);
      EXPECT_LE(std::abs(Fx), 0.05 * Fn) << "x = " << x << " shortcut " << shortcut;  // paper Fig. 7
      // Across the ridges: A is pushed back towards the nested position, by
      // the flank slope 2a / (f lambda) = 0.67 times F_n (Eq. 5: F_y / F_n =
      // d delta / dy); the central difference over one texel straddles the
      // band's edges, hence the range.
      EXPECT_LT(Fy, -0.4 * Fn) << "x = " << x;
      EXPECT_GT(Fy, -0.8 * Fn) << "x = " << x;
      worst = std::max(worst, std::abs(Fx) / Fn);
    }
    RecordProperty(shortcut ? "worst_Fx_over_Fn_shortcut" : "worst_Fx_over_Fn", std::to_string(worst));
  }
}

// Fig. 8. Two sinusoidally striped blocks (a = 0.1 mm, lambda = 1 mm, ridges
// along y), nested with zero clearance. A is rotated about n through its
// centre of mass (above the window centre) by theta. With m the ridge normal
// and R the rotation, h_A - h_B = a sin(k m.x) - a sin(k (R m).x): a carrier
// along m + Rm times 2a sin(k x.(m - Rm) / 2), whose argument grows across
// the ridges' length: over the window (half-width L = the outermost texel
// centre) the closed form is
//   delta(theta) = 2a sin(k L sin|theta| / 2)          (k L sin|theta| / 2 < pi/2)
// reached at the window's edge where the carrier peaks. The top block must
// rise by delta: it grows with |theta|, and T_n = -k delta d delta/d theta_n
// opposes the rotation.
TEST(Physics, RotatingInterlockedStripedBlocksRaisesAndResists) {
  const double a = 1e-4, lam = 1e-3, kk = 2 * kPi / lam;
  synth::BlockSpec sb;
  sb.atlas_size = 1024;
  sb.subdiv = 8;
  sb.relief.profile = synth::Profile::sine;
  sb.relief.amplitude = a;
  sb.relief.wavelength = lam;
  const auto B = synth::make_block(sb);
  synth::BlockSpec sa = sb;
  sa.face_up = false;
  sa.thickness = 4e-3;
  const auto A = synth::make_block(sa);
  const int N = 64;
  const double cell = lam / 20;
  const double L = (N / 2 - 0.5) * cell;
  const double eps_atlas = 2 * synth::relief_interp_error(B);

  auto closed = [&](double th) { return 2 * a * std::sin(kk * L * std::sin(std::abs(th)) / 2); };
  auto closed_d = [&](double th) {
    return a * kk * L * std::cos(th) * std::cos(kk * L * std::sin(std::abs(th)) / 2) * (th > 0 ? 1 : -1);
  };
  for (bool shortcut : {false, true}) {
    ForceOptions opt;
    opt.shortcut = shortcut;
    DepthScratch scratch;
    scratch.reserve(N);
    double prev = 0;
    for (double deg : {2.0, 4.0, 6.0, 8.0, 10.0}) {
      double d_pm[2], tn_pm[2];
      for (int sgn : {1, -1}) {
        const double th = sgn * deg * kPi / 180;
        const Vec3 n(0, 0, -1);
        Pose pa = synth::make_pose(Vec3::Zero(), Eigen::Quaterniond(Eigen::AngleAxisd(th, n))), pb;
        ContactPatch patch = synth::make_patch(n, Vec3::UnitX(), Vec3::Zero(), cell, N, A.face_tris, B.face_tris);
        const Eigen::Isometry3d Q = random_frame(int(deg) * 2 + (sgn > 0));
        synth::transform_scene(Q, pa, pb, patch);
        compute_patch_wrench(A.model, pa, B.model, pb, patch, opt, scratch);
        ASSERT_TRUE(patch.covered);
        // Closed form. The maximum is on the outermost texel rows only up to
        // (a) the carrier: sampled every cell along the rows, within
        //     cell / 2 of its crest: relative loss <= 1 - cos(k cell / 2);
        // (b) the corner: the carrier crest nearest the corner may be up to
        //     one wavelength inside it, where the envelope's argument is
        //     smaller by at most k lambda sin^2(theta/2) (exactly
        //     k x.(m - Rm)/2 with |m - Rm| = 2 sin(theta/2)); and larger by
        //     k L sin^2(|theta|/2) at the corner itself.
        const double D = closed(th);
        const double tol =
            D * (1 - std::cos(kk * cell / 2)) + 2 * a * kk * (lam + L) * std::pow(std::sin(th / 2), 2) + eps_atlas;
        EXPECT_NEAR(patch.delta, D, tol) << deg << " deg, sign " << sgn << " shortcut " << shortcut;
        // Torque about n opposes the rotation (Fig. 8), with the size of
        // -k delta d delta/d theta: the derivative within the same bounds
        // over the step, plus the step's own truncation.
        const double Tn = patch.torque.dot(patch.n);
        EXPECT_LT(Tn * th, 0.0) << deg << " deg";
        const double dth = default_ang_step(patch, pa.iso() * A.model.mass.center_of_mass);
        // The shortcut resamples h_A(0) bilinearly for the n-rotation:
        // <= a k^2 cell^2 / 4 on each delta (test_depth_shortcut).
        const double dtol = tol / dth + a * std::pow(kk * L, 3) * dth * dth / 6 +
                            (shortcut ? a * kk * kk * cell * cell / 4 / dth : 0.0);
        EXPECT_NEAR(patch.grad[5], closed_d(th), dtol) << deg << " deg, sign " << sgn;
        d_pm[sgn > 0] = patch.delta;
        tn_pm[sgn > 0] = Tn;
      }
      // Symmetric in theta, torque flips sign.
      EXPECT_NEAR(d_pm[0], d_pm[1], 2 * eps_atlas + 2 * closed(deg * kPi / 180) * (1 - std::cos(kk * cell / 2)));
      EXPECT_LT(tn_pm[0] * tn_pm[1], 0.0);
      // Grows with |theta|.
      EXPECT_GT(d_pm[1], prev) << deg << " deg";
      prev = d_pm[1];
    }
  }
}

}  // namespace
}  // namespace hrt
