// Contact clustering and patch geometry on synthetic box
// models: separated regions -> separate patches, touching pieces -> one
// patch, sharp edges split by the normal angle, n from A into B, the
// triangle lists face each other, the window covers the patch with its origin
// on a lattice fixed to B, u continuous across frames, patch identity.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "contact/scratch.h"
#include "hrt/scene.h"
#include "test_contact_models.h"

using hrt::ContactPatch;
using hrt::Pose;
using hrt::Scene;
using hrt::SceneOptions;
using hrt::State;
using hrt::Vec3;
using hrt_test::Box;
using hrt_test::make_box;
using hrt_test::make_boxes;
using hrt_test::pose_at;

namespace {

SceneOptions opts(double margin = 1e-3, int resolution = 50) {
  SceneOptions o;
  o.collision.margin = margin;
  o.force.resolution = resolution;
  return o;
}

void run_contacts(const Scene& scene, State& st) {
  hrt::detect_pairs(scene, st);
  hrt::cluster_pairs(scene, st);
}

// (u, v) coordinates of a world point relative to B's origin.
Eigen::Vector2d uv_of(const ContactPatch& p, const Pose& pose_b, const Vec3& x) {
  const Vec3 d = x - pose_b.position;
  return {p.u.dot(d), p.v.dot(d)};
}

// Lattice coordinates of the window origin (must be integers).
Eigen::Vector2d lattice_coords(const ContactPatch& p, const Pose& pose_b) {
  return uv_of(p, pose_b, p.window.origin) / p.window.cell;
}

bool is_integer(double x, double eps = 1e-6) { return std::abs(x - std::round(x)) < eps; }

// A 4 x 2 cm bar (one piece) resting 0.5 mm above a plate: one patch.
struct BarOnPlate {
  hrt::Model bar = make_box(Vec3(-0.02, -0.01, -0.005), Vec3(0.02, 0.01, 0.005), "bar");
  hrt::Model plate = make_box(Vec3(-0.1, -0.1, -0.01), Vec3(0.1, 0.1, 0.0), "plate");
  Pose above(double gap = 0.5e-3, Vec3 xy = Vec3::Zero()) const { return pose_at(Vec3(xy.x(), xy.y(), 0.005 + gap)); }
};

}  // namespace

TEST(Contact, SinglePatchGeometry) {
  BarOnPlate m;
  Scene scene({&m.bar, &m.plate}, opts());
  State st(scene);
  st.poses[0] = m.above();
  run_contacts(scene, st);
  ASSERT_EQ(st.num_patches, 1);
  const ContactPatch& p = st.patches[0];
  EXPECT_EQ(p.object_b, 1);
  EXPECT_EQ(p.piece_pairs, 1);
  EXPECT_NEAR(p.n.z(), -1.0, 1e-9);  // from A (above) into B
  // Right-handed orthonormal basis.
  EXPECT_NEAR(p.u.dot(p.n), 0.0, 1e-12);
  EXPECT_NEAR(p.v.dot(p.n), 0.0, 1e-12);
  EXPECT_NEAR(p.u.norm(), 1.0, 1e-12);
  EXPECT_NEAR((p.u.cross(p.v) - p.n).norm(), 0.0, 1e-12);
  // Triangles: A's bottom face (2 triangles) faces +n, B's top face faces -n.
  ASSERT_EQ(p.tris_a.size(), 2u);
  ASSERT_EQ(p.tris_b.size(), 2u);
  for (uint32_t f : p.tris_a) EXPECT_GT(m.bar.face_normals[f].dot(p.n), 0.99);
  for (uint32_t f : p.tris_b) EXPECT_LT(m.plate.face_normals[f].dot(p.n), -0.99);
  EXPECT_EQ(p.window.resolution, 50);
}

// The window covers the domain D (the overlap of A's and B's triangles in
// (u, v)) with at least one texel of padding (the default FD step) on every
// side, and its origin lies on the lattice t_B + Z cell u + Z cell v.
TEST(Contact, WindowCoversPatchAndSnapsToBLattice) {
  BarOnPlate m;
  Scene scene({&m.bar, &m.plate}, opts());
  State st(scene);
  const Pose pb = pose_at(Vec3(0.0013, -0.0021, 0.0), Eigen::Quaterniond(Eigen::AngleAxisd(0.2, Vec3::UnitZ())));
  st.poses[1] = pb;
  st.poses[0] = pose_at(Vec3(0.0031, 0.0017, 0.0055), Eigen::Quaterniond(Eigen::AngleAxisd(0.5, Vec3::UnitZ())));
  run_contacts(scene, st);
  ASSERT_EQ(st.num_patches, 1);
  const ContactPatch& p = st.patches[0];
  const double cell = p.window.cell;
  const Eigen::Vector2d o = uv_of(p, pb, p.window.origin);
  const double side = p.window.resolution * cell;
  // Every corner of A's bottom face (the domain D here, A lies inside B).
  const Eigen::Isometry3d wa = st.poses[0].iso();
  for (double x : {-0.02, 0.02})
    for (double y : {-0.01, 0.01}) {
      const Eigen::Vector2d c = uv_of(p, pb, wa * Vec3(x, y, -0.005));
      EXPECT_GE(c.x() - o.x(), cell - 1e-12);
      EXPECT_GE(c.y() - o.y(), cell - 1e-12);
      EXPECT_LE(c.x() - o.x(), side - cell + 1e-12);
      EXPECT_LE(c.y() - o.y(), side - cell + 1e-12);
    }
  // Not absurdly large: the bar's diagonal 44.7 mm needs at most ~2^(1/4) x
  // (44.7 mm + 3 texels) / 50 per texel.
  EXPECT_LT(cell, 1.2 * std::sqrt(0.04 * 0.04 + 0.02 * 0.02) / 46);
  const Eigen::Vector2d lc = lattice_coords(p, pb);
  EXPECT_TRUE(is_integer(lc.x())) << lc.transpose();
  EXPECT_TRUE(is_integer(lc.y())) << lc.transpose();
  // The origin lies in the plane through the contact (heights are n . p).
  EXPECT_NEAR(p.n.dot(p.window.origin - 0.5 * (p.p_a + p.p_b)), 0.0, 1e-12);
}

// The padding holds for any placement (the texel-size ladder and the centring
// must not eat it) and for an explicit, larger translation step.
TEST(Contact, WindowPaddingCoversTheFiniteDifferenceSteps) {
  BarOnPlate m;
  for (int resolution : {16, 32, 50, 64, 128})
    for (double lin_step : {0.0, 3e-3}) {
      SceneOptions o = opts(1e-3, resolution);
      o.force.lin_step = lin_step;
      o.force.ang_step = lin_step > 0 ? 1e-4 : 0.0;  // small: the padding is lin_step's
      Scene scene({&m.bar, &m.plate}, o);
      State st(scene);
      std::mt19937 rng(5);
      std::uniform_real_distribution<double> U(-1, 1);
      for (int trial = 0; trial < 40; ++trial) {
        const Pose pb =
            pose_at(Vec3(U(rng), U(rng), 0) * 0.003, Eigen::Quaterniond(Eigen::AngleAxisd(U(rng), Vec3::UnitZ())));
        st.poses[1] = pb;
        st.poses[0] = pose_at(pb.position + Vec3(U(rng) * 0.03, U(rng) * 0.03, 0.0055),
                              Eigen::Quaterniond(Eigen::AngleAxisd(3 * U(rng), Vec3::UnitZ())));
        run_contacts(scene, st);
        ASSERT_EQ(st.num_patches, 1);
        const ContactPatch& p = st.patches[0];
        const double pad = lin_step > 0 ? lin_step : p.window.cell;
        const Eigen::Vector2d o2 = uv_of(p, pb, p.window.origin);
        const double side = p.window.resolution * p.window.cell;
        const Eigen::Isometry3d wa = st.poses[0].iso();
        for (double x : {-0.02, 0.02})
          for (double y : {-0.01, 0.01}) {
            const Eigen::Vector2d c = uv_of(p, pb, wa * Vec3(x, y, -0.005)) - o2;
            EXPECT_GE(c.minCoeff(), pad - 1e-12) << "trial " << trial;
            EXPECT_LE(c.maxCoeff(), side - pad + 1e-12) << "trial " << trial;
          }
      }
    }
}

// Hysteresis of the texel size: while A slides off B's edge and the domain
// shrinks by 15 % (from 40 to 34 mm: the required texel drops from 0.85 to
// 0.72 mm, across the ladder step at 2^-10.25 m = 0.82 mm, where the ladder
// alone would switch from 2^-10 m to 2^-10.25 m), a tracked patch keeps its
// texel size (and so its lattice); the window still covers D.
TEST(Contact, TexelSizeIsStableWhileTheDomainShrinks) {
  BarOnPlate m;
  hrt::Model small_plate = make_box(Vec3(-0.1, -0.1, -0.01), Vec3(0.0, 0.1, 0.0), "half_plate");
  Scene scene({&m.bar, &small_plate}, opts());
  State st(scene);
  double cell0 = 0;
  for (int k = 0; k <= 12; ++k) {
    // The bar's right end passes B's edge (x = 0) and moves on 0.5 mm per frame.
    const double x = -0.02 + k * 0.5e-3;
    st.poses[0] = m.above(0.5e-3, Vec3(x, 0, 0));
    run_contacts(scene, st);
    ASSERT_EQ(st.num_patches, 1);
    const ContactPatch& p = st.patches[0];
    if (k == 0) cell0 = p.window.cell;
    EXPECT_DOUBLE_EQ(p.window.cell, cell0) << "frame " << k;
    // D: the bar's footprint cut at x = 0.
    const Eigen::Vector2d o2 = uv_of(p, st.poses[1], p.window.origin);
    const double side = p.window.resolution * p.window.cell;
    const double hi_x = std::min(0.0, x + 0.02);
    for (double cx : {x - 0.02, hi_x})
      for (double cy : {-0.01, 0.01}) {
        const Eigen::Vector2d c = uv_of(p, st.poses[1], Vec3(cx, cy, 0)) - o2;
        EXPECT_GE(c.minCoeff(), p.window.cell - 1e-12);
        EXPECT_LE(c.maxCoeff(), side - p.window.cell + 1e-12);
      }
  }
  // Without the track (a fresh state) the final, smaller domain gets a finer texel.
  State fresh(scene);
  fresh.poses = st.poses;
  run_contacts(scene, fresh);
  EXPECT_LT(fresh.patches[0].window.cell, cell0);
}

// Moving A by a fraction of a texel keeps the texel centres where they are on
// B (the window may only shift by whole texels), so samples do not swim.
TEST(Contact, SamplesDoNotSwimWhenAMovesSlightly) {
  BarOnPlate m;
  Scene scene({&m.bar, &m.plate}, opts());
  State st(scene);
  const Pose pb = pose_at(Vec3(0.01, 0.0, 0.0), Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Vec3::UnitZ())));
  st.poses[1] = pb;
  st.poses[0] = m.above(0.5e-3, Vec3(0.004, 0.002, 0));
  run_contacts(scene, st);
  ASSERT_EQ(st.num_patches, 1);
  const ContactPatch p0 = st.patches[0];
  const uint64_t id0 = st.patch_ids[0];
  int shifted = 0;
  for (int step = 1; step <= 12; ++step) {
    // Slide by 0.37 texel per frame along a direction that is not a lattice axis.
    st.poses[0].position += 0.37 * p0.window.cell * Vec3(0.8, 0.6, 0.0);
    run_contacts(scene, st);
    ASSERT_EQ(st.num_patches, 1);
    const ContactPatch& p = st.patches[0];
    EXPECT_EQ(st.patch_ids[0], id0);
    EXPECT_DOUBLE_EQ(p.window.cell, p0.window.cell);
    EXPECT_NEAR((p.u - p0.u).norm(), 0.0, 1e-12);
    EXPECT_NEAR((p.n - p0.n).norm(), 0.0, 1e-12);
    // The origin moved by whole texels along u and v.
    const Eigen::Vector2d d = (uv_of(p, pb, p.window.origin) - uv_of(p0, pb, p0.window.origin)) / p.window.cell;
    EXPECT_TRUE(is_integer(d.x())) << d.transpose();
    EXPECT_TRUE(is_integer(d.y())) << d.transpose();
    if (d.norm() > 0.5) ++shifted;
  }
  // The window followed A (4.4 texels of travel), by whole texels.
  EXPECT_GT(shifted, 0);
}

// The lattice is fixed to B: moving B and A together rigidly moves the
// window origin (and u) with B.
TEST(Contact, LatticeFollowsB) {
  BarOnPlate m;
  Scene scene({&m.bar, &m.plate}, opts());
  State st(scene);
  st.poses[1] = pose_at(Vec3::Zero());
  st.poses[0] = m.above();
  run_contacts(scene, st);
  const ContactPatch p0 = st.patches[0];
  Eigen::Isometry3d G = Eigen::Isometry3d::Identity();
  G.linear() = Eigen::AngleAxisd(0.05, Vec3(0.2, 0.3, 1).normalized()).toRotationMatrix();
  G.translation() = Vec3(0.0012, -0.0007, 0.0003);
  st.poses[0] = hrt_test::moved(G, st.poses[0]);
  st.poses[1] = hrt_test::moved(G, st.poses[1]);
  run_contacts(scene, st);
  ASSERT_EQ(st.num_patches, 1);
  const ContactPatch& p = st.patches[0];
  EXPECT_NEAR((p.window.origin - G * p0.window.origin).norm(), 0.0, 1e-9);
  EXPECT_NEAR((p.u - G.linear() * p0.u).norm(), 0.0, 1e-9);
  EXPECT_DOUBLE_EQ(p.window.cell, p0.window.cell);
}

// A cube's bottom-left edge circles B's top-right edge at 0.5 mm, so the
// edge-edge normal n = -(sin phi, 0, cos phi) turns by 1 degree per frame.
// u stays continuous (the previous u, kept in B's frame, projected on the new
// plane). Control: the rule for a new patch (B's axis least aligned with n)
// picks x at phi = 0 and y for phi > 0, a 90 degree jump, so a state without
// tracking fails the continuity check.
TEST(Contact, TangentBasisIsContinuousAcrossFrames) {
  hrt::Model cube = make_box(Vec3(-0.01, -0.01, -0.01), Vec3(0.01, 0.01, 0.01), "cube");
  hrt::Model plate = make_box(Vec3(-0.1, -0.1, -0.01), Vec3(0.0, 0.1, 0.0), "plate");
  Scene scene({&cube, &plate}, opts(1e-3));
  State st(scene);
  const double r = 0.5e-3;
  Vec3 u_prev = Vec3::Zero();
  uint64_t id = 0;
  for (int k = 0; k <= 10; ++k) {
    const double phi = k * M_PI / 180.0;
    // Cube's bottom-left edge (x = -0.01, z = -0.01 in its frame) at (r sin phi, r cos phi).
    st.poses[0] = pose_at(Vec3(0.01 + r * std::sin(phi), 0.0, 0.01 + r * std::cos(phi)));
    run_contacts(scene, st);
    ASSERT_EQ(st.num_patches, 1) << k;
    const ContactPatch& p = st.patches[0];
    EXPECT_NEAR((p.n - Vec3(-std::sin(phi), 0, -std::cos(phi))).norm(), 0.0, 1e-6) << k;
    if (k == 0) {
      id = st.patch_ids[0];
    } else {
      EXPECT_EQ(st.patch_ids[0], id);
      // u turns by the step (1 degree), no more.
      EXPECT_GT(p.u.dot(u_prev), std::cos(1.01 * M_PI / 180.0)) << "frame " << k;
    }
    u_prev = p.u;
  }
  State fresh(scene);
  fresh.poses = st.poses;
  run_contacts(scene, fresh);
  ASSERT_EQ(fresh.num_patches, 1);
  EXPECT_LT(std::abs(fresh.patches[0].u.dot(u_prev)), 0.1);
}

// Two separated contact regions of one B are two patches: a bar bridging two
// separate blocks of one object.
TEST(Contact, SeparatedRegionsGiveSeparatePatches) {
  hrt::Model bar = make_box(Vec3(-0.05, -0.005, -0.005), Vec3(0.05, 0.005, 0.005), "bar");
  hrt::Model supports = make_boxes({Box{Vec3(-0.045, -0.01, -0.02), Vec3(-0.035, 0.01, 0.0)},
                                    Box{Vec3(0.035, -0.01, -0.02), Vec3(0.045, 0.01, 0.0)}},
                                   "supports");
  Scene scene({&bar, &supports}, opts());
  State st(scene);
  st.poses[0] = pose_at(Vec3(0, 0, 0.0054));
  run_contacts(scene, st);
  ASSERT_EQ(st.num_pairs, 2);
  ASSERT_EQ(st.num_patches, 2);
  // Each patch holds one pair, its window covers its own support only.
  for (int k = 0; k < 2; ++k) {
    const ContactPatch& p = st.patches[k];
    EXPECT_EQ(p.piece_pairs, 1);
    EXPECT_NEAR(p.n.z(), -1.0, 1e-9);
    EXPECT_LT(p.window.resolution * p.window.cell, 0.03);
  }
  EXPECT_LT(st.patches[0].p_b.x() * st.patches[1].p_b.x(), 0.0);  // one each side
  EXPECT_NE(st.patch_ids[0], st.patch_ids[1]);

  // The same with two feet on A and one plate as B.
  hrt::Model feet = make_boxes({Box{Vec3(-0.04, -0.005, -0.005), Vec3(-0.03, 0.005, 0.005)},
                                Box{Vec3(0.03, -0.005, -0.005), Vec3(0.04, 0.005, 0.005)}},
                               "feet");
  hrt::Model plate = make_box(Vec3(-0.1, -0.1, -0.01), Vec3(0.1, 0.1, 0.0), "plate");
  Scene scene2({&feet, &plate}, opts());
  State st2(scene2);
  st2.poses[0] = pose_at(Vec3(0, 0, 0.0054));
  run_contacts(scene2, st2);
  EXPECT_EQ(st2.num_patches, 2);
}

// A long bar (one piece) leaning on a small tower and on the floor it stands
// on: the tower and the floor are adjacent pieces and the normals differ by
// only 7 degrees, but the two contacts are 8 cm apart, more than the two B
// pieces' radii (5.1 + 1.2 cm): two patches, not one window spanning both.
TEST(Contact, DistantContactsOnAdjacentPiecesStaySeparate) {
  hrt::Model bar = make_box(Vec3(-0.06, -0.005, -0.002), Vec3(0.06, 0.005, 0.002), "bar");
  hrt::Model b = make_boxes({Box{Vec3(-0.1, -0.01, -0.005), Vec3(0.0, 0.01, 0.0)},   // floor
                             Box{Vec3(-0.1, -0.01, 0.0), Vec3(-0.09, 0.01, 0.01)}},  // tower on it
                            "floor_tower");
  Scene scene({&bar, &b}, opts(1e-3));
  State st(scene);
  const double theta = std::atan2(0.01, 0.08);  // descending towards +x
  const Eigen::Matrix3d R = Eigen::AngleAxisd(theta, Vec3::UnitY()).toRotationMatrix();
  const Vec3 corner(-0.01, 0.0, 0.0004);  // bar's bottom +x corner edge, 0.4 mm above the floor
  st.poses[0] = pose_at(corner - R * Vec3(0.06, 0.0, -0.002), Eigen::Quaterniond(R));
  run_contacts(scene, st);
  ASSERT_EQ(st.num_pairs, 2);
  ASSERT_EQ(st.num_patches, 2);
  EXPECT_GT(std::abs(st.patches[0].p_b.x() - st.patches[1].p_b.x()), 0.07);
  // Each window covers its own contact only (not the 8 cm between them).
  for (int k = 0; k < 2; ++k) EXPECT_LT(st.patches[k].window.resolution * st.patches[k].window.cell, 0.07);
}

// One contact region spanning two touching pieces of B (and two of A) is one patch.
TEST(Contact, TouchingPiecesFormOnePatch) {
  hrt::Model a = make_boxes(
      {Box{Vec3(-0.02, -0.01, -0.005), Vec3(0.0, 0.01, 0.005)}, Box{Vec3(0.0, -0.01, -0.005), Vec3(0.02, 0.01, 0.005)}},
      "a2");
  hrt::Model b = make_boxes(
      {Box{Vec3(-0.05, -0.05, -0.01), Vec3(0.003, 0.05, 0.0)}, Box{Vec3(0.003, -0.05, -0.01), Vec3(0.05, 0.05, 0.0)}},
      "b2");
  Scene scene({&a, &b}, opts());
  State st(scene);
  st.poses[0] = pose_at(Vec3(0, 0, 0.0055));
  run_contacts(scene, st);
  // A's left piece touches B's left piece only; A's right piece touches both.
  ASSERT_EQ(st.num_pairs, 3);
  ASSERT_EQ(st.num_patches, 1);
  const ContactPatch& p = st.patches[0];
  EXPECT_EQ(p.piece_pairs, 3);
  // Both bottoms of A (2 x 2 triangles) and both tops of B.
  EXPECT_EQ(p.tris_a.size(), 4u);
  EXPECT_EQ(p.tris_b.size(), 4u);
  EXPECT_TRUE(std::is_sorted(p.tris_a.begin(), p.tris_a.end()));
}

// Faces meeting at a sharp edge (a floor and a wall of B, touching pieces)
// touched by one cube: the normals differ by 90 degrees -> two patches.
TEST(Contact, SharpEdgeSplitsByNormalAngle) {
  hrt::Model cube = make_box(Vec3(-0.01, -0.01, -0.01), Vec3(0.01, 0.01, 0.01), "cube");
  hrt::Model corner = make_boxes({Box{Vec3(-0.05, -0.05, -0.01), Vec3(0.05, 0.05, 0.0)},   // floor
                                  Box{Vec3(0.0105, -0.05, 0.0), Vec3(0.03, 0.05, 0.05)}},  // wall at x = 10.5 mm
                                 "corner");
  Scene scene({&cube, &corner}, opts(1e-3));
  State st(scene);
  st.poses[0] = pose_at(Vec3(0, 0, 0.0104));  // 0.4 mm above the floor, 0.5 mm from the wall
  run_contacts(scene, st);
  ASSERT_EQ(st.num_patches, 2);
  Vec3 n0 = st.patches[0].n, n1 = st.patches[1].n;
  if (n0.z() > n1.z()) std::swap(n0, n1);
  EXPECT_NEAR(n0.z(), -1.0, 1e-9);  // into the floor
  EXPECT_NEAR(n1.x(), 1.0, 1e-9);   // into the wall
  // With a wide enough angle limit they merge (the criterion is what splits them).
  SceneOptions wide = opts(1e-3);
  wide.cluster.max_normal_angle_deg = 100;
  Scene scene2({&cube, &corner}, wide);
  State st2(scene2);
  st2.poses = st.poses;
  run_contacts(scene2, st2);
  EXPECT_EQ(st2.num_patches, 1);
}

// Beyond max_patches, the lightest patches are dropped and counted.
TEST(Contact, PatchCapKeepsTheHeaviest) {
  hrt::Model bar = make_box(Vec3(-0.05, -0.005, -0.005), Vec3(0.05, 0.005, 0.005), "bar");
  hrt::Model supports = make_boxes({Box{Vec3(-0.045, -0.01, -0.02), Vec3(-0.035, 0.01, 0.0)},
                                    Box{Vec3(0.035, -0.01, -0.0203), Vec3(0.045, 0.01, -0.0003)}},
                                   "supports");
  SceneOptions o = opts();
  o.cluster.max_patches = 1;
  Scene scene({&bar, &supports}, o);
  State st(scene);
  st.poses[0] = pose_at(Vec3(0, 0, 0.0054));  // gaps 0.4 mm (left) and 0.7 mm (right)
  run_contacts(scene, st);
  ASSERT_EQ(st.num_pairs, 2);
  ASSERT_EQ(st.num_patches, 1);
  EXPECT_LT(st.patches[0].p_b.x(), 0.0);  // the closer (heavier) left contact
  EXPECT_EQ(st.warnings.patches_dropped, 1u);
}

// A patch that disappears and comes back is a new patch (new id); the
// undersampling flag resets with it.
TEST(Contact, PatchIdentityEndsWhenContactBreaks) {
  BarOnPlate m;
  Scene scene({&m.bar, &m.plate}, opts());
  State st(scene);
  st.poses[0] = m.above(0.5e-3);
  run_contacts(scene, st);
  ASSERT_EQ(st.num_patches, 1);
  const uint64_t id0 = st.patch_ids[0];
  st.scratch->tracks[0].warned = true;
  st.poses[0] = m.above(0.6e-3);
  run_contacts(scene, st);
  ASSERT_EQ(st.num_patches, 1);
  EXPECT_EQ(st.patch_ids[0], id0);
  EXPECT_TRUE(st.scratch->tracks[0].warned);
  st.poses[0] = m.above(5e-3);  // lifted off
  run_contacts(scene, st);
  EXPECT_EQ(st.num_patches, 0);
  st.poses[0] = m.above(0.5e-3);
  run_contacts(scene, st);
  ASSERT_EQ(st.num_patches, 1);
  EXPECT_NE(st.patch_ids[0], id0);
  EXPECT_FALSE(st.scratch->tracks[0].warned);
}

// n is the weighted mean of the pair normals (A into B) with weights
// (tol - d) / tol: a pair entering the tolerance starts at weight ~0, so n
// turns continuously. A cube near a floor approaches a wall (pieces of B that
// touch; the angle limit is widened so they form one patch): n turns from
// -z towards +x smoothly, not by a 45 degree jump when the wall pair enters.
TEST(Contact, NormalIsContinuousWhenPairsEnter) {
  hrt::Model cube = make_box(Vec3(-0.01, -0.01, -0.01), Vec3(0.01, 0.01, 0.01), "cube");
  hrt::Model corner = make_boxes(
      {Box{Vec3(-0.05, -0.05, -0.01), Vec3(0.05, 0.05, 0.0)}, Box{Vec3(0.0105, -0.05, 0.0), Vec3(0.03, 0.05, 0.05)}},
      "corner");
  SceneOptions o = opts(1e-3);
  o.cluster.max_normal_angle_deg = 100;
  Scene scene({&cube, &corner}, o);
  State st(scene);
  Vec3 prev_n = Vec3::Zero();
  int max_pairs = 0;
  for (int k = 0; k <= 70; ++k) {
    const double wall_gap = 1.5e-3 - k * 2e-5;                  // 1.5 mm -> 0.1 mm in 20 um steps
    st.poses[0] = pose_at(Vec3(0.0005 - wall_gap, 0, 0.0103));  // floor gap 0.3 mm
    run_contacts(scene, st);
    ASSERT_EQ(st.num_patches, 1) << k;
    max_pairs = std::max(max_pairs, st.num_pairs);
    const Vec3& n = st.patches[0].n;
    if (!prev_n.isZero()) EXPECT_GT(n.dot(prev_n), std::cos(2.0 * M_PI / 180.0)) << "frame " << k;
    prev_n = n;
  }
  EXPECT_EQ(max_pairs, 2);      // the wall pair did enter
  EXPECT_GT(prev_n.x(), 0.35);  // and turned n towards the wall
}
