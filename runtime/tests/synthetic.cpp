// Builders of in-memory Models with analytic atlases (see synthetic.h).
#include "synthetic.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <new>
#include <stdexcept>

// Counting replacements of the global allocation functions (see
// allocation_count). The array and sized forms default to these; the
// aligned forms are left to the library (Eigen's fixed-size types in the
// code under test do not use them).
namespace {
std::atomic<uint64_t> g_allocations{0};
}
void* operator new(std::size_t n) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void* operator new[](std::size_t n) { return operator new(n); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }

namespace hrt::synth {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr int kGutter = 4;  // atlas gutter, texels (the spec's default)

// An affine map from atlas texel coordinates (x = u W - 0.5, y = (1 - v) H - 0.5)
// of one face's rectangle to the face's object-space plane point.
struct FaceRect {
  int x0, y0, x1, y1;  // texel rectangle [x0, x1) x [y0, y1) covered by the face
};

}  // namespace

double Relief::profile_value(double xi) const {
  switch (profile) {
    case Profile::flat: return 0.0;
    case Profile::sine: return std::sin(2 * kPi * xi);
    case Profile::ridges: {
      // Plateau +1 centred on xi = 0, valley -1 centred on xi = 0.5, linear
      // flanks of width `flank` (periods) centred on |xi| = 0.25.
      const double c = xi - std::floor(xi + 0.5);  // in [-0.5, 0.5)
      return std::clamp((0.25 - std::abs(c)) / (0.5 * flank), -1.0, 1.0);
    }
  }
  return 0.0;
}

double Relief::z(double x, double y) const {
  const double s = std::cos(angle) * x + std::sin(angle) * y - shift;
  const double dx = x - bump_x, dy = y - bump_y;
  const double b = -(face_up ? 1.0 : -1.0) * bump * (dx * dx + dy * dy) / 2;
  return offset + amplitude * profile_value(s / wavelength) + b;
}

Eigen::Vector2d Relief::gradient(double x, double y) const {
  const Eigen::Vector2d m(std::cos(angle), std::sin(angle));
  const double s = m.x() * x + m.y() * y - shift;
  double dp = 0;  // d profile / d s
  switch (profile) {
    case Profile::flat: break;
    case Profile::sine: dp = amplitude * 2 * kPi / wavelength * std::cos(2 * kPi * s / wavelength); break;
    case Profile::ridges: {
      const double xi = s / wavelength;
      const double c = xi - std::floor(xi + 0.5);
      const double t = (0.25 - std::abs(c)) / (0.5 * flank);
      if (std::abs(t) < 1) dp = amplitude * (c > 0 ? -1.0 : 1.0) / (0.5 * flank * wavelength);
      break;
    }
  }
  const double sg = -(face_up ? 1.0 : -1.0) * bump;
  return dp * m + sg * Eigen::Vector2d(x - bump_x, y - bump_y);
}

SynthBlock make_block(const BlockSpec& spec_in) {
  if (spec_in.atlas_size < 64 || spec_in.subdiv < 1)
    throw std::invalid_argument("synth: atlas_size >= 64, subdiv >= 1");
  SynthBlock out;
  out.spec = spec_in;
  out.spec.relief.face_up = spec_in.face_up;
  const BlockSpec& sp = out.spec;
  const Relief& rel = sp.relief;
  Model& M = out.model;
  M.name = "synthetic block";
  M.format_version = "1.0";

  const int S = sp.subdiv;
  const double sx = sp.size_x, sy = sp.size_y, t = sp.thickness;
  const double zb = sp.face_up ? -t : t;  // back face
  const double sgn = sp.face_up ? 1.0 : -1.0;
  // Coarse textured face: follows the bump (if any), not the ridges.
  Relief coarse = rel;
  coarse.profile = Profile::flat;
  coarse.offset = 0;

  const int W = sp.atlas_size, H = sp.atlas_size;
  // Atlas layout: the textured face takes the top rows [0, Ht) (all columns,
  // inset by the gutter); the five other faces share the bottom strip, one
  // cell each, inset by the gutter on every side.
  const int Ht = (3 * H) / 4;
  const FaceRect top{kGutter, kGutter, W - kGutter, Ht - kGutter};
  const int strip_y0 = Ht + kGutter, strip_y1 = H - kGutter;
  auto cell_rect = [&](int k) {
    const int cw = W / 5;
    return FaceRect{k * cw + kGutter, strip_y0, (k + 1) * cw - kGutter, strip_y1};
  };
  // UV of a rectangle point (s, r) in [0, 1]^2: the rectangle's texel edges.
  auto rect_uv = [&](const FaceRect& R, double s, double r) {
    const double x = R.x0 + s * (R.x1 - R.x0);  // texel-edge coordinates (x + 0.5 in the spec)
    const double y = R.y0 + r * (R.y1 - R.y0);
    return Vec2f(static_cast<float>(x / W), static_cast<float>(1.0 - y / H));
  };

  // Vertices: textured face grid, back face grid.
  auto fidx = [&](int i, int j) { return static_cast<uint32_t>(j * (S + 1) + i); };
  auto bidx = [&](int i, int j) { return static_cast<uint32_t>((S + 1) * (S + 1) + j * (S + 1) + i); };
  for (int pass = 0; pass < 2; ++pass)
    for (int j = 0; j <= S; ++j)
      for (int i = 0; i <= S; ++i) {
        const double x = -sx / 2 + sx * i / S, y = -sy / 2 + sy * j / S;
        M.vertices.emplace_back(x, y, pass == 0 ? coarse.z(x, y) : zb);
      }

  // Adds a triangle with its UVs, wound so that its normal points along `out_dir`.
  auto add = [&](uint32_t a, uint32_t b, uint32_t c, Vec2f ua, Vec2f ub, Vec2f uc, const Vec3& out_dir,
                 std::vector<uint32_t>* list) {
    const Vec3 nrm = (M.vertices[b] - M.vertices[a]).cross(M.vertices[c] - M.vertices[a]);
    if (nrm.dot(out_dir) < 0) {
      std::swap(b, c);
      std::swap(ub, uc);
    }
    if (list) list->push_back(static_cast<uint32_t>(M.faces.size()));
    M.faces.push_back({a, b, c});
    M.uvs.push_back({ua, ub, uc});
  };
  // Textured face: rectangle point (s, r) = ((x + sx/2)/sx, (y + sy/2)/sy).
  for (int j = 0; j < S; ++j)
    for (int i = 0; i < S; ++i) {
      auto uv = [&](int ii, int jj) { return rect_uv(top, double(ii) / S, double(jj) / S); };
      const Vec3 o(0, 0, sgn);
      add(fidx(i, j), fidx(i + 1, j), fidx(i + 1, j + 1), uv(i, j), uv(i + 1, j), uv(i + 1, j + 1), o, &out.face_tris);
      add(fidx(i, j), fidx(i + 1, j + 1), fidx(i, j + 1), uv(i, j), uv(i + 1, j + 1), uv(i, j + 1), o, &out.face_tris);
    }
  // Back face (cell 0): same (s, r).
  const FaceRect back = cell_rect(0);
  for (int j = 0; j < S; ++j)
    for (int i = 0; i < S; ++i) {
      auto uv = [&](int ii, int jj) { return rect_uv(back, double(ii) / S, double(jj) / S); };
      const Vec3 o(0, 0, -sgn);
      add(bidx(i, j), bidx(i + 1, j), bidx(i + 1, j + 1), uv(i, j), uv(i + 1, j), uv(i + 1, j + 1), o, &out.back_tris);
      add(bidx(i, j), bidx(i + 1, j + 1), bidx(i, j + 1), uv(i, j), uv(i + 1, j + 1), uv(i, j + 1), o, &out.back_tris);
    }
  // Sides (cells 1..4): strips between the face boundary and the back
  // boundary; rectangle coordinate s along the edge, r = 0 at the face, 1 at the back.
  struct Side {
    int cell;
    Vec3 out_dir;
  };
  const Side sides[4] = {{1, Vec3(0, -1, 0)}, {2, Vec3(1, 0, 0)}, {3, Vec3(0, 1, 0)}, {4, Vec3(-1, 0, 0)}};
  for (const Side& sd : sides) {
    const FaceRect R = cell_rect(sd.cell);
    for (int k = 0; k < S; ++k) {
      int i0, j0, i1, j1;
      switch (sd.cell) {
        case 1:
          i0 = k;
          j0 = 0;
          i1 = k + 1;
          j1 = 0;
          break;
        case 2:
          i0 = S;
          j0 = k;
          i1 = S;
          j1 = k + 1;
          break;
        case 3:
          i0 = k;
          j0 = S;
          i1 = k + 1;
          j1 = S;
          break;
        default:
          i0 = 0;
          j0 = k;
          i1 = 0;
          j1 = k + 1;
          break;
      }
      const Vec2f f0 = rect_uv(R, double(k) / S, 0), f1 = rect_uv(R, double(k + 1) / S, 0);
      const Vec2f b0 = rect_uv(R, double(k) / S, 1), b1 = rect_uv(R, double(k + 1) / S, 1);
      add(fidx(i0, j0), fidx(i1, j1), bidx(i1, j1), f0, f1, b1, sd.out_dir, nullptr);
      add(fidx(i0, j0), bidx(i1, j1), bidx(i0, j0), f0, b1, b0, sd.out_dir, nullptr);
    }
  }
  for (size_t f = 0; f < M.faces.size(); ++f) {
    const Vec3 &a = M.vertices[M.faces[f][0]], &b = M.vertices[M.faces[f][1]], &c = M.vertices[M.faces[f][2]];
    const Vec3 cr = (b - a).cross(c - a);
    M.face_areas.push_back(0.5 * cr.norm());
    M.face_normals.push_back(cr.normalized());
  }

  // Atlas: every texel within the gutter of a face rectangle gets the exact
  // surface point of the (extended) face at its centre; A = 1 inside.
  Atlas& at = M.atlas;
  at.width = W;
  at.height = H;
  at.rgba.assign(static_cast<size_t>(W) * H * 4, 0.0f);
  auto fill = [&](const FaceRect& R, auto&& point_of) {
    for (int y = std::max(0, R.y0 - kGutter); y < std::min(H, R.y1 + kGutter); ++y)
      for (int x = std::max(0, R.x0 - kGutter); x < std::min(W, R.x1 + kGutter); ++x) {
        const double s = (x + 0.5 - R.x0) / (R.x1 - R.x0), r = (y + 0.5 - R.y0) / (R.y1 - R.y0);
        const Vec3 p = point_of(s, r);
        float* px = &at.rgba[(static_cast<size_t>(y) * W + x) * 4];
        px[0] = static_cast<float>(p.x());
        px[1] = static_cast<float>(p.y());
        px[2] = static_cast<float>(p.z());
        px[3] = (s > 0 && s < 1 && r > 0 && r < 1) ? 1.0f : 0.0f;
      }
  };
  fill(top, [&](double s, double r) {
    const double x = -sx / 2 + s * sx, y = -sy / 2 + r * sy;
    return Vec3(x, y, rel.z(x, y));
  });
  fill(back, [&](double s, double r) { return Vec3(-sx / 2 + s * sx, -sy / 2 + r * sy, zb); });
  for (const Side& sd : sides) {
    fill(cell_rect(sd.cell), [&](double s, double r) {
      double x, y;
      switch (sd.cell) {
        case 1:
          x = -sx / 2 + s * sx;
          y = -sy / 2;
          break;
        case 2:
          x = sx / 2;
          y = -sy / 2 + s * sy;
          break;
        case 3:
          x = -sx / 2 + s * sx;
          y = sy / 2;
          break;
        default:
          x = -sx / 2;
          y = -sy / 2 + s * sy;
          break;
      }
      // The side is planar; its face edge follows the coarse face (bump).
      const double zf = coarse.z(x, y);
      return Vec3(x, y, zf + r * (zb - zf));
    });
  }
  out.atlas_texel = std::max(sx / (top.x1 - top.x0), sy / (top.y1 - top.y0));

  // One convex piece: the box (the coarse face's bump is ignored; tests of
  // the depth code do not use pieces).
  ConvexPiece piece;
  const double zt = sp.face_up ? 0.0 : 0.0;
  for (int k = 0; k < 8; ++k)
    piece.vertices.emplace_back((k & 1) ? sx / 2 : -sx / 2, (k & 2) ? sy / 2 : -sy / 2, (k & 4) ? zb : zt);
  const int quads[6][4] = {{0, 1, 3, 2}, {4, 6, 7, 5}, {0, 4, 5, 1}, {2, 3, 7, 6}, {0, 2, 6, 4}, {1, 5, 7, 3}};
  const Vec3 centre(0, 0, zb / 2);
  for (const auto& q : quads)
    for (int tri = 0; tri < 2; ++tri) {
      Tri f{static_cast<uint32_t>(q[0]), static_cast<uint32_t>(q[1 + tri]), static_cast<uint32_t>(q[2 + tri])};
      const Vec3 &a = piece.vertices[f[0]], &b = piece.vertices[f[1]], &c = piece.vertices[f[2]];
      if ((b - a).cross(c - a).dot(a - centre) < 0) std::swap(f[1], f[2]);
      piece.faces.push_back(f);
    }
  for (uint32_t f = 0; f < M.faces.size(); ++f) piece.coarse_faces.push_back(f);
  M.pieces.push_back(std::move(piece));

  M.mass.basis = "coarse";
  M.mass.volume = sx * sy * t;
  M.mass.center_of_mass = centre;
  const double m = M.mass.volume * M.mass.density;
  M.mass.inertia = Mat3::Zero();
  M.mass.inertia(0, 0) = m * (sy * sy + t * t) / 12;
  M.mass.inertia(1, 1) = m * (sx * sx + t * t) / 12;
  M.mass.inertia(2, 2) = m * (sx * sx + sy * sy) / 12;
  M.mass.closed = true;

  M.quality.texel_size = out.atlas_texel;
  M.quality.min_wavelength = 2 * out.atlas_texel;
  M.quality.displacement_outward = std::abs(rel.amplitude) + std::abs(rel.offset);
  M.quality.displacement_inward = std::abs(rel.amplitude) + std::abs(rel.offset);
  M.quality.bbox_diagonal = std::sqrt(sx * sx + sy * sy + t * t);
  prepare_surface_map(M);
  return out;
}

double relief_interp_error(const SynthBlock& b) {
  const Relief& r = b.spec.relief;
  double curv = std::abs(r.bump);
  const double k = 2 * kPi / r.wavelength;
  if (r.profile == Profile::sine) curv += std::abs(r.amplitude) * k * k;
  if (r.profile == Profile::ridges) {
    // Piecewise linear: interpolation is exact except within one texel of a
    // kink, where it is off by at most slope * texel / 2.
    const double slope = 2 * std::abs(r.amplitude) / (r.flank * r.wavelength);
    return slope * b.atlas_texel * std::sqrt(2.0) / 2 + curv * 2 * b.atlas_texel * b.atlas_texel / 8;
  }
  const double diag2 = 2 * b.atlas_texel * b.atlas_texel;
  return curv * diag2 / 8;
}

ContactPatch make_patch(const Vec3& n, const Vec3& u, const Vec3& centre, double cell, int N,
                        const std::vector<uint32_t>& tris_a, const std::vector<uint32_t>& tris_b) {
  ContactPatch p;
  p.n = n.normalized();
  p.u = (u - u.dot(p.n) * p.n).normalized();
  p.v = p.n.cross(p.u);
  p.window.cell = cell;
  p.window.resolution = N;
  p.window.origin = centre - 0.5 * N * cell * (p.u + p.v);
  p.p_a = p.p_b = centre;
  p.tris_a = tris_a;
  p.tris_b = tris_b;
  p.piece_pairs = 1;
  return p;
}

void transform_scene(const Eigen::Isometry3d& Q, Pose& pose_a, Pose& pose_b, ContactPatch& patch) {
  const Eigen::Quaterniond q(Q.linear());
  for (Pose* p : {&pose_a, &pose_b}) {
    p->position = Q * p->position;
    p->rotation = (q * p->rotation).normalized();
  }
  patch.n = Q.linear() * patch.n;
  patch.u = Q.linear() * patch.u;
  patch.v = Q.linear() * patch.v;
  patch.window.origin = Q * patch.window.origin;
  patch.p_a = Q * patch.p_a;
  patch.p_b = Q * patch.p_b;
}

uint64_t allocation_count() { return g_allocations.load(std::memory_order_relaxed); }

Pose make_pose(const Vec3& position, const Eigen::Quaterniond& rotation) {
  Pose p;
  p.position = position;
  p.rotation = rotation.normalized();
  return p;
}

}  // namespace hrt::synth
