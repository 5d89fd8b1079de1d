// Contact clustering (paper Sec. 3.3 step 1, Sec. 6.4: ~104 piece pairs
// clustered into up to 7 contacts) and the geometry of each contact patch.
//
// Clustering. Piece pairs of the same B are joined (union-find, transitive)
// when
//   - their normals are within ClusterOptions::max_normal_angle_deg (a patch
//     is one height field along one n), and
//   - their A pieces are the same or adjacent, and their B pieces are the same
//     or adjacent (adjacent: hulls within ModelGeometry::adjacency_tolerance,
//     i.e. the pieces of one part that meet along CoACD's cut planes), and
//   - their contact points (midpoints of p_a, p_b) are closer than the sum of
//     the bounding radii of the two pieces on each side where they differ.
// So a contact region that spans several touching pieces of A and of B is one
// patch, while separated contacts (two feet of A on B, A bridging two
// separate pieces of B, a long tool resting on two distant places of a part)
// are separate patches. Two patches of one B may then cover neighbouring
// regions; a region is never split between them unless its contact points lie
// farther apart than the pieces are large.
//
// Per patch (all in the world frame):
//   - weights w_i = max((tol - d_i) / tol, 1e-3) x area_i per pair: a pair
//     that just entered the tolerance weighs ~0, so n and the points move
//     continuously as pairs come and go; overlapping pairs weigh more; and
//     each pair counts for the area over which its pieces overlap as seen
//     along its normal (area_i, pair_overlap_area: the intersection of the
//     two pieces' boxes in B's frame, grown by the tolerance, projected
//     along n_i; continuous in the poses). With depth
//     weights alone, the pairs across CoACD's cuts of the demo's ridged
//     blocks, which overlap only in 3.3 mm strips along bevelled hull faces
//     tilted by 23.6 degrees, tilted n by 6.8 degrees (delta 0.736 mm
//     against 0.788 mm along z, |F| 11 % low at N = 256); weighted by area,
//     1.8 degrees (0.763 mm, |F| 6 % low). Where a pair with a tilted normal
//     really carries the contact it counts more than before (the bench's
//     rasp in the bracket's corner: the plate patch tilts 1.3 instead of 0.3
//     degrees towards the fillet piece at the wall's foot, which the rasp
//     overlaps by 0.43 mm against 0.03-0.1 mm for the plate pieces);
//   - n = normalize(sum w_i n_i) (from A into B); p_a, p_b the weighted means
//     of the pairs' points;
//   - identity across frames: matched to the previous frame's patches (same B,
//     normals within the angle, contact point on B within
//     track_radius_factor x the previous window side, greedy by distance);
//     u is the previous u (kept in B's frame) projected onto the new plane, or
//     for a new patch the axis of B's frame least aligned with n, projected;
//     v = n x u, so {u, v, n} is right-handed;
//   - triangles: tris_a = the coarse faces of the patch's A pieces (pieces'
//     coarse_faces) whose outward normal has n . normal > kFacingCos = 0.5 (facing
//     B), tris_b = those of the B pieces with n . normal < -kFacingCos, each
//     side culled first against the other side's pieces (grown by the reach
//     below), ascending;
//   - window: the intersection of the (u, v) bounding rectangles of tris_a and
//     tris_b, each triangle clipped to the part that can come within reach of
//     the other surface along n (the domain D of Eq. 9 that matters can only
//     lie there; triangles wholly out of reach are dropped), padded on every
//     side by the largest finite-difference displacement (lin_step, and
//     ang_step times the distance from A's centre of mass; one grid texel by
//     default) plus one texel on each side for the snapping; square, N x N
//     texels (N = ForceOptions::resolution, or with
//     ClusterOptions::auto_resolution the smallest N up to max_resolution
//     whose texel is at most auto_cell_fraction x the shorter
//     min_wavelength). The texel size is quantised to the ladder 2^(k/4) m (with
//     hysteresis for tracked patches) and the origin is snapped to the lattice
//     {t_B + i cell u + j cell v} fixed to B, so texel centres stay put on B
//     while A moves and the samples do not swim. Triangles whose (u, v) box
//     misses the window grown by the pad are dropped (they cannot reach any
//     texel in any of the 11 configurations).
//
// Nothing here allocates: every list lives in State, reserved for the
// largest models of the scene.
#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "collision/collision.h"
#include "contact/scratch.h"
#include "hrt/scene.h"

namespace hrt {

namespace {

using collision::ModelGeometry;

// A face belongs to a patch's height field only when it faces the other
// object within 60 degrees of n (cos > 0.5). Steeper faces project to
// slivers whose heights span the whole face: a wall next to a floor contact
// would put the wall's top into the floor's height map and make delta jump
// when a finite-difference step moves A over the sliver; and a patch whose n
// is edge-on to the surfaces in contact (two textured plates face to face,
// piece pairs whose separating axis is a cut face's horizontal normal) would
// take the relief's flanks, tilted 68 degrees from such an n, and rasterize
// faces millimetres apart (tests/integration/test_fullsurface_depth.py, the gratings;
// with cos > 0.2 they gave 165 N). Such faces belong to the patch whose n
// they face (clustering splits normals more than 45 degrees apart, so every
// face is within 45 + 15 degrees of some patch's n it belongs to).
constexpr double kFacingCos = 0.5;
// Ladder of texel sizes: 2^(1/4) steps.
constexpr double kLadderStepsPerOctave = 4.0;

int uf_find(std::vector<int>& parent, int i) {
  while (parent[static_cast<size_t>(i)] != i) {
    int& p = parent[static_cast<size_t>(i)];
    p = parent[static_cast<size_t>(p)];  // path halving
    i = p;
  }
  return i;
}

void uf_union(std::vector<int>& parent, int i, int j) {
  int ri = uf_find(parent, i), rj = uf_find(parent, j);
  if (ri == rj) return;
  // The smaller index becomes the root, so roots are the first pair of a cluster.
  if (ri < rj)
    parent[static_cast<size_t>(rj)] = ri;
  else
    parent[static_cast<size_t>(ri)] = rj;
}

double ladder_cell(double x) {
  const double k = std::ceil(kLadderStepsPerOctave * std::log2(x) - 1e-9);
  return std::exp2(k / kLadderStepsPerOctave);
}

struct Rect {
  double lo_u = std::numeric_limits<double>::infinity(), lo_v = std::numeric_limits<double>::infinity();
  double hi_u = -std::numeric_limits<double>::infinity(), hi_v = -std::numeric_limits<double>::infinity();
  bool empty() const { return !(lo_u <= hi_u && lo_v <= hi_v); }
  void add(double a, double b) {
    lo_u = std::min(lo_u, a);
    hi_u = std::max(hi_u, a);
    lo_v = std::min(lo_v, b);
    hi_v = std::max(hi_v, b);
  }
};

// (u, v) coordinates relative to the lattice anchor t_B, and heights
// h = n . x (absolute, world), of the vertices of model M placed by its pose:
// (u . (R x + t - anchor), v . (...), n . (R x + t)). Each vertex is projected
// once per patch and cached (stamped) in the State's scratch.
struct Projector {
  Vec3 ua, va, na;
  double ou, ov, oh;
  const Model* m;
  uint32_t* vstamp;
  double* vproj;  // 3 per vertex: a, b, h
  uint32_t stamp;
  Projector(const Model& model, const Eigen::Isometry3d& world_from_m, const Vec3& u, const Vec3& v, const Vec3& n,
            const Vec3& anchor, uint32_t* stamps, double* proj, uint32_t stamp_value)
      : m(&model), vstamp(stamps), vproj(proj), stamp(stamp_value) {
    ua = world_from_m.linear().transpose() * u;
    va = world_from_m.linear().transpose() * v;
    na = world_from_m.linear().transpose() * n;
    ou = u.dot(world_from_m.translation() - anchor);
    ov = v.dot(world_from_m.translation() - anchor);
    oh = n.dot(world_from_m.translation());
  }
  const double* vertex(uint32_t vi) const {
    double* p = vproj + 3 * static_cast<size_t>(vi);
    if (vstamp[vi] != stamp) {
      vstamp[vi] = stamp;
      const Vec3& x = m->vertices[vi];
      p[0] = ua.dot(x) + ou;
      p[1] = va.dot(x) + ov;
      p[2] = na.dot(x) + oh;
    }
    return p;
  }
  // Bounding box in (u, v) of triangle f (`full`), and of the part of it where
  // sign * (h - c) >= 0 (`clipped`; h is affine on the triangle, so that part
  // is the triangle cut by a line). Returns false when that part is empty.
  bool boxes(uint32_t f, double c, double sign, Rect& full, Rect& clipped) const {
    const double* q[3];
    double s[3];
    full = Rect{};
    clipped = Rect{};
    for (int k = 0; k < 3; ++k) {
      q[k] = vertex(m->faces[f][static_cast<size_t>(k)]);
      s[k] = sign * (q[k][2] - c);
      full.add(q[k][0], q[k][1]);
    }
    for (int k = 0; k < 3; ++k) {
      const int l = (k + 1) % 3;
      if (s[k] >= 0) clipped.add(q[k][0], q[k][1]);
      if ((s[k] >= 0) != (s[l] >= 0)) {  // the cut line crosses edge k-l
        const double t = s[k] / (s[k] - s[l]);
        clipped.add(q[k][0] + t * (q[l][0] - q[k][0]), q[k][1] + t * (q[l][1] - q[k][1]));
      }
    }
    return !clipped.empty();
  }
};

// Union of the object-frame boxes of `pieces` (centre, half extents).
void pieces_box(const ModelGeometry& g, const std::vector<int>& pieces, int npieces, Vec3& center, Vec3& half) {
  Vec3 lo = Vec3::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (int k = 0; k < npieces; ++k) {
    const collision::Bounds& bd = g.piece_bounds[static_cast<size_t>(pieces[static_cast<size_t>(k)])];
    lo = lo.cwiseMin(bd.center - bd.half);
    hi = hi.cwiseMax(bd.center + bd.half);
  }
  center = 0.5 * (lo + hi);
  half = 0.5 * (hi - lo);
}

// Collects the coarse faces of `pieces` whose world normal faces `dir` and
// whose bounding sphere touches the box (region_center, region_half) given in
// m's object frame (the other side's pieces, grown by the reach: a face
// beyond it cannot come near the other surface), deduplicated with face_mark,
// sorted.
void collect_faces(const Model& m, const ModelGeometry& g, const Eigen::Matrix3d& rot, const Vec3& dir,
                   const std::vector<int>& pieces_in, int npieces, const Vec3& region_center, const Vec3& region_half,
                   std::vector<uint32_t>& face_mark, uint32_t stamp, std::vector<uint32_t>& out,
                   std::vector<uint32_t>* away = nullptr) {
  out.clear();
  if (away) away->clear();
  const Vec3 dir_local = rot.transpose() * dir;
  const Vec3 rlo = region_center - region_half, rhi = region_center + region_half;
  // A face faces dir when n_f . dir > kFacingCos, i.e. its angle to dir is
  // below kFacingAngle; a bucket whose cone lies entirely beyond that is skipped.
  const double kFacingAngle = std::acos(kFacingCos);
  for (int k = 0; k < npieces; ++k) {
    const int p = pieces_in[static_cast<size_t>(k)];
    for (int bi = g.piece_first_bucket[static_cast<size_t>(p)]; bi < g.piece_first_bucket[static_cast<size_t>(p) + 1];
         ++bi) {
      const ModelGeometry::FaceBucket& bucket = g.buckets[static_cast<size_t>(bi)];
      const double theta = std::acos(std::clamp(bucket.axis.dot(dir_local), -1.0, 1.0));
      if (!away && theta - bucket.half_angle >= kFacingAngle) continue;
      for (int ci = bucket.first_chunk; ci < bucket.first_chunk + bucket.num_chunks; ++ci) {
        const ModelGeometry::FaceChunk& ch = g.chunks[static_cast<size_t>(ci)];
        if ((ch.lo.array() > rhi.array()).any() || (ch.hi.array() < rlo.array()).any()) continue;
        for (int j = ch.first; j < ch.first + ch.count; ++j) {
          const uint32_t f = g.face_order[static_cast<size_t>(j)];
          if (face_mark[f] == stamp) continue;
          face_mark[f] = stamp;
          const bool facing = m.face_normals[f].dot(dir_local) > kFacingCos;
          if (!facing && !away) continue;
          const Eigen::Vector4d& sph = g.face_spheres[f];
          const Vec3 gap = ((sph.head<3>() - region_center).cwiseAbs() - region_half).cwiseMax(0.0);
          if (gap.squaredNorm() > sph[3] * sph[3]) continue;
          (facing ? out : *away).push_back(f);
        }
      }
    }
  }
  std::sort(out.begin(), out.end());
  if (away) std::sort(away->begin(), away->end());
}

// Overlap area of pair p's pieces as seen along its normal n_i (the n rule,
// see the top of this file): the box where the two pieces' boxes in B's
// frame intersect (B's piece: its exact box; A's piece: the exact box of its
// vertices in B's frame, from support points), grown by the pair's
// tolerance on every axis so that it is positive for every pair within the
// tolerance, projected along n_i: |n_x| l_y l_z + |n_y| l_x l_z + |n_z| l_x
// l_y. Continuous in the poses; m^2, floored at (1e-6 x the scene's scale)^2.
double pair_overlap_area(const ModelGeometry& ga, const Eigen::Isometry3d& world_from_a, const ModelGeometry& gb,
                         const Eigen::Isometry3d& world_from_b, const PiecePair& p) {
  const Eigen::Isometry3d b_from_a = world_from_b.inverse(Eigen::Isometry) * world_from_a;
  const Eigen::Matrix3d rt = b_from_a.linear().transpose();
  const collision::Bounds& bb = gb.piece_bounds[static_cast<size_t>(p.piece_b)];
  Vec3 len;
  int warm = 0;
  for (int k = 0; k < 3; ++k) {
    const Vec3 dir = rt.col(k);  // B's axis k in A's frame
    const double t = b_from_a.translation()[k];
    const double hi = collision::piece_support(ga, p.piece_a, dir, &warm) + t;
    const double lo = -collision::piece_support(ga, p.piece_a, -dir, &warm) + t;
    const double l = std::min(hi, bb.center[k] + bb.half[k]) - std::max(lo, bb.center[k] - bb.half[k]) + p.tolerance;
    len[k] = std::max(l, 0.0);
  }
  const Vec3 nb = (world_from_b.linear().transpose() * p.n).cwiseAbs();
  const double area = nb.x() * len.y() * len.z() + nb.y() * len.x() * len.z() + nb.z() * len.x() * len.y();
  const double floor_len = 1e-6 * std::max(ga.scale, gb.scale);
  return std::max(area, floor_len * floor_len);
}

}  // namespace

namespace {

// Greedy matching of this frame's patches to the previous frame's tracks
// (closest contact point on B first). match[k] = track index or -1.
void match_tracks(const Scene& scene, State& st, const double cos_max, int* match) {
  FrameScratch& sc = *st.scratch;
  const int K = st.num_patches;
  const double radius_factor = scene.options().cluster.track_radius_factor;
  char* track_taken = sc.track_taken.data();
  for (int t = 0; t < sc.num_tracks; ++t) track_taken[t] = 0;
  for (int k = 0; k < K; ++k) match[k] = -1;
  for (;;) {
    double best = std::numeric_limits<double>::infinity();
    int bk = -1, bt = -1;
    for (int k = 0; k < K; ++k) {
      if (match[k] >= 0) continue;
      const PatchTrack& cur = sc.next_tracks[static_cast<size_t>(k)];
      for (int t = 0; t < sc.num_tracks; ++t) {
        if (track_taken[t]) continue;
        const PatchTrack& prev = sc.tracks[static_cast<size_t>(t)];
        if (prev.object_b != cur.object_b) continue;
        if (prev.n_local.dot(cur.n_local) < cos_max) continue;
        const double d = (prev.p_b_local - cur.p_b_local).norm();
        if (d > radius_factor * prev.side) continue;
        if (d < best) {
          best = d;
          bk = k;
          bt = t;
        }
      }
    }
    if (bk < 0) break;
    match[bk] = bt;
    track_taken[bt] = 1;
  }
}

// What every patch of a frame shares: A (the first model), its pose, the options.
struct ClusterContext {
  const Scene& scene;
  const ClusterOptions& copt;
  const ForceOptions& fopt;
  double cos_max;
  const collision::World& world;
  const ModelGeometry& ga;
  const Model& A;
  Eigen::Isometry3d world_from_a;
  Vec3 c_a;
  int N;
  int max_n;  // auto resolution's budget (N without it)
};

// Auto resolution: the grid texel each B's patches aim at (0 = none).
void set_target_cells(const ClusterContext& cx, FrameScratch& sc) {
  double* target_cell = sc.target_cell.data();
  for (int b = 0; b < cx.scene.size(); ++b) {
    double lam = std::numeric_limits<double>::infinity();
    if (cx.A.quality.min_wavelength > 0) lam = std::min(lam, cx.A.quality.min_wavelength);
    if (cx.scene.model(b).quality.min_wavelength > 0) lam = std::min(lam, cx.scene.model(b).quality.min_wavelength);
    target_cell[b] = cx.copt.auto_resolution && std::isfinite(lam) ? cx.copt.auto_cell_fraction * lam : 0.0;
  }
}

// Weights and union-find.
void weigh_and_join(const ClusterContext& cx, State& st, const int np) {
  FrameScratch& sc = *st.scratch;
  const ModelGeometry& ga = cx.ga;
  for (int i = 0; i < np; ++i) {
    const PiecePair& p = st.pairs[static_cast<size_t>(i)];
    const double depth = p.tolerance > 0 ? std::max((p.tolerance - p.distance) / p.tolerance, 1e-3) : 1.0;
    sc.pair_weight[static_cast<size_t>(i)] =
        depth * pair_overlap_area(ga, cx.world_from_a, cx.world.geometry(p.object_b),
                                  st.poses[static_cast<size_t>(p.object_b)].iso(), p);
    sc.uf_parent[static_cast<size_t>(i)] = i;
  }
  for (int i = 0; i < np; ++i) {
    const PiecePair& pi = st.pairs[static_cast<size_t>(i)];
    const ModelGeometry& gb = cx.world.geometry(pi.object_b);
    for (int j = i + 1; j < np; ++j) {
      const PiecePair& pj = st.pairs[static_cast<size_t>(j)];
      if (pj.object_b != pi.object_b) break;  // detect_pairs emits the pairs grouped by object
      if (pi.n.dot(pj.n) < cx.cos_max) continue;
      if (!ga.adjacent(pi.piece_a, pj.piece_a)) continue;
      if (!gb.adjacent(pi.piece_b, pj.piece_b)) continue;
      // Proximity: on each side whose pieces differ, the contact points must
      // lie within the two pieces' bounding radii of each other, so that one
      // large piece (a long tool) touching two distant places of adjacent
      // pieces of the other object gives two patches, not one huge window.
      double reach = std::numeric_limits<double>::infinity();
      if (pi.piece_a != pj.piece_a)
        reach = std::min(reach, ga.piece_bounds[static_cast<size_t>(pi.piece_a)].radius +
                                    ga.piece_bounds[static_cast<size_t>(pj.piece_a)].radius);
      if (pi.piece_b != pj.piece_b)
        reach = std::min(reach, gb.piece_bounds[static_cast<size_t>(pi.piece_b)].radius +
                                    gb.piece_bounds[static_cast<size_t>(pj.piece_b)].radius);
      if ((0.5 * (pi.p_a + pi.p_b) - 0.5 * (pj.p_a + pj.p_b)).squaredNorm() > reach * reach) continue;
      uf_union(sc.uf_parent, i, j);
    }
  }
}

// Clusters (numbered by their first pair), capped by weight; returns the
// number of patches (also st.num_patches).
int number_patches(const ClusterContext& cx, State& st, const int np) {
  FrameScratch& sc = *st.scratch;
  int nclusters = 0;
  for (int i = 0; i < np; ++i) {
    const int r = uf_find(sc.uf_parent, i);  // r <= i: the root is the smallest index
    if (r == i) {
      sc.cluster_weight[static_cast<size_t>(nclusters)] = 0.0;
      sc.pair_cluster[static_cast<size_t>(i)] = nclusters++;
    } else {
      sc.pair_cluster[static_cast<size_t>(i)] = sc.pair_cluster[static_cast<size_t>(r)];
    }
    sc.cluster_weight[static_cast<size_t>(sc.pair_cluster[static_cast<size_t>(i)])] +=
        sc.pair_weight[static_cast<size_t>(i)];
  }
  const int maxp = cx.copt.max_patches;
  const int K = std::min(nclusters, maxp);
  for (int c = 0; c < nclusters; ++c) sc.cluster_patch[static_cast<size_t>(c)] = c;
  if (nclusters > maxp) {
    // Keep the maxp heaviest (ties: the first found), in order of first pair.
    int* order = sc.cluster_order.data();
    for (int c = 0; c < nclusters; ++c) order[c] = c;
    std::sort(order, order + nclusters, [&](int x, int y) {
      const double wx = sc.cluster_weight[static_cast<size_t>(x)], wy = sc.cluster_weight[static_cast<size_t>(y)];
      return wx != wy ? wx > wy : x < y;
    });
    std::sort(order, order + maxp);
    for (int c = 0; c < nclusters; ++c) sc.cluster_patch[static_cast<size_t>(c)] = -1;
    for (int k = 0; k < maxp; ++k) sc.cluster_patch[static_cast<size_t>(order[k])] = k;
    st.warnings.patches_dropped += static_cast<uint64_t>(nclusters - maxp);
  }
  st.num_patches = K;
  return K;
}

// Pairs grouped by patch (counting sort, stable: ascending pair index).
void group_pairs(FrameScratch& sc, const int np, const int K) {
  for (int k = 0; k < K; ++k) sc.patch_pair_count[static_cast<size_t>(k)] = 0;
  for (int i = 0; i < np; ++i) {
    const int k = sc.cluster_patch[static_cast<size_t>(sc.pair_cluster[static_cast<size_t>(i)])];
    if (k >= 0) ++sc.patch_pair_count[static_cast<size_t>(k)];
  }
  for (int k = 0, acc = 0; k < K; ++k) {
    sc.patch_first_pair[static_cast<size_t>(k)] = acc;
    acc += sc.patch_pair_count[static_cast<size_t>(k)];
    sc.patch_pair_count[static_cast<size_t>(k)] = 0;
  }
  for (int i = 0; i < np; ++i) {
    const int k = sc.cluster_patch[static_cast<size_t>(sc.pair_cluster[static_cast<size_t>(i)])];
    if (k < 0) continue;
    sc.pair_order[static_cast<size_t>(sc.patch_first_pair[static_cast<size_t>(k)] +
                                      sc.patch_pair_count[static_cast<size_t>(k)]++)] = i;
  }
}

// Per patch: n, points (weighted means); identity in B's frame.
void patch_means(State& st, const int K) {
  FrameScratch& sc = *st.scratch;
  for (int k = 0; k < K; ++k) {
    ContactPatch& patch = st.patches[static_cast<size_t>(k)];
    const int first = sc.patch_first_pair[static_cast<size_t>(k)];
    const int count = sc.patch_pair_count[static_cast<size_t>(k)];
    Vec3 nsum = Vec3::Zero(), pa = Vec3::Zero(), pb = Vec3::Zero();
    double wsum = 0.0, wmax = -1.0;
    Vec3 nmax = Vec3::UnitZ();
    int object_b = -1;
    for (int s = 0; s < count; ++s) {
      const int i = sc.pair_order[static_cast<size_t>(first + s)];
      const PiecePair& p = st.pairs[static_cast<size_t>(i)];
      const double w = sc.pair_weight[static_cast<size_t>(i)];
      nsum += w * p.n;
      pa += w * p.p_a;
      pb += w * p.p_b;
      wsum += w;
      if (w > wmax) {
        wmax = w;
        nmax = p.n;
      }
      object_b = p.object_b;
    }
    const double len = nsum.norm();
    // Opposite normals cannot cancel within the angle limit; guard anyway.
    patch.n = len > 1e-9 * wsum ? Vec3(nsum / len) : nmax;
    patch.p_a = pa / wsum;
    patch.p_b = pb / wsum;
    patch.object_b = object_b;
    patch.piece_pairs = count;
    const Eigen::Isometry3d world_from_b = st.poses[static_cast<size_t>(object_b)].iso();
    PatchTrack& tr = sc.next_tracks[static_cast<size_t>(k)];
    tr.object_b = object_b;
    tr.p_b_local = world_from_b.inverse(Eigen::Isometry) * patch.p_b;
    tr.n_local = world_from_b.linear().transpose() * patch.n;
  }
}

// Tangent basis: the previous u (kept in B's frame) projected on the new
// plane, or for a new patch the axis of B's frame least aligned with n.
Vec3 tangent_u(const PatchTrack* prev, const Eigen::Matrix3d& rb, const Vec3& n) {
  Vec3 u = Vec3::Zero();
  if (prev) {
    const Vec3 u0 = rb * prev->u_local;
    u = u0 - u0.dot(n) * n;
    if (u.norm() < 0.1) u.setZero();  // n turned by > ~84 deg: start afresh
  }
  if (u.isZero()) {
    int axis = 0;
    double best = 2.0;
    for (int a = 0; a < 3; ++a) {
      const double c = std::abs(rb.col(a).dot(n));
      if (c < best - 1e-12) {
        best = c;
        axis = a;
      }
    }
    const Vec3 e = rb.col(axis);
    u = e - e.dot(n) * n;
  }
  u.normalize();
  return u;
}

// The next stamp of the face, piece and vertex marks.
uint32_t next_face_stamp(FrameScratch& sc) {
  ++sc.face_stamp;
  if (sc.face_stamp == 0) {  // wrapped: clear the marks (once every 2^32 patches)
    std::fill(sc.face_mark_a.begin(), sc.face_mark_a.end(), 0u);
    std::fill(sc.face_mark_b.begin(), sc.face_mark_b.end(), 0u);
    std::fill(sc.piece_mark_a.begin(), sc.piece_mark_a.end(), 0u);
    std::fill(sc.piece_mark_b.begin(), sc.piece_mark_b.end(), 0u);
    std::fill(sc.vertex_stamp_a.begin(), sc.vertex_stamp_a.end(), 0u);
    std::fill(sc.vertex_stamp_b.begin(), sc.vertex_stamp_b.end(), 0u);
    sc.face_stamp = 1;
  }
  return sc.face_stamp;
}

// Triangles of patch k's pieces facing each other (patch.tris_a, tris_b,
// reach_a, reach_b, facing).
void patch_faces(const ClusterContext& cx, State& st, const int k, const Eigen::Isometry3d& world_from_b,
                 const double reach_h, const uint32_t stamp) {
  FrameScratch& sc = *st.scratch;
  ContactPatch& patch = st.patches[static_cast<size_t>(k)];
  const int b = patch.object_b;
  const Vec3& n = patch.n;
  // Unique pieces of the patch, sorted.
  int na = 0;
  const int first = sc.patch_first_pair[static_cast<size_t>(k)];
  const int count = sc.patch_pair_count[static_cast<size_t>(k)];
  for (int s = 0; s < count; ++s) {
    const PiecePair& p = st.pairs[static_cast<size_t>(sc.pair_order[static_cast<size_t>(first + s)])];
    if (sc.piece_mark_a[static_cast<size_t>(p.piece_a)] != stamp) {
      sc.piece_mark_a[static_cast<size_t>(p.piece_a)] = stamp;
      sc.piece_list_a[static_cast<size_t>(na++)] = p.piece_a;
    }
  }
  int nb = 0;
  for (int s = 0; s < count; ++s) {
    const PiecePair& p = st.pairs[static_cast<size_t>(sc.pair_order[static_cast<size_t>(first + s)])];
    if (sc.piece_mark_b[static_cast<size_t>(p.piece_b)] != stamp) {
      sc.piece_mark_b[static_cast<size_t>(p.piece_b)] = stamp;
      sc.piece_list_b[static_cast<size_t>(nb++)] = p.piece_b;
    }
  }
  std::sort(sc.piece_list_a.begin(), sc.piece_list_a.begin() + na);
  std::sort(sc.piece_list_b.begin(), sc.piece_list_b.begin() + nb);
  // Each side's faces are first culled against the other side's pieces
  // (their box, taken into this side's frame), grown by the reach along n
  // (below) plus the largest finite-difference displacement (one texel of
  // a window no larger than that box, or the fixed steps).
  const ForceOptions& fopt = cx.fopt;
  const int N = cx.N;
  const ModelGeometry& gb = cx.world.geometry(b);
  const Eigen::Isometry3d a_from_b = cx.world_from_a.inverse(Eigen::Isometry) * world_from_b;
  Vec3 cb, hb, ca_, ha;
  pieces_box(gb, sc.piece_list_b, nb, cb, hb);
  pieces_box(cx.ga, sc.piece_list_a, na, ca_, ha);
  const double grow_a = reach_h + fopt.lin_step + 2.0 * hb.maxCoeff() / (N - 4);
  const double grow_b = reach_h + fopt.lin_step + 2.0 * ha.maxCoeff() / (N - 4);
  const Vec3 region_a_c = a_from_b * cb;
  const Vec3 region_a_h = a_from_b.linear().cwiseAbs() * hb + Vec3::Constant(grow_a);
  const Vec3 region_b_c = a_from_b.inverse(Eigen::Isometry) * ca_;
  const Vec3 region_b_h = a_from_b.linear().transpose().cwiseAbs() * ha + Vec3::Constant(grow_b);
  // The mesh heights take every face in the region, at any angle
  // (hrt/depth.h HeightMode::mesh): the others go to reach_a / reach_b.
  const bool mesh = fopt.heights == HeightMode::mesh;
  collect_faces(cx.A, cx.ga, cx.world_from_a.linear(), n, sc.piece_list_a, na, region_a_c, region_a_h, sc.face_mark_a,
                stamp, patch.tris_a, mesh ? &patch.reach_a : nullptr);
  collect_faces(cx.scene.model(b), gb, world_from_b.linear(), -n, sc.piece_list_b, nb, region_b_c, region_b_h,
                sc.face_mark_b, stamp, patch.tris_b, mesh ? &patch.reach_b : nullptr);
  if (!mesh) patch.reach_a.clear(), patch.reach_b.clear();
  // No face of one side faces the other along n: n is edge-on to the
  // surfaces in contact (frame.cpp refuses the patch).
  patch.facing = !patch.tris_a.empty() && !patch.tris_b.empty();
}

// Window: (u, v) bounds, relative to the lattice anchor t_B, of the parts
// of A's and B's triangles that can come within reach of the other
// surface, intersected. Reach along n: a point of A lower than B's
// highest point (smallest h_B) minus `reach_h` cannot touch B (h_A - h_B
// < -reach_h everywhere), and likewise for B against A's highest point
// (largest h_A). reach_h = 2 x the pair tolerance (which already holds both
// textures' outward displacements) plus what a finite-difference rotation
// can lift a point. Triangles entirely out of reach are dropped; the full
// boxes of the kept ones, by list position, go to the scratch's tri_box_a / tri_box_b
// for the final culling.
Rect reach_rect(const ClusterContext& cx, FrameScratch& sc, ContactPatch& patch, const Eigen::Isometry3d& world_from_b,
                const Vec3& anchor, const double reach_h, const uint32_t stamp) {
  const Model& A = cx.A;
  const Model& B = cx.scene.model(patch.object_b);
  const Vec3 &u = patch.u, &v = patch.v, &n = patch.n;
  const Projector proj_a(A, cx.world_from_a, u, v, n, anchor, sc.vertex_stamp_a.data(), sc.vertex_proj_a.data(), stamp);
  const Projector proj_b(B, world_from_b, u, v, n, anchor, sc.vertex_stamp_b.data(), sc.vertex_proj_b.data(), stamp);
  double ha_max = -std::numeric_limits<double>::infinity();
  double hb_min = std::numeric_limits<double>::infinity();
  for (uint32_t f : patch.tris_a)
    for (uint32_t vi : A.faces[f]) ha_max = std::max(ha_max, proj_a.vertex(vi)[2]);
  for (uint32_t f : patch.tris_b)
    for (uint32_t vi : B.faces[f]) hb_min = std::min(hb_min, proj_b.vertex(vi)[2]);
  Rect ra, rb_rect, full, part;
  double* box_a = sc.tri_box_a.data();
  double* box_b = sc.tri_box_b.data();
  size_t w = 0;
  for (uint32_t f : patch.tris_a) {
    if (!proj_a.boxes(f, hb_min - reach_h, +1.0, full, part)) continue;
    ra.add(part.lo_u, part.lo_v);
    ra.add(part.hi_u, part.hi_v);
    double* bx = box_a + 4 * w;
    bx[0] = full.lo_u, bx[1] = full.lo_v, bx[2] = full.hi_u, bx[3] = full.hi_v;
    patch.tris_a[w++] = f;
  }
  patch.tris_a.resize(w);  // shrinking: no allocation
  w = 0;
  for (uint32_t f : patch.tris_b) {
    if (!proj_b.boxes(f, ha_max + reach_h, -1.0, full, part)) continue;
    rb_rect.add(part.lo_u, part.lo_v);
    rb_rect.add(part.hi_u, part.hi_v);
    double* bx = box_b + 4 * w;
    bx[0] = full.lo_u, bx[1] = full.lo_v, bx[2] = full.hi_u, bx[3] = full.hi_v;
    patch.tris_b[w++] = f;
  }
  patch.tris_b.resize(w);
  Rect d;
  d.lo_u = std::max(ra.lo_u, rb_rect.lo_u);
  d.hi_u = std::min(ra.hi_u, rb_rect.hi_u);
  d.lo_v = std::max(ra.lo_v, rb_rect.lo_v);
  d.hi_v = std::min(ra.hi_v, rb_rect.hi_v);
  return d;
}

// The window's lattice placement (relative to the anchor) and its pad.
struct WindowPlace {
  double cell = 0.0, side = 0.0, lo_u = 0.0, lo_v = 0.0, pad = 0.0;
};

// Sizes and places patch.window around the rectangle d (empty: around the
// contact point), padded, on B's lattice.
WindowPlace place_window(const ClusterContext& cx, State& st, ContactPatch& patch, const PatchTrack* prev,
                         const Vec3& anchor, Rect d) {
  const ForceOptions& fopt = cx.fopt;
  const Vec3 &u = patch.u, &v = patch.v, &n = patch.n;
  const int b = patch.object_b;
  const double* target_cell = st.scratch->target_cell.data();
  const Vec3 mid = 0.5 * (patch.p_a + patch.p_b);
  if (d.empty()) {
    // No overlap in projection (e.g. side-by-side pieces within the
    // tolerance): a window around the contact point; Eq. 9 finds no texel
    // covered by both and the patch gives no force.
    ++st.warnings.empty_windows;
    const double cu = u.dot(mid - anchor), cv = v.dot(mid - anchor);
    d = Rect{};
    d.add(cu, cv);
  }
  const double extent = std::max(d.hi_u - d.lo_u, d.hi_v - d.lo_v);
  const double cu = 0.5 * (d.lo_u + d.hi_u), cv = 0.5 * (d.lo_v + d.hi_v);
  const Vec3 center_w = anchor + cu * u + cv * v + (n.dot(mid - anchor)) * n;
  // Padding: the largest displacement of a window point over the 11
  // configurations. Fixed steps give a fixed part, automatic ones (0) move
  // points by one grid texel (depth.h), i.e. a part proportional to the cell.
  const double r_est = 1.1 * ((cx.c_a - center_w).norm() + 0.7072 * extent);
  double pad_fixed = 0.0;
  int pad_cells = 0;
  if (fopt.lin_step > 0)
    pad_fixed = std::max(pad_fixed, fopt.lin_step);
  else
    pad_cells = 1;
  if (fopt.ang_step > 0)
    pad_fixed = std::max(pad_fixed, fopt.ang_step * r_est);
  else
    pad_cells = 1;
  // Centring the window and snapping its origin down to the lattice costs
  // up to one texel on either side, hence
  //   N cell >= extent + 2 (pad_fixed + pad_cells cell) + 2 cell.
  // With auto_resolution, N grows (up to the budget) until the texel is at
  // most auto_cell_fraction x the shorter min_wavelength.
  const int max_n = cx.max_n;
  int Np = cx.N;
  double cell = 0.0, cell_min = 0.0;
  for (;;) {
    const double denom = static_cast<double>(Np - 2 - 2 * pad_cells);
    cell_min = (extent + 2.0 * pad_fixed) / denom;
    const double floor_cell = std::max(2.0 * cx.scene.tolerance(b) / Np, 1e-9);
    cell_min = std::max(cell_min, floor_cell);
    cell = ladder_cell(cell_min);
    if (prev && prev->cell >= cell_min && prev->cell <= cell_min * std::sqrt(2.0)) cell = prev->cell;
    if (!(target_cell[b] > 0) || cell <= target_cell[b] || Np >= max_n) break;
    // The texel shrinks about as 1 / N; one more step absorbs the ladder.
    Np = std::min(max_n, std::max(Np + 1, static_cast<int>(std::ceil(Np * cell / target_cell[b])) + 1));
  }
  WindowPlace wp;
  wp.cell = cell;
  wp.side = Np * cell;
  wp.lo_u = cell * std::floor((cu - 0.5 * wp.side) / cell + 1e-9);
  wp.lo_v = cell * std::floor((cv - 0.5 * wp.side) / cell + 1e-9);
  wp.pad = pad_fixed + pad_cells * cell;
  patch.window.cell = cell;
  patch.window.resolution = Np;
  patch.window.origin = anchor + wp.lo_u * u + wp.lo_v * v + (n.dot(mid - anchor)) * n;
  return wp;
}

// Drop triangles that cannot reach the window in any configuration (their
// full boxes from reach_rect).
void cull_to_window(const FrameScratch& sc, ContactPatch& patch, const WindowPlace& wp) {
  const double* box_a = sc.tri_box_a.data();
  const double* box_b = sc.tri_box_b.data();
  const double wlo_u = wp.lo_u - wp.pad, whi_u = wp.lo_u + wp.side + wp.pad;
  const double wlo_v = wp.lo_v - wp.pad, whi_v = wp.lo_v + wp.side + wp.pad;
  auto outside = [&](const double* bx) { return bx[2] < wlo_u || bx[0] > whi_u || bx[3] < wlo_v || bx[1] > whi_v; };
  size_t w = 0;
  for (size_t k = 0; k < patch.tris_a.size(); ++k)
    if (!outside(box_a + 4 * k)) patch.tris_a[w++] = patch.tris_a[k];
  patch.tris_a.resize(w);
  w = 0;
  for (size_t k = 0; k < patch.tris_b.size(); ++k)
    if (!outside(box_b + 4 * k)) patch.tris_b[w++] = patch.tris_b[k];
  patch.tris_b.resize(w);
  // Nothing left on one side within reach of the other along n: no height
  // field of this contact exists along n either.
  patch.facing = patch.facing && !patch.tris_a.empty() && !patch.tris_b.empty();
}

// Per patch: basis, triangles, window; the track for the next frame.
void shape_patch(const ClusterContext& cx, State& st, const int k, const PatchTrack* prev) {
  FrameScratch& sc = *st.scratch;
  ContactPatch& patch = st.patches[static_cast<size_t>(k)];
  PatchTrack& tr = sc.next_tracks[static_cast<size_t>(k)];
  const int b = patch.object_b;
  const Eigen::Isometry3d world_from_b = st.poses[static_cast<size_t>(b)].iso();
  const Eigen::Matrix3d rb = world_from_b.linear();
  const Vec3& n = patch.n;
  const Vec3 u = tangent_u(prev, rb, n);
  patch.u = u;
  patch.v = n.cross(u);

  const uint32_t stamp = next_face_stamp(sc);
  const double tol = cx.scene.tolerance(b);
  const double reach_h = 2.0 * tol + (cx.fopt.ang_step > 0 ? cx.fopt.ang_step * cx.ga.scale : 0.0);
  patch_faces(cx, st, k, world_from_b, reach_h, stamp);
  const Vec3 anchor = world_from_b.translation();
  const Rect d = reach_rect(cx, sc, patch, world_from_b, anchor, reach_h, stamp);
  const WindowPlace wp = place_window(cx, st, patch, prev, anchor, d);
  cull_to_window(sc, patch, wp);

  // Results are filled by the force stage.
  patch.delta = 0.0;
  patch.grad = Vec6::Zero();
  patch.force.setZero();
  patch.torque.setZero();
  patch.covered = false;

  // Track for the next frame.
  tr.u_local = rb.transpose() * u;
  tr.cell = wp.cell;
  tr.side = wp.side;
  if (prev) {
    tr.id = prev->id;
    tr.warned = prev->warned;
  } else {
    tr.id = sc.next_track_id++;
    tr.warned = false;
  }
  st.patch_ids[static_cast<size_t>(k)] = tr.id;
}

}  // namespace

void cluster_pairs(const Scene& scene, State& st) {
  const int np = st.num_pairs;
  const ClusterOptions& copt = scene.options().cluster;
  const ForceOptions& fopt = scene.options().force;
  const Model& A = scene.model(0);
  const Eigen::Isometry3d world_from_a = st.poses[0].iso();
  const int N = fopt.resolution;
  FrameScratch& sc = *st.scratch;
  const ClusterContext cx{scene,
                          copt,
                          fopt,
                          std::cos(copt.max_normal_angle_deg * M_PI / 180.0),
                          scene.world(),
                          scene.world().geometry(0),
                          A,
                          world_from_a,
                          world_from_a * A.mass.center_of_mass,
                          N,
                          copt.auto_resolution ? std::max(N, copt.max_resolution) : N};
  set_target_cells(cx, sc);
  weigh_and_join(cx, st, np);
  const int K = number_patches(cx, st, np);
  group_pairs(sc, np, K);
  patch_means(st, K);
  int* match = sc.cluster_order.data();  // scratch (>= K entries), the capping is done
  match_tracks(scene, st, cx.cos_max, match);
  for (int k = 0; k < K; ++k)
    shape_patch(cx, st, k, match[k] >= 0 ? &sc.tracks[static_cast<size_t>(match[k])] : nullptr);
  std::swap(sc.tracks, sc.next_tracks);
  sc.num_tracks = K;
}

}  // namespace hrt
