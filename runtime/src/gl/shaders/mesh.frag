// One texel of one mesh quad: the highest (A) or lowest (B) point of the
// quad's two triangles over the texel's square (splat_triangle), or the
// quad's extreme corner when the quad lies inside the square.
uniform int u_place;
flat in ivec2 g_quad;
flat in int g_fast;
layout(location = 0) out uvec2 o_h;
layout(location = 1) out uvec4 o_seed;
layout(location = 2) out vec4 o_jac;

void main() {
  int p = u_place;
  int i = int(gl_FragCoord.x) - piv(p, PI_TILE_X);
  int j = int(gl_FragCoord.y) - piv(p, PI_TILE_Y);
  int S = piv(p, PI_S);
  if (i < 0 || j < 0 || i >= S || j >= S) discard;
  bool mx = piv(p, PI_KEEP_MAX) != 0;
  int qi = g_quad.x, qj = g_quad.y;
  Corner c00 = mesh_corner(p, qi, qj), c10 = mesh_corner(p, qi + 1, qj);
  Corner c01 = mesh_corner(p, qi, qj + 1), c11 = mesh_corner(p, qi + 1, qj + 1);
  double h;
  if (g_fast != 0) {
    h = extreme4(mx, c00.h, c10.h, c01.h, c11.h);
  } else {
    double v0, v1;
    bool m0 = splat_value(p, c00, c10, c11, i, j, v0);
    bool m1 = splat_value(p, c00, c11, c01, i, j, v1);
    if (!m0 && !m1) discard;
    h = !m1 ? v0 : !m0 ? v1 : (mx ? max(v0, v1) : min(v0, v1));
  }
  o_h = pack_d(h);
  o_seed = uvec4(0u);
  o_jac = vec4(0.0);
  gl_FragDepth = height_depth(p, h);
}
