// The mesh heights, one atlas quad per point: which face entry the point is
// (a binary search over the entries' first items), whether
// raster_triangle_mesh visits the quad (its row's interval of half-planes,
// the usable flag, finite corners, the height cull, the grid), and the
// texels its footprint can meet, handed to mesh.geom as a box.
uniform int u_place;
flat out ivec4 v_box;   // texels i0, i1, j0, j1 (empty: nothing drawn)
flat out ivec2 v_quad;  // the quad's atlas column and row
flat out int v_fast;    // 1: the quad lies inside one texel's square

void main() {
  int p = u_place;
  v_box = ivec4(1, 0, 1, 0);
  v_quad = ivec2(0);
  v_fast = 0;
  gl_Position = vec4(0.0, 0.0, 0.0, 1.0);
  int item = gl_VertexID;
  int off = piv(p, PI_MESH_OFFSET), cnt = piv(p, PI_MESH_COUNT);
  if (cnt <= 0) return;
  int lo = 0, hi = cnt - 1;
  while (lo < hi) {
    int mid = (lo + hi + 1) / 2;
    if (mesh[(off + mid) * MI_STRIDE + MI_FIRST] <= item) lo = mid;
    else hi = mid - 1;
  }
  int e = (off + lo) * MI_STRIDE;
  uint f = uint(mesh[e + MI_FACE]);
  int width = mesh[e + MI_WIDTH];
  int r = item - mesh[e + MI_FIRST];
  int qi = mesh[e + MI_QI0] + r % width, qj = mesh[e + MI_QJ0] + r / width;
  double reach = double(intBitsToFloat(mesh[e + MI_REACH]));
  int S = piv(p, PI_S);
  double Sd = double(S);
  bool mx = piv(p, PI_KEEP_MAX) != 0;
  Tri T = triangle_setup_face(p, f);
  if (f >= uint(piv(p, PI_FACE_COUNT))) return;
  double x[3] = T.x, y[3] = T.y, ax[3] = T.ax, ay[3] = T.ay;
  // Whole-face culls.
  double R = reach / pdv(p, PD_CELL) + 1.0lf;
  if (max(max(x[0], x[1]), x[2]) + R < -0.5lf || min(min(x[0], x[1]), x[2]) - R > Sd - 0.5lf ||
      max(max(y[0], y[1]), y[2]) + R < -0.5lf || min(min(y[0], y[1]), y[2]) - R > Sd - 0.5lf)
    return;
  bool has_cull = piv(p, PI_HAS_CULL) != 0;
  double cull = pdv(p, PD_CULL);
  int fb = piv(p, PI_FACE_BASE), vb = piv(p, PI_VERT_BASE);
  dvec3 nobj = pd3(p, PD_N);
  double hc[3];
  double hlo = 1e308lf, hhi = -1e308lf;
  for (int c = 0; c < 3; ++c) {
    int vi = vb + int(faces[3 * (fb + int(f)) + c]);
    precise double h = nobj.x * verts[3 * vi] + nobj.y * verts[3 * vi + 1] + nobj.z * verts[3 * vi + 2];
    hlo = min(hlo, h);
    hhi = max(hhi, h);
    precise double hco = h + pdv(p, PD_N + 3);
    hc[c] = hco;
  }
  {
    precise double dl = pdv(p, PD_N + 3) - reach, du = pdv(p, PD_N + 3) + reach;
    precise double l = hlo + dl, u = hhi + du;
    if (has_cull && (mx ? u < cull : l > cull)) return;
  }
  precise double e1x = ax[1] - ax[0], e1y = ay[1] - ay[0], e2x = ax[2] - ax[0], e2y = ay[2] - ay[0];
  precise double area2 = e1x * e2y - e2x * e1y;
  if (!(abs(area2) > 1e-12lf)) return;
  // The half-planes g.i i + g.j j + g.0 >= 0 at the quad's centre.
  dvec3 hp[8];
  int nh = 0;
  double sgn = area2 > 0.0lf ? 1.0lf : -1.0lf;
  for (int k = 0; k < 3; ++k) {
    int k1 = (k + 1) % 3;
    precise double nx = -sgn * (ay[k1] - ay[k]), ny = sgn * (ax[k1] - ax[k]);
    precise double len = sqrt(nx * nx + ny * ny);
    precise double ux = nx / len, uy = ny / len;
    precise double g0 = -(ux * ax[k] + uy * ay[k]) + 1.0lf;
    hp[nh++] = dvec3(ux, uy, g0);
  }
  {
    precise double inv = 1.0lf / area2;
    for (int q = 0; q < 5; ++q) {
      if (q == 4 && !has_cull) break;
      double v0, v1, v2, sign, bound;
      double Rg = reach / pdv(p, PD_CELL);
      if (q < 2) {
        v0 = x[0], v1 = x[1], v2 = x[2];
      } else if (q < 4) {
        v0 = y[0], v1 = y[1], v2 = y[2];
      } else {
        v0 = hc[0], v1 = hc[1], v2 = hc[2];
      }
      if (q == 0 || q == 2) sign = 1.0lf, bound = -0.5lf - Rg;
      else if (q == 1 || q == 3) sign = -1.0lf, bound = Sd - 0.5lf + Rg;
      else if (mx) sign = 1.0lf, bound = cull - reach;
      else sign = -1.0lf, bound = cull + reach;
      precise double d1 = v1 - v0, d2 = v2 - v0;
      precise double da = (d1 * e2y - d2 * e1y) * inv;
      precise double db = (d2 * e1x - d1 * e2x) * inv;
      if (!finite_d(da) || !finite_d(db)) continue;
      precise double slack = (kQuadReadMargin + 0.75lf) * sqrt(da * da + db * db);
      precise double g0 = sign * (v0 + da * (0.5lf - ax[0]) + db * (0.5lf - ay[0]) - bound) + slack;
      hp[nh++] = dvec3(sign * da, sign * db, g0);
    }
  }
  // The row's interval (row_range).
  int W = piv(p, PI_ATLAS_W), H = piv(p, PI_ATLAS_H);
  int qi0 = int(clamp(floor(min(min(ax[0], ax[1]), ax[2]) - 1.5lf), 0.0lf, double(W - 2)));
  int qi1 = int(clamp(ceil(max(max(ax[0], ax[1]), ax[2]) + 0.5lf), 0.0lf, double(W - 2)));
  double flo = double(qi0), fhi = double(qi1);
  double cj = double(qj) + 0.5lf;
  for (int k = 0; k < nh && flo <= fhi; ++k) {
    precise double rest = hp[k].y * cj + hp[k].z;
    precise double eps = 1e-9lf * (abs(rest) + abs(hp[k].x) * (abs(flo) + abs(fhi)) + 1.0lf);
    if (abs(hp[k].x) < 1e-300lf) {
      if (rest + eps < 0.0lf) flo = fhi + 1.0lf;
    } else if (hp[k].x > 0.0lf) {
      precise double t = -(rest + eps) / hp[k].x - 0.5lf;
      flo = max(flo, t);
    } else {
      precise double t = -(rest + eps) / hp[k].x - 0.5lf;
      fhi = min(fhi, t);
    }
  }
  if (!(flo <= fhi)) return;
  if (qi < int(ceil(flo)) || qi > int(floor(fhi))) return;
  if (texelFetch(u_ok, ivec2(qi, qj), 0).r == 0u) return;
  Corner c00 = mesh_corner(p, qi, qj), c10 = mesh_corner(p, qi + 1, qj);
  Corner c01 = mesh_corner(p, qi, qj + 1), c11 = mesh_corner(p, qi + 1, qj + 1);
  if (!(c00.ok && c10.ok && c01.ok && c11.ok)) return;
  double hq = extreme4(mx, c00.h, c10.h, c01.h, c11.h);
  if (has_cull && (mx ? hq < cull : hq > cull)) return;
  double lx = min(min(c00.x, c10.x), min(c01.x, c11.x)), hx = max(max(c00.x, c10.x), max(c01.x, c11.x));
  double ly = min(min(c00.y, c10.y), min(c01.y, c11.y)), hy = max(max(c00.y, c10.y), max(c01.y, c11.y));
  if (hx < -0.5lf || lx > Sd - 0.5lf || hy < -0.5lf || ly > Sd - 0.5lf) return;
  double ci = floor(lx + 0.5lf), cjj = floor(ly + 0.5lf);
  v_quad = ivec2(qi, qj);
  if (hx < ci + 0.5lf && hy < cjj + 0.5lf && ci >= 0.0lf && cjj >= 0.0lf && ci < Sd && cjj < Sd) {
    v_fast = 1;
    v_box = ivec4(int(ci), int(ci), int(cjj), int(cjj));
    return;
  }
  v_box = ivec4(max(0, int(ceil(lx - 0.5lf))), min(S - 1, int(floor(hx + 0.5lf))), max(0, int(ceil(ly - 0.5lf))),
                min(S - 1, int(floor(hy + 0.5lf))));
}
