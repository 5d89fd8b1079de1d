// Coarse collision detection on the convex pieces (paper Sec. 6.1), private.
//
// Built once per Scene: per model, one fcl::Convexd per piece (the bundle's
// vertices and outward CCW faces), the pieces' object-frame AABBs and bounding
// spheres, the piece adjacency (for clustering), and for every B an FCL
// DynamicAABBTreeCollisionManager holding B's pieces in B's own frame (B's
// tree never changes; A's pieces are brought into B's frame per frame).
//
// Per frame and per B: object-level sphere culling, then for each piece of A
// an AABB query (A's piece box in B's frame, inflated by the tolerance) down
// B's tree, a bounding-sphere lower bound, and a signed distance with FCL's
// own GJK (and its EPA when the coarse pieces overlap) for the survivors.
// libccd (FCL's default GST_LIBCCD solver) is never reached: its EPA aborts
// on an assertion for some piece pairs.
#pragma once

#include <memory>
#include <vector>

#include <fcl/fcl.h>

#include "hrt/model.h"
#include "hrt/scene.h"

namespace hrt::collision {

// Object-frame bounds of a piece (or of a whole model).
struct Bounds {
  Vec3 center = Vec3::Zero();  // AABB centre
  Vec3 half = Vec3::Zero();    // AABB half extents
  double radius = 0.0;         // bounding sphere about `center`
};

// The collision geometry of one model (shared by every scene object that uses
// the same Model).
struct ModelGeometry {
  const Model* model = nullptr;
  std::vector<std::shared_ptr<fcl::Convexd>> convex;  // one per piece
  std::vector<Bounds> piece_bounds;
  Bounds bounds;       // all pieces together
  double scale = 0.0;  // bbox diagonal of the pieces, m
  // Piece adjacency (CSR), from the bundle alone: pieces p, q are adjacent
  // when their coarse-face lists share a coarse vertex, or when a face plane
  // of one touches the other from outside within adjacency_tolerance (pieces
  // meeting along a cut face) with their boxes that close.
  std::vector<int> adj_offset;  // size pieces + 1
  std::vector<int> adj_list;    // sorted per piece
  double adjacency_tolerance = 0.0;
  bool adjacent(int p, int q) const;
  // The pieces that list each coarse face (CSR, the inverse of the pieces'
  // coarse_faces): every part of a face lies in (within map_tolerance of)
  // one of them. Used by the safety bound (src/contact/frame.cpp).
  std::vector<int> face_piece_offset;  // size faces + 1
  std::vector<int> face_pieces;
  // Bounding sphere (centre xyz, radius) of every coarse face, object frame.
  std::vector<Eigen::Vector4d> face_spheres;
  // Each piece's coarse faces grouped for culling (clustering picks the faces
  // of a patch that face the other object and lie near it): per piece, buckets
  // by dominant normal axis (+-x, +-y, +-z) with a normal cone, each bucket in
  // chunks of up to kChunkFaces spatially sorted faces with their box.
  struct FaceChunk {
    Vec3 lo, hi;       // box of the chunk's face spheres
    int first, count;  // into face_order
  };
  struct FaceBucket {
    Vec3 axis;          // unit mean normal
    double half_angle;  // every face normal is within this angle of axis (rad)
    int first_chunk, num_chunks;
  };
  static constexpr int kChunkFaces = 16;
  std::vector<int> piece_first_bucket;  // size pieces + 1
  std::vector<FaceBucket> buckets;
  std::vector<FaceChunk> chunks;
  std::vector<uint32_t> face_order;
  // Outward face planes (nx, ny, nz, d: n . x = d) per piece, object frame.
  std::vector<std::vector<Eigen::Vector4d>> planes;
  // Edges of each piece between two faces that are not coplanar (the only
  // edges that can form a face of a Minkowski difference), with the outward
  // unit normals of the two faces: the separating-axis depth (piece_distance).
  struct PieceEdge {
    Vec3 a, b;    // end points, object frame
    Vec3 n1, n2;  // outward normals of the two faces that share the edge
  };
  std::vector<std::vector<PieceEdge>> edges;
  // Per piece, for the separating-axis depth: the vertex graph (support
  // points by hill climbing, exact on a convex polytope) and the faces
  // (indices into planes) and edges (into edges) in spatially sorted chunks
  // of up to kSatChunk with their object-frame boxes, so that only the
  // features near the other piece are tested.
  struct SatChunk {
    Vec3 lo, hi;
    int first, count;  // into face_order / edge_order
  };
  static constexpr int kSatChunk = 16;
  struct PieceSat {
    std::vector<int> adj_offset, adj;          // vertex adjacency (CSR)
    std::vector<Eigen::Vector4d> face_sphere;  // per plane: centre xyz, radius
    std::vector<SatChunk> face_chunks, edge_chunks;
    std::vector<int> face_order, edge_order;
  };
  std::vector<PieceSat> sat;
  // B side: the broad-phase tree of the pieces in the object frame (built and
  // balanced by FCL's DynamicAABBTreeCollisionManager; detect_pairs descends
  // its tree with A's piece boxes).
  std::unique_ptr<fcl::DynamicAABBTreeCollisionManagerd> tree;
  std::vector<std::unique_ptr<fcl::CollisionObjectd>> tree_objects;  // user data = piece index
};

class World {
 public:
  World(const std::vector<const Model*>& objects);
  ~World();
  const ModelGeometry& geometry(int object) const { return *per_object_[static_cast<size_t>(object)]; }
  // Largest number of pieces of any B (size of the candidate buffer).
  int max_b_pieces() const { return max_b_pieces_; }

 private:
  std::vector<std::unique_ptr<ModelGeometry>> owned_;
  std::vector<const ModelGeometry*> per_object_;
  int max_b_pieces_ = 0;
};

// Builds the geometry of one model (exposed for tests).
std::unique_ptr<ModelGeometry> build_geometry(const Model& model, bool with_tree);

// Signed distance between piece pa of A (placed by b_from_a in B's frame) and
// piece pb of B, in B's frame. Fills d, p_a, p_b (B frame) and n (B frame,
// from A into B); returns false when FCL failed. fallback is set when the
// points coincided and n came from B's face planes. Separated pieces: FCL's
// GJK distance; intersecting ones: the exact separating-axis penetration
// depth (see collision.cpp).
bool piece_distance(const ModelGeometry& ga, int pa, const Eigen::Isometry3d& b_from_a, const ModelGeometry& gb, int pb,
                    double distance_tolerance, double& d, Vec3& p_a, Vec3& p_b, Vec3& n, bool& fallback);

// Support value of piece `piece` along `dir` (object frame): the largest
// dir . x over the piece's vertices, by hill climbing on its vertex graph
// (exact on a convex polytope). `warm` (optional) is the vertex to start from
// and receives the vertex found, so repeated queries along nearby directions
// take a few steps. Allocates nothing.
double piece_support(const ModelGeometry& g, int piece, const Vec3& dir, int* warm = nullptr);

}  // namespace hrt::collision
