// The narrow phase of a frame's piece pairs and the texture force of its
// patches on a pool of threads (SceneOptions::threads,
// src/parallel/task_pool.h): every task runs once,
// the pool allocates nothing per run, a task's exception reaches the caller,
// and a frame gives bit for bit the same pairs, patches, forces and warnings on 1,
// 2 or 3 threads as the serial code (which thread or scratch buffer
// evaluates a patch must not matter).
#include <gtest/gtest.h>

#include <atomic>
#include <cstring>
#include <stdexcept>
#include <vector>

#include "contact/scratch.h"
#include "hrt/scene.h"
#include "parallel/task_pool.h"
#include "synthetic.h"
#include "test_contact_models.h"
#include "test_io_writer.h"

namespace {

TEST(TaskPool, RunsEveryTaskOnceOnTheNamedSlots) {
  for (int threads : {1, 2, 3, 8}) {
    hrt::TaskPool pool(threads);
    EXPECT_EQ(pool.threads(), threads);
    for (int count : {0, 1, 2, 5, 64, 1000}) {
      std::vector<std::atomic<int>> runs(static_cast<size_t>(count));
      std::atomic<int> bad_slot{0};
      auto fn = [&](int task, int slot) {
        runs[static_cast<size_t>(task)].fetch_add(1);
        if (slot < 0 || slot >= threads) bad_slot.fetch_add(1);
      };
      const uint64_t before = hrt::synth::allocation_count();
      pool.run(count, fn);
      EXPECT_EQ(hrt::synth::allocation_count(), before) << threads << " threads, " << count << " tasks";
      for (int k = 0; k < count; ++k) EXPECT_EQ(runs[static_cast<size_t>(k)].load(), 1) << k;
      EXPECT_EQ(bad_slot.load(), 0);
    }
  }
}

TEST(TaskPool, RethrowsTheFirstExceptionAfterAllTasksEnded) {
  hrt::TaskPool pool(3);
  std::atomic<int> ran{0};
  auto fn = [&](int task, int) {
    ran.fetch_add(1);
    if (task == 7) throw std::runtime_error("task 7");
  };
  EXPECT_THROW(pool.run(40, fn), std::runtime_error);
  EXPECT_EQ(ran.load(), 40);
  // The pool is usable afterwards.
  ran = 0;
  auto ok = [&](int, int) { ran.fetch_add(1); };
  pool.run(40, ok);
  EXPECT_EQ(ran.load(), 40);
}

bool same_bits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }

template <class M>
bool same_bits(const M& a, const M& b) {
  for (int i = 0; i < a.size(); ++i)
    if (!same_bits(a.data()[i], b.data()[i])) return false;
  return true;
}

// The golden ridged box (a real baked bundle: textured, curved edges) upside
// down on two copies of itself 45 mm apart, sliding and turning: frames of
// two and more patches (one per copy and more where the ridges nest), whose
// patches are shared between the threads, and over one copy only: frames
// of one patch, whose configurations are shared.
TEST(ParallelFrame, ThreadsGiveTheSerialResultBitForBit) {
  const hrt::Model box = hrt::load_bundle(hrt_test::golden_dir() + "/ridged_box.hbundle");
  std::vector<hrt::Pose> poses;
  for (int i = 0; i < 8; ++i) {
    const double a = 0.05 * i;
    poses.push_back(hrt_test::pose_at(
        hrt::Vec3(0.0225 + 0.0007 * i, 0.001 - 0.0003 * i, 0.0119 - 0.00002 * i),
        Eigen::Quaterniond(Eigen::AngleAxisd(a, hrt::Vec3::UnitZ())) * Eigen::Quaterniond(0, 1, 0, 0)));
  }
  for (int i = 0; i < 3; ++i)  // over the first box only: one patch, its configurations shared
    poses.push_back(hrt_test::pose_at(
        hrt::Vec3(-0.002 + 0.0011 * i, 0.001, 0.0118),
        Eigen::Quaterniond(Eigen::AngleAxisd(0.2 * i, hrt::Vec3::UnitZ())) * Eigen::Quaterniond(0, 1, 0, 0)));
  int most_patches = 0, single_patch_frames = 0;
  for (hrt::HeightMode mode : {hrt::HeightMode::surface, hrt::HeightMode::coarse, hrt::HeightMode::mesh}) {
    for (int threads : {2, 3}) {
      hrt::SceneOptions serial;
      serial.force.heights = mode;
      serial.threads = 1;
      hrt::SceneOptions par = serial;
      par.threads = threads;
      hrt::Scene scene1({&box, &box, &box}, serial);
      hrt::Scene scene2({&box, &box, &box}, par);
      hrt::State ref(scene1), st(scene2);
      EXPECT_EQ(ref.scratch->pool, nullptr);
      ASSERT_NE(st.scratch->pool, nullptr);
      ref.poses[2] = st.poses[2] = hrt_test::pose_at(hrt::Vec3(0.045, 0, 0));
      for (const hrt::Pose& p : poses) {
        ref.poses[0] = st.poses[0] = p;
        hrt::frame(scene1, ref);
        hrt::frame(scene2, st);
        ASSERT_EQ(ref.num_pairs, st.num_pairs);
        for (int k = 0; k < st.num_pairs; ++k) {
          const hrt::PiecePair& x = ref.pairs[static_cast<size_t>(k)];
          const hrt::PiecePair& y = st.pairs[static_cast<size_t>(k)];
          EXPECT_TRUE(x.object_b == y.object_b && x.piece_a == y.piece_a && x.piece_b == y.piece_b &&
                      same_bits(x.distance, y.distance) && same_bits(x.n, y.n) && same_bits(x.p_a, y.p_a))
              << "pair " << k;
        }
        ASSERT_EQ(ref.num_patches, st.num_patches);
        most_patches = std::max(most_patches, st.num_patches);
        single_patch_frames += st.num_patches == 1;
        EXPECT_TRUE(same_bits(ref.force, st.force) && same_bits(ref.torque, st.torque))
            << threads << " threads: " << ref.force.transpose() << " vs " << st.force.transpose();
        for (int b = 1; b < 3; ++b) EXPECT_TRUE(same_bits(ref.wrench_b[b], st.wrench_b[b]));
        for (int k = 0; k < st.num_patches; ++k) {
          const hrt::ContactPatch& x = ref.patches[static_cast<size_t>(k)];
          const hrt::ContactPatch& y = st.patches[static_cast<size_t>(k)];
          EXPECT_TRUE(same_bits(x.delta, y.delta) && same_bits(x.grad, y.grad) && same_bits(x.force, y.force) &&
                      same_bits(x.torque, y.torque) && x.refused == y.refused && x.clamped == y.clamped &&
                      x.contact_texels == y.contact_texels)
              << "patch " << k << ": delta " << x.delta << " vs " << y.delta;
        }
        EXPECT_EQ(ref.warnings.depth.uncovered_configurations, st.warnings.depth.uncovered_configurations);
        EXPECT_EQ(ref.warnings.depth.undersampled_patches, st.warnings.depth.undersampled_patches);
        EXPECT_EQ(ref.warnings.refused_patches, st.warnings.refused_patches);
      }
    }
  }
  EXPECT_GE(most_patches, 2) << "no frame had patches to share between threads";
  EXPECT_GE(single_patch_frames, 6) << "too few frames of one patch (configurations shared)";
}

}  // namespace
