// The per-frame driver (paper Sec. 3.3): collision -> clustering -> texture
// force per patch (depth.h, Eq. 5-9) -> net wrench on A, opposite wrenches on
// the Bs. Allocates nothing of its own and prints nothing.
#include <chrono>

#include "hrt/depth.h"
#include "hrt/scene.h"

namespace hrt {

namespace {
using Clock = std::chrono::steady_clock;
double micros(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::micro>(b - a).count();
}
}  // namespace

void frame(const Scene& scene, State& st) {
  const auto t0 = Clock::now();
  detect_pairs(scene, st);
  const auto t1 = Clock::now();
  cluster_pairs(scene, st);
  const auto t2 = Clock::now();

  const Model& A = scene.model(0);
  const Pose& pose_a = st.poses[0];
  const Vec3 c_a = pose_a.iso() * A.mass.center_of_mass;
  st.force.setZero();
  st.torque.setZero();
  for (Vec6& w : st.wrench_b) w.setZero();
  for (int k = 0; k < st.num_patches; ++k) {
    ContactPatch& patch = st.patches[static_cast<size_t>(k)];
    const int b = patch.object_b;
    const Model& B = scene.model(b);
    const Pose& pose_b = st.poses[static_cast<size_t>(b)];
    // The undersampling warning (Sec. 7.2) counts once per patch lifetime:
    // the flag lives in the patch's track (cluster_pairs keeps it across frames).
    compute_patch_wrench(A, pose_a, B, pose_b, patch, scene.options().force, st.depth, &st.warnings.depth,
                         &st.tracks[static_cast<size_t>(k)].warned);
    st.force += patch.force;
    st.torque += patch.torque;
    Vec3 fb, tb;
    wrench_on_b(patch.force, patch.torque, c_a, pose_b.iso() * B.mass.center_of_mass, fb, tb);
    st.wrench_b[static_cast<size_t>(b)].head<3>() += fb;
    st.wrench_b[static_cast<size_t>(b)].tail<3>() += tb;
  }
  const auto t3 = Clock::now();
  st.timings.collision_us = micros(t0, t1);
  st.timings.clustering_us = micros(t1, t2);
  st.timings.force_us = micros(t2, t3);
  st.timings.total_us = micros(t0, t3);
  ++st.frame_count;
}

}  // namespace hrt
