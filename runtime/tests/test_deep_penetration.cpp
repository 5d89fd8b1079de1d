// The deep fallback (src/contact/frame.cpp, "Deep fallback"): a probe
// deeper than its patches can be trusted keeps a force that pushes it out,
// the penalty U = k/2 O^2 of one piece pair along its remembered axis; its
// force and torque are -dU/d(translation, rotation about c_A), checked here
// against central differences of U computed from the pieces' vertices alone.
// Ordinary contacts get no fallback.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <string>

#include "contact/scratch.h"
#include "hrt/depth.h"
#include "hrt/scene.h"
#include "test_contact_models.h"

using hrt::Pose;
using hrt::Scene;
using hrt::SceneOptions;
using hrt::State;
using hrt::Vec3;
using hrt::Vec6;
using hrt_test::make_box;
using hrt_test::pose_at;

namespace {

// A 10 x 10 x 4 mm probe centred on its origin and a 200 x 200 x 6 mm plate
// whose top face is z = 0: a probe whose bottom is d deep has its shortest
// way out up while d < (4 + 6) / 2 = 5 mm, down beyond.
hrt::Model small_probe() { return make_box(Vec3(-0.005, -0.005, -0.002), Vec3(0.005, 0.005, 0.002), "a"); }
hrt::Model thin_plate() { return make_box(Vec3(-0.1, -0.1, -0.006), Vec3(0.1, 0.1, 0.0), "b"); }

SceneOptions options() {
  SceneOptions o;
  o.collision.margin = 1e-4;  // 0.1 mm: the boxes have no relief, tol = margin
  o.force.resolution = 16;
  return o;
}

// The overlap along `axis` of A's only piece at `pa` and B's at `pb`, from the
// models' vertices (independent of the runtime's support search).
double overlap_along(const hrt::Model& a, const Pose& pa, const hrt::Model& b, const Pose& pb, const Vec3& axis) {
  double hi = -std::numeric_limits<double>::infinity(), lo = std::numeric_limits<double>::infinity();
  for (const Vec3& x : a.pieces[0].vertices) hi = std::max(hi, axis.dot(pa.iso() * x));
  for (const Vec3& y : b.pieces[0].vertices) lo = std::min(lo, axis.dot(pb.iso() * y));
  return hi - lo;
}

// A's pose moved by the twist component i (0-2: translation along x, y, z;
// 3-5: rotation about x, y, z through A's centre of mass) by `step`.
Pose perturbed(const hrt::Model& a, const Pose& p, int i, double step) {
  Pose q = p;
  if (i < 3) {
    q.position[i] += step;
    return q;
  }
  const Vec3 c = p.iso() * a.mass.center_of_mass;
  const Eigen::Quaterniond r(Eigen::AngleAxisd(step, Vec3::Unit(i - 3)));
  q.rotation = (r * p.rotation).normalized();
  q.position = c + r * (p.position - c);
  return q;
}

// The fallback's wrench against the central differences of U = k/2 O^2
// (O from the vertices along the fallback's fixed axis), and frame()'s own
// O at the perturbed poses against the same vertices.
void expect_gradient_of_energy(const Scene& scene, State& st, const std::string& what) {
  const hrt::Model& a = scene.model(0);
  const hrt::Model& b = scene.model(1);
  const double k = scene.options().force.stiffness;
  ASSERT_TRUE(st.deep_active[1]) << what;
  const Vec3 axis = st.deep_axis[1];
  const Vec6 w = st.deep_wrench[1];
  const Pose pose = st.poses[0];
  const double o = overlap_along(a, pose, b, st.poses[1], axis);
  EXPECT_NEAR(st.deep_overlap[1], o, 1e-12) << what;
  const double steps[2] = {1e-6, 1e-5};  // m, rad
  for (int i = 0; i < 6; ++i) {
    const double h = steps[i / 3];
    const Pose plus = perturbed(a, pose, i, h), minus = perturbed(a, pose, i, -h);
    const double op = overlap_along(a, plus, b, st.poses[1], axis);
    const double om = overlap_along(a, minus, b, st.poses[1], axis);
    const double fd = -(0.5 * k * op * op - 0.5 * k * om * om) / (2 * h);
    // U is quadratic in a translation (O linear): exact up to rounding of
    // k O^2 / 2 (~1e-2 J x 1e-16) over 2e-6 m; in a rotation O is smooth away
    // from a change of support vertex: O(h^2) of k O |x - c| ~ 1e-7.
    EXPECT_NEAR(w[i], fd, 1e-6 * (1 + std::abs(fd))) << what << ", component " << i;
    // frame() at the perturbed poses: the pair keeps its axis, O matches.
    st.poses[0] = plus;
    hrt::frame(scene, st);
    ASSERT_TRUE(st.deep_active[1]) << what << ", component " << i;
    EXPECT_NEAR((st.deep_axis[1] - axis).norm(), 0.0, 1e-12) << what;
    EXPECT_NEAR(st.deep_overlap[1], op, 1e-12) << what << ", component " << i;
  }
  st.poses[0] = pose;
  hrt::frame(scene, st);
}

// A probe resting on the plate (0.5 mm deep), then 7 mm deep in one step:
// past the middle, its pair's normal turns to the plate's bottom (the
// texture force would push it through). The pair keeps the axis it had
// (into the plate from above, -z): the patch is replaced, the force is
// k O up, O = 7 mm along -z, and it is the negative gradient of k/2 O^2.
TEST(DeepFallback, FlippedPairKeepsItsAxisAndTheForceIsTheGradientOfItsEnergy) {
  hrt::Model a = small_probe();
  hrt::Model b = thin_plate();
  Scene scene({&a, &b}, options());
  const double k = scene.options().force.stiffness;
  for (const bool tilted : {false, true}) {
    const std::string what = tilted ? "tilted" : "face on";
    // A generic tilt makes the support a single vertex (a smooth O); face on,
    // the support is the bottom face and the force acts at its centre.
    const Eigen::Quaterniond q = tilted ? Eigen::Quaterniond(Eigen::AngleAxisd(0.2, Vec3(1, 0.5, 0.3).normalized()))
                                        : Eigen::Quaterniond::Identity();
    State st(scene);
    const double lift = tilted ? [&] {
      double lo = 1;
      for (const Vec3& x : a.pieces[0].vertices) lo = std::min(lo, (q * x).z());
      return -lo;
    }()
                               : 0.002;
    st.poses[0] = pose_at(Vec3(0.01, -0.02, lift - 0.5e-3), q);
    hrt::frame(scene, st);
    ASSERT_EQ(st.num_patches, 1) << what;
    EXPECT_EQ(st.num_deep, 0) << what;
    EXPECT_LT(st.patches[0].n.z(), -0.99) << what;  // into the plate from above
    ASSERT_GT(st.force.z(), 0.0) << what;
    const double depth = 7e-3;
    st.poses[0] = pose_at(Vec3(0.01, -0.02, lift - depth), q);
    hrt::frame(scene, st);
    ASSERT_EQ(st.num_pairs, 1) << what;
    EXPECT_GT(st.pairs[0].n.z(), 0.99) << what << ": the pieces' shortest way apart is now down";
    ASSERT_TRUE(st.scratch->pair_flipped[0]) << what;
    ASSERT_EQ(st.num_deep, 1) << what;
    EXPECT_NEAR((st.deep_axis[1] - (-Vec3::UnitZ())).norm(), 0.0, 1e-12) << what;
    EXPECT_NEAR(st.deep_overlap[1], depth, 1e-9) << what;
    for (int p = 0; p < st.num_patches; ++p) {
      EXPECT_TRUE(st.patches[static_cast<size_t>(p)].deep_replaced) << what;
      EXPECT_EQ(st.patches[static_cast<size_t>(p)].force.norm(), 0.0) << what;
    }
    EXPECT_EQ(st.force.norm(), 0.0) << what << ": the patches' sum no longer pushes the probe through";
    const Vec3 f = st.deep_wrench[1].head<3>(), t = st.deep_wrench[1].tail<3>();
    EXPECT_NEAR((f - k * depth * Vec3::UnitZ()).norm(), 0.0, 1e-9) << what;
    const Vec3 c = st.poses[0].iso() * a.mass.center_of_mass;
    EXPECT_NEAR((t - (st.deep_point[1] - c).cross(f)).norm(), 0.0, 1e-12) << what;
    if (!tilted) EXPECT_NEAR(t.norm(), 0.0, 1e-12) << what << ": the bottom face's centre is below c_A";
    EXPECT_EQ(st.warnings.deep_fallbacks, 1u) << what;
    EXPECT_EQ(st.warnings.deep_fallback_patches, static_cast<uint64_t>(st.num_patches)) << what;
    expect_gradient_of_energy(scene, st, what);
    // Back out past the middle: the pair's own normal agrees again, the
    // patch gives the force, no fallback.
    st.poses[0] = pose_at(Vec3(0.01, -0.02, lift - 2e-3), q);
    hrt::frame(scene, st);
    EXPECT_EQ(st.num_deep, 0) << what;
    EXPECT_GT(st.force.z(), 0.0) << what;
  }
}

// A contact that starts past the middle (the probe 1 mm above the plate in
// one frame, 7 mm deep in the next: it crossed more than half the plate in
// one frame) is judged from the side it came from: up. The same pose with
// no history is judged along the pieces' shortest way apart (down): that is
// a pose, not a motion, and the patch's own force stands.
TEST(DeepFallback, ContactThatStartsDeepIsJudgedFromTheSideTheProbeCameFrom) {
  hrt::Model a = small_probe();
  hrt::Model b = thin_plate();
  Scene scene({&a, &b}, options());
  const double k = scene.options().force.stiffness;
  State st(scene);
  st.poses[0] = pose_at(Vec3(0.0, 0.0, 0.002 + 1e-3));
  hrt::frame(scene, st);
  ASSERT_EQ(st.num_pairs, 0);
  st.poses[0] = pose_at(Vec3(0.0, 0.0, 0.002 - 7e-3));
  hrt::frame(scene, st);
  ASSERT_EQ(st.num_deep, 1);
  EXPECT_NEAR((st.deep_axis[1] + Vec3::UnitZ()).norm(), 0.0, 1e-12);
  EXPECT_NEAR((st.deep_wrench[1].head<3>() - k * 7e-3 * Vec3::UnitZ()).norm(), 0.0, 1e-9);
  expect_gradient_of_energy(scene, st, "started deep");

  State fresh(scene);
  fresh.poses[0] = st.poses[0];
  hrt::frame(scene, fresh);
  EXPECT_EQ(fresh.num_deep, 0);
  EXPECT_LT(fresh.force.z(), 0.0);  // 3 mm out through the bottom, the shorter way
}

// A refused patch whose pieces overlap beyond the deep threshold keeps their
// penalty (the probe box's bottom face heights corrupted 5 mm outward, as in
// PatchSafety.HeightsBeyondThePiecesAreClampedOrRefused, but 1.5 mm deep:
// beyond the 1 mm tolerance); 0.2 mm deep it gives no force, as before.
TEST(DeepFallback, RefusedDeepPatchKeepsThePiecesPenalty) {
  for (const double delta0 : {0.2e-3, 1.5e-3}) {
    hrt::Model a = hrt_test::probe_box();
    const int strip = 32;  // strip 0 of the atlas: box 0's bottom (-z) face
    for (int j = 0; j < a.atlas.height; ++j)
      for (int i = 0; i < strip; ++i) a.atlas.rgba[(static_cast<size_t>(j) * a.atlas.width + i) * 4 + 2] -= 5e-3f;
    hrt::prepare_surface_map(a);
    hrt::Model b = hrt_test::plate_box();
    SceneOptions o;
    o.collision.margin = 1e-3;
    Scene scene({&a, &b}, o);
    State st(scene);
    const double k = scene.options().force.stiffness;
    st.poses[0] = pose_at(Vec3(0.003, 0.002, 0.005 - delta0));
    hrt::frame(scene, st);
    ASSERT_EQ(st.num_patches, 1);
    const hrt::ContactPatch& p = st.patches[0];
    ASSERT_TRUE(p.refused) << delta0;
    EXPECT_EQ(p.force.norm(), 0.0);
    EXPECT_EQ(st.force.norm(), 0.0);
    if (delta0 < scene.tolerance(1)) {
      EXPECT_EQ(st.num_deep, 0);
      EXPECT_FALSE(p.deep_replaced);
      EXPECT_EQ(st.warnings.deep_fallbacks, 0u);
    } else {
      ASSERT_EQ(st.num_deep, 1);
      EXPECT_TRUE(p.deep_replaced);
      EXPECT_NEAR(st.deep_overlap[1], delta0, 1e-12);
      EXPECT_NEAR((st.deep_wrench[1].head<3>() - k * delta0 * Vec3::UnitZ()).norm(), 0.0, 1e-9);
      EXPECT_EQ(st.warnings.deep_fallbacks, 1u);
      EXPECT_EQ(st.warnings.deep_fallback_patches, 1u);
    }
  }
}

// Ordinary contacts (the flat boxes of the safety tests, overlapping by up
// to 0.8 mm at random placements, one State over all of them, and a slide
// along the plate) get no fallback and no replaced patch.
TEST(DeepFallback, OrdinaryContactsGetNone) {
  hrt::Model a = hrt_test::probe_box();
  hrt::Model b = hrt_test::plate_box();
  SceneOptions o;
  o.collision.margin = 1e-3;
  Scene scene({&a, &b}, o);
  State st(scene);
  std::mt19937 rng(11);
  std::normal_distribution<double> g(0, 1);
  for (double delta0 : {0.0, 0.1e-3, 0.8e-3}) {
    for (int trial = 0; trial < 4; ++trial) {
      Eigen::Isometry3d G = Eigen::Isometry3d::Identity();
      G.linear() = Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
      st.poses[0] = hrt_test::moved(G, pose_at(Vec3(0.013, -0.007, 0.005 - delta0)));
      st.poses[1] = hrt_test::moved(G, pose_at(Vec3::Zero()));
      hrt::frame(scene, st);
      EXPECT_EQ(st.num_deep, 0);
      for (int p = 0; p < st.num_patches; ++p) EXPECT_FALSE(st.patches[static_cast<size_t>(p)].deep_replaced);
    }
  }
  st.poses[1] = pose_at(Vec3::Zero());
  for (int i = 0; i <= 50; ++i) {
    st.poses[0] = pose_at(Vec3(-0.05 + 0.002 * i, 0.0, 0.005 - 0.5e-3));
    hrt::frame(scene, st);
    EXPECT_EQ(st.num_deep, 0);
    EXPECT_GT(st.force.z(), 0.0);
  }
  EXPECT_EQ(st.warnings.deep_fallbacks, 0u);
  EXPECT_EQ(st.warnings.deep_fallback_patches, 0u);
}

}  // namespace
