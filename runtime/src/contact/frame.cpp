// The per-frame driver (paper Sec. 3.3): collision -> clustering -> texture
// force per patch (depth.h, Eq. 5-9) -> safety per patch -> net wrench on A,
// opposite wrenches on the Bs. Allocates nothing of its own and prints
// nothing.
//
// Safety (issue 8, "cause 6"): whatever the atlas heights say, a patch's
// force must be one the coarse geometry allows. After compute_patch_wrench,
// per patch, with the convex pieces' vertices placed by the poses (never
// FCL's normals or points, except as axes to test along):
//
//   For a piece pair i (A's piece P, B's piece Q, tolerance tol_i, unit axis
//   n_i = the pair's normal) and the patch normal n, with
//     a_lo, a_hi = min, max of n . x over P's vertices,
//     b_lo, b_hi = min, max of n . x over Q's vertices,
//     reach_i = a_hi - b_lo       (how far P reaches past Q's near side along n),
//     O_i = max over P of n_i . x - min over Q of n_i . x
//                                 (the pieces' overlap along n_i; = -distance_i
//                                  when FCL's answer is exact),
//     c_i = n . n_i:
//
//   * Bound (clamp). The full surfaces lie within displacement_outward of
//     their pieces, and tol_i >= the sum of both, so along any axis m with
//     m . n > 0 the grown pieces overlap by at most O_m + tol_i, and moving A
//     by t along -n lowers that overlap by t (m . n): the directional
//     penetration depth of the pair along n is at most
//       beta_i = min( (tol_i + O_i) / c_i   (axis n_i; only when c_i > 0),
//                     tol_i + reach_i )     (axis n itself).
//     The first is the (tolerance - signed distance) / cos(angle(n,
//     n_i)); the second keeps the bound finite when n_i is far from n. A
//     texel's A height comes from a point of a triangle of tris_a, i.e. of
//     A's surface near a piece that lists that triangle (a triangle listed
//     by one piece may reach into a neighbouring one: the map is
//     many-to-many), its B height likewise, and two pieces that are not a
//     pair are farther apart than their tolerance, so their surfaces cannot
//     overlap; hence
//     delta <= delta_bound = max(0, max of beta_i over the pairs of the
//     frame between a piece of A that lists one of the patch's A triangles
//     and a piece of B that lists one of its B triangles, and the patch's
//     own pairs). (Every part of a coarse triangle lies in one of the pieces
//     that list it: the map is made by clipping against each piece. Taking
//     only the patch's own pairs clamped a legitimate side contact of the
//     golden bumpy blob on the ridged box, whose A triangles reach into a
//     piece of another patch.)
//     A patch with delta > delta_bound is clamped: its force is
//     wrench_from_gradient(delta_bound, the same gradient).
//
//   * Refusal. n must agree with each of the patch's own pairs: A's piece
//     must lie on the -n side of its B piece up to their overlap. Refused
//     when, for some pair,
//       reach_i > (tol_i + O_i) / max(c_i, 1/2) + max(a_hi - a_lo, b_hi - b_lo) / 2,
//     i.e. A's piece reaches past B's near side by more than the pair's
//     overlap allows plus half the larger piece's extent along n: most of a
//     piece lies beyond the other along n, the signature of a normal that
//     points out of B (cause 6: a tool piece partly beside and partly above a
//     plate, its pair normal up, so the heights of its top faces were
//     compared with the plate's bottom: delta 14-33 mm). A legitimate contact
//     whose n is tilted by phi from the touching faces makes reach_i exceed
//     the overlap by at most about (width of P + width of Q) sin(phi), far
//     below half an extent that is itself about width sin(phi) + thickness,
//     for tilts up to some 20 degrees even for a flat, wide piece (the rasp,
//     160 x 20 x 6.8 mm). A non-finite delta or gradient is refused too.
//     A refused patch gives no force (its delta and gradient are kept for
//     diagnostics); sessions are to fade it out (a dropped patch is itself a
//     click).
//
// Both are counted per frame in Warnings (refused_patches, clamped_patches)
// and recorded per patch (ContactPatch::refused, clamped, delta_bound,
// delta_force).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

#include "collision/collision.h"
#include "hrt/depth.h"
#include "hrt/scene.h"

namespace hrt {

namespace {
using Clock = std::chrono::steady_clock;
double micros(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::micro>(b - a).count();
}

// The refusal carries a pair's overlap over to n with 1 / max(cos, 1/2): a
// pair normal more than 60 degrees from n allows twice its overlap.
constexpr double kJudgeCos = 0.5;
// A patch whose delta exceeds this many times the bound of its own pairs is
// refused (apply_patch_safety).
constexpr double kRefuseFactor = 2.0;

// Extents of a piece along a world direction: [lo, hi] of dir . x.
struct Extent {
  double lo, hi;
};
Extent piece_extent(const collision::ModelGeometry& g, int piece, const Eigen::Isometry3d& world_from_m,
                    const Vec3& dir, int* warm) {
  const Vec3 d = world_from_m.linear().transpose() * dir;
  const double off = dir.dot(world_from_m.translation());
  const double hi = collision::piece_support(g, piece, d, warm) + off;
  const double lo = -collision::piece_support(g, piece, -d, warm) + off;
  return {lo, hi};
}

// Overlap of pair p's pieces along its own axis n_p, from the vertices:
// max over P of n_p . x - min over Q of n_p . x.
double pair_axis_overlap(const collision::ModelGeometry& ga, const Eigen::Isometry3d& world_from_a,
                         const collision::ModelGeometry& gb, const Eigen::Isometry3d& world_from_b,
                         const PiecePair& p) {
  int wa = 0, wb = 0;
  const Extent fa = piece_extent(ga, p.piece_a, world_from_a, p.n, &wa);
  const Extent fb = piece_extent(gb, p.piece_b, world_from_b, p.n, &wb);
  return fa.hi - fb.lo;
}

// Refusal and bound of patch k (see the header comment). st.pair_overlap
// holds O_i of every pair.
void check_patch(const Scene& scene, State& st, int k, bool& refused, double& bound, double& bound_own) {
  const ContactPatch& patch = st.patches[static_cast<size_t>(k)];
  const Vec3& n = patch.n;
  const int b = patch.object_b;
  const collision::ModelGeometry& ga = scene.world().geometry(0);
  const collision::ModelGeometry& gb = scene.world().geometry(b);
  const Eigen::Isometry3d world_from_a = st.poses[0].iso();
  const Eigen::Isometry3d world_from_b = st.poses[static_cast<size_t>(b)].iso();
  const int first = st.patch_first_pair[static_cast<size_t>(k)];
  const int count = st.patch_pair_count[static_cast<size_t>(k)];
  refused = false;
  bound = 0.0;
  bound_own = 0.0;
  // The pieces that list the patch's triangles (marked with a fresh stamp).
  if (++st.safety_stamp == 0) {
    std::fill(st.safety_mark_a.begin(), st.safety_mark_a.end(), 0u);
    std::fill(st.safety_mark_b.begin(), st.safety_mark_b.end(), 0u);
    st.safety_stamp = 1;
  }
  const uint32_t stamp = st.safety_stamp;
  for (uint32_t f : patch.tris_a)
    for (int j = ga.face_piece_offset[f]; j < ga.face_piece_offset[f + 1]; ++j)
      st.safety_mark_a[static_cast<size_t>(ga.face_pieces[static_cast<size_t>(j)])] = stamp;
  for (uint32_t f : patch.tris_b)
    for (int j = gb.face_piece_offset[f]; j < gb.face_piece_offset[f + 1]; ++j)
      st.safety_mark_b[static_cast<size_t>(gb.face_pieces[static_cast<size_t>(j)])] = stamp;
  for (int i = 0; i < st.num_pairs; ++i) {
    const PiecePair& p = st.pairs[static_cast<size_t>(i)];
    if (p.object_b != b) continue;
    bool own = false;
    for (int s = 0; s < count && !own; ++s) own = st.pair_order[static_cast<size_t>(first + s)] == i;
    const bool listed = st.safety_mark_a[static_cast<size_t>(p.piece_a)] == stamp &&
                        st.safety_mark_b[static_cast<size_t>(p.piece_b)] == stamp;
    if (!own && !listed) continue;
    int wa = 0, wb = 0;
    const Extent ea = piece_extent(ga, p.piece_a, world_from_a, n, &wa);
    const Extent eb = piece_extent(gb, p.piece_b, world_from_b, n, &wb);
    const double reach = ea.hi - eb.lo;
    const double tol = p.tolerance;
    const double o = st.pair_overlap[static_cast<size_t>(i)];
    const double c = n.dot(p.n);
    const double along_pair = c > 0 ? (tol + o) / c : std::numeric_limits<double>::infinity();
    bound = std::max(bound, std::min(along_pair, tol + reach));
    // Refusal: only the patch's own pairs judge its n.
    if (!own) continue;
    bound_own = std::max(bound_own, std::min(along_pair, tol + reach));
    // The overlap the pair allows along n: its own overlap carried over to
    // n, at most doubled (whether n is within 60 degrees of n_i or not).
    const double allowed = (tol + o) / std::max(c, kJudgeCos);
    if (reach > allowed + 0.5 * std::max(ea.hi - ea.lo, eb.hi - eb.lo)) refused = true;
  }
}

}  // namespace

void compute_pair_overlaps(const Scene& scene, State& st) {
  const collision::ModelGeometry& ga = scene.world().geometry(0);
  const Eigen::Isometry3d world_from_a = st.poses[0].iso();
  for (int i = 0; i < st.num_pairs; ++i) {
    const PiecePair& p = st.pairs[static_cast<size_t>(i)];
    st.pair_overlap[static_cast<size_t>(i)] =
        pair_axis_overlap(ga, world_from_a, scene.world().geometry(p.object_b),
                          st.poses[static_cast<size_t>(p.object_b)].iso(), p);
  }
}

void apply_patch_safety(const Scene& scene, State& st, int k) {
  ContactPatch& patch = st.patches[static_cast<size_t>(k)];
  bool refused = false;
  double bound = 0.0, bound_own = 0.0;
  check_patch(scene, st, k, refused, bound, bound_own);
  // Heights far beyond what the patch's own piece pairs allow along n do not
  // belong to this contact: a patch whose n is edge-on to the surfaces in
  // contact (pieces of two plates face to face whose separating axis is a cut
  // face's normal, horizontal) rasterizes faces far apart along n (12.7 mm
  // where the pairs overlap by 0.3 mm: the gratings of
  // tests/test_fullsurface_depth.py, 165 N before this rule). Twice the own
  // pairs' bound leaves room for the triangles of a legitimate patch that
  // reach into other pieces' pairs (the clamp below handles those).
  if (patch.covered && std::isfinite(patch.delta) && patch.delta > kRefuseFactor * bound_own) refused = true;
  // No face of A's pieces faces n (or of B's faces -n) within 60 degrees: n
  // is edge-on to the surfaces, and no height field along it is this
  // contact's (cluster.cpp sets `facing`). Such a patch has no triangles and
  // so no force either way; refusing says why (the gratings' side pairs,
  // whose separating axes are cut-face normals 70-90 degrees off the plates').
  if (!patch.facing) refused = true;
  if (!std::isfinite(patch.delta) || !patch.grad.allFinite() || !patch.force.allFinite() ||
      !patch.torque.allFinite() || !std::isfinite(bound))
    refused = true;
  patch.delta_bound = std::isfinite(bound) ? bound : 0.0;
  patch.refused = refused;
  patch.clamped = false;
  patch.delta_force = patch.covered && std::isfinite(patch.delta) ? std::max(patch.delta, 0.0) : 0.0;
  if (refused) {
    patch.delta_force = 0.0;
    patch.force.setZero();
    patch.torque.setZero();
    ++st.warnings.refused_patches;
  } else if (patch.covered && patch.delta > bound) {
    patch.clamped = true;
    patch.delta_force = bound;
    wrench_from_gradient(patch, bound, patch.grad, scene.options().force.stiffness, patch.force, patch.torque);
    ++st.warnings.clamped_patches;
  }
}

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
  // O_i of every pair, for the safety checks (apply_patch_safety).
  compute_pair_overlaps(scene, st);
  if (st.depth_backend && st.num_patches > 0) {
    // All patches of the frame in one call (the GL backend tiles them).
    for (int k = 0; k < st.num_patches; ++k) {
      const ContactPatch& patch = st.patches[static_cast<size_t>(k)];
      DepthJob& job = st.depth_jobs[static_cast<size_t>(k)];
      job.a = &A;
      job.b = &scene.model(patch.object_b);
      job.pose_a = pose_a;
      job.pose_b = st.poses[static_cast<size_t>(patch.object_b)];
      job.patch = &patch;
    }
    st.depth_backend->evaluate(st.depth_jobs.data(), st.num_patches, scene.options().force, st.depth_results.data());
  }
  for (int k = 0; k < st.num_patches; ++k) {
    ContactPatch& patch = st.patches[static_cast<size_t>(k)];
    const int b = patch.object_b;
    const Model& B = scene.model(b);
    const Pose& pose_b = st.poses[static_cast<size_t>(b)];
    // The undersampling warning (Sec. 7.2) counts once per patch lifetime:
    // the flag lives in the patch's track (cluster_pairs keeps it across frames).
    if (st.depth_backend)
      apply_depth_gradient(A, B, patch, st.depth_results[static_cast<size_t>(k)], scene.options().force,
                           &st.warnings.depth, &st.tracks[static_cast<size_t>(k)].warned);
    else
      compute_patch_wrench(A, pose_a, B, pose_b, patch, scene.options().force, st.depth, &st.warnings.depth,
                           &st.tracks[static_cast<size_t>(k)].warned);

    apply_patch_safety(scene, st, k);

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
