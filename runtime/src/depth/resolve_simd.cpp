// resolve_all (resolve_simd.h): Google Highway, one copy per x86 target,
// chosen at run time (HWY_DYNAMIC_DISPATCH). Lanes are the texels of a row;
// the atlas point's coordinates and the residual are double, the bilinear
// lookup is float (the atlas is float32), exactly as HeightSampler::project
// does it (raster.cpp): Bilerp's top = a + fx (b - a), bot = c + fx (d - c),
// v = top + fy (bot - top), and _mm_dp_ps's dot (p0 + p1) + (p2 + 0).
// No fused multiply-add anywhere (CMakeLists sets -ffp-contract=off here):
// the results equal the scalar path's bit for bit (runtime/tests/
// test_resolve_simd.cpp checks every target the CPU runs).
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "depth/resolve_simd.cpp"
#include <hwy/foreach_target.h>  // IWYU pragma: keep
#include <hwy/highway.h>

#include <algorithm>
#include <cmath>

#include "depth/resolve_simd.h"
#include "hrt/depth.h"

HWY_BEFORE_NAMESPACE();
namespace hrt {
namespace depth_simd {
namespace HWY_NAMESPACE {
namespace hn = hwy::HWY_NAMESPACE;

// Lanes of double in the widest vector of any target (AVX-512: 8), with room.
constexpr size_t kMaxLanes = 16;

// HeightSampler::project (raster.cpp) for the active lanes: the range test
// (also NaN), the clamped 2 x 2 footprint, the unusable-quad flag, the
// bilinear point in float and its dots with gx, gy and n. Lanes that fail
// leave `active`; false when none is left. P is ResolveArgs or SurfaceTri.
template <class DD>
class Lookup {
  using DF = hn::Rebind<float, DD>;
  using DI = hn::Rebind<int32_t, DD>;
  using VD = hn::Vec<DD>;
  using VF = hn::Vec<DF>;
  using VI = hn::Vec<DI>;

 public:
  template <class P>
  explicit Lookup(const P& p)
      : rgba_(p.rgba),
        ok_(p.ok),
        lo_(hn::Set(dd_, -1e6)),
        hi_(hn::Set(dd_, 1e6)),
        one_i_(hn::Set(di_, 1)),
        wi_(hn::Set(di_, p.w)),
        wmax_(hn::Set(di_, p.w - 1)),
        hmax_(hn::Set(di_, p.h - 1)),
        stride_(hn::Set(di_, p.stride)),
        byte_(hn::Set(di_, 0xFF)) {
    for (int c = 0; c < 3; ++c)
      gx_[c] = hn::Set(df_, p.gx4[c]), gy_[c] = hn::Set(df_, p.gy4[c]), gn_[c] = hn::Set(df_, p.n4[c]);
  }

  template <class M>
  HWY_INLINE bool project(VD vax, VD vay, M& active, VD& px, VD& py, VD& pz) {
    active = hn::And(active,
                     hn::And(hn::And(hn::Gt(vax, lo_), hn::Lt(vax, hi_)), hn::And(hn::Gt(vay, lo_), hn::Lt(vay, hi_))));
    if (hn::AllFalse(dd_, active)) return false;
    const VD sx = hn::IfThenElseZero(active, vax), sy = hn::IfThenElseZero(active, vay);
    const VD fx0 = hn::Floor(sx), fy0 = hn::Floor(sy);
    const VF fx = hn::DemoteTo(df_, hn::Sub(sx, fx0)), fy = hn::DemoteTo(df_, hn::Sub(sy, fy0));
    const VI i0 = hn::DemoteTo(di_, fx0), j0 = hn::DemoteTo(di_, fy0), zero = hn::Zero(di_);
    const VI ia = hn::Min(hn::Max(i0, zero), wmax_), ib = hn::Min(hn::Max(hn::Add(i0, one_i_), zero), wmax_);
    const VI ja = hn::Min(hn::Max(j0, zero), hmax_), jb = hn::Min(hn::Max(hn::Add(j0, one_i_), zero), hmax_);
    if (ok_) {
      // Highway has no byte gather: each quad flag is the low byte of a
      // 32-bit gather at its byte offset (quad_ok is padded by
      // SurfaceMap::kQuadOkPadding bytes for the last one; x86 is little-endian).
      const VI word = hn::GatherOffset(di_, reinterpret_cast<const int32_t*>(ok_), hn::Add(hn::Mul(ja, wi_), ia));
      active = hn::And(active, hn::Ne(hn::PromoteTo(dd_, hn::And(word, byte_)), hn::Zero(dd_)));
      if (hn::AllFalse(dd_, active)) return false;
    }
    const VI ra = hn::Mul(ja, stride_), rb = hn::Mul(jb, stride_);
    const VI ca = hn::ShiftLeft<2>(ia), cb = hn::ShiftLeft<2>(ib);
    const VI o00 = hn::Add(ra, ca), o01 = hn::Add(ra, cb), o10 = hn::Add(rb, ca), o11 = hn::Add(rb, cb);
    VF v[3];
    for (int c = 0; c < 3; ++c) {  // Bilerp
      const float* base = rgba_ + c;
      const VF a = hn::GatherIndex(df_, base, o00), b = hn::GatherIndex(df_, base, o01);
      const VF cc = hn::GatherIndex(df_, base, o10), d = hn::GatherIndex(df_, base, o11);
      const VF top = hn::Add(a, hn::Mul(fx, hn::Sub(b, a)));
      const VF bot = hn::Add(cc, hn::Mul(fx, hn::Sub(d, cc)));
      v[c] = hn::Add(top, hn::Mul(fy, hn::Sub(bot, top)));
    }
    px = hn::PromoteTo(dd_, dot(v, gx_));
    py = hn::PromoteTo(dd_, dot(v, gy_));
    pz = hn::PromoteTo(dd_, dot(v, gn_));
    return true;
  }

 private:
  // _mm_dp_ps's order: (p0 + p1) + (p2 + 0).
  HWY_INLINE VF dot(const VF* v, const VF* w) const {
    return hn::Add(hn::Add(hn::Mul(v[0], w[0]), hn::Mul(v[1], w[1])), hn::Add(hn::Mul(v[2], w[2]), hn::Zero(df_)));
  }
  const DD dd_{};
  const DF df_{};
  const DI di_{};
  const float* rgba_;
  const uint8_t* ok_;
  VD lo_, hi_;
  VI one_i_, wi_, wmax_, hmax_, stride_, byte_;
  VF gx_[3], gy_[3], gn_[3];
};

void ResolveAll(const ResolveArgs& A) {
  const hn::ScalableTag<double> dd;
  const hn::Rebind<float, decltype(dd)> df;
  using VD = hn::Vec<decltype(dd)>;
  using VF = hn::Vec<decltype(df)>;
  const size_t L = hn::Lanes(dd);
  const int N = A.N, S = A.N + 2 * A.border;
  const VD inf = hn::Set(dd, HUGE_VAL);
  Lookup<decltype(dd)> look(A);
  const VD ox = hn::Set(dd, A.ox), oy = hn::Set(dd, A.oy), oh = hn::Set(dd, A.oh), tol2 = hn::Set(dd, A.tol2);
  const VD none = hn::Set(dd, A.none), uncovered = hn::Set(dd, -A.none);
  const VD gx0 = hn::Set(dd, A.gx0), gxi = hn::Set(dd, A.gxi), gxj = hn::Set(dd, A.gxj), gxh = hn::Set(dd, A.gxh);
  const VD gy0 = hn::Set(dd, A.gy0), gyi = hn::Set(dd, A.gyi), gyj = hn::Set(dd, A.gyj), gyh = hn::Set(dd, A.gyh);
  const VD iota = hn::Iota(dd, 0.0);
  // A row's last, partial vector is read from and written to these.
  HWY_ALIGN double t_h[kMaxLanes], t_a[2 * kMaxLanes], t_o[kMaxLanes], t_out[kMaxLanes];
  HWY_ALIGN float t_j[4 * kMaxLanes];
  for (int j = 0; j < N; ++j) {
    const size_t row = static_cast<size_t>(j) * N;
    if (j < A.j0 || j >= A.j1 || A.i0 >= A.i1) {
      std::fill(A.out + row, A.out + row + N, A.none);
      continue;
    }
    std::fill(A.out + row, A.out + row + A.i0, A.none);
    std::fill(A.out + row + A.i1, A.out + row + N, A.none);
    const VD Y = hn::Set(dd, static_cast<double>(j));
    const size_t srow = static_cast<size_t>(j + A.border) * S + A.border;
    for (int i0 = A.i0; i0 < A.i1; i0 += static_cast<int>(L)) {
      const size_t m = std::min(L, static_cast<size_t>(A.i1 - i0));
      const double* ph0 = A.seed_h + srow + i0;
      const double* pa = A.seed_a + 2 * (srow + i0);
      const float* pj = A.seed_j + 4 * (srow + i0);
      const double* po = A.other ? A.other + row + i0 : nullptr;
      double* pout = A.out + row + i0;
      if (m < L) {
        // The tail: copies padded with uncovered seeds. Straight copies: the
        // same copy written as one loop of `l < m ? src : pad` gave some
        // lanes wrong seeds in GCC 12's AVX-512 build (the bit-for-bit test
        // failed on AVX3 only, once tails fell inside the covered box).
        std::copy(ph0, ph0 + m, t_h), std::fill(t_h + m, t_h + L, HUGE_VAL);
        std::copy(pa, pa + 2 * m, t_a), std::fill(t_a + 2 * m, t_a + 2 * L, 0.0);
        std::copy(pj, pj + 4 * m, t_j), std::fill(t_j + 4 * m, t_j + 4 * L, 0.0f);
        if (po) std::copy(po, po + m, t_o), std::fill(t_o + m, t_o + L, 0.0);
        ph0 = t_h, pa = t_a, pj = t_j, po = po ? t_o : nullptr, pout = t_out;
      }
      const VD h0 = hn::LoadU(dd, ph0);
      // resolve_heights' skips: the other side uncovered, no seed.
      auto active = hn::Lt(hn::Abs(h0), inf);
      if (po) active = hn::AndNot(hn::Eq(hn::LoadU(dd, po), uncovered), active);
      if (hn::AllFalse(dd, active)) {
        hn::StoreU(none, dd, pout);
      } else {
        VD vax, vay;
        hn::LoadInterleaved2(dd, pa, vax, vay);
        VF f0, f1, f2, f3;
        hn::LoadInterleaved4(df, pj, f0, f1, f2, f3);
        const VD J0 = hn::PromoteTo(dd, f0), J1 = hn::PromoteTo(dd, f1), J2 = hn::PromoteTo(dd, f2),
                 J3 = hn::PromoteTo(dd, f3);
        const VD X = hn::Add(iota, hn::Set(dd, static_cast<double>(i0)));
        {  // the first step, from the seed's own column (no lookup)
          const VD rx = hn::Sub(X, hn::Add(hn::Add(hn::Add(gx0, hn::Mul(gxi, X)), hn::Mul(gxj, Y)), hn::Mul(gxh, h0)));
          const VD ry = hn::Sub(Y, hn::Add(hn::Add(hn::Add(gy0, hn::Mul(gyi, X)), hn::Mul(gyj, Y)), hn::Mul(gyh, h0)));
          vax = hn::Add(vax, hn::Add(hn::Mul(J0, rx), hn::Mul(J1, ry)));
          vay = hn::Add(vay, hn::Add(hn::Mul(J2, rx), hn::Mul(J3, ry)));
        }
        VD h = none;
        for (int it = 0; it < kMaxLateralIterations; ++it) {
          VD px, py, pz;
          if (!look.project(vax, vay, active, px, py, pz)) break;
          const VD rx = hn::Sub(X, hn::Add(px, ox)), ry = hn::Sub(Y, hn::Add(py, oy));
          const auto in = hn::And(active, hn::Le(hn::Add(hn::Mul(rx, rx), hn::Mul(ry, ry)), tol2));
          h = hn::IfThenElse(in, hn::Add(pz, oh), h);
          active = hn::AndNot(in, active);
          if (hn::AllFalse(dd, active)) break;
          vax = hn::Add(vax, hn::Add(hn::Mul(J0, rx), hn::Mul(J1, ry)));
          vay = hn::Add(vay, hn::Add(hn::Mul(J2, rx), hn::Mul(J3, ry)));
        }
        hn::StoreU(h, dd, pout);
      }
      if (m < L)
        for (size_t l = 0; l < m; ++l) A.out[row + i0 + l] = t_out[l];
    }
  }
}

// raster_triangle_surface's loop over a list of its texels (raster.cpp).
void SurfaceTexels(const SurfaceTri& T, int count, const double* HWY_RESTRICT tx, const double* HWY_RESTRICT ty,
                   double* HWY_RESTRICT hv, double* HWY_RESTRICT wax_out, double* HWY_RESTRICT way_out,
                   uint8_t* HWY_RESTRICT wrote_out) {
  const hn::ScalableTag<double> dd;
  using VD = hn::Vec<decltype(dd)>;
  const size_t L = hn::Lanes(dd);
  const VD zero = hn::Zero(dd), one = hn::Set(dd, 1.0);
  Lookup<decltype(dd)> look(T);
  const VD ox = hn::Set(dd, T.ox), oy = hn::Set(dd, T.oy), oh = hn::Set(dd, T.oh), tol2 = hn::Set(dd, T.tol2);
  const VD x0 = hn::Set(dd, T.x0), y0 = hn::Set(dd, T.y0), x1 = hn::Set(dd, T.x1), y1 = hn::Set(dd, T.y1);
  const VD x2 = hn::Set(dd, T.x2), y2 = hn::Set(dd, T.y2);
  const VD e1x = hn::Set(dd, T.e1x), e1y = hn::Set(dd, T.e1y), e2x = hn::Set(dd, T.e2x), e2y = hn::Set(dd, T.e2y);
  const VD inv = hn::Set(dd, T.inv);
  const VD ax0 = hn::Set(dd, T.ax0), ay0 = hn::Set(dd, T.ay0);
  const VD daxx = hn::Set(dd, T.dax_dx), daxy = hn::Set(dd, T.dax_dy), dayx = hn::Set(dd, T.day_dx),
           dayy = hn::Set(dd, T.day_dy);
  const VD sc0 = hn::Set(dd, T.scale[0]), sc1 = hn::Set(dd, T.scale[1]), sc2 = hn::Set(dd, T.scale[2]);
  const VD nmargin = hn::Set(dd, -T.margin);
  const VD hbound = hn::Set(dd, T.keep_max ? T.hhi : T.hlo);
  HWY_ALIGN double t_w[kMaxLanes];
  // bary of raster_triangle_surface: b1, b2 and b0 = 1 - b1 - b2.
  auto bary = [&](VD px, VD py, VD& b0, VD& b1, VD& b2) {
    const VD dx = hn::Sub(px, x0), dy = hn::Sub(py, y0);
    b1 = hn::Mul(hn::Sub(hn::Mul(dx, e2y), hn::Mul(e2x, dy)), inv);
    b2 = hn::Mul(hn::Sub(hn::Mul(e1x, dy), hn::Mul(dx, e1y)), inv);
    b0 = hn::Sub(hn::Sub(one, b1), b2);
  };
  auto clamp0 = [&](VD b) { return hn::IfThenElse(hn::Lt(b, zero), zero, b); };  // std::max(b, 0.0)
  // The caller pads the arrays to a whole number of vectors (kSpan is a
  // multiple of every lane count); lanes past `count` start inactive.
  for (int s = 0; s < count; s += static_cast<int>(L)) {
    const size_t m = std::min(L, static_cast<size_t>(count - s));
    const VD r0 = hn::LoadU(dd, hv + s);
    // A texel already at or beyond anything this triangle can give is done.
    auto active = hn::AndNot(T.keep_max ? hn::Ge(r0, hbound) : hn::Le(r0, hbound), hn::FirstN(dd, m));
    if (hn::AllFalse(dd, active)) {
      for (size_t l = 0; l < m; ++l) wrote_out[s + l] = 0;
      continue;
    }
    const VD X = hn::LoadU(dd, tx + s), Y = hn::LoadU(dd, ty + s);
    VD qx = X, qy = Y;
    {
      VD b0, b1, b2;
      bary(qx, qy, b0, b1, b2);
      const auto outside = hn::Or(hn::Or(hn::Lt(b0, zero), hn::Lt(b1, zero)), hn::Lt(b2, zero));
      if (!hn::AllFalse(dd, outside)) {
        const VD c0 = clamp0(b0), c1 = clamp0(b1), c2 = clamp0(b2);
        const VD cs = hn::Add(hn::Add(c0, c1), c2);
        const VD cx = hn::Div(hn::Add(hn::Add(hn::Mul(c0, x0), hn::Mul(c1, x1)), hn::Mul(c2, x2)), cs);
        const VD cy = hn::Div(hn::Add(hn::Add(hn::Mul(c0, y0), hn::Mul(c1, y1)), hn::Mul(c2, y2)), cs);
        qx = hn::IfThenElse(outside, cx, qx);
        qy = hn::IfThenElse(outside, cy, qy);
      }
    }
    VD rowv = r0;
    VD wax = zero, way = zero;
    auto wrote = hn::FirstN(dd, 0);
    for (int it = 0; it < kMaxLateralIterations; ++it) {
      const VD dqx = hn::Sub(qx, x0), dqy = hn::Sub(qy, y0);
      const VD vax = hn::Add(hn::Add(ax0, hn::Mul(daxx, dqx)), hn::Mul(daxy, dqy));
      const VD vay = hn::Add(hn::Add(ay0, hn::Mul(dayx, dqx)), hn::Mul(dayy, dqy));
      VD px, py, pz;
      if (!look.project(vax, vay, active, px, py, pz)) break;
      const VD rx = hn::Sub(X, hn::Add(px, ox)), ry = hn::Sub(Y, hn::Add(py, oy));
      const auto in = hn::And(active, hn::Le(hn::Add(hn::Mul(rx, rx), hn::Mul(ry, ry)), tol2));
      if (!hn::AllFalse(dd, in)) {
        const VD h = hn::Add(pz, oh);
        const auto better = hn::And(in, T.keep_max ? hn::Gt(h, rowv) : hn::Lt(h, rowv));
        rowv = hn::IfThenElse(better, h, rowv);
        wax = hn::IfThenElse(better, vax, wax);
        way = hn::IfThenElse(better, vay, way);
        wrote = hn::Or(wrote, better);
        active = hn::AndNot(in, active);
        if (hn::AllFalse(dd, active)) break;
      }
      qx = hn::Add(qx, rx);
      qy = hn::Add(qy, ry);
      VD b0, b1, b2;
      bary(qx, qy, b0, b1, b2);
      const auto gone = hn::Or(hn::Or(hn::Lt(hn::Mul(b0, sc0), nmargin), hn::Lt(hn::Mul(b1, sc1), nmargin)),
                               hn::Lt(hn::Mul(b2, sc2), nmargin));
      active = hn::AndNot(gone, active);
    }
    hn::StoreU(rowv, dd, hv + s);
    hn::StoreU(wax, dd, wax_out + s);
    hn::StoreU(way, dd, way_out + s);
    hn::Store(hn::IfThenElseZero(wrote, one), dd, t_w);
    for (size_t l = 0; l < m; ++l) wrote_out[s + l] = t_w[l] != 0.0;
  }
}

const char* ResolveTarget() { return hwy::TargetName(HWY_TARGET); }

}  // namespace HWY_NAMESPACE
}  // namespace depth_simd
}  // namespace hrt
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace hrt {
namespace depth_simd {

HWY_EXPORT(ResolveAll);
HWY_EXPORT(ResolveTarget);
HWY_EXPORT(SurfaceTexels);

void resolve_all(const ResolveArgs& a) { HWY_DYNAMIC_DISPATCH(ResolveAll)(a); }

const char* resolve_target() { return HWY_DYNAMIC_DISPATCH(ResolveTarget)(); }

void surface_texels(const SurfaceTri& t, int count, const double* tx, const double* ty, double* h, double* ax,
                    double* ay, uint8_t* wrote) {
  HWY_DYNAMIC_DISPATCH(SurfaceTexels)(t, count, tx, ty, h, ax, ay, wrote);
}

}  // namespace depth_simd
}  // namespace hrt
#endif
