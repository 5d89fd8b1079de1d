// The per-frame driver (Sec. 3.3): collision -> clustering -> texture force
// -> sums, end to end on synthetic boxes with an identity haptic texture
// (test_contact_models.h), where the exact answers are known: two flat
// surfaces overlapping by delta0 give delta = delta0, grad = (0, 0, 1, 0, 0, 0),
// F = k delta0 (-n) on A, no torque; B gets the opposite wrench about its
// own centre of mass, and the two wrenches balance about any point.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "hrt/scene.h"
#include "test_contact_models.h"

using hrt::Pose;
using hrt::Scene;
using hrt::SceneOptions;
using hrt::State;
using hrt::Vec3;
using hrt::Vec6;
using hrt_test::Box;
using hrt_test::make_box;
using hrt_test::make_boxes;
using hrt_test::pose_at;

namespace {

// Float32 atlas positions of 0.1 m objects: ~1e-8 m of rounding.
constexpr double kPosTol = 2e-8;

Eigen::Isometry3d random_motion(std::mt19937& rng) {
  std::normal_distribution<double> g(0, 1);
  Eigen::Isometry3d G = Eigen::Isometry3d::Identity();
  G.linear() = Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
  G.translation() = 0.1 * Vec3(g(rng), g(rng), g(rng));
  return G;
}

// The resultant of both wrenches about point p (must vanish).
Vec6 resultant_about(const Vec3& p, const Vec3& fa, const Vec3& ta, const Vec3& ca, const Vec3& fb, const Vec3& tb,
                     const Vec3& cb) {
  Vec6 r;
  r.head<3>() = fa + fb;
  r.tail<3>() = ta + (ca - p).cross(fa) + tb + (cb - p).cross(fb);
  return r;
}

}  // namespace

TEST(Frame, FlatOverlapGivesStiffnessTimesDepth) {
  hrt::Model a = hrt_test::probe_box();
  hrt::Model b = hrt_test::plate_box();
  SceneOptions o;
  o.collision.margin = 1e-3;
  Scene scene({&a, &b}, o);
  State st(scene);
  const double k = scene.options().force.stiffness;
  EXPECT_EQ(k, hrt::kDefaultStiffness);
  std::mt19937 rng(11);
  for (double delta0 : {0.1e-3, 0.35e-3}) {
    for (int trial = 0; trial < 3; ++trial) {
      const Eigen::Isometry3d G = random_motion(rng);
      st.poses[0] = hrt_test::moved(
          G, pose_at(Vec3(0.013, -0.007, 0.005 - delta0), Eigen::Quaterniond(Eigen::AngleAxisd(0.4, Vec3::UnitZ()))));
      st.poses[1] = hrt_test::moved(G, pose_at(Vec3::Zero()));
      hrt::frame(scene, st);
      ASSERT_EQ(st.num_patches, 1);
      const hrt::ContactPatch& p = st.patches[0];
      const Vec3 n_world = G.linear() * Vec3(0, 0, -1);
      EXPECT_NEAR((p.n - n_world).norm(), 0.0, 1e-9);
      EXPECT_TRUE(p.covered);
      EXPECT_NEAR(p.delta, delta0, kPosTol);
      EXPECT_NEAR(p.grad[2], 1.0, 1e-12);
      // Flat surfaces: no tangential slope.
      EXPECT_NEAR(p.grad[0], 0.0, 1e-6);
      EXPECT_NEAR(p.grad[1], 0.0, 1e-6);
      // Tilting A about u through c_A moves a patch point r = p - c_A along n
      // by theta v . r: d delta / d theta_u = v . (centre of D - c_A), which is
      // 0 here (D, A's footprint, lies straight below c_A) up to the texel
      // grid (the covered texels' extent is symmetric within one texel).
      const double cell = p.window.cell;
      for (int i : {3, 4, 5}) EXPECT_NEAR(p.grad[i], 0.0, cell) << i;
      // Eq. 5-6: F = -k delta n, on A; the net equals the single patch.
      EXPECT_NEAR((st.force - (-k * delta0) * n_world).norm(), 0.0, k * kPosTol + 1e-4 * k * delta0);
      EXPECT_NEAR(st.torque.norm(), 0.0, 2 * k * delta0 * cell);
      // B's wrench balances A's about any point.
      const Vec3 ca = st.poses[0].iso() * a.mass.center_of_mass;
      const Vec3 cb = st.poses[1].iso() * b.mass.center_of_mass;
      const Vec6 r = resultant_about(Vec3(0.3, -0.2, 0.1), st.force, st.torque, ca, st.wrench_b[1].head<3>(),
                                     st.wrench_b[1].tail<3>(), cb);
      EXPECT_NEAR(r.norm(), 0.0, 1e-9 * k);
      EXPECT_GE(st.timings.collision_us, 0.0);
      EXPECT_GE(st.timings.total_us, st.timings.collision_us);
    }
  }
}

// Inside the tolerance but not touching: a patch, delta < 0, no force
// (U = k max(delta, 0)^2 / 2).
TEST(Frame, GapInsideToleranceGivesNoForce) {
  hrt::Model a = hrt_test::probe_box();
  hrt::Model b = hrt_test::plate_box();
  SceneOptions o;
  o.collision.margin = 1e-3;
  Scene scene({&a, &b}, o);
  State st(scene);
  st.poses[0] = pose_at(Vec3(0, 0, 0.005 + 0.3e-3));
  hrt::frame(scene, st);
  ASSERT_EQ(st.num_patches, 1);
  EXPECT_NEAR(st.patches[0].delta, -0.3e-3, kPosTol);
  EXPECT_EQ(st.force.norm(), 0.0);
  EXPECT_EQ(st.torque.norm(), 0.0);
  EXPECT_EQ(st.wrench_b[1].norm(), 0.0);
}

// Two patches on two objects and on one object with two regions: forces
// add per patch, each B gets the opposite of its own patches, and the whole
// system balances.
TEST(Frame, WrenchesSumOverPatchesAndObjects) {
  hrt::Model bar = make_box(Vec3(-0.05, -0.005, -0.005), Vec3(0.05, 0.005, 0.005), "bar");
  hrt::Model supports = make_boxes({Box{Vec3(-0.045, -0.01, -0.02), Vec3(-0.035, 0.01, 0.0)},
                                    Box{Vec3(0.035, -0.01, -0.02), Vec3(0.045, 0.01, -0.0001)}},
                                   "supports");
  hrt::Model cube = make_box(Vec3(-0.005, -0.005, -0.005), Vec3(0.005, 0.005, 0.005), "cube");
  SceneOptions o;
  o.collision.margin = 1e-3;
  Scene scene({&bar, &supports, &cube}, o);
  State st(scene);
  const double d_left = 0.3e-3, d_right = 0.2e-3, d_top = 0.15e-3;
  st.poses[0] = pose_at(Vec3(0, 0, 0.005 - d_left));  // left support top at z = 0, right at -0.1 mm
  st.poses[1] = pose_at(Vec3::Zero());
  st.poses[2] = pose_at(Vec3(0.0, 0.0, 0.005 - d_left + 0.005 + 0.005 - d_top));  // cube on top of the bar
  hrt::frame(scene, st);
  ASSERT_EQ(st.num_patches, 3);
  const double k = scene.options().force.stiffness;
  const Vec3 expected_force = k * (d_left + d_right) * Vec3::UnitZ() - k * d_top * Vec3::UnitZ();
  EXPECT_NEAR((st.force - expected_force).norm(), 0.0, 3 * k * kPosTol);
  double sum_delta = 0;
  for (int i = 0; i < 3; ++i) sum_delta += st.patches[i].delta;
  EXPECT_NEAR(sum_delta, d_left + d_right + d_top, 3 * kPosTol);
  // Object 1 gets minus the two support patches' forces, object 2 minus the top one.
  EXPECT_NEAR((st.wrench_b[1].head<3>() + k * (d_left + d_right) * Vec3::UnitZ()).norm(), 0.0, 3 * k * kPosTol);
  EXPECT_NEAR((st.wrench_b[2].head<3>() - k * d_top * Vec3::UnitZ()).norm(), 0.0, 3 * k * kPosTol);
  // Balance of the whole system about an arbitrary point.
  const Vec3 p(0.01, 0.02, -0.03);
  Vec3 f = st.force, t = st.torque + (st.poses[0].iso() * bar.mass.center_of_mass - p).cross(st.force);
  for (int b = 1; b < 3; ++b) {
    const Vec3 cb = st.poses[b].iso() * scene.model(b).mass.center_of_mass;
    f += st.wrench_b[b].head<3>();
    t += st.wrench_b[b].tail<3>() + (cb - p).cross(st.wrench_b[b].head<3>());
  }
  EXPECT_NEAR(f.norm(), 0.0, 1e-9 * k);
  EXPECT_NEAR(t.norm(), 0.0, 1e-9 * k);
  // The supports' torque about their own centre is not zero (the bar presses
  // off-centre): the (c_A - c_B) x F term is exercised.
  EXPECT_GT(st.wrench_b[1].tail<3>().norm(), 1e-3 * k * d_left * 0.01);
}
