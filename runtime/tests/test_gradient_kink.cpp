// Eq. 7's translation step straddling a kink of delta (kink_safe_difference,
// hrt/depth.h): on synthetic delta_at values (a V-shaped kink, smooth
// parabolas, lines), through finish_depth_gradient (what both backends
// run), and on the synthetic nested gratings of test_depth_analytic seen
// within one grid texel of their nested position.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "depth/internal.h"
#include "hrt/depth.h"
#include "hrt/force.h"
#include "synthetic.h"

namespace hrt {
namespace {

constexpr double kPi = 3.14159265358979323846;

// delta at configuration 0 and at +-h along one axis, for delta(x) = f(x0 + x).
template <class F>
void sample(const F& f, double x0, double h, double& dp, double& d0, double& dm) {
  dp = f(x0 + h);
  d0 = f(x0);
  dm = f(x0 - h);
}

// A V of slopes -G and +G (its bottom at x = 0, value c) seen from x0: the
// true derivative is sign(x0) G. The central difference is G x0 / h within
// the step; the one-sided difference on x0's side of the kink is exact.
TEST(GradientKink, VShapedKinkWithinTheStepGivesTheBranchSlope) {
  const double G = 0.42, h = 4e-4, c = -5e-5;
  auto V = [&](double x) { return c + G * std::abs(x); };
  // From where the side is decided (kKinkDecided: |central| / (turn / 2) =
  // |x0| / (h - |x0|) >= kKinkDecided) to just inside the step (the turn,
  // 2 G (1 - |x0| / h), at least kKinkStraddleTurn of G).
  const double first = 1.01 * kKinkDecided / (1 + kKinkDecided);
  for (double f : {first, 0.12, 0.25, 0.5, 0.75, 0.9, 0.97}) {
    for (double sgn : {1.0, -1.0}) {
      const double x0 = sgn * f * h;
      double dp, d0, dm, w = -1;
      sample(V, x0, h, dp, d0, dm);
      const double g = kink_safe_difference(dp, d0, dm, h, &w);
      EXPECT_NEAR(g, sgn * G, 1e-9 * G) << "x0/h " << x0 / h;
      EXPECT_EQ(w, 1.0) << "x0/h " << x0 / h;
      // The plain central difference is what Eq. 7 gave: a fraction of it.
      EXPECT_NEAR((dp - dm) / (2 * h), sgn * G * f, 1e-9 * G);
    }
  }
  // At 0.98 h the slope turns by 0.04 of itself (between kKinkSmoothTurn and
  // kKinkStraddleTurn): a blend, closer to the branch slope than the
  // central difference (off by G (1 - |x0| / h) = 0.02 G).
  {
    double dp, d0, dm, w = -1;
    sample(V, 0.98 * h, h, dp, d0, dm);
    const double g = kink_safe_difference(dp, d0, dm, h, &w);
    EXPECT_GT(w, 0.0);
    EXPECT_LT(w, 1.0);
    EXPECT_LT(std::abs(g - G), std::abs((dp - dm) / (2 * h) - G));
  }
  // Past the step the central difference is exact and kept.
  {
    double dp, d0, dm, w = -1;
    sample(V, 1.2 * h, h, dp, d0, dm);
    EXPECT_NEAR(kink_safe_difference(dp, d0, dm, h, &w), G, 1e-9 * G);
    EXPECT_EQ(w, 0.0);
  }
}

// At the V's bottom the gradient is undefined: the result runs continuously
// through the central difference (0 for a symmetric V), kept exactly within
// kKinkUndecided, with a bounded slope in the ramp to the branch slope.
TEST(GradientKink, ContinuousThroughTheBottomOfAV) {
  const double G = 0.42, h = 4e-4;
  auto V = [&](double x) { return G * std::abs(x); };
  double dp, d0, dm;
  sample(V, 0.0, h, dp, d0, dm);
  EXPECT_EQ(kink_safe_difference(dp, d0, dm, h), 0.0);
  double prev = -G;
  const int steps = 4000;
  for (int i = 0; i <= steps; ++i) {
    const double x0 = (-0.5 + static_cast<double>(i) / steps) * h;  // -h/2 .. h/2
    sample(V, x0, h, dp, d0, dm);
    const double g = kink_safe_difference(dp, d0, dm, h);
    const double central = (dp - dm) / (2 * h);
    const double dcentral = G / steps;  // the central difference's change per sample
    // In the ramp g = central + sign (|central| - kKinkUndecided turn / 2) / (kKinkDecided - kKinkUndecided),
    // and turn / 2 = G (1 - |x0| / h) changes as fast as the central difference.
    const double ramp = 1 + (1 + kKinkUndecided) / (kKinkDecided - kKinkUndecided);
    if (i > 0) EXPECT_LE(std::abs(g - prev), ramp * dcentral * (1 + 1e-6)) << x0 / h;
    const double r = std::abs(x0) / (h - std::abs(x0));
    if (r <= kKinkUndecided) EXPECT_EQ(g, central) << x0 / h;
    EXPECT_LE(std::abs(g), G * (1 + 1e-12));
    EXPECT_GE(g * central, 0.0);  // never against the central difference's sign
    prev = g;
  }
}

// Smooth curvature is no kink: a concave parabola (any position) and a
// convex one far enough from its vertex (the slope turns by less than
// kKinkSmoothTurn of itself over the step) keep Eq. 7's central difference
// bit for bit; so do lines.
TEST(GradientKink, SmoothParabolaKeepsTheCentralDifference) {
  const double h = 4e-4, c = 300.0;  // delta'' = +-2c = 600 1/m: a 2 mm relief of amplitude 0.1 mm
  auto concave = [&](double x) { return -c * x * x; };
  auto convex = [&](double x) { return c * x * x; };
  auto line = [&](double x) { return 0.3 * x + 1e-4; };
  for (double x0 : {0.0, 0.3 * h, -0.7 * h, 3 * h, -12 * h, 50 * h}) {
    double dp, d0, dm, w = -1;
    sample(concave, x0, h, dp, d0, dm);
    EXPECT_EQ(kink_safe_difference(dp, d0, dm, h, &w), (dp - dm) / (2 * h)) << x0 / h;
    EXPECT_EQ(w, 0.0);
    sample(line, x0, h, dp, d0, dm);
    EXPECT_EQ(kink_safe_difference(dp, d0, dm, h), (dp - dm) / (2 * h)) << x0 / h;
  }
  // Convex: the slope turns by 2 c h over the step; against the steeper
  // one-sided slope c (2 |x0| + h) that is 2 h / (2 |x0| + h), at most
  // kKinkSmoothTurn from |x0| = 49.5 h on.
  for (double x0 : {50 * h, -60 * h, 120 * h}) {
    double dp, d0, dm, w = -1;
    sample(convex, x0, h, dp, d0, dm);
    EXPECT_EQ(kink_safe_difference(dp, d0, dm, h, &w), (dp - dm) / (2 * h)) << x0 / h;
    EXPECT_EQ(w, 0.0);
    // And that central difference is the derivative (exact for a parabola).
    EXPECT_NEAR((dp - dm) / (2 * h), 2 * c * x0, 1e-9);
  }
  // At the vertex itself (the one-sided slopes' sizes within kKinkUndecided
  // of each other) the central difference is kept.
  {
    double dp, d0, dm;
    sample(convex, 0.01 * h, h, dp, d0, dm);
    EXPECT_EQ(kink_safe_difference(dp, d0, dm, h), (dp - dm) / (2 * h));
  }
  // Elsewhere near a convex vertex three values cannot tell a smooth well
  // from a V (depth.h): it is differentiated one-sided, off by at most
  // delta'' h / 2 (the first-order error).
  for (double x0 : {0.2 * h, 2 * h, -5 * h, 20 * h}) {
    double dp, d0, dm;
    sample(convex, x0, h, dp, d0, dm);
    EXPECT_LE(std::abs(kink_safe_difference(dp, d0, dm, h) - 2 * c * x0), c * h * (1 + 1e-9)) << x0 / h;
  }
}

// finish_depth_gradient (shared by the CPU and GL backends) applies it to
// u and v from delta_at[] alone, keeps the rotations' central differences
// and the one-sided difference next to an uncovered configuration.
TEST(GradientKink, FinishDepthGradientUsesItForTranslationsOnly) {
  const double G = 0.42, h = 4e-4, th = 0.03;
  auto V = [&](double x) { return 2e-5 + G * std::abs(x); };
  DepthGradient g;
  g.lin_step = h;
  g.ang_step = th;
  const double xu = 0.3 * h, xv = -0.6 * h;  // A's offset from the kink along u and v
  double* D = g.delta_at;
  // delta = 2e-5 + G |x| along each axis through configuration 0 (D[0] is
  // V(xu) = V(xv) only if |xu| = |xv|; use one V per axis around its own D[0]).
  D[0] = V(xu);
  D[1] = V(xu + h);
  D[2] = V(xu - h);
  const double shift = V(xu) - V(xv);  // the v axis's V moved so that it passes through D[0]
  D[3] = V(xv + h) + shift;
  D[4] = V(xv - h) + shift;
  // The rotations: a V of slope 0.01 m/rad seen 0.2 step from its bottom.
  for (int c : {5, 7, 9}) {
    D[c] = D[0] + 0.01 * (1.2 * th) - 0.01 * 0.2 * th;
    D[c + 1] = D[0] + 0.01 * (0.8 * th) - 0.01 * 0.2 * th;
  }
  finish_depth_gradient(g);
  ASSERT_TRUE(g.covered);
  EXPECT_EQ(g.delta, D[0]);
  EXPECT_NEAR(g.grad[0], G, 1e-9);
  EXPECT_NEAR(g.grad[1], -G, 1e-9);
  EXPECT_EQ(g.grad[2], 1.0);
  for (int i = 3; i < 6; ++i) {
    const int c = 5 + 2 * (i - 3);
    EXPECT_EQ(g.grad[i], (D[c] - D[c + 1]) / (2 * th)) << i;
  }
  EXPECT_EQ(g.uncovered_configurations, 0);
  // An uncovered neighbour: the one-sided difference, as before.
  D[1] = -std::numeric_limits<double>::infinity();
  finish_depth_gradient(g);
  EXPECT_EQ(g.grad[0], (D[0] - D[2]) / h);
  EXPECT_EQ(g.uncovered_configurations, 1);
}

// The synthetic nested gratings (ridges at 23 degrees, not lattice-aligned)
// seen from within one grid texel of the nested position, apart and
// pressed: d delta / ds = a k cos(pi s / lambda) sign(s) along the ridge
// normal m, from the full chain of compute_patch_wrench (both modes).
TEST(GradientKink, NestedGratingsWithinOneTexelOfTheKink) {
  const double a = 1e-4, lam = 2e-3, phi = 23.0 * kPi / 180, kk = 2 * kPi / lam;
  const double amp = a * kk;  // the gradient's amplitude 2 a pi / lambda
  synth::BlockSpec sb = synth::sine_grating_spec(a, lam, phi);
  const synth::SynthBlock B = synth::make_block(sb);
  synth::BlockSpec sa = sb;
  sa.face_up = false;
  sa.thickness = 2e-3;
  const synth::SynthBlock A = synth::make_block(sa);
  const Vec3 m(std::cos(phi), std::sin(phi), 0);
  const double cell = lam / 20;  // 0.1 mm: the u step reaches cos(23) cell = 0.092 mm across the ridges
  const int N = 50;
  double worst_new = 0, worst_central = 0;
  // A lifted by `lift`: delta(s) = 2 a |sin(pi s / lambda)| - lift, pressed
  // (lift < 0) or apart at the nested position.
  for (double lift : {-3e-5, 2e-5}) {
    for (double s : {-0.08e-3, -0.05e-3, -0.03e-3, -0.015e-3, 0.012e-3, 0.02e-3, 0.04e-3, 0.07e-3, 0.09e-3}) {
      for (bool shortcut : {false, true}) {
        Pose pa = synth::make_pose(Vec3(0, 0, lift) + s * m), pb;
        ContactPatch patch =
            synth::make_patch(Vec3(0, 0, -1), Vec3::UnitX(), Vec3::Zero(), cell, N, A.face_tris, B.face_tris);
        DepthScratch scratch;
        scratch.reserve(N);
        ForceOptions opt;
        opt.shortcut = shortcut;
        const DepthGradient g = compute_depth_gradient(A.model, pa, B.model, pb, patch, opt, scratch);
        ASSERT_TRUE(g.covered);
        const double ds = amp * std::cos(kPi * s / lam) * (s > 0 ? 1 : -1);
        // grad (u = x, v = n x u = -y) against ds m.
        const Eigen::Vector2d want(ds * m.x(), -ds * m.y());
        const Eigen::Vector2d got(g.grad[0], g.grad[1]);
        const Eigen::Vector2d central((g.delta_at[1] - g.delta_at[2]) / (2 * g.lin_step),
                                      (g.delta_at[3] - g.delta_at[4]) / (2 * g.lin_step));
        worst_new = std::max(worst_new, (got - want).norm() / amp);
        worst_central = std::max(worst_central, (central - want).norm() / amp);
        EXPECT_LT((got - want).norm(), 0.1 * amp)
            << "s " << s << " lift " << lift << " shortcut " << shortcut << " grad " << got.transpose() << " want "
            << want.transpose() << " central " << central.transpose();
      }
    }
  }
  // Not vacuous: Eq. 7's central difference is far off at these offsets.
  EXPECT_GT(worst_central, 0.5);
  std::printf(
      "nested gratings within one texel of the kink: worst |grad - closed form| %.3f of 2 a pi / lambda "
      "(central differences: %.3f)\n",
      worst_new, worst_central);
}

}  // namespace
}  // namespace hrt
