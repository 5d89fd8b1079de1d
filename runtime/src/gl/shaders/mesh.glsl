// The mesh heights (HeightMode::mesh): raster_triangle_mesh and
// splat_triangle of src/depth/raster.cpp, one atlas quad per point of the
// draw. Same arithmetic in double, same order, `precise` against fused
// multiply-adds, so that both backends keep the same quads and give the same
// heights.

// Per (placement, face) entry, MI_STRIDE ints: the face's rectangle of atlas
// quads (columns qi0..qi1 from row qj0 on), the first item (quad) of the
// entry in the draw, and its half-planes: where they start in `planes`
// (3 doubles each: gi, gj, g0) and how many. Written by depth_gl.cpp
// (mesh_entries) with src/depth/mesh_rows.h.
layout(std430, binding = 13) readonly buffer MeshItems { int mesh[]; };
layout(std430, binding = 14) readonly buffer MeshPlanes { double planes[]; };
#define MI_STRIDE 6
#define MI_QI0 0
#define MI_QI1 1
#define MI_QJ0 2
#define MI_FIRST 3
#define MI_PLANES 4
#define MI_NPLANES 5

// MeshRows::range: row j's interval [lo, hi] of the entry's quads (empty
// when lo > hi), the same operations in the same order.
void mesh_row_range(int e, int j, out int lo, out int hi) {
  double flo = double(mesh[e + MI_QI0]), fhi = double(mesh[e + MI_QI1]);
  precise double cj = double(j) + 0.5lf;
  int o = mesh[e + MI_PLANES], nh = mesh[e + MI_NPLANES];
  for (int k = 0; k < nh && flo <= fhi; ++k) {
    double gi = planes[3 * (o + k)], gj = planes[3 * (o + k) + 1], g0 = planes[3 * (o + k) + 2];
    precise double rest = gj * cj + g0;
    precise double eps = 1e-9lf * (abs(rest) + abs(gi) * (abs(flo) + abs(fhi)) + 1.0lf);
    if (abs(gi) < 1e-300lf) {
      if (rest + eps < 0.0lf) flo = fhi + 1.0lf;
    } else if (gi > 0.0lf) {
      precise double t = -(rest + eps) / gi - 0.5lf;
      flo = max(flo, t);
    } else {
      precise double t = -(rest + eps) / gi - 0.5lf;
      fhi = min(fhi, t);
    }
  }
  if (!(flo <= fhi)) {
    lo = 1;
    hi = 0;
    return;
  }
  lo = int(ceil(flo));
  hi = int(floor(fhi));
}

// One projected atlas texel (MeshCorner): grid coordinates and height.
struct Corner {
  double x, y, h;
  bool ok;
};

bool finite_d(double v) { return !isnan(v) && !isinf(v); }

Corner mesh_corner(int p, int i, int j) {
  vec3 t = texelFetch(u_atlas, ivec2(i, j), 0).xyz;
  double px = double(t.x), py = double(t.y), pz = double(t.z);
  Corner c;
  precise double x = pdv(p, PD_GX) * px + pdv(p, PD_GX + 1) * py + pdv(p, PD_GX + 2) * pz + pdv(p, PD_GX + 3);
  precise double y = pdv(p, PD_GY) * px + pdv(p, PD_GY + 1) * py + pdv(p, PD_GY + 2) * pz + pdv(p, PD_GY + 3);
  precise double h = pdv(p, PD_N) * px + pdv(p, PD_N + 1) * py + pdv(p, PD_N + 2) * pz + pdv(p, PD_N + 3);
  c.x = x;
  c.y = y;
  c.h = h;
  c.ok = finite_d(x) && finite_d(y) && finite_d(h);
  return c;
}

double extreme4(bool mx, double a, double b, double c, double d) {
  // std::max({a, b, c, d}): the first of the largest.
  double r = a;
  if (mx) {
    if (r < b) r = b;
    if (r < c) r = c;
    if (r < d) r = d;
  } else {
    if (b < r) r = b;
    if (c < r) r = c;
    if (d < r) r = d;
  }
  return r;
}

// splat_triangle's value at texel (i, j) of the placement's S x S tile:
// false when the triangle's conservative footprint misses the texel.
bool splat_value(int p, Corner c0, Corner c1, Corner c2, int i, int j, out double v) {
  v = 0.0lf;
  int S = piv(p, PI_S);
  bool mx = piv(p, PI_KEEP_MAX) != 0;
  double xmin = min(min(c0.x, c1.x), c2.x), xmax = max(max(c0.x, c1.x), c2.x);
  double ymin = min(min(c0.y, c1.y), c2.y), ymax = max(max(c0.y, c1.y), c2.y);
  double Sd = double(S);
  if (!(xmax >= -0.5lf) || !(xmin <= Sd - 0.5lf) || !(ymax >= -0.5lf) || !(ymin <= Sd - 0.5lf)) return false;
  int i0 = max(0, int(ceil(xmin - 0.5lf)));
  int i1 = min(S - 1, int(floor(xmax + 0.5lf)));
  int j0 = max(0, int(ceil(ymin - 0.5lf)));
  int j1 = min(S - 1, int(floor(ymax + 0.5lf)));
  if (i < i0 || i > i1 || j < j0 || j > j1) return false;
  double hext = c0.h;
  if (mx) {
    if (hext < c1.h) hext = c1.h;
    if (hext < c2.h) hext = c2.h;
  } else {
    if (c1.h < hext) hext = c1.h;
    if (c2.h < hext) hext = c2.h;
  }
  if (i0 == i1 && j0 == j1) {
    v = hext;
    return true;
  }
  precise double e1x = c1.x - c0.x, e1y = c1.y - c0.y, e2x = c2.x - c0.x, e2y = c2.y - c0.y;
  precise double area2 = e1x * e2y - e2x * e1y;
  double a = 0.0lf, b = 0.0lf;
  bool plane = abs(area2) > 1e-12lf;
  if (plane) {
    precise double inv = 1.0lf / area2;
    precise double dh1 = c1.h - c0.h, dh2 = c2.h - c0.h;
    precise double aa = (dh1 * e2y - dh2 * e1y) * inv;
    precise double bb = (dh2 * e1x - dh1 * e2x) * inv;
    a = aa;
    b = bb;
    plane = finite_d(a) && finite_d(b);
  }
  double sgn = area2 >= 0.0lf ? 1.0lf : -1.0lf;
  double px[3] = double[3](c0.x, c1.x, c2.x), py[3] = double[3](c0.y, c1.y, c2.y);
  for (int k = 0; k < 3; ++k) {
    int k1 = (k + 1) % 3;
    precise double gx = -sgn * (py[k1] - py[k]);
    precise double gy = sgn * (px[k1] - px[k]);
    precise double g0 = -(gx * px[k] + gy * py[k]);
    precise double reach = 0.5lf * (abs(gx) + abs(gy)) + 1e-9lf * (abs(g0) + 1.0lf);
    precise double e = gx * double(i) + gy * double(j) + g0 + reach;
    if (!(e >= 0.0lf)) return false;
  }
  double h = hext;
  if (plane) {
    precise double slack = 0.5lf * (abs(a) + abs(b));
    precise double hc = c0.h + a * (double(i) - c0.x) + b * (double(j) - c0.y);
    precise double up = hc + slack, down = hc - slack;
    h = mx ? min(hext, up) : max(hext, down);
  }
  v = h;
  return true;
}
