// The per-frame driver (paper Sec. 3.3): collision -> clustering -> texture
// force per patch (depth.h, Eq. 5-9) -> safety per patch -> net wrench on A,
// opposite wrenches on the Bs. Allocates nothing of its own and prints
// nothing.
//
// Safety: whatever the atlas heights say, a patch's
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
//
// Deep fallback. A patch's texture force is one height field along one n,
// and a probe driven deep into B (a scripted jump, a stiff coupling, a
// session that starts inside) leaves that model: its patch is refused
// (above), or it passes every check with n the wrong way: a pair's normal is
// its pieces' shortest way apart, which turns to B's far side once A's piece
// is past the middle of B's piece (a 10 mm jump into the 6 mm slab of the
// session tests: the texture force then pushes the probe through the slab).
// A probe must never be left deep with no force, nor pushed further in:
//
//   Per pair i an axis a_i (unit, world, from A into B) and the pieces'
//   overlap along it, O_i = max over P of a_i . x - min over Q of a_i . x:
//   a_i = n_i, except that
//   * a pair that was also a pair in the last frame keeps that frame's axis
//     (fixed in B's frame) when n_i turns by more than 90 degrees from it: it
//     "flipped" (A's piece went past the middle of B's); and
//   * a pair of a contact that starts deep (A had no pair with B in the last
//     frame) gets a_i = -n_i when, at A's pose of the last frame, the pieces
//     were apart along -n_i but not along n_i: A came in from B's other side
//     and crossed more than half of B's piece in one frame.
//   A flipped pair keeps its axis only while it is deep:
//     O_i > thr(A, B) = tol(A, B) + A.displacement_inward + B.displacement_inward
//   (each surface lies within hull_deviation + displacement_inward inside its
//   pieces, both in tol, so beyond thr the surfaces themselves overlap along a_i).
//
//   A patch is replaced (ContactPatch::deep_replaced: no force, delta_force 0)
//   when one of its pairs flipped, or when it was refused for its normal or
//   its depth (not for `facing` alone or a non-finite value) and one of its
//   pairs is deep. Object B gets a fallback when a patch of B was replaced,
//   or when B has deep pairs and no patch of B gives a force. The fallback is
//   the penalty of one pair, the deepest candidate j (the pairs of B's
//   replaced patches; all of B's pairs when no patch of B gives a force),
//   never a sum over pairs (fifty pairs of a decomposed tool in one slab are
//   one penetration, not fifty):
//     U = k/2 O_j^2   (a_j fixed in B's frame, k the scene's stiffness),
//     F = -k O_j a_j,   T = (x* - c_A) x F,
//   x* the centroid of A's piece's vertices at its support along a_j (A's
//   deepest point; the centre of the face when a face is the support). O_j
//   grows by exactly the distance A moves along a_j and turns with x*, so
//   (F, T) = -dU/d(translation, rotation about c_A) (checked against finite
//   differences of U in runtime/tests/test_deep_penetration.cpp): the force
//   pushes A out along -a_j (positive work as A leaves), and it is finite
//   (O_j is at most the two pieces' extent along a_j). Kept in State::deep_*
//   per object, not in State::force (hrt/scene.h); counted in
//   Warnings::deep_fallbacks and deep_fallback_patches.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>

#include "collision/collision.h"
#include "contact/scratch.h"
#include "hrt/depth.h"
#include "hrt/force.h"
#include "hrt/scene.h"
#include "parallel/task_pool.h"

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
// The pool's cost estimate of a patch: its grid's texels plus this many per
// face whose heights it rasterizes (a face covers some tens of texels of
// the scenes measured; only the order of the estimates matters).
constexpr double kTexelsPerFace = 20.0;

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

// Refusal and bound of patch k (see the header comment). The scratch's
// pair_overlap holds O_i of every pair.
void check_patch(const Scene& scene, State& st, int k, bool& refused, double& bound, double& bound_own) {
  FrameScratch& sc = *st.scratch;
  const ContactPatch& patch = st.patches[static_cast<size_t>(k)];
  const Vec3& n = patch.n;
  const int b = patch.object_b;
  const collision::ModelGeometry& ga = scene.world().geometry(0);
  const collision::ModelGeometry& gb = scene.world().geometry(b);
  const Eigen::Isometry3d world_from_a = st.poses[0].iso();
  const Eigen::Isometry3d world_from_b = st.poses[static_cast<size_t>(b)].iso();
  const int first = sc.patch_first_pair[static_cast<size_t>(k)];
  const int count = sc.patch_pair_count[static_cast<size_t>(k)];
  refused = false;
  bound = 0.0;
  bound_own = 0.0;
  // The pieces that list the patch's triangles (marked with a fresh stamp).
  if (++sc.safety_stamp == 0) {
    std::fill(sc.safety_mark_a.begin(), sc.safety_mark_a.end(), 0u);
    std::fill(sc.safety_mark_b.begin(), sc.safety_mark_b.end(), 0u);
    sc.safety_stamp = 1;
  }
  const uint32_t stamp = sc.safety_stamp;
  for (uint32_t f : patch.tris_a)
    for (int j = ga.face_piece_offset[f]; j < ga.face_piece_offset[f + 1]; ++j)
      sc.safety_mark_a[static_cast<size_t>(ga.face_pieces[static_cast<size_t>(j)])] = stamp;
  for (uint32_t f : patch.tris_b)
    for (int j = gb.face_piece_offset[f]; j < gb.face_piece_offset[f + 1]; ++j)
      sc.safety_mark_b[static_cast<size_t>(gb.face_pieces[static_cast<size_t>(j)])] = stamp;
  for (int i = 0; i < st.num_pairs; ++i) {
    const PiecePair& p = st.pairs[static_cast<size_t>(i)];
    if (p.object_b != b) continue;
    bool own = false;
    for (int s = 0; s < count && !own; ++s) own = sc.pair_order[static_cast<size_t>(first + s)] == i;
    const bool listed = sc.safety_mark_a[static_cast<size_t>(p.piece_a)] == stamp &&
                        sc.safety_mark_b[static_cast<size_t>(p.piece_b)] == stamp;
    if (!own && !listed) continue;
    int wa = 0, wb = 0;
    const Extent ea = piece_extent(ga, p.piece_a, world_from_a, n, &wa);
    const Extent eb = piece_extent(gb, p.piece_b, world_from_b, n, &wb);
    const double reach = ea.hi - eb.lo;
    const double tol = p.tolerance;
    const double o = sc.pair_overlap[static_cast<size_t>(i)];
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

// ---------------------------------------------------------------------------
// Deep fallback (see the header comment)
// ---------------------------------------------------------------------------

// Identity of a piece pair across frames: object (16 bits), A's piece and B's
// piece (24 bits each; a model with more pieces would only share memories).
uint64_t pair_key(const PiecePair& p) {
  return (static_cast<uint64_t>(p.object_b & 0xffff) << 48) | (static_cast<uint64_t>(p.piece_a & 0xffffff) << 24) |
         static_cast<uint64_t>(p.piece_b & 0xffffff);
}

// Overlap of A's piece pa (placed by world_from_a) and B's piece pb along `axis`.
double axis_overlap(const collision::ModelGeometry& ga, int pa, const Eigen::Isometry3d& world_from_a,
                    const collision::ModelGeometry& gb, int pb, const Eigen::Isometry3d& world_from_b,
                    const Vec3& axis) {
  int wa = 0, wb = 0;
  return piece_extent(ga, pa, world_from_a, axis, &wa).hi - piece_extent(gb, pb, world_from_b, axis, &wb).lo;
}

double deep_threshold(const Scene& scene, int b) {
  return scene.tolerance(b) + scene.model(0).quality.displacement_inward + scene.model(b).quality.displacement_inward;
}

// A's deepest point along `axis` (world): the centroid of piece pa's vertices
// within a hair of its support, so that a face-on support acts at the face's
// centre (a corner would give the penalty a torque of its own).
Vec3 deepest_point(const collision::ModelGeometry& ga, int pa, const Eigen::Isometry3d& world_from_a,
                   const Vec3& axis) {
  const std::vector<Vec3>& v = ga.model->pieces[static_cast<size_t>(pa)].vertices;
  const Vec3 d = world_from_a.linear().transpose() * axis;
  double hi = -std::numeric_limits<double>::infinity();
  for (const Vec3& x : v) hi = std::max(hi, d.dot(x));
  const double eps = 1e-9 * (1.0 + ga.piece_bounds[static_cast<size_t>(pa)].radius) +
                     1e-7 * ga.piece_bounds[static_cast<size_t>(pa)].radius;
  Vec3 sum = Vec3::Zero();
  int count = 0;
  for (const Vec3& x : v)
    if (d.dot(x) >= hi - eps) {
      sum += x;
      ++count;
    }
  return world_from_a * (count > 0 ? Vec3(sum / count) : Vec3::Zero());
}

// Sizes the deep-fallback scratch of `st` (an allocation only on the first
// frame of a State a Session did not prepare, or when the pair buffer grew).
void size_deep_state(State& st) {
  FrameScratch& sc = *st.scratch;
  const size_t n = st.poses.size();
  if (st.deep_active.size() != n) {
    st.deep_active.assign(n, 0);
    st.deep_overlap.assign(n, 0.0);
    st.deep_axis.assign(n, Vec3::Zero());
    st.deep_point.assign(n, Vec3::Zero());
    st.deep_grad.assign(n, Vec6::Zero());
    st.deep_wrench.assign(n, Vec6::Zero());
    st.deep_pair.assign(n, -1);
    sc.free_last.assign(n, 0);
    sc.free_pose.assign(n, Pose{});
  }
  const size_t m = st.pairs.size();
  if (sc.pair_axis.size() < m) {
    sc.pair_axis.resize(m);
    sc.pair_axis_overlap.resize(m);
    sc.pair_flipped.resize(m);
    sc.pair_key.resize(m);
    sc.pair_sort.resize(m);
  }
  if (sc.memory_key.size() < m) {
    sc.memory_key.resize(m);
    sc.memory_axis.resize(m);
  }
}

// Per pair: its axis, the overlap along it and whether it flipped (the
// header's rules); then this frame's pairs become the memory of the next.
void judge_pairs(const Scene& scene, State& st) {
  size_deep_state(st);
  FrameScratch& sc = *st.scratch;
  const int np = st.num_pairs;
  for (int i = 0; i < np; ++i) {
    sc.pair_key[static_cast<size_t>(i)] = pair_key(st.pairs[static_cast<size_t>(i)]);
    sc.pair_sort[static_cast<size_t>(i)] = i;
  }
  std::sort(sc.pair_sort.begin(), sc.pair_sort.begin() + np,
            [&](int x, int y) { return sc.pair_key[static_cast<size_t>(x)] < sc.pair_key[static_cast<size_t>(y)]; });
  const collision::ModelGeometry& ga = scene.world().geometry(0);
  const Eigen::Isometry3d world_from_a = st.poses[0].iso();
  int j = 0;
  for (int s = 0; s < np; ++s) {
    const int i = sc.pair_sort[static_cast<size_t>(s)];
    const PiecePair& p = st.pairs[static_cast<size_t>(i)];
    const uint64_t key = sc.pair_key[static_cast<size_t>(i)];
    const int b = p.object_b;
    const collision::ModelGeometry& gb = scene.world().geometry(b);
    const Pose& pose_b = st.poses[static_cast<size_t>(b)];
    const Eigen::Isometry3d world_from_b = pose_b.iso();
    while (j < sc.num_memory && sc.memory_key[static_cast<size_t>(j)] < key) ++j;
    Vec3 axis = p.n;
    bool flipped = false;
    if (j < sc.num_memory && sc.memory_key[static_cast<size_t>(j)] == key) {
      const Vec3 m = pose_b.rotation * sc.memory_axis[static_cast<size_t>(j)];
      if (p.n.dot(m) < 0.0) {
        axis = m;
        flipped = true;
      }
    } else if (sc.free_last[static_cast<size_t>(b)]) {
      // A contact that starts here: where was A in the last frame, on which
      // side of B's piece along n?
      const Eigen::Isometry3d a_then = world_from_b * sc.free_pose[static_cast<size_t>(b)].iso();
      const double along_n = axis_overlap(ga, p.piece_a, a_then, gb, p.piece_b, world_from_b, p.n);
      const double along_minus_n = axis_overlap(ga, p.piece_a, a_then, gb, p.piece_b, world_from_b, -p.n);
      if (along_minus_n <= 0.0 && along_n > 0.0) {
        axis = -p.n;
        flipped = true;
      }
    }
    double overlap = sc.pair_overlap[static_cast<size_t>(i)];
    if (flipped) {
      overlap = axis_overlap(ga, p.piece_a, world_from_a, gb, p.piece_b, world_from_b, axis);
      if (!(overlap > deep_threshold(scene, b)) || !std::isfinite(overlap)) {
        // Not deep (a touching pair whose normal is ill-defined): its own n.
        axis = p.n;
        flipped = false;
        overlap = sc.pair_overlap[static_cast<size_t>(i)];
      }
    }
    sc.pair_axis[static_cast<size_t>(i)] = axis;
    sc.pair_axis_overlap[static_cast<size_t>(i)] = overlap;
    sc.pair_flipped[static_cast<size_t>(i)] = flipped ? 1 : 0;
  }
  // Memory for the next frame (sorted by key, axes in B's frame).
  for (int s = 0; s < np; ++s) {
    const int i = sc.pair_sort[static_cast<size_t>(s)];
    const Pose& pose_b = st.poses[static_cast<size_t>(st.pairs[static_cast<size_t>(i)].object_b)];
    sc.memory_key[static_cast<size_t>(s)] = sc.pair_key[static_cast<size_t>(i)];
    sc.memory_axis[static_cast<size_t>(s)] = pose_b.rotation.conjugate() * sc.pair_axis[static_cast<size_t>(i)];
  }
  sc.num_memory = np;
  // Which objects A is free of this frame (for the next frame's onsets).
  for (size_t b = 1; b < sc.free_last.size(); ++b) sc.free_last[b] = 1;
  for (int i = 0; i < np; ++i) sc.free_last[static_cast<size_t>(st.pairs[static_cast<size_t>(i)].object_b)] = 0;
  for (size_t b = 1; b < sc.free_last.size(); ++b)
    if (sc.free_last[b]) {
      const Eigen::Isometry3d rel = st.poses[b].iso().inverse() * world_from_a;
      sc.free_pose[b].position = rel.translation();
      sc.free_pose[b].rotation = Eigen::Quaterniond(rel.linear()).normalized();
    }
}

// The patches a fallback replaces, and the fallback of each object (the
// header's rules). After the safety stage, before the sums.
void apply_deep_fallback(const Scene& scene, State& st) {
  const FrameScratch& sc = *st.scratch;
  const int nb = scene.size();
  st.num_deep = 0;
  for (int b = 0; b < nb; ++b) {
    st.deep_active[static_cast<size_t>(b)] = 0;
    st.deep_overlap[static_cast<size_t>(b)] = 0.0;
    st.deep_pair[static_cast<size_t>(b)] = -1;
  }
  for (int k = 0; k < st.num_patches; ++k) st.patches[static_cast<size_t>(k)].deep_replaced = false;
  if (st.num_pairs == 0) return;
  // Best candidate pair per object (deep_pair, deep_overlap): the deepest,
  // a flipped pair before any other (its axis is the contact's history; a
  // pair judged along its own n may be one whose n turned without our
  // seeing it, a pair new this frame).
  auto offer = [&](int i) {
    const int b = st.pairs[static_cast<size_t>(i)].object_b;
    const double o = sc.pair_axis_overlap[static_cast<size_t>(i)];
    if (!(o > deep_threshold(scene, b)) || !std::isfinite(o)) return;
    char& active = st.deep_active[static_cast<size_t>(b)];
    const int best = st.deep_pair[static_cast<size_t>(b)];
    const bool flipped = sc.pair_flipped[static_cast<size_t>(i)];
    const bool best_flipped = active && sc.pair_flipped[static_cast<size_t>(best)];
    if (!active || (flipped && !best_flipped) ||
        (flipped == best_flipped && o > st.deep_overlap[static_cast<size_t>(b)])) {
      active = 1;
      st.deep_overlap[static_cast<size_t>(b)] = o;
      st.deep_pair[static_cast<size_t>(b)] = i;
    }
  };
  for (int k = 0; k < st.num_patches; ++k) {
    ContactPatch& patch = st.patches[static_cast<size_t>(k)];
    const int first = sc.patch_first_pair[static_cast<size_t>(k)];
    const int count = sc.patch_pair_count[static_cast<size_t>(k)];
    const double thr = deep_threshold(scene, patch.object_b);
    bool flipped = false, deep = false;
    for (int s = 0; s < count; ++s) {
      const int i = sc.pair_order[static_cast<size_t>(first + s)];
      flipped = flipped || sc.pair_flipped[static_cast<size_t>(i)];
      deep = deep || sc.pair_axis_overlap[static_cast<size_t>(i)] > thr;
    }
    // Refused for its normal or its depth: `facing` and finite (a patch that
    // faces nothing has no triangles; a non-finite one is a failure, not a depth).
    const bool refused_deep = patch.refused && patch.facing && std::isfinite(patch.delta) && patch.grad.allFinite();
    if (!flipped && !(refused_deep && deep)) continue;
    patch.deep_replaced = true;
    patch.force.setZero();
    patch.torque.setZero();
    patch.delta_force = 0.0;
    ++st.warnings.deep_fallback_patches;
    for (int s = 0; s < count; ++s) offer(sc.pair_order[static_cast<size_t>(first + s)]);
  }
  // Objects with deep pairs and no patch that gives a force.
  for (int b = 1; b < nb; ++b) {
    if (st.deep_active[static_cast<size_t>(b)]) continue;
    bool force = false, deep = false;
    for (int k = 0; k < st.num_patches && !force; ++k) {
      const ContactPatch& p = st.patches[static_cast<size_t>(k)];
      force = p.object_b == b && !p.refused && !p.deep_replaced && p.covered && p.delta_force > 0;
    }
    if (force) continue;
    const double thr = deep_threshold(scene, b);
    for (int i = 0; i < st.num_pairs && !deep; ++i)
      deep = st.pairs[static_cast<size_t>(i)].object_b == b && sc.pair_axis_overlap[static_cast<size_t>(i)] > thr;
    if (!deep) continue;
    for (int k = 0; k < st.num_patches; ++k) {
      ContactPatch& p = st.patches[static_cast<size_t>(k)];
      if (p.object_b != b) continue;
      p.deep_replaced = true;  // no force either way; counted as what the fallback stands for
      p.force.setZero();
      p.torque.setZero();
      p.delta_force = 0.0;
      ++st.warnings.deep_fallback_patches;
    }
    for (int i = 0; i < st.num_pairs; ++i)
      if (st.pairs[static_cast<size_t>(i)].object_b == b) offer(i);
  }
  // The wrench of each object's pair.
  const collision::ModelGeometry& ga = scene.world().geometry(0);
  const Eigen::Isometry3d world_from_a = st.poses[0].iso();
  const Vec3 c_a = world_from_a * scene.model(0).mass.center_of_mass;
  const double k = scene.options().force.stiffness;
  for (int b = 1; b < nb; ++b) {
    if (!st.deep_active[static_cast<size_t>(b)]) continue;
    const int i = st.deep_pair[static_cast<size_t>(b)];
    const PiecePair& p = st.pairs[static_cast<size_t>(i)];
    const Vec3 axis = sc.pair_axis[static_cast<size_t>(i)];
    const double o = st.deep_overlap[static_cast<size_t>(b)];
    const Vec3 x = deepest_point(ga, p.piece_a, world_from_a, axis);
    Vec6 g;
    g << axis, (x - c_a).cross(axis);
    const Vec6 w = -k * o * g;
    if (!w.allFinite()) {  // never expected (finite poses, finite pieces); no force rather than a NaN
      st.deep_active[static_cast<size_t>(b)] = 0;
      continue;
    }
    st.deep_axis[static_cast<size_t>(b)] = axis;
    st.deep_point[static_cast<size_t>(b)] = x;
    st.deep_grad[static_cast<size_t>(b)] = g;
    st.deep_wrench[static_cast<size_t>(b)] = w;
    ++st.num_deep;
    ++st.warnings.deep_fallbacks;
  }
}

}  // namespace

void compute_pair_overlaps(const Scene& scene, State& st) {
  FrameScratch& sc = *st.scratch;
  const collision::ModelGeometry& ga = scene.world().geometry(0);
  const Eigen::Isometry3d world_from_a = st.poses[0].iso();
  for (int i = 0; i < st.num_pairs; ++i) {
    const PiecePair& p = st.pairs[static_cast<size_t>(i)];
    sc.pair_overlap[static_cast<size_t>(i)] = pair_axis_overlap(ga, world_from_a, scene.world().geometry(p.object_b),
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
  // tests/integration/test_fullsurface_depth.py, 165 N before this rule). Twice the own
  // pairs' bound leaves room for the triangles of a legitimate patch that
  // reach into other pieces' pairs (the clamp below handles those).
  if (patch.covered && std::isfinite(patch.delta) && patch.delta > kRefuseFactor * bound_own) refused = true;
  // No face of A's pieces faces n (or of B's faces -n) within 60 degrees: n
  // is edge-on to the surfaces, and no height field along it is this
  // contact's (cluster.cpp sets `facing`). Such a patch has no triangles and
  // so no force either way; refusing says why (the gratings' side pairs,
  // whose separating axes are cut-face normals 70-90 degrees off the plates').
  if (!patch.facing) refused = true;
  if (!std::isfinite(patch.delta) || !patch.grad.allFinite() || !patch.force.allFinite() || !patch.torque.allFinite() ||
      !std::isfinite(bound))
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
  FrameScratch& sc = *st.scratch;
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
  // O_i of every pair, for the safety checks (apply_patch_safety), and the
  // axis each pair's penetration is judged along (deep fallback).
  compute_pair_overlaps(scene, st);
  judge_pairs(scene, st);
  if (st.depth_backend && st.num_patches > 0) {
    // All patches of the frame in one call (the GL backend tiles them).
    for (int k = 0; k < st.num_patches; ++k) {
      const ContactPatch& patch = st.patches[static_cast<size_t>(k)];
      DepthJob& job = sc.depth_jobs[static_cast<size_t>(k)];
      job.a = &A;
      job.b = &scene.model(patch.object_b);
      job.pose_a = pose_a;
      job.pose_b = st.poses[static_cast<size_t>(patch.object_b)];
      job.patch = &patch;
    }
    st.depth_backend->evaluate(sc.depth_jobs.data(), st.num_patches, scene.options().force, sc.depth_results.data());
  }
  // The CPU code on the pool: each patch's delta and gradient on its own
  // (per-thread scratch; a patch's result does not depend on which thread or
  // scratch computed it), then the force model and the safety checks below
  // in patch order, as with a backend.
  // A frame of one patch shares the patch: in the mesh and coarse modes its
  // configurations, which rasterize each (milliseconds); in the surface mode
  // B's heights beside A's configuration 0 (with seeds), then the re-solved
  // configurations (compute_depth_gradient). On the paper's translation
  // scene, one patch per frame, two threads: 1.4-1.6x per frame. With more
  // patches, those that would keep one thread busy alone are shared that way
  // first (below), then whole patches go to the threads, the costliest first
  // (estimated by the faces whose heights they rasterize and the grid's
  // texels) so that none is left to the end.
  const bool pooled = !st.depth_backend && sc.pool && st.num_patches >= 1;
  const ForceOptions& fopt = scene.options().force;
  if (pooled && st.num_patches == 1) {
    const ContactPatch& patch = st.patches[0];
    const int b = patch.object_b;
    sc.depth_results[0] = compute_depth_gradient(A, pose_a, scene.model(b), st.poses[static_cast<size_t>(b)], patch,
                                                 fopt, sc.depth, sc.pool.get());
  } else if (pooled) {
    int* order = sc.pool_order.data();
    double* cost = sc.pool_cost.data();
    for (int k = 0; k < st.num_patches; ++k) {
      const ContactPatch& p = st.patches[static_cast<size_t>(k)];
      const double texels = static_cast<double>(p.window.resolution) * p.window.resolution;
      order[k] = k;
      cost[k] = static_cast<double>(p.tris_a.size() + p.tris_b.size() + p.reach_a.size() + p.reach_b.size()) *
                    kTexelsPerFace +
                texels;
    }
    std::sort(order, order + st.num_patches,
              [&](int x, int y) { return cost[x] > cost[y] || (cost[x] == cost[y] && x < y); });
    // A patch that costs more than the threads' fair share of what is left
    // would keep one thread busy while the others idle: such patches, the
    // costliest first, are shared between the threads one at a time (as a
    // frame of one patch is), then the rest go out whole.
    double left = 0;
    for (int t = 0; t < st.num_patches; ++t) left += cost[order[t]];
    int first = 0;
    while (first < st.num_patches && cost[order[first]] * sc.pool->threads() > left) {
      const int k = order[first++];
      left -= cost[k];
      const ContactPatch& patch = st.patches[static_cast<size_t>(k)];
      const int b = patch.object_b;
      sc.depth_results[static_cast<size_t>(k)] = compute_depth_gradient(
          A, pose_a, scene.model(b), st.poses[static_cast<size_t>(b)], patch, fopt, sc.depth, sc.pool.get());
    }
    auto task = [&](int t, int slot) {
      const int k = order[first + t];
      const ContactPatch& patch = st.patches[static_cast<size_t>(k)];
      const int b = patch.object_b;
      DepthScratch& scratch = slot == 0 ? sc.depth : sc.pool_depth[static_cast<size_t>(slot - 1)];
      sc.depth_results[static_cast<size_t>(k)] =
          compute_depth_gradient(A, pose_a, scene.model(b), st.poses[static_cast<size_t>(b)], patch, fopt, scratch);
    };
    if (first < st.num_patches) sc.pool->run(st.num_patches - first, task);
  }
  for (int k = 0; k < st.num_patches; ++k) {
    ContactPatch& patch = st.patches[static_cast<size_t>(k)];
    const int b = patch.object_b;
    const Model& B = scene.model(b);
    const Pose& pose_b = st.poses[static_cast<size_t>(b)];
    // The undersampling warning (Sec. 7.2) counts once per patch lifetime:
    // the flag lives in the patch's track (cluster_pairs keeps it across frames).
    if (st.depth_backend || pooled)
      apply_depth_gradient(A, B, patch, sc.depth_results[static_cast<size_t>(k)], scene.options().force,
                           &st.warnings.depth, &sc.tracks[static_cast<size_t>(k)].warned);
    else
      compute_patch_wrench(A, pose_a, B, pose_b, patch, scene.options().force, sc.depth, &st.warnings.depth,
                           &sc.tracks[static_cast<size_t>(k)].warned);

    apply_patch_safety(scene, st, k);
  }
  // A probe deeper than its patches can be trusted: the pieces' penalty.
  apply_deep_fallback(scene, st);
  for (int k = 0; k < st.num_patches; ++k) {
    const ContactPatch& patch = st.patches[static_cast<size_t>(k)];
    const int b = patch.object_b;
    st.force += patch.force;
    st.torque += patch.torque;
    Vec3 fb, tb;
    wrench_on_b(patch.force, patch.torque, c_a,
                st.poses[static_cast<size_t>(b)].iso() * scene.model(b).mass.center_of_mass, fb, tb);
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
