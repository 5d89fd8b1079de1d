// The texels of one atlas row that can lie within a distance of a UV
// triangle: a superset, computed from the three edge lines, that skips most
// of a thin or slanted triangle's bounding box (prepare_surface_map).
#pragma once

#include <algorithm>
#include <cmath>

namespace hrt {

// Atlas texel coordinates (texel centres at integers) of a triangle whose
// doubled signed area is area2 != 0, and a margin in texels. Outside a
// convex triangle the distance to it is at least the distance to any edge's
// line, so a texel centre within `margin` of the triangle lies within
// `margin` of the inner side of all three lines. RowSpan gives, per row j,
// the range of i where it does, widened by kSlack texel so that rounding
// never drops a texel that the exact distance would keep (tested against a
// brute force: runtime/tests/test_surface_map.cpp).
class RowSpan {
 public:
  static constexpr double kSlack = 1e-3;

  RowSpan(const double* ax, const double* ay, double margin) : ax0_(ax[0]), ay0_(ay[0]) {
    e1x_ = ax[1] - ax[0], e1y_ = ay[1] - ay[0], e2x_ = ax[2] - ax[0], e2y_ = ay[2] - ay[0];
    area2_ = e1x_ * e2y_ - e2x_ * e1y_;
    // b_k = alpha_k(j) + beta_k i along a row; the distance outside edge k
    // (opposite corner k) to its line is -b_k |area2| / |edge k|.
    beta_[0] = -(e2y_ - e1y_) / area2_, beta_[1] = e2y_ / area2_, beta_[2] = -e1y_ / area2_;
    const double len[3] = {std::hypot(ax[2] - ax[1], ay[2] - ay[1]), std::hypot(ax[0] - ax[2], ay[0] - ay[2]),
                           std::hypot(ax[1] - ax[0], ay[1] - ay[0])};
    for (int k = 0; k < 3; ++k) lim_[k] = -(margin + kSlack) * len[k] / std::abs(area2_);
  }

  // [ia, ib] within [i0, i1] for row j; false when the row has none.
  bool span(int j, int i0, int i1, int& ia, int& ib) const {
    double lo = i0, hi = i1;
    const double dy0 = j - ay0_;
    const double b1 = (-ax0_ * e2y_ - e2x_ * dy0) / area2_, b2 = (e1x_ * dy0 + ax0_ * e1y_) / area2_;
    const double alpha[3] = {1 - b1 - b2, b1, b2};  // at i = 0
    for (int k = 0; k < 3 && lo <= hi; ++k) {
      const double need = lim_[k] - alpha[k];  // beta_k i >= need
      if (beta_[k] > 0)
        lo = std::max(lo, need / beta_[k]);
      else if (beta_[k] < 0)
        hi = std::min(hi, need / beta_[k]);
      else if (need > 0)
        hi = lo - 1;
    }
    if (!(lo <= hi)) return false;
    ia = std::max(i0, static_cast<int>(std::ceil(lo - kSlack)));
    ib = std::min(i1, static_cast<int>(std::floor(hi + kSlack)));
    return ia <= ib;
  }

 private:
  double ax0_, ay0_, e1x_, e1y_, e2x_, e2y_, area2_;
  double beta_[3], lim_[3];
};

}  // namespace hrt
