// load_bundle: reads and checks a bundle directory (docs/bundle-format.md).
//
// The first problem found is thrown as a BundleError. The checks run in the
// order of the spec's error classes, which is also the order in which
// `hbake validate` (hbake/bundle/validate.py, the reference) sorts its problems, so a
// bundle with one problem gets the same class from both readers, and the
// messages use the same wording:
//   io       bundle directory and manifest.json exist and are readable
//   schema   manifest.json is UTF-8 JSON with an object at the top
//   version  format == "hbundle", format_version major == 1
//   schema   every field of the schema with its type (manifest.cpp)
//   io       the three files exist and are regular files
//   hash     byte size and SHA-256 of each file equal the manifest's
//   mesh     coarse.ply: header, length, counts, finite positions, indices,
//            no degenerate face, finite UVs in [0, 1]
//   atlas    atlas.exr: header, compression, windows, channels, FLOAT; A in
//            {0, 1}; every texel a bilinear lookup inside a UV triangle reads
//            is finite and filled (covered or within the gutter); no stray
//            non-finite texel; coverage agrees with the UV triangles
//   pieces   pieces.ply: header, length, ids, order, indices, finite
//            positions, map; per piece >= 4 vertices and faces, closed,
//            no zero-area face, positive volume, convex
// The same bytes are hashed and parsed (each file is read once).
//
// Index checks (vertex indices, piece ids, map indices) always run, whatever
// LoadOptions says, because later stages index arrays with them; the value
// checks (finite values, UV range, degeneracy, closedness, convexity, atlas
// texels) run when LoadOptions::check_invariants is set.
#include <sys/stat.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <utility>

#include "io/bundle_io.h"

namespace hrt {

const char* to_string(BundleErrorClass c) {
  switch (c) {
    case BundleErrorClass::io: return "io";
    case BundleErrorClass::version: return "version";
    case BundleErrorClass::schema: return "schema";
    case BundleErrorClass::hash: return "hash";
    case BundleErrorClass::mesh: return "mesh";
    case BundleErrorClass::atlas: return "atlas";
    case BundleErrorClass::pieces: return "pieces";
  }
  return "unknown";
}

namespace {

using io::FileEntry;

// Texel-space margin of the coverage check (a check of the spec beyond
// `hbake validate`'s): a texel centre farther than this inside a UV triangle
// must have A = 1, and a texel with A = 1 must have its centre inside some UV
// triangle or within this distance of one. Centres within the margin of an
// edge may go either way: the stored UVs are float32 (rounded by up to
// W 2^-24 texel, 6e-5 at W = 1024) and the writer may rasterise the unrounded ones.
constexpr double kCoverageMargin = 1e-3;

// Widening (texels) of the per-row candidate spans of the atlas checks, far
// above the rounding of their computation (coordinates up to 8192 texels).
constexpr double kSpanPad = 1e-6;

// Work bound of the atlas's per-triangle checks: rows and candidate texels
// examined, at most this many per texel of the atlas plus per triangle
// (docs/input-contract.md). Bounds their cost by the atlas's own size and
// the file's, whatever the UV triangles.
constexpr uint64_t kWorkPerTexel = 16;
constexpr uint64_t kWorkPerTriangle = 64;

// The spec's convexity tolerance: 1e-6 * bbox_diagonal + 1e-9 m, with the
// bounding-box diagonal of the coarse mesh (as hbake.bundle.convexity_tolerance).
constexpr double kConvexRel = 1e-6;
constexpr double kConvexAbs = 1e-9;

std::string join_path(const std::string& dir, const std::string& name) {
  if (!dir.empty() && dir.back() == '/') return dir + name;
  return dir + "/" + name;
}

std::string fmt(const char* f, double x) {
  char buf[64];
  std::snprintf(buf, sizeof buf, f, x);
  return buf;
}

std::string s(size_t n) { return std::to_string(n); }

// "1 face", "3 faces" (the Python reader's wording).
std::string count_of(size_t n, const std::string& noun, const std::string& plural = "") {
  return s(n) + " " + (n == 1 ? noun : (plural.empty() ? noun + "s" : plural));
}

// Count of offending items and the first of them, for messages like
// "3 faces with ...: face 7 = [...]".
struct First {
  size_t count = 0;
  size_t first = 0;
  void add(size_t k) {
    if (count++ == 0) first = k;
  }
  explicit operator bool() const { return count > 0; }
};

std::string tri_list(const Tri& t) { return "[" + s(t[0]) + ", " + s(t[1]) + ", " + s(t[2]) + "]"; }

bool finite3(const std::array<float, 3>& p) {
  return std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]);
}

// Positions (coarse and piece vertices, atlas RGB) lie within this many
// meters of the object origin on each axis: hbake's input limit
// (hbake/constants.py MAX_COORDINATE, docs/input-contract.md). Farther ones
// are no haptic object, and they drive the frame's rasterizer and forces
// into magnitudes nothing downstream is made for.
constexpr double kMaxCoordinate = 1e4;
bool far3(const std::array<float, 3>& p) {
  return std::abs(p[0]) > kMaxCoordinate || std::abs(p[1]) > kMaxCoordinate || std::abs(p[2]) > kMaxCoordinate;
}

Vec3 to_vec3(const std::array<float, 3>& p) { return Vec3(p[0], p[1], p[2]); }

// ---- coarse mesh --------------------------------------------------------------

void load_coarse(Model& model, const io::CoarsePly& ply, const io::ManifestInfo& info, const std::string& label,
                 bool invariants) {
  auto fail = [&](const std::string& what) { throw BundleError(BundleErrorClass::mesh, label + ": " + what); };
  const size_t n = ply.vertices.size(), m = ply.faces.size();
  if (n != info.coarse_vertices || m != info.coarse_triangles) {
    fail(s(n) + " vertices and " + s(m) + " faces, the manifest says " + s(info.coarse_vertices) + " and " +
         s(info.coarse_triangles));
  }
  if (n < 3) fail(s(n) + " vertices (at least 3 needed)");
  if (m < 1) fail("no faces");
  if (invariants) {
    First bad;
    for (size_t i = 0; i < n; ++i)
      if (!finite3(ply.vertices[i])) bad.add(i);
    if (bad) {
      const auto& v = ply.vertices[bad.first];
      fail(count_of(bad.count, "vertex", "vertices") + " with non-finite positions: vertex " + s(bad.first) + " = [" +
           fmt("%g", v[0]) + ", " + fmt("%g", v[1]) + ", " + fmt("%g", v[2]) + "]");
    }
    First far;
    for (size_t i = 0; i < n; ++i)
      if (far3(ply.vertices[i])) far.add(i);
    if (far) {
      const auto& v = ply.vertices[far.first];
      fail(count_of(far.count, "vertex", "vertices") + " farther than 10000 m from the origin along an axis: vertex " +
           s(far.first) + " = [" + fmt("%g", v[0]) + ", " + fmt("%g", v[1]) + ", " + fmt("%g", v[2]) + "]");
    }
  }
  {
    First bad;
    for (size_t f = 0; f < m; ++f) {
      const Tri& t = ply.faces[f];
      if (t[0] >= n || t[1] >= n || t[2] >= n) bad.add(f);
    }
    if (bad) {
      fail(count_of(bad.count, "face") + " with a vertex index out of range (vertex count " + s(n) + "): face " +
           s(bad.first) + " = " + tri_list(ply.faces[bad.first]));
    }
  }
  model.vertices.resize(n);
  for (size_t i = 0; i < n; ++i) model.vertices[i] = to_vec3(ply.vertices[i]);
  model.faces = ply.faces;
  model.face_normals.resize(m);
  model.face_areas.resize(m);
  First degenerate;
  for (size_t f = 0; f < m; ++f) {
    const Tri& t = ply.faces[f];
    // Geometric normal (v1 - v0) x (v2 - v0): outward by the spec's winding.
    const Vec3 c = (model.vertices[t[1]] - model.vertices[t[0]]).cross(model.vertices[t[2]] - model.vertices[t[0]]);
    const double len = c.norm();
    const bool same = t[0] == t[1] || t[1] == t[2] || t[0] == t[2];
    if (same || len == 0.0) degenerate.add(f);
    model.face_areas[f] = 0.5 * len;
    model.face_normals[f] = len > 0.0 ? Vec3(c / len) : Vec3::Zero();
  }
  if (invariants && degenerate) {
    fail(count_of(degenerate.count, "degenerate face") + " (zero area): face " + s(degenerate.first) + " = " +
         tri_list(ply.faces[degenerate.first]));
  }
  model.uvs.resize(m);
  First nonfinite, outside;
  for (size_t f = 0; f < m; ++f) {
    const auto& uv = ply.uvs[f];
    bool fin = true, in = true;
    for (float x : uv) {
      fin = fin && std::isfinite(x);
      in = in && !(x < 0.0f || x > 1.0f);  // NaN counts as non-finite only, as in the reference
    }
    if (!fin) nonfinite.add(f);
    if (!in) outside.add(f);
    for (int k = 0; k < 3; ++k) model.uvs[f][k] = Vec2f(uv[2 * k], uv[2 * k + 1]);
  }
  if (invariants && nonfinite)
    fail(count_of(nonfinite.count, "face") + " with non-finite UVs: face " + s(nonfinite.first));
  if (invariants && outside) {
    const auto& uv = ply.uvs[outside.first];
    std::string list;
    for (int k = 0; k < 3; ++k)
      list += std::string(k ? ", " : "") + "[" + fmt("%.9g", uv[2 * k]) + ", " + fmt("%.9g", uv[2 * k + 1]) + "]";
    fail(count_of(outside.count, "face") + " with UVs outside [0, 1]: face " + s(outside.first) + " has [" + list +
         "]");
  }
}

// ---- atlas texels -------------------------------------------------------------

// Marks, in `mask`, every texel (clamped to the image) that a bilinear lookup
// at some point of the UV triangle reads: a point at texel coordinates (x, y)
// reads texels floor(x) + {0, 1} x floor(y) + {0, 1}, so texel (i, j) is read
// iff the triangle meets the closed square [i-1, i+1] x [j-1, j+1]; tested by
// separating axes (the two box axes and the three edge normals), as
// hbake.bundle._footprint_texels does.
// `work` counts the rows and candidate texels examined (see kWorkPerTexel).
template <typename Visit>
void footprint(const std::array<Vec2f, 3>& uv, int W, int H, uint64_t& work, Visit&& visit) {
  double px[3], py[3];
  for (int k = 0; k < 3; ++k) {
    px[k] = static_cast<double>(uv[k].x()) * W - 0.5;
    py[k] = (1.0 - static_cast<double>(uv[k].y())) * H - 0.5;
  }
  const double xmin = std::min({px[0], px[1], px[2]}), xmax = std::max({px[0], px[1], px[2]});
  const double ymin = std::min({py[0], py[1], py[2]}), ymax = std::max({py[0], py[1], py[2]});
  // Candidates bounded by the image (plus one): beyond it lookups clamp to the border.
  const long i0 = std::max<long>(static_cast<long>(std::floor(xmin)) - 1, -1);
  const long i1 = std::min<long>(static_cast<long>(std::ceil(xmax)) + 1, W);
  const long j0 = std::max<long>(static_cast<long>(std::floor(ymin)) - 1, -1);
  const long j1 = std::min<long>(static_cast<long>(std::ceil(ymax)) + 1, H);
  double nx[3], ny[3], tmin[3], tmax[3], r[3];
  for (int k = 0; k < 3; ++k) {
    const int k1 = (k + 1) % 3;
    nx[k] = py[k1] - py[k];
    ny[k] = px[k] - px[k1];
    tmin[k] = HUGE_VAL;
    tmax[k] = -HUGE_VAL;
    for (int q = 0; q < 3; ++q) {
      const double t = px[q] * nx[k] + py[q] * ny[k];
      tmin[k] = std::min(tmin[k], t);
      tmax[k] = std::max(tmax[k], t);
    }
    r[k] = std::fabs(nx[k]) + std::fabs(ny[k]);
  }
  for (long j = j0; j <= j1; ++j) {
    if (j < ymin - 1 || j > ymax + 1) continue;
    ++work;
    // Candidates of this row: the x-extent of the triangle within the band
    // [j-1, j+1] (widened by kSpanPad), so the work per triangle is its rows
    // plus the texels it reads, not its bounding box (a sliver UV triangle
    // across the atlas once cost W x H tests). A superset of the texels the
    // exact test below keeps, so the result is unchanged.
    const double ylo = j - 1 - kSpanPad, yhi = j + 1 + kSpanPad;
    double xa = HUGE_VAL, xb = -HUGE_VAL;
    for (int k = 0; k < 3; ++k) {
      if (py[k] >= ylo && py[k] <= yhi) xa = std::min(xa, px[k]), xb = std::max(xb, px[k]);
      const int k1 = (k + 1) % 3;
      if (py[k] == py[k1]) continue;
      for (const double yl : {ylo, yhi}) {
        if ((py[k] - yl) * (py[k1] - yl) > 0) continue;
        const double x = px[k] + (yl - py[k]) / (py[k1] - py[k]) * (px[k1] - px[k]);
        xa = std::min(xa, x);
        xb = std::max(xb, x);
      }
    }
    if (!(xa <= xb)) continue;
    const long ia = std::max<long>(i0, static_cast<long>(std::floor(xa - 1 - kSpanPad)) - 1);
    const long ib = std::min<long>(i1, static_cast<long>(std::ceil(xb + 1 + kSpanPad)) + 1);
    if (ib >= ia) work += static_cast<uint64_t>(ib - ia + 1);
    for (long i = ia; i <= ib; ++i) {
      if (i < xmin - 1 || i > xmax + 1) continue;
      bool keep = true;
      for (int k = 0; k < 3 && keep; ++k) {
        const double c = i * nx[k] + j * ny[k];
        keep = c + r[k] >= tmin[k] && c - r[k] <= tmax[k];
      }
      if (keep) visit(static_cast<int>(std::clamp<long>(i, 0, W - 1)), static_cast<int>(std::clamp<long>(j, 0, H - 1)));
    }
  }
}

// check_atlas_texels' passes over one atlas, in the order of their messages.
struct AtlasCheck {
  const Model& model;
  const Atlas& a;
  const std::string& label;
  const int W, H;
  const size_t npx;
  // Work bound of the two per-triangle passes below (rows and candidate
  // texels examined). A valid atlas's UV triangles do not overlap, so their
  // footprints cover the atlas about once (1.2-2.8 W H on the golden and
  // benchmark bundles, counting whole bounding boxes): overlapping copies or
  // slivers crossing the atlas, which no baker writes, are refused before
  // they cost W H per triangle.
  const uint64_t work_limit;
  uint64_t work = 0;
  std::vector<uint8_t> finite, covered, filled;

  AtlasCheck(const Model& m, const std::string& l)
      : model(m),
        a(m.atlas),
        label(l),
        W(m.atlas.width),
        H(m.atlas.height),
        npx(static_cast<size_t>(W) * H),
        work_limit(kWorkPerTexel * npx + kWorkPerTriangle * m.faces.size()),
        finite(npx),
        covered(npx),
        filled(npx) {}

  [[noreturn]] void fail(const std::string& what) const {
    throw BundleError(BundleErrorClass::atlas, label + ": " + what);
  }
  size_t at(int i, int j) const { return static_cast<size_t>(j) * W + i; }
  static std::string texel_str(int i, int j) { return "texel (" + std::to_string(i) + ", " + std::to_string(j) + ")"; }
  void check_work() const {
    if (work > work_limit) {
      fail("the UV triangles need more than " + std::to_string(work_limit) + " texel tests (" +
           std::to_string(kWorkPerTexel) + " per texel of the atlas + " + std::to_string(kWorkPerTriangle) +
           " per triangle): UV triangles overlap or are slivers across the atlas");
    }
  }

  // Coverage values (finite ones) must be 0 or 1.
  void coverage_values() {
    First bad_a;
    for (int j = 0; j < H; ++j) {
      for (int i = 0; i < W; ++i) {
        const float* t = a.texel(i, j);
        finite[at(i, j)] = std::isfinite(t[0]) && std::isfinite(t[1]) && std::isfinite(t[2]) && std::isfinite(t[3]);
        covered[at(i, j)] = finite[at(i, j)] && t[3] == 1.0f;
        if (std::isfinite(t[3]) && t[3] != 0.0f && t[3] != 1.0f) bad_a.add(at(i, j));
      }
    }
    if (bad_a) {
      const int i = static_cast<int>(bad_a.first % W), j = static_cast<int>(bad_a.first / W);
      fail(count_of(bad_a.count, "texel") + " with coverage A other than 0 or 1 (first: " + texel_str(i, j) +
           " has A = " + fmt("%.9g", a.texel(i, j)[3]) + ")");
    }
  }

  // filled = within Chebyshev distance `gutter` of a covered texel (separable
  // box maximum: rows, then columns, with running counts).
  void fill(const int g) {
    std::vector<uint8_t> rows(npx);
    for (int j = 0; j < H; ++j) {
      int cnt = 0;
      for (int i = 0; i < std::min(g, W); ++i) cnt += covered[at(i, j)];
      for (int i = 0; i < W; ++i) {
        if (i + g < W) cnt += covered[at(i + g, j)];
        if (i - g - 1 >= 0) cnt -= covered[at(i - g - 1, j)];
        rows[at(i, j)] = cnt > 0;
      }
    }
    // Columns, row by row (cache-friendly): cnt[i] counts rows[.][i] over rows j-g..j+g.
    std::vector<int> cnt(static_cast<size_t>(W), 0);
    for (int j = 0; j < std::min(g, H); ++j)
      for (int i = 0; i < W; ++i) cnt[i] += rows[at(i, j)];
    for (int j = 0; j < H; ++j) {
      if (j + g < H)
        for (int i = 0; i < W; ++i) cnt[i] += rows[at(i, j + g)];
      if (j - g - 1 >= 0)
        for (int i = 0; i < W; ++i) cnt[i] -= rows[at(i, j - g - 1)];
      for (int i = 0; i < W; ++i) filled[at(i, j)] = cnt[i] > 0;
    }
  }

  // Footprints of the UV triangles: every texel read must be finite and
  // filled; non-finite texels only where none is read; positions near the origin.
  void footprints(const int g) {
    std::vector<uint8_t> read(npx, 0);
    First nonfinite_tris, unfilled_tris;
    std::string nonfinite_example, unfilled_example;
    for (size_t f = 0; f < model.faces.size(); ++f) {
      size_t nonfinite = 0, unfilled = 0;
      int ni = 0, nj = 0, ui = 0, uj = 0;
      footprint(model.uvs[f], W, H, work, [&](int i, int j) {
        const size_t k = at(i, j);
        read[k] = 1;
        if (!finite[k] && nonfinite++ == 0) ni = i, nj = j;
        if (finite[k] && !filled[k] && unfilled++ == 0) ui = i, uj = j;
      });
      if (nonfinite) {
        if (!nonfinite_tris)
          nonfinite_example = "triangle " + s(f) + " reads " + s(nonfinite) + ", e.g. " + texel_str(ni, nj);
        nonfinite_tris.add(f);
      }
      if (unfilled) {
        if (!unfilled_tris)
          unfilled_example = "triangle " + s(f) + " reads " + s(unfilled) + ", e.g. " + texel_str(ui, uj);
        unfilled_tris.add(f);
      }
      check_work();
    }
    if (nonfinite_tris) {
      fail("bilinear lookups inside " + count_of(nonfinite_tris.count, "UV triangle") +
           " read non-finite texels: " + nonfinite_example);
    }
    if (unfilled_tris) {
      fail("bilinear lookups inside " + count_of(unfilled_tris.count, "UV triangle") +
           " read texels that are neither covered nor within the gutter (" + std::to_string(g) +
           ") of a covered texel: " + unfilled_example);
    }
    First stray;
    for (size_t k = 0; k < npx; ++k)
      if (!finite[k] && !read[k]) stray.add(k);
    if (stray) {
      fail(count_of(stray.count, "non-finite texel") + " outside every UV triangle's footprint (first: " +
           texel_str(static_cast<int>(stray.first % W), static_cast<int>(stray.first / W)) +
           "); unused texels must hold 0");
    }
    First far;
    for (int j = 0; j < H; ++j)
      for (int i = 0; i < W; ++i) {
        const float* t = a.texel(i, j);
        if (finite[at(i, j)] && far3({t[0], t[1], t[2]})) far.add(at(i, j));
      }
    if (far) {
      fail(count_of(far.count, "texel") +
           " with a position farther than 10000 m from the origin along an axis (first: " +
           texel_str(static_cast<int>(far.first % W), static_cast<int>(far.first / W)) + ")");
    }
  }

  // Coverage against the UVs (the spec: A = 1 exactly where the texel centre
  // lies inside a UV triangle). Texel (i, j) has its centre at x = i + 0.5,
  // y = j + 0.5 in the frame x = u W, y = (1 - v) H.
  void coverage_against_uvs() {
    std::vector<uint8_t> near(npx, 0);  // 1 = centre inside or within the margin of some triangle
    for (size_t f = 0; f < model.faces.size(); ++f) {
      double px[3], py[3];
      for (int k = 0; k < 3; ++k) {
        px[k] = static_cast<double>(model.uvs[f][k].x()) * W;
        py[k] = (1.0 - static_cast<double>(model.uvs[f][k].y())) * H;
      }
      const double area2 = (px[1] - px[0]) * (py[2] - py[0]) - (px[2] - px[0]) * (py[1] - py[0]);
      if (area2 == 0.0) continue;  // a zero-area UV triangle contains no texel centre
      const double sgn = area2 > 0 ? 1.0 : -1.0;
      double ex[3], ey[3], el[3];
      for (int k = 0; k < 3; ++k) {
        ex[k] = px[(k + 1) % 3] - px[k];
        ey[k] = py[(k + 1) % 3] - py[k];
        el[k] = std::hypot(ex[k], ey[k]);
      }
      const double x0 = std::min({px[0], px[1], px[2]}) - kCoverageMargin,
                   x1 = std::max({px[0], px[1], px[2]}) + kCoverageMargin;
      const double y0 = std::min({py[0], py[1], py[2]}) - kCoverageMargin,
                   y1 = std::max({py[0], py[1], py[2]}) + kCoverageMargin;
      const int i0 = std::max(0, static_cast<int>(std::ceil(x0 - 0.5))),
                i1 = std::min(W - 1, static_cast<int>(std::floor(x1 - 0.5)));
      const int j0 = std::max(0, static_cast<int>(std::ceil(y0 - 0.5))),
                j1 = std::min(H - 1, static_cast<int>(std::floor(y1 - 0.5)));
      for (int j = j0; j <= j1; ++j) {
        const double cy = j + 0.5;
        // Candidates of this row: the centres cx where each edge's signed
        // distance is >= -margin (a linear bound on cx per edge, widened by
        // kSpanPad), so the work is the triangle's rows plus its texels, not its
        // bounding box; the exact test below decides as before.
        double lo = i0 + 0.5, hi = i1 + 0.5;
        for (int k = 0; k < 3 && lo <= hi; ++k) {
          // sgn (ex (cy - py) - ey (cx - px)) >= -margin el  <=>  a (cx - px) >= b
          const double a = -sgn * ey[k], b = -kCoverageMargin * el[k] - sgn * ex[k] * (cy - py[k]);
          if (a > 0)
            lo = std::max(lo, px[k] + b / a - kSpanPad);
          else if (a < 0)
            hi = std::min(hi, px[k] + b / a + kSpanPad);
          else if (b > kSpanPad * el[k])
            hi = lo - 1;  // parallel edge, row wholly outside
        }
        ++work;
        if (!(lo <= hi)) continue;
        const int ia = std::max(i0, static_cast<int>(std::ceil(lo - 0.5)));
        const int ib = std::min(i1, static_cast<int>(std::floor(hi - 0.5)));
        if (ib >= ia) work += static_cast<uint64_t>(ib - ia + 1);
        for (int i = ia; i <= ib; ++i) {
          const double cx = i + 0.5;
          double d = HUGE_VAL;  // signed distance (texels) of the centre inside the nearest edge
          for (int k = 0; k < 3; ++k) d = std::min(d, sgn * (ex[k] * (cy - py[k]) - ey[k] * (cx - px[k])) / el[k]);
          if (d < -kCoverageMargin) continue;
          near[at(i, j)] = 1;
          if (d > kCoverageMargin && a.texel(i, j)[3] != 1.0f) {
            fail(texel_str(i, j) + " has its centre inside the UV triangle of coarse face " + s(f) +
                 " but coverage A = " + fmt("%.9g", a.texel(i, j)[3]) + " (must be 1)");
          }
        }
      }
      check_work();
    }
    for (int j = 0; j < H; ++j) {
      for (int i = 0; i < W; ++i) {
        if (a.texel(i, j)[3] == 1.0f && !near[at(i, j)]) {
          fail(texel_str(i, j) + " has coverage A = 1 but its centre lies in no UV triangle of the coarse mesh");
        }
      }
    }
  }
};

void check_atlas_texels(const Model& model, const io::ManifestInfo& info, const std::string& label) {
  AtlasCheck c(model, label);
  c.coverage_values();
  c.fill(info.gutter);
  c.footprints(info.gutter);
  c.coverage_against_uvs();
}

// ---- pieces -------------------------------------------------------------------

// load_pieces' failure: the pieces file's error class, the bundle's label.
struct PiecesFail {
  const std::string& label;
  [[noreturn]] void operator()(const std::string& what) const {
    throw BundleError(BundleErrorClass::pieces, label + ": " + what);
  }
};

// Piece ids in range and ordered; faces' vertices in range and of their own piece.
void check_piece_ids(const io::PiecesPly& ply, const io::ManifestInfo& info, const PiecesFail& fail) {
  const size_t nv = ply.vertices.size(), nf = ply.faces.size(), np = ply.coarse_faces.size();
  if (np != info.piece_count) fail(s(np) + " pieces, the manifest says " + s(info.piece_count));
  if (np == 0) fail("no pieces");
  const std::string range = " (pieces are 0.." + s(np - 1) + ")";
  for (size_t i = 0; i < nv; ++i)
    if (ply.vertex_piece[i] >= np) fail("vertex " + s(i) + " has piece id " + s(ply.vertex_piece[i]) + range);
  for (size_t f = 0; f < nf; ++f)
    if (ply.face_piece[f] >= np) fail("face " + s(f) + " has piece id " + s(ply.face_piece[f]) + range);
  for (size_t i = 1; i < nv; ++i) {
    if (ply.vertex_piece[i] < ply.vertex_piece[i - 1]) {
      fail("vertices are not stored piece by piece (vertex " + s(i) + " has piece " + s(ply.vertex_piece[i]) +
           " after piece " + s(ply.vertex_piece[i - 1]) + ")");
    }
  }
  for (size_t f = 1; f < nf; ++f) {
    if (ply.face_piece[f] < ply.face_piece[f - 1]) {
      fail("faces are not stored piece by piece (face " + s(f) + " has piece " + s(ply.face_piece[f]) +
           " after piece " + s(ply.face_piece[f - 1]) + ")");
    }
  }
  {
    First oob, wrong;
    for (size_t f = 0; f < nf; ++f) {
      const Tri& t = ply.faces[f];
      if (t[0] >= nv || t[1] >= nv || t[2] >= nv) oob.add(f);
    }
    if (oob) {
      fail(count_of(oob.count, "face") + " with a vertex index out of range (vertex count " + s(nv) + "): face " +
           s(oob.first) + " = " + tri_list(ply.faces[oob.first]));
    }
    for (size_t f = 0; f < nf; ++f) {
      const Tri& t = ply.faces[f];
      for (int k = 0; k < 3; ++k) {
        if (ply.vertex_piece[t[k]] != ply.face_piece[f]) {
          wrong.add(f);
          break;
        }
      }
    }
    if (wrong) {
      const Tri& t = ply.faces[wrong.first];
      std::vector<uint32_t> ids = {ply.vertex_piece[t[0]], ply.vertex_piece[t[1]], ply.vertex_piece[t[2]]};
      std::sort(ids.begin(), ids.end());
      ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
      std::string list;
      for (uint32_t id : ids) list += (list.empty() ? "" : ", ") + s(id);
      fail(count_of(wrong.count, "face") + " using vertices of another piece: face " + s(wrong.first) + " (piece " +
           s(ply.face_piece[wrong.first]) + ") uses vertices of pieces [" + list + "]");
    }
  }
}

// Vertex positions finite and near the origin.
void check_piece_vertices(const io::PiecesPly& ply, const PiecesFail& fail) {
  const size_t nv = ply.vertices.size();
  First bad;
  for (size_t i = 0; i < nv; ++i)
    if (!finite3(ply.vertices[i])) bad.add(i);
  if (bad)
    fail(count_of(bad.count, "vertex", "vertices") + " with non-finite positions (first: vertex " + s(bad.first) + ")");
  First far;
  for (size_t i = 0; i < nv; ++i)
    if (far3(ply.vertices[i])) far.add(i);
  if (far)
    fail(count_of(far.count, "vertex", "vertices") +
         " farther than 10000 m from the origin along an axis (first: vertex " + s(far.first) + ")");
}

// Each piece's coarse triangles in range, ascending and unique.
void check_coarse_maps(const Model& model, const io::PiecesPly& ply, const PiecesFail& fail) {
  const size_t np = ply.coarse_faces.size();
  const size_t ncoarse = model.faces.size();
  for (size_t p = 0; p < np; ++p) {
    const auto& mp = ply.coarse_faces[p];
    for (uint32_t t : mp) {
      if (t >= ncoarse) {
        fail("piece " + s(p) + " maps to coarse triangle " + s(*std::max_element(mp.begin(), mp.end())) +
             ", out of range (coarse triangle count " + s(ncoarse) + ")");
      }
    }
    for (size_t k = 1; k < mp.size(); ++k)
      if (mp[k] <= mp[k - 1]) fail("coarse_faces of piece " + s(p) + " are not ascending and unique");
  }
}

// Pieces: contiguous ranges (vbegin, fbegin: each piece's first vertex and
// face, then the counts). The piece limits bound the per-piece checks below (closedness sorts the
// edges, convexity tests every vertex against every face plane) and the
// later stages (FCL's convex pieces), whatever LoadOptions says: without
// them one piece of 8 MB took a minute to check.
void piece_ranges(const io::PiecesPly& ply, const PiecesFail& fail, std::vector<size_t>& vbegin,
                  std::vector<size_t>& fbegin) {
  const size_t nv = ply.vertices.size(), nf = ply.faces.size(), np = ply.coarse_faces.size();
  vbegin.assign(np + 1, 0);
  fbegin.assign(np + 1, 0);
  for (size_t i = 0; i < nv; ++i) ++vbegin[ply.vertex_piece[i] + 1];
  for (size_t f = 0; f < nf; ++f) ++fbegin[ply.face_piece[f] + 1];
  for (size_t p = 0; p < np; ++p) {
    vbegin[p + 1] += vbegin[p];
    fbegin[p + 1] += fbegin[p];
  }
  for (size_t p = 0; p < np; ++p) {
    const size_t pv = vbegin[p + 1] - vbegin[p], pf = fbegin[p + 1] - fbegin[p];
    if (pv > io::kMaxPieceVertices) {
      fail("piece " + s(p) + " has " + s(pv) + " vertices, more than the limit " + s(io::kMaxPieceVertices));
    }
    if (pf > io::kMaxPieceFaces) {
      fail("piece " + s(p) + " has " + s(pf) + " faces, more than the limit " + s(io::kMaxPieceFaces) +
           " (a convex piece of at most " + s(io::kMaxPieceVertices) + " vertices has at most " +
           s(io::kMaxPieceFaces) + " triangles)");
    }
  }
}

// The first piece of each kind of defect, and their counts.
struct PieceIssues {
  First small, open, degen, inward, nonconvex;
  std::string small_ex, open_ex, degen_ex, inward_ex, nonconvex_ex;
};

// The invariants of piece p (of at least 4 vertices and faces): closed,
// no zero-area face, wound outward, convex within tol. Records the first
// defect found in `is`.
void check_piece(const ConvexPiece& piece, const size_t p, const double tol, PieceIssues& is) {
  // Closed and consistently wound: every directed edge once, its reverse once.
  std::vector<std::pair<uint32_t, uint32_t>> edges;
  edges.reserve(piece.faces.size() * 3);
  for (const Tri& t : piece.faces)
    for (int k = 0; k < 3; ++k) edges.emplace_back(t[k], t[(k + 1) % 3]);
  std::sort(edges.begin(), edges.end());
  bool closed = std::adjacent_find(edges.begin(), edges.end()) == edges.end();
  for (size_t k = 0; k < edges.size() && closed; ++k) {
    closed = std::binary_search(edges.begin(), edges.end(), std::make_pair(edges[k].second, edges[k].first));
  }
  if (!closed) {
    if (!is.open) is.open_ex = "piece " + s(p);
    is.open.add(p);
    return;
  }
  const size_t nfp = piece.faces.size();
  std::vector<Vec3> normals(nfp);
  bool zero = false;
  for (size_t f = 0; f < nfp && !zero; ++f) {
    const Tri& t = piece.faces[f];
    normals[f] = (piece.vertices[t[1]] - piece.vertices[t[0]]).cross(piece.vertices[t[2]] - piece.vertices[t[0]]);
    if (normals[f].norm() == 0.0) {
      zero = true;
      if (!is.degen) is.degen_ex = "piece " + s(p) + " face " + s(f) + " (local)";
    }
  }
  if (zero) {
    is.degen.add(p);
    return;
  }
  // Signed volume about the centroid (divergence theorem): > 0 iff outward.
  Vec3 ctr = Vec3::Zero();
  for (const Vec3& v : piece.vertices) ctr += v;
  ctr /= static_cast<double>(piece.vertices.size());
  double vol = 0.0;
  for (const Tri& t : piece.faces) {
    vol += (piece.vertices[t[0]] - ctr).dot((piece.vertices[t[1]] - ctr).cross(piece.vertices[t[2]] - ctr));
  }
  vol /= 6.0;
  if (!(vol > 0.0)) {
    if (!is.inward) is.inward_ex = "piece " + s(p) + " (volume " + fmt("%.3g", vol) + " m^3)";
    is.inward.add(p);
    return;
  }
  // Convex: every vertex of the piece on or behind every face plane.
  double worst = -HUGE_VAL;
  size_t wf = 0, wv = 0;
  for (size_t f = 0; f < nfp; ++f) {
    const Vec3 nrm = normals[f].normalized();
    const Vec3& a = piece.vertices[piece.faces[f][0]];
    for (size_t i = 0; i < piece.vertices.size(); ++i) {
      const double d = nrm.dot(piece.vertices[i] - a);
      if (d > worst) {
        worst = d;
        wf = f;
        wv = i;
      }
    }
  }
  if (worst > tol) {
    if (!is.nonconvex) {
      is.nonconvex_ex = "piece " + s(p) + ": vertex " + s(wv) + " lies " + fmt("%.3g", worst) + " m in front of face " +
                        s(wf) + " (local indices)";
    }
    is.nonconvex.add(p);
  }
}

void load_pieces(Model& model, const io::PiecesPly& ply, const io::ManifestInfo& info, const std::string& label,
                 bool invariants) {
  const PiecesFail fail{label};
  check_piece_ids(ply, info, fail);
  if (invariants) check_piece_vertices(ply, fail);
  check_coarse_maps(model, ply, fail);
  const size_t np = ply.coarse_faces.size();

  // Pieces: contiguous ranges (ids are in range and ordered).
  std::vector<size_t> vbegin, fbegin;
  piece_ranges(ply, fail, vbegin, fbegin);
  // The coarse mesh's bounding-box diagonal sets the convexity tolerance.
  Vec3 lo = Vec3::Constant(HUGE_VAL), hi = Vec3::Constant(-HUGE_VAL);
  for (const Vec3& v : model.vertices) {
    if (!v.allFinite()) continue;
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  const double tol = kConvexRel * (model.vertices.empty() ? 0.0 : (hi - lo).norm()) + kConvexAbs;

  // One message per kind, reported in the reference's order of kinds.
  PieceIssues is;
  model.pieces.resize(np);
  for (size_t p = 0; p < np; ++p) {
    ConvexPiece& piece = model.pieces[p];
    const size_t v0 = vbegin[p], v1 = vbegin[p + 1], f0 = fbegin[p], f1 = fbegin[p + 1];
    piece.vertices.resize(v1 - v0);
    for (size_t i = v0; i < v1; ++i) piece.vertices[i - v0] = to_vec3(ply.vertices[i]);
    piece.faces.resize(f1 - f0);
    for (size_t f = f0; f < f1; ++f) {
      for (int k = 0; k < 3; ++k) piece.faces[f - f0][k] = static_cast<uint32_t>(ply.faces[f][k] - v0);
    }
    piece.coarse_faces = ply.coarse_faces[p];
    if (piece.vertices.size() < 4 || piece.faces.size() < 4) {
      if (!is.small)
        is.small_ex =
            "piece " + s(p) + " has " + s(piece.vertices.size()) + " vertices, " + s(piece.faces.size()) + " faces";
      is.small.add(p);
      continue;
    }
    if (invariants) check_piece(piece, p, tol, is);
  }
  if (is.small) fail(count_of(is.small.count, "piece") + " with fewer than 4 vertices or 4 faces: " + is.small_ex);
  if (is.open) fail(count_of(is.open.count, "piece") + " not a closed, consistently wound polyhedron: " + is.open_ex);
  if (is.degen) fail(count_of(is.degen.count, "piece") + " with a zero-area face: " + is.degen_ex);
  if (is.inward) fail(count_of(is.inward.count, "piece") + " wound inward (negative volume): " + is.inward_ex);
  if (is.nonconvex)
    fail(count_of(is.nonconvex.count, "piece") + " not convex (tolerance " + fmt("%.3g", tol) +
         " m): " + is.nonconvex_ex);
}

}  // namespace

Model load_bundle(const std::string& path, const LoadOptions& opts) {
  struct stat st{};
  if (::stat(path.c_str(), &st) != 0)
    throw BundleError(BundleErrorClass::io, path + ": bundle directory does not exist");
  if (!S_ISDIR(st.st_mode))
    throw BundleError(BundleErrorClass::io, path + ": not a directory (a bundle is a directory)");

  const std::string mlabel = join_path(path, "manifest.json");
  std::string mbytes;
  try {
    mbytes = io::read_file(mlabel, mlabel, io::kMaxManifestBytes);
  } catch (const BundleError& e) {
    throw BundleError(BundleErrorClass::io,
                      std::string(e.what()) == mlabel + ": missing file" ? mlabel + ": missing" : e.what());
  }
  Model model;
  model.path = path;
  // nlohmann-json parses iteratively, but copies, dumps and the checker's
  // messages recurse into values: the nesting depth is bounded while parsing.
  const auto depth_guard = [&mlabel](int depth, nlohmann::json::parse_event_t event, nlohmann::json&) {
    // `depth` counts the containers already open (0 at the top-level value).
    if ((event == nlohmann::json::parse_event_t::object_start || event == nlohmann::json::parse_event_t::array_start) &&
        depth >= io::kMaxJsonDepth) {
      throw BundleError(BundleErrorClass::schema, mlabel + ": arrays and objects nested deeper than " +
                                                      std::to_string(io::kMaxJsonDepth) + " levels");
    }
    return true;
  };
  nlohmann::json manifest;
  try {
    manifest = nlohmann::json::parse(mbytes, depth_guard);
  } catch (const nlohmann::json::exception& e) {
    std::string what = e.what();
    const size_t close = what.find("] ");
    if (close != std::string::npos) what = what.substr(close + 2);
    throw BundleError(BundleErrorClass::schema, mlabel + ": not valid UTF-8 JSON: " + what);
  }
  const io::ManifestInfo info = io::check_manifest(manifest, mlabel);
  model.manifest = std::make_shared<const nlohmann::json>(std::move(manifest));
  model.name = info.source_name;
  model.format_version = info.format_version;
  model.mass = info.mass;
  model.quality = info.quality;

  // All three files exist, then size and hash file by file, then the contents.
  const FileEntry* entries[3] = {&info.coarse_mesh, &info.atlas, &info.pieces};
  static const char* kKeys[3] = {"coarse_mesh", "atlas", "pieces"};
  // Sizes from stat first (class io: missing, not regular, over the limit),
  // and the manifest's sizes (class hash) before a file is read, so a huge
  // file is never read into memory.
  static const uint64_t kLimits[3] = {io::kMaxPlyBytes, io::kMaxExrBytes, io::kMaxPlyBytes};
  std::string labels[3], bytes[3];
  uint64_t sizes[3] = {0, 0, 0};
  for (int k = 0; k < 3; ++k) {
    labels[k] = join_path(path, entries[k]->path);
    try {
      sizes[k] = io::file_size(labels[k], labels[k], kLimits[k]);
    } catch (const BundleError& e) {
      if (std::string(e.what()) == labels[k] + ": missing file") {
        throw BundleError(BundleErrorClass::io, labels[k] + ": missing (" + kKeys[k] + " file named by the manifest)");
      }
      throw;
    }
  }
  for (int k = 0; k < 3; ++k) {
    if (opts.verify_hashes && sizes[k] != entries[k]->bytes) {
      throw BundleError(BundleErrorClass::hash,
                        labels[k] + ": " + s(sizes[k]) + " bytes, the manifest says " + s(entries[k]->bytes));
    }
    bytes[k] = io::read_file(labels[k], labels[k], kLimits[k]);
    if (opts.verify_hashes) {
      if (bytes[k].size() != entries[k]->bytes) {
        throw BundleError(BundleErrorClass::hash,
                          labels[k] + ": " + s(bytes[k].size()) + " bytes, the manifest says " + s(entries[k]->bytes));
      }
      const std::string sha = io::sha256_hex(bytes[k]);
      if (sha != entries[k]->sha256) {
        throw BundleError(BundleErrorClass::hash, labels[k] + ": SHA-256 " + sha.substr(0, 12) +
                                                      "... differs from the manifest's " +
                                                      entries[k]->sha256.substr(0, 12) + "...");
      }
    }
  }

  load_coarse(model, io::parse_coarse_ply(bytes[0], labels[0]), info, labels[0], opts.check_invariants);
  if (info.atlas_width != static_cast<uint64_t>(info.atlas_spec.width) ||
      info.atlas_height != static_cast<uint64_t>(info.atlas_spec.height)) {
    throw BundleError(BundleErrorClass::atlas, mlabel + ": atlas is " + s(info.atlas_width) + "x" +
                                                   s(info.atlas_height) + " but files.atlas says " +
                                                   s(info.atlas_spec.width) + "x" + s(info.atlas_spec.height));
  }
  // The atlas limit before anything of the atlas's size is allocated (a
  // manifest and header agreeing on 16384 x 16384 once allocated 4 GiB).
  if (!(info.atlas_width <= static_cast<uint64_t>(io::kMaxAtlasSide) &&
        info.atlas_height <= static_cast<uint64_t>(io::kMaxAtlasSide) &&
        info.atlas_width * info.atlas_height <= static_cast<uint64_t>(io::kMaxAtlasTexels))) {
    throw BundleError(BundleErrorClass::atlas, mlabel + ": atlas is " + s(info.atlas_width) + " x " +
                                                   s(info.atlas_height) + " texels, more than the limit" +
                                                   io::kAtlasLimitText);
  }
  model.atlas = io::read_atlas_exr(bytes[1], labels[1], info.atlas_spec, opts.decode_threads);
  if (opts.check_invariants) check_atlas_texels(model, info, labels[1]);
  load_pieces(model, io::parse_pieces_ply(bytes[2], labels[2], io::pieces_layout_is_table(info.format_version)), info,
              labels[2], opts.check_invariants);
  prepare_surface_map(model);
  return model;
}

}  // namespace hrt
