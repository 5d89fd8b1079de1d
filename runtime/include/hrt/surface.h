// The surface map of a model: what the depth code needs to evaluate the
// *reconstructed full surface* on a texel column rather than the literal
// Eq. 8 of the paper (docs/bundle-format.md "Heights").
//
// Why. The atlas stores, for a coarse surface point q, a full-surface point
// f(q) that lies beside q's column along n whenever the bake's ray direction
// (the interpolated coarse normal, or whatever a route used) is not n: by up
// to |f(q) - q| sin(angle). Eq. 8 places n . f(q) at q's own column, so on a
// flank of slope s the height is off by s times that lateral offset. The
// depth code removes it with a per-texel fixed-point correction (raster.cpp)
// that needs, per coarse face, a bound on the lateral offset for a given n,
// and, per atlas quad, whether bilinear interpolation there is meaningful.
//
// Computed once per model (load_bundle calls prepare_surface_map), immutable
// afterwards, shared by every placement of the model.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include <Eigen/Core>

namespace hrt {

struct Model;

// A texel-to-texel step longer than this many atlas texels (manifest
// atlas.texel_size) is a discontinuity of f: the two texels map to distant
// parts of the full surface (a ray on the other wall of a thin feature, a
// chart border), and a bilinear lookup across it would return a point in
// the air between them. The full surface's step per texel is at most
// sqrt(1 + s^2) times the coarse step for slopes s up to ~75 degrees (3.9),
// which the facing test of the clustering (cos > 0.2, 78 degrees) admits.
constexpr double kJumpTexels = 4.0;

// The mesh heights (hrt/depth.h HeightMode::mesh) visit the quads whose
// centre lies within one texel of a face's UV triangle: their corners lie
// within 1 + sqrt(2)/2 texels of it (rounded up).
constexpr double kQuadReadMargin = 1.75;

struct SurfaceMap {
  bool ready = false;
  // Per coarse face: the offsets w = f(q) - q over the atlas texels the face's
  // lookups read (texel centres within one texel of its UV triangle, q the
  // coarse point those texel centres parameterize, extended past the edges),
  // split along a unit `axis` (the mean offset direction, either way: relief
  // goes in and out): |w . axis| <= along, |w - (w . axis) axis| <= across,
  // |w| <= reach (m). For a unit n at angle theta to the axis line the
  // lateral offset |w - (w . n) n| <= along sin(theta) + across.
  struct Face {
    Eigen::Vector3f axis = Eigen::Vector3f::UnitZ();
    float along = 0.0f, across = 0.0f, reach = 0.0f;
    // |w| <= quad_reach (m) for every texel a usable atlas quad of the mesh
    // heights reads (corners of quads whose centre lies within one texel of
    // the UV triangle: texels within kQuadReadMargin of it), q the closest
    // point of the face to the texel's UV. >= reach.
    float quad_reach = 0.0f;
  };
  std::vector<Face> faces;
  // Per atlas texel (i, j), row-major W x H: 1 when the 2 x 2 lookup quad
  // with top-left texel (i, j) (clamped at the image's last row and column,
  // as lookups clamp) is usable: all four texels filled (within atlas.gutter
  // of a covered texel, docs/bundle-format.md) and no edge of the quad longer
  // than kJumpTexels * texel_size. Lookups in an unusable quad return no
  // point (the texel column stays uncovered by that lookup). Followed by
  // kQuadOkPadding zero bytes: the vector kernels read a flag as the low byte
  // of a 32-bit load (src/depth/resolve_simd.cpp).
  std::vector<uint8_t> quad_ok;
  static constexpr size_t kQuadOkPadding = 3;
  double jump = 0.0;       // m: kJumpTexels * texel_size (0: no texel size known, no jump test)
  uint64_t cut_quads = 0;  // quads with a filled corner cut by the jump test (for reports)
  // Blocks of kQuadBlock x kQuadBlock quads (block (bi, bj) holds the quads
  // with top-left texel in [bi B, bi B + B) x [bj B, bj B + B)), row-major
  // blocks_w x blocks_h: the object-frame box of the corners of the block's
  // usable quads (lo > hi when it has none). The mesh heights skip a whole
  // block from it (beside the grid, behind the cull, occluded).
  static constexpr int kQuadBlock = 8;
  struct Block {
    Eigen::Vector3f lo{1.0f, 1.0f, 1.0f}, hi{-1.0f, -1.0f, -1.0f};
  };
  std::vector<Block> blocks;
  int blocks_w = 0, blocks_h = 0;

  // Upper bound (m) on the lateral offset of face f's points for the
  // object-frame unit direction n_obj.
  double lateral_bound(uint32_t f, const Eigen::Vector3d& n_obj) const {
    const Face& F = faces[f];
    const double c = F.axis.cast<double>().dot(n_obj);
    return std::min<double>(F.reach, F.along * std::sqrt(std::max(0.0, 1.0 - c * c)) + F.across);
  }
};

// Fills model.surface from its coarse mesh, UVs, atlas and
// quality.texel_size. O(atlas texels + faces); allocates model-sized arrays.
void prepare_surface_map(Model& model);

// Where the atlas's grid mesh leaves the surface out: the quads whose centre
// lies inside a UV triangle (every lookup inside the triangles reads one),
// and those of them that are not usable (SurfaceMap::quad_ok: a corner
// unfilled, or an edge longer than the jump length, a discontinuity such as
// the two walls of a feature thinner than the texels). The mesh heights see
// no surface in a cut quad, so its widest edge bounds the hole there
// (docs/bundle-format.md "Heights over a texel's square"). hrt check prints it.
struct SurfaceCoverage {
  uint64_t quads = 0;       // quads with their centre inside a UV triangle
  uint64_t cut = 0;         // of those, not usable
  double widest_cut = 0.0;  // m: the longest edge of a cut quad
};
// O(atlas texels + faces). Needs model.surface (prepare_surface_map).
SurfaceCoverage surface_coverage(const Model& model);

}  // namespace hrt
