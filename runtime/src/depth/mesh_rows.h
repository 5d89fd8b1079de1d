// The mesh heights' visiting rule for one coarse face under one placement
// (HeightMode::mesh, docs/bundle-format.md "Heights over a texel's square"):
// whether the face is skipped whole, and per row of atlas quads the interval
// of quads worth visiting. Shared by the CPU rasterization
// (raster_triangle_mesh in raster.cpp) and the GL backend: its plan keeps a
// face or not by setup() and hands the half-planes to the vertex shader,
// which repeats range() per quad, so both visit the same quads and give the
// same bits.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

#include "depth/internal.h"
#include "hrt/model.h"
#include "hrt/surface.h"

namespace hrt {

struct MeshRows {
  // The rectangle of quads (columns qi0..qi1, rows qj0..qj1) around the UV triangle.
  int qi0 = 0, qi1 = -1, qj0 = 0, qj1 = -1;
  // The heights of the face's points lie in [hlo, hhi] (relative to n . origin).
  double hlo = 0, hhi = 0;
  // R: quad_reach in grid texels plus one texel for the footprints.
  double R = 0;

  // False when the face can hold no texel's extreme: off the grid by more
  // than its reach, on the far side of the cull (NaN: none), a degenerate UV
  // triangle, an atlas smaller than 2 x 2. x, y: the corners' grid
  // coordinates; ax, ay: their atlas coordinates (texel units); gx, gy, nobj,
  // ox, oy, oh: the placement (PlacementParams).
  bool setup(const Model& M, uint32_t f, const Vec3& nobj, double oh, int S, double cell, bool keep_max, double cull,
             const double* x, const double* y, const double* ax, const double* ay) {
    const SurfaceMap::Face& sf = M.surface.faces[f];
    // Whole-face culls: every point a quad of the face reads lies within
    // quad_reach of the face (hrt/surface.h).
    const double reach = sf.quad_reach;
    R = reach / cell + 1.0;  // grid texels, plus a texel for the footprints
    if (std::max({x[0], x[1], x[2]}) + R < -0.5 || std::min({x[0], x[1], x[2]}) - R > S - 0.5 ||
        std::max({y[0], y[1], y[2]}) + R < -0.5 || std::min({y[0], y[1], y[2]}) - R > S - 0.5)
      return false;
    hlo = std::numeric_limits<double>::infinity(), hhi = -hlo;
    for (int c = 0; c < 3; ++c) {
      const double h = nobj.dot(M.vertices[M.faces[f][c]]);
      hlo = std::min(hlo, h);
      hhi = std::max(hhi, h);
    }
    hlo += oh - reach;
    hhi += oh + reach;
    if (keep_max ? hhi < cull : hlo > cull) return false;
    const int W = M.atlas.width, H = M.atlas.height;
    if (W < 2 || H < 2) return false;
    const double e1x = ax[1] - ax[0], e1y = ay[1] - ay[0], e2x = ax[2] - ax[0], e2y = ay[2] - ay[0];
    const double area2 = e1x * e2y - e2x * e1y;
    if (!(std::abs(area2) > 1e-12)) return false;

    // The quads worth visiting, as half-planes in atlas coordinates evaluated
    // at a quad's centre (i + 0.5, j + 0.5): g[0] i + g[1] j + g[2] >= 0. Each
    // row's quads are then one interval, found without testing every quad (a
    // CAD part's flat side under a small window, a side face edge-on along n
    // whose quads all project onto a few texels, are visited only where they
    // can matter).
    nh = 0;
    // (1) Centre within one texel of the UV triangle.
    const double sgn = area2 > 0 ? 1.0 : -1.0;
    for (int k = 0; k < 3; ++k) {
      const int k1 = (k + 1) % 3;
      double nx = -sgn * (ay[k1] - ay[k]), ny = sgn * (ax[k1] - ax[k]);
      // sqrt, not hypot: the GL backend's mesh.vert repeats this bit for bit.
      const double len = std::sqrt(nx * nx + ny * ny);
      nx /= len, ny /= len;
      hp[nh++] = {nx, ny, -(nx * ax[k] + ny * ay[k]) + 1.0};
    }
    // (2) Only where a quad's points can project onto the grid or lie on the
    // near side of the height cull. The face's affine map from atlas to grid x,
    // y and height (the coarse point a texel parameterizes, extrapolated past
    // the edges); a point a quad reads lies within `reach` (m) of the closest
    // face point to its texel, which is within 1.75 + 0.71 texels of the
    // quad's centre: `slack` covers that step of the affine map.
    {
      double hc[3];
      for (int c = 0; c < 3; ++c) hc[c] = nobj.dot(M.vertices[M.faces[f][c]]) + oh;
      const double inv = 1.0 / area2;
      // d/d(ax), d/d(ay) of a quantity with values q[0..2] at the corners.
      auto affine = [&](const double* q, double& da, double& db) {
        const double d1 = q[1] - q[0], d2 = q[2] - q[0];
        da = (d1 * e2y - d2 * e1y) * inv;
        db = (d2 * e1x - d1 * e2x) * inv;
      };
      auto add = [&](const double* q, double sign, double bound) {  // sign (q - bound) >= 0 at the corners' map
        double da, db;
        affine(q, da, db);
        if (!std::isfinite(da) || !std::isfinite(db)) return;
        const double slack = (kQuadReadMargin + 0.75) * std::sqrt(da * da + db * db);
        // sign (q0 + da (i + 0.5 - ax0) + db (j + 0.5 - ay0) - bound) + slack >= 0
        hp[nh++] = {sign * da, sign * db, sign * (q[0] + da * (0.5 - ax[0]) + db * (0.5 - ay[0]) - bound) + slack};
      };
      const double Rg = reach / cell;  // grid texels (gx, gy are per metre / cell)
      add(x, +1.0, -0.5 - Rg);
      add(x, -1.0, S - 0.5 + Rg);
      add(y, +1.0, -0.5 - Rg);
      add(y, -1.0, S - 0.5 + Rg);
      if (std::isfinite(cull)) {
        if (keep_max)
          add(hc, +1.0, cull - reach);
        else
          add(hc, -1.0, cull + reach);
      }
    }
    // Rows of quads: centres within one texel of the triangle's box.
    auto clampi = [](double v, int lo, int hi) {  // clamped in double first (far faces, huge coordinates)
      return static_cast<int>(std::clamp(v, static_cast<double>(lo), static_cast<double>(hi)));
    };
    qi0 = clampi(std::floor(std::min({ax[0], ax[1], ax[2]}) - 1.5), 0, W - 2);
    qi1 = clampi(std::ceil(std::max({ax[0], ax[1], ax[2]}) + 0.5), 0, W - 2);
    qj0 = clampi(std::floor(std::min({ay[0], ay[1], ay[2]}) - 1.5), 0, H - 2);
    qj1 = clampi(std::ceil(std::max({ay[0], ay[1], ay[2]}) + 0.5), 0, H - 2);
    return true;
  }

  // The interval of row j, [lo, hi] (empty when lo > hi), widened by a
  // hair: a quad visited in excess is still a piece of the full surface.
  void range(int j, int& lo, int& hi) const {
    double flo = qi0, fhi = qi1;
    const double cj = j + 0.5;
    for (int k = 0; k < nh && flo <= fhi; ++k) {
      const double rest = hp[k].gj * cj + hp[k].g0;  // + gi (i + 0.5) >= 0
      const double eps = 1e-9 * (std::abs(rest) + std::abs(hp[k].gi) * (std::abs(flo) + std::abs(fhi)) + 1.0);
      if (std::abs(hp[k].gi) < 1e-300) {
        if (rest + eps < 0) flo = fhi + 1;
      } else if (hp[k].gi > 0) {
        flo = std::max(flo, -(rest + eps) / hp[k].gi - 0.5);
      } else {
        fhi = std::min(fhi, -(rest + eps) / hp[k].gi - 0.5);
      }
    }
    if (!(flo <= fhi)) {
      lo = 1, hi = 0;
      return;
    }
    lo = static_cast<int>(std::ceil(flo));
    hi = static_cast<int>(std::floor(fhi));
  }

  // The half-planes range() intersects: count, and (gi, gj, g0) per plane
  // into out[3 k .. 3 k + 2] (out holds kMaxPlanes x 3).
  static constexpr int kMaxPlanes = 8;
  int planes(double* out) const {
    for (int k = 0; k < nh; ++k) out[3 * k] = hp[k].gi, out[3 * k + 1] = hp[k].gj, out[3 * k + 2] = hp[k].g0;
    return nh;
  }

 private:
  struct HalfPlane {
    double gi, gj, g0;
  };
  HalfPlane hp[kMaxPlanes];
  int nh = 0;
};

}  // namespace hrt
