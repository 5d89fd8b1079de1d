// The fixed point of the surface heights re-solved from configuration 0's
// seeds (resolve_heights, raster.cpp), vectorized across texels with Google
// Highway's run-time dispatch (SSE4, AVX2 or AVX-512, whichever the CPU
// has). Internal to src/depth.
#pragma once

#include <cstddef>
#include <cstdint>

namespace hrt::depth_simd {

// The atlas and placement as HeightSampler::project reads them, and the
// first step's affine map (ResolveMotion).
struct ResolveArgs {
  const float* rgba;
  int w, h;
  int stride;         // floats per atlas row (4 w)
  const uint8_t* ok;  // SurfaceMap::quad_ok, or null
  float n4[4], gx4[4], gy4[4];
  double ox, oy, oh, tol2;
  double gx0, gxi, gxj, gxh, gy0, gyi, gyj, gyh;
  int N, border;
  int i0, i1, j0, j1;    // the texels that can hold a seed (N x N coordinates)
  double none;           // -inf (A, keep_max) or +inf
  const double* seed_h;  // (N + 2 border)^2
  const double* seed_a;  // 2 per seed texel
  const float* seed_j;   // 4 per seed texel
  const double* other;   // N^2 or null
  double* out;           // N^2
};

// resolve_heights' loop over every texel: the same operations in the same
// order as resolve_heights_reference's scalar loop, so the same bits on
// every target (this file is compiled without floating-point contraction).
// Texels outside the seeds' box [i0, i1) x [j0, j1) are set to `none`
// without a test (they hold no seed). Lanes are independent, so where the
// vectors start does not change a texel's result.
void resolve_all(const ResolveArgs& a);

// The Highway target resolve_all dispatches to on this CPU (for reports).
const char* resolve_target();

}  // namespace hrt::depth_simd

namespace hrt::depth_simd {

// One coarse triangle of the surface mode (raster_triangle_surface,
// raster.cpp) over the texels of one row: the atlas and placement as above,
// the triangle's grid corners, edges, barycentric and UV maps, the ownership
// margin and the height range its points can reach.
struct SurfaceTri {
  const float* rgba;
  int w, h;
  int stride;
  const uint8_t* ok;
  float n4[4], gx4[4], gy4[4];
  double ox, oy, oh, tol2;
  double x0, y0, x1, y1, x2, y2;
  double e1x, e1y, e2x, e2y, inv;
  double ax0, ay0, dax_dx, dax_dy, day_dx, day_dy;
  double scale[3], margin, hlo, hhi;
  bool keep_max;
};

// Largest list surface_texels takes at once (a multiple of every lane count).
constexpr int kSpan = 64;

// Texels (tx[t], ty[t]), t < count, of the triangle, whose current heights
// are h[t]: each texel's fixed point as raster_triangle_surface's scalar loop
// runs it, the same bits. Where a texel's height improves, h[t] takes the new
// height, (ax[t], ay[t]) the atlas point and wrote[t] = 1, else wrote[t] = 0.
// The arrays hold kSpan entries (those past count are ignored).
void surface_texels(const SurfaceTri& t, int count, const double* tx, const double* ty, double* h, double* ax,
                    double* ay, uint8_t* wrote);

}  // namespace hrt::depth_simd
