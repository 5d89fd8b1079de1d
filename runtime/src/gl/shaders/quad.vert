// A slot's N x N tile of the difference depth buffer as one quad (4
// vertices, a triangle strip). u_depth_mode 0: z = 0.5 (the difference pass
// writes gl_FragDepth); 1: z = the midpoint of the slot's search interval
// (0 for the coverage query, u_coverage = 1). Clip control is
// GL_ZERO_TO_ONE, so z is the window depth.
uniform int u_slot;
uniform vec2 u_target;
uniform int u_depth_mode;
uniform int u_coverage;
layout(std430, binding = 10) readonly buffer ResultsQ { double results_q[]; };

void main() {
  int s = u_slot;
  int N = slv(s, SL_N);
  float x0 = float(slv(s, SL_DIFF_X)), y0 = float(slv(s, SL_DIFF_Y));
  float cx = (gl_VertexID & 1) != 0 ? x0 + float(N) : x0;
  float cy = (gl_VertexID & 2) != 0 ? y0 + float(N) : y0;
  float z = 0.5;
  if (u_depth_mode == 1) z = u_coverage != 0 ? 0.0 : float(0.5lf * (results_q[s * 16 + 10] + results_q[s * 16 + 11]));
  gl_Position = vec4(2.0 * cx / u_target.x - 1.0, 2.0 * cy / u_target.y - 1.0, z, 1.0);
}
