// prepare_surface_map's row spans (surface/row_span.h) against a brute force:
// on random triangles (thin, slanted, tiny, huge, either orientation) every
// texel centre whose Euclidean distance to the triangle is within the margin
// must lie in its row's span, or prepare_surface_map would miss a texel that
// bounds a face's lateral offsets. The span may hold more (it is a superset);
// the test also checks that it is not the whole box for a thin slanted
// triangle, the case it exists for.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

#include "hrt/surface.h"
#include "surface/row_span.h"

namespace {

// Distance from (px, py) to the closed triangle (ax, ay), from its definition:
// 0 inside, else the nearest of the three segments.
double distance_to_triangle(const double* ax, const double* ay, double px, double py) {
  const double area2 = (ax[1] - ax[0]) * (ay[2] - ay[0]) - (ax[2] - ax[0]) * (ay[1] - ay[0]);
  bool inside = true;
  for (int k = 0; k < 3; ++k) {
    const int l = (k + 1) % 3;
    const double cross = (ax[l] - ax[k]) * (py - ay[k]) - (ay[l] - ay[k]) * (px - ax[k]);
    if (cross * area2 < 0) inside = false;
  }
  if (inside) return 0.0;
  double best = std::numeric_limits<double>::infinity();
  for (int k = 0; k < 3; ++k) {
    const int l = (k + 1) % 3;
    const double sx = ax[l] - ax[k], sy = ay[l] - ay[k];
    const double ss = sx * sx + sy * sy;
    const double t = ss > 0 ? std::clamp(((px - ax[k]) * sx + (py - ay[k]) * sy) / ss, 0.0, 1.0) : 0.0;
    best = std::min(best, std::hypot(px - (ax[k] + t * sx), py - (ay[k] + t * sy)));
  }
  return best;
}

struct Counts {
  long kept = 0, in_span = 0, box = 0;
};

// Every texel within `margin` of the triangle is inside its row's span.
Counts check_triangle(const double* ax, const double* ay, double margin) {
  Counts c;
  const int i0 = static_cast<int>(std::floor(std::min({ax[0], ax[1], ax[2]}) - margin)) - 2;
  const int i1 = static_cast<int>(std::ceil(std::max({ax[0], ax[1], ax[2]}) + margin)) + 2;
  const int j0 = static_cast<int>(std::floor(std::min({ay[0], ay[1], ay[2]}) - margin)) - 2;
  const int j1 = static_cast<int>(std::ceil(std::max({ay[0], ay[1], ay[2]}) + margin)) + 2;
  const hrt::RowSpan rows(ax, ay, margin);
  for (int j = j0; j <= j1; ++j) {
    int ia = 0, ib = -1;
    const bool any = rows.span(j, i0, i1, ia, ib);
    if (any) c.in_span += ib - ia + 1;
    for (int i = i0; i <= i1; ++i) {
      ++c.box;
      if (!(distance_to_triangle(ax, ay, i, j) <= margin)) continue;
      ++c.kept;
      EXPECT_TRUE(any && ia <= i && i <= ib)
          << "texel (" << i << ", " << j << ") at distance " << distance_to_triangle(ax, ay, i, j)
          << " is outside the span [" << ia << ", " << ib << "] of the triangle (" << ax[0] << ", " << ay[0] << "), ("
          << ax[1] << ", " << ay[1] << "), (" << ax[2] << ", " << ay[2] << ")";
    }
  }
  return c;
}

TEST(SurfaceMapRowSpan, HoldsEveryTexelWithinTheMarginOfRandomTriangles) {
  std::mt19937_64 rng(20261202);
  std::uniform_real_distribution<double> pos(0.0, 1000.0), size(-1.0, 1.0), unit(0.0, 1.0);
  long triangles = 0;
  for (int t = 0; t < 3000; ++t) {
    double ax[3], ay[3];
    // Scales from a sub-texel sliver to a 300-texel triangle; corners off the
    // texel centres, in either winding.
    const double scale = std::pow(10.0, -0.5 + 3.0 * unit(rng));
    const double cx = pos(rng), cy = pos(rng);
    for (int k = 0; k < 3; ++k) ax[k] = cx + scale * size(rng), ay[k] = cy + scale * size(rng);
    if (t % 3 == 0) {  // a needle: the third corner near the first edge
      const double s = unit(rng);
      ax[2] = ax[0] + s * (ax[1] - ax[0]) + 0.05 * size(rng);
      ay[2] = ay[0] + s * (ay[1] - ay[0]) + 0.05 * size(rng);
    }
    const double area2 = (ax[1] - ax[0]) * (ay[2] - ay[0]) - (ax[2] - ax[0]) * (ay[1] - ay[0]);
    if (!(std::abs(area2) > 1e-12)) continue;  // prepare_surface_map skips these faces
    for (double margin : {hrt::kQuadReadMargin, 1.0, 0.0}) check_triangle(ax, ay, margin);
    ++triangles;
  }
  EXPECT_GT(triangles, 2900);
}

TEST(SurfaceMapRowSpan, CornersAndEdgesOnTexelCentres) {
  // Integer corners put texel centres exactly on the edges and at the margin:
  // rounding must not drop them.
  const double cases[][6] = {{0, 0, 10, 0, 0, 10},  {0, 0, 0, 10, 10, 0}, {3, 2, 40, 7, 5, 9},
                             {0, 0, 100, 1, 50, 1}, {7, 7, 8, 7, 7, 8},   {0, 0, 200, 199, 1, 0}};
  for (const auto& c : cases) {
    const double ax[3] = {c[0], c[2], c[4]}, ay[3] = {c[1], c[3], c[5]};
    for (double margin : {hrt::kQuadReadMargin, 1.0, 2.0, 0.0}) check_triangle(ax, ay, margin);
  }
}

TEST(SurfaceMapRowSpan, SkipsMostOfAThinSlantedTrianglesBox) {
  // A needle along the diagonal of a 200 x 200 box: the texels within 1.75 of
  // it are a band of a few percent of the box, and the spans hold little more.
  const double ax[3] = {0.3, 200.2, 100.6}, ay[3] = {0.1, 199.7, 100.9};
  const Counts c = check_triangle(ax, ay, hrt::kQuadReadMargin);
  EXPECT_GT(c.kept, 0);
  EXPECT_LE(c.in_span, 2 * c.kept + 400);
  EXPECT_LT(c.in_span, c.box / 10);
}

}  // namespace
