// A scene of haptic bundles and the per-frame driver (paper Sec. 3.3).
//
// Scene: the immutable part. A static list of models, object 0 being the
// probe A (the object the user moves), 1..n-1 the objects B it touches, plus
// the options. Building a Scene builds the collision geometry once: one
// fcl::Convexd per convex piece of every model, an FCL dynamic AABB tree of
// each B's pieces in B's own frame, and each model's piece adjacency.
//
// State: everything that changes from frame to frame, preallocated when it is
// made from a Scene so that frame() allocates nothing of its own (see the
// note on FCL below). Its public members are what a caller sets (poses, the
// depth backend) or reads: the piece pairs found by collision detection, the
// contact patches, the net wrench on A and the opposite wrenches on every B,
// the deep fallback, per-stage timings and warning counters. The stages'
// scratch (tracks, union-find, marks, depth buffers, the thread pool) sits
// behind State::scratch, internal (src/contact/scratch.h).
//
// One frame (Sec. 3.3, steps 1-3), frame(scene, state):
//   1. collision: FCL distance queries between the pieces of A and the pieces
//      of every B that are closer than the pair's tolerance (overlap included):
//      per piece pair the closest points (or the penetration points) and a
//      normal from A into B (Sec. 6.1: "interpenetration is considered to
//      occur when objects are closer than a distance tolerance").
//   2. clustering: piece pairs -> contact patches (p_A, p_B, n = the mean of
//      the pairs' normals weighted by depth (tol - d) / tol times overlap
//      area, see src/contact/cluster.cpp; a continuous
//      tangent basis u, v, the sampling window, the coarse triangles of A and
//      B to rasterize).
//   3. texture force: compute_patch_wrench (depth.h, Eq. 5-9) per patch, then
//      the sums: F, T on A; (-F, -T_A - (c_A - c_B) x F) on each B.
//
// Conventions: docs/bundle-format.md (meters, quaternions x y z w, n from A
// into B, delta > 0 = overlap, torques on A about A's centre of mass).
//
// Allocation note: FCL 0.7 allocates inside its narrow phase (Convex::
// findExtremeVertex builds a std::vector per support call, and the libccd
// adapter news its shape wrappers); everything of ours is preallocated.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "hrt/contact.h"
#include "hrt/depth.h"
#include "hrt/depth_backend.h"
#include "hrt/model.h"

namespace hrt {

// ---------------------------------------------------------------------------
// Options (every default documented here; this header is the one place).
// ---------------------------------------------------------------------------

struct CollisionOptions {
  // Extra distance (m) added to each pair's contact tolerance
  //   tol(A, B) = A.displacement_outward + A.hull_deviation
  //             + B.displacement_outward + B.hull_deviation + margin
  // (docs/bundle-format.md). Negative = automatic: auto_margin_fraction times
  // the smaller of the two bundles' bbox diagonals (1 mm for a 1 m part).
  double margin = -1.0;
  double auto_margin_fraction = 1e-3;
};

struct ClusterOptions {
  // Two piece pairs of the same B join one patch only when their normals are
  // within this angle (degrees): a patch is one height field along one n, so
  // contacts on faces meeting at a sharp edge stay separate patches.
  double max_normal_angle_deg = 45.0;
  // Most patches per frame (capacity of State::patches). Beyond it the
  // patches with the smallest weight are dropped and counted in
  // Warnings::patches_dropped.
  int max_patches = 32;
  // A patch of the previous frame and one of this frame are the same contact
  // (for the continuity of u and of the lattice, and for once-per-lifetime
  // warnings) when they touch the same B, their normals are within
  // max_normal_angle_deg, and their contact points on B are closer than
  // track_radius_factor times the previous window's side.
  double track_radius_factor = 0.5;
  // Sampling: with auto_resolution, each patch gets its own grid
  // resolution N (>= ForceOptions::resolution, <= max_resolution, the
  // budget) so that its grid texel stays at or below
  // auto_cell_fraction x the smaller quality.min_wavelength of A and B
  // (bundles that record none impose nothing). 1/4: min_wavelength is two
  // atlas texels, so the grid texel is then at most half an atlas texel:
  // every atlas texel is sampled at least twice along each axis and the grid
  // maximum of the bilinear heights is missed by at most half a grid texel of
  // slope (Sec. 7.2 asks only for half a wavelength, one atlas texel, which
  // can skip a texel's extreme). Off by default: on the benchmark scenes
  // (examples/bench_runtime.sh) the windows of the rasp on the CAD part span
  // tens of millimetres over atlas texels of about 0.1 mm, so every patch
  // would run at the budget (128: about 4 to 6 times the force cost of the
  // default N = 50, docs/guides/performance.md), and the per-frame budget of the paper's
  // scenes is N = 50. State reserves its depth buffers for max_resolution.
  bool auto_resolution = false;
  int max_resolution = 128;
  double auto_cell_fraction = 0.25;
};

struct SceneOptions {
  CollisionOptions collision;
  ClusterOptions cluster;
  // Texture force model (depth.h): resolution N (default 50, the paper's
  // 50 x 50 buffer), stiffness k (default kDefaultStiffness = 1000 N/m),
  // finite-difference steps (default one grid texel and the matching angle),
  // the Sec. 5.2 shortcut (default off).
  ForceOptions force;
  // Threads of the texture force: the patches of a frame are evaluated in
  // parallel on a fixed pool that State starts once (1: the calling thread
  // only; 0: every hardware thread). The results do not depend on it.
  int threads = 1;
};
// The most threads SceneOptions::threads may ask for (a pool and a scratch
// buffer each, started by State).
constexpr int kMaxThreads = 256;
// The threads a SceneOptions::threads value means: n >= 1 as is, 0 every
// hardware thread (std::thread::hardware_concurrency, at least 1).
int resolve_threads(int requested);

// ---------------------------------------------------------------------------
// Scene (immutable)
// ---------------------------------------------------------------------------

namespace collision {
class World;  // FCL geometry of the scene (src/collision/collision.h)
}

class Scene {
 public:
  // objects[0] is the probe A; at least two objects; no null pointer. The
  // models must outlive the Scene (it keeps the pointers). Throws
  // std::invalid_argument on a bad list or bad options.
  explicit Scene(std::vector<const Model*> objects, const SceneOptions& options = {});
  ~Scene();
  Scene(const Scene&) = delete;
  Scene& operator=(const Scene&) = delete;

  int size() const { return static_cast<int>(objects_.size()); }
  const Model& model(int i) const { return *objects_[static_cast<size_t>(i)]; }
  const SceneOptions& options() const { return options_; }
  // Contact tolerance (m) between A and object b (b >= 1), see CollisionOptions.
  double tolerance(int b) const { return tolerance_[static_cast<size_t>(b)]; }
  const collision::World& world() const { return *world_; }

 private:
  std::vector<const Model*> objects_;
  SceneOptions options_;
  std::vector<double> tolerance_;
  std::unique_ptr<collision::World> world_;
};

// ---------------------------------------------------------------------------
// State (preallocated, reused every frame)
// ---------------------------------------------------------------------------

// One pair of convex pieces (A's piece_a, B's piece_b) closer than the
// tolerance, as collision detection reports it.
struct PiecePair {
  int object_b = -1;
  int piece_a = -1;
  int piece_b = -1;
  double distance = 0.0;         // signed, m; < 0: the coarse pieces overlap by -distance
  double tolerance = 0.0;        // the pair's tolerance, m
  Vec3 p_a = Vec3::Zero();       // world: closest point on A's piece (deepest point when overlapping)
  Vec3 p_b = Vec3::Zero();       // world: closest point on B's piece
  Vec3 n = Vec3::UnitZ();        // unit, world, from A into B
  bool fallback_normal = false;  // points (nearly) coincided: n from B's face planes
};

// Wall-clock time of the last frame's stages, microseconds (steady_clock).
struct StageTimings {
  double collision_us = 0.0;
  double clustering_us = 0.0;
  double force_us = 0.0;
  double total_us = 0.0;
};

// Counters, accumulated over frames (never printed by frame()).
struct Warnings {
  uint64_t fallback_normals = 0;  // piece pairs whose closest points coincided
  uint64_t fcl_failures = 0;      // FCL threw on a pair (the pair was skipped)
  uint64_t pairs_grown = 0;       // the pair buffer (or the pool's narrow-phase list) had to grow (an allocation)
  uint64_t patches_dropped = 0;   // patches beyond ClusterOptions::max_patches
  uint64_t empty_windows = 0;     // A's and B's triangles did not overlap in (u, v)
  uint64_t refused_patches = 0;   // n disagreed with the pieces (or a non-finite result): no force
  uint64_t clamped_patches = 0;   // delta above the pieces' bound: the force of the bound
  // Deep penetration (src/contact/frame.cpp, "Deep fallback"): per frame and
  // object, a penalty from the convex pieces replaced the patches' force.
  uint64_t deep_fallbacks = 0;         // fallback wrenches applied (one per object and frame at most)
  uint64_t deep_fallback_patches = 0;  // patches whose force a fallback replaced (refused deep, or a flipped pair)
  DepthWarnings depth;                 // undersampled patches, uncovered FD configurations
};

struct FrameScratch;  // the stages' internal scratch (src/contact/scratch.h)

struct State {
  // Preallocates everything for `scene` (the scratch included); poses start
  // at identity.
  explicit State(const Scene& scene);
  ~State();
  State(const State&) = delete;
  State& operator=(const State&) = delete;

  std::vector<Pose> poses;       // one per object, [0] = A (set these before frame())
  std::vector<Vec6> velocities;  // placeholder for a simulation (twist per object); frame() ignores it

  std::vector<PiecePair> pairs;  // capacity; the first num_pairs are this frame's
  int num_pairs = 0;
  std::vector<ContactPatch> patches;  // capacity max_patches; the first num_patches are valid
  int num_patches = 0;
  // patch_ids[k]: tracking id of patches[k], kept across frames while the
  // contact lasts (ClusterOptions::track_radius_factor); a new contact gets a new id.
  std::vector<uint64_t> patch_ids;

  Vec3 force = Vec3::Zero();   // net force of the patches on A, world, N
  Vec3 torque = Vec3::Zero();  // net torque of the patches on A about its centre of mass, world, N m
  // Per object b >= 1: the opposite wrench (force, torque about B's centre of
  // mass), world: (-F, -T_A - (c_A - c_B) x F) summed over its patches. [0] is zero.
  std::vector<Vec6> wrench_b;

  // Deep fallback of this frame (src/contact/frame.cpp, "Deep fallback"),
  // per object b >= 1 ([0] unused), at the scene's stiffness k. Not part of
  // force, torque and wrench_b above (those stay the patches' sums, as
  // `hrt query` reports them); a session adds it (session.cpp). It derives
  // from U = k/2 O^2, O the overlap along deep_axis of one piece pair.
  std::vector<char> deep_active;     // b's fallback acts this frame
  std::vector<double> deep_overlap;  // O, m (> the deep threshold)
  std::vector<Vec3> deep_axis;       // unit, world, from A into B: the force on A is -k O deep_axis
  std::vector<Vec3> deep_point;      // world: A's deepest point along deep_axis (where the force acts)
  std::vector<Vec6> deep_grad;       // dO / d(translation, rotation about c_A) = (axis, (point - c_A) x axis)
  std::vector<Vec6> deep_wrench;     // on A: (force, torque about c_A) = -k O deep_grad
  std::vector<int> deep_pair;        // the pair (index into pairs) it is the penalty of
  int num_deep = 0;                  // objects with deep_active this frame

  StageTimings timings;
  Warnings warnings;
  uint64_t frame_count = 0;

  // Where the depth query runs (hrt/depth_backend.h; non-owning, the caller
  // keeps it alive): null means the CPU code inline, one patch at a time.
  // With a backend, frame() hands it all patches of the frame at once.
  DepthBackend* depth_backend = nullptr;

  // Internal (src/contact/scratch.h): the stages' buffers, reused every
  // frame, and what they carry from one frame to the next (patch tracks, the
  // deep fallback's pair memory). Allocated with the State.
  std::unique_ptr<FrameScratch> scratch;
};

// One haptic frame: collision -> clustering -> per-patch wrench -> sums.
// Reads state.poses, writes everything else in `state`.
void frame(const Scene& scene, State& state);

// The first two stages alone (frame() calls them; exposed for tests and tools).
void detect_pairs(const Scene& scene, State& state);
void cluster_pairs(const Scene& scene, State& state);
// The safety stage of frame() for patch k, after compute_patch_wrench filled
// it (src/contact/frame.cpp states the rules): sets its delta_bound, refused,
// clamped and delta_force, zeroes or clamps its force and torque, counts
// Warnings::refused_patches / clamped_patches. Exposed for tests and tools.
void apply_patch_safety(const Scene& scene, State& state, int k);
// Fills the pairs' overlaps along their own normals, in the scratch, for
// this frame's pairs (frame() calls it before the patches; a caller of
// apply_patch_safety alone calls it first).
void compute_pair_overlaps(const Scene& scene, State& state);

}  // namespace hrt
