// One coarse face of a placement as a screen-aligned box over the texels it
// can write (6 vertices per face: two triangles), clipped to the tile: its
// projection's bounding box grown by one texel, and on the surface path by
// the lateral bound L plus the tolerance as well. The fragment shader
// decides each texel exactly as raster.cpp does; the box only has to cover.
uniform int u_place;
uniform vec2 u_target;  // render target size (texels)
flat out uint v_t;

void main() {
  int p = u_place;
  uint t = uint(gl_VertexID / 6);
  int corner = gl_VertexID % 6;
  v_t = t;
  Tri T = triangle_setup(p, t);
  double S = double(piv(p, PI_S));
  double L;
  bool surface = T.valid && on_surface_path(p, T, L);
  double grow = 1.0lf + (surface ? L + pdv(p, PD_TOL) : 0.0lf);
  double x0 = min(min(T.x[0], T.x[1]), T.x[2]) - grow, x1 = max(max(T.x[0], T.x[1]), T.x[2]) + grow;
  double y0 = min(min(T.y[0], T.y[1]), T.y[2]) - grow, y1 = max(max(T.y[0], T.y[1]), T.y[2]) + grow;
  // Texel i's centre is at grid x = i, pixel centre tile_x + i + 0.5: the tile spans grid [-0.5, S - 0.5].
  x0 = clamp(x0, -0.5lf, S - 0.5lf);
  x1 = clamp(x1, -0.5lf, S - 0.5lf);
  y0 = clamp(y0, -0.5lf, S - 0.5lf);
  y1 = clamp(y1, -0.5lf, S - 0.5lf);
  if (!T.valid || !(x1 > x0) || !(y1 > y0)) {
    gl_Position = vec4(2.0, 2.0, 0.0, 1.0);  // outside the view: nothing drawn
    return;
  }
  // Corners of the two triangles: (0,0) (1,0) (1,1) / (0,0) (1,1) (0,1).
  const int cx[6] = int[6](0, 1, 1, 0, 1, 0);
  const int cy[6] = int[6](0, 0, 1, 0, 1, 1);
  double gxw = (cx[corner] == 0 ? x0 : x1) + 0.5lf + double(piv(p, PI_TILE_X));
  double gyw = (cy[corner] == 0 ? y0 : y1) + 0.5lf + double(piv(p, PI_TILE_Y));
  gl_Position = vec4(float(2.0lf * gxw / double(u_target.x) - 1.0lf), float(2.0lf * gyw / double(u_target.y) - 1.0lf),
                     0.5, 1.0);
}
