// Coarse collision detection on the convex pieces (paper Sec. 6.1): geometry
// built once per Scene, and the per-frame pair query (detect_pairs).
#include "collision/collision.h"
#include "contact/scratch.h"
#include "parallel/task_pool.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <string>

namespace hrt::collision {

namespace {

// Spatially sorted chunks of items with boxes (sorted by centre along the
// longest extent of all centres, then cut into runs of `chunk`).
void make_chunks(const std::vector<Vec3>& lo, const std::vector<Vec3>& hi, int chunk,
                 std::vector<ModelGeometry::SatChunk>& chunks, std::vector<int>& order) {
  const size_t n = lo.size();
  order.resize(n);
  for (size_t i = 0; i < n; ++i) order[i] = static_cast<int>(i);
  if (n == 0) return;
  Vec3 clo = Vec3::Constant(std::numeric_limits<double>::infinity()), chi = -clo;
  for (size_t i = 0; i < n; ++i) {
    const Vec3 c = 0.5 * (lo[i] + hi[i]);
    clo = clo.cwiseMin(c);
    chi = chi.cwiseMax(c);
  }
  int ax = 0;
  (chi - clo).maxCoeff(&ax);
  std::stable_sort(order.begin(), order.end(), [&](int x, int y) {
    return lo[static_cast<size_t>(x)][ax] + hi[static_cast<size_t>(x)][ax] <
           lo[static_cast<size_t>(y)][ax] + hi[static_cast<size_t>(y)][ax];
  });
  for (size_t k = 0; k < n; k += static_cast<size_t>(chunk)) {
    ModelGeometry::SatChunk ch;
    ch.first = static_cast<int>(k);
    ch.count = static_cast<int>(std::min<size_t>(static_cast<size_t>(chunk), n - k));
    ch.lo = Vec3::Constant(std::numeric_limits<double>::infinity());
    ch.hi = -ch.lo;
    for (int j = 0; j < ch.count; ++j) {
      const size_t i = static_cast<size_t>(order[k + static_cast<size_t>(j)]);
      ch.lo = ch.lo.cwiseMin(lo[i]);
      ch.hi = ch.hi.cwiseMax(hi[i]);
    }
    chunks.push_back(ch);
  }
}

void build_piece_sat(const ConvexPiece& piece, const std::vector<ModelGeometry::PieceEdge>& edges,
                     ModelGeometry::PieceSat& sat) {
  const size_t nv = piece.vertices.size();
  // Vertex graph from the faces' edges (both directions, deduplicated).
  std::vector<std::pair<int, int>> links;
  links.reserve(piece.faces.size() * 6);
  for (const Tri& f : piece.faces)
    for (int c = 0; c < 3; ++c) {
      const int i = static_cast<int>(f[static_cast<size_t>(c)]),
                j = static_cast<int>(f[static_cast<size_t>((c + 1) % 3)]);
      links.emplace_back(i, j);
      links.emplace_back(j, i);
    }
  std::sort(links.begin(), links.end());
  links.erase(std::unique(links.begin(), links.end()), links.end());
  sat.adj_offset.assign(nv + 1, 0);
  for (const auto& l : links) ++sat.adj_offset[static_cast<size_t>(l.first) + 1];
  for (size_t i = 0; i < nv; ++i) sat.adj_offset[i + 1] += sat.adj_offset[i];
  sat.adj.resize(links.size());
  for (size_t k = 0; k < links.size(); ++k) sat.adj[k] = links[k].second;
  // Faces in the order of planes (the same zero-area skip).
  std::vector<Vec3> lo, hi;
  for (const Tri& f : piece.faces) {
    const Vec3& a = piece.vertices[f[0]];
    const Vec3& b = piece.vertices[f[1]];
    const Vec3& c = piece.vertices[f[2]];
    if (!((b - a).cross(c - a).norm() > 0)) continue;
    const Vec3 m = (a + b + c) / 3.0;
    const double r = std::max({(a - m).norm(), (b - m).norm(), (c - m).norm()});
    sat.face_sphere.emplace_back(m.x(), m.y(), m.z(), r);
    lo.push_back(a.cwiseMin(b).cwiseMin(c));
    hi.push_back(a.cwiseMax(b).cwiseMax(c));
  }
  make_chunks(lo, hi, ModelGeometry::kSatChunk, sat.face_chunks, sat.face_order);
  lo.clear();
  hi.clear();
  for (const ModelGeometry::PieceEdge& e : edges) {
    lo.push_back(e.a.cwiseMin(e.b));
    hi.push_back(e.a.cwiseMax(e.b));
  }
  make_chunks(lo, hi, ModelGeometry::kSatChunk, sat.edge_chunks, sat.edge_order);
}

Bounds bounds_of(const std::vector<Vec3>& pts) {
  Bounds b;
  if (pts.empty()) return b;
  Vec3 lo = pts[0], hi = pts[0];
  for (const Vec3& p : pts) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  b.center = 0.5 * (lo + hi);
  b.half = 0.5 * (hi - lo);
  double r2 = 0.0;
  for (const Vec3& p : pts) r2 = std::max(r2, (p - b.center).squaredNorm());
  b.radius = std::sqrt(r2);
  return b;
}

}  // namespace

bool ModelGeometry::adjacent(int p, int q) const {
  if (p == q) return true;
  auto first = adj_list.begin() + adj_offset[static_cast<size_t>(p)];
  auto last = adj_list.begin() + adj_offset[static_cast<size_t>(p) + 1];
  return std::binary_search(first, last, q);
}

namespace {

// The FCL convex of each piece, its face planes and bounds; the model's bounds.
void convex_pieces(ModelGeometry& g, const Model& model) {
  const size_t np = model.pieces.size();
  std::vector<Vec3> all;
  g.convex.reserve(np);
  g.piece_bounds.reserve(np);
  g.planes.resize(np);
  for (size_t p = 0; p < np; ++p) {
    const ConvexPiece& piece = model.pieces[p];
    auto verts = std::make_shared<std::vector<Vec3>>(piece.vertices.begin(), piece.vertices.end());
    auto faces = std::make_shared<std::vector<int>>();
    faces->reserve(piece.faces.size() * 4);
    for (const Tri& f : piece.faces) {
      faces->push_back(3);
      for (int c = 0; c < 3; ++c) faces->push_back(static_cast<int>(f[static_cast<size_t>(c)]));
      // Outward face plane n . x = d, for the fallback normal.
      const Vec3& a = piece.vertices[f[0]];
      Vec3 nrm = (piece.vertices[f[1]] - a).cross(piece.vertices[f[2]] - a);
      double len = nrm.norm();
      if (len > 0) {
        nrm /= len;
        g.planes[p].push_back(Eigen::Vector4d(nrm.x(), nrm.y(), nrm.z(), nrm.dot(a)));
      }
    }
    g.convex.push_back(std::make_shared<fcl::Convexd>(std::shared_ptr<const std::vector<Vec3>>(verts),
                                                      static_cast<int>(piece.faces.size()),
                                                      std::shared_ptr<const std::vector<int>>(faces), false));
    g.piece_bounds.push_back(bounds_of(piece.vertices));
    all.insert(all.end(), piece.vertices.begin(), piece.vertices.end());
  }
  g.bounds = bounds_of(all);
}

// Edges between non-coplanar faces, for the separating-axis depth. Pieces
// are closed and consistently wound (checked by the loader), so every
// directed edge (i, j) of a face has its reverse (j, i) in another face.
void hull_edges(ModelGeometry& g, const Model& model) {
  const size_t np = model.pieces.size();
  g.edges.resize(np);
  g.sat.resize(np);
  for (size_t p = 0; p < np; ++p) {
    const ConvexPiece& piece = model.pieces[p];
    std::vector<std::pair<uint64_t, Vec3>> half;  // key (i << 32 | j), outward normal of its face
    half.reserve(piece.faces.size() * 3);
    for (const Tri& f : piece.faces) {
      const Vec3 nrm = (piece.vertices[f[1]] - piece.vertices[f[0]]).cross(piece.vertices[f[2]] - piece.vertices[f[0]]);
      const double len = nrm.norm();
      if (!(len > 0)) continue;
      for (int c = 0; c < 3; ++c) {
        const uint64_t i = f[static_cast<size_t>(c)], j = f[static_cast<size_t>((c + 1) % 3)];
        half.emplace_back((i << 32) | j, nrm / len);
      }
    }
    std::sort(half.begin(), half.end(), [](const auto& x, const auto& y) { return x.first < y.first; });
    for (const auto& [key, n1] : half) {
      const uint64_t i = key >> 32, j = key & 0xffffffffu;
      if (i > j) continue;  // each undirected edge once, from its (i < j) half
      const uint64_t rkey = (j << 32) | i;
      auto it = std::lower_bound(half.begin(), half.end(), rkey, [](const auto& x, uint64_t k) { return x.first < k; });
      if (it == half.end() || it->first != rkey) continue;
      if (n1.dot(it->second) > 1.0 - 1e-12) continue;  // coplanar: not an edge of the hull
      g.edges[p].push_back({piece.vertices[i], piece.vertices[j], n1, it->second});
    }
    build_piece_sat(piece, g.edges[p], g.sat[p]);
  }
}

// The pieces of each coarse face, and the faces' bounding spheres.
void face_pieces(ModelGeometry& g, const Model& model) {
  const size_t np = model.pieces.size();
  g.face_piece_offset.assign(model.faces.size() + 1, 0);
  for (size_t p = 0; p < np; ++p)
    for (uint32_t f : model.pieces[p].coarse_faces) ++g.face_piece_offset[f + 1];
  for (size_t f = 0; f < model.faces.size(); ++f) g.face_piece_offset[f + 1] += g.face_piece_offset[f];
  g.face_pieces.assign(static_cast<size_t>(g.face_piece_offset.back()), 0);
  {
    std::vector<int> fill(g.face_piece_offset.begin(), g.face_piece_offset.end() - 1);
    for (size_t p = 0; p < np; ++p)
      for (uint32_t f : model.pieces[p].coarse_faces)
        g.face_pieces[static_cast<size_t>(fill[f]++)] = static_cast<int>(p);
  }
  g.face_spheres.reserve(model.faces.size());
  for (const Tri& f : model.faces) {
    const Vec3 c = (model.vertices[f[0]] + model.vertices[f[1]] + model.vertices[f[2]]) / 3.0;
    double r = 0.0;
    for (uint32_t vi : f) r = std::max(r, (model.vertices[vi] - c).norm());
    g.face_spheres.emplace_back(c.x(), c.y(), c.z(), r);
  }
}

// Face buckets and chunks per piece (see ModelGeometry).
void face_buckets(ModelGeometry& g, const Model& model) {
  const size_t np = model.pieces.size();
  g.piece_first_bucket.assign(np + 1, 0);
  for (size_t p = 0; p < np; ++p) {
    std::vector<uint32_t> by_axis[6];
    for (uint32_t f : model.pieces[p].coarse_faces) {
      const Vec3& nf = model.face_normals[f];
      int axis = 0;
      nf.cwiseAbs().maxCoeff(&axis);
      by_axis[2 * axis + (nf[axis] < 0 ? 1 : 0)].push_back(f);
    }
    for (auto& list : by_axis) {
      if (list.empty()) continue;
      ModelGeometry::FaceBucket bucket;
      Vec3 mean = Vec3::Zero();
      for (uint32_t f : list) mean += model.face_normals[f];
      bucket.axis = mean.norm() > 0 ? Vec3(mean.normalized()) : model.face_normals[list[0]];
      double min_cos = 1.0;
      for (uint32_t f : list) min_cos = std::min(min_cos, model.face_normals[f].dot(bucket.axis));
      bucket.half_angle = std::acos(std::clamp(min_cos, -1.0, 1.0)) + 1e-9;
      // Spatially coherent chunks: sort by the centroid along the bucket's
      // longest extent, then cut into runs of kChunkFaces.
      Vec3 lo = Vec3::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
      for (uint32_t f : list) {
        lo = lo.cwiseMin(g.face_spheres[f].head<3>());
        hi = hi.cwiseMax(g.face_spheres[f].head<3>());
      }
      int ax = 0;
      (hi - lo).maxCoeff(&ax);
      std::stable_sort(list.begin(), list.end(),
                       [&](uint32_t x, uint32_t y) { return g.face_spheres[x][ax] < g.face_spheres[y][ax]; });
      bucket.first_chunk = static_cast<int>(g.chunks.size());
      for (size_t k = 0; k < list.size(); k += ModelGeometry::kChunkFaces) {
        ModelGeometry::FaceChunk ch;
        ch.first = static_cast<int>(g.face_order.size());
        ch.count = static_cast<int>(std::min<size_t>(ModelGeometry::kChunkFaces, list.size() - k));
        ch.lo = Vec3::Constant(std::numeric_limits<double>::infinity());
        ch.hi = -ch.lo;
        for (int j = 0; j < ch.count; ++j) {
          const uint32_t f = list[k + static_cast<size_t>(j)];
          const Eigen::Vector4d& sph = g.face_spheres[f];
          ch.lo = ch.lo.cwiseMin(sph.head<3>() - Vec3::Constant(sph[3]));
          ch.hi = ch.hi.cwiseMax(sph.head<3>() + Vec3::Constant(sph[3]));
          g.face_order.push_back(f);
        }
        g.chunks.push_back(ch);
      }
      bucket.num_chunks = static_cast<int>(g.chunks.size()) - bucket.first_chunk;
      g.buckets.push_back(bucket);
    }
    g.piece_first_bucket[p + 1] = static_cast<int>(g.buckets.size());
  }
}

// Adjacency, from the bundle alone (no narrow phase: FCL 0.7's libccd EPA
// aborts the process on an assertion for some touching piece pairs, and
// an assertion cannot be caught; runtime/tests/data/epa_abort_pair.json).
// Pieces p, q are adjacent when
//   (a) their coarse-face lists share a coarse vertex (CoACD cuts the
//       surface between them, so the triangles on either side of a cut, or
//       one cut triangle listed by both, share vertices), or
//   (b) a face plane of one is a touching separating plane of the other:
//       all of q's vertices lie on or outside a face plane of p within
//       adjacency_tolerance and one lies on it (pieces meeting along an
//       interior cut face, e.g. an interior piece that lists no triangle),
//       with their boxes within the tolerance.
void piece_adjacency(ModelGeometry& g, const Model& model) {
  const size_t np = model.pieces.size();
  std::vector<std::vector<int>> adj(np);
  {
    // (a): per coarse vertex, the pieces whose faces use it.
    std::vector<std::vector<int>> vertex_pieces(model.vertices.size());
    for (size_t p = 0; p < np; ++p)
      for (uint32_t f : model.pieces[p].coarse_faces)
        for (uint32_t vi : model.faces[f]) {
          auto& list = vertex_pieces[vi];
          if (list.empty() || list.back() != static_cast<int>(p)) list.push_back(static_cast<int>(p));
        }
    for (const auto& list : vertex_pieces)
      for (size_t i = 0; i < list.size(); ++i)
        for (size_t j = i + 1; j < list.size(); ++j) {
          adj[static_cast<size_t>(list[i])].push_back(list[j]);
          adj[static_cast<size_t>(list[j])].push_back(list[i]);
        }
  }
  const double tol = g.adjacency_tolerance;
  auto touching_plane = [&](size_t p, size_t q) {
    for (const Eigen::Vector4d& pl : g.planes[p]) {
      double lo = std::numeric_limits<double>::infinity();
      for (const Vec3& x : model.pieces[q].vertices) lo = std::min(lo, pl.head<3>().dot(x) - pl[3]);
      if (lo >= -tol && lo <= tol) return true;
    }
    return false;
  };
  for (size_t p = 0; p < np; ++p) {
    for (size_t q = p + 1; q < np; ++q) {
      const Bounds& bp = g.piece_bounds[p];
      const Bounds& bq = g.piece_bounds[q];
      Vec3 gap = ((bp.center - bq.center).cwiseAbs() - bp.half - bq.half);
      if (gap.maxCoeff() > tol) continue;
      if (touching_plane(p, q) || touching_plane(q, p)) {
        adj[p].push_back(static_cast<int>(q));
        adj[q].push_back(static_cast<int>(p));
      }
    }
  }
  g.adj_offset.assign(np + 1, 0);
  for (size_t p = 0; p < np; ++p) {
    std::sort(adj[p].begin(), adj[p].end());
    adj[p].erase(std::unique(adj[p].begin(), adj[p].end()), adj[p].end());
    g.adj_offset[p + 1] = g.adj_offset[p] + static_cast<int>(adj[p].size());
    g.adj_list.insert(g.adj_list.end(), adj[p].begin(), adj[p].end());
  }
}

// The broad phase's tree of the pieces.
void piece_tree(ModelGeometry& g) {
  const size_t np = g.convex.size();
  g.tree = std::make_unique<fcl::DynamicAABBTreeCollisionManagerd>();
  std::vector<fcl::CollisionObjectd*> objs;
  for (size_t p = 0; p < np; ++p) {
    auto obj = std::make_unique<fcl::CollisionObjectd>(g.convex[p]);
    obj->setUserData(reinterpret_cast<void*>(static_cast<intptr_t>(p)));
    obj->computeAABB();
    objs.push_back(obj.get());
    g.tree_objects.push_back(std::move(obj));
  }
  g.tree->registerObjects(objs);
  g.tree->setup();
}

}  // namespace

std::unique_ptr<ModelGeometry> build_geometry(const Model& model, bool with_tree) {
  auto g = std::make_unique<ModelGeometry>();
  g->model = &model;
  const size_t np = model.pieces.size();
  if (np == 0) throw std::invalid_argument(model.path + ": the model has no convex pieces");
  convex_pieces(*g, model);
  hull_edges(*g, model);
  face_pieces(*g, model);
  face_buckets(*g, model);
  g->scale = 2.0 * g->bounds.half.norm();
  g->adjacency_tolerance = 1e-3 * g->scale;
  piece_adjacency(*g, model);
  if (with_tree) piece_tree(*g);
  return g;
}

World::World(const std::vector<const Model*>& objects) {
  // One geometry per distinct Model (the same bundle may appear several times).
  for (size_t i = 0; i < objects.size(); ++i) {
    const ModelGeometry* found = nullptr;
    for (const auto& g : owned_)
      if (g->model == objects[i]) found = g.get();
    bool need_tree = i > 0;
    if (found && (!need_tree || found->tree)) {
      per_object_.push_back(found);
    } else if (found) {
      // Seen before only as A: rebuild with a tree (A and some B share the model).
      owned_.push_back(build_geometry(*objects[i], true));
      per_object_.push_back(owned_.back().get());
    } else {
      owned_.push_back(build_geometry(*objects[i], need_tree));
      per_object_.push_back(owned_.back().get());
    }
    if (i > 0) max_b_pieces_ = std::max(max_b_pieces_, static_cast<int>(objects[i]->pieces.size()));
  }
}

World::~World() = default;

namespace {

// The face of B's piece whose plane lies closest to p_b (the face p_b lies
// on); A penetrates B against that face's outward normal.
bool nearest_face_normal(const ModelGeometry& gb, int pb, const Vec3& p_b, Vec3& n) {
  const auto& planes = gb.planes[static_cast<size_t>(pb)];
  double best = -std::numeric_limits<double>::infinity();
  n = Vec3::UnitZ();
  for (const Eigen::Vector4d& pl : planes) {
    double s = pl.head<3>().dot(p_b) - pl[3];
    if (s > best) {
      best = s;
      n = -pl.head<3>();
    }
  }
  return true;
}

// Whether the segment p0 p1 meets the box [lo, hi] (slab test).
bool segment_meets_box(const Vec3& p0, const Vec3& p1, const Vec3& lo, const Vec3& hi) {
  double t0 = 0.0, t1 = 1.0;
  const Vec3 d = p1 - p0;
  for (int k = 0; k < 3; ++k) {
    if (d[k] == 0.0) {
      if (p0[k] < lo[k] || p0[k] > hi[k]) return false;
      continue;
    }
    double ta = (lo[k] - p0[k]) / d[k], tb = (hi[k] - p0[k]) / d[k];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
    if (t0 > t1) return false;
  }
  return true;
}

// Support point of a convex piece along dir (object frame) by steepest
// ascent on its vertex graph from `start`: on a convex polytope a vertex no
// neighbour of which is higher is a highest vertex (every improving polytope
// edge is an edge of the triangulation), so this is exact; on a piece convex
// only within the bundle's tolerance it errs by at most that tolerance.
int climb(const std::vector<Vec3>& v, const ModelGeometry::PieceSat& s, const Vec3& dir, int start, double& value) {
  int cur = start;
  value = dir.dot(v[static_cast<size_t>(cur)]);
  for (;;) {
    int next = cur;
    for (int k = s.adj_offset[static_cast<size_t>(cur)]; k < s.adj_offset[static_cast<size_t>(cur) + 1]; ++k) {
      const int j = s.adj[static_cast<size_t>(k)];
      const double x = dir.dot(v[static_cast<size_t>(j)]);
      if (x > value) {
        value = x;
        next = j;
      }
    }
    if (next == cur) return cur;
    cur = next;
  }
}

}  // namespace

double piece_support(const ModelGeometry& g, int piece, const Vec3& dir, int* warm) {
  const auto ip = static_cast<size_t>(piece);
  const std::vector<Vec3>& v = g.model->pieces[ip].vertices;
  int start = warm ? *warm : 0;
  if (start < 0 || start >= static_cast<int>(v.size())) start = 0;
  double value = 0;
  const int best = climb(v, g.sat[ip], dir, start, value);
  if (warm) *warm = best;
  return value;
}

namespace {

bool boxes_meet(const Vec3& alo, const Vec3& ahi, const Vec3& blo, const Vec3& bhi) {
  return !((alo.array() > bhi.array()).any() || (ahi.array() < blo.array()).any());
}

bool sphere_meets_box(const Eigen::Vector4d& s, const Vec3& lo, const Vec3& hi) {
  const Vec3 c = s.head<3>();
  const Vec3 q = c.cwiseMax(lo).cwiseMin(hi);
  return (q - c).squaredNorm() <= s[3] * s[3];
}

// Penetration depth of two convex pieces by the separating-axis theorem,
// which is exact for convex polytopes: the depth (the shortest translation of
// A that separates them) is the smallest overlap over the face normals of the
// Minkowski difference A - B, i.e. A's face normals, B's (reversed), and the
// cross products of edge pairs whose arcs on the Gauss map intersect
// (Gregorius, "The Separating Axis Test between Convex Polyhedra", GDC 2013).
// No iteration to converge, so no degenerate case to fail on.
//
// Cost. The overlap along an axis u is support_A(u) + support_B(-u), each
// found by hill climbing. Any axis's overlap bounds the depth from above, and
// the face (or edge pair) of the Minkowski difference that realises the
// depth has its two witness points, one on each piece, `depth` apart, so its
// feature on each piece lies within `depth` of the other piece. So with a
// bound U (first the overlap along the line between the boxes' centres, then
// the best so far), only the features within U of the other piece's box are
// tested: chunks of faces and edges by their boxes, then faces by their
// bounding spheres and edges by segment-box tests. Exact, and in shallow
// contact (the haptic case) it leaves a handful of features even for a
// piece of hundreds (docs/guides/runtime.md: the narrow-phase benchmark).
//
// Frames: A's features in A's frame, B's in B's, x_B = R x_A + t. Sets
// d = -depth (d > 0 when a face axis separates them: touching within GJK's
// tolerance), n (B frame) from A into B, and p_a, p_b on the deepest
// features (p_a - p_b = depth n).
bool sat_depth(const ModelGeometry& ga, int pa, const Eigen::Isometry3d& b_from_a, const ModelGeometry& gb, int pb,
               double eps, double& d, Vec3& p_a, Vec3& p_b, Vec3& n) {
  const auto ia = static_cast<size_t>(pa), ib = static_cast<size_t>(pb);
  const std::vector<Vec3>& va = ga.model->pieces[ia].vertices;
  const std::vector<Vec3>& vb = gb.model->pieces[ib].vertices;
  const ModelGeometry::PieceSat& sa = ga.sat[ia];
  const ModelGeometry::PieceSat& sb = gb.sat[ib];
  const Mat3 R = b_from_a.linear();
  const Mat3 Rt = R.transpose();
  const Vec3 t = b_from_a.translation();
  int cur_a = 0, cur_b = 0;  // warm starts of the hill climbs
  // support_A(R^T u) + u . t + support_B(-u): A's highest minus B's lowest along u (B frame).
  auto overlap = [&](const Vec3& u) {
    double ha = 0, hb = 0;
    cur_a = climb(va, sa, Rt * u, cur_a, ha);
    cur_b = climb(vb, sb, -u, cur_b, hb);
    return ha + u.dot(t) + hb;
  };
  // Conservative boxes of each piece in the other's frame.
  const Bounds& boxa = ga.piece_bounds[ia];
  const Bounds& boxb = gb.piece_bounds[ib];
  const Vec3 a_in_b_c = R * boxa.center + t, a_in_b_h = R.cwiseAbs() * boxa.half;
  const Vec3 b_in_a_c = Rt * (boxb.center - t), b_in_a_h = Rt.cwiseAbs() * boxb.half;

  Vec3 axis = boxb.center - a_in_b_c;
  axis = axis.norm() > 0 ? Vec3(axis.normalized()) : Vec3::UnitZ();
  double best = overlap(axis);
  if (!std::isfinite(best)) return false;

  // The faces of one piece near the other piece's box (grown by the current
  // bound), by chunk boxes then face spheres; face_overlap(plane) gives the
  // overlap and axis (B frame) of that face's normal.
  auto scan_faces = [&](const ModelGeometry::PieceSat& s, const std::vector<Eigen::Vector4d>& planes,
                        const Vec3& other_c, const Vec3& other_h, auto&& face_overlap) {
    for (const ModelGeometry::SatChunk& ch : s.face_chunks) {
      const Vec3 g = Vec3::Constant(std::max(best, 0.0) + eps);
      if (!boxes_meet(ch.lo, ch.hi, other_c - other_h - g, other_c + other_h + g)) continue;
      for (int k = ch.first; k < ch.first + ch.count; ++k) {
        const size_t f = static_cast<size_t>(s.face_order[static_cast<size_t>(k)]);
        const Vec3 gf = Vec3::Constant(std::max(best, 0.0) + eps);  // best may have dropped
        if (!sphere_meets_box(s.face_sphere[f], other_c - other_h - gf, other_c + other_h + gf)) continue;
        Vec3 u;
        const double o = face_overlap(planes[f], u);
        if (o < best) {
          best = o;
          axis = u;
        }
      }
    }
  };
  // A's faces (outward normal m_A; u = R m_A): overlap = A's plane offset
  // in B's frame + support_B(-u). In A's frame, against B's box there.
  scan_faces(sa, ga.planes[ia], b_in_a_c, b_in_a_h, [&](const Eigen::Vector4d& pl, Vec3& u) {
    u = R * pl.head<3>();
    double hb = 0;
    cur_b = climb(vb, sb, -u, cur_b, hb);
    return pl[3] + u.dot(t) + hb;
  });
  // B's faces (outward m; u = -m): overlap = support_A(-R^T m) - m . t + B's
  // offset. In B's frame, against A's box there.
  scan_faces(sb, gb.planes[ib], a_in_b_c, a_in_b_h, [&](const Eigen::Vector4d& pl, Vec3& u) {
    const Vec3 m = pl.head<3>();
    u = -m;
    double ha = 0;
    cur_a = climb(va, sa, -(Rt * m), cur_a, ha);
    return ha - m.dot(t) + pl[3];
  });
  // Edge pairs that form a face of A - B: arcs (n1a, n2a) and (-n1b, -n2b)
  // intersect on the unit sphere. When a face axis already separates the
  // pieces (best < 0) they only touch, and that axis is kept.
  if (best >= 0) {
    const double grow = best + eps;
    const Vec3 g = Vec3::Constant(grow);
    thread_local std::vector<const ModelGeometry::PieceEdge*> near_b;
    near_b.clear();
    {
      const Vec3 lo = a_in_b_c - a_in_b_h - g, hi = a_in_b_c + a_in_b_h + g;
      for (const ModelGeometry::SatChunk& ch : sb.edge_chunks) {
        if (!boxes_meet(ch.lo, ch.hi, lo, hi)) continue;
        for (int k = ch.first; k < ch.first + ch.count; ++k) {
          const ModelGeometry::PieceEdge& e = gb.edges[ib][static_cast<size_t>(sb.edge_order[static_cast<size_t>(k)])];
          if (segment_meets_box(e.a, e.b, lo, hi)) near_b.push_back(&e);
        }
      }
    }
    if (!near_b.empty()) {
      const Vec3 lo = b_in_a_c - b_in_a_h - g, hi = b_in_a_c + b_in_a_h + g;
      for (const ModelGeometry::SatChunk& ch : sa.edge_chunks) {
        if (!boxes_meet(ch.lo, ch.hi, lo, hi)) continue;
        for (int k = ch.first; k < ch.first + ch.count; ++k) {
          const ModelGeometry::PieceEdge& ea = ga.edges[ia][static_cast<size_t>(sa.edge_order[static_cast<size_t>(k)])];
          if (!segment_meets_box(ea.a, ea.b, lo, hi)) continue;
          const Vec3 a1 = R * ea.n1, a2 = R * ea.n2;
          const Vec3 pa0 = R * ea.a + t;
          const Vec3 da = R * (ea.b - ea.a);
          const Vec3 bxa = a2.cross(a1);
          for (const ModelGeometry::PieceEdge* ebp : near_b) {
            const ModelGeometry::PieceEdge& eb = *ebp;
            const Vec3 c = -eb.n1, dd = -eb.n2;
            const double cba = c.dot(bxa), dba = dd.dot(bxa);
            if (!(cba * dba < 0)) continue;
            const Vec3 dxc = dd.cross(c);
            const double adc = a1.dot(dxc), bdc = a2.dot(dxc);
            if (!(adc * bdc < 0) || !(cba * bdc > 0)) continue;
            Vec3 u = da.cross(eb.b - eb.a);
            const double len = u.norm();
            if (!(len > 1e-12 * da.norm() * (eb.b - eb.a).norm())) continue;  // parallel edges
            u /= len;
            if (u.dot(a1 + a2) < 0) u = -u;  // outward from A at its edge
            const double o = u.dot(pa0 - eb.a);
            if (o < best) {
              best = o;
              axis = u;
            }
          }
        }
      }
    }
  }
  if (!std::isfinite(best)) return false;
  // The deepest features along the axis: A's vertices within eps of its
  // highest, B's within eps of its lowest; the contact point lies over the
  // smaller of the two (a vertex or an edge inside a face), or midway.
  const Vec3 axis_a = Rt * axis;
  double amax = -std::numeric_limits<double>::infinity(), bmin = std::numeric_limits<double>::infinity();
  for (const Vec3& x : va) amax = std::max(amax, axis_a.dot(x));
  for (const Vec3& x : vb) bmin = std::min(bmin, axis.dot(x));
  Vec3 ca = Vec3::Zero(), cb = Vec3::Zero();
  int na = 0, nb = 0;
  for (const Vec3& x : va)
    if (axis_a.dot(x) >= amax - eps) {
      ca += x;
      ++na;
    }
  for (const Vec3& x : vb)
    if (axis.dot(x) <= bmin + eps) {
      cb += x;
      ++nb;
    }
  ca = R * (ca / std::max(na, 1)) + t;
  cb /= std::max(nb, 1);
  amax += axis.dot(t);
  const Vec3 lateral = na < nb ? ca : nb < na ? cb : Vec3(0.5 * (ca + cb));
  const Vec3 l0 = lateral - axis.dot(lateral) * axis;
  p_a = l0 + amax * axis;
  p_b = l0 + bmin * axis;
  d = -(amax - bmin);
  n = axis;
  return p_a.allFinite() && p_b.allFinite() && std::isfinite(d);
}

}  // namespace

bool piece_distance(const ModelGeometry& ga, int pa, const Eigen::Isometry3d& b_from_a, const ModelGeometry& gb, int pb,
                    double distance_tolerance, double& d, Vec3& p_a, Vec3& p_b, Vec3& n, bool& fallback) {
  // Two stages, neither of which reaches an EPA:
  //  1. FCL's GJK distance without signed distance (GST_LIBCCD, the same GJK
  //     as before for separated pieces); it stops at "intersecting".
  //  2. Only for intersecting pieces: the separating-axis depth (sat_depth).
  // Why not FCL's or libccd's EPA: FCL 0.7's (its libccd extension, used for
  // signed distance) aborts the process on an assertion for some piece pairs
  // (isOutsidePolytopeFace; runtime/tests/data/epa_abort_pair.json), and an
  // assertion cannot be caught; FCL's own (GST_INDEP) returns InvalidHull and
  // depths 10-100 times too small on that pair's poses, and libccd's
  // ccdGJKPenetration underestimates them by up to 10 % (measured in
  // test_narrow_phase.cpp's development against the libccd-extension EPA).
  fcl::DistanceRequestd req(true, false);
  req.distance_tolerance = distance_tolerance;
  fcl::DistanceResultd res;
  fcl::Transform3d tf_a = fcl::Transform3d::Identity();
  tf_a.linear() = b_from_a.linear();
  tf_a.translation() = b_from_a.translation();
  try {
    fcl::distance(ga.convex[static_cast<size_t>(pa)].get(), tf_a, gb.convex[static_cast<size_t>(pb)].get(),
                  fcl::Transform3d::Identity(), req, res);
  } catch (const std::exception&) {
    return false;
  }
  // FCL's GJK can report a small positive distance for pieces that overlap
  // deeply (a pebble piece against itself, 2.3 mm deep, reported 6.6 um
  // apart: tests/test_narrow_phase.cpp). A separated answer is checked
  // by its certificate: the plane normal to p_b - p_a must separate the
  // pieces, i.e. the exact supports along it (hill climbing, as sat_depth
  // uses) must leave a gap of about d. If not, the separating-axis depth
  // decides (it also returns a separation when the pieces are apart).
  bool separated = res.min_distance > 0;
  if (separated) {
    const Vec3 gap = res.nearest_points[1] - res.nearest_points[0];
    const double len = gap.norm();
    const double slack = std::max(distance_tolerance, 1e-9 * std::max(ga.scale, gb.scale));
    if (len > 0) {
      const Vec3 u = gap / len;  // B frame
      const double ha = piece_support(ga, pa, b_from_a.linear().transpose() * u) + u.dot(b_from_a.translation());
      const double hb = -piece_support(gb, pb, -u);
      separated = hb - ha >= res.min_distance - slack - 1e-3 * res.min_distance;
    } else {
      separated = false;
    }
  }
  if (separated) {
    d = res.min_distance;
    p_a = res.nearest_points[0];
    p_b = res.nearest_points[1];
  } else {
    // Intersecting (or touching within GJK's tolerance): exact depth.
    fallback = false;
    return sat_depth(ga, pa, b_from_a, gb, pb, distance_tolerance, d, p_a, p_b, n);
  }
  if (!std::isfinite(d) || !p_a.allFinite() || !p_b.allFinite()) return false;
  // Separated: A moves towards B along p_b - p_a. Overlapping: p_a is A's
  // deepest point inside B and p_b B's deepest point inside A, so A
  // penetrates B along p_a - p_b.
  Vec3 dir = d >= 0 ? Vec3(p_b - p_a) : Vec3(p_a - p_b);
  double len = dir.norm();
  // Below this the direction is numerical noise (touching pieces).
  const double eps = 1e-7 * std::max(ga.scale, gb.scale);
  fallback = !(len > eps);
  if (!fallback) {
    n = dir / len;
    return true;
  }
  return nearest_face_normal(gb, pb, p_b, n);
}

}  // namespace hrt::collision

namespace hrt {

using collision::Bounds;
using collision::ModelGeometry;

namespace {

using TreeNode = fcl::detail::NodeBase<fcl::AABBd>;

// Descends B's AABB tree (built and balanced by FCL's DynamicAABBTree
// manager) with A's piece box in B's frame; records overlapping leaves.
// Recursive (the tree is balanced: depth ~ log2(pieces)), allocation free.
void query_tree(const TreeNode* node, const Vec3& lo, const Vec3& hi, int* out, int& count) {
  const fcl::AABBd& bv = node->bv;
  if ((bv.min_.array() > hi.array()).any() || (bv.max_.array() < lo.array()).any()) return;
  if (node->isLeaf()) {
    auto* obj = static_cast<const fcl::CollisionObjectd*>(node->data);
    out[count++] = static_cast<int>(reinterpret_cast<intptr_t>(obj->getUserData()));
    return;
  }
  query_tree(node->children[0], lo, hi, out, count);
  query_tree(node->children[1], lo, hi, out, count);
}

}  // namespace

void detect_pairs(const Scene& scene, State& state) {
  FrameScratch& sc = *state.scratch;
  state.num_pairs = 0;
  const collision::World& world = scene.world();
  const ModelGeometry& ga = world.geometry(0);
  const Eigen::Isometry3d world_from_a = state.poses[0].iso();
  int* cand = sc.candidates.data();
  const int na = static_cast<int>(ga.piece_bounds.size());
  // With a pool, the narrow phase (GJK and the separating-axis depth, most of
  // the stage) runs on it: the pairs the box tests pass are listed in order,
  // evaluated in parallel, and kept in the list's order, so the pairs are
  // those of the serial loop, in its order.
  const bool pooled = sc.pool != nullptr;
  int num_jobs = 0;

  // A pair the narrow phase evaluated: kept when within the tolerance.
  auto keep = [&](int b, int pa, int pb, double tol, bool ok, double d, const Vec3& p_a, const Vec3& p_b, const Vec3& n,
                  bool fallback) {
    if (!ok) {
      ++state.warnings.fcl_failures;
      return;
    }
    if (d > tol) return;
    if (state.num_pairs == static_cast<int>(state.pairs.size())) {
      // Grow (an allocation, counted): the capacity was too small.
      const size_t cap = state.pairs.size() * 2;
      state.pairs.resize(cap);
      sc.resize_pair_scratch(cap);
      ++state.warnings.pairs_grown;
    }
    const Eigen::Isometry3d world_from_b = state.poses[static_cast<size_t>(b)].iso();
    PiecePair& pp = state.pairs[static_cast<size_t>(state.num_pairs++)];
    pp.object_b = b;
    pp.piece_a = pa;
    pp.piece_b = pb;
    pp.distance = d;
    pp.tolerance = tol;
    pp.p_a = world_from_b * p_a;
    pp.p_b = world_from_b * p_b;
    pp.n = world_from_b.linear() * n;
    pp.fallback_normal = fallback;
    if (fallback) ++state.warnings.fallback_normals;
  };

  for (int b = 1; b < scene.size(); ++b) {
    const ModelGeometry& gb = world.geometry(b);
    const double tol = scene.tolerance(b);
    const Eigen::Isometry3d world_from_b = state.poses[static_cast<size_t>(b)].iso();
    const Eigen::Isometry3d b_from_a = world_from_b.inverse(Eigen::Isometry) * world_from_a;
    sc.narrow_b_from_a[static_cast<size_t>(b)] = b_from_a;
    // GJK stops when it improves by less than this (FCL's default 1e-6 is
    // absolute, too coarse for millimetre parts).
    const double gjk_tol = 1e-6 * std::max(ga.scale, gb.scale);

    // Object level: bounding spheres.
    const Vec3 ca = b_from_a * ga.bounds.center;
    if ((ca - gb.bounds.center).norm() > ga.bounds.radius + gb.bounds.radius + tol) continue;

    const Eigen::Isometry3d a_from_b = b_from_a.inverse(Eigen::Isometry);
    const TreeNode* root = gb.tree->getTree().getRoot();
    if (!root) continue;
    const Model& A = *ga.model;
    const Model& B = *gb.model;
    for (int pa = 0; pa < na; ++pa) {
      const Bounds& bpa = ga.piece_bounds[static_cast<size_t>(pa)];
      const Vec3 c = b_from_a * bpa.center;
      if ((c - gb.bounds.center).norm() > bpa.radius + gb.bounds.radius + tol) continue;
      // The exact box of A's piece in B's frame, inflated by the tolerance:
      // every point within tol of the piece lies inside. Querying B's tree
      // (exact boxes of B's pieces) with it is the separating-axis test on
      // B's axes.
      Vec3 lo = Vec3::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
      for (const Vec3& x : A.pieces[static_cast<size_t>(pa)].vertices) {
        const Vec3 y = b_from_a * x;
        lo = lo.cwiseMin(y);
        hi = hi.cwiseMax(y);
      }
      int count = 0;
      query_tree(root, lo - Vec3::Constant(tol), hi + Vec3::Constant(tol), cand, count);
      std::sort(cand, cand + count);  // deterministic order whatever the tree's shape
      const Vec3 a_lo = bpa.center - bpa.half - Vec3::Constant(tol);
      const Vec3 a_hi = bpa.center + bpa.half + Vec3::Constant(tol);
      for (int k = 0; k < count; ++k) {
        const int pb = cand[k];
        const Bounds& bpb = gb.piece_bounds[static_cast<size_t>(pb)];
        if ((c - bpb.center).norm() - bpa.radius - bpb.radius > tol) continue;
        // Separating-axis test on A's axes: the box of B's piece in A's frame
        // against A's piece box grown by tol. Far cheaper than GJK, and most
        // broad-phase candidates beyond the tolerance stop here.
        Vec3 blo = Vec3::Constant(std::numeric_limits<double>::infinity()), bhi = -blo;
        for (const Vec3& x : B.pieces[static_cast<size_t>(pb)].vertices) {
          const Vec3 y = a_from_b * x;
          blo = blo.cwiseMin(y);
          bhi = bhi.cwiseMax(y);
        }
        if ((blo.array() > a_hi.array()).any() || (bhi.array() < a_lo.array()).any()) continue;
        if (pooled) {
          if (num_jobs == static_cast<int>(sc.narrow_jobs.size())) {
            // Grow (an allocation, counted with the pairs' growth).
            sc.narrow_jobs.resize(2 * sc.narrow_jobs.size());
            ++state.warnings.pairs_grown;
          }
          FrameScratch::NarrowJob& job = sc.narrow_jobs[static_cast<size_t>(num_jobs++)];
          job.b = b;
          job.piece_a = pa;
          job.piece_b = pb;
          job.tolerance = tol;
          job.gjk_tolerance = gjk_tol;
          continue;
        }
        double d = 0;
        Vec3 p_a, p_b, n;
        bool fallback = false;
        const bool ok = collision::piece_distance(ga, pa, b_from_a, gb, pb, gjk_tol, d, p_a, p_b, n, fallback);
        keep(b, pa, pb, tol, ok, d, p_a, p_b, n, fallback);
      }
    }
  }
  if (!pooled || num_jobs == 0) return;
  auto narrow = [&](int k, int) {
    FrameScratch::NarrowJob& job = sc.narrow_jobs[static_cast<size_t>(k)];
    job.fallback = false;
    job.ok = collision::piece_distance(ga, job.piece_a, sc.narrow_b_from_a[static_cast<size_t>(job.b)],
                                       world.geometry(job.b), job.piece_b, job.gjk_tolerance, job.d, job.p_a, job.p_b,
                                       job.n, job.fallback);
  };
  sc.pool->run(num_jobs, narrow);
  for (int k = 0; k < num_jobs; ++k) {
    const FrameScratch::NarrowJob& job = sc.narrow_jobs[static_cast<size_t>(k)];
    keep(job.b, job.piece_a, job.piece_b, job.tolerance, job.ok, job.d, job.p_a, job.p_b, job.n, job.fallback);
  }
}

}  // namespace hrt
