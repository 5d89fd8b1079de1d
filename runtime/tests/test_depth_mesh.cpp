// The mesh heights (HeightMode::mesh, docs/bundle-format.md "Heights over a
// texel's square") against a brute force written from the definition: every
// usable atlas quad whose centre lies within one texel of a listed face's UV
// triangle, split along its (i, j)-(i + 1, j + 1) diagonal, each triangle
// clipped exactly to every texel's square. The runtime skips rows, blocks,
// faces and quads that cannot hold a texel's extreme; none of that may
// change a height. Per texel (keep_max; the min side mirrored):
//   exact <= mesh <= corners,
// exact: the largest height that the triangles of the quads within one texel
// (Euclidean) reach over the square (the clipped polygons' vertices, a
// linear h); corners: the largest corner of the triangles that meet the
// square, of quads within 2.5 texels (near a sharp UV corner the runtime may
// take a few more quads, each a genuine piece of the surface). Both bounds
// come from the geometry alone.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "hrt/depth.h"
#include "hrt/surface.h"
#include "synthetic.h"

namespace {

using hrt::Vec3;
constexpr double kPi = 3.14159265358979323846;
constexpr double kInf = std::numeric_limits<double>::infinity();

struct P2 {
  double x, y, h;
};

// Sutherland-Hodgman against one axis-aligned half-plane, h carried linearly.
std::vector<P2> clip(const std::vector<P2>& in, int axis, double bound, bool keep_below) {
  std::vector<P2> out;
  auto coord = [axis](const P2& p) { return axis == 0 ? p.x : p.y; };
  auto inside = [&](const P2& p) { return keep_below ? coord(p) <= bound : coord(p) >= bound; };
  for (size_t k = 0; k < in.size(); ++k) {
    const P2& a = in[k];
    const P2& b = in[(k + 1) % in.size()];
    const bool ia = inside(a), ib = inside(b);
    if (ia) out.push_back(a);
    if (ia != ib) {
      const double t = (bound - coord(a)) / (coord(b) - coord(a));
      out.push_back({a.x + t * (b.x - a.x), a.y + t * (b.y - a.y), a.h + t * (b.h - a.h)});
    }
  }
  return out;
}

// Euclidean distance from (px, py) to the triangle (ax, ay).
double uv_distance(const double* ax, const double* ay, double px, double py) {
  const double area2 = (ax[1] - ax[0]) * (ay[2] - ay[0]) - (ax[2] - ax[0]) * (ay[1] - ay[0]);
  bool inside = true;
  double best = kInf;
  for (int k = 0; k < 3; ++k) {
    const int l = (k + 1) % 3;
    const double ex = ax[l] - ax[k], ey = ay[l] - ay[k];
    const double cross = ex * (py - ay[k]) - ey * (px - ax[k]);
    if (cross * area2 < 0) inside = false;
    const double ee = ex * ex + ey * ey;
    const double t = ee > 0 ? std::clamp(((px - ax[k]) * ex + (py - ay[k]) * ey) / ee, 0.0, 1.0) : 0.0;
    best = std::min(best, std::hypot(px - (ax[k] + t * ex), py - (ay[k] + t * ey)));
  }
  return inside ? 0.0 : best;
}

struct Reference {
  std::vector<double> exact, corners;
};

// The brute force over the quads of `tris` (grid coordinates: texel centres
// at integers; heights relative to n . origin).
Reference brute_force(const hrt::Model& M, const std::vector<uint32_t>& tris, const hrt::ContactPatch& patch,
                      bool keep_max) {
  const hrt::Window& w = patch.window;
  const int N = w.resolution;
  const double sgn = keep_max ? 1.0 : -1.0;  // work on sgn * h, keeping the max
  Reference r{std::vector<double>(static_cast<size_t>(N) * N, -kInf),
              std::vector<double>(static_cast<size_t>(N) * N, -kInf)};
  const hrt::Atlas& at = M.atlas;
  const int W = at.width, H = at.height;
  // must: quads whose centre lies within one texel (Euclidean) of a UV
  // triangle, the documented set; may: within 2.5 texels (the runtime may
  // take a few more near sharp corners, each a genuine piece of the surface).
  std::vector<uint8_t> must(static_cast<size_t>(W) * H, 0), may(static_cast<size_t>(W) * H, 0);
  for (uint32_t f : tris) {
    double ax[3], ay[3];
    for (int c = 0; c < 3; ++c) {
      ax[c] = M.uvs[f][c].x() * W - 0.5;
      ay[c] = (1.0 - M.uvs[f][c].y()) * H - 0.5;
    }
    const int i0 = std::max(0, static_cast<int>(std::floor(std::min({ax[0], ax[1], ax[2]}) - 3)));
    const int i1 = std::min(W - 2, static_cast<int>(std::ceil(std::max({ax[0], ax[1], ax[2]}) + 3)));
    const int j0 = std::max(0, static_cast<int>(std::floor(std::min({ay[0], ay[1], ay[2]}) - 3)));
    const int j1 = std::min(H - 2, static_cast<int>(std::ceil(std::max({ay[0], ay[1], ay[2]}) + 3)));
    for (int j = j0; j <= j1; ++j)
      for (int i = i0; i <= i1; ++i) {
        const double d = uv_distance(ax, ay, i + 0.5, j + 0.5);
        if (d <= 1.0) must[static_cast<size_t>(j) * W + i] = 1;
        if (d <= 2.5) may[static_cast<size_t>(j) * W + i] = 1;
      }
  }
  auto corner = [&](int i, int j) {
    const float* t = at.texel(i, j);
    const Vec3 P(t[0], t[1], t[2]);
    const Vec3 d = P - w.origin;
    return P2{d.dot(patch.u) / w.cell - 0.5, d.dot(patch.v) / w.cell - 0.5, sgn * patch.n.dot(d)};
  };
  for (int j = 0; j + 1 < H; ++j)
    for (int i = 0; i + 1 < W; ++i) {
      const size_t q = static_cast<size_t>(j) * W + i;
      if (!may[q] || !M.surface.quad_ok[q]) continue;
      const P2 c00 = corner(i, j), c10 = corner(i + 1, j), c01 = corner(i, j + 1), c11 = corner(i + 1, j + 1);
      for (const std::vector<P2>& tri : {std::vector<P2>{c00, c10, c11}, std::vector<P2>{c00, c11, c01}}) {
        double lx = kInf, hx = -kInf, ly = kInf, hy = -kInf, top = -kInf;
        for (const P2& p : tri) {
          lx = std::min(lx, p.x), hx = std::max(hx, p.x), ly = std::min(ly, p.y), hy = std::max(hy, p.y);
          top = std::max(top, p.h);
        }
        const int i0 = std::max(0, static_cast<int>(std::floor(lx + 0.5)) - 1);
        const int i1 = std::min(N - 1, static_cast<int>(std::ceil(hx + 0.5)) + 1);
        const int j0 = std::max(0, static_cast<int>(std::floor(ly + 0.5)) - 1);
        const int j1 = std::min(N - 1, static_cast<int>(std::ceil(hy + 0.5)) + 1);
        for (int gj = j0; gj <= j1; ++gj)
          for (int gi = i0; gi <= i1; ++gi) {
            const size_t t = static_cast<size_t>(gj) * N + gi;
            // Meets the square grown by a hair: the loose bound.
            constexpr double e = 1e-6;
            std::vector<P2> g =
                clip(clip(clip(clip(tri, 0, gi - 0.5 - e, false), 0, gi + 0.5 + e, true), 1, gj - 0.5 - e, false), 1,
                     gj + 0.5 + e, true);
            if (g.empty()) continue;
            r.corners[t] = std::max(r.corners[t], top);
            if (!must[q]) continue;
            std::vector<P2> c = clip(clip(clip(clip(tri, 0, gi - 0.5, false), 0, gi + 0.5, true), 1, gj - 0.5, false),
                                     1, gj + 0.5, true);
            for (const P2& p : c) r.exact[t] = std::max(r.exact[t], p.h);
          }
      }
    }
  for (size_t t = 0; t < r.exact.size(); ++t) {
    r.exact[t] *= sgn;
    r.corners[t] *= sgn;
  }
  return r;
}

std::vector<double> mesh_heights(const hrt::Model& M, const std::vector<uint32_t>& tris, const hrt::ContactPatch& patch,
                                 bool keep_max, double cull = std::numeric_limits<double>::quiet_NaN()) {
  const int N = patch.window.resolution;
  std::vector<double> h(static_cast<size_t>(N) * N);
  hrt::rasterize_heights(M, Eigen::Isometry3d::Identity(), tris, patch.n, patch.u, patch.v, patch.window, 0, keep_max,
                         h.data(), hrt::HeightMode::mesh, cull);
  return h;
}

// Ridges (steep flanks, like a fin's sides) at 23 degrees on a 20 mm block.
hrt::synth::SynthBlock ridged_block() {
  hrt::synth::BlockSpec s;
  s.atlas_size = 256;
  s.subdiv = 4;
  s.relief.profile = hrt::synth::Profile::ridges;
  s.relief.amplitude = 2e-4;
  s.relief.wavelength = 1.7e-3;
  s.relief.angle = 23 * kPi / 180;
  return hrt::synth::make_block(s);
}

struct Case {
  double tilt_deg;
  double cell;  // m
  int N;
  bool keep_max;
};

}  // namespace

TEST(MeshHeights, EveryTexelBetweenTheExactAndTheCornerBoundsOfTheBruteForce) {
  const hrt::synth::SynthBlock B = ridged_block();
  ASSERT_TRUE(B.model.surface.ready);
  std::vector<uint32_t> all(B.model.faces.size());
  for (size_t f = 0; f < all.size(); ++f) all[f] = static_cast<uint32_t>(f);
  const Vec3 axis(std::cos(70 * kPi / 180), std::sin(70 * kPi / 180), 0);
  // Grids finer than the atlas (0.03 mm) and coarser (0.45 mm: the whole face
  // under 44 texels), n tilted off the face normal by angles that are not
  // multiples of 45 degrees; the block as B (n into its face, the smallest
  // height kept) and as A (n out of it, the largest).
  for (const Case& c :
       {Case{0, 3e-5, 48, false}, Case{17, 3e-5, 48, true}, Case{38, 4.5e-4, 44, false}, Case{29, 4.5e-4, 44, true}}) {
    SCOPED_TRACE(testing::Message() << "tilt " << c.tilt_deg << " cell " << c.cell << " keep_max " << c.keep_max);
    const Vec3 down = Eigen::AngleAxisd(c.tilt_deg * kPi / 180, axis) * Vec3(0, 0, -1);
    const Vec3 n = c.keep_max ? Vec3(-down) : down;
    const hrt::ContactPatch patch =
        hrt::synth::make_patch(n, Vec3(1, 0.2, 0), Vec3(1e-4, -2e-4, 0), c.cell, c.N, {}, all);
    const std::vector<double> h = mesh_heights(B.model, all, patch, c.keep_max);
    const Reference ref = brute_force(B.model, all, patch, c.keep_max);
    // Float positions projected in double: 1e-12 m of rounding at most.
    constexpr double eps = 1e-12;
    int covered = 0, bad = 0;
    for (size_t t = 0; t < h.size(); ++t) {
      const double lo = c.keep_max ? ref.exact[t] : ref.corners[t];
      const double hi = c.keep_max ? ref.corners[t] : ref.exact[t];
      if (std::isfinite(ref.exact[t])) {
        ++covered;
        if (!(h[t] >= lo - eps && h[t] <= hi + eps)) {
          ++bad;
          ADD_FAILURE() << "texel " << t % c.N << "," << t / c.N << " h " << h[t] << " exact " << ref.exact[t]
                        << " corners " << ref.corners[t];
        }
      } else if (std::isfinite(h[t]) && !std::isfinite(ref.corners[t])) {
        ++bad;  // a height where no quad's triangle meets the square
      }
    }
    EXPECT_GT(covered, c.N * c.N / 4);
    EXPECT_EQ(bad, 0);
  }
}

TEST(MeshHeights, DrawingOrderAndTheCullChangeNoHeightThatMatters) {
  const hrt::synth::SynthBlock B = ridged_block();
  std::vector<uint32_t> all(B.model.faces.size());
  for (size_t f = 0; f < all.size(); ++f) all[f] = static_cast<uint32_t>(f);
  const Vec3 n = Eigen::AngleAxisd(21 * kPi / 180, Vec3(0.3, 0.95, 0).normalized()) * Vec3(0, 0, -1);
  const hrt::ContactPatch patch = hrt::synth::make_patch(n, Vec3(1, 0.2, 0), Vec3(1e-4, -2e-4, 0), 2e-4, 50, {}, all);
  const std::vector<double> h = mesh_heights(B.model, all, patch, false);
  std::vector<uint32_t> shuffled = all;
  std::mt19937 rng(7);
  std::shuffle(shuffled.begin(), shuffled.end(), rng);
  EXPECT_EQ(mesh_heights(B.model, shuffled, patch, false), h);
  // A cull at the median height: every texel at or below it (the kept side
  // for B, the smallest) keeps its height bit for bit.
  std::vector<double> finite;
  for (double x : h)
    if (std::isfinite(x)) finite.push_back(x);
  ASSERT_FALSE(finite.empty());
  std::nth_element(finite.begin(), finite.begin() + finite.size() / 2, finite.end());
  const double cull = finite[finite.size() / 2];
  const std::vector<double> hc = mesh_heights(B.model, all, patch, false, cull);
  int kept = 0;
  for (size_t t = 0; t < h.size(); ++t)
    if (h[t] <= cull) {
      ++kept;
      EXPECT_EQ(hc[t], h[t]) << "texel " << t;
    }
  EXPECT_GT(kept, 0);
}

// hrt check's `surface` line (hrt::surface_coverage): one atlas texel inside the
// textured face moved 3 mm off its place cuts exactly the four quads that read it
// (their edges to it pass the jump length), and the widest cut edge is the moved
// texel's distance to its farthest neighbour, computed here from the atlas itself.
TEST(MeshHeights, SurfaceCoverageCountsTheQuadsADiscontinuityCuts) {
  hrt::synth::SynthBlock B = ridged_block();
  hrt::Model& M = B.model;
  const hrt::SurfaceCoverage before = hrt::surface_coverage(M);
  EXPECT_GT(before.quads, 1000u);
  // A texel at the centre of one of the face's UV triangles.
  const uint32_t f = B.face_tris[B.face_tris.size() / 2];
  const int W = M.atlas.width, H = M.atlas.height;
  double cx = 0, cy = 0;
  for (int c = 0; c < 3; ++c) {
    cx += (M.uvs[f][c].x() * W - 0.5) / 3;
    cy += ((1.0 - M.uvs[f][c].y()) * H - 0.5) / 3;
  }
  const int ti = static_cast<int>(std::lround(cx)), tj = static_cast<int>(std::lround(cy));
  // The four quads around it must lie inside UV triangles and be usable now.
  for (int dj = -1; dj <= 0; ++dj)
    for (int di = -1; di <= 0; ++di) ASSERT_TRUE(M.surface.quad_ok[static_cast<size_t>(tj + dj) * W + ti + di]);
  float* t = &M.atlas.rgba[(static_cast<size_t>(tj) * W + ti) * 4];
  t[2] += 3e-3f;  // 3 mm along z: far past the jump length (4 texels, ~0.3 mm)
  double widest = 0;
  for (int dj = -1; dj <= 1; ++dj)
    for (int di = -1; di <= 1; ++di) {
      if ((di == 0) == (dj == 0)) continue;  // the four edge neighbours
      const float* n = M.atlas.texel(ti + di, tj + dj);
      widest = std::max(widest, std::sqrt(static_cast<double>(n[0] - t[0]) * (n[0] - t[0]) +
                                          static_cast<double>(n[1] - t[1]) * (n[1] - t[1]) +
                                          static_cast<double>(n[2] - t[2]) * (n[2] - t[2])));
    }
  hrt::prepare_surface_map(M);
  const hrt::SurfaceCoverage after = hrt::surface_coverage(M);
  EXPECT_EQ(after.quads, before.quads);
  EXPECT_EQ(after.cut, before.cut + 4);
  EXPECT_NEAR(after.widest_cut, std::max(before.widest_cut, widest), 1e-9);
}
