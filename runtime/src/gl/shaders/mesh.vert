// The mesh heights, one atlas quad per point: which face entry the point is
// (a binary search over the entries' first items), whether
// raster_triangle_mesh visits the quad (its row's interval, from the
// half-planes the CPU computed for the face; the usable flag, finite
// corners, the height cull, the grid), and the texels its footprint can
// meet, handed to mesh.geom as a box.
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
  int qi0 = mesh[e + MI_QI0], width = mesh[e + MI_QI1] - qi0 + 1;
  int r = item - mesh[e + MI_FIRST];
  int qi = qi0 + r % width, qj = mesh[e + MI_QJ0] + r / width;
  {
    int rlo, rhi;
    mesh_row_range(e, qj, rlo, rhi);
    if (qi < rlo || qi > rhi) return;
  }
  int S = piv(p, PI_S);
  double Sd = double(S);
  bool mx = piv(p, PI_KEEP_MAX) != 0;
  bool has_cull = piv(p, PI_HAS_CULL) != 0;
  double cull = pdv(p, PD_CULL);
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
