// delta at the 11 configurations of A and its gradient by central
// differences (paper Eq. 7), with the optional Sec. 5.2 shortcut.
#include <algorithm>
#include <cmath>
#include <limits>

#include "depth/internal.h"
#include "depth/reduce.h"
#include "hrt/depth.h"
#include "parallel/task_pool.h"

namespace hrt {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

int side_with_border(int resolution) { return resolution + 2 * DepthScratch::kReservedBorder; }

void ensure_capacity(DepthScratch& s, int N, int border) {
  const int S = N + 2 * border;
  if (s.capacity < N) s.reserve(N);
  if (s.ha0.size() < static_cast<size_t>(S) * S) s.ha0.resize(static_cast<size_t>(S) * S);  // one growth only
  s.seeds.reserve(S);
}

using depth_reduce::covered_box;
using depth_reduce::CoveredBox;
using depth_reduce::max_diff;

// max over the N x N texels of ha(i - di, j - dj) - hb(i, j), ha stored with
// border b (row length S = N + 2b), |di|, |dj| <= b: the depth of A
// translated by (di, dj) whole texels (its height map moves with it). Only
// the texels whose source lies in ha's covered box are visited.
double shifted_depth(const double* ha, int S, int b, const CoveredBox& box, const double* hb, int N, int di, int dj) {
  double d = -kInf;
  const int jlo = std::max(0, box.j0 + dj - b), jhi = std::min(N, box.j1 + dj - b);
  const int ilo = std::max(0, box.i0 + di - b), ihi = std::min(N, box.i1 + di - b);
  if (ilo >= ihi) return d;
  for (int j = jlo; j < jhi; ++j)
    d = std::max(d, max_diff(ha + static_cast<size_t>(j - dj + b) * S + (ilo - di + b),
                             hb + static_cast<size_t>(j) * N + ilo, ihi - ilo));
  return d;
}

// Linear interpolation between the shifts floor(s) and floor(s) + 1 along
// one axis, for a translation that is not a whole number of texels. A texel
// is covered only when both sources are.
double fractional_shift_depth(const double* ha, int S, int b, const double* hb, int N, double sx, double sy) {
  const double fsx = std::floor(sx), fsy = std::floor(sy);
  const int dx = static_cast<int>(fsx), dy = static_cast<int>(fsy);
  const double wx = sx - fsx, wy = sy - fsy;
  double d = -kInf;
  for (int j = 0; j < N; ++j) {
    for (int i = 0; i < N; ++i) {
      // source point (i - sx, j - sy) in the bordered map
      const int si = i - dx - (wx > 0 ? 1 : 0) + b;
      const int sj = j - dy - (wy > 0 ? 1 : 0) + b;
      const double fx = wx > 0 ? 1.0 - wx : 0.0, fy = wy > 0 ? 1.0 - wy : 0.0;
      if (si < 0 || sj < 0 || si + (fx > 0) >= S || sj + (fy > 0) >= S) continue;
      const double* r0 = ha + static_cast<size_t>(sj) * S + si;
      const double* r1 = fy > 0 ? r0 + S : r0;
      const double h00 = r0[0], h10 = fx > 0 ? r0[1] : h00, h01 = r1[0], h11 = fx > 0 ? r1[1] : h01;
      double h;
      if (fx == 0.0 && fy == 0.0) {
        h = h00;
      } else if (fy == 0.0) {
        if (h00 == -kInf || h10 == -kInf) continue;
        h = h00 + fx * (h10 - h00);
      } else if (fx == 0.0) {
        if (h00 == -kInf || h01 == -kInf) continue;
        h = h00 + fy * (h01 - h00);
      } else {
        if (h00 == -kInf || h10 == -kInf || h01 == -kInf || h11 == -kInf) continue;
        const double top = h00 + fx * (h10 - h00), bot = h01 + fx * (h11 - h01);
        h = top + fy * (bot - top);
      }
      d = std::max(d, h - hb[static_cast<size_t>(j) * N + i]);
    }
  }
  return d;
}

// The shortcut for a rotation of A by theta about the axis n through c
// (grid coordinates (cx, cy), texel units): heights are invariant under it
// (h = n . p), so h_A'(x) = h_A(0)(R(-theta) (x - c) + c), resampled
// bilinearly; a texel is covered only when its four sources are.
double rotated_depth(const double* ha, int S, int b, const double* hb, int N, double cx, double cy, double theta) {
  const double cs = std::cos(theta), sn = std::sin(theta);
  double d = -kInf;
  for (int j = 0; j < N; ++j) {
    const double ry = j - cy;
    // Source point, affine in i: (cx + cs rx + sn ry + b, cy - sn rx + cs ry + b), rx = i - cx.
    double sx = cx + cs * (0 - cx) + sn * ry + b;
    double sy = cy - sn * (0 - cx) + cs * ry + b;
    const double* rb = hb + static_cast<size_t>(j) * N;
    for (int i = 0; i < N; ++i, sx += cs, sy -= sn) {
      const double fsx = std::floor(sx), fsy = std::floor(sy);
      const int si = static_cast<int>(fsx), sj = static_cast<int>(fsy);
      if (si < 0 || sj < 0 || si + 1 >= S || sj + 1 >= S) continue;
      const double fx = sx - fsx, fy = sy - fsy;
      const double* r0 = ha + static_cast<size_t>(sj) * S + si;
      const double* r1 = r0 + S;
      const double h00 = r0[0], h10 = r0[1], h01 = r1[0], h11 = r1[1];
      // Uncovered sources hold -inf (never +inf): one test for all four.
      if (h00 + h10 + h01 + h11 == -kInf) continue;
      const double top = h00 + fx * (h10 - h00), bot = h01 + fx * (h11 - h01);
      d = std::max(d, top + fy * (bot - top) - rb[i]);
    }
  }
  return d;
}

}  // namespace

const std::vector<uint32_t>& height_faces(const std::vector<uint32_t>& tris, const std::vector<uint32_t>& reach,
                                          HeightMode mode, std::vector<uint32_t>& buf) {
  if (mode != HeightMode::mesh || reach.empty()) return tris;
  buf.clear();
  buf.insert(buf.end(), tris.begin(), tris.end());
  buf.insert(buf.end(), reach.begin(), reach.end());
  return buf;
}

void DepthScratch::reserve(int resolution) {
  if (resolution <= capacity) return;
  const size_t n2 = static_cast<size_t>(resolution) * resolution;
  const size_t s = static_cast<size_t>(side_with_border(resolution));
  hb.resize(n2);
  ha.resize(n2);
  hcfg.resize(10 * n2);
  if (ha0.size() < s * s) ha0.resize(s * s);
  seeds.reserve(static_cast<int>(s));
  capacity = resolution;
}

Eigen::Isometry3d config_motion(Config c, const ContactPatch& patch, const Vec3& c_world, double lin_step,
                                double ang_step) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  auto rot = [&](const Vec3& axis, double angle) {
    // Rotation about the axis through c_world: p -> c + R (p - c).
    Eigen::Isometry3d M = Eigen::Isometry3d::Identity();
    M.linear() = Eigen::AngleAxisd(angle, axis).toRotationMatrix();
    M.translation() = c_world - M.linear() * c_world;
    return M;
  };
  switch (c) {
    case Config::plus_u: T.translation() = lin_step * patch.u; break;
    case Config::minus_u: T.translation() = -lin_step * patch.u; break;
    case Config::plus_v: T.translation() = lin_step * patch.v; break;
    case Config::minus_v: T.translation() = -lin_step * patch.v; break;
    case Config::plus_theta_u: T = rot(patch.u, ang_step); break;
    case Config::minus_theta_u: T = rot(patch.u, -ang_step); break;
    case Config::plus_theta_v: T = rot(patch.v, ang_step); break;
    case Config::minus_theta_v: T = rot(patch.v, -ang_step); break;
    case Config::plus_theta_n: T = rot(patch.n, ang_step); break;
    case Config::minus_theta_n: T = rot(patch.n, -ang_step); break;
    default: break;
  }
  return T;
}

double effective_lin_step(const ContactPatch& patch, const ForceOptions& opt) {
  return opt.lin_step > 0 ? opt.lin_step : patch.window.cell;
}

double default_ang_step(const ContactPatch& patch, const Vec3& c_a_world) {
  const Window& w = patch.window;
  const double L = w.cell * w.resolution;
  double R = 0;
  for (int k = 0; k < 4; ++k) {
    const Vec3 corner = w.origin + ((k & 1) ? L : 0.0) * patch.u + ((k & 2) ? L : 0.0) * patch.v;
    R = std::max(R, (corner - c_a_world).norm());
  }
  // R >= half the window's diagonal > 0 for a valid window.
  return R > 0 ? w.cell / R : 0.0;
}

double effective_ang_step(const ContactPatch& patch, const Vec3& c_a_world, const ForceOptions& opt) {
  return opt.ang_step > 0 ? opt.ang_step : default_ang_step(patch, c_a_world);
}

bool plan_depth(const Model& A, const Pose& pose_a, const Model& B, const Pose& pose_b, const ContactPatch& patch,
                const ForceOptions& opt, DepthPlan& plan) {
  const int N = patch.window.resolution;
  if (N <= 0 || !(patch.window.cell > 0)) return false;
  const Eigen::Isometry3d Ta = pose_a.iso();
  const Eigen::Isometry3d Tb = pose_b.iso();
  const Vec3 c_a = Ta * A.mass.center_of_mass;
  const double du = effective_lin_step(patch, opt);
  const double dth = effective_ang_step(patch, c_a, opt);
  plan.lin_step = du;
  plan.ang_step = dth;
  plan.world_from_b = Tb;
  const double cell = patch.window.cell;

  // Border of h_A(0) for the shortcut: the largest texel displacement of the
  // resampled configurations (translation du, n-rotation about c_A).
  int border = 0;
  plan.cx = plan.cy = 0;
  if (opt.shortcut) {
    const double cx = (c_a - patch.window.origin).dot(patch.u) / cell - 0.5;
    const double cy = (c_a - patch.window.origin).dot(patch.v) / cell - 0.5;
    plan.cx = cx, plan.cy = cy;
    double rmax = 0;  // in-plane distance (texels) from c_A to the farthest texel centre
    for (int k = 0; k < 4; ++k) {
      const double x = (k & 1) ? N - 1 : 0, y = (k & 2) ? N - 1 : 0;
      rmax = std::max(rmax, std::hypot(x - cx, y - cy));
    }
    const double disp = std::max(du / cell, std::abs(2.0 * std::sin(0.5 * dth)) * rmax);
    // Clamped in double first: disp can exceed int for a far c_A.
    border = std::isnan(disp) ? N : static_cast<int>(std::clamp(std::ceil(disp - 1e-9), 1.0, static_cast<double>(N)));
  }
  // Surface mode without the shortcut: seeded re-solves; whole-texel
  // translations by shifting.
  plan.seeded = opt.heights == HeightMode::surface && !opt.shortcut && A.surface.ready;
  plan.shift_m = 0;
  // The mesh mode's height of a texel is a max over its footprint: a
  // translation by whole texels moves it exactly too.
  const bool mesh = opt.heights == HeightMode::mesh && !opt.shortcut && A.surface.ready;
  if (plan.seeded || mesh) {
    const double s = du / cell, rs = std::round(s);
    if (std::abs(s - rs) < 1e-9 && rs >= 1 && rs <= DepthScratch::kReservedBorder) plan.shift_m = static_cast<int>(rs);
    border = plan.shift_m;
  }
  plan.border = border;

  const std::vector<uint32_t>& ta = patch.tris_a;
  const std::vector<uint32_t>& tb = patch.tris_b;
  const Vec3& n = patch.n;
  // Culling bounds for the surface mode's costly triangles (rasterize_heights):
  // the lowest point B's triangles can have and the highest A's can, along
  // n, from their corners and the surface map's reach, relative to n .
  // origin. A triangle of A below B's lowest (or of B above A's highest) by
  // more than the configurations can move A along n (a translation along u
  // or v none; a rotation dth about c_A at most dth times the distance, plus
  // two grid texels of slack) overlaps nowhere at any configuration: it could
  // only change a maximum that is below zero, which makes no force.
  plan.cull_a = plan.cull_b = std::numeric_limits<double>::quiet_NaN();
  if ((opt.heights == HeightMode::surface || opt.heights == HeightMode::mesh) && A.surface.ready && B.surface.ready) {
    const double h0 = n.dot(patch.window.origin);
    double lo_b = kInf, hi_a = -kInf, r_a = 0;
    const bool with_reach = opt.heights == HeightMode::mesh;
    // The mesh heights read the corners of quads beside the UV triangle too.
    auto face_reach = [&](const SurfaceMap::Face& sf) { return with_reach ? sf.quad_reach : sf.reach; };
    auto low_b = [&](const std::vector<uint32_t>& list) {
      for (uint32_t f : list) {
        if (f >= B.faces.size()) continue;
        for (int c = 0; c < 3; ++c)
          lo_b = std::min(lo_b, n.dot(Tb * B.vertices[B.faces[f][c]]) - h0 - face_reach(B.surface.faces[f]));
      }
    };
    auto high_a = [&](const std::vector<uint32_t>& list) {
      for (uint32_t f : list) {
        if (f >= A.faces.size()) continue;
        for (int c = 0; c < 3; ++c) {
          const Vec3 p = Ta * A.vertices[A.faces[f][c]];
          hi_a = std::max(hi_a, n.dot(p) - h0 + face_reach(A.surface.faces[f]));
          r_a = std::max(r_a, (p - c_a).norm() + face_reach(A.surface.faces[f]));
        }
      }
    };
    low_b(tb);
    high_a(ta);
    if (with_reach) low_b(patch.reach_b), high_a(patch.reach_a);
    const double motion = std::abs(dth) * r_a + 2.0 * cell;
    if (std::isfinite(lo_b) && std::isfinite(hi_a) && std::isfinite(motion)) {
      plan.cull_a = lo_b - motion;
      plan.cull_b = hi_a + motion;
    }
  }
  plan.world_from_a[0] = Ta;
  for (int c = 1; c < static_cast<int>(Config::count); ++c)
    plan.world_from_a[c] = config_motion(static_cast<Config>(c), patch, c_a, du, dth) * Ta;
  return true;
}

// The contact region (where the two overlap), for friction's centre of
// pressure (hrt/session.h). One pass over configuration 0.
static void contact_region(const double* ha0, const int S, const int border, const CoveredBox& box0, const double* hb,
                           const int N, DepthGradient& out) {
  double w_sum = 0, wi = 0, wj = 0;
  int lo_i = N, lo_j = N, hi_i = -1, hi_j = -1, count_overlap = 0;
  // Only configuration 0's covered box can overlap (row-major order kept).
  const int jlo = std::max(0, box0.j0 - border), jhi = std::min(N, box0.j1 - border);
  const int ilo = std::max(0, box0.i0 - border), ihi = std::min(N, box0.i1 - border);
  for (int j = jlo; j < jhi; ++j) {
    const double* ra = ha0 + static_cast<size_t>(j + border) * S + border;
    const double* rb = hb + static_cast<size_t>(j) * N;
    for (int i = ilo; i < ihi; ++i) {
      const double d = ra[i] - rb[i];
      if (!(d > 0)) continue;  // -inf (uncovered) and touching texels are no overlap
      ++count_overlap;
      w_sum += d;
      wi += d * (i + 0.5);
      wj += d * (j + 0.5);
      lo_i = std::min(lo_i, i), hi_i = std::max(hi_i, i);
      lo_j = std::min(lo_j, j), hi_j = std::max(hi_j, j);
    }
  }
  if (count_overlap > 0 && w_sum > 0) {
    out.region_texels = count_overlap;
    out.region_center[0] = wi / w_sum;
    out.region_center[1] = wj / w_sum;
    out.region_lo[0] = lo_i, out.region_lo[1] = lo_j;
    out.region_hi[0] = hi_i + 1, out.region_hi[1] = hi_j + 1;
  }
}

// The shortcut (Sec. 5.2): the translations and the rotations about n as
// shifts and rotations of configuration 0's heights; s: the linear step in
// texels.
static void shortcut_depths(const double* ha0, const int S, const int border, const CoveredBox& box0, const double* hb,
                            const int N, const double s, const double cx, const double cy, const double dth,
                            double* D) {
  const double rs = std::round(s);
  if (std::abs(s - rs) < 1e-9 && rs <= border) {
    const int m = static_cast<int>(rs);
    D[1] = shifted_depth(ha0, S, border, box0, hb, N, m, 0);
    D[2] = shifted_depth(ha0, S, border, box0, hb, N, -m, 0);
    D[3] = shifted_depth(ha0, S, border, box0, hb, N, 0, m);
    D[4] = shifted_depth(ha0, S, border, box0, hb, N, 0, -m);
  } else {
    D[1] = fractional_shift_depth(ha0, S, border, hb, N, s, 0);
    D[2] = fractional_shift_depth(ha0, S, border, hb, N, -s, 0);
    D[3] = fractional_shift_depth(ha0, S, border, hb, N, 0, s);
    D[4] = fractional_shift_depth(ha0, S, border, hb, N, 0, -s);
  }
  D[9] = rotated_depth(ha0, S, border, hb, N, cx, cy, dth);
  D[10] = rotated_depth(ha0, S, border, hb, N, cx, cy, -dth);
}

// The depths of the rendered configurations (bufs[k] holds configuration
// rendered[k]; k = 0 is configuration 0), whole-texel translations as shifts
// of configuration 0 (seeded: those of `rendered`; the mesh mode's are not
// in it).
static void configuration_depths(const double* ha0, const int S, const int border, const CoveredBox& box0,
                                 const double* hb, const int N, const bool seeded, const bool mesh_shift,
                                 const int shift_m, double* const* bufs, const int* rendered, const int count,
                                 double* D) {
  // Seeded configurations are covered where configuration 0 is (their
  // re-solves start from its seeds); the mesh mode's have their own boxes.
  auto box_of = [&](const double* h) {
    return seeded ? CoveredBox{box0.i0 - border, box0.i1 - border, box0.j0 - border, box0.j1 - border}
                  : covered_box(h, N, -kInf);
  };
  // The mesh mode's whole-texel translations are not in `rendered`: shifts.
  // (They were left uncovered before, which zeroed the gradient's u and v.)
  if (mesh_shift)
    for (int c = 1; c <= 4; ++c) {
      const int di = c == 1 ? shift_m : c == 2 ? -shift_m : 0, dj = c == 3 ? shift_m : c == 4 ? -shift_m : 0;
      D[c] = shifted_depth(ha0, S, border, box0, hb, N, di, dj);
    }
  for (int k = 1; k < count; ++k) {
    const int c = rendered[k];
    if (seeded && shift_m > 0 && c >= 1 && c <= 4) {
      const int di = c == 1 ? shift_m : c == 2 ? -shift_m : 0, dj = c == 3 ? shift_m : c == 4 ? -shift_m : 0;
      D[c] = shifted_depth(ha0, S, border, box0, hb, N, di, dj);
    } else {
      D[c] = shifted_depth(bufs[k], N, 0, box_of(bufs[k]), hb, N, 0, 0);
    }
  }
}

DepthGradient compute_depth_gradient(const Model& A, const Pose& pose_a, const Model& B, const Pose& pose_b,
                                     const ContactPatch& patch, const ForceOptions& opt, DepthScratch& scratch,
                                     TaskPool* pool) {
  DepthGradient out;
  const int N = patch.window.resolution;
  for (double& d : out.delta_at) d = -kInf;
  out.grad << 0, 0, 1, 0, 0, 0;
  DepthPlan plan;
  if (!plan_depth(A, pose_a, B, pose_b, patch, opt, plan)) return out;
  const double du = plan.lin_step, dth = plan.ang_step;
  out.lin_step = du;
  out.ang_step = dth;
  const double cell = patch.window.cell;
  const int border = plan.border, shift_m = plan.shift_m;
  const bool seeded = plan.seeded;
  const double cx = plan.cx, cy = plan.cy;
  ensure_capacity(scratch, N, border);
  const int S = N + 2 * border;

  const std::vector<uint32_t>& ta = height_faces(patch.tris_a, patch.reach_a, opt.heights, scratch.tris_a);
  const std::vector<uint32_t>& tb = height_faces(patch.tris_b, patch.reach_b, opt.heights, scratch.tris_b);
  const Vec3 &n = patch.n, &u = patch.u, &v = patch.v;
  // A frame of one patch in the surface mode shares the patch with the pool
  // (frame() passes it only then): B's heights beside A's configuration 0,
  // then the re-solved configurations. Each task is the serial code on its
  // own output, so the result does not depend on the threads.
  const bool share = seeded && pool && pool->threads() > 1;
  auto raster_b = [&]() {
    rasterize_heights(B, plan.world_from_b, tb, n, u, v, patch.window, 0, false, scratch.hb.data(), opt.heights,
                      plan.cull_b);
  };
  if (!share) raster_b();
  const double* hb = scratch.hb.data();
  const double* ha0 = scratch.ha0.data();
  const size_t n2 = static_cast<size_t>(N) * N;
  double* D = out.delta_at;

  // A at configuration 0 (with the shortcut's border) and at the
  // configurations that are rendered: all 10 perturbed ones, or with the
  // shortcut the 4 tilts (theta_u, theta_v). One pass over the triangles.
  Eigen::Isometry3d T[11];
  double* bufs[11];
  int borders[11] = {};
  int rendered[11];
  int count = 0;
  T[count] = plan.world_from_a[0];
  bufs[count] = scratch.ha0.data();
  borders[count] = border;
  rendered[count++] = 0;
  // The mesh mode rasterizes every configuration (its heights are exact,
  // nothing to re-solve), but its whole-texel translations are shifts too.
  const bool mesh_shift = !seeded && opt.heights == HeightMode::mesh && shift_m > 0;
  for (int c = 1; c < static_cast<int>(Config::count); ++c) {
    if (opt.shortcut && (c < 5 || c > 8)) continue;
    if (mesh_shift && c <= 4) continue;
    T[count] = plan.world_from_a[c];
    bufs[count] = scratch.hcfg.data() + (c - 1) * n2;
    rendered[count++] = c;
  }
  if (seeded) {
    // Configuration 0 rasterized with seeds, the others re-solved from them
    // (each moves the window's points by about a texel, so the fixed point
    // converges in a lookup or two from the seed, and no triangle is
    // rasterized again; coverage is configuration 0's). A translation by a
    // whole number m of texels along u or v moves A's surface, and so its
    // height map, by exactly m texels: those four are shifts of h_A(0),
    // rasterized with a border of m.
    auto raster_a0 = [&]() {
      rasterize_heights_seeded(A, T[0], ta, n, u, v, patch.window, border, true, bufs[0], scratch.seeds, plan.cull_a);
    };
    int todo[11];
    int ntodo = 0;
    for (int k = 1; k < count; ++k) {
      const int c = rendered[k];
      if (!(shift_m > 0 && c >= 1 && c <= 4)) todo[ntodo++] = k;
    }
    auto resolve = [&](int t, int) {
      const int k = todo[t];
      resolve_heights(A, T[k], T[0], n, u, v, patch.window, true, bufs[0], border, scratch.seeds, bufs[k], hb);
    };
    if (share) {
      auto rasters = [&](int task, int) { task == 0 ? raster_a0() : raster_b(); };
      pool->run(2, rasters);
      pool->run(ntodo, resolve);
    } else {
      raster_a0();
      for (int t = 0; t < ntodo; ++t) resolve(t, 0);
    }
  } else {
    const double cull = opt.heights == HeightMode::mesh ? plan.cull_a : std::numeric_limits<double>::quiet_NaN();
    // One pass over the triangles per group of configurations (a triangle's
    // atlas region is read from the cache for all the group's placements but
    // the first): one group, or one per pool thread.
    const int groups = pool ? std::min(pool->threads(), count) : 1;
    auto raster = [&](int g, int) {
      const int lo = g * count / groups, hi = (g + 1) * count / groups;
      rasterize_heights_multi(A, T + lo, borders + lo, hi - lo, ta, n, u, v, patch.window, true, bufs + lo, opt.heights,
                              cull);
    };
    if (groups > 1) {
      pool->run(groups, raster);
    } else {
      raster(0, 0);
    }
  }

  // Seeded configurations are covered where configuration 0 is (their
  // re-solves start from its seeds); the mesh mode's have their own boxes.
  const CoveredBox box0 = false ? CoveredBox{scratch.seeds.i0, scratch.seeds.i1, scratch.seeds.j0, scratch.seeds.j1}
                                : covered_box(ha0, S, -kInf);
  D[0] = shifted_depth(ha0, S, border, box0, hb, N, 0, 0);
  if (D[0] == -kInf) return out;  // nothing covered by both: no contact
  if (D[0] > 0) contact_region(ha0, S, border, box0, hb, N, out);
  configuration_depths(ha0, S, border, box0, hb, N, seeded, mesh_shift, shift_m, bufs, rendered, count, D);

  if (opt.shortcut) shortcut_depths(ha0, S, border, box0, hb, N, du / cell, cx, cy, dth, D);

  finish_depth_gradient(out);
  return out;
}

double kink_safe_difference(double d_plus, double d_zero, double d_minus, double step, double* straddle) {
  const double central = (d_plus - d_minus) / (2 * step);  // Eq. 7, bit for bit when no kink is seen
  if (straddle) *straddle = 0.0;
  const double s_plus = (d_plus - d_zero) / step, s_minus = (d_zero - d_minus) / step;
  // delta is a max of functions smooth in A's configuration: a kink only
  // turns its slope upwards, so a concave or straight triple hides none.
  const double turn = s_plus - s_minus;
  if (!(turn > 0)) return central;
  // The turn against the steeper one-sided slope: a small fraction for
  // smooth curvature, up to 2 for a kink (a V seen from its bottom).
  const double q = turn / std::max(std::abs(s_plus), std::abs(s_minus));
  const double kink = std::clamp((q - kKinkSmoothTurn) / (kKinkStraddleTurn - kKinkSmoothTurn), 0.0, 1.0);
  if (!(kink > 0)) return central;
  // The one-sided difference across the kink mixes the two branches'
  // slopes, so it is the smaller in size: the steeper one is configuration
  // 0's own branch. r = |central| / (turn / 2) is how clearly it is steeper
  // (for slopes of opposite signs, the difference of their sizes over
  // their sum; >= 1 for equal signs): near a V's bottom the side is
  // undecided and the central difference (0 at a symmetric V) is kept.
  const double r = std::abs(central) / (0.5 * turn);
  const double side = std::clamp((r - kKinkUndecided) / (kKinkDecided - kKinkUndecided), 0.0, 1.0);
  const double blend = kink * side;
  if (straddle) *straddle = blend;
  // central + sign(central) turn / 2 is the steeper one-sided difference.
  return central + std::copysign(blend * 0.5 * turn, central);
}

void finish_depth_gradient(DepthGradient& out) {
  const double* D = out.delta_at;
  const double du = out.lin_step, dth = out.ang_step;
  out.covered = D[0] > -kInf;
  out.uncovered_configurations = 0;
  out.grad << 0, 0, 1, 0, 0, 0;
  if (!out.covered) {
    out.delta = 0;
    return;
  }
  out.delta = D[0];
  // Central differences (Eq. 7); one-sided when one neighbour is uncovered.
  // The translations' central differences are checked for a kink within the
  // step (kink_safe_difference; see depth.h).
  auto diff = [&](int plus, int minus, double step, bool kink_safe) {
    const bool p = D[plus] > -kInf, m = D[minus] > -kInf;
    if (!p) ++out.uncovered_configurations;
    if (!m) ++out.uncovered_configurations;
    if (p && m)
      return kink_safe ? kink_safe_difference(D[plus], D[0], D[minus], step) : (D[plus] - D[minus]) / (2 * step);
    if (p) return (D[plus] - D[0]) / step;
    if (m) return (D[0] - D[minus]) / step;
    return 0.0;
  };
  out.grad[0] = diff(1, 2, du, true);
  out.grad[1] = diff(3, 4, du, true);
  out.grad[2] = 1.0;
  out.grad[3] = dth > 0 ? diff(5, 6, dth, false) : 0.0;
  out.grad[4] = dth > 0 ? diff(7, 8, dth, false) : 0.0;
  out.grad[5] = dth > 0 ? diff(9, 10, dth, false) : 0.0;
}

}  // namespace hrt
