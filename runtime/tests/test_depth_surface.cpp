// The surface heights (HeightMode::surface, docs/bundle-format.md "Heights on
// a texel column") against the closed form of the synthetic sine grating,
// on columns tilted from the face normal (where the literal Eq. 8 has
// parallax: the atlas point of a coarse point lies straight above it, not on
// the tilted column).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <limits>
#include <vector>

#include "hrt/depth.h"
#include "synthetic.h"

namespace {

using hrt::Vec3;
constexpr double kPi = 3.14159265358979323846;

struct Column {
  double worst = 0;
  int covered = 0;
};

// Heights of the block's textured face along n over a 50 x 50 window, and
// the worst |height - closed form| over the covered texels.
Column compare(const hrt::synth::SynthBlock& B, const Vec3& n, hrt::HeightMode mode) {
  const double lam = B.spec.relief.wavelength;
  const hrt::ContactPatch patch =
      hrt::synth::make_patch(n, Vec3(1, 0.2, 0), Vec3(1e-4, -2e-4, 0), lam / 40, 50, {}, B.face_tris);
  const int N = patch.window.resolution;
  std::vector<double> h(static_cast<size_t>(N) * N);
  hrt::rasterize_heights(B.model, Eigen::Isometry3d::Identity(), B.face_tris, patch.n, patch.u, patch.v, patch.window,
                         0, false, h.data(), mode);
  Column out;
  for (int j = 0; j < N; ++j)
    for (int i = 0; i < N; ++i) {
      const double hk = h[static_cast<size_t>(j) * N + i];
      if (!std::isfinite(hk)) continue;
      ++out.covered;
      const Vec3 X =
          patch.window.origin + (i + 0.5) * patch.window.cell * patch.u + (j + 0.5) * patch.window.cell * patch.v;
      // The column X + t n meets the face where g(t) = p_z - z(p_x, p_y) = 0;
      // g' = n_z - grad z . n_xy < 0 here (checked by the bracket), so
      // bisection finds the one root; heights are relative to n . origin and
      // n . X = n . origin, so the height is t.
      auto g = [&](double t) {
        const Vec3 p = X + t * patch.n;
        return p.z() - B.spec.relief.z(p.x(), p.y());
      };
      double lo = -5e-3, hi = 5e-3;
      EXPECT_GT(g(lo), 0);
      EXPECT_LT(g(hi), 0);
      for (int it = 0; it < 200; ++it) {
        const double mid = 0.5 * (lo + hi);
        (g(mid) > 0 ? lo : hi) = mid;
      }
      out.worst = std::max(out.worst, std::abs(hk - 0.5 * (lo + hi)));
    }
  return out;
}

}  // namespace

TEST(SurfaceHeights, TiltedColumnsMatchTheClosedForm) {
  const double a = 1e-4, lam = 2e-3, phi = 23 * kPi / 180;
  const hrt::synth::SynthBlock B = hrt::synth::make_block(hrt::synth::sine_grating_spec(a, lam, phi));
  const double slope = a * 2 * kPi / lam;  // 0.31: the grating's largest slope
  for (double tilt_deg : {0.0, 12.0, 25.0, 37.0}) {
    const double tilt = tilt_deg * kPi / 180;
    // n from A (above) into the face: -z tilted about an axis 70 degrees from x.
    const Vec3 axis(std::cos(70 * kPi / 180), std::sin(70 * kPi / 180), 0);
    const Vec3 n = Eigen::AngleAxisd(tilt, axis) * Vec3(0, 0, -1);
    // Bound, fixed before measuring. The atlas's bilinear interpolation
    // errs by at most relief_interp_error (vertically); along the column that
    // is divided by |g'| >= cos(tilt) - slope sin(tilt). The converged point
    // lies within the lateral tolerance e of the column, which costs e times
    // the face's slope relative to n, at most tan(tilt + atan(slope)).
    // Heights in float: 1e-9 m at these coordinates (<= 1e-2 m).
    const double e = hrt::kLateralTolerance * std::min(lam / 40, B.atlas_texel);
    const double bound = hrt::synth::relief_interp_error(B) / (std::cos(tilt) - slope * std::sin(tilt)) +
                         e * std::tan(tilt + std::atan(slope)) + 1e-9;
    const Column s = compare(B, n, hrt::HeightMode::surface);
    const Column c = compare(B, n, hrt::HeightMode::coarse);
    std::printf("tilt %4.1f deg: surface worst %.3g m, coarse (Eq. 8) worst %.3g m, bound %.3g m, covered %d / %d\n",
                tilt_deg, s.worst, c.worst, bound, s.covered, c.covered);
    EXPECT_LE(s.worst, bound) << "tilt " << tilt_deg;
    // The window lies inside the face: every texel is covered in both modes.
    EXPECT_EQ(s.covered, 50 * 50);
    EXPECT_EQ(c.covered, 50 * 50);
    // Not vacuous: tilted, the literal Eq. 8 errs by the parallax
    // a sin(tilt) times the slope, far beyond the bound.
    if (tilt_deg >= 12) EXPECT_GT(c.worst, 3 * bound) << "tilt " << tilt_deg;
  }
}
