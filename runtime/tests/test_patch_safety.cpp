// Safety of the per-patch force (rules at the top of
// src/contact/frame.cpp): whatever the atlas heights say, a patch gives the
// force of a depth the convex pieces allow (clamp to delta_bound), and a
// patch whose n disagrees with its pieces gives none (refusal). Ordinary
// contacts are neither clamped nor refused.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>

#include "contact/scratch.h"
#include "hrt/depth.h"
#include "hrt/force.h"
#include "hrt/scene.h"
#include "test_contact_models.h"
#include "test_io_writer.h"

using hrt::Pose;
using hrt::Scene;
using hrt::SceneOptions;
using hrt::State;
using hrt::Vec3;
using hrt_test::make_box;
using hrt_test::pose_at;

namespace {

// Float32 atlas positions of 0.1 m objects: ~1e-8 m of rounding (as in
// test_contact_frame.cpp).
constexpr double kPosTol = 2e-8;

Eigen::Quaterniond random_rotation(std::mt19937& rng) {
  std::normal_distribution<double> g(0, 1);
  return Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized();
}

// The patches of the last frame; `before` = the counters before it.
void expect_ordinary(const State& st, const hrt::Warnings& before, const std::string& what) {
  for (int k = 0; k < st.num_patches; ++k) {
    const hrt::ContactPatch& p = st.patches[static_cast<size_t>(k)];
    EXPECT_FALSE(p.refused) << what << ", patch " << k << " delta " << p.delta << " n " << p.n.transpose();
    EXPECT_FALSE(p.clamped) << what << ", patch " << k << " delta " << p.delta << " bound " << p.delta_bound;
    if (p.covered && p.delta > 0) EXPECT_EQ(p.delta_force, p.delta) << what;
    EXPECT_TRUE(p.force.allFinite() && p.torque.allFinite()) << what;
  }
  EXPECT_EQ(st.warnings.refused_patches, before.refused_patches) << what;
  EXPECT_EQ(st.warnings.clamped_patches, before.clamped_patches) << what;
}

// Flat boxes overlapping by delta0 at random placements (the scene of
// Frame.FlatOverlapGivesStiffnessTimesDepth): the exact delta is delta0, the
// pieces overlap by delta0 along n, so delta_bound = tol + delta0 (the
// geometric bound, with tol = the 1 mm margin: no relief) and delta is far
// below it.
TEST(PatchSafety, FlatContactsAreNeitherRefusedNorClamped) {
  hrt::Model a = hrt_test::probe_box();
  hrt::Model b = hrt_test::plate_box();
  SceneOptions o;
  o.collision.margin = 1e-3;
  Scene scene({&a, &b}, o);
  State st(scene);
  std::mt19937 rng(5);
  for (double delta0 : {0.0, 0.1e-3, 0.8e-3}) {
    for (int trial = 0; trial < 4; ++trial) {
      Eigen::Isometry3d G = Eigen::Isometry3d::Identity();
      G.linear() = random_rotation(rng).toRotationMatrix();
      st.poses[0] = hrt_test::moved(
          G, pose_at(Vec3(0.013, -0.007, 0.005 - delta0), Eigen::Quaterniond(Eigen::AngleAxisd(0.4, Vec3::UnitZ()))));
      st.poses[1] = hrt_test::moved(G, pose_at(Vec3::Zero()));
      const hrt::Warnings before = st.warnings;
      hrt::frame(scene, st);
      ASSERT_EQ(st.num_patches, 1);
      const hrt::ContactPatch& p = st.patches[0];
      EXPECT_NEAR(p.delta_bound, scene.tolerance(1) + delta0, 1e-9);
      expect_ordinary(st, before, "flat boxes, delta0 " + std::to_string(delta0));
    }
  }
}

// Golden bundles (hbake-baked, real pieces and atlases) pressed into one
// another: the demo's kind of scene (ridged box upside down on a ridged box,
// 1 mm off the nested position, 0.2 mm low) and every golden bundle pressed
// 1 mm (at the coarse level: the golden textures lie up to 1.5 mm inside) onto the ridged box at seeded random
// orientations. No patch may be refused or clamped.
TEST(PatchSafety, GoldenContactsAreNeitherRefusedNorClamped) {
  const std::string dir = hrt_test::golden_dir();
  const hrt::Model box = hrt::load_bundle(dir + "/ridged_box.hbundle");
  {
    Scene scene({&box, &box});
    State st(scene);
    st.poses[0] = pose_at(Vec3(0, 0.001, 0.0118), Eigen::Quaterniond(0, 1, 0, 0));  // 180 deg about x
    const hrt::Warnings before = st.warnings;
    hrt::frame(scene, st);
    ASSERT_GE(st.num_patches, 1);
    double dmax = 0;
    for (int k = 0; k < st.num_patches; ++k) dmax = std::max(dmax, st.patches[static_cast<size_t>(k)].delta);
    EXPECT_GT(dmax, 1e-4);
    expect_ordinary(st, before, "ridged box on ridged box");
  }
  double top_b = -1e9;
  for (const Vec3& x : box.vertices) top_b = std::max(top_b, x.z());
  std::mt19937 rng(8);
  int in_contact = 0, total = 0;
  for (const char* name : {"ridged_box", "bumpy_blob", "pebble"}) {
    const hrt::Model a = hrt::load_bundle(dir + "/" + name + ".hbundle");
    Scene scene({&a, &box});
    State st(scene);
    for (int trial = 0; trial < 8; ++trial) {
      const Eigen::Quaterniond q = random_rotation(rng);
      double low = 1e9;
      Vec3 c = Vec3::Zero();
      for (const Vec3& x : a.vertices) {
        low = std::min(low, (q * x).z());
        c += q * x;
      }
      c /= static_cast<double>(a.vertices.size());
      st.poses[0] = pose_at(Vec3(-c.x(), -c.y(), top_b - low - 1e-3), q);
      const hrt::Warnings before = st.warnings;
      hrt::frame(scene, st);
      ++total;
      for (int k = 0; k < st.num_patches; ++k)
        if (st.patches[static_cast<size_t>(k)].force.norm() > 0) {
          ++in_contact;
          break;
        }
      expect_ordinary(st, before, std::string(name) + " trial " + std::to_string(trial));
    }
  }
  EXPECT_GE(in_contact, total / 2);  // most of these poses are real contacts with a force
}

// Heights corrupted far outward: A's bottom face (the face in contact) has
// its atlas z lowered by 5 mm, so Eq. 9 reports delta0 + 5 mm. The pieces
// overlap by delta0 along n = -z, so the geometric bound is exactly
// tol + delta0 (tol = the 1 mm margin; no relief): the patch is clamped to
// it, its force is k (tol + delta0) up (the corrupted face is flat, so the
// gradient stays (0, 0, 1, ...)), and the counter says so.
// Heights beyond what the pieces allow: between the bound and twice the own
// pairs' bound they are clamped to the bound (the force of delta_bound);
// beyond that they are not this contact's and the patch is refused
// (frame.cpp, kRefuseFactor). The bound here is tol + delta0 = 1.2 mm (1 mm
// margin): a 1.5 mm corruption (delta 1.7 mm) is clamped, a 5 mm one
// (delta 5.2 mm) refused.
TEST(PatchSafety, HeightsBeyondThePiecesAreClampedOrRefused) {
  for (const float corrupt : {1.5e-3f, 5e-3f}) {
    hrt::Model a = hrt_test::probe_box();
    // Strip 0 of the atlas is box 0's bottom (-z) face (test_contact_models.h).
    const int strip = 32;
    for (int j = 0; j < a.atlas.height; ++j)
      for (int i = 0; i < strip; ++i) a.atlas.rgba[(static_cast<size_t>(j) * a.atlas.width + i) * 4 + 2] -= corrupt;
    hrt::prepare_surface_map(a);
    hrt::Model b = hrt_test::plate_box();
    SceneOptions o;
    o.collision.margin = 1e-3;
    Scene scene({&a, &b}, o);
    State st(scene);
    const double k = scene.options().force.stiffness;
    const double delta0 = 0.2e-3;
    st.poses[0] = pose_at(Vec3(0.003, 0.002, 0.005 - delta0));
    hrt::frame(scene, st);
    ASSERT_EQ(st.num_patches, 1);
    const hrt::ContactPatch& p = st.patches[0];
    ASSERT_TRUE(p.covered);
    EXPECT_NEAR(p.delta, delta0 + corrupt, 1e-6);  // what the corrupted heights say
    const double bound = scene.tolerance(1) + delta0;
    EXPECT_NEAR(p.delta_bound, bound, 1e-9);
    if (p.delta < 2 * bound) {
      EXPECT_TRUE(p.clamped);
      EXPECT_FALSE(p.refused);
      EXPECT_EQ(p.delta_force, p.delta_bound);
      Vec3 f_expected, t_expected;
      hrt::wrench_from_gradient(p, p.delta_bound, p.grad, k, f_expected, t_expected);
      EXPECT_NEAR((p.force - f_expected).norm(), 0.0, 1e-12);
      EXPECT_NEAR((p.torque - t_expected).norm(), 0.0, 1e-12);
      EXPECT_NEAR((st.force - k * bound * Vec3::UnitZ()).norm(), 0.0, k * kPosTol + 1e-4 * k * bound);
      EXPECT_EQ(st.warnings.clamped_patches, 1u);
      EXPECT_EQ(st.warnings.refused_patches, 0u);
    } else {
      EXPECT_TRUE(p.refused);
      EXPECT_EQ(p.delta_force, 0.0);
      EXPECT_EQ(st.force.norm(), 0.0);
      EXPECT_EQ(st.warnings.refused_patches, 1u);
    }
  }
}

// A deeply interpenetrating pose of the golden ridged boxes (A's coarse
// pieces sunk 8 mm into B's): wherever the heights put delta, the force is
// that of at most delta_bound, finite, and the counters match the patches.
TEST(PatchSafety, DeepInterpenetrationGivesABoundedFiniteForce) {
  const hrt::Model box = hrt::load_bundle(hrt_test::golden_dir() + "/ridged_box.hbundle");
  Scene scene({&box, &box});
  State st(scene);
  const double k = scene.options().force.stiffness;
  std::mt19937 rng(3);
  uint64_t clamped = 0, refused = 0;
  for (int trial = 0; trial < 6; ++trial) {
    st.poses[0] = pose_at(Vec3(0.002 * trial, 0.001, 0.004), random_rotation(rng));
    hrt::frame(scene, st);
    for (int kp = 0; kp < st.num_patches; ++kp) {
      const hrt::ContactPatch& p = st.patches[static_cast<size_t>(kp)];
      ASSERT_TRUE(std::isfinite(p.delta_bound));
      EXPECT_LE(p.delta_force, p.delta_bound);
      EXPECT_TRUE(p.force.allFinite() && p.torque.allFinite());
      // Eq. 5: |F| = k delta_force |(grad_u, grad_v, 1)|.
      EXPECT_NEAR(p.force.norm(), k * p.delta_force * p.grad.head<3>().norm(), 1e-9 * k);
      clamped += p.clamped;
      refused += p.refused;
    }
    EXPECT_TRUE(st.force.allFinite() && st.torque.allFinite());
  }
  EXPECT_EQ(st.warnings.clamped_patches, clamped);
  EXPECT_EQ(st.warnings.refused_patches, refused);
}

// A wrong-way normal (cause 6): the patch of A resting on the plate, as
// clustering made it, with n turned to point up out of the plate (+z, what a
// pair normal of a piece partly beside and partly above the plate produced),
// and the triangles that n selects (A's top, the plate's bottom), so that
// Eq. 9 compares A's top with the plate's bottom: delta = 10 mm + 10 mm -
// delta0. Along +z, A's piece (10 mm tall) lies wholly beyond the plate's
// near side (its bottom), by far more than the pieces' overlap allows: the
// patch is refused, gives no force, and the counter says so. The same patch
// with its own n is accepted.
TEST(PatchSafety, WrongWayNormalIsRefused) {
  hrt::Model a = hrt_test::probe_box();
  hrt::Model b = hrt_test::plate_box();
  SceneOptions o;
  o.collision.margin = 1e-3;
  Scene scene({&a, &b}, o);
  State st(scene);
  const double delta0 = 0.3e-3;
  st.poses[0] = pose_at(Vec3(0.01, 0.0, 0.005 - delta0));
  hrt::detect_pairs(scene, st);
  hrt::cluster_pairs(scene, st);
  hrt::compute_pair_overlaps(scene, st);
  ASSERT_EQ(st.num_patches, 1);
  hrt::ContactPatch& p = st.patches[0];
  // Its own n: accepted.
  hrt::compute_patch_wrench(a, st.poses[0], b, st.poses[1], p, scene.options().force, st.scratch->depth);
  hrt::apply_patch_safety(scene, st, 0);
  EXPECT_FALSE(p.refused);
  EXPECT_FALSE(p.clamped);
  EXPECT_NEAR(p.delta, delta0, kPosTol);
  // Turned the wrong way, with the triangles that n selects.
  p.n = Vec3::UnitZ();
  p.u = Vec3::UnitX();
  p.v = p.n.cross(p.u);
  p.tris_a.clear();
  p.tris_b.clear();
  for (uint32_t f = 0; f < a.faces.size(); ++f)
    if (a.face_normals[f].dot(p.n) > 0.2) p.tris_a.push_back(f);
  for (uint32_t f = 0; f < b.faces.size(); ++f)
    if (b.face_normals[f].dot(p.n) < -0.2) p.tris_b.push_back(f);
  const double cell = 1e-3;
  p.window.cell = cell;
  p.window.resolution = scene.options().force.resolution;
  p.window.origin = Vec3(0.01 - 25 * cell, -25 * cell, 0.0);
  hrt::compute_patch_wrench(a, st.poses[0], b, st.poses[1], p, scene.options().force, st.scratch->depth);
  ASSERT_TRUE(p.covered);
  EXPECT_NEAR(p.delta, 0.02 - delta0, 1e-6);  // A's top minus the plate's bottom
  ASSERT_GT(p.force.norm(), 1.0);             // 20 N into the plate before the check
  const uint64_t before = st.warnings.refused_patches;
  hrt::apply_patch_safety(scene, st, 0);
  EXPECT_TRUE(p.refused);
  EXPECT_EQ(p.force.norm(), 0.0);
  EXPECT_EQ(p.torque.norm(), 0.0);
  EXPECT_EQ(p.delta_force, 0.0);
  EXPECT_EQ(st.warnings.refused_patches, before + 1);
}

}  // namespace
