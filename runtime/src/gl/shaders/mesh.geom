// The texels a mesh quad can write (mesh.vert's box) as a screen-aligned
// rectangle of the placement's tile; mesh.frag decides each texel.
layout(points) in;
layout(triangle_strip, max_vertices = 4) out;
uniform int u_place;
uniform vec2 u_target;  // render target size (texels)
flat in ivec4 v_box[];
flat in ivec2 v_quad[];
flat in int v_fast[];
flat out ivec2 g_quad;
flat out int g_fast;

void main() {
  ivec4 b = v_box[0];
  if (b.x > b.y || b.z > b.w) return;
  int tx = piv(u_place, PI_TILE_X), ty = piv(u_place, PI_TILE_Y);
  // Texel i covers pixels [tile_x + i, tile_x + i + 1): its centre is inside.
  float x0 = 2.0 * float(tx + b.x) / u_target.x - 1.0, x1 = 2.0 * float(tx + b.y + 1) / u_target.x - 1.0;
  float y0 = 2.0 * float(ty + b.z) / u_target.y - 1.0, y1 = 2.0 * float(ty + b.w + 1) / u_target.y - 1.0;
  vec2 c[4] = vec2[4](vec2(x0, y0), vec2(x1, y0), vec2(x0, y1), vec2(x1, y1));
  for (int k = 0; k < 4; ++k) {
    g_quad = v_quad[0];
    g_fast = v_fast[0];
    gl_Position = vec4(c[k], 0.5, 1.0);
    EmitVertex();
  }
  EndPrimitive();
}
