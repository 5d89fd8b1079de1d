// The internal scratch of a State (hrt/scene.h): the buffers the stages of
// frame() reuse from one frame to the next, and what they carry over between
// frames (the patch tracks, the deep fallback's pair memory). Only the
// runtime and its tests read them, so they live behind State::scratch rather
// than in the public header. The State constructor (src/contact/scene.cpp)
// sizes every buffer here so that frame() allocates nothing of its own.
// Not installed.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include <Eigen/Geometry>

#include "hrt/depth.h"
#include "hrt/depth_backend.h"
#include "hrt/scene.h"
#include "parallel/task_pool.h"

namespace hrt {

// Identity of a patch across frames. After clustering, each new patch is
// matched greedily (closest first) to a patch of the previous frame on the
// same B whose normal is within max_normal_angle_deg and whose contact point
// on B is within track_radius_factor x its window side; a match keeps the id,
// the tangent u (projected onto the new plane), the texel size (hysteresis)
// and the once-per-lifetime warning flag; an unmatched patch gets a new id.
// Stored in B's object frame so that it follows B when B moves. After
// cluster_pairs, FrameScratch::tracks[k] is the track of State::patches[k].
struct PatchTrack {
  uint64_t id = 0;
  int object_b = -1;
  Vec3 p_b_local = Vec3::Zero();
  Vec3 n_local = Vec3::UnitZ();
  Vec3 u_local = Vec3::UnitX();
  double cell = 0.0;
  double side = 0.0;    // window side N * cell, m
  bool warned = false;  // undersampling warning counted for this patch's lifetime
};

struct FrameScratch {
  // The pairs of patch k are pair_order[patch_first_pair[k] ..
  // + patch_pair_count[k]) (capacity max_patches; pair_order per pair).
  std::vector<int> patch_first_pair;
  std::vector<int> patch_pair_count;
  std::vector<int> pair_order;  // pair indices grouped by patch

  // Previous frame's tracks, union-find, marks.
  std::vector<PatchTrack> tracks, next_tracks;
  int num_tracks = 0;
  uint64_t next_track_id = 1;
  std::vector<int> uf_parent;        // per pair (capacity of State::pairs)
  std::vector<double> pair_weight;   // per pair
  std::vector<double> pair_overlap;  // per pair: its pieces' overlap along its own n (safety checks)
  // Per pair (deep fallback, frame.cpp): the axis its penetration is judged
  // along (its n, or the remembered one when n flipped), the pieces' overlap
  // along it, whether it flipped; sized to State::pairs by frame().
  std::vector<Vec3> pair_axis;
  std::vector<double> pair_axis_overlap;
  std::vector<char> pair_flipped;
  std::vector<uint64_t> pair_key;  // (object, piece_a, piece_b)
  std::vector<int> pair_sort;      // pair indices sorted by key
  // The pairs of the last frame, sorted by key, with the axis each was judged
  // along, in B's frame (a pair present in consecutive frames keeps it when
  // its n turns by more than 90 degrees: the probe went past the middle of B's piece).
  std::vector<uint64_t> memory_key;
  std::vector<Vec3> memory_axis;
  int num_memory = 0;
  // Per object: A had no pair with it in the last frame, and A's pose in its
  // frame then (a contact that starts deep is judged by which side A came from).
  std::vector<char> free_last;
  std::vector<Pose> free_pose;
  std::vector<int> pair_cluster;  // per pair: cluster id
  std::vector<double> cluster_weight;
  std::vector<int> cluster_patch;  // cluster -> patch index, -1 when dropped
  std::vector<int> cluster_order;
  std::vector<int> candidates;
  std::vector<uint32_t> face_mark_a, face_mark_b;  // per coarse face: stamp of the last patch that took it
  uint32_t face_stamp = 0;
  std::vector<uint32_t> piece_mark_a, piece_mark_b;
  std::vector<int> piece_list_a, piece_list_b;         // unique pieces of one patch
  std::vector<uint32_t> safety_mark_a, safety_mark_b;  // per piece: stamp of the patch whose triangles it lists
  uint32_t safety_stamp = 0;
  std::vector<uint32_t> vertex_stamp_a, vertex_stamp_b;  // per coarse vertex: stamp of its cached projection
  std::vector<double> vertex_proj_a, vertex_proj_b;      // 3 per coarse vertex: (u, v) and height of one patch
  std::vector<double> tri_box_a, tri_box_b;              // 4 per triangle of one patch: its (u, v) box
  std::vector<char> track_taken;                         // per previous track, during matching
  std::vector<double> target_cell;                       // per object: auto-resolution texel target (0 = none)
  DepthScratch depth;
  // With State::depth_backend: the frame's patches handed to it at once.
  std::vector<DepthJob> depth_jobs;          // capacity max_patches
  std::vector<DepthGradient> depth_results;  // capacity max_patches
  // SceneOptions::threads > 1: the pool and one DepthScratch per pool thread
  // but the caller's (which uses `depth`), reserved like it.
  std::unique_ptr<TaskPool> pool;
  std::vector<DepthScratch> pool_depth;
  std::vector<int> pool_order;    // capacity max_patches: the patches, costliest first
  std::vector<double> pool_cost;  // capacity max_patches: their cost estimates
  // With the pool, detect_pairs' narrow phase: the piece pairs the box tests
  // passed, in the serial loop's order, and their results.
  struct NarrowJob {
    int b = 0, piece_a = 0, piece_b = 0;
    double tolerance = 0, gjk_tolerance = 0;
    bool ok = false, fallback = false;
    double d = 0;
    Vec3 p_a = Vec3::Zero(), p_b = Vec3::Zero(), n = Vec3::UnitZ();
  };
  std::vector<NarrowJob> narrow_jobs;
  std::vector<Eigen::Isometry3d> narrow_b_from_a;  // per object, this frame
  void resize_pair_scratch(size_t n);              // the per-pair scratch above, for n pairs
};

}  // namespace hrt
