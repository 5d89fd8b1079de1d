// Directional penetration depth (paper Eq. 8-9) and its gradient (Eq. 7) on
// the CPU; the force model that turns them into a wrench (Eq. 3-6) is in
// hrt/force.h.
//
// For one contact patch (contact.h: n, u, v, window, tris_a, tris_b):
//   1. The coarse triangles of A (tris_a) and of B (tris_b) are rasterized
//      orthographically along n into the N x N grid of patch.window (texel
//      centres as contact.h defines them). At each covered texel the per-corner
//      UV is interpolated (affine: the projection is orthographic), the atlas
//      is sampled bilinearly (the mapping f of Sec. 5.1; same convention as
//      Atlas::sample), the object-space point goes to the world and its height
//      is h = n . p (Eq. 1, 8). Per texel A keeps the largest h over its
//      triangles (its deepest point along n), B the smallest (its first point).
//   2. delta = max over texels covered by both of (h_A - h_B)   (Eq. 9).
//      Sign convention (docs/bundle-format.md): n points from A into B, so
//      delta > 0 means overlap, d delta / d n = +1, and the force on A is
//      along -n.
//   3. The gradient (Eq. 7) by central differences over the 11
//      configurations of A: 0, +-du, +-dv (translations along u, v),
//      +-dtheta_u, +-dtheta_v, +-dtheta_n (rotations about the axes u, v, n
//      through A's centre of mass c_A). d delta / d n = 1 by definition
//      (translating A along n adds the step to every h_A). The patch's
//      contact data (n, u, v, window, triangles) are frozen for all 11.
//      Where a kink of delta lies within a translation step, the steeper
//      one-sided difference replaces the central one (kink_safe_difference).
//   The wrench that follows from the gradient (Eq. 5-6) is hrt/force.h's.
//
// Nothing here allocates once DepthScratch is reserved for the largest
// resolution in use, and nothing prints: warnings are counted in a
// DepthWarnings that the caller owns.
#pragma once

#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "hrt/contact.h"
#include "hrt/model.h"

namespace hrt {

class TaskPool;  // src/parallel/task_pool.h

// Default stiffness k of Eq. 3 (N/m): 1 N/mm, the order of what a
// Phantom-class 6-DoF device renders stably through a virtual coupling
// (the paper does not give its value).
constexpr double kDefaultStiffness = 1000.0;
// Default grid resolution N (the paper's 50 x 50 buffer, Sec. 6.1 and 6.4).
constexpr int kDefaultResolution = 50;
// Largest grid resolution N of a patch ([force] resolution and
// max_resolution of a scene, hrt query --resolution; the Scene refuses
// more). A patch's depth buffers take about 110 N^2 bytes (13 N x N grids
// of doubles and the seeds): 115 MB at N = 1024, which keeps `hrt run` and
// `hrt query` under 1 GiB with any accepted value.
constexpr int kMaxResolution = 1024;

// How a texel's height is found (docs/bundle-format.md, "Heights").
enum class HeightMode : int {
  // The reconstructed full surface on the texel's column (default): for each
  // coarse triangle whose atlas points can lie beside their coarse point's
  // column by more than the lateral tolerance (SurfaceMap::lateral_bound),
  // the triangle's projection is grown by that bound and every texel centre
  // x in it is solved by the fixed point q <- q + (x - P(f(q))) (q a point of
  // the triangle in grid coordinates, P the projection along n), until the
  // atlas point f(q) projects within the lateral tolerance of x; the height is
  // n . f(q). Lookups never interpolate across a discontinuity of the atlas
  // (SurfaceMap::quad_ok). Other triangles are rasterized as in `coarse`.
  surface = 0,
  // The literal Eq. 8 of bundle format 1.0: n . f(q) at q's own column, q the
  // coarse point under the texel centre (parallax included). For comparison
  // and benchmarks.
  coarse = 1,
  // The displaced surface itself, conservative per grid texel: every usable
  // atlas quad (SurfaceMap::quad_ok) of each coarse face in reach, at any
  // angle to n (ContactPatch::reach_a / reach_b as well as tris_a / tris_b),
  // is split into two triangles whose corners are the atlas positions; each
  // triangle is projected along n, and every grid texel whose square
  // footprint it meets keeps the triangle's largest height over the
  // footprint (A; B the smallest), bounded by the plane's value at the
  // footprint's corners and by the triangle's corners. So a texel holds the
  // highest point of A's full surface over its whole square (to within the
  // triangles' flatness: the atlas quads' bilinear twist), not at its
  // centre: a tip or fin narrower than a texel cannot hide between centres,
  // a face turned away from n still contributes the parts of its surface
  // that stick out towards B, and the height of a texel changes
  // continuously as A moves. No fixed point. CPU backend only. See
  // docs/bundle-format.md "Heights".
  mesh = 2,
};

// "surface", "coarse", "mesh" (the names of scene files, flags and JSON).
const char* to_string(HeightMode mode);
// The name -> mode; false for anything else.
bool parse_height_mode(const std::string& name, HeightMode& out);

// Lateral tolerance of the surface mode, as a fraction of the smaller of the
// grid texel and the model's atlas texel: a converged f(q) projects within
// this of the texel centre, so the height error it adds is at most
// kLateralTolerance * min(cell, texel) * slope.
constexpr double kLateralTolerance = 0.05;
// Most fixed-point iterations per texel and triangle (each is one bilinear
// lookup); the iteration contracts by the lateral stretch of f, ~0.3 on the
// steepest relief of the test scenes, so 8 reach 1e-4 of the first offset.
constexpr int kMaxLateralIterations = 8;

struct ForceOptions {
  // Heights of Eq. 8: the reconstructed surface on the texel column (default)
  // or the literal coarse-column lookup of format 1.0 (see HeightMode).
  HeightMode heights = HeightMode::surface;
  // N: the grid of a patch window is N x N texels (the clustering code builds
  // windows with this N; compute_patch_wrench uses patch.window.resolution).
  int resolution = kDefaultResolution;
  // k of Eq. 3, N/m.
  double stiffness = kDefaultStiffness;
  // Translation step du = dv of Eq. 7, m. 0: one grid texel (window.cell), so
  // that the shortcut's shifted height maps are exact.
  double lin_step = 0;
  // Rotation step dtheta_u = dtheta_v = dtheta_n of Eq. 7, rad. 0: the
  // "matching angle" cell / R, R = the largest distance from c_A to the four
  // corners of the window: no point of the window moves by more than one
  // grid texel under any of the three rotations (see default_ang_step).
  double ang_step = 0;
  // The paper's Sec. 5.2 shortcut: h_A(+-du), h_A(+-dv) and h_A(+-dtheta_n)
  // are resampled from h_A(0) (rasterized with a border of ceil(du / cell)
  // texels) instead of rasterized again. Shifts by a whole number of texels
  // are exact; the n-rotation uses bilinear resampling (an approximation).
  // Only the in-plane rotations dtheta_u, dtheta_v are rendered again (the
  // paper's text lists h_A(+-du), h_A(+-dv) there: a typo, translations do
  // not need rendering, tilts do).
  bool shortcut = false;
};

// Counters the caller owns (in its State); the depth code never prints.
struct DepthWarnings {
  // Patches whose grid texel was coarser than half the shortest relief
  // wavelength of A or B (quality.min_wavelength, Sec. 7.2): counted once per
  // patch lifetime (see compute_patch_wrench's warned flag).
  uint64_t undersampled_patches = 0;
  // Finite-difference configurations of Eq. 7 in which no texel was covered
  // by both objects (a one-sided difference was used, or 0 when both sides
  // were uncovered).
  uint64_t uncovered_configurations = 0;
};

// Per-texel seeds of the surface mode: the atlas coordinates (2 doubles per
// texel) of the point each texel kept at configuration 0, and the
// atlas-per-grid Jacobian (4 floats) of the coarse triangle it came from.
struct HeightSeeds {
  std::vector<double> a;
  std::vector<float> j;
  // The texels that hold a seed (a finite height) lie in rows [j0, j1) and
  // columns [i0, i1) of the bordered map: set by rasterize_heights_seeded,
  // read by resolve_heights to skip the rest (the whole map until set).
  int i0 = 0, i1 = std::numeric_limits<int>::max(), j0 = 0, j1 = std::numeric_limits<int>::max();
  void reserve(int side) {  // side = N + 2 border
    const size_t n2 = static_cast<size_t>(side) * side;
    if (a.size() < 2 * n2) a.resize(2 * n2);
    if (j.size() < 4 * n2) j.resize(4 * n2);
  }
};

// Preallocated buffers for one patch evaluation (one per thread).
// Heights are stored relative to n . window.origin, in metres, as double;
// an uncovered texel of A holds -inf, of B +inf, so h_A - h_B is -inf there
// and never NaN.
struct DepthScratch {
  int capacity = 0;          // side length (texels, border included) reserved
  std::vector<double> hb;    // B's min heights, N x N
  std::vector<double> ha0;   // A at configuration 0, (N + 2 b)^2 with border b
  std::vector<double> ha;    // A at one configuration (directional_depth)
  std::vector<double> hcfg;  // A at the 10 perturbed configurations, N x N each
  HeightSeeds seeds;         // A's configuration-0 seeds (surface mode)
  // HeightMode::mesh: a patch's tris and reach lists of one side, joined.
  std::vector<uint32_t> tris_a, tris_b;

  // Border of the shortcut's h_A(0) map reserved by reserve() (texels); a
  // larger lin_step makes compute_patch_wrench grow the buffers once.
  static constexpr int kReservedBorder = 4;
  // Allocates for N x N grids (N <= resolution) with a border of
  // kReservedBorder texels. Call once before the frame loop.
  void reserve(int resolution);
};

// The 11 configurations of Eq. 7, in the order of DepthGradient::delta_at.
enum class Config : int {
  zero = 0,
  plus_u,
  minus_u,
  plus_v,
  minus_v,
  plus_theta_u,
  minus_theta_u,
  plus_theta_v,
  minus_theta_v,
  plus_theta_n,
  minus_theta_n,
  count
};

// Rigid motion of A (world frame, applied after A's pose) for one
// configuration: translation by +-lin_step along u or v, or rotation by
// +-ang_step about u, v or n through the point c (A's centre of mass, world).
Eigen::Isometry3d config_motion(Config c, const ContactPatch& patch, const Vec3& c_world, double lin_step,
                                double ang_step);

// Effective steps for a patch (resolving the 0 defaults of ForceOptions).
double effective_lin_step(const ContactPatch& patch, const ForceOptions& opt);
double default_ang_step(const ContactPatch& patch, const Vec3& c_a_world);
double effective_ang_step(const ContactPatch& patch, const Vec3& c_a_world, const ForceOptions& opt);

// True when the grid texel of `w` is coarser than half of the shortest relief
// wavelength recorded in A or B (quality.min_wavelength > 0), Sec. 7.2.
bool grid_undersamples(const Model& A, const Model& B, const Window& w);

// Height map of one surface (Eq. 8): rasterizes `tris` of model M placed by
// world_from_m orthographically along n into the window grid extended by
// `border` texels on every side, i.e. texel (i, j) for -border <= i, j <
// N + border is stored at out[(j + border) * (N + 2 border) + (i + border)].
// keep_max: keep the largest h per texel (A), else the smallest (B). The
// buffer is first filled with -inf (keep_max) or +inf. Heights are relative
// to n . w.origin. Allocates nothing.
// cull (NaN: none): in the surface mode a triangle on the costly path (its
// lateral bound beyond the tolerance), in the mesh mode a face, a block of
// quads or a quad, whose points all lie below `cull` (keep_max) or above it
// (else), relative to n . w.origin, is skipped: the
// caller knows no texel it covers can matter (compute_depth_gradient: A's
// triangles that cannot reach B's lowest possible point, and B's that A's
// highest cannot reach, less the configurations' motion: they could only
// give overlaps below zero, which make no force).
void rasterize_heights(const Model& M, const Eigen::Isometry3d& world_from_m, const std::vector<uint32_t>& tris,
                       const Vec3& n, const Vec3& u, const Vec3& v, const Window& w, int border, bool keep_max,
                       double* out, HeightMode mode = HeightMode::surface,
                       double cull = std::numeric_limits<double>::quiet_NaN());

// Eq. 9 for one configuration of A: world_from_a is A's whole placement
// (pose_a.iso(), possibly composed with a config_motion), world_from_b B's.
// Rasterizes both triangle lists of the patch over its window (frozen n, u,
// v, window) and returns max over texels covered by both of h_A - h_B (m).
// When no texel is covered by both, returns -infinity and sets *covered to
// false. Rasterizes B every call: for tests and tools; the force loop uses
// compute_patch_wrench.
double directional_depth(const Model& A, const Eigen::Isometry3d& world_from_a, const Model& B,
                         const Eigen::Isometry3d& world_from_b, const ContactPatch& patch, DepthScratch& scratch,
                         bool* covered = nullptr, HeightMode mode = HeightMode::surface);

// delta and gradient of one patch, without forces (the force model below
// is Eq. 5 applied to these). delta_at[c] holds delta at configuration c
// (-inf where uncovered).
struct DepthGradient {
  double delta = 0;
  Vec6 grad = Vec6::Zero();  // d delta / d(u, v, n, theta_u, theta_v, theta_n); [2] == 1
  bool covered = false;
  double lin_step = 0, ang_step = 0;  // the steps used
  double delta_at[static_cast<int>(Config::count)] = {};
  int uncovered_configurations = 0;
  // The contact region at configuration 0: the texels where A and B overlap
  // (h_A - h_B > 0), in window texel coordinates (texel (i, j) spans
  // [i, i + 1] x [j, j + 1]): their centroid weighted by the overlap, and
  // their bounding box. region_texels = 0 when delta <= 0 (touching within
  // the tolerance only: no overlap).
  int region_texels = 0;
  double region_center[2] = {0, 0};
  double region_lo[2] = {0, 0}, region_hi[2] = {0, 0};
};
// `pool` (optional; frame() passes it for a frame of one patch): in the
// mesh and coarse modes, A's rasterized configurations are shared between
// its threads in groups; in the surface mode, B's heights run beside A's
// configuration 0, then the re-solved configurations are shared. The result
// is the same bit for bit with or without it. Not while `pool` runs other
// tasks.
DepthGradient compute_depth_gradient(const Model& A, const Pose& pose_a, const Model& B, const Pose& pose_b,
                                     const ContactPatch& patch, const ForceOptions& opt, DepthScratch& scratch,
                                     TaskPool* pool = nullptr);

// A kink within Eq. 7's translation step.
//
// delta is the maximum over the window of h_A - h_B, so as A slides it is
// piecewise smooth, with a kink wherever the deepest point jumps from one
// feature to another: two nested reliefs make a V about the nested position
// (slopes -+2 a pi / lambda for gratings of amplitude a and wavelength
// lambda). The default step is one grid texel; when a kink lies within it,
// the central difference (delta(+h) - delta(-h)) / 2h averages the slopes of
// the two branches and misses by up to the whole slope (a V seen 0.1 step
// from its bottom gives a tenth of it). Both backends evaluate exactly the
// 11 configurations, so the kink is told from the three values of the axis:
//   s+ = (delta(+h) - delta(0)) / h, s- = (delta(0) - delta(-h)) / h,
//   turn = s+ - s-, q = turn / max(|s+|, |s-|).
// - A maximum of smooth branches only turns its slope upwards at a kink:
//   turn <= 0 (concave, straight) keeps the central difference.
// - Smooth curvature turns the slope by |delta''| h, a small part of it
//   where the step resolves the relief; a kink within the step by up to 2
//   (a V seen from its bottom). q <= kKinkSmoothTurn keeps the central
//   difference bit for bit, q >= kKinkStraddleTurn takes the one-sided
//   difference below, linear in between.
// - The side: the one-sided difference across the kink mixes the two
//   branches' slopes and is the smaller in size; the steeper one (s+ when
//   the central difference is positive, else s-) is configuration 0's own
//   branch: exact for a V of equal slopes (nested equal reliefs) and for any
//   kink seen from its steeper branch; seen from the shallower branch of an
//   uneven kink it is off by up to the turn (the central difference by half
//   of it).
// - Near a V's bottom the two sizes are alike and the side is undecided:
//   with r = |central| / (turn / 2) (for slopes of opposite signs, the
//   difference of their sizes over their sum; >= 1 for equal signs), r <=
//   kKinkUndecided keeps the central difference (0 at a symmetric V, whose
//   gradient there is undefined), r >= kKinkDecided the one-sided one,
//   linear in between: the gradient runs continuously through the V (no
//   force step as A crosses it), and is exact from about kKinkDecided of a
//   step from its bottom on. Within the ramp a difference of delta between
//   the backends (float rounding, the occlusion search's quantum) moves the
//   result up to 1 + 1 / (kKinkDecided - kKinkUndecided), about 15, times
//   as much as it moves the central difference; elsewhere at most twice
//   (one-sided).
// What it costs: the one-sided difference is first order (|delta''| h / 2 of
// the branch, against |delta'''| h^2 / 6 for the central one); a kink near
// the far end of the step, whose small turn the branch's own concave
// curvature cancels, goes unseen (the central difference is kept, off by
// the kink's share of the step); and a convex stretch that turns the slope
// by more than kKinkStraddleTurn over a step (the bottom of a smooth well,
// which three values cannot tell from a V) is differentiated one-sided too.
// And the force now turns within a fraction of a step at a V's bottom where
// it used to turn over two steps: a session's linear prediction between
// frames (the multirate model) follows it less well (on the ball sliding
// over the strip grating of tests/integration/test_session_physics.py at 100 Hz, RMS
// error 3.22 mN against 2.67 mN with Eq. 7's central differences).
// The rotations keep Eq. 7's central differences: their kinks include a
// flat face tilting on a flat face, whose smooth central-difference torque
// about the rest position the session's stiffness is built around.
//
// The curvature that apply_depth_gradient takes from the same delta_at[]
// (the second differences, (s+ - s-) / h: the session's stiffness and its
// multirate force model) is left as it is: across a kink within the step
// it is the kink's turn spread over the step, i.e. how much the gradient
// changes within about one step of motion, which is what a stiffness that
// stands for the force over the motion until the next frame has to
// anticipate (the one-sided gradient keeps its value up to the kink, then
// turns by the whole slope). Measured on the ball sliding over the strip
// grating of tests/integration/test_session_physics.py, leaving the kink's part out of
// it where the one-sided difference is used makes the multirate prediction
// worse (RMS error 3.44 mN against 3.22 mN with the turn kept).
constexpr double kKinkSmoothTurn = 0.02;
constexpr double kKinkStraddleTurn = 0.05;
constexpr double kKinkUndecided = 0.03;
constexpr double kKinkDecided = 0.10;
// d delta / dx from delta at x + step, x and x - step by the rule above;
// straddle (optional) gets the weight of the one-sided difference in the
// result (0: the central difference, 1: the steeper one-sided one).
double kink_safe_difference(double d_plus, double d_zero, double d_minus, double step, double* straddle = nullptr);

}  // namespace hrt
