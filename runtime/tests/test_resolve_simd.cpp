// The surface heights' vectorized fixed points (src/depth/resolve_simd.cpp,
// Google Highway) against the scalar loops they replaced (the reference,
// hrt::use_reference_heights / resolve_heights_reference): the same heights
// and seeds bit for bit, on every vector target this CPU runs (SSE4, AVX2,
// AVX-512 where present), for the patches real frames make on a baked
// bundle: the rasterization of both sides (with seeds for A), A's placement
// then moved as Eq. 7's configurations move it and further (several lookups
// per texel), both keep directions, with the other side's coverage; and
// whole frames' wrenches.
#include <gtest/gtest.h>

#include <hwy/targets.h>

#include <cmath>
#include <cstring>
#include <random>
#include <vector>

#include "depth/internal.h"
#include "hrt/depth.h"
#include "hrt/scene.h"
#include "test_contact_models.h"
#include "test_io_writer.h"

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

TEST(ResolveSimd, EqualsTheScalarReferenceBitForBitOnEveryTarget) {
  const hrt::Model box = hrt::load_bundle(hrt_test::golden_dir() + "/ridged_box.hbundle");
  ASSERT_TRUE(box.surface.ready);
  hrt::SceneOptions so;
  so.threads = 1;
  hrt::Scene scene({&box, &box}, so);
  hrt::State st(scene);
  st.poses[1] = hrt_test::pose_at(hrt::Vec3(0.0, 0, 0));
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  // Every target Highway compiled that this CPU runs.
  std::vector<int64_t> targets;
  for (int64_t bits = hwy::SupportedTargets(); bits != 0; bits &= bits - 1) targets.push_back(bits & -bits);
  ASSERT_FALSE(targets.empty());
  std::vector<std::string> seen;
  size_t compared = 0, resolved = 0, patches = 0, rastered = 0;
  for (int f = 0; f < 6; ++f) {
    const double a = 0.11 * f + 0.05;
    st.poses[0] = hrt_test::pose_at(hrt::Vec3(-0.002 + 0.0009 * f, 0.001 - 0.0004 * f, 0.0119 - 0.00002 * f),
                                    Eigen::Quaterniond(Eigen::AngleAxisd(a, hrt::Vec3::UnitZ())) *
                                        Eigen::Quaterniond(Eigen::AngleAxisd(0.03 * f, hrt::Vec3::UnitX())) *
                                        Eigen::Quaterniond(0, 1, 0, 0));
    hrt::frame(scene, st);
    for (int k = 0; k < st.num_patches; ++k) {
      const hrt::ContactPatch& p = st.patches[static_cast<size_t>(k)];
      if (p.tris_a.empty()) continue;
      ++patches;
      const int N = p.window.resolution, border = 2, S = N + 2 * border;
      const Eigen::Isometry3d TA = st.poses[0].iso();
      for (bool keep_max : {true, false}) {
        std::vector<double> h0(static_cast<size_t>(S) * S), other(static_cast<size_t>(N) * N);
        hrt::HeightSeeds seeds;
        seeds.reserve(S);
        hrt::use_reference_heights(true);
        hrt::rasterize_heights_seeded(box, TA, p.tris_a, p.n, p.u, p.v, p.window, border, keep_max, h0.data(), seeds);
        hrt::use_reference_heights(false);
        {  // the rasterization's fixed point (with seeds), and B's side without
          const Eigen::Isometry3d TB = st.poses[1].iso();
          std::vector<double> hb_ref(static_cast<size_t>(N) * N), hb(hb_ref.size()), h1(h0.size());
          hrt::use_reference_heights(true);
          hrt::rasterize_heights(box, TB, p.tris_b, p.n, p.u, p.v, p.window, 0, keep_max, hb_ref.data());
          hrt::use_reference_heights(false);
          for (int64_t t : targets) {
            hwy::SetSupportedTargetsForTest(t);
            hrt::HeightSeeds s1;
            s1.reserve(S);
            hrt::rasterize_heights_seeded(box, TA, p.tris_a, p.n, p.u, p.v, p.window, border, keep_max, h1.data(), s1);
            hrt::rasterize_heights(box, TB, p.tris_b, p.n, p.u, p.v, p.window, 0, keep_max, hb.data());
            const std::string name = hrt::resolve_heights_target();
            ASSERT_EQ(std::memcmp(h0.data(), h1.data(), h0.size() * sizeof(double)), 0) << name << " seeded heights";
            ASSERT_EQ(std::memcmp(hb_ref.data(), hb.data(), hb.size() * sizeof(double)), 0) << name << " B heights";
            for (size_t q = 0; q < h0.size(); ++q) {
              if (!std::isfinite(h0[q])) continue;
              ASSERT_EQ(std::memcmp(&seeds.a[2 * q], &s1.a[2 * q], 2 * sizeof(double)), 0) << name << " seed " << q;
              ASSERT_EQ(std::memcmp(&seeds.j[4 * q], &s1.j[4 * q], 4 * sizeof(float)), 0) << name << " seed " << q;
            }
            ++rastered;
          }
          hwy::SetSupportedTargetsForTest(0);
        }
        // The other side uncovered on a random quarter of the texels.
        for (double& o : other) o = U(rng) > 0.5 ? (keep_max ? kInf : -kInf) : 0.0;
        for (int m = 0; m < 6; ++m) {
          // Motions from a fraction of a texel to several (the configurations'
          // and beyond): rotations about A's centre and translations.
          const double s = 0.3 * (m + 1);
          const hrt::Vec3 axis = hrt::Vec3(U(rng), U(rng), U(rng)).normalized();
          Eigen::Isometry3d motion = Eigen::Isometry3d::Identity();
          const hrt::Vec3 c = TA * box.mass.center_of_mass;
          motion.translate(c);
          motion.rotate(Eigen::AngleAxisd(s * p.window.cell / 0.02, axis));
          motion.translate(-c);
          motion.pretranslate(s * p.window.cell * hrt::Vec3(U(rng), U(rng), U(rng)));
          const Eigen::Isometry3d T = motion * TA;
          std::vector<double> ref(static_cast<size_t>(N) * N), got(ref.size());
          const double* oth = m % 2 ? other.data() : nullptr;
          hrt::resolve_heights_reference(box, T, TA, p.n, p.u, p.v, p.window, keep_max, h0.data(), border, seeds,
                                         ref.data(), oth);
          for (int64_t t : targets) {
            hwy::SetSupportedTargetsForTest(t);
            const std::string name = hrt::resolve_heights_target();
            if (std::find(seen.begin(), seen.end(), name) == seen.end()) seen.push_back(name);
            std::fill(got.begin(), got.end(), 12345.0);
            hrt::resolve_heights(box, T, TA, p.n, p.u, p.v, p.window, keep_max, h0.data(), border, seeds, got.data(),
                                 oth);
            ASSERT_EQ(std::memcmp(ref.data(), got.data(), ref.size() * sizeof(double)), 0)
                << "target " << name << ", frame " << f << ", patch " << k << ", motion " << m;
            ++compared;
          }
          hwy::SetSupportedTargetsForTest(0);
          for (double h : ref) resolved += std::isfinite(h);
        }
      }
    }
  }
  std::string names;
  for (const std::string& n : seen) names += n + " ";
  std::printf("heights: %zu raster and %zu resolve comparisons over %zu patches, %zu texels resolved; targets %s\n",
              rastered, compared, patches, resolved, names.c_str());
  EXPECT_GE(patches, 4u);
  EXPECT_GE(resolved, 5000u);  // not vacuous: most texels converge
}

// The unusable-quad flags (SurfaceMap::quad_ok), read by the vector kernels
// as one 32-bit gather per lookup: with a random fifth of the quads made
// unusable (a pattern no neighbour predicts), heights and re-solved heights
// still equal the reference's on every target, and the flags change them.
TEST(ResolveSimd, UnusableQuadsAreReadAsTheReferenceReadsThem) {
  const hrt::Model box = hrt::load_bundle(hrt_test::golden_dir() + "/ridged_box.hbundle");
  hrt::Model holed = box;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  const size_t quads = static_cast<size_t>(holed.atlas.width) * holed.atlas.height;
  ASSERT_EQ(holed.surface.quad_ok.size(), quads + hrt::SurfaceMap::kQuadOkPadding);
  for (size_t q = 0; q < quads; ++q)
    if (U(rng) > 0.6) holed.surface.quad_ok[q] = 0;
  hrt::SceneOptions so;
  so.threads = 1;
  hrt::Scene scene({&box, &box}, so);
  hrt::State st(scene);
  st.poses[1] = hrt_test::pose_at(hrt::Vec3(0.0, 0, 0));
  st.poses[0] = hrt_test::pose_at(
      hrt::Vec3(-0.001, 0.0006, 0.0119),
      Eigen::Quaterniond(Eigen::AngleAxisd(0.27, hrt::Vec3::UnitZ())) * Eigen::Quaterniond(0, 1, 0, 0));
  hrt::frame(scene, st);
  std::vector<int64_t> targets;
  for (int64_t bits = hwy::SupportedTargets(); bits != 0; bits &= bits - 1) targets.push_back(bits & -bits);
  size_t changed = 0, compared = 0;
  for (int k = 0; k < st.num_patches; ++k) {
    const hrt::ContactPatch& p = st.patches[static_cast<size_t>(k)];
    if (p.tris_a.empty()) continue;
    const int N = p.window.resolution, border = 1, S = N + 2 * border;
    const Eigen::Isometry3d TA = st.poses[0].iso();
    Eigen::Isometry3d T = TA;
    T.pretranslate(0.4 * p.window.cell * p.u);
    std::vector<double> intact(static_cast<size_t>(S) * S), h0(intact.size()), h1(intact.size());
    std::vector<double> ref(static_cast<size_t>(N) * N), got(ref.size());
    hrt::HeightSeeds seeds, s1, s_intact;
    seeds.reserve(S), s1.reserve(S), s_intact.reserve(S);
    hrt::use_reference_heights(true);
    hrt::rasterize_heights_seeded(box, TA, p.tris_a, p.n, p.u, p.v, p.window, border, true, intact.data(), s_intact);
    hrt::rasterize_heights_seeded(holed, TA, p.tris_a, p.n, p.u, p.v, p.window, border, true, h0.data(), seeds);
    hrt::resolve_heights_reference(holed, T, TA, p.n, p.u, p.v, p.window, true, h0.data(), border, seeds, ref.data());
    hrt::use_reference_heights(false);
    for (size_t q = 0; q < h0.size(); ++q) changed += std::memcmp(&h0[q], &intact[q], sizeof(double)) != 0;
    for (int64_t t : targets) {
      hwy::SetSupportedTargetsForTest(t);
      const std::string name = hrt::resolve_heights_target();
      hrt::rasterize_heights_seeded(holed, TA, p.tris_a, p.n, p.u, p.v, p.window, border, true, h1.data(), s1);
      ASSERT_EQ(std::memcmp(h0.data(), h1.data(), h0.size() * sizeof(double)), 0) << name << " heights";
      std::fill(got.begin(), got.end(), 12345.0);
      hrt::resolve_heights(holed, T, TA, p.n, p.u, p.v, p.window, true, h0.data(), border, seeds, got.data());
      ASSERT_EQ(std::memcmp(ref.data(), got.data(), ref.size() * sizeof(double)), 0) << name << " re-solved";
      ++compared;
    }
    hwy::SetSupportedTargetsForTest(0);
  }
  EXPECT_GE(compared, 2u);
  EXPECT_GE(changed, 100u);  // the holes reach the heights: the flags are really read
}

// Whole frames (collision, patches, Eq. 7, the force model) with the
// vectorized loops and with the reference: the same wrench, bit for bit.
TEST(ResolveSimd, FramesEqualTheReferenceBitForBit) {
  const hrt::Model box = hrt::load_bundle(hrt_test::golden_dir() + "/ridged_box.hbundle");
  hrt::SceneOptions so;
  so.threads = 1;
  hrt::Scene scene({&box, &box}, so);
  hrt::State ref(scene), st(scene);
  int patches = 0;
  for (int f = 0; f < 8; ++f) {
    const hrt::Pose p = hrt_test::pose_at(
        hrt::Vec3(-0.002 + 0.0007 * f, 0.001 - 0.0003 * f, 0.0119 - 0.00002 * f),
        Eigen::Quaterniond(Eigen::AngleAxisd(0.07 * f, hrt::Vec3::UnitZ())) * Eigen::Quaterniond(0, 1, 0, 0));
    ref.poses[0] = st.poses[0] = p;
    hrt::use_reference_heights(true);
    hrt::frame(scene, ref);
    hrt::use_reference_heights(false);
    hrt::frame(scene, st);
    ASSERT_EQ(ref.num_patches, st.num_patches);
    patches += st.num_patches;
    EXPECT_EQ(std::memcmp(ref.force.data(), st.force.data(), sizeof(double) * 3), 0) << "frame " << f;
    EXPECT_EQ(std::memcmp(ref.torque.data(), st.torque.data(), sizeof(double) * 3), 0) << "frame " << f;
    for (int k = 0; k < st.num_patches; ++k) {
      const hrt::ContactPatch& x = ref.patches[static_cast<size_t>(k)];
      const hrt::ContactPatch& y = st.patches[static_cast<size_t>(k)];
      EXPECT_EQ(std::memcmp(&x.delta, &y.delta, sizeof(double)), 0) << "frame " << f << " patch " << k;
      EXPECT_EQ(std::memcmp(x.grad.data(), y.grad.data(), sizeof(double) * 6), 0) << "frame " << f << " patch " << k;
    }
  }
  EXPECT_GE(patches, 6);
}

}  // namespace
