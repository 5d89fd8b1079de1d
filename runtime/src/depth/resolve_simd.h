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
  double none;             // -inf (A, keep_max) or +inf
  const double* seed_h;    // (N + 2 border)^2
  const double* seed_a;    // 2 per seed texel
  const float* seed_j;     // 4 per seed texel
  const double* other;     // N^2 or null
  double* out;             // N^2
};

// resolve_heights' loop over every texel: the same operations in the same
// order as resolve_heights_reference's scalar loop, so the same bits on
// every target (this file is compiled without floating-point contraction).
void resolve_all(const ResolveArgs& a);

// The Highway target resolve_all dispatches to on this CPU (for reports).
const char* resolve_target();

}  // namespace hrt::depth_simd
