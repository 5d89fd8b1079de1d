// The wrench is minus the gradient of the penetration energy
// U = k max(delta, 0)^2 / 2 (Eq. 3-5): checked against finite differences of
// delta (directional_depth, contacts frozen: n, u, v, window, triangles)
// under rigid motions of A along random world directions and about random
// axes through A's centre of mass, with steps a quarter and four times the
// runtime's own, in randomly rotated scenes with gratings at 23 degrees
// (axis-aligned cases hide frame mistakes).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>

#include "hrt/depth.h"
#include "hrt/force.h"
#include "synthetic.h"

namespace hrt {
namespace {

constexpr double kPi = 3.14159265358979323846;

Eigen::Quaterniond random_quat(std::mt19937& rng) {
  std::normal_distribution<double> g(0.0, 1.0);
  Eigen::Quaterniond q(g(rng), g(rng), g(rng), g(rng));
  return q.normalized();
}
Vec3 random_unit(std::mt19937& rng) {
  std::normal_distribution<double> g(0.0, 1.0);
  return Vec3(g(rng), g(rng), g(rng)).normalized();
}

struct EnergyScene {
  synth::SynthBlock A, B;
  Pose pa, pb;
  ContactPatch patch;
};

// B: sinusoidal grating (a = 0.1 mm, lambda = 2 mm) at 23 degrees, face up.
// A: the same grating, face down, on a gentle bump (curvature `bump`),
// offset by s along the ridge normal and lowered into B: its deepest points
// are near the bump's centre, so delta has an isolated maximum and is a
// smooth function of A's configuration.
EnergyScene make_scene(std::mt19937& rng, double s_over_lambda, double bump) {
  const double a = 1e-4, lam = 2e-3, phi = 23.0 * kPi / 180;
  const synth::BlockSpec sb = synth::sine_grating_spec(a, lam, phi);
  EnergyScene S;
  S.B = synth::make_block(sb);
  synth::BlockSpec sa = sb;
  sa.face_up = false;
  sa.thickness = 10e-3;
  sa.relief.bump = bump;
  S.A = synth::make_block(sa);
  const Vec3 m(std::cos(phi), std::sin(phi), 0);
  S.pa = synth::make_pose(Vec3(0, 0, 0.5 * a) + s_over_lambda * lam * m);
  S.pb = synth::make_pose(Vec3::Zero());
  S.patch = synth::make_patch(Vec3(0, 0, -1), Vec3::UnitX(), Vec3::Zero(), lam / 40, 50, S.A.face_tris, S.B.face_tris);
  Eigen::Isometry3d Q = Eigen::Isometry3d::Identity();
  Q.linear() = random_quat(rng).toRotationMatrix();
  Q.translation() = Vec3(0.01, -0.02, 0.03);
  synth::transform_scene(Q, S.pa, S.pb, S.patch);
  return S;
}

double depth_moved(const EnergyScene& S, const Eigen::Isometry3d& motion, DepthScratch& scratch) {
  bool cov = false;
  const double d = directional_depth(S.A.model, motion * S.pa.iso(), S.B.model, S.pb.iso(), S.patch, scratch, &cov);
  EXPECT_TRUE(cov);
  return d;
}

TEST(ForceEnergy, WrenchIsMinusGradientOfPenetrationEnergy) {
  std::mt19937 rng(2024);
  const double k = 1000.0, a = 1e-4, lam = 2e-3, bump = 300.0, kk = 2 * kPi / lam;
  for (bool shortcut : {false, true}) {
    for (int scene = 0; scene < 3; ++scene) {
      EnergyScene S = make_scene(rng, 0.12 + 0.1 * scene, bump);
      DepthScratch scratch;
      scratch.reserve(50);
      ForceOptions opt;
      opt.stiffness = k;
      opt.shortcut = shortcut;
      ContactPatch patch = S.patch;
      compute_patch_wrench(S.A.model, S.pa, S.B.model, S.pb, patch, opt, scratch);
      ASSERT_TRUE(patch.covered);
      ASSERT_GT(patch.delta, 0);
      const Vec3 c_a = S.pa.iso() * S.A.model.mass.center_of_mass;
      const double h = patch.window.cell;
      const double th = default_ang_step(patch, c_a);
      const double kd = k * patch.delta;
      // Not vacuous: a real tangential force and torque.
      const Vec3 Ft = patch.force - patch.force.dot(patch.n) * patch.n;
      ASSERT_GT(Ft.norm(), 0.1 * patch.force.norm());
      ASSERT_GT(patch.torque.norm(), 0.1 * patch.force.norm() * 1e-3);

      // Tolerances. delta is a max over texels of functions smooth in A's
      // configuration; the runtime's central difference and the independent
      // one each measure the slope of that max, and the slopes of
      // neighbouring texels that take turns as the maximum differ by at most
      // |hess h_A| * cell per unit of surface motion, hess h_A <= a k^2 + bump
      // (grating plus bump curvature): half of it on average over a step.
      // The 4x step adds the central difference's truncation
      // |delta'''| eps^2 / 6, |delta'''| <= a k^3. For translations this is
      // at most 5% of |F| (|grad delta| >= 1), and it is what we assert.
      // For rotations the same bound, with the surface moving |x - c_A| ~ 5 mm
      // per radian, is 15-45% of |T|: too loose to be useful. It is not
      // approached because the texels that compete for the maximum lie within
      // a fraction of a texel of the crest line (the 23 degree lattice
      // samples it densely): over 30 random scenes (s = 0.12 .. 0.41 lambda,
      // both modes) the largest error was 2.8% of |T| with full
      // re-rasterization and 3.8% with the shortcut (whose n-rotation is a
      // bilinear resampling). We assert 8% of |T|: a torque taken about the
      // contact point instead of c_A is off by |c_A - p| |F_t| > 100% of |T|,
      // one left in (u, v, n) coordinates by O(|T|).
      const double hess = a * kk * kk + bump;
      for (int dir = 0; dir < 4; ++dir) {
        const Vec3 e = random_unit(rng);
        for (double f : {0.25, 4.0}) {
          const double eps = f * h;
          Eigen::Isometry3d Tp = Eigen::Isometry3d::Identity(), Tm = Eigen::Isometry3d::Identity();
          Tp.translation() = eps * e;
          Tm.translation() = -eps * e;
          const double dd = (depth_moved(S, Tp, scratch) - depth_moved(S, Tm, scratch)) / (2 * eps);
          const double tol = kd * (hess * h / 2 + a * kk * kk * kk * eps * eps / 6);
          EXPECT_NEAR(patch.force.dot(e), -kd * dd, tol)
              << "shortcut " << shortcut << " scene " << scene << " translation " << dir << " step x" << f;
        }
      }
      for (int dir = 0; dir < 4; ++dir) {
        const Vec3 ax = random_unit(rng);
        for (double f : {0.25, 4.0}) {
          const double eps = f * th;
          auto rot = [&](double ang) {
            Eigen::Isometry3d M = Eigen::Isometry3d::Identity();
            M.linear() = Eigen::AngleAxisd(ang, ax).toRotationMatrix();
            M.translation() = c_a - M.linear() * c_a;
            return M;
          };
          const double dd = (depth_moved(S, rot(eps), scratch) - depth_moved(S, rot(-eps), scratch)) / (2 * eps);
          const double tol = 0.08 * patch.torque.norm();
          EXPECT_NEAR(patch.torque.dot(ax), -kd * dd, tol)
              << "shortcut " << shortcut << " scene " << scene << " rotation " << dir << " step x" << f;
        }
      }
    }
  }
}

}  // namespace
}  // namespace hrt
