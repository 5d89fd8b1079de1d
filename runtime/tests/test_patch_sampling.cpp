// Per-patch grid resolution (ClusterOptions::auto_resolution):
// N grows until the grid texel is at most 1/4 of the bundles' shorter
// min_wavelength, capped by max_resolution; the depth buffers are reserved
// for the cap, so the clustering and force stages allocate nothing.
#include <gtest/gtest.h>

#include <algorithm>

#include "contact/scratch.h"
#include "hrt/depth.h"
#include "hrt/force.h"
#include "hrt/scene.h"
#include "synthetic.h"
#include "test_contact_models.h"
#include "test_io_writer.h"

namespace {

// The demo's kind of scene on the golden ridged box (real bundle: 40 x 30 mm
// top, min_wavelength 2.41 mm): upside down on itself, 1 mm off the nested
// position, 0.2 mm low.
void demo_scene(hrt::State& st) {
  st.poses[0] = hrt_test::pose_at(hrt::Vec3(0, 0.001, 0.0118), Eigen::Quaterniond(0, 1, 0, 0));
}

TEST(PatchSampling, AutoResolutionKeepsTheTexelBelowAQuarterWavelength) {
  const hrt::Model box = hrt::load_bundle(hrt_test::golden_dir() + "/ridged_box.hbundle");
  const double target = 0.25 * box.quality.min_wavelength;
  for (int budget : {64, 128, 512}) {
    hrt::SceneOptions o;
    o.cluster.auto_resolution = true;
    o.cluster.max_resolution = budget;
    hrt::Scene scene({&box, &box}, o);
    hrt::State st(scene);
    demo_scene(st);
    hrt::frame(scene, st);
    ASSERT_GE(st.num_patches, 1);
    bool any_raised = false;
    for (int k = 0; k < st.num_patches; ++k) {
      const hrt::Window& w = st.patches[static_cast<size_t>(k)].window;
      EXPECT_GE(w.resolution, o.force.resolution);
      EXPECT_LE(w.resolution, budget);
      // Either the texel meets the target or the budget is spent.
      EXPECT_TRUE(w.cell <= target || w.resolution == budget) << "N " << w.resolution << " cell " << w.cell;
      any_raised = any_raised || w.resolution > o.force.resolution;
    }
    EXPECT_TRUE(any_raised) << "the 40 mm window needs more than 50 texels of 0.6 mm";
    // No allocation in clustering, force and safety at the largest N
    // (collision is FCL's and allocates inside its narrow phase).
    hrt::detect_pairs(scene, st);
    const uint64_t before = hrt::synth::allocation_count();
    hrt::cluster_pairs(scene, st);
    hrt::compute_pair_overlaps(scene, st);
    for (int k = 0; k < st.num_patches; ++k) {
      hrt::ContactPatch& p = st.patches[static_cast<size_t>(k)];
      hrt::compute_patch_wrench(box, st.poses[0], box, st.poses[1], p, scene.options().force, st.scratch->depth);
      hrt::apply_patch_safety(scene, st, k);
    }
    EXPECT_EQ(hrt::synth::allocation_count(), before) << "budget " << budget;
  }
}

// Off (the default), every patch uses ForceOptions::resolution.
TEST(PatchSampling, OffByDefault) {
  const hrt::Model box = hrt::load_bundle(hrt_test::golden_dir() + "/ridged_box.hbundle");
  hrt::Scene scene({&box, &box});
  EXPECT_FALSE(scene.options().cluster.auto_resolution);
  hrt::State st(scene);
  demo_scene(st);
  hrt::frame(scene, st);
  ASSERT_GE(st.num_patches, 1);
  for (int k = 0; k < st.num_patches; ++k)
    EXPECT_EQ(st.patches[static_cast<size_t>(k)].window.resolution, hrt::kDefaultResolution);
}

TEST(PatchSampling, BudgetBelowTheResolutionIsRefused) {
  const hrt::Model box = hrt::load_bundle(hrt_test::golden_dir() + "/ridged_box.hbundle");
  hrt::SceneOptions o;
  o.cluster.auto_resolution = true;
  o.cluster.max_resolution = 32;  // below N = 50
  EXPECT_THROW(hrt::Scene({&box, &box}, o), std::invalid_argument);
}

}  // namespace
