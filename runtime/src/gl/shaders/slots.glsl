// The (patch, configuration) slots of the max search: where h_A and h_B of
// each texel come from. Shared by reduce.comp and the occlusion search's
// difference pass.
layout(std430, binding = 9) readonly buffer Slots { int slots[]; };
#define SL_STRIDE 16
#define SL_KIND 0      // 0: A's configuration-0 tile shifted by (di, dj); 1: a rendered tile; 2: the configuration buffer
#define SL_AX 1        // A tile's corner in the render target
#define SL_AY 2
#define SL_BORDER 3    // A tile's border
#define SL_DI 4
#define SL_DJ 5
#define SL_CFG 6       // kind 2: offset in the configuration buffer
#define SL_BX 7        // B tile's corner
#define SL_BY 8
#define SL_N 9
#define SL_REGION 10   // 1: also the contact region (configuration 0)
#define SL_DIFF_X 11   // occlusion search: the slot's tile in the difference depth buffer
#define SL_DIFF_Y 12
#define SL_PLACE_B 13  // B's placement record (for its depth mapping)

layout(std430, binding = 8) readonly buffer CfgIn { uvec2 cfg_in[]; };
layout(binding = 2) uniform usampler2D u_h;     // render target heights
layout(binding = 5) uniform sampler2D u_depth;  // render target depth (0 = uncovered)

int slv(int s, int k) { return slots[s * SL_STRIDE + k]; }

// h_A - h_B at texel (i, j) of slot s, and whether both cover it.
bool slot_diff(int s, int i, int j, out double d) {
  d = 0.0lf;
  ivec2 bt = ivec2(slv(s, SL_BX) + i, slv(s, SL_BY) + j);
  if (!(texelFetch(u_depth, bt, 0).r > 0.0)) return false;
  double hb = unpack_d(texelFetch(u_h, bt, 0).xy);
  double ha;
  int kind = slv(s, SL_KIND);
  if (kind == 2) {
    ha = unpack_d(cfg_in[slv(s, SL_CFG) + j * slv(s, SL_N) + i]);
    if (isinf(ha)) return false;
  } else {
    int b = slv(s, SL_BORDER);
    ivec2 at = ivec2(slv(s, SL_AX) + i - slv(s, SL_DI) + b, slv(s, SL_AY) + j - slv(s, SL_DJ) + b);
    if (!(texelFetch(u_depth, at, 0).r > 0.0)) return false;
    ha = unpack_d(texelFetch(u_h, at, 0).xy);
  }
  d = ha - hb;
  return true;
}
