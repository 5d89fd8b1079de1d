// The occlusion search's difference pass: h_A - h_B of the slot's texel
// scaled into [0, 1] over [-R, R] (R per slot), covered texels at least
// 2^-23 so that the cleared 0 means "not covered by both".
uniform int u_slot;
layout(std430, binding = 11) readonly buffer Ranges { double ranges[]; };

void main() {
  int s = u_slot;
  int i = int(gl_FragCoord.x) - slv(s, SL_DIFF_X), j = int(gl_FragCoord.y) - slv(s, SL_DIFF_Y);
  double d;
  if (!slot_diff(s, i, j, d)) discard;
  double R = ranges[s];
  double t = clamp((d + R) / (2.0lf * R), 1.0lf / 8388608.0lf, 1.0lf);
  gl_FragDepth = float(t);
}
