// resolve_heights (src/depth/raster.cpp) for one configuration of one patch
// per z slice: per texel covered at configuration 0, the fixed point started
// from the seed's atlas point; out to the configuration buffer as doubles
// (-inf: uncovered). One dispatch per patch (its model's atlas is bound).
layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;
layout(std430, binding = 8) writeonly buffer Cfg { uvec2 cfg[]; };
layout(binding = 2) uniform usampler2D u_h0;    // render target: heights (packed doubles)
layout(binding = 3) uniform usampler2D u_seed;  // seeds' atlas points (two packed doubles)
layout(binding = 4) uniform sampler2D u_jac;    // seeds' Jacobians
layout(binding = 5) uniform sampler2D u_depth;  // render target depth: 0 = uncovered
uniform int u_first_place;                      // placement of this patch's first re-solved configuration

const int kMaxLateralIterations = 8;

void main() {
  int p = u_first_place + int(gl_GlobalInvocationID.z);
  int N = piv(p, PI_N);
  int i = int(gl_GlobalInvocationID.x), j = int(gl_GlobalInvocationID.y);
  if (i >= N || j >= N) return;
  int out_k = piv(p, PI_OUT_OFFSET) + j * N + i;
  double kNegInf = packDouble2x32(uvec2(0u, 0xFFF00000u));
  int b = piv(p, PI_SEED_BORDER);
  ivec2 st = ivec2(piv(p, PI_SEED_X) + i + b, piv(p, PI_SEED_Y) + j + b);
  cfg[out_k] = pack_d(kNegInf);
  if (!(texelFetch(u_depth, st, 0).r > 0.0)) return;  // not covered at configuration 0
  double h0 = unpack_d(texelFetch(u_h0, st, 0).xy);
  uvec4 s = texelFetch(u_seed, st, 0);
  double a_x = unpack_d(s.xy), a_y = unpack_d(s.zw);
  vec4 J = texelFetch(u_jac, st, 0);
  double gx0 = pdv(p, PD_RM), gxi = pdv(p, PD_RM + 1), gxj = pdv(p, PD_RM + 2), gxh = pdv(p, PD_RM + 3);
  double gy0 = pdv(p, PD_RM + 4), gyi = pdv(p, PD_RM + 5), gyj = pdv(p, PD_RM + 6), gyh = pdv(p, PD_RM + 7);
  double di = double(i), dj = double(j);
  {
    double rx = di - (gx0 + gxi * di + gxj * dj + gxh * h0), ry = dj - (gy0 + gyi * di + gyj * dj + gyh * h0);
    a_x += double(J.x) * rx + double(J.y) * ry;
    a_y += double(J.z) * rx + double(J.w) * ry;
  }
  double tol = pdv(p, PD_TOL), tol2 = tol * tol;
  double ox = pdv(p, PD_GX + 3), oy = pdv(p, PD_GY + 3), oh = pdv(p, PD_N + 3);
  for (int it = 0; it < kMaxLateralIterations; ++it) {
    double px, py, ph;
    if (!project(p, a_x, a_y, px, py, ph)) break;
    double rx = di - (px + ox), ry = dj - (py + oy);
    if (rx * rx + ry * ry <= tol2) {
      cfg[out_k] = pack_d(ph + oh);
      break;
    }
    a_x += double(J.x) * rx + double(J.y) * ry;
    a_y += double(J.z) * rx + double(J.w) * ry;
  }
}
