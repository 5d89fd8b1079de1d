// prepare_surface_map (hrt/surface.h): per-face lateral-offset bounds and the
// per-quad usability mask of the atlas.
#include <algorithm>
#include <cmath>
#include <limits>

#include <nlohmann/json.hpp>

#include "hrt/model.h"
#include "hrt/surface.h"
#include "surface/row_span.h"

namespace hrt {
namespace {

// Texels whose centre lies within this many texels of a face's UV triangle
// count as read by the face's lookups: a bilinear lookup at a point inside
// the triangle reads texels at Chebyshev distance < 1 from it.
constexpr double kReadMargin = 1.0;

// Spec default of atlas.gutter (docs/bundle-format.md), for models that carry
// no manifest (tests that build a Model by hand).
constexpr int kDefaultGutter = 4;

// Atlas texel coordinates of face f's UV corners (spec: x = u W - 0.5,
// y = (1 - v) H - 0.5).
void atlas_corners(const Model& model, size_t f, double* ax, double* ay) {
  const double W = model.atlas.width, H = model.atlas.height;
  for (int c = 0; c < 3; ++c) {
    ax[c] = static_cast<double>(model.uvs[f][c].x()) * W - 0.5;
    ay[c] = (1.0 - static_cast<double>(model.uvs[f][c].y())) * H - 0.5;
  }
}

int manifest_gutter(const Model& m) {
  if (!m.manifest) return kDefaultGutter;  // a model built in code
  const nlohmann::json& j = *m.manifest;
  if (j.is_object() && j.contains("atlas") && j["atlas"].is_object() && j["atlas"].contains("gutter") &&
      j["atlas"]["gutter"].is_number_integer())
    return std::max(1, j["atlas"]["gutter"].get<int>());
  return kDefaultGutter;
}

// filled[t]: texel t within `g` (Chebyshev) of a covered texel (A != 0):
// a separable max filter of the coverage, rows then columns.
std::vector<uint8_t> filled_mask(const Atlas& at, int g) {
  const int W = at.width, H = at.height;
  std::vector<uint8_t> cov(static_cast<size_t>(W) * H), tmp(cov.size()), out(cov.size());
  for (size_t t = 0; t < cov.size(); ++t) cov[t] = at.rgba[4 * t + 3] != 0.0f;
  // Row pass: distance to the last covered texel on either side within g.
  for (int j = 0; j < H; ++j) {
    const uint8_t* c = &cov[static_cast<size_t>(j) * W];
    uint8_t* o = &tmp[static_cast<size_t>(j) * W];
    int last = -(1 << 30);
    for (int i = 0; i < W; ++i) {
      if (c[i]) last = i;
      o[i] = i - last <= g;
    }
    last = 1 << 30;
    for (int i = W - 1; i >= 0; --i) {
      if (c[i]) last = i;
      o[i] = o[i] || last - i <= g;
    }
  }
  for (int i = 0; i < W; ++i) {
    int last = -(1 << 30);
    for (int j = 0; j < H; ++j) {
      if (tmp[static_cast<size_t>(j) * W + i]) last = j;
      out[static_cast<size_t>(j) * W + i] = j - last <= g;
    }
    last = 1 << 30;
    for (int j = H - 1; j >= 0; --j) {
      if (tmp[static_cast<size_t>(j) * W + i]) last = j;
      uint8_t& o = out[static_cast<size_t>(j) * W + i];
      o = o || last - j <= g;
    }
  }
  return out;
}

// Quads: the usable ones (their four texels filled, no jump between
// neighbours) in sm.quad_ok.
void mark_quads(SurfaceMap& sm, const Atlas& at, const std::vector<uint8_t>& filled) {
  const int W = at.width, H = at.height;
  sm.quad_ok.assign(static_cast<size_t>(W) * H + SurfaceMap::kQuadOkPadding, 0);
  const double jump2 = sm.jump * sm.jump;
  auto pos = [&](int i, int j) {
    const float* p = at.texel(i, j);
    return Eigen::Vector3d(p[0], p[1], p[2]);
  };
  for (int j = 0; j < H; ++j) {
    const int j1 = std::min(j + 1, H - 1);
    for (int i = 0; i < W; ++i) {
      const int i1 = std::min(i + 1, W - 1);
      const size_t t00 = static_cast<size_t>(j) * W + i, t10 = static_cast<size_t>(j) * W + i1;
      const size_t t01 = static_cast<size_t>(j1) * W + i, t11 = static_cast<size_t>(j1) * W + i1;
      const bool any = filled[t00] || filled[t10] || filled[t01] || filled[t11];
      if (!(filled[t00] && filled[t10] && filled[t01] && filled[t11])) continue;
      bool ok = true;
      if (jump2 > 0) {
        const Eigen::Vector3d a = pos(i, j), b = pos(i1, j), c = pos(i, j1), d = pos(i1, j1);
        ok = (a - b).squaredNorm() <= jump2 && (c - d).squaredNorm() <= jump2 && (a - c).squaredNorm() <= jump2 &&
             (b - d).squaredNorm() <= jump2;
      }
      sm.quad_ok[t00] = ok;
      if (!ok && any) ++sm.cut_quads;
    }
  }
}

// Block boxes of the usable quads' corners (hrt/surface.h).
void block_boxes(SurfaceMap& sm, const Atlas& at) {
  const int W = at.width, H = at.height;
  constexpr int B = SurfaceMap::kQuadBlock;
  sm.blocks_w = (W + B - 1) / B, sm.blocks_h = (H + B - 1) / B;
  sm.blocks.assign(static_cast<size_t>(sm.blocks_w) * sm.blocks_h, SurfaceMap::Block{});
  for (int j = 0; j < H; ++j) {
    const int j1 = std::min(j + 1, H - 1);
    for (int i = 0; i < W; ++i) {
      if (!sm.quad_ok[static_cast<size_t>(j) * W + i]) continue;
      const int i1 = std::min(i + 1, W - 1);
      SurfaceMap::Block& b = sm.blocks[static_cast<size_t>(j / B) * sm.blocks_w + i / B];
      const bool first = b.lo.x() > b.hi.x();
      for (const float* p : {at.texel(i, j), at.texel(i1, j), at.texel(i, j1), at.texel(i1, j1)}) {
        const Eigen::Vector3f q(p[0], p[1], p[2]);
        if (first && b.lo.x() > b.hi.x()) {
          b.lo = b.hi = q;
        } else {
          b.lo = b.lo.cwiseMin(q);
          b.hi = b.hi.cwiseMax(q);
        }
      }
    }
  }
}

// A texel is read by some lookup only through a usable quad (a lookup in
// an unusable one returns no height): texels none of whose four quads is
// usable never bound a face's offsets. Without this, a texel one texel off
// a small chart, filled from the neighbouring chart of the atlas, puts that
// chart's surface (millimetres away) into the face's reach, and the face
// then rasterizes dilated by millimetres (seen on a 600-face sphere: 87 of
// 124 faces with a reach above 50 um, up to 1.9 mm, for a surface 6 um off
// its coarse mesh).
std::vector<uint8_t> readable_texels(const SurfaceMap& sm, const int W, const int H) {
  std::vector<uint8_t> readable(static_cast<size_t>(W) * H, 0);
  for (int j = 0; j < H; ++j)
    for (int i = 0; i < W; ++i) {
      if (!sm.quad_ok[static_cast<size_t>(j) * W + i]) continue;
      const int i1 = std::min(i + 1, W - 1), j1 = std::min(j + 1, H - 1);
      readable[static_cast<size_t>(j) * W + i] = readable[static_cast<size_t>(j) * W + i1] = 1;
      readable[static_cast<size_t>(j1) * W + i] = readable[static_cast<size_t>(j1) * W + i1] = 1;
    }
  return readable;
}

// The offsets w (surface point minus face point) of the readable texels
// within kReadMargin of face f's UV triangle, and quad_reach over those
// beyond it (up to kQuadReadMargin: only a mesh quad's corner). Counts the
// texels examined in `work`; false past `budget`.
bool face_offsets(const Model& model, const size_t f, const std::vector<uint8_t>& readable, const uint64_t budget,
                  uint64_t& work, std::vector<Eigen::Vector3d>& w, double& quad_reach) {
  const Atlas& at = model.atlas;
  const int W = at.width, H = at.height;
  const Tri& tri = model.faces[f];
  double ax[3], ay[3];
  atlas_corners(model, f, ax, ay);
  const double e1x = ax[1] - ax[0], e1y = ay[1] - ay[0], e2x = ax[2] - ax[0], e2y = ay[2] - ay[0];
  const double area2 = e1x * e2y - e2x * e1y;
  w.clear();
  quad_reach = 0.0;
  if (std::abs(area2) > 1e-12) {
    // Clamped in double before the conversion (a bundle loaded without the
    // invariant checks may carry any UV).
    auto to_index = [](double x, int hi) {
      if (!(x >= 0)) return 0;  // also NaN
      return x <= hi ? static_cast<int>(x) : hi;
    };
    const int i0 = to_index(std::floor(std::min({ax[0], ax[1], ax[2]}) - kQuadReadMargin), W - 1);
    const int i1 = to_index(std::ceil(std::max({ax[0], ax[1], ax[2]}) + kQuadReadMargin), W - 1);
    const int j0 = to_index(std::floor(std::min({ay[0], ay[1], ay[2]}) - kQuadReadMargin), H - 1);
    const int j1 = to_index(std::ceil(std::max({ay[0], ay[1], ay[2]}) + kQuadReadMargin), H - 1);
    if (i0 <= i1 && j0 <= j1) work += static_cast<uint64_t>(i1 - i0 + 1) * static_cast<uint64_t>(j1 - j0 + 1);
    if (work > budget) return false;  // ready stays false
    const Eigen::Vector3d &P0 = model.vertices[tri[0]], &P1 = model.vertices[tri[1]], &P2 = model.vertices[tri[2]];
    // Each row visits only the texels that can lie within kQuadReadMargin
    // of the UV triangle (the others are skipped below anyway, and on a
    // thin or slanted triangle they are most of its box).
    const RowSpan rows(ax, ay, kQuadReadMargin);
    for (int j = j0; j <= j1; ++j) {
      int ia, ib;
      if (!rows.span(j, i0, i1, ia, ib)) continue;
      for (int i = ia; i <= ib; ++i) {
        // Barycentrics of the texel centre (i, j) in the UV triangle.
        const double dx = i - ax[0], dy = j - ay[0];
        const double b1 = (dx * e2y - e2x * dy) / area2, b2 = (e1x * dy - dx * e1y) / area2, b0 = 1 - b1 - b2;
        // The texel counts when its centre lies within kReadMargin of the
        // UV triangle (Euclidean; the tips of a needle triangle reach no
        // farther). q: the face point at the closest point of the UV
        // triangle (the point a lookup that reads this texel is near), not
        // the extrapolated one, which for a needle lies metres away.
        double c[3] = {b0, b1, b2};
        bool read = true;  // within kReadMargin (else only a mesh quad's corner)
        if (b0 < 0 || b1 < 0 || b2 < 0) {
          double best = std::numeric_limits<double>::infinity();
          for (int k = 0; k < 3; ++k) {  // segment from corner k to corner k+1
            const int l = (k + 1) % 3;
            const double sx = ax[l] - ax[k], sy = ay[l] - ay[k];
            const double ss = sx * sx + sy * sy;
            const double t = ss > 0 ? std::clamp(((i - ax[k]) * sx + (j - ay[k]) * sy) / ss, 0.0, 1.0) : 0.0;
            const double ddx = i - (ax[k] + t * sx), ddy = j - (ay[k] + t * sy);
            const double d2 = ddx * ddx + ddy * ddy;
            if (d2 < best) {
              best = d2;
              c[0] = c[1] = c[2] = 0.0;
              c[k] = 1.0 - t;
              c[l] = t;
            }
          }
          if (best > kQuadReadMargin * kQuadReadMargin) continue;
          read = best <= kReadMargin * kReadMargin;
        }
        if (!readable[static_cast<size_t>(j) * W + i]) continue;
        const float* p = at.texel(i, j);
        const Eigen::Vector3d q = c[0] * P0 + c[1] * P1 + c[2] * P2;
        const Eigen::Vector3d d = Eigen::Vector3d(p[0], p[1], p[2]) - q;
        if (read)
          w.push_back(d);
        else
          quad_reach = std::max(quad_reach, d.norm());
      }
    }
  }
  return true;
}

// Face f's bounds (SurfaceMap::Face) from its offsets w and quad_reach.
void face_bounds(const Eigen::Vector3d& nf, const std::vector<Eigen::Vector3d>& w, const double quad_reach,
                 SurfaceMap::Face& out) {
  out.quad_reach = static_cast<float>(quad_reach * (1 + 1e-6)) + std::numeric_limits<float>::denorm_min();
  if (w.empty()) return;  // no texel read: the face has no lateral offset to correct

  // The lateral offset of w and of -w are the same, and the relief goes
  // both ways (in and out of the coarse surface): the bound is about the
  // *line* of the axis. Axis: the mean of the offset directions, each
  // flipped to the side of the face normal.
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  double reach = 0.0;
  for (const Eigen::Vector3d& x : w) {
    const double r = x.norm();
    reach = std::max(reach, r);
    if (r > 0) sum += (x.dot(nf) < 0 ? -1.0 : 1.0) * x / r;
  }
  Eigen::Vector3d axis = sum.norm() > 1e-12 ? Eigen::Vector3d(sum.normalized()) : nf;
  if (!(axis.norm() > 0.5)) axis = Eigen::Vector3d::UnitZ();
  double along = 0.0, across = 0.0;  // max |w . axis|, max |w - (w . axis) axis|
  for (const Eigen::Vector3d& x : w) {
    const double a = axis.dot(x);
    along = std::max(along, std::abs(a));
    across = std::max(across, (x - a * axis).norm());
  }
  // Rounded outward so the bound stays a bound in float.
  out.axis = axis.cast<float>();
  out.along = static_cast<float>(along * (1 + 1e-6)) + std::numeric_limits<float>::denorm_min();
  out.across = static_cast<float>(across * (1 + 1e-6)) + std::numeric_limits<float>::denorm_min();
  out.reach = static_cast<float>(reach * (1 + 1e-6)) + std::numeric_limits<float>::denorm_min();
  out.quad_reach = std::max(out.quad_reach, out.reach);
}

}  // namespace

void prepare_surface_map(Model& model) {
  SurfaceMap& sm = model.surface;
  sm = SurfaceMap{};
  const Atlas& at = model.atlas;
  const int W = at.width, H = at.height;
  if (W <= 0 || H <= 0 || at.rgba.size() != static_cast<size_t>(W) * H * 4) return;
  const double texel = model.quality.texel_size;
  sm.jump = texel > 0 ? kJumpTexels * texel : 0.0;

  mark_quads(sm, at, filled_mask(at, manifest_gutter(model)));
  block_boxes(sm, at);
  const std::vector<uint8_t> readable = readable_texels(sm, W, H);

  // --- faces -----------------------------------------------------------------
  const size_t F = model.faces.size();
  sm.faces.assign(F, SurfaceMap::Face{});
  // Work bound: texel centres examined, at most this many per atlas texel
  // plus per face, the loader's bound on its own atlas checks
  // (docs/input-contract.md). A valid atlas's UV triangles do not overlap, so
  // their boxes cover it about twice; a bundle loaded without the invariant
  // checks may have slivers across the whole atlas: beyond the bound the map
  // is not made (ready stays false) and the model's heights are Eq. 8's.
  const uint64_t budget = 16ull * static_cast<uint64_t>(W) * static_cast<uint64_t>(H) + 64ull * F;
  uint64_t work = 0;
  std::vector<Eigen::Vector3d> w;  // offsets of one face (reused)
  for (size_t f = 0; f < F; ++f) {
    double quad_reach = 0.0;  // over the texels beyond kReadMargin (the rest: reach)
    if (!face_offsets(model, f, readable, budget, work, w, quad_reach)) return;  // ready stays false
    SurfaceMap::Face& out = sm.faces[f];
    face_bounds(model.face_normals[f], w, quad_reach, out);
  }
  sm.ready = true;
}

SurfaceCoverage surface_coverage(const Model& model) {
  SurfaceCoverage out;
  const SurfaceMap& sm = model.surface;
  const Atlas& at = model.atlas;
  const int W = at.width, H = at.height;
  if (!sm.ready || W < 2 || H < 2 || sm.quad_ok.size() != static_cast<size_t>(W) * H + SurfaceMap::kQuadOkPadding)
    return out;
  // A quad counts once even where two triangles' boxes overlap.
  std::vector<uint8_t> seen(static_cast<size_t>(W) * H, 0);
  for (size_t f = 0; f < model.faces.size(); ++f) {
    double ax[3], ay[3];
    atlas_corners(model, f, ax, ay);
    const double e1x = ax[1] - ax[0], e1y = ay[1] - ay[0], e2x = ax[2] - ax[0], e2y = ay[2] - ay[0];
    const double area2 = e1x * e2y - e2x * e1y;
    if (!(std::abs(area2) > 1e-12)) continue;
    // Quad (i, j) has its centre at (i + 0.5, j + 0.5).
    auto clampi = [](double v, int hi) { return static_cast<int>(std::clamp(v, 0.0, static_cast<double>(hi))); };
    const int i0 = clampi(std::floor(std::min({ax[0], ax[1], ax[2]}) - 0.5), W - 2);
    const int i1 = clampi(std::ceil(std::max({ax[0], ax[1], ax[2]}) - 0.5), W - 2);
    const int j0 = clampi(std::floor(std::min({ay[0], ay[1], ay[2]}) - 0.5), H - 2);
    const int j1 = clampi(std::ceil(std::max({ay[0], ay[1], ay[2]}) - 0.5), H - 2);
    for (int j = j0; j <= j1; ++j)
      for (int i = i0; i <= i1; ++i) {
        const double dx = i + 0.5 - ax[0], dy = j + 0.5 - ay[0];
        const double b1 = (dx * e2y - e2x * dy) / area2, b2 = (e1x * dy - dx * e1y) / area2;
        if (b1 < 0 || b2 < 0 || b1 + b2 > 1) continue;
        const size_t q = static_cast<size_t>(j) * W + i;
        if (seen[q]) continue;
        seen[q] = 1;
        ++out.quads;
        if (sm.quad_ok[q]) continue;
        ++out.cut;
        const float* c[4] = {at.texel(i, j), at.texel(i + 1, j), at.texel(i + 1, j + 1), at.texel(i, j + 1)};
        for (int k = 0; k < 4; ++k) {
          // (A valid bundle fills every texel a lookup inside a triangle reads:
          // docs/bundle-format.md, the coverage rule; a cut here is a jump.)
          const float *a = c[k], *b = c[(k + 1) % 4];
          const double d = std::sqrt(static_cast<double>(a[0] - b[0]) * (a[0] - b[0]) +
                                     static_cast<double>(a[1] - b[1]) * (a[1] - b[1]) +
                                     static_cast<double>(a[2] - b[2]) * (a[2] - b[2]));
          if (std::isfinite(d)) out.widest_cut = std::max(out.widest_cut, d);
        }
      }
  }
  return out;
}

}  // namespace hrt
