// Contact patches and the texture force model (paper Sec. 3.3, 4, 5).
//
// Data flow of one frame:
//   (poses, Models) --collision--> piece pairs --clustering--> ContactPatch
//   (geometry: p_a, p_b, n, u, v, window, triangle lists)
//   --depth (Eq. 8-9) at 11 configurations--> delta, grad delta
//   --force model (Eq. 5-7)--> wrench on A (and the opposite one on B).
//
// Conventions (docs/bundle-format.md): world frame, meters, radians;
// n points from the probe A into B; delta > 0 means overlap; the force on A is
// along -n. Torques on A are about A's centre of mass c_A.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "hrt/math.h"
#include "hrt/model.h"

namespace hrt {

// The square sampling window of a patch in the (u, v) plane. Grid texel (i, j)
// (i along u, j along v, 0 <= i, j < resolution) has its centre at the world point
//   origin + (i + 0.5) * cell * u + (j + 0.5) * cell * v
// (origin lies on the plane through the patch; heights are h = n . p, absolute).
struct Window {
  Vec3 origin = Vec3::Zero();  // world, corner of texel (0, 0)
  double cell = 0.0;           // m, grid texel size
  int resolution = 0;          // N: the grid is N x N texels
};

// One contact patch between the probe A and another object B.
struct ContactPatch {
  int object_b = -1;        // index of B in the scene (A is the probe)
  Vec3 p_a = Vec3::Zero();  // contact point on A (world)
  Vec3 p_b = Vec3::Zero();  // contact point on B (world)
  Vec3 n = Vec3::UnitZ();   // unit, from A into B
  Vec3 u = Vec3::UnitX();   // unit tangent; {u, v, n} right-handed
  Vec3 v = Vec3::UnitY();
  Window window;
  std::vector<uint32_t> tris_a;  // coarse triangles of A facing +n (the highest surface)
  std::vector<uint32_t> tris_b;  // coarse triangles of B facing -n (the lowest surface)
  // HeightMode::mesh only (else empty): the other coarse triangles of the
  // patch's pieces near the other side (turned more than 60 degrees from n,
  // resp. -n), whose full surface can still stick out towards it (tips,
  // fins). They join the height fields, not the window.
  std::vector<uint32_t> reach_a;
  std::vector<uint32_t> reach_b;
  int piece_pairs = 0;  // how many piece pairs were clustered into this patch

  // Results of the force model (filled by compute_patch_wrench).
  double delta = 0.0;        // directional penetration depth (Eq. 9), m
  Vec6 grad = Vec6::Zero();  // d delta / d(u, v, n, theta_u, theta_v, theta_n); [2] == 1
  // Second differences of delta from the same configurations (Eq. 7's
  // central differences give them for free): d2 delta / d q_i^2 for q = (u,
  // v, n, theta_u, theta_v, theta_n), 1/m and m/rad^2; [2] = 0 (delta is
  // linear in n); 0 where a neighbour is uncovered. The diagonal of the
  // Hessian that the Gauss-Newton stiffness leaves out (hrt/session.h).
  Vec6 curvature = Vec6::Zero();
  Vec3 force = Vec3::Zero();   // on A, world, N
  Vec3 torque = Vec3::Zero();  // on A about A's centre of mass, world, N m
  bool covered = false;        // some texel was covered by both A and B

  // Safety (frame(), after the force model; src/contact/frame.cpp states the
  // rules): whatever the atlas heights say, a patch's force is that of a
  // depth the coarse geometry allows, along a normal its pieces agree with.
  //   delta_bound: upper bound on delta that the convex pieces guarantee
  //                (max over the patch's piece pairs of the pair's overlap
  //                carried over to n; m).
  //   clamped:     delta > delta_bound: the force is that of delta_bound
  //                (same gradient).
  //   refused:     n disagrees with the pieces' geometry (some pair's A piece
  //                lies mostly beyond its B piece along n; or no face of A's
  //                pieces near B faces n within 60 degrees, or none of B's
  //                faces -n: n is edge-on to the surfaces, see `facing`), delta
  //                exceeds twice what the patch's own pairs allow, or the
  //                force model returned a non-finite value: no force at all.
  //   facing:      clustering found faces of A's pieces facing n and of B's
  //                facing -n, near and within reach of the other side's;
  //                false: n is edge-on to the surfaces, or they cannot meet
  //                along it (no triangles, so no force either way).
  //   delta_force: the depth the force was computed from: min(delta,
  //                delta_bound), 0 when refused or uncovered.
  // delta, grad above stay the force model's own values (Eq. 7, 9).
  double delta_bound = 0.0;
  double delta_force = 0.0;
  // The contact region (compute_patch_wrench): the texels of the window
  // where A and B overlap. contact_center: their overlap-weighted centroid
  // (world, on the window's plane); contact_lo/hi: their bounding box as
  // offsets from it along u and v (m; lo <= 0 <= hi). contact_texels = 0:
  // no overlap (touching within the tolerance only).
  Vec3 contact_center = Vec3::Zero();
  double contact_lo_u = 0.0, contact_hi_u = 0.0, contact_lo_v = 0.0, contact_hi_v = 0.0;
  int contact_texels = 0;
  bool clamped = false;
  bool refused = false;
  bool facing = true;
  // Deep fallback (frame(); src/contact/frame.cpp states the rules): the
  // probe is deeper than this patch's force can be trusted (refused with its
  // pieces overlapping beyond the deep threshold, or one of its pairs' normals
  // flipped past the middle of B's piece): its force, torque and delta_force
  // are zero, and its object's penalty (State::deep_*) acts instead.
  bool deep_replaced = false;
};

}  // namespace hrt
