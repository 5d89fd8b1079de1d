// One texel of one coarse face: raster_triangle (plain path) or
// raster_triangle_surface (the fixed point of the surface mode), as
// src/depth/raster.cpp computes it, with the same coverage rule. Writes the
// height (double, relative to n . window origin), the seed (atlas point and
// the face's atlas-per-grid Jacobian) and the depth that selects the winner.
uniform int u_place;
flat in uint v_t;
layout(location = 0) out uvec2 o_h;
layout(location = 1) out uvec4 o_seed;
layout(location = 2) out vec4 o_jac;

const double kEdgeEps = 1e-9lf;
const int kMaxLateralIterations = 8;

void emit(int p, double h, double a_x, double a_y, double jxx, double jxy, double jyx, double jyy) {
  o_h = pack_d(h);
  o_seed = uvec4(pack_d(a_x), pack_d(a_y));
  o_jac = vec4(float(jxx), float(jxy), float(jyx), float(jyy));
  gl_FragDepth = height_depth(p, h);
}

void main() {
  int p = u_place;
  int i = int(gl_FragCoord.x) - piv(p, PI_TILE_X);
  int j = int(gl_FragCoord.y) - piv(p, PI_TILE_Y);
  int S = piv(p, PI_S);
  if (i < 0 || j < 0 || i >= S || j >= S) discard;
  Tri T = triangle_setup(p, v_t);
  if (!T.valid) discard;
  double x[3] = T.x, y[3] = T.y, ax[3] = T.ax, ay[3] = T.ay;
  double e1x = x[1] - x[0], e1y = y[1] - y[0];
  double e2x = x[2] - x[0], e2y = y[2] - y[0];
  double area2 = T.area2;
  double L;
  if (on_surface_path(p, T, L)) {
    // raster_triangle_surface
    double tol = pdv(p, PD_TOL), tol2 = tol * tol;
    double D = L + tol;
    double xmin = min(min(x[0], x[1]), x[2]) - D, xmax = max(max(x[0], x[1]), x[2]) + D;
    double ymin = min(min(y[0], y[1]), y[2]) - D, ymax = max(max(y[0], y[1]), y[2]) + D;
    if (!(xmax >= 0.0lf) || !(xmin <= double(S - 1)) || !(ymax >= 0.0lf) || !(ymin <= double(S - 1))) discard;
    int i0 = int(ceil(max(xmin, 0.0lf)));
    int i1 = int(floor(min(xmax, double(S - 1))));
    int j0 = int(ceil(max(ymin, 0.0lf)));
    int j1 = int(floor(min(ymax, double(S - 1))));
    if (j < j0 || j > j1) discard;
    double inv = 1.0lf / area2;
    double dax_dx = ((ax[1] - ax[0]) * e2y - (ax[2] - ax[0]) * e1y) * inv;
    double dax_dy = ((ax[2] - ax[0]) * e1x - (ax[1] - ax[0]) * e2x) * inv;
    double day_dx = ((ay[1] - ay[0]) * e2y - (ay[2] - ay[0]) * e1y) * inv;
    double day_dy = ((ay[2] - ay[0]) * e1x - (ay[1] - ay[0]) * e2x) * inv;
    double len[3] = double[3](length(dvec2(x[2] - x[1], y[2] - y[1])), length(dvec2(x[0] - x[2], y[0] - y[2])),
                              length(dvec2(x[1] - x[0], y[1] - y[0])));
    double aa = abs(area2);
    double scale[3] = double[3](aa / len[0], aa / len[1], aa / len[2]);
    double det = abs(dax_dx * day_dy - dax_dy * day_dx);
    double margin = (det > 0.0lf ? 1.0lf / sqrt(det) : 1.0lf) + tol;
    // The culling bound (rasterize_heights' cull).
    if (piv(p, PI_HAS_CULL) != 0) {
      int fb = piv(p, PI_FACE_BASE), vb = piv(p, PI_VERT_BASE);
      dvec3 nobj = pd3(p, PD_N);
      double hlo = 1e308lf, hhi = -1e308lf;
      for (int c = 0; c < 3; ++c) {
        int vi = vb + int(faces[3 * (fb + int(T.f)) + c]);
        double h = nobj.x * verts[3 * vi] + nobj.y * verts[3 * vi + 1] + nobj.z * verts[3 * vi + 2];
        hlo = min(hlo, h);
        hhi = max(hhi, h);
      }
      double reach = double(surf[6 * (fb + int(T.f)) + 5]);
      hlo += pdv(p, PD_N + 3) - reach;
      hhi += pdv(p, PD_N + 3) + reach;
      double cull = pdv(p, PD_CULL);
      if (piv(p, PI_KEEP_MAX) != 0 ? hhi < cull : hlo > cull) discard;
    }
    // The row's span: b_k scale_k >= -D for the three edges.
    double beta[3] = double[3](-(e2y - e1y) * inv, e2y * inv, -e1y * inv);
    double lo = double(i0), hi = double(i1);
    {
      double dx = 0.0lf - x[0], dy = double(j) - y[0];
      double b0[3];
      b0[1] = (dx * e2y - e2x * dy) * inv;
      b0[2] = (e1x * dy - dx * e1y) * inv;
      b0[0] = 1.0lf - b0[1] - b0[2];
      for (int k = 0; k < 3 && lo <= hi; ++k) {
        double lim = -D / scale[k] - b0[k];
        if (beta[k] > 0.0lf) lo = max(lo, lim / beta[k]);
        else if (beta[k] < 0.0lf) hi = min(hi, lim / beta[k]);
        else if (lim > 0.0lf) hi = lo - 1.0lf;
      }
    }
    if (!(lo <= hi)) discard;
    int ia = int(ceil(lo - 1e-9lf)), ib = int(floor(hi + 1e-9lf));
    if (i < max(ia, i0) || i > min(ib, i1)) discard;
    // The start: X clamped into the triangle.
    double qx = double(i), qy = double(j);
    double b[3];
    {
      double dx = qx - x[0], dy = qy - y[0];
      b[1] = (dx * e2y - e2x * dy) * inv;
      b[2] = (e1x * dy - dx * e1y) * inv;
      b[0] = 1.0lf - b[1] - b[2];
    }
    if (b[0] < 0.0lf || b[1] < 0.0lf || b[2] < 0.0lf) {
      double c0 = max(b[0], 0.0lf), c1 = max(b[1], 0.0lf), c2 = max(b[2], 0.0lf);
      double cs = c0 + c1 + c2;
      qx = (c0 * x[0] + c1 * x[1] + c2 * x[2]) / cs;
      qy = (c0 * y[0] + c1 * y[1] + c2 * y[2]) / cs;
    }
    double ox = pdv(p, PD_GX + 3), oy = pdv(p, PD_GY + 3), oh = pdv(p, PD_N + 3);
    for (int it = 0; it < kMaxLateralIterations; ++it) {
      double a_x = ax[0] + dax_dx * (qx - x[0]) + dax_dy * (qy - y[0]);
      double a_y = ay[0] + day_dx * (qx - x[0]) + day_dy * (qy - y[0]);
      double px, py, ph;
      if (!project(p, a_x, a_y, px, py, ph)) break;
      double rx = double(i) - (px + ox), ry = double(j) - (py + oy);
      if (rx * rx + ry * ry <= tol2) {
        emit(p, ph + oh, a_x, a_y, dax_dx, dax_dy, day_dx, day_dy);
        return;
      }
      qx += rx;
      qy += ry;
      double dx = qx - x[0], dy = qy - y[0];
      double bq1 = (dx * e2y - e2x * dy) * inv;
      double bq2 = (e1x * dy - dx * e1y) * inv;
      double bq0 = 1.0lf - bq1 - bq2;
      if (bq0 * scale[0] < -margin || bq1 * scale[1] < -margin || bq2 * scale[2] < -margin) break;
    }
    discard;
  }
  // raster_triangle's plain path: rows j0..j1, the span [xl, xr] from the edges.
  double ymin = min(min(y[0], y[1]), y[2]), ymax = max(max(y[0], y[1]), y[2]);
  if (!(ymax + kEdgeEps >= 0.0lf) || !(ymin - kEdgeEps <= double(S - 1))) discard;
  int j0 = int(ceil(max(ymin - kEdgeEps, 0.0lf)));
  int j1 = int(floor(min(ymax + kEdgeEps, double(S - 1))));
  if (j < j0 || j > j1) discard;
  double xl = 1e308lf, xr = -1e308lf;
  for (int e = 0; e < 3; ++e) {
    int a = e, bb = (e + 1) % 3;
    double ya = y[a], yb = y[bb];
    if ((double(j) < min(ya, yb) - kEdgeEps) || (double(j) > max(ya, yb) + kEdgeEps)) continue;
    if (abs(yb - ya) < 1e-300lf) {
      xl = min(xl, min(x[a], x[bb]));
      xr = max(xr, max(x[a], x[bb]));
      continue;
    }
    double s = clamp((double(j) - ya) / (yb - ya), 0.0lf, 1.0lf);
    double xi = x[a] + s * (x[bb] - x[a]);
    xl = min(xl, xi);
    xr = max(xr, xi);
  }
  if (!(xl <= xr)) discard;
  if (!(xr + kEdgeEps >= 0.0lf) || !(xl - kEdgeEps <= double(S - 1))) discard;
  int i0 = int(ceil(max(xl - kEdgeEps, 0.0lf)));
  int i1 = int(floor(min(xr + kEdgeEps, double(S - 1))));
  if (i < i0 || i > i1) discard;
  double inv = 1.0lf / area2;
  double dax_dx = ((ax[1] - ax[0]) * e2y - (ax[2] - ax[0]) * e1y) * inv;
  double dax_dy = ((ax[2] - ax[0]) * e1x - (ax[1] - ax[0]) * e2x) * inv;
  double day_dx = ((ay[1] - ay[0]) * e2y - (ay[2] - ay[0]) * e1y) * inv;
  double day_dy = ((ay[2] - ay[0]) * e1x - (ay[1] - ay[0]) * e2x) * inv;
  // The CPU steps the atlas point along the row from i0 (cax += dax_dx);
  // here it is evaluated at i directly: they differ by rounding only.
  double cax = ax[0] + dax_dx * (double(i0) - x[0]) + dax_dy * (double(j) - y[0]) + dax_dx * double(i - i0);
  double cay = ay[0] + day_dx * (double(i0) - x[0]) + day_dy * (double(j) - y[0]) + day_dx * double(i - i0);
  double h;
  if (!sample_height(p, cax, cay, h)) discard;
  emit(p, h, cax, cay, dax_dx, dax_dy, day_dx, day_dy);
}
