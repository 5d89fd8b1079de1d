// Shared by every program of the GL depth backend (src/gl/depth_gl.cpp
// prepends it). The arithmetic repeats src/depth/raster.cpp line by line:
// geometry in double, atlas lookups in float with the CPU's operation order
// (`precise` forbids the fused multiply-adds the CPU does not use), so that
// both backends take the same decisions and give the same heights up to
// float32 rounding.

// Model data, all models concatenated (bases in the placement record).
layout(std430, binding = 0) readonly buffer Verts { double verts[]; };   // 3 per coarse vertex
layout(std430, binding = 1) readonly buffer Faces { uint faces[]; };     // 3 per face (model-local vertex indices)
layout(std430, binding = 2) readonly buffer Uvs { float uvs[]; };        // 6 per face (u, v per corner)
layout(std430, binding = 3) readonly buffer Surf { float surf[]; };      // 6 per face: axis xyz, along, across, reach
// The frame: triangle lists and placement records.
layout(std430, binding = 4) readonly buffer Tris { uint tris[]; };
layout(std430, binding = 5) readonly buffer PlaceD { double pd[]; };
layout(std430, binding = 6) readonly buffer PlaceI { int pi[]; };
layout(std430, binding = 7) readonly buffer PlaceF { float pf[]; };

// Placement record layout (kept in step with depth_gl.cpp's PlaceRecord).
#define PD_STRIDE 32
#define PI_STRIDE 24
#define PF_STRIDE 12
// doubles
#define PD_GX 0      // gx.xyz, then ox at 3
#define PD_GY 4      // gy.xyz, then oy at 7
#define PD_N 8       // n_obj.xyz, then oh at 11
#define PD_TOL 12
#define PD_CELL 13
#define PD_CULL 14
#define PD_HMIN 15
#define PD_HSCALE 16
#define PD_RM 17     // ResolveMotion: gx0 gxi gxj gxh gy0 gyi gyj gyh
// ints
#define PI_S 0
#define PI_KEEP_MAX 1
#define PI_SURFACE 2
#define PI_TILE_X 3
#define PI_TILE_Y 4
#define PI_TRI_OFFSET 5
#define PI_TRI_COUNT 6
#define PI_VERT_BASE 7
#define PI_FACE_BASE 8
#define PI_ATLAS_W 9
#define PI_ATLAS_H 10
#define PI_USE_OK 11
#define PI_HAS_CULL 12
#define PI_N 13
#define PI_SEED_BORDER 14
#define PI_SEED_X 15
#define PI_SEED_Y 16
#define PI_OUT_OFFSET 17
#define PI_FACE_COUNT 18
#define PI_MESH_OFFSET 19  // HeightMode::mesh: first of the placement's face entries (mesh.glsl)
#define PI_MESH_COUNT 20   // and their number
// floats
#define PF_GX4 0
#define PF_GY4 4
#define PF_N4 8

layout(binding = 0) uniform sampler2D u_atlas;   // RGBA32F positions, texelFetch only
layout(binding = 1) uniform usampler2D u_ok;     // R8UI SurfaceMap::quad_ok

double pdv(int p, int k) { return pd[p * PD_STRIDE + k]; }
int piv(int p, int k) { return pi[p * PI_STRIDE + k]; }
float pfv(int p, int k) { return pf[p * PF_STRIDE + k]; }
dvec3 pd3(int p, int k) { return dvec3(pdv(p, k), pdv(p, k + 1), pdv(p, k + 2)); }
vec3 pf3(int p, int k) { return vec3(pfv(p, k), pfv(p, k + 1), pfv(p, k + 2)); }

// Bilerp of raster.cpp: top = a + fx (b - a), bot = c + fx (d - c),
// v = top + fy (bot - top), then the dot (v0 w0 + v1 w1) + v2 w2.
float bilerp_dot(vec3 a, vec3 b, vec3 c, vec3 d, float fx, float fy, vec3 w) {
  precise vec3 top = a + fx * (b - a);
  precise vec3 bot = c + fx * (d - c);
  precise vec3 v = top + fy * (bot - top);
  precise float s = v.x * w.x + v.y * w.y;
  precise float r = s + v.z * w.z;
  return r;
}

// HeightSampler::footprint: the clamped 2 x 2 texels of (ax, ay); false in
// an unusable quad.
bool footprint(int p, double ax, double ay, out vec3 q0, out vec3 q1, out vec3 q2, out vec3 q3, out float fx,
               out float fy) {
  double fx0 = floor(ax), fy0 = floor(ay);
  fx = float(ax - fx0);
  fy = float(ay - fy0);
  int i0 = int(fx0), j0 = int(fy0);
  int w = piv(p, PI_ATLAS_W), h = piv(p, PI_ATLAS_H);
  int ia = clamp(i0, 0, w - 1), ib = clamp(i0 + 1, 0, w - 1);
  int ja = clamp(j0, 0, h - 1), jb = clamp(j0 + 1, 0, h - 1);
  if (piv(p, PI_USE_OK) != 0 && texelFetch(u_ok, ivec2(ia, ja), 0).r == 0u) return false;
  q0 = texelFetch(u_atlas, ivec2(ia, ja), 0).xyz;
  q1 = texelFetch(u_atlas, ivec2(ib, ja), 0).xyz;
  q2 = texelFetch(u_atlas, ivec2(ia, jb), 0).xyz;
  q3 = texelFetch(u_atlas, ivec2(ib, jb), 0).xyz;
  return true;
}

// HeightSampler::clamped + oh: the height of the atlas point at (ax, ay);
// false in an unusable quad (the CPU's NaN, which never wins).
bool sample_height(int p, double ax, double ay, out double h) {
  vec3 q0, q1, q2, q3;
  float fx, fy;
  if (!footprint(p, ax, ay, q0, q1, q2, q3, fx, fy)) return false;
  h = double(bilerp_dot(q0, q1, q2, q3, fx, fy, pf3(p, PF_N4))) + pdv(p, PD_N + 3);
  return true;
}

// HeightSampler::project: grid coordinates (before the offsets) and height
// (before oh) of the atlas point at (ax, ay).
bool project(int p, double ax, double ay, out double px, out double py, out double ph) {
  if (!(ax > -1e6 && ax < 1e6 && ay > -1e6 && ay < 1e6)) return false;
  vec3 q0, q1, q2, q3;
  float fx, fy;
  if (!footprint(p, ax, ay, q0, q1, q2, q3, fx, fy)) return false;
  px = double(bilerp_dot(q0, q1, q2, q3, fx, fy, pf3(p, PF_GX4)));
  py = double(bilerp_dot(q0, q1, q2, q3, fx, fy, pf3(p, PF_GY4)));
  ph = double(bilerp_dot(q0, q1, q2, q3, fx, fy, pf3(p, PF_N4)));
  return true;
}

// Height to depth (the depth test keeps A's highest and B's lowest point per
// texel; the cleared 0 means uncovered): A maps increasing, B decreasing,
// both into [2^-20, 1 - 2^-20].
float height_depth(int p, double h) {
  double t = (h - pdv(p, PD_HMIN)) * pdv(p, PD_HSCALE);
  t = clamp(t, 0.0lf, 1.0lf - 2.0lf / 1048576.0lf);
  double d = 1.0lf / 1048576.0lf + t;
  return float(piv(p, PI_KEEP_MAX) != 0 ? d : 1.0lf - d);
}

// One coarse face's set-up for a placement (raster_triangle's first lines).
struct Tri {
  double x[3], y[3], ax[3], ay[3];
  double area2;
  uint f;
  bool valid;
};

Tri triangle_setup_face(int p, uint f) {
  Tri T;
  T.valid = false;
  T.f = f;
  if (f >= uint(piv(p, PI_FACE_COUNT))) return T;
  int fb = piv(p, PI_FACE_BASE), vb = piv(p, PI_VERT_BASE);
  double W = double(piv(p, PI_ATLAS_W)), H = double(piv(p, PI_ATLAS_H));
  dvec3 gx = pd3(p, PD_GX), gy = pd3(p, PD_GY);
  for (int c = 0; c < 3; ++c) {
    int vi = vb + int(faces[3 * (fb + int(f)) + c]);
    dvec3 P = dvec3(verts[3 * vi], verts[3 * vi + 1], verts[3 * vi + 2]);
    T.x[c] = gx.x * P.x + gx.y * P.y + gx.z * P.z + pdv(p, PD_GX + 3);
    T.y[c] = gy.x * P.x + gy.y * P.y + gy.z * P.z + pdv(p, PD_GY + 3);
    T.ax[c] = double(uvs[6 * (fb + int(f)) + 2 * c]) * W - 0.5lf;
    T.ay[c] = (1.0lf - double(uvs[6 * (fb + int(f)) + 2 * c + 1])) * H - 0.5lf;
  }
  double e1x = T.x[1] - T.x[0], e1y = T.y[1] - T.y[0];
  double e2x = T.x[2] - T.x[0], e2y = T.y[2] - T.y[0];
  T.area2 = e1x * e2y - e2x * e1y;
  T.valid = abs(T.area2) >= 1e-12lf;
  return T;
}

Tri triangle_setup(int p, uint t) { return triangle_setup_face(p, tris[piv(p, PI_TRI_OFFSET) + int(t)]); }

// SurfaceMap::lateral_bound / cell: grid texels.
double lateral_texels(int p, uint f) {
  int fb = piv(p, PI_FACE_BASE);
  int o = 6 * (fb + int(f));
  dvec3 axis = dvec3(double(surf[o]), double(surf[o + 1]), double(surf[o + 2]));
  dvec3 nobj = pd3(p, PD_N);
  double c = axis.x * nobj.x + axis.y * nobj.y + axis.z * nobj.z;
  double lb = min(double(surf[o + 5]), double(surf[o + 3]) * sqrt(max(0.0lf, 1.0lf - c * c)) + double(surf[o + 4]));
  return lb / pdv(p, PD_CELL);
}

bool on_surface_path(int p, Tri T, out double L) {
  L = 0.0lf;
  if (piv(p, PI_SURFACE) == 0) return false;
  L = lateral_texels(p, T.f);
  return L > pdv(p, PD_TOL);
}

// Packed doubles in integer render targets and buffers.
uvec2 pack_d(double v) { return unpackDouble2x32(v); }
double unpack_d(uvec2 u) { return packDouble2x32(u); }
