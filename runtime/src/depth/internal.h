// The depth computation's internals, shared by the CPU code (src/depth), the
// GL backend (src/gl) and the tests, but not part of the public API
// (hrt/depth.h): the seeded rasterization and the re-solves of Eq. 7's
// configurations, their scalar reference, and the numbers both backends
// plan a patch with. Not installed.
#pragma once

#include <cstdint>
#include <limits>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "hrt/contact.h"
#include "hrt/depth.h"
#include "hrt/model.h"

namespace hrt {

// The same for `count` placements of M at once (out[k] gets placement k,
// with border borders[k], or 0 when borders is null): triangle by triangle,
// all placements in turn, so that each triangle's atlas region is read from
// the cache for all placements but the first (they differ by about a texel).
void rasterize_heights_multi(const Model& M, const Eigen::Isometry3d* world_from_m, const int* borders, int count,
                             const std::vector<uint32_t>& tris, const Vec3& n, const Vec3& u, const Vec3& v,
                             const Window& w, bool keep_max, double* const* out, HeightMode mode = HeightMode::surface,
                             double cull = std::numeric_limits<double>::quiet_NaN());

// rasterize_heights in the surface mode (with `border`, same layout), also
// writing each texel's seed (seeds reserved for w.resolution + 2 border).
void rasterize_heights_seeded(const Model& M, const Eigen::Isometry3d& world_from_m, const std::vector<uint32_t>& tris,
                              const Vec3& n, const Vec3& u, const Vec3& v, const Window& w, int border, bool keep_max,
                              double* out, HeightSeeds& seeds, double cull = std::numeric_limits<double>::quiet_NaN());

// The surface-mode heights of M at a placement close to the one that made
// `seeds` (a finite-difference configuration of Eq. 7: at most a texel or so
// of motion): per texel covered at that placement (seed_h finite), the fixed
// point of HeightMode::surface started from the seed's atlas point. A texel
// uncovered there stays uncovered (coverage is that of configuration 0),
// and so does one whose iteration does not converge. seed_h and seeds have
// `border` (as rasterize_heights_seeded wrote them); out is N x N.
// seed_world_from_m is the placement the seeds were made at.
// other (optional, N x N): the other side's heights; a texel the other side
// does not cover (+inf for keep_max, -inf else) can give no overlap and is
// left uncovered without being resolved (the max of Eq. 9 is unchanged).
void resolve_heights(const Model& M, const Eigen::Isometry3d& world_from_m, const Eigen::Isometry3d& seed_world_from_m,
                     const Vec3& n, const Vec3& u, const Vec3& v, const Window& w, bool keep_max, const double* seed_h,
                     int border, const HeightSeeds& seeds, double* out, const double* other = nullptr);

// resolve_heights computes its fixed point for blocks of texels vectorized
// across lanes (Google Highway, dispatched at run time to the widest vectors
// the CPU has). The scalar loop it replaced stays as the reference: the
// same result, bit for bit, on every target (tested).
void resolve_heights_reference(const Model& M, const Eigen::Isometry3d& world_from_m,
                               const Eigen::Isometry3d& seed_world_from_m, const Vec3& n, const Vec3& u, const Vec3& v,
                               const Window& w, bool keep_max, const double* seed_h, int border,
                               const HeightSeeds& seeds, double* out, const double* other = nullptr);
// The vector target resolve_heights runs on this CPU ("AVX2", "AVX3", ...).
const char* resolve_heights_target();
// Test and benchmark entry: on the calling thread, true makes the surface
// mode's fixed points (the rasterization's and resolve_heights') run the
// scalar reference loops instead of the vectorized ones. The results are the
// same bit for bit either way; only the speed differs.
void use_reference_heights(bool on);

// The faces whose heights one side of a patch contributes: `tris` (tris_a or
// tris_b), and in the mesh mode the side's reach list as well, joined in
// `buf` (which grows to the largest patch once).
const std::vector<uint32_t>& height_faces(const std::vector<uint32_t>& tris, const std::vector<uint32_t>& reach,
                                          HeightMode mode, std::vector<uint32_t>& buf);

// ---- What both backends share (the GL backend, hrt/gl_depth.h, repeats the
// CPU's arithmetic from these numbers) ----

// One placement of a model over a patch grid (extended by `border` texels):
// object point P -> grid x = gx . P + ox, y = gy . P + oy (texel centres at
// integers, border included), height relative to n . window.origin =
// n_obj . P + oh. gx4, gy4, n4 are gx, gy, n_obj in float (the atlas
// lookups' arithmetic). surface: the surface mode applies (the model has a
// surface map and the mode is surface); tol: its lateral tolerance in grid
// texels.
struct PlacementParams {
  Vec3 gx = Vec3::Zero(), gy = Vec3::Zero(), nobj = Vec3::UnitZ();
  double ox = 0, oy = 0, oh = 0;
  double tol = 0;
  bool surface = false;
  float gx4[4] = {}, gy4[4] = {}, n4[4] = {};
};
PlacementParams placement_params(const Model& M, const Eigen::Isometry3d& world_from_m, const Vec3& n, const Vec3& u,
                                 const Vec3& v, const Window& w, int border, HeightMode mode);

// resolve_heights' first residual of texel (i, j) with configuration-0
// height h (grid texels): (i, j) - (gx0 + gxi i + gxj j + gxh h, gy0 + ...).
struct ResolveMotion {
  double gx0 = 0, gxi = 0, gxj = 0, gxh = 0, gy0 = 0, gyi = 0, gyj = 0, gyh = 0;
};
ResolveMotion resolve_motion(const Eigen::Isometry3d& world_from_m, const Eigen::Isometry3d& seed_world_from_m,
                             const Vec3& n, const Vec3& u, const Vec3& v, const Window& w);

// How compute_depth_gradient evaluates one patch: the steps, A's placements
// at the 11 configurations, which are rasterized and which re-solved from
// configuration 0's seeds or shifted from its map, and the culling bounds.
struct DepthPlan {
  double lin_step = 0, ang_step = 0;
  // Surface mode without the shortcut: configuration 0 rasterized with seeds,
  // the others re-solved from them; the translations by shift_m whole texels
  // (0: none, re-solved too) are shifts of h_A(0), which has border `border`.
  bool seeded = false;
  int shift_m = 0;
  int border = 0;
  double cx = 0, cy = 0;  // c_A in grid coordinates (the shortcut's rotation centre)
  // rasterize_heights' `cull` for A's and B's triangles (NaN: none).
  double cull_a = 0, cull_b = 0;
  Eigen::Isometry3d world_from_a[11];  // A's placement at each configuration (Config order)
  Eigen::Isometry3d world_from_b;
};
// False when the window is unusable (N <= 0 or cell <= 0): no contact.
bool plan_depth(const Model& A, const Pose& pose_a, const Model& B, const Pose& pose_b, const ContactPatch& patch,
                const ForceOptions& opt, DepthPlan& plan);

// The last step of compute_depth_gradient, shared by the backends: from
// delta_at[], lin_step and ang_step, sets covered (delta_at[0] > -inf),
// delta, grad (Eq. 7's central differences, one-sided next to an uncovered
// configuration; the translations' through kink_safe_difference) and
// uncovered_configurations.
void finish_depth_gradient(DepthGradient& g);

}  // namespace hrt
