// Max reductions over rows of height maps, written with SSE2 because the
// compiler does not vectorize a max reduction without -ffast-math. max is
// exact (it does not round), so any order gives the same bits. Internal to
// src/depth.
#pragma once

#include <algorithm>
#include <limits>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace hrt::depth_reduce {

// max over k < n of a[k] - b[k]. -inf - finite = -inf, and (since A's
// uncovered texels hold -inf and B's +inf) never NaN, so maxpd's NaN rule
// does not matter.
inline double max_diff(const double* a, const double* b, int n) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  int i = 0;
  double d = -kInf;
#if defined(__SSE2__)
  __m128d m0 = _mm_set1_pd(-kInf), m1 = m0;
  for (; i + 4 <= n; i += 4) {
    m0 = _mm_max_pd(m0, _mm_sub_pd(_mm_loadu_pd(a + i), _mm_loadu_pd(b + i)));
    m1 = _mm_max_pd(m1, _mm_sub_pd(_mm_loadu_pd(a + i + 2), _mm_loadu_pd(b + i + 2)));
  }
  const __m128d m = _mm_max_pd(m0, m1);
  d = std::max(_mm_cvtsd_f64(m), _mm_cvtsd_f64(_mm_unpackhi_pd(m, m)));
#endif
  for (; i < n; ++i) d = std::max(d, a[i] - b[i]);
  return d;
}

// max over k < n of s * a[k], s = +1 or -1: whether a row of heights holds
// any (A's uncovered texels are -inf, s = 1; B's +inf, s = -1).
inline double max_scaled(const double* a, int n, double s) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  int i = 0;
  double d = -kInf;
#if defined(__SSE2__)
  const __m128d vs = _mm_set1_pd(s);
  __m128d m0 = _mm_set1_pd(-kInf), m1 = m0;
  for (; i + 4 <= n; i += 4) {
    m0 = _mm_max_pd(m0, _mm_mul_pd(vs, _mm_loadu_pd(a + i)));
    m1 = _mm_max_pd(m1, _mm_mul_pd(vs, _mm_loadu_pd(a + i + 2)));
  }
  const __m128d m = _mm_max_pd(m0, m1);
  d = std::max(_mm_cvtsd_f64(m), _mm_cvtsd_f64(_mm_unpackhi_pd(m, m)));
#endif
  for (; i < n; ++i) d = std::max(d, s * a[i]);
  return d;
}

// The texels of an S x S map that hold a height (anything but `none`, -inf
// for A or +inf for B): rows [j0, j1), columns [i0, i1); all zero when
// none does. A patch covers a blob of a few hundred of the N^2 texels, so
// most rows are skipped by one max each.
struct CoveredBox {
  int i0 = 0, i1 = 0, j0 = 0, j1 = 0;
};

inline CoveredBox covered_box(const double* h, int S, double none) {
  const double s = none < 0 ? 1.0 : -1.0;
  CoveredBox box{S, 0, S, 0};
  for (int j = 0; j < S; ++j) {
    const double* row = h + static_cast<size_t>(j) * S;
    if (max_scaled(row, S, s) == -std::numeric_limits<double>::infinity()) continue;
    int first = 0, last = S - 1;
    while (row[first] == none) ++first;
    while (row[last] == none) --last;
    box.i0 = std::min(box.i0, first), box.i1 = std::max(box.i1, last + 1);
    box.j0 = std::min(box.j0, j), box.j1 = j + 1;
  }
  if (box.j1 == 0) box = CoveredBox{};
  return box;
}

}  // namespace hrt::depth_reduce
