// Height maps by orthographic rasterization (paper Eq. 8) and the depth of
// one configuration (Eq. 9). See hrt/depth.h for the conventions.
#include <algorithm>
#include <cmath>
#include <limits>

#if defined(__SSE4_1__)
#include <smmintrin.h>
#endif

#include "depth/internal.h"
#include "depth/mesh_rows.h"
#include "depth/reduce.h"
#include "depth/resolve_simd.h"
#include "hrt/depth.h"

namespace hrt {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
// Texel centres within this many grid texels outside a triangle's edge
// still count as inside it, so that a centre exactly on an edge shared by
// two triangles is never dropped by rounding (max/min make a centre counted
// twice harmless).
constexpr double kEdgeEps = 1e-9;
// Triangles whose projection has a smaller doubled area (grid texels^2) are
// edge-on along n: they cover no texel centre robustly, their neighbours do.
constexpr double kMinArea2 = 1e-12;

// The atlas in the form the inner loop wants: n_obj . (bilinear RGB), with
// the spec's convention (docs/bundle-format.md "UV to texel"): continuous
// texel coordinates x = u W - 0.5, y = (1 - v) H - 0.5, texels clamped to
// the image. Equal to n_obj . Atlas::sample(u, v) (tested), inlined because
// it runs once per covered texel per configuration. Positions are
// interpolated as float4 (the atlas is float32) and dotted with n once.
// The bilinear interpolation of four float4 texels (a b / c d, weights fx
// along x, fy along y), the one formula every lookup below uses.
struct Bilerp {
#if defined(__SSE4_1__)
  __m128 v;
  Bilerp(const float* a, const float* b, const float* c, const float* d, float fx, float fy) {
    const __m128 va = _mm_loadu_ps(a), vb = _mm_loadu_ps(b), vc = _mm_loadu_ps(c), vd = _mm_loadu_ps(d);
    const __m128 vfx = _mm_set1_ps(fx), vfy = _mm_set1_ps(fy);
    const __m128 top = _mm_add_ps(va, _mm_mul_ps(vfx, _mm_sub_ps(vb, va)));
    const __m128 bot = _mm_add_ps(vc, _mm_mul_ps(vfx, _mm_sub_ps(vd, vc)));
    v = _mm_add_ps(top, _mm_mul_ps(vfy, _mm_sub_ps(bot, top)));
  }
  // dot with the first three components of w4 (its fourth is ignored).
  float dot(const float* w4) const { return _mm_cvtss_f32(_mm_dp_ps(v, _mm_loadu_ps(w4), 0x71)); }
#else
  float p[3];
  Bilerp(const float* a, const float* b, const float* c, const float* d, float fx, float fy) {
    for (int k = 0; k < 3; ++k) {
      const float top = a[k] + fx * (b[k] - a[k]), bot = c[k] + fx * (d[k] - c[k]);
      p[k] = top + fy * (bot - top);
    }
  }
  float dot(const float* w4) const { return w4[0] * p[0] + w4[1] * p[1] + w4[2] * p[2]; }
#endif
};

struct HeightSampler {
  const float* rgba;
  int w, h;
  size_t stride;  // floats per atlas row
  float n[4];     // n_obj, 0 for the coverage channel
  // SurfaceMap::quad_ok (surface mode), or null (coarse mode: every quad is
  // used, as format 1.0 reads). A lookup in an unusable quad returns NaN,
  // which the max / min of the callers ignore (std::max(a, NaN) == a).
  const uint8_t* ok;

  // The clamped 2 x 2 footprint of (ax, ay): false in an unusable quad.
  inline bool footprint(double ax, double ay, const float** q, float& fx, float& fy) const {
    const double fx0 = std::floor(ax), fy0 = std::floor(ay);
    fx = static_cast<float>(ax - fx0), fy = static_cast<float>(ay - fy0);
    const int i0 = static_cast<int>(fx0), j0 = static_cast<int>(fy0);
    const int ia = std::clamp(i0, 0, w - 1), ib = std::clamp(i0 + 1, 0, w - 1);
    const int ja = std::clamp(j0, 0, h - 1), jb = std::clamp(j0 + 1, 0, h - 1);
    if (ok && !ok[static_cast<size_t>(ja) * w + ia]) return false;
    q[0] = rgba + ja * stride + ia * 4, q[1] = rgba + ja * stride + ib * 4;
    q[2] = rgba + jb * stride + ia * 4, q[3] = rgba + jb * stride + ib * 4;
    return true;
  }
  // Clamped lookup, valid anywhere.
  inline double clamped(double ax, double ay) const {
    const float* q[4];
    float fx, fy;
    if (!footprint(ax, ay, q, fx, fy)) return std::numeric_limits<double>::quiet_NaN();
    return Bilerp(q[0], q[1], q[2], q[3], fx, fy).dot(n);
  }
  // Lookup whose 2 x 2 footprint is known to lie inside the image
  // (0 <= ax < w - 1, 0 <= ay < h - 1): no clamping.
  inline double inside(double ax, double ay) const {
    const int i0 = static_cast<int>(ax), j0 = static_cast<int>(ay);  // truncation == floor for ax, ay >= 0
    const float fx = static_cast<float>(ax - i0), fy = static_cast<float>(ay - j0);
    if (ok && !ok[static_cast<size_t>(j0) * w + i0]) return std::numeric_limits<double>::quiet_NaN();
    const float* p = rgba + j0 * stride + i0 * 4;
    return Bilerp(p, p + 4, p + stride, p + stride + 4, fx, fy).dot(n);
  }
  // The bilinear point at atlas coordinates (ax, ay) (clamped lookup) dotted
  // with gx, gy (float4, object frame, 0 last) and with n: its grid
  // coordinates (before the placement's offsets) and height. Float, as the
  // atlas is: the products are <= ~1e3 grid texels, so rounding is ~1e-4
  // texel, far below the lateral tolerance. False in an unusable quad.
  inline bool project(double ax, double ay, const float* gx4, const float* gy4, double& px, double& py,
                      double& ph) const {
    if (!(ax > -1e6 && ax < 1e6 && ay > -1e6 && ay < 1e6)) return false;  // also NaN
    const float* q[4];
    float fx, fy;
    if (!footprint(ax, ay, q, fx, fy)) return false;
    const Bilerp b(q[0], q[1], q[2], q[3], fx, fy);
    px = b.dot(gx4);
    py = b.dot(gy4);
    ph = b.dot(n);
    return true;
  }
};

}  // namespace

namespace {

// One placement of a model over the grid: the affine maps from object space
// to grid coordinates and to heights, and the sampler dotted with n_obj.
struct Placement {
  Vec3 gx, gy;  // grid x = gx . P + ox, y = gy . P + oy (texel centres at integers, border included)
  double ox, oy;
  double oh;  // h = sample . (n_obj) + oh, relative to n . origin
  HeightSampler sample;
  int S;  // side of the output buffer
  bool keep_max;
  double* out;
  // Surface mode (HeightMode::surface): the model's surface map, n in the
  // object frame, the lateral tolerance (grid texels) and the grid texel (m).
  const SurfaceMap* surface;
  Vec3 nobj;
  double tol;
  double cell;
  // Optional seed outputs (config 0 of the surface mode, HeightSeeds): per
  // texel the atlas coordinates of the point kept and the atlas-per-grid
  // Jacobian of the triangle it came from.
  double* seed_a = nullptr;
  float* seed_j = nullptr;
  float gx4[4] = {}, gy4[4] = {};                          // gx, gy as float4 for HeightSampler::project
  double cull = std::numeric_limits<double>::quiet_NaN();  // see rasterize_heights (depth.h)
  // HeightMode::mesh: the atlas quads themselves (raster_triangle_mesh).
  bool mesh = false;
};

Placement make_placement(const Model& M, const Eigen::Isometry3d& world_from_m, const Vec3& n, const Vec3& u,
                         const Vec3& v, const Window& w, int border, bool keep_max, double* out, HeightMode mode) {
  const PlacementParams pp = placement_params(M, world_from_m, n, u, v, w, border, mode);
  const Atlas& at = M.atlas;
  Placement pl{pp.gx,
               pp.gy,
               pp.ox,
               pp.oy,
               pp.oh,
               HeightSampler{at.rgba.data(),
                             at.width,
                             at.height,
                             static_cast<size_t>(at.width) * 4,
                             {pp.n4[0], pp.n4[1], pp.n4[2], 0.0f},
                             pp.surface ? M.surface.quad_ok.data() : nullptr},
               w.resolution + 2 * border,
               keep_max,
               out,
               pp.surface ? &M.surface : nullptr,
               pp.nobj,
               pp.tol,
               w.cell};
  for (int k = 0; k < 4; ++k) {
    pl.gx4[k] = pp.gx4[k];
    pl.gy4[k] = pp.gy4[k];
  }
  if (mode == HeightMode::mesh && M.surface.ready) {
    pl.mesh = true;
    pl.surface = &M.surface;
    pl.sample.ok = M.surface.quad_ok.data();
  }
  return pl;
}

inline void write_seed(const Placement& pl, size_t k, double a_x, double a_y, double jxx, double jxy, double jyx,
                       double jyy) {
  pl.seed_a[2 * k] = a_x;
  pl.seed_a[2 * k + 1] = a_y;
  float* J = pl.seed_j + 4 * k;
  J[0] = static_cast<float>(jxx), J[1] = static_cast<float>(jxy), J[2] = static_cast<float>(jyx),
  J[3] = static_cast<float>(jyy);
}

// The heights of face f's full-surface points lie within the surface map's
// reach of its corners': [hlo, hhi] (relative to n . origin). True when the
// whole range is on the far side of pl.cull (the face cannot matter; a NaN
// cull never culls).
inline bool culled_by_height(const Model& M, uint32_t f, const Placement& pl, double& hlo, double& hhi) {
  const double reach = pl.mesh ? pl.surface->faces[f].quad_reach : pl.surface->faces[f].reach;
  hlo = kInf, hhi = -kInf;
  for (int c = 0; c < 3; ++c) {
    const double h = pl.nobj.dot(M.vertices[M.faces[f][c]]);
    hlo = std::min(hlo, h);
    hhi = std::max(hhi, h);
  }
  hlo += pl.oh - reach;
  hhi += pl.oh + reach;
  return pl.keep_max ? hhi < pl.cull : hlo > pl.cull;
}

// The scalar reference of the surface mode's fixed points instead of the
// vectorized loops (use_reference_heights, hrt/depth.h).
thread_local bool t_reference_heights = false;

// The surface mode for a triangle whose atlas points can lie up to L grid
// texels beside their coarse point's column (L > the lateral tolerance).
//
// Every texel centre X within L (+ tolerance) of the triangle's projection
// can be the column of one of its points, so those are visited (the
// triangle's box grown by L, then the three edges moved out by L). For each,
// the fixed point q <- q + (X - P(f(q))) runs on the coarse point q (grid
// coordinates of the triangle's plane, atlas coordinates by the triangle's
// affine UV map, extended past its edges), starting from X clamped into the
// triangle. It stops when P(f(q)) is within the tolerance of X (the height is
// then n . f(q)), when q leaves the triangle grown by one atlas texel (that
// point belongs to a neighbour, which visits X itself), when a lookup falls
// in an unusable quad, or after kMaxLateralIterations. The contraction is
// I - dP(f)/dq, small wherever f's lateral stretch is near 1 (f = q + w with
// w slowly turning). Expressible in a fragment shader: one loop of lookups.
void raster_triangle_surface(const Model& M, uint32_t f, const Placement& pl, const double* x, const double* y,
                             const double* ax, const double* ay, double L) {
  const int S = pl.S;
  const double tol = pl.tol, tol2 = tol * tol;
  const double D = L + tol;
  const double xmin = std::min({x[0], x[1], x[2]}) - D, xmax = std::max({x[0], x[1], x[2]}) + D;
  const double ymin = std::min({y[0], y[1], y[2]}) - D, ymax = std::max({y[0], y[1], y[2]}) + D;
  if (!(xmax >= 0) || !(xmin <= S - 1) || !(ymax >= 0) || !(ymin <= S - 1)) return;
  const int i0 = static_cast<int>(std::ceil(std::max(xmin, 0.0)));
  const int i1 = static_cast<int>(std::floor(std::min(xmax, static_cast<double>(S - 1))));
  const int j0 = static_cast<int>(std::ceil(std::max(ymin, 0.0)));
  const int j1 = static_cast<int>(std::floor(std::min(ymax, static_cast<double>(S - 1))));
  if (i0 > i1 || j0 > j1) return;

  const double e1x = x[1] - x[0], e1y = y[1] - y[0];
  const double e2x = x[2] - x[0], e2y = y[2] - y[0];
  const double area2 = e1x * e2y - e2x * e1y;
  const double inv = 1.0 / area2;
  const double dax_dx = ((ax[1] - ax[0]) * e2y - (ax[2] - ax[0]) * e1y) * inv;
  const double dax_dy = ((ax[2] - ax[0]) * e1x - (ax[1] - ax[0]) * e2x) * inv;
  const double day_dx = ((ay[1] - ay[0]) * e2y - (ay[2] - ay[0]) * e1y) * inv;
  const double day_dy = ((ay[2] - ay[0]) * e1x - (ay[1] - ay[0]) * e2x) * inv;
  // Barycentric b_k of grid point (px, py): b1 = ((px - x0) e2y - e2x (py - y0)) / area2,
  // b2 = (e1x (py - y0) - (px - x0) e1y) / area2; outside distance of edge k
  // (opposite corner k) = -b_k |area2| / |edge k|.
  const double len[3] = {std::hypot(x[2] - x[1], y[2] - y[1]), std::hypot(x[0] - x[2], y[0] - y[2]),
                         std::hypot(x[1] - x[0], y[1] - y[0])};
  const double aa = std::abs(area2);
  const double scale[3] = {aa / len[0], aa / len[1], aa / len[2]};  // b_k -> grid texels from edge k
  // One atlas texel in grid texels (the triangle's UV map scales areas by
  // |det|): the ownership margin.
  const double det = std::abs(dax_dx * day_dy - dax_dy * day_dx);
  const double margin = (det > 0 ? 1.0 / std::sqrt(det) : 1.0) + tol;
  double hlo, hhi;
  if (culled_by_height(M, f, pl, hlo, hhi)) return;
  const HeightSampler& sample = pl.sample;
  auto bary = [&](double px, double py, double* b) {
    const double dx = px - x[0], dy = py - y[0];
    b[1] = (dx * e2y - e2x * dy) * inv;
    b[2] = (e1x * dy - dx * e1y) * inv;
    b[0] = 1.0 - b[1] - b[2];
  };

  depth_simd::SurfaceTri tri{};
  if (!t_reference_heights) {
    tri.rgba = sample.rgba, tri.w = sample.w, tri.h = sample.h, tri.stride = static_cast<int>(sample.stride);
    tri.ok = sample.ok;
    for (int c = 0; c < 4; ++c) tri.n4[c] = sample.n[c], tri.gx4[c] = pl.gx4[c], tri.gy4[c] = pl.gy4[c];
    tri.ox = pl.ox, tri.oy = pl.oy, tri.oh = pl.oh, tri.tol2 = tol2;
    tri.x0 = x[0], tri.y0 = y[0], tri.x1 = x[1], tri.y1 = y[1], tri.x2 = x[2], tri.y2 = y[2];
    tri.e1x = e1x, tri.e1y = e1y, tri.e2x = e2x, tri.e2y = e2y, tri.inv = inv;
    tri.ax0 = ax[0], tri.ay0 = ay[0], tri.dax_dx = dax_dx, tri.dax_dy = dax_dy, tri.day_dx = day_dx,
    tri.day_dy = day_dy;
    for (int k = 0; k < 3; ++k) tri.scale[k] = scale[k];
    tri.margin = margin, tri.hlo = hlo, tri.hhi = hhi, tri.keep_max = pl.keep_max;
  }
  // The vector path's queue of texels (any rows), run kSpan at a time.
  size_t k_q[depth_simd::kSpan];
  double x_q[depth_simd::kSpan], y_q[depth_simd::kSpan], h_q[depth_simd::kSpan], ax_q[depth_simd::kSpan],
      ay_q[depth_simd::kSpan];
  uint8_t w_q[depth_simd::kSpan];
  int n_q = 0;
  auto flush = [&]() {
    for (int t = n_q; t < depth_simd::kSpan && (t & 7); ++t) x_q[t] = y_q[t] = h_q[t] = 0.0;  // padding lanes
    depth_simd::surface_texels(tri, n_q, x_q, y_q, h_q, ax_q, ay_q, w_q);
    for (int t = 0; t < n_q; ++t) {
      if (!w_q[t]) continue;
      pl.out[k_q[t]] = h_q[t];
      if (pl.seed_a) write_seed(pl, k_q[t], ax_q[t], ay_q[t], dax_dx, dax_dy, day_dx, day_dy);
    }
    n_q = 0;
  };
  // b_k(x, y) is affine: b_k = alpha_k(y) + beta_k x along a row.
  const double beta[3] = {-(e2y - e1y) * inv, e2y * inv, -e1y * inv};
  for (int j = j0; j <= j1; ++j) {
    // The row's span: b_k scale_k >= -D for the three edges.
    double lo = i0, hi = i1;
    {
      double b0[3];
      bary(0.0, j, b0);
      for (int k = 0; k < 3 && lo <= hi; ++k) {
        const double lim = -D / scale[k] - b0[k];  // beta_k x >= lim
        if (beta[k] > 0)
          lo = std::max(lo, lim / beta[k]);
        else if (beta[k] < 0)
          hi = std::min(hi, lim / beta[k]);
        else if (lim > 0)
          hi = lo - 1;
      }
    }
    if (!(lo <= hi)) continue;
    const int ia = static_cast<int>(std::ceil(lo - 1e-9)), ib = static_cast<int>(std::floor(hi + 1e-9));
    double* row = pl.out + static_cast<size_t>(j) * S;
    if (!t_reference_heights) {  // queued for the vectorized loop (src/depth/resolve_simd.cpp)
      for (int i = std::max(ia, i0); i <= std::min(ib, i1); ++i) {
        if (pl.keep_max ? row[i] >= hhi : row[i] <= hlo) continue;
        k_q[n_q] = static_cast<size_t>(j) * S + i, x_q[n_q] = i, y_q[n_q] = j, h_q[n_q] = row[i];
        if (++n_q == depth_simd::kSpan) flush();
      }
      continue;
    }
    for (int i = std::max(ia, i0); i <= std::min(ib, i1); ++i) {
      // A texel already at or beyond anything this triangle can give is done.
      if (pl.keep_max ? row[i] >= hhi : row[i] <= hlo) continue;
      // The start depends on the texel alone (X clamped into the triangle),
      // not on its neighbours' solutions: the GL backend runs one texel per
      // fragment and must converge to the same point. A warm start from the
      // row's previous texel was 4-10 % faster on the scraping bench (texture
      // force per frame, N = 50 and 128, examples/bench_heights.sh's scene)
      // but made the result depend on the order of texels and triangles.
      double qx = i, qy = j;
      double b[3];
      bary(qx, qy, b);
      if (b[0] < 0 || b[1] < 0 || b[2] < 0) {
        const double c0 = std::max(b[0], 0.0), c1 = std::max(b[1], 0.0), c2 = std::max(b[2], 0.0);
        const double cs = c0 + c1 + c2;
        qx = (c0 * x[0] + c1 * x[1] + c2 * x[2]) / cs;
        qy = (c0 * y[0] + c1 * y[1] + c2 * y[2]) / cs;
      }
      for (int it = 0; it < kMaxLateralIterations; ++it) {
        const double a_x = ax[0] + dax_dx * (qx - x[0]) + dax_dy * (qy - y[0]);
        const double a_y = ay[0] + day_dx * (qx - x[0]) + day_dy * (qy - y[0]);
        double px, py, ph;
        if (!sample.project(a_x, a_y, pl.gx4, pl.gy4, px, py, ph)) break;
        const double rx = i - (px + pl.ox), ry = j - (py + pl.oy);
        if (rx * rx + ry * ry <= tol2) {
          const double h = ph + pl.oh;
          if (pl.keep_max ? h > row[i] : h < row[i]) {
            row[i] = h;
            if (pl.seed_a) write_seed(pl, static_cast<size_t>(j) * S + i, a_x, a_y, dax_dx, dax_dy, day_dx, day_dy);
          }
          break;
        }
        qx += rx;
        qy += ry;
        double bq[3];
        bary(qx, qy, bq);
        if (bq[0] * scale[0] < -margin || bq[1] * scale[1] < -margin || bq[2] * scale[2] < -margin) break;
      }
    }
  }
  if (n_q > 0) flush();
}

// One projected atlas texel of the mesh mode: grid coordinates and height.
struct MeshCorner {
  double x, y, h;
  bool ok;
};

// Conservative rasterization of one projected triangle (grid coordinates,
// texel centres at integers, so texel (i, j)'s footprint is [i - 0.5, i +
// 0.5] x [j - 0.5, j + 0.5]) into pl.out: every texel whose footprint the
// triangle meets keeps (keep_max) the largest height the triangle's plane
// reaches over the footprint, at most its highest corner; else the smallest.
// The footprint test is the separating-axis test of a triangle and a square
// (the square's two axes by the bounding box, then the three edge normals).
inline void splat_triangle(const Placement& pl, const MeshCorner& c0, const MeshCorner& c1, const MeshCorner& c2) {
  const int S = pl.S;
  const double xmin = std::min({c0.x, c1.x, c2.x}), xmax = std::max({c0.x, c1.x, c2.x});
  const double ymin = std::min({c0.y, c1.y, c2.y}), ymax = std::max({c0.y, c1.y, c2.y});
  if (!(xmax >= -0.5) || !(xmin <= S - 0.5) || !(ymax >= -0.5) || !(ymin <= S - 0.5)) return;
  // Footprints meeting the box: i - 0.5 <= xmax and i + 0.5 >= xmin.
  const int i0 = std::max(0, static_cast<int>(std::ceil(xmin - 0.5)));
  const int i1 = std::min(S - 1, static_cast<int>(std::floor(xmax + 0.5)));
  const int j0 = std::max(0, static_cast<int>(std::ceil(ymin - 0.5)));
  const int j1 = std::min(S - 1, static_cast<int>(std::floor(ymax + 0.5)));
  if (i0 > i1 || j0 > j1) return;
  const bool mx = pl.keep_max;
  const double hext = mx ? std::max({c0.h, c1.h, c2.h}) : std::min({c0.h, c1.h, c2.h});
  if (i0 == i1 && j0 == j1) {  // the common case: a quad smaller than a texel
    double& o = pl.out[static_cast<size_t>(j0) * S + i0];
    o = mx ? std::max(o, hext) : std::min(o, hext);
    return;
  }
  const double e1x = c1.x - c0.x, e1y = c1.y - c0.y, e2x = c2.x - c0.x, e2y = c2.y - c0.y;
  const double area2 = e1x * e2y - e2x * e1y;
  // The plane h = c0.h + a (x - c0.x) + b (y - c0.y); a sliver (edge-on
  // along n) keeps its extreme corner over its whole box.
  double a = 0, b = 0;
  bool plane = std::abs(area2) > 1e-12;
  if (plane) {
    const double inv = 1.0 / area2;
    const double dh1 = c1.h - c0.h, dh2 = c2.h - c0.h;
    a = (dh1 * e2y - dh2 * e1y) * inv;
    b = (dh2 * e1x - dh1 * e2x) * inv;
    plane = std::isfinite(a) && std::isfinite(b);
  }
  // Edge k from corner k to corner k + 1 with the inward normal (ny, -nx)
  // times the orientation: inside where E_k(x, y) >= 0. A square meets the
  // triangle's half-plane when E_k at its corner farthest inside is >= 0,
  // i.e. E_k(centre) + 0.5 (|gx| + |gy|) >= 0.
  const MeshCorner* C[3] = {&c0, &c1, &c2};
  const double sgn = area2 >= 0 ? 1.0 : -1.0;
  double gx[3], gy[3], g0[3], reach[3];
  for (int k = 0; k < 3; ++k) {
    const MeshCorner& p = *C[k];
    const MeshCorner& q = *C[(k + 1) % 3];
    gx[k] = -sgn * (q.y - p.y);
    gy[k] = sgn * (q.x - p.x);
    g0[k] = -(gx[k] * p.x + gy[k] * p.y);
    reach[k] = 0.5 * (std::abs(gx[k]) + std::abs(gy[k])) + 1e-9 * (std::abs(g0[k]) + 1.0);
  }
  const double slack = 0.5 * (std::abs(a) + std::abs(b));
  for (int j = j0; j <= j1; ++j) {
    double* row = pl.out + static_cast<size_t>(j) * S;
    for (int i = i0; i <= i1; ++i) {
      bool meets = true;
      for (int k = 0; k < 3 && meets; ++k) meets = gx[k] * i + gy[k] * j + g0[k] + reach[k] >= 0;
      if (!meets) continue;
      double h = hext;
      if (plane) {
        const double hc = c0.h + a * (i - c0.x) + b * (j - c0.y);
        h = mx ? std::min(hext, hc + slack) : std::max(hext, hc - slack);
      }
      row[i] = mx ? std::max(row[i], h) : std::min(row[i], h);
    }
  }
}

// Occluded faces (true: nothing to draw): where every texel the face can
// reach already holds a height at least as extreme as any of its points, it
// can change nothing
// (the max is exact whatever the order; mesh_order draws the most extreme
// faces first so that this test bites). Scanned only when the texels are
// fewer than the face's quads.
static bool face_occluded(const Placement& pl, const double* x, const double* y, const double* ax, const double* ay,
                          const double R, const double hlo, const double hhi) {
  const int S = pl.S;
  const int i0 = std::max(0, static_cast<int>(std::ceil(std::min({x[0], x[1], x[2]}) - R - 0.5)));
  const int i1 = std::min(S - 1, static_cast<int>(std::floor(std::max({x[0], x[1], x[2]}) + R + 0.5)));
  const int j0 = std::max(0, static_cast<int>(std::ceil(std::min({y[0], y[1], y[2]}) - R - 0.5)));
  const int j1 = std::min(S - 1, static_cast<int>(std::floor(std::max({y[0], y[1], y[2]}) + R + 0.5)));
  if (i0 > i1 || j0 > j1) return true;  // reaches no texel: nothing to draw
  const double area2 = (ax[1] - ax[0]) * (ay[2] - ay[0]) - (ax[2] - ax[0]) * (ay[1] - ay[0]);
  const double texels = static_cast<double>(i1 - i0 + 1) * (j1 - j0 + 1);
  if (texels < 0.5 * std::abs(area2)) {
    bool occluded = true;
    for (int j = j0; j <= j1 && occluded; ++j) {
      const double* row = pl.out + static_cast<size_t>(j) * S;
      for (int i = i0; i <= i1; ++i)
        if (pl.keep_max ? row[i] < hhi : row[i] > hlo) {
          occluded = false;
          break;
        }
    }
    if (occluded) return true;
  }
  return false;
}

// Block tests (SurfaceMap::Block): the box projected by its centre and
// half-extents; a block passes when its box can reach the grid, the near
// side of the cull, and a texel that holds less than the box's extreme.
static bool block_passes(const Placement& pl, const SurfaceMap& sm, const int bi, const int bj) {
  constexpr int B = SurfaceMap::kQuadBlock;
  const int S = pl.S;
  const bool mx = pl.keep_max;
  const double cull = pl.cull;
  const bool cull_on = std::isfinite(cull);
  const SurfaceMap::Block& blk = sm.blocks[static_cast<size_t>(bj) * sm.blocks_w + bi];
  if (blk.lo.x() > blk.hi.x()) return false;  // no usable quad
  const Vec3 c = 0.5 * (blk.lo.cast<double>() + blk.hi.cast<double>());
  const Vec3 e = 0.5 * (blk.hi.cast<double>() - blk.lo.cast<double>());
  const double xc = pl.gx.dot(c) + pl.ox, yc = pl.gy.dot(c) + pl.oy, hc = pl.nobj.dot(c) + pl.oh;
  const double xe = pl.gx.cwiseAbs().dot(e), ye = pl.gy.cwiseAbs().dot(e), he = pl.nobj.cwiseAbs().dot(e);
  if (xc + xe < -0.5 || xc - xe > S - 0.5 || yc + ye < -0.5 || yc - ye > S - 0.5) return false;
  const double hx = mx ? hc + he : hc - he;  // the box's extreme
  if (cull_on && (mx ? hx < cull : hx > cull)) return false;
  const int i0 = std::max(0, static_cast<int>(std::ceil(xc - xe - 0.5)));
  const int i1 = std::min(S - 1, static_cast<int>(std::floor(xc + xe + 0.5)));
  const int j0 = std::max(0, static_cast<int>(std::ceil(yc - ye - 0.5)));
  const int j1 = std::min(S - 1, static_cast<int>(std::floor(yc + ye + 0.5)));
  if ((i1 - i0 + 1) * (j1 - j0 + 1) > B * B) return true;  // not worth the scan
  for (int j = j0; j <= j1; ++j) {
    const double* row = pl.out + static_cast<size_t>(j) * S;
    for (int i = i0; i <= i1; ++i)
      if (mx ? row[i] < hx : row[i] > hx) return true;
  }
  return false;  // occluded
}

// Projects atlas texels (i0..i1, j) into out[i - qi0] (grid coordinates and height).
static void project_texels(const Placement& pl, const float* rgba, const size_t stride, const int qi0, const int j,
                           const int i0, const int i1, MeshCorner* out) {
  const float* t = rgba + static_cast<size_t>(j) * stride + static_cast<size_t>(i0) * 4;
  for (int i = i0; i <= i1; ++i, t += 4) {
    const double px = t[0], py = t[1], pz = t[2];
    MeshCorner& c = out[i - qi0];
    c.x = pl.gx[0] * px + pl.gx[1] * py + pl.gx[2] * pz + pl.ox;
    c.y = pl.gy[0] * px + pl.gy[1] * py + pl.gy[2] * pz + pl.oy;
    c.h = pl.nobj[0] * px + pl.nobj[1] * py + pl.nobj[2] * pz + pl.oh;
    c.ok = std::isfinite(c.x) && std::isfinite(c.y) && std::isfinite(c.h);
  }
}

// HeightMode::mesh for coarse face f: every usable atlas quad whose centre
// lies within one atlas texel of the face's UV triangle (the face's own
// texels and the seam's: neighbouring faces of a chart share quads across
// their edge, harmlessly visited twice; across a chart border the gutter's
// quads close the gap), split along its (i, j)-(i + 1, j + 1) diagonal into
// two triangles on the atlas positions, conservatively rasterized.
//
// Why hand-written: this is what a GPU does with a grid mesh and texel
// fetches, but the CPU backend must agree with the GL one texel for texel
// and needs conservative coverage (no GL 4.5 core feature gives it).
void raster_triangle_mesh(const Model& M, uint32_t f, const Placement& pl, const double* x, const double* y,
                          const double* ax, const double* ay) {
  const int S = pl.S;
  MeshRows rows_of;
  if (!rows_of.setup(M, f, pl.nobj, pl.oh, S, pl.cell, pl.keep_max, pl.cull, x, y, ax, ay)) return;
  const double R = rows_of.R, hlo = rows_of.hlo, hhi = rows_of.hhi;
  if (face_occluded(pl, x, y, ax, ay, R, hlo, hhi)) return;
  const Atlas& at = M.atlas;
  const int W = at.width;
  const int qi0 = rows_of.qi0, qi1 = rows_of.qi1, qj0 = rows_of.qj0, qj1 = rows_of.qj1;
  auto row_range = [&](int j, int& lo, int& hi) { rows_of.range(j, lo, hi); };

  // Two rows of projected texels, indexed by i - qi0, with the interval of
  // each that holds projections. thread_local: grows to the widest face once
  // per thread, so the frame loop does not allocate afterwards.
  const int nq = qi1 - qi0 + 2;
  thread_local std::vector<MeshCorner> rows;
  if (rows.size() < 2 * static_cast<size_t>(nq)) rows.resize(2 * static_cast<size_t>(nq));
  MeshCorner* top = rows.data();
  MeshCorner* bot = rows.data() + nq;
  int top_row = -1, top_lo = 1, top_hi = 0, bot_row = -1, bot_lo = 1, bot_hi = 0;
  const float* rgba = at.rgba.data();
  const size_t stride = static_cast<size_t>(W) * 4;
  auto project = [&](int j, int i0, int i1, MeshCorner* out) { project_texels(pl, rgba, stride, qi0, j, i0, i1, out); };
  // Makes row buffer `buf` (holding texel row `row` over [lo, hi]) hold
  // texel row j over at least [a, b].
  auto ensure = [&](MeshCorner* buf, int& row, int& lo, int& hi, int j, int a, int b) {
    if (row != j || lo > hi || b < lo - 1 || a > hi + 1) {
      project(j, a, b, buf);
      row = j, lo = a, hi = b;
      return;
    }
    if (a < lo) project(j, a, lo - 1, buf), lo = a;
    if (b > hi) project(j, hi + 1, b, buf), hi = b;
  };
  const uint8_t* ok = pl.surface->quad_ok.data();
  const bool mx = pl.keep_max;
  const double cull = pl.cull;
  const bool cull_on = std::isfinite(cull);
  constexpr int B = SurfaceMap::kQuadBlock;
  const SurfaceMap& sm = *pl.surface;
  thread_local std::vector<int> rlo, rhi;
  thread_local std::vector<uint8_t> pass;
  for (int bj = qj0 / B; bj <= qj1 / B; ++bj) {
    const int ja = std::max(qj0, bj * B), jb = std::min(qj1, bj * B + B - 1);
    rlo.assign(B, 1), rhi.assign(B, 0);
    int ulo = std::numeric_limits<int>::max(), uhi = -1;
    for (int j = ja; j <= jb; ++j) {
      row_range(j, rlo[j - ja], rhi[j - ja]);
      if (rlo[j - ja] <= rhi[j - ja]) ulo = std::min(ulo, rlo[j - ja]), uhi = std::max(uhi, rhi[j - ja]);
    }
    if (ulo > uhi) continue;
    const int bi0 = ulo / B, bi1 = uhi / B;
    pass.assign(static_cast<size_t>(bi1 - bi0 + 1), 0);
    bool any = false;
    for (int bi = bi0; bi <= bi1; ++bi) any |= (pass[bi - bi0] = block_passes(pl, sm, bi, bj)) != 0;
    if (!any) continue;
    for (int j = ja; j <= jb; ++j) {
      const int lo_j = rlo[j - ja], hi_j = rhi[j - ja];
      if (lo_j > hi_j) continue;
      const uint8_t* okrow = ok + static_cast<size_t>(j) * W;
      // Runs of passing blocks within [lo_j, hi_j].
      for (int bi = lo_j / B; bi <= hi_j / B; ++bi) {
        if (!pass[bi - bi0]) continue;
        int bend = bi;
        while (bend + 1 <= hi_j / B && pass[bend + 1 - bi0]) ++bend;
        const int lo = std::max(lo_j, bi * B), hi = std::min(hi_j, bend * B + B - 1);
        bi = bend;
        // Texel rows j and j + 1 over [lo, hi + 1]; the buffer holding row j
        // (last row's bottom) becomes the top.
        if (bot_row == j) {
          std::swap(top, bot);
          std::swap(top_row, bot_row), std::swap(top_lo, bot_lo), std::swap(top_hi, bot_hi);
        }
        ensure(top, top_row, top_lo, top_hi, j, lo, hi + 1);
        ensure(bot, bot_row, bot_lo, bot_hi, j + 1, lo, hi + 1);
        for (int i = lo; i <= hi; ++i) {
          if (!okrow[i]) continue;
          const int k = i - qi0;
          const MeshCorner &c00 = top[k], &c10 = top[k + 1], &c01 = bot[k], &c11 = bot[k + 1];
          if (!(c00.ok && c10.ok && c01.ok && c11.ok)) continue;
          const double hq = mx ? std::max({c00.h, c10.h, c01.h, c11.h}) : std::min({c00.h, c10.h, c01.h, c11.h});
          if (cull_on && (mx ? hq < cull : hq > cull)) continue;  // on the far side of the cull
          // A quad inside one texel's square (the common case where the atlas is
          // finer than the grid): its highest corner is the highest point of its
          // two triangles there, one update.
          const double lx = std::min({c00.x, c10.x, c01.x, c11.x}), hx = std::max({c00.x, c10.x, c01.x, c11.x});
          const double ly = std::min({c00.y, c10.y, c01.y, c11.y}), hy = std::max({c00.y, c10.y, c01.y, c11.y});
          if (hx < -0.5 || lx > S - 0.5 || hy < -0.5 || ly > S - 0.5) continue;  // beside the grid
          const double ci = std::floor(lx + 0.5), cj = std::floor(ly + 0.5);
          if (hx < ci + 0.5 && hy < cj + 0.5 && ci >= 0 && cj >= 0 && ci < S && cj < S) {
            double& o = pl.out[static_cast<size_t>(cj) * S + static_cast<size_t>(ci)];
            o = mx ? std::max(o, hq) : std::min(o, hq);
            continue;
          }
          {  // occluded: the (at most 2 x 2) texels its box meets already hold more
            const int i0 = std::max(0, static_cast<int>(std::ceil(lx - 0.5)));
            const int i1 = std::min(S - 1, static_cast<int>(std::floor(hx + 0.5)));
            const int j0 = std::max(0, static_cast<int>(std::ceil(ly - 0.5)));
            const int j1 = std::min(S - 1, static_cast<int>(std::floor(hy + 0.5)));
            if (i1 - i0 <= 1 && j1 - j0 <= 1) {
              bool occluded = true;
              for (int jj = j0; jj <= j1 && occluded; ++jj)
                for (int ii = i0; ii <= i1 && occluded; ++ii) {
                  const double o = pl.out[static_cast<size_t>(jj) * S + ii];
                  occluded = mx ? o >= hq : o <= hq;
                }
              if (occluded) continue;
            }
          }
          splat_triangle(pl, c00, c10, c11);
          splat_triangle(pl, c00, c11, c01);
        }
      }
    }
  }
}

// Rasterizes coarse triangle f of M under placement pl into pl.out.
void raster_triangle(const Model& M, uint32_t f, const Placement& pl) {
  const int S = pl.S;
  const double W = M.atlas.width, H = M.atlas.height;
  const Tri& tri = M.faces[f];
  double x[3], y[3], ax[3], ay[3];
  for (int c = 0; c < 3; ++c) {
    const Vec3& P = M.vertices[tri[c]];
    x[c] = pl.gx.dot(P) + pl.ox;
    y[c] = pl.gy.dot(P) + pl.oy;
    // Atlas texel coordinates of the corner's UV (spec convention).
    ax[c] = static_cast<double>(M.uvs[f][c].x()) * W - 0.5;
    ay[c] = (1.0 - static_cast<double>(M.uvs[f][c].y())) * H - 0.5;
  }
  const double e1x = x[1] - x[0], e1y = y[1] - y[0];
  const double e2x = x[2] - x[0], e2y = y[2] - y[0];
  if (pl.mesh) {  // any face, edge-on along n or not: its full surface need not be
    raster_triangle_mesh(M, f, pl, x, y, ax, ay);
    return;
  }
  const double area2 = e1x * e2y - e2x * e1y;
  if (std::abs(area2) < kMinArea2) return;
  if (pl.surface) {
    const double L = pl.surface->lateral_bound(f, pl.nobj) / pl.cell;  // grid texels
    if (L > pl.tol) {
      raster_triangle_surface(M, f, pl, x, y, ax, ay, L);
      return;
    }
  }
  const double ymin = std::min({y[0], y[1], y[2]}), ymax = std::max({y[0], y[1], y[2]});
  // Clamped to the grid in double before the conversion: a far vertex (the
  // loader accepts any finite position) projects to ~1e10 texels, beyond int
  // (found by the fuzz target; runtime/fuzz/regressions/depth-raster-*).
  if (!(ymax + kEdgeEps >= 0) || !(ymin - kEdgeEps <= S - 1)) return;
  const int j0 = static_cast<int>(std::ceil(std::max(ymin - kEdgeEps, 0.0)));
  const int j1 = static_cast<int>(std::floor(std::min(ymax + kEdgeEps, static_cast<double>(S - 1))));
  if (j0 > j1) return;
  const double xmin = std::min({x[0], x[1], x[2]}), xmax = std::max({x[0], x[1], x[2]});
  if (xmax < -kEdgeEps || xmin > S - 1 + kEdgeEps) return;

  // The projection is affine, so are the barycentrics and the UV (no
  // perspective correction): atlas coords = a0 + dadx (x - x0) + dady (y - y0).
  const double inv = 1.0 / area2;
  const double dax_dx = ((ax[1] - ax[0]) * e2y - (ax[2] - ax[0]) * e1y) * inv;
  const double dax_dy = ((ax[2] - ax[0]) * e1x - (ax[1] - ax[0]) * e2x) * inv;
  const double day_dx = ((ay[1] - ay[0]) * e2y - (ay[2] - ay[0]) * e1y) * inv;
  const double day_dy = ((ay[2] - ay[0]) * e1x - (ay[1] - ay[0]) * e2x) * inv;
  const HeightSampler& sample = pl.sample;
  const double oh = pl.oh;

  for (int j = j0; j <= j1; ++j) {
    // Span of the row y = j inside the triangle: intersections with the edges.
    double xl = kInf, xr = -kInf;
    for (int e = 0; e < 3; ++e) {
      const int a = e, b = (e + 1) % 3;
      const double ya = y[a], yb = y[b];
      if ((j < std::min(ya, yb) - kEdgeEps) || (j > std::max(ya, yb) + kEdgeEps)) continue;
      if (std::abs(yb - ya) < 1e-300) {
        xl = std::min({xl, x[a], x[b]});
        xr = std::max({xr, x[a], x[b]});
        continue;
      }
      const double s = std::clamp((j - ya) / (yb - ya), 0.0, 1.0);
      const double xi = x[a] + s * (x[b] - x[a]);
      xl = std::min(xl, xi);
      xr = std::max(xr, xi);
    }
    if (!(xl <= xr)) continue;
    if (!(xr + kEdgeEps >= 0) || !(xl - kEdgeEps <= S - 1)) continue;
    const int i0 = static_cast<int>(std::ceil(std::max(xl - kEdgeEps, 0.0)));
    const int i1 = static_cast<int>(std::floor(std::min(xr + kEdgeEps, static_cast<double>(S - 1))));
    if (i0 > i1) continue;
    double cax = ax[0] + dax_dx * (i0 - x[0]) + dax_dy * (j - y[0]);
    double cay = ay[0] + day_dx * (i0 - x[0]) + day_dy * (j - y[0]);
    double* row = pl.out + static_cast<size_t>(j) * S;
    // The span's atlas coordinates are affine in i: if both ends keep the
    // 2 x 2 footprint inside the image, every texel between does.
    const double ex = cax + dax_dx * (i1 - i0), ey = cay + day_dx * (i1 - i0);
    const bool in = std::min(cax, ex) >= 0 && std::max(cax, ex) < W - 1 - 1e-6 && std::min(cay, ey) >= 0 &&
                    std::max(cay, ey) < H - 1 - 1e-6;
    if (pl.seed_a) {
      // Config 0 with seeds: keep the atlas point of the winner as well.
      const size_t base = static_cast<size_t>(j) * S;
      for (int i = i0; i <= i1; ++i, cax += dax_dx, cay += day_dx) {
        const double h = sample.clamped(cax, cay) + oh;  // NaN (unusable quad) never wins
        if (pl.keep_max ? h > row[i] : h < row[i]) {
          row[i] = h;
          write_seed(pl, base + i, cax, cay, dax_dx, dax_dy, day_dx, day_dy);
        }
      }
    } else if (in && pl.keep_max) {
      for (int i = i0; i <= i1; ++i, cax += dax_dx, cay += day_dx)
        row[i] = std::max(row[i], sample.inside(cax, cay) + oh);
    } else if (in) {
      for (int i = i0; i <= i1; ++i, cax += dax_dx, cay += day_dx)
        row[i] = std::min(row[i], sample.inside(cax, cay) + oh);
    } else if (pl.keep_max) {
      for (int i = i0; i <= i1; ++i, cax += dax_dx, cay += day_dx)
        row[i] = std::max(row[i], sample.clamped(cax, cay) + oh);
    } else {
      for (int i = i0; i <= i1; ++i, cax += dax_dx, cay += day_dx)
        row[i] = std::min(row[i], sample.clamped(cax, cay) + oh);
    }
  }
}

bool usable(const Model& M, const Window& w) {
  return w.resolution > 0 && w.cell > 0 && M.atlas.width > 0 && M.atlas.height > 0;
}

}  // namespace

PlacementParams placement_params(const Model& M, const Eigen::Isometry3d& world_from_m, const Vec3& n, const Vec3& u,
                                 const Vec3& v, const Window& w, int border, HeightMode mode) {
  PlacementParams pp;
  pp.surface = mode == HeightMode::surface && M.surface.ready;
  const Mat3 R = world_from_m.linear();
  const Vec3 t = world_from_m.translation();
  const double inv_cell = 1.0 / w.cell;
  pp.nobj = R.transpose() * n;
  pp.gx = R.transpose() * u * inv_cell;
  pp.gy = R.transpose() * v * inv_cell;
  pp.ox = (t - w.origin).dot(u) * inv_cell - 0.5 + border;
  pp.oy = (t - w.origin).dot(v) * inv_cell - 0.5 + border;
  pp.oh = (t - w.origin).dot(n);
  pp.tol = kLateralTolerance * std::min(1.0, M.quality.texel_size > 0 ? M.quality.texel_size * inv_cell : 1.0);
  for (int k = 0; k < 3; ++k) {
    pp.gx4[k] = static_cast<float>(pp.gx[k]);
    pp.gy4[k] = static_cast<float>(pp.gy[k]);
    pp.n4[k] = static_cast<float>(pp.nobj[k]);
  }
  return pp;
}

ResolveMotion resolve_motion(const Eigen::Isometry3d& world_from_m, const Eigen::Isometry3d& seed_world_from_m,
                             const Vec3& n, const Vec3& u, const Vec3& v, const Window& w) {
  // The seed's point lies (within the tolerance) on texel (i, j)'s column at
  // height seed_h: its world position is affine in (i, j, h), and so are its
  // grid coordinates after the motion from the seed's placement to this one.
  // So the first residual needs no lookup: r0 = (i, j) - G (i, j, h).
  const Eigen::Isometry3d motion = world_from_m * seed_world_from_m.inverse(Eigen::Isometry);
  const Mat3 Rm = motion.linear();
  const double cell = w.cell;
  // p(i, j, h) = origin + (i + 0.5) cell u + (j + 0.5) cell v + h n (heights relative to n . origin);
  // x' = u . (motion p - origin) / cell - 0.5, likewise y'.
  const Vec3 mo = motion * w.origin - w.origin;
  const Vec3 Ru = Rm * u, Rv = Rm * v, Rn = Rm * n;
  ResolveMotion r;
  r.gxi = u.dot(Ru), r.gxj = u.dot(Rv), r.gxh = u.dot(Rn) / cell;
  r.gyi = v.dot(Ru), r.gyj = v.dot(Rv), r.gyh = v.dot(Rn) / cell;
  r.gx0 = u.dot(mo) / cell + 0.5 * (r.gxi + r.gxj) - 0.5, r.gy0 = v.dot(mo) / cell + 0.5 * (r.gyi + r.gyj) - 0.5;
  return r;
}

// The mesh heights' drawing order: the faces whose points can reach
// farthest along the kept extreme first (the highest for keep_max), so that
// raster_triangle_mesh's occlusion tests skip the faces and quads behind
// them. The heights are a max (or min) and do not depend on the order.
const std::vector<uint32_t>& mesh_order(const Model& M, const std::vector<uint32_t>& tris, const Placement& pl) {
  thread_local std::vector<std::pair<double, uint32_t>> keyed;
  thread_local std::vector<uint32_t> order;
  if (!pl.mesh) return tris;
  keyed.clear();
  for (uint32_t f : tris) {
    if (f >= M.faces.size()) continue;
    double hlo, hhi;
    culled_by_height(M, f, pl, hlo, hhi);
    keyed.emplace_back(pl.keep_max ? -hhi : hlo, f);
  }
  std::sort(keyed.begin(), keyed.end());  // ties by face index: deterministic
  order.clear();
  for (const auto& k : keyed) order.push_back(k.second);
  return order;
}

void rasterize_heights(const Model& M, const Eigen::Isometry3d& world_from_m, const std::vector<uint32_t>& tris,
                       const Vec3& n, const Vec3& u, const Vec3& v, const Window& w, int border, bool keep_max,
                       double* out, HeightMode mode, double cull) {
  const int S = w.resolution + 2 * border;
  std::fill(out, out + static_cast<size_t>(std::max(S, 0)) * std::max(S, 0), keep_max ? -kInf : kInf);
  if (tris.empty() || !usable(M, w)) return;
  Placement pl = make_placement(M, world_from_m, n, u, v, w, border, keep_max, out, mode);
  pl.cull = cull;
  for (uint32_t f : mesh_order(M, tris, pl))
    if (f < M.faces.size()) raster_triangle(M, f, pl);
}

void rasterize_heights_multi(const Model& M, const Eigen::Isometry3d* world_from_m, const int* borders, int count,
                             const std::vector<uint32_t>& tris, const Vec3& n, const Vec3& u, const Vec3& v,
                             const Window& w, bool keep_max, double* const* out, HeightMode mode, double cull) {
  constexpr int kMax = 16;
  for (int k = 0; k < count; ++k) {
    const int S = std::max(w.resolution + 2 * (borders ? borders[k] : 0), 0);
    std::fill(out[k], out[k] + static_cast<size_t>(S) * S, keep_max ? -kInf : kInf);
  }
  if (tris.empty() || !usable(M, w)) return;
  // Triangle by triangle, all placements in turn: they differ by at most a
  // texel or so, so each triangle's atlas region is read from cache for all
  // but the first.
  for (int k0 = 0; k0 < count; k0 += kMax) {
    const int m = std::min(kMax, count - k0);
    Placement pl[kMax] = {};
    for (int k = 0; k < m; ++k) {
      pl[k] = make_placement(M, world_from_m[k0 + k], n, u, v, w, borders ? borders[k0 + k] : 0, keep_max, out[k0 + k],
                             mode);
      pl[k].cull = cull;
    }
    for (uint32_t f : mesh_order(M, tris, pl[0])) {
      if (f >= M.faces.size()) continue;
      for (int k = 0; k < m; ++k) raster_triangle(M, f, pl[k]);
    }
  }
}

void rasterize_heights_seeded(const Model& M, const Eigen::Isometry3d& world_from_m, const std::vector<uint32_t>& tris,
                              const Vec3& n, const Vec3& u, const Vec3& v, const Window& w, int border, bool keep_max,
                              double* out, HeightSeeds& seeds, double cull) {
  const int S = std::max(w.resolution + 2 * border, 0);
  const double none = keep_max ? -kInf : kInf;
  std::fill(out, out + static_cast<size_t>(S) * S, none);
  seeds.i0 = seeds.i1 = seeds.j0 = seeds.j1 = 0;
  if (tris.empty() || !usable(M, w)) return;
  Placement pl = make_placement(M, world_from_m, n, u, v, w, border, keep_max, out, HeightMode::surface);
  pl.cull = cull;
  pl.seed_a = seeds.a.data();
  pl.seed_j = seeds.j.data();
  for (uint32_t f : tris)
    if (f < M.faces.size()) raster_triangle(M, f, pl);
  const depth_reduce::CoveredBox box = depth_reduce::covered_box(out, S, none);
  seeds.i0 = box.i0, seeds.i1 = box.i1, seeds.j0 = box.j0, seeds.j1 = box.j1;
}

namespace {

// resolve_heights with the fixed point either scalar (the reference) or
// in blocks of texels vectorized across lanes (src/depth/resolve_simd.cpp):
// the same operations in the same order, so the same bits.
void resolve_heights_impl(const Model& M, const Eigen::Isometry3d& world_from_m,
                          const Eigen::Isometry3d& seed_world_from_m, const Vec3& n, const Vec3& u, const Vec3& v,
                          const Window& w, bool keep_max, const double* seed_h, int border, const HeightSeeds& seeds,
                          double* out, const double* other, bool simd) {
  const int N = w.resolution;
  const size_t n2 = static_cast<size_t>(std::max(N, 0)) * std::max(N, 0);
  const double none = keep_max ? -kInf : kInf;
  if (!usable(M, w)) {
    std::fill(out, out + n2, none);
    return;
  }
  const Placement pl = make_placement(M, world_from_m, n, u, v, w, 0, keep_max, out, HeightMode::surface);
  const double tol2 = pl.tol * pl.tol;
  const ResolveMotion rm = resolve_motion(world_from_m, seed_world_from_m, n, u, v, w);
  const double gxi = rm.gxi, gxj = rm.gxj, gxh = rm.gxh, gyi = rm.gyi, gyj = rm.gyj, gyh = rm.gyh;
  const double gx0 = rm.gx0, gy0 = rm.gy0;
  if (simd) {
    const HeightSampler& s = pl.sample;
    depth_simd::ResolveArgs a{};
    a.rgba = s.rgba, a.w = s.w, a.h = s.h, a.stride = static_cast<int>(s.stride), a.ok = s.ok;
    for (int c = 0; c < 4; ++c) a.n4[c] = s.n[c], a.gx4[c] = pl.gx4[c], a.gy4[c] = pl.gy4[c];
    a.ox = pl.ox, a.oy = pl.oy, a.oh = pl.oh, a.tol2 = tol2;
    a.gx0 = gx0, a.gxi = gxi, a.gxj = gxj, a.gxh = gxh, a.gy0 = gy0, a.gyi = gyi, a.gyj = gyj, a.gyh = gyh;
    a.N = N, a.border = border, a.none = none;
    a.seed_h = seed_h, a.seed_a = seeds.a.data(), a.seed_j = seeds.j.data(), a.other = other, a.out = out;
    // The seeds' box in the N x N texels (texels outside hold no seed).
    a.i0 = std::clamp(seeds.i0 - border, 0, N), a.i1 = std::clamp(seeds.i1 - border, a.i0, N);
    a.j0 = std::clamp(seeds.j0 - border, 0, N), a.j1 = std::clamp(seeds.j1 - border, a.j0, N);
    depth_simd::resolve_all(a);
    return;
  }
  for (int j = 0; j < N; ++j)
    for (int i = 0; i < N; ++i) {
      const size_t k = static_cast<size_t>(j) * N + i;
      const size_t ks = static_cast<size_t>(j + border) * (N + 2 * border) + (i + border);  // in the bordered seeds
      out[k] = none;
      if (other && other[k] == -none) continue;  // the other side is uncovered here
      const double h0 = seed_h[ks];
      if (!(std::abs(h0) < kInf)) continue;  // not covered at configuration 0
      double a_x = seeds.a[2 * ks], a_y = seeds.a[2 * ks + 1];
      const float* J = &seeds.j[4 * ks];
      {
        const double rx = i - (gx0 + gxi * i + gxj * j + gxh * h0), ry = j - (gy0 + gyi * i + gyj * j + gyh * h0);
        a_x += J[0] * rx + J[1] * ry;
        a_y += J[2] * rx + J[3] * ry;
      }
      for (int it = 0; it < kMaxLateralIterations; ++it) {
        double px, py, ph;
        if (!pl.sample.project(a_x, a_y, pl.gx4, pl.gy4, px, py, ph)) break;
        const double rx = i - (px + pl.ox), ry = j - (py + pl.oy);
        if (rx * rx + ry * ry <= tol2) {
          out[k] = ph + pl.oh;
          break;
        }
        a_x += J[0] * rx + J[1] * ry;
        a_y += J[2] * rx + J[3] * ry;
      }
    }
}

}  // namespace

void resolve_heights(const Model& M, const Eigen::Isometry3d& world_from_m, const Eigen::Isometry3d& seed_world_from_m,
                     const Vec3& n, const Vec3& u, const Vec3& v, const Window& w, bool keep_max, const double* seed_h,
                     int border, const HeightSeeds& seeds, double* out, const double* other) {
  resolve_heights_impl(M, world_from_m, seed_world_from_m, n, u, v, w, keep_max, seed_h, border, seeds, out, other,
                       !t_reference_heights);
}

void use_reference_heights(bool on) { t_reference_heights = on; }

void resolve_heights_reference(const Model& M, const Eigen::Isometry3d& world_from_m,
                               const Eigen::Isometry3d& seed_world_from_m, const Vec3& n, const Vec3& u, const Vec3& v,
                               const Window& w, bool keep_max, const double* seed_h, int border,
                               const HeightSeeds& seeds, double* out, const double* other) {
  resolve_heights_impl(M, world_from_m, seed_world_from_m, n, u, v, w, keep_max, seed_h, border, seeds, out, other,
                       false);
}

const char* resolve_heights_target() { return depth_simd::resolve_target(); }

double directional_depth(const Model& A, const Eigen::Isometry3d& world_from_a, const Model& B,
                         const Eigen::Isometry3d& world_from_b, const ContactPatch& patch, DepthScratch& scratch,
                         bool* covered, HeightMode mode) {
  const int N = patch.window.resolution;
  if (scratch.capacity < N) scratch.reserve(N);
  rasterize_heights(B, world_from_b, height_faces(patch.tris_b, patch.reach_b, mode, scratch.tris_b), patch.n, patch.u,
                    patch.v, patch.window, 0, false, scratch.hb.data(), mode);
  rasterize_heights(A, world_from_a, height_faces(patch.tris_a, patch.reach_a, mode, scratch.tris_a), patch.n, patch.u,
                    patch.v, patch.window, 0, true, scratch.ha.data(), mode);
  double d = -kInf;
  const size_t count = static_cast<size_t>(N) * N;
  const double* ha = scratch.ha.data();
  const double* hb = scratch.hb.data();
  for (size_t k = 0; k < count; ++k) d = std::max(d, ha[k] - hb[k]);
  if (covered) *covered = d > -kInf;
  return d;
}

}  // namespace hrt
