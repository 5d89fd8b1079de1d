// Height maps by orthographic rasterization (paper Eq. 8) and the depth of
// one configuration (Eq. 9). See hrt/depth.h for the conventions.
#include <algorithm>
#include <cmath>
#include <limits>

#if defined(__SSE4_1__)
#include <smmintrin.h>
#endif

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
struct HeightSampler {
  const float* rgba;
  int w, h;
  size_t stride;  // floats per atlas row
  float n[4];     // n_obj, 0 for the coverage channel

  // Clamped lookup, valid anywhere.
  inline double clamped(double ax, double ay) const {
    const double fx0 = std::floor(ax), fy0 = std::floor(ay);
    const float fx = static_cast<float>(ax - fx0), fy = static_cast<float>(ay - fy0);
    const int i0 = static_cast<int>(fx0), j0 = static_cast<int>(fy0);
    const int ia = std::clamp(i0, 0, w - 1), ib = std::clamp(i0 + 1, 0, w - 1);
    const int ja = std::clamp(j0, 0, h - 1), jb = std::clamp(j0 + 1, 0, h - 1);
    return lerp_dot(rgba + ja * stride + ia * 4, rgba + ja * stride + ib * 4, rgba + jb * stride + ia * 4,
                    rgba + jb * stride + ib * 4, fx, fy);
  }
  // Lookup whose 2 x 2 footprint is known to lie inside the image
  // (0 <= ax < w - 1, 0 <= ay < h - 1): no clamping.
  inline double inside(double ax, double ay) const {
    const int i0 = static_cast<int>(ax), j0 = static_cast<int>(ay);  // truncation == floor for ax, ay >= 0
    const float fx = static_cast<float>(ax - i0), fy = static_cast<float>(ay - j0);
    const float* p = rgba + j0 * stride + i0 * 4;
    return lerp_dot(p, p + 4, p + stride, p + stride + 4, fx, fy);
  }
  inline double lerp_dot(const float* a, const float* b, const float* c, const float* d, float fx, float fy) const {
#if defined(__SSE4_1__)
    const __m128 va = _mm_loadu_ps(a), vb = _mm_loadu_ps(b), vc = _mm_loadu_ps(c), vd = _mm_loadu_ps(d);
    const __m128 vfx = _mm_set1_ps(fx), vfy = _mm_set1_ps(fy);
    const __m128 top = _mm_add_ps(va, _mm_mul_ps(vfx, _mm_sub_ps(vb, va)));
    const __m128 bot = _mm_add_ps(vc, _mm_mul_ps(vfx, _mm_sub_ps(vd, vc)));
    const __m128 v = _mm_add_ps(top, _mm_mul_ps(vfy, _mm_sub_ps(bot, top)));
    return static_cast<double>(_mm_cvtss_f32(_mm_dp_ps(v, _mm_loadu_ps(n), 0x71)));
#else
    float r = 0;
    for (int k = 0; k < 3; ++k) {
      const float top = a[k] + fx * (b[k] - a[k]), bot = c[k] + fx * (d[k] - c[k]);
      r += n[k] * (top + fy * (bot - top));
    }
    return static_cast<double>(r);
#endif
  }
};

}  // namespace

namespace {

// One placement of a model over the grid: the affine maps from object space
// to grid coordinates and to heights, and the sampler dotted with n_obj.
struct Placement {
  Vec3 gx, gy;      // grid x = gx . P + ox, y = gy . P + oy (texel centres at integers, border included)
  double ox, oy;
  double oh;        // h = sample . (n_obj) + oh, relative to n . origin
  HeightSampler sample;
  int S;            // side of the output buffer
  bool keep_max;
  double* out;
};

Placement make_placement(const Model& M, const Eigen::Isometry3d& world_from_m, const Vec3& n, const Vec3& u,
                         const Vec3& v, const Window& w, int border, bool keep_max, double* out) {
  const Mat3 R = world_from_m.linear();
  const Vec3 t = world_from_m.translation();
  const double inv_cell = 1.0 / w.cell;
  const Vec3 nobj = R.transpose() * n;
  const Atlas& at = M.atlas;
  return Placement{R.transpose() * u * inv_cell,
                   R.transpose() * v * inv_cell,
                   (t - w.origin).dot(u) * inv_cell - 0.5 + border,
                   (t - w.origin).dot(v) * inv_cell - 0.5 + border,
                   (t - w.origin).dot(n),
                   HeightSampler{at.rgba.data(), at.width, at.height, static_cast<size_t>(at.width) * 4,
                                 {static_cast<float>(nobj.x()), static_cast<float>(nobj.y()),
                                  static_cast<float>(nobj.z()), 0.0f}},
                   w.resolution + 2 * border,
                   keep_max,
                   out};
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
  const double area2 = e1x * e2y - e2x * e1y;
  if (std::abs(area2) < kMinArea2) return;
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
    if (in && pl.keep_max) {
      for (int i = i0; i <= i1; ++i, cax += dax_dx, cay += day_dx) row[i] = std::max(row[i], sample.inside(cax, cay) + oh);
    } else if (in) {
      for (int i = i0; i <= i1; ++i, cax += dax_dx, cay += day_dx) row[i] = std::min(row[i], sample.inside(cax, cay) + oh);
    } else if (pl.keep_max) {
      for (int i = i0; i <= i1; ++i, cax += dax_dx, cay += day_dx) row[i] = std::max(row[i], sample.clamped(cax, cay) + oh);
    } else {
      for (int i = i0; i <= i1; ++i, cax += dax_dx, cay += day_dx) row[i] = std::min(row[i], sample.clamped(cax, cay) + oh);
    }
  }
}

bool usable(const Model& M, const Window& w) {
  return w.resolution > 0 && w.cell > 0 && M.atlas.width > 0 && M.atlas.height > 0;
}

}  // namespace

void rasterize_heights(const Model& M, const Eigen::Isometry3d& world_from_m, const std::vector<uint32_t>& tris,
                       const Vec3& n, const Vec3& u, const Vec3& v, const Window& w, int border, bool keep_max,
                       double* out) {
  const int S = w.resolution + 2 * border;
  std::fill(out, out + static_cast<size_t>(std::max(S, 0)) * std::max(S, 0), keep_max ? -kInf : kInf);
  if (tris.empty() || !usable(M, w)) return;
  const Placement pl = make_placement(M, world_from_m, n, u, v, w, border, keep_max, out);
  for (uint32_t f : tris)
    if (f < M.faces.size()) raster_triangle(M, f, pl);
}

void rasterize_heights_multi(const Model& M, const Eigen::Isometry3d* world_from_m, const int* borders, int count,
                             const std::vector<uint32_t>& tris, const Vec3& n, const Vec3& u, const Vec3& v,
                             const Window& w, bool keep_max, double* const* out) {
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
    for (int k = 0; k < m; ++k)
      pl[k] = make_placement(M, world_from_m[k0 + k], n, u, v, w, borders ? borders[k0 + k] : 0, keep_max, out[k0 + k]);
    for (uint32_t f : tris) {
      if (f >= M.faces.size()) continue;
      for (int k = 0; k < m; ++k) raster_triangle(M, f, pl[k]);
    }
  }
}

double directional_depth(const Model& A, const Eigen::Isometry3d& world_from_a, const Model& B,
                         const Eigen::Isometry3d& world_from_b, const ContactPatch& patch, DepthScratch& scratch,
                         bool* covered) {
  const int N = patch.window.resolution;
  if (scratch.capacity < N) scratch.reserve(N);
  rasterize_heights(B, world_from_b, patch.tris_b, patch.n, patch.u, patch.v, patch.window, 0, false,
                    scratch.hb.data());
  rasterize_heights(A, world_from_a, patch.tris_a, patch.n, patch.u, patch.v, patch.window, 0, true,
                    scratch.ha.data());
  double d = -kInf;
  const size_t count = static_cast<size_t>(N) * N;
  const double* ha = scratch.ha.data();
  const double* hb = scratch.hb.data();
  for (size_t k = 0; k < count; ++k) d = std::max(d, ha[k] - hb[k]);
  if (covered) *covered = d > -kInf;
  return d;
}

}  // namespace hrt
