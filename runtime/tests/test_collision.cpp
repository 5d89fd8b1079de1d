// Coarse collision detection (paper Sec. 6.1) on synthetic
// box models: pairs inside the tolerance and not beyond, distances and closest
// points against the analytic box-box distance, normals from A into B,
// overlap, rigid invariance, the broad phase against a brute-force sweep.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <set>
#include <tuple>

#include "collision/collision.h"
#include "hrt/scene.h"
#include "test_contact_models.h"

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

SceneOptions with_margin(double margin) {
  SceneOptions o;
  o.collision.margin = margin;
  return o;
}

// A unit-ish box (5 cm) above a plate, separated by `gap` along z.
struct TwoBoxes {
  hrt::Model a = make_box(Vec3(-0.025, -0.025, -0.025), Vec3(0.025, 0.025, 0.025), "a");
  hrt::Model b = make_box(Vec3(-0.1, -0.1, -0.02), Vec3(0.1, 0.1, 0.0), "b");
};

}  // namespace

TEST(Collision, ToleranceIsSumOfBoundsPlusMargin) {
  TwoBoxes m;
  m.a.quality.displacement_outward = 1e-4;
  m.a.quality.hull_deviation = 2e-5;
  m.b.quality.displacement_outward = 3e-4;
  m.b.quality.hull_deviation = 4e-5;
  Scene explicit_margin({&m.a, &m.b}, with_margin(5e-4));
  EXPECT_DOUBLE_EQ(explicit_margin.tolerance(1), 1e-4 + 2e-5 + 3e-4 + 4e-5 + 5e-4);
  // Automatic margin: 1e-3 x the smaller bbox diagonal.
  Scene auto_margin({&m.a, &m.b});
  const double diag = std::min(m.a.quality.bbox_diagonal, m.b.quality.bbox_diagonal);
  EXPECT_DOUBLE_EQ(auto_margin.tolerance(1), 1e-4 + 2e-5 + 3e-4 + 4e-5 + 1e-3 * diag);
}

TEST(Collision, RejectsBadScenes) {
  TwoBoxes m;
  EXPECT_THROW(Scene({&m.a}), std::invalid_argument);
  EXPECT_THROW(Scene({&m.a, nullptr}), std::invalid_argument);
  SceneOptions bad;
  bad.force.resolution = 2;
  EXPECT_THROW(Scene({&m.a, &m.b}, bad), std::invalid_argument);
  bad = SceneOptions{};
  bad.force.stiffness = -1;
  EXPECT_THROW(Scene({&m.a, &m.b}, bad), std::invalid_argument);
}

// The pair appears exactly while the gap is within the tolerance; distance,
// points and normal equal the analytic values for axis-aligned boxes.
TEST(Collision, PairWithinToleranceNotBeyond) {
  TwoBoxes m;
  const double tol = 1e-3;
  Scene scene({&m.a, &m.b}, with_margin(tol));
  State st(scene);
  for (double gap : {0.2e-3, 0.9e-3, 0.999e-3, 1.001e-3, 1.5e-3, 5e-3}) {
    st.poses[0] = pose_at(Vec3(0.01, -0.02, 0.025 + gap));
    st.poses[1] = pose_at(Vec3::Zero());
    hrt::detect_pairs(scene, st);
    if (gap <= tol) {
      ASSERT_EQ(st.num_pairs, 1) << "gap " << gap;
      const hrt::PiecePair& p = st.pairs[0];
      EXPECT_EQ(p.object_b, 1);
      EXPECT_NEAR(p.distance, gap, 1e-9);
      // Face-face: the closest points lie on A's bottom face and B's top face
      // (anywhere on the overlap of the two faces' footprints).
      EXPECT_NEAR(p.p_a.z(), gap, 1e-9);
      EXPECT_NEAR(p.p_b.z(), 0.0, 1e-9);
      EXPECT_NEAR((p.p_a - p.p_b).head<2>().norm(), 0.0, 1e-9);
      // From A (above) into B (below).
      EXPECT_NEAR(p.n.z(), -1.0, 1e-9);
    } else {
      EXPECT_EQ(st.num_pairs, 0) << "gap " << gap;
    }
  }
}

// Edge-on contact (A offset diagonally beyond B's corner): the analytic
// distance between axis-aligned boxes is the norm of the per-axis gaps, and
// the normal is that gap vector, normalised.
TEST(Collision, CornerDistanceAndNormal) {
  hrt::Model a = make_box(Vec3(-0.01, -0.01, -0.01), Vec3(0.01, 0.01, 0.01), "a");
  hrt::Model b = make_box(Vec3(0, 0, 0), Vec3(0.05, 0.05, 0.05), "b");
  Scene scene({&a, &b}, with_margin(2e-3));
  State st(scene);
  const Vec3 gaps(-0.6e-3, -0.8e-3, 0.3e-3);  // A beyond B's (0,0) edge in x and y, overlapping in z
  // A's max corner at (gx, gy) below B's min corner.
  st.poses[0] = pose_at(Vec3(-0.01 + gaps.x(), -0.01 + gaps.y(), 0.02));
  hrt::detect_pairs(scene, st);
  ASSERT_EQ(st.num_pairs, 1);
  const hrt::PiecePair& p = st.pairs[0];
  EXPECT_NEAR(p.distance, 1e-3, 1e-9);  // hypot(0.6, 0.8) mm
  EXPECT_NEAR(p.n.x(), 0.6, 1e-6);
  EXPECT_NEAR(p.n.y(), 0.8, 1e-6);
  EXPECT_NEAR(p.n.z(), 0.0, 1e-6);
}

TEST(Collision, OverlapGivesNegativeDistanceAndNormalIntoB) {
  TwoBoxes m;
  Scene scene({&m.a, &m.b}, with_margin(1e-3));
  State st(scene);
  const double depth = 4e-3;
  st.poses[0] = pose_at(Vec3(0.0, 0.03, 0.025 - depth));
  hrt::detect_pairs(scene, st);
  ASSERT_EQ(st.num_pairs, 1);
  const hrt::PiecePair& p = st.pairs[0];
  EXPECT_NEAR(p.distance, -depth, 1e-7);
  EXPECT_NEAR(p.n.z(), -1.0, 1e-6);
  // p_a is A's point deepest in B, p_b B's point deepest in A.
  EXPECT_NEAR(p.p_a.z() - p.p_b.z(), -depth, 1e-7);
}

TEST(Collision, TouchingGivesAPairWithAUsableNormal) {
  TwoBoxes m;
  Scene scene({&m.a, &m.b}, with_margin(1e-3));
  State st(scene);
  st.poses[0] = pose_at(Vec3(0.0, 0.0, 0.025));  // faces exactly touching
  hrt::detect_pairs(scene, st);
  ASSERT_EQ(st.num_pairs, 1);
  EXPECT_NEAR(st.pairs[0].distance, 0.0, 1e-9);
  EXPECT_NEAR(st.pairs[0].n.z(), -1.0, 1e-6);
}

// The same relative placement under a random global rigid motion gives the
// same distances and the normals rotated with it.
TEST(Collision, InvariantUnderGlobalRigidMotion) {
  TwoBoxes m;
  Scene scene({&m.a, &m.b}, with_margin(1e-3));
  State st(scene);
  const Pose pa = pose_at(Vec3(0.02, 0.01, 0.0255), Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Vec3::UnitZ())));
  const Pose pb = pose_at(Vec3::Zero());
  st.poses = {pa, pb};
  hrt::detect_pairs(scene, st);
  ASSERT_EQ(st.num_pairs, 1);
  const hrt::PiecePair ref = st.pairs[0];
  EXPECT_NEAR(ref.distance, 0.5e-3, 1e-9);

  std::mt19937 rng(7);
  std::normal_distribution<double> g(0, 1);
  for (int trial = 0; trial < 5; ++trial) {
    Eigen::Isometry3d G = Eigen::Isometry3d::Identity();
    G.linear() = Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
    G.translation() = Vec3(g(rng), g(rng), g(rng));
    st.poses = {hrt_test::moved(G, pa), hrt_test::moved(G, pb)};
    hrt::detect_pairs(scene, st);
    ASSERT_EQ(st.num_pairs, 1);
    EXPECT_NEAR(st.pairs[0].distance, ref.distance, 1e-9);
    EXPECT_NEAR((st.pairs[0].n - G.linear() * ref.n).norm(), 0.0, 1e-6);
  }
}

// Several Bs: pairs come per object, object-level culling does not lose any.
TEST(Collision, EveryOtherObjectIsChecked) {
  hrt::Model a = make_box(Vec3(-0.05, -0.01, -0.01), Vec3(0.05, 0.01, 0.01), "bar");
  hrt::Model b = make_box(Vec3(-0.01, -0.01, -0.01), Vec3(0.01, 0.01, 0.01), "cube");
  Scene scene({&a, &b, &b, &b}, with_margin(1e-3));
  State st(scene);
  st.poses[0] = pose_at(Vec3::Zero());
  st.poses[1] = pose_at(Vec3(-0.04, 0, -0.0205));  // under the left end, gap 0.5 mm
  st.poses[2] = pose_at(Vec3(0.04, 0, -0.0205));   // under the right end
  st.poses[3] = pose_at(Vec3(0.0, 0, -0.03));      // gap 10 mm: beyond
  hrt::detect_pairs(scene, st);
  ASSERT_EQ(st.num_pairs, 2);
  EXPECT_EQ(st.pairs[0].object_b, 1);
  EXPECT_EQ(st.pairs[1].object_b, 2);
}

// Broad phase (sphere culling + B's AABB tree + sphere bound) against a
// brute-force sweep over every piece pair, on multi-piece objects in random
// poses: the same set of pairs with the same distances.
TEST(Collision, BroadPhaseMatchesBruteForce) {
  std::mt19937 rng(2024);
  std::uniform_real_distribution<double> U(-1, 1);
  auto random_boxes = [&](int n, double spread) {
    std::vector<Box> boxes;
    for (int i = 0; i < n; ++i) {
      Vec3 c(U(rng) * spread, U(rng) * spread, U(rng) * spread);
      Vec3 h(0.004 + 0.006 * std::abs(U(rng)), 0.004 + 0.006 * std::abs(U(rng)), 0.004 + 0.006 * std::abs(U(rng)));
      boxes.push_back(Box{c - h, c + h});
    }
    return boxes;
  };
  hrt::Model a = make_boxes(random_boxes(12, 0.03), "a");
  hrt::Model b = make_boxes(random_boxes(40, 0.05), "b");
  const double tol = 2e-3;
  Scene scene({&a, &b}, with_margin(tol));
  State st(scene);
  const auto geom_a = hrt::collision::build_geometry(a, false);
  const auto geom_b = hrt::collision::build_geometry(b, false);
  int total_pairs = 0;
  for (int trial = 0; trial < 30; ++trial) {
    Eigen::Quaterniond q(U(rng), U(rng), U(rng), U(rng));
    st.poses[0] = pose_at(Vec3(U(rng), U(rng), U(rng)) * 0.04, q);
    st.poses[1] = pose_at(Vec3(U(rng), U(rng), U(rng)) * 0.01, Eigen::Quaterniond(U(rng), U(rng), U(rng), U(rng)));
    hrt::detect_pairs(scene, st);
    std::set<std::pair<int, int>> got;
    for (int i = 0; i < st.num_pairs; ++i) got.insert({st.pairs[i].piece_a, st.pairs[i].piece_b});
    ASSERT_EQ(got.size(), static_cast<size_t>(st.num_pairs)) << "duplicate pairs";

    const Eigen::Isometry3d b_from_a = st.poses[1].iso().inverse() * st.poses[0].iso();
    std::set<std::pair<int, int>> want;
    for (int pa = 0; pa < 12; ++pa)
      for (int pb = 0; pb < 40; ++pb) {
        double d;
        Vec3 p1, p2, n;
        bool fb;
        ASSERT_TRUE(hrt::collision::piece_distance(*geom_a, pa, b_from_a, *geom_b, pb, 1e-12, d, p1, p2, n, fb));
        if (d <= tol) want.insert({pa, pb});
      }
    EXPECT_EQ(got, want) << "trial " << trial;
    total_pairs += static_cast<int>(want.size());
  }
  // The sweep must actually exercise pairs (a test that finds none proves nothing).
  EXPECT_GT(total_pairs, 30);
}

// Adjacency: pieces that touch are adjacent, separated ones are not.
TEST(Collision, PieceAdjacency) {
  hrt::Model m = make_boxes({Box{Vec3(0, 0, 0), Vec3(0.01, 0.01, 0.01)},
                             Box{Vec3(0.01, 0, 0), Vec3(0.02, 0.01, 0.01)},   // shares a face with 0
                             Box{Vec3(0.05, 0, 0), Vec3(0.06, 0.01, 0.01)}},  // 3 cm away
                            "three");
  const auto g = hrt::collision::build_geometry(m, false);
  EXPECT_TRUE(g->adjacent(0, 1));
  EXPECT_TRUE(g->adjacent(1, 0));
  EXPECT_FALSE(g->adjacent(0, 2));
  EXPECT_FALSE(g->adjacent(1, 2));
  EXPECT_TRUE(g->adjacent(2, 2));
}
