// Bilinear lookup in the haptic texture (docs/bundle-format.md, "UV to texel").
//
// Convention: x = u W - 0.5, y = (1 - v) H - 0.5 (texel centres at integer
// x, y; row 0 is the first stored scanline, the top of the image, so v points
// up); i0 = floor(x), fx = x - i0 (same for y); the four texels are clamped to
// the image; weights (1-fx)(1-fy), fx(1-fy), (1-fx)fy, fx fy.
//
// Precision: all arithmetic is float32 (this runs per texel in the depth
// stage). x = u W - 0.5 is rounded twice, so it is off by at most
// ulp(W) ~ W 2^-23 texel (2.4e-4 texel at W = 2048) from the exact value, plus
// u's own float32 rounding (also ~W 2^-24 texel) when the caller had a double.
// The result therefore differs from an exact (float64) evaluation by at most
//   |dx| * (largest difference between the 4 texels) + a few ulp(|texel|),
// i.e. float32 rounding (the bound test_io_golden.cpp asserts).
// Precondition: a loaded atlas (width, height >= 1).
#include <cmath>

#include "hrt/model.h"

namespace hrt {
namespace {

// Texel indices and weights of one axis. NaN and far out-of-range coordinates
// are clamped first, so the float -> int conversion is always defined.
inline void axis(float x, int n, int& i0, int& i1, float& f) {
  if (!(x >= -1.0f)) x = -1.0f;  // also catches NaN
  if (!(x <= static_cast<float>(n))) x = static_cast<float>(n);
  const float fl = std::floor(x);
  f = x - fl;
  const int i = static_cast<int>(fl);
  i0 = i < 0 ? 0 : (i > n - 1 ? n - 1 : i);
  i1 = i + 1 < 0 ? 0 : (i + 1 > n - 1 ? n - 1 : i + 1);
}

}  // namespace

Eigen::Vector4f Atlas::sample4(float u, float v) const {
  int i0, i1, j0, j1;
  float fx, fy;
  axis(u * static_cast<float>(width) - 0.5f, width, i0, i1, fx);
  axis((1.0f - v) * static_cast<float>(height) - 0.5f, height, j0, j1, fy);
  const Eigen::Map<const Eigen::Vector4f> t00(texel(i0, j0)), t10(texel(i1, j0)), t01(texel(i0, j1)),
      t11(texel(i1, j1));
  return ((1.0f - fx) * (1.0f - fy)) * t00 + (fx * (1.0f - fy)) * t10 + ((1.0f - fx) * fy) * t01 + (fx * fy) * t11;
}

Eigen::Vector3f Atlas::sample(float u, float v) const { return sample4(u, v).head<3>(); }

}  // namespace hrt
