// The GL depth backend (hrt/gl_depth.h): height tiles rendered with the
// shaders of src/gl/shaders/, the re-solves and the max search on the GPU,
// the finite differences on the CPU (finish_depth_gradient, as the CPU
// backend). The CPU's plan of a patch (plan_depth, placement_params,
// resolve_motion in hrt/depth.h) is computed once here and handed to the
// shaders as placement records, so the two backends share every number
// that decides what is rasterized where.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include <epoxy/gl.h>

#include "depth/internal.h"
#include "depth/mesh_rows.h"
#include "hrt/gl_depth.h"

namespace hrt::gl {

const char* glsl_source(const char* name);  // generated from src/gl/shaders/ (cmake/embed_glsl.cmake)

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// Record layouts: kept in step with common.glsl and slots.glsl.
constexpr int kPD = 32, kPI = 24, kPF = 12, kSL = 16, kRS = 16;
enum : int {
  PD_GX = 0,
  PD_GY = 4,
  PD_N = 8,
  PD_TOL = 12,
  PD_CELL = 13,
  PD_CULL = 14,
  PD_HMIN = 15,
  PD_HSCALE = 16,
  PD_RM = 17
};
enum : int {
  PI_S = 0,
  PI_KEEP_MAX,
  PI_SURFACE,
  PI_TILE_X,
  PI_TILE_Y,
  PI_TRI_OFFSET,
  PI_TRI_COUNT,
  PI_VERT_BASE,
  PI_FACE_BASE,
  PI_ATLAS_W,
  PI_ATLAS_H,
  PI_USE_OK,
  PI_HAS_CULL,
  PI_N,
  PI_SEED_BORDER,
  PI_SEED_X,
  PI_SEED_Y,
  PI_OUT_OFFSET,
  PI_FACE_COUNT,
  PI_MESH_OFFSET,
  PI_MESH_COUNT
};
constexpr int kMI = 6;  // ints per mesh entry (mesh.glsl)
enum : int { PF_GX4 = 0, PF_GY4 = 4, PF_N4 = 8 };
enum : int {
  SL_KIND = 0,
  SL_AX,
  SL_AY,
  SL_BORDER,
  SL_DI,
  SL_DJ,
  SL_CFG,
  SL_BX,
  SL_BY,
  SL_N,
  SL_REGION,
  SL_DIFF_X,
  SL_DIFF_Y,
  SL_PLACE_B
};

using Clock = std::chrono::steady_clock;
double us_since(Clock::time_point t0) { return std::chrono::duration<double, std::micro>(Clock::now() - t0).count(); }

std::string shader_log(GLuint obj, bool program) {
  GLint n = 0;
  if (program)
    glGetProgramiv(obj, GL_INFO_LOG_LENGTH, &n);
  else
    glGetShaderiv(obj, GL_INFO_LOG_LENGTH, &n);
  std::string log(static_cast<size_t>(std::max(n, 1)), '\0');
  if (program)
    glGetProgramInfoLog(obj, n, nullptr, log.data());
  else
    glGetShaderInfoLog(obj, n, nullptr, log.data());
  // First line only: the message must stay one line.
  const size_t nl = log.find('\n');
  if (nl != std::string::npos) log.resize(nl);
  return log;
}

const char* source(const char* name) {
  const char* s = glsl_source(name);
  if (!s) throw GlError(std::string("GL depth backend: shader ") + name + " is not in the library (build error)");
  return s;
}

// A program from (stage, files) pairs; every stage gets "#version 450 core"
// and common.glsl first.
GLuint make_program(const char* what, std::initializer_list<std::pair<GLenum, std::vector<const char*>>> stages) {
  const GLuint prog = glCreateProgram();
  std::vector<GLuint> shaders;
  for (const auto& st : stages) {
    std::vector<const char*> parts{"#version 450 core\n", source("common.glsl")};
    for (const char* f : st.second) parts.push_back(source(f));
    const GLuint sh = glCreateShader(st.first);
    glShaderSource(sh, static_cast<GLsizei>(parts.size()), parts.data(), nullptr);
    glCompileShader(sh);
    GLint ok = 0;
    glGetShaderiv(sh, GL_COMPILE_STATUS, &ok);
    if (!ok) {
      const std::string log = shader_log(sh, false);
      glDeleteShader(sh);
      throw GlError(std::string("GL depth backend: the ") + what + " shader does not compile: " + log);
    }
    glAttachShader(prog, sh);
    shaders.push_back(sh);
  }
  glLinkProgram(prog);
  for (GLuint sh : shaders) glDeleteShader(sh);
  GLint ok = 0;
  glGetProgramiv(prog, GL_LINK_STATUS, &ok);
  if (!ok)
    throw GlError(std::string("GL depth backend: the ") + what + " program does not link: " + shader_log(prog, true));
  return prog;
}

GLuint make_texture(GLenum format, int w, int h) {
  GLuint t = 0;
  glCreateTextures(GL_TEXTURE_2D, 1, &t);
  glTextureStorage2D(t, 1, format, w, h);
  // texelFetch only; integer formats are incomplete with a linear filter.
  glTextureParameteri(t, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
  glTextureParameteri(t, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
  return t;
}

// Rows of square tiles packed left to right, top to bottom (deterministic).
struct Shelf {
  int size = 0, x = 0, y = 0, h = 0;
  bool place(int s, int& tx, int& ty) {
    if (s > size) return false;
    if (x + s > size) {
      y += h;
      x = 0;
      h = 0;
    }
    if (y + s > size) return false;
    tx = x, ty = y;
    x += s;
    h = std::max(h, s);
    return true;
  }
  int rows() const { return y + h; }
};

}  // namespace

struct GlDepthBackend::Impl {
  GlDepthOptions opt;
  GlDepthStats stats;
  struct ModelGpu {
    const Model* model = nullptr;
    int vert_base = 0, face_base = 0, face_count = 0;
    GLuint atlas = 0, ok = 0;
    double diag = 0;  // bounding-box diagonal (height range without a surface map)
  };
  std::vector<ModelGpu> models;
  GLuint buf_verts = 0, buf_faces = 0, buf_uvs = 0, buf_surf = 0;
  // Per-frame buffers, grown (rarely) by ensure().
  struct Buf {
    GLuint id = 0;
    size_t bytes = 0;
  };
  Buf tris, pd, pi, pf, cfg, slots, results, ranges, queries, meshb, meshdb;
  int target = 0;
  GLuint fbo = 0, tex_h = 0, tex_seed = 0, tex_jac = 0, tex_depth = 0;
  GLuint diff_fbo = 0, tex_diff = 0;
  GLuint vao = 0;
  GLuint prog_raster = 0, prog_resolve = 0, prog_reduce = 0, prog_diff = 0, prog_query = 0, prog_search = 0;
  GLuint prog_mesh = 0;
  std::vector<GLuint> query_ids;
  // Uniform locations, looked up once (a lookup per frame is a string search in the driver).
  struct Locations {
    GLint raster_place = -1, raster_target = -1, resolve_first = -1, reduce_first = -1, reduce_region = -1;
    GLint diff_slot = -1, diff_target = -1, diff_mode = -1, query_slot = -1, query_target = -1, query_mode = -1;
    GLint query_cov = -1, search_first = -1, search_count = -1, search_step = -1;
    GLint mesh_place = -1, mesh_target = -1;
  } loc;

  // The batch being built (CPU side; capacities kept between frames).
  struct JobInfo {
    int job = -1;
    DepthPlan plan;
    int N = 0;
    int first_slot = 0;
    int resolve_place = -1, resolve_count = 0;
    const ModelGpu* a = nullptr;
    double R = 0;
  };
  std::vector<JobInfo> batch;
  std::vector<double> pdv;
  std::vector<int> piv;
  std::vector<float> pfv;
  std::vector<uint32_t> trisv;
  std::vector<int> slotv;
  std::vector<double> rangev;
  std::vector<double> resultv;
  std::vector<int> render_places;  // placement indices drawn into the render target
  // HeightMode::mesh: placements drawn by the mesh program (placement, quads),
  // their face entries (kMI ints each), and the face lists with reach.
  std::vector<std::pair<int, int>> mesh_places;
  std::vector<int> meshv;
  std::vector<double> meshd;  // their half-planes, 3 doubles each
  std::vector<uint32_t> list_a, list_b;
  std::vector<const ModelGpu*> place_model;
  Shelf shelf, diff_shelf;
  size_t cfg_used = 0;
  std::vector<double> quantum;  // per job of the last evaluate()

  ~Impl() {
    GLuint bufs[] = {buf_verts, buf_faces, buf_uvs,    buf_surf,  tris.id,    pd.id,    pi.id,    pf.id,
                     cfg.id,    slots.id,  results.id, ranges.id, queries.id, meshb.id, meshdb.id};
    glDeleteBuffers(static_cast<GLsizei>(sizeof bufs / sizeof bufs[0]), bufs);
    for (ModelGpu& m : models) {
      glDeleteTextures(1, &m.atlas);
      glDeleteTextures(1, &m.ok);
    }
    GLuint texs[] = {tex_h, tex_seed, tex_jac, tex_depth, tex_diff};
    glDeleteTextures(5, texs);
    glDeleteFramebuffers(1, &fbo);
    glDeleteFramebuffers(1, &diff_fbo);
    glDeleteVertexArrays(1, &vao);
    for (GLuint p : {prog_raster, prog_resolve, prog_reduce, prog_diff, prog_query, prog_search, prog_mesh})
      glDeleteProgram(p);
    if (!query_ids.empty()) glDeleteQueries(static_cast<GLsizei>(query_ids.size()), query_ids.data());
  }

  void ensure(Buf& b, size_t bytes) {
    if (b.bytes >= bytes && b.id) return;
    const size_t grown = std::max(bytes, 2 * b.bytes);
    if (b.id) {
      glDeleteBuffers(1, &b.id);
      ++stats.buffer_growths;
    }
    glCreateBuffers(1, &b.id);
    glNamedBufferData(b.id, static_cast<GLsizeiptr>(grown), nullptr, GL_DYNAMIC_DRAW);
    b.bytes = grown;
  }

  void make_targets(int size) {
    GLuint texs[] = {tex_h, tex_seed, tex_jac, tex_depth, tex_diff};
    if (tex_h) glDeleteTextures(5, texs);
    if (fbo) glDeleteFramebuffers(1, &fbo);
    if (diff_fbo) glDeleteFramebuffers(1, &diff_fbo);
    target = size;
    tex_h = make_texture(GL_RG32UI, size, size);
    tex_seed = make_texture(GL_RGBA32UI, size, size);
    tex_jac = make_texture(GL_RGBA32F, size, size);
    tex_depth = make_texture(GL_DEPTH_COMPONENT32F, size, size);
    glCreateFramebuffers(1, &fbo);
    glNamedFramebufferTexture(fbo, GL_COLOR_ATTACHMENT0, tex_h, 0);
    glNamedFramebufferTexture(fbo, GL_COLOR_ATTACHMENT1, tex_seed, 0);
    glNamedFramebufferTexture(fbo, GL_COLOR_ATTACHMENT2, tex_jac, 0);
    glNamedFramebufferTexture(fbo, GL_DEPTH_ATTACHMENT, tex_depth, 0);
    const GLenum draw[] = {GL_COLOR_ATTACHMENT0, GL_COLOR_ATTACHMENT1, GL_COLOR_ATTACHMENT2};
    glNamedFramebufferDrawBuffers(fbo, 3, draw);
    if (glCheckNamedFramebufferStatus(fbo, GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
      throw GlError(
          "GL depth backend: the height render target (RG32UI + RGBA32UI + RGBA32F + D32F) is not complete here");
    tex_diff = make_texture(GL_DEPTH_COMPONENT32F, size, size);
    glCreateFramebuffers(1, &diff_fbo);
    glNamedFramebufferTexture(diff_fbo, GL_DEPTH_ATTACHMENT, tex_diff, 0);
    glNamedFramebufferDrawBuffer(diff_fbo, GL_NONE);
    if (glCheckNamedFramebufferStatus(diff_fbo, GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
      throw GlError("GL depth backend: the difference depth buffer (D32F) is not complete here");
  }

  const ModelGpu& model_of(const Model* m) const {
    for (const ModelGpu& g : models)
      if (g.model == m) return g;
    throw std::invalid_argument("GL depth backend: a patch's model was not given to the backend at construction");
  }

  // A placement record; returns its index.
  int add_place(const ModelGpu& mg, const PlacementParams& pp, const Window& w, int S, bool keep_max, int tx, int ty,
                int tri_offset, int tri_count, double cull, double hmin, double hmax) {
    const int p = static_cast<int>(place_model.size());
    place_model.push_back(&mg);
    pdv.resize(pdv.size() + kPD, 0.0);
    piv.resize(piv.size() + kPI, 0);
    pfv.resize(pfv.size() + kPF, 0.0f);
    double* d = &pdv[static_cast<size_t>(p) * kPD];
    int* i = &piv[static_cast<size_t>(p) * kPI];
    float* f = &pfv[static_cast<size_t>(p) * kPF];
    for (int k = 0; k < 3; ++k) {
      d[PD_GX + k] = pp.gx[k];
      d[PD_GY + k] = pp.gy[k];
      d[PD_N + k] = pp.nobj[k];
      f[PF_GX4 + k] = pp.gx4[k];
      f[PF_GY4 + k] = pp.gy4[k];
      f[PF_N4 + k] = pp.n4[k];
    }
    d[PD_GX + 3] = pp.ox, d[PD_GY + 3] = pp.oy, d[PD_N + 3] = pp.oh;
    d[PD_TOL] = pp.tol;
    d[PD_CELL] = w.cell;
    const bool has_cull = std::isfinite(cull);
    d[PD_CULL] = has_cull ? cull : 0.0;
    d[PD_HMIN] = hmin;
    d[PD_HSCALE] = (1.0 - std::ldexp(1.0, -19)) / std::max(hmax - hmin, 1e-300);
    const Model& M = *mg.model;
    i[PI_S] = S;
    i[PI_KEEP_MAX] = keep_max ? 1 : 0;
    i[PI_SURFACE] = pp.surface ? 1 : 0;
    i[PI_TILE_X] = tx, i[PI_TILE_Y] = ty;
    i[PI_TRI_OFFSET] = tri_offset, i[PI_TRI_COUNT] = tri_count;
    i[PI_VERT_BASE] = mg.vert_base, i[PI_FACE_BASE] = mg.face_base;
    i[PI_ATLAS_W] = M.atlas.width, i[PI_ATLAS_H] = M.atlas.height;
    i[PI_USE_OK] = pp.surface ? 1 : 0;
    i[PI_HAS_CULL] = has_cull ? 1 : 0;
    i[PI_N] = w.resolution;
    i[PI_FACE_COUNT] = mg.face_count;
    return p;
  }

  // The range of heights a placement's triangles can give (relative to n .
  // origin): corners +- the surface map's reach (or the model's diagonal
  // when it has no surface map), for the depth test's mapping.
  void height_range(const ModelGpu& mg, const PlacementParams& pp, const std::vector<uint32_t>& tris_list, double& lo,
                    double& hi, bool quads = false) const {
    const Model& M = *mg.model;
    lo = kInf, hi = -kInf;
    for (uint32_t f : tris_list) {
      if (f >= M.faces.size()) continue;
      const double r = !M.surface.ready ? mg.diag : quads ? M.surface.faces[f].quad_reach : M.surface.faces[f].reach;
      for (int c = 0; c < 3; ++c) {
        const double h = pp.nobj.dot(M.vertices[M.faces[f][c]]) + pp.oh;
        lo = std::min(lo, h - r);
        hi = std::max(hi, h + r);
      }
    }
    if (!(lo <= hi)) lo = -1.0, hi = 1.0;
    lo -= 1e-9, hi += 1e-9;
  }

  // The mesh heights' quads of one placement: per face that
  // raster_triangle_mesh does not skip whole (MeshRows::setup, the same code)
  // one entry, its rectangle of atlas quads, and its half-planes in meshd;
  // the vertex shader repeats MeshRows::range for the quad's row. Per face,
  // not per row, so the plan costs a few hundred operations per face (per row
  // it cost more than the draw). Appends to meshv and meshd; returns the
  // first entry, sets the entry and quad counts.
  int mesh_entries(const Model& M, const std::vector<uint32_t>& list, const PlacementParams& pp, int S, const Window& w,
                   bool keep_max, double cull, int& entries, int& items) {
    const int first = static_cast<int>(meshv.size() / kMI);
    entries = 0, items = 0;
    if (!M.surface.ready) return first;
    const double W = M.atlas.width, H = M.atlas.height;
    double planes[3 * MeshRows::kMaxPlanes];
    for (uint32_t f : list) {
      if (f >= M.faces.size()) continue;
      double x[3], y[3], ax[3], ay[3];
      for (int c = 0; c < 3; ++c) {  // raster_triangle's set-up
        const Vec3& P = M.vertices[M.faces[f][c]];
        x[c] = pp.gx.dot(P) + pp.ox;
        y[c] = pp.gy.dot(P) + pp.oy;
        ax[c] = static_cast<double>(M.uvs[f][c].x()) * W - 0.5;
        ay[c] = (1.0 - static_cast<double>(M.uvs[f][c].y())) * H - 0.5;
      }
      MeshRows rows;
      if (!rows.setup(M, f, pp.nobj, pp.oh, S, w.cell, keep_max, cull, x, y, ax, ay)) continue;
      const long long area = static_cast<long long>(rows.qi1 - rows.qi0 + 1) * (rows.qj1 - rows.qj0 + 1);
      if (area <= 0) continue;
      if (items + area > (1LL << 30))
        throw std::invalid_argument("GL depth backend: a patch's mesh heights would draw more than 2^30 atlas quads");
      const int nh = rows.planes(planes);
      const int offset = static_cast<int>(meshd.size() / 3);
      meshd.insert(meshd.end(), planes, planes + 3 * nh);
      meshv.insert(meshv.end(), {rows.qi0, rows.qi1, rows.qj0, items, offset, nh});
      items += static_cast<int>(area);
      ++entries;
    }
    return first;
  }

  // Placement p drawn by the mesh program: its quads (mesh_entries).
  void set_mesh(int p, const Model& M, const std::vector<uint32_t>& list, const PlacementParams& pp, int S,
                const Window& w, bool keep_max, double cull) {
    int entries = 0, items = 0;
    const int first = mesh_entries(M, list, pp, S, w, keep_max, cull, entries, items);
    int* i = &piv[static_cast<size_t>(p) * kPI];
    i[PI_MESH_OFFSET] = first, i[PI_MESH_COUNT] = entries;
    mesh_places.emplace_back(p, items);
  }

  void add_slot(int kind, int ax, int ay, int border, int di, int dj, int cfg_off, int bx, int by, int N, bool region,
                double R) {
    const size_t s = slotv.size() / kSL;
    slotv.resize(slotv.size() + kSL, 0);
    int* q = &slotv[s * kSL];
    q[SL_KIND] = kind, q[SL_AX] = ax, q[SL_AY] = ay, q[SL_BORDER] = border, q[SL_DI] = di, q[SL_DJ] = dj;
    q[SL_CFG] = cfg_off, q[SL_BX] = bx, q[SL_BY] = by, q[SL_N] = N, q[SL_REGION] = region ? 1 : 0;
    rangev.push_back(R);
    if (opt.search == MaxSearch::occlusion) {
      int tx = 0, ty = 0;
      diff_shelf.place(N, tx, ty);  // room checked by try_add
      q[SL_DIFF_X] = tx, q[SL_DIFF_Y] = ty;
    }
  }

  void begin_batch() {
    batch.clear();
    pdv.clear();
    piv.clear();
    pfv.clear();
    trisv.clear();
    slotv.clear();
    rangev.clear();
    render_places.clear();
    place_model.clear();
    mesh_places.clear();
    meshv.clear();
    meshd.clear();
    shelf = Shelf{target};
    diff_shelf = Shelf{target};
    cfg_used = 0;
  }

  // Adds job k to the batch; false when its tiles do not fit (the caller
  // flushes and retries on an empty batch).
  bool try_add(const DepthJob& job, int k, const ForceOptions& fo, DepthGradient& out_k) {
    const ContactPatch& patch = *job.patch;
    JobInfo ji;
    ji.job = k;
    if (!plan_depth(*job.a, job.pose_a, *job.b, job.pose_b, patch, fo, ji.plan)) {
      // compute_depth_gradient's unusable window: nothing covered.
      out_k = DepthGradient{};
      for (double& d : out_k.delta_at) d = -kInf;
      return true;
    }
    const int N = patch.window.resolution;
    ji.N = N;
    const DepthPlan& plan = ji.plan;
    const int b = plan.border;
    const int SA = N + 2 * b;
    // The mesh heights draw every configuration but the whole-texel
    // translations, shifts of A0 as on the CPU (compute_depth_gradient).
    const HeightMode mode = fo.heights;
    const bool mesh = mode == HeightMode::mesh;
    const bool mesh_shift = !plan.seeded && mesh && plan.shift_m > 0;
    // Room: B, A0, and A's other configurations when they are rasterized.
    const int rendered_extra = plan.seeded ? 0 : mesh_shift ? 6 : 10;
    int resolves = 0;
    if (plan.seeded)
      for (int c = 1; c < 11; ++c)
        if (!(plan.shift_m > 0 && c <= 4)) ++resolves;
    {
      Shelf trial = shelf;
      int tx = 0, ty = 0;
      bool fits = trial.place(N, tx, ty) && trial.place(SA, tx, ty);
      for (int r = 0; r < rendered_extra && fits; ++r) fits = trial.place(N, tx, ty);
      if (opt.search == MaxSearch::occlusion) {
        Shelf dtrial = diff_shelf;
        for (int c = 0; c < 11 && fits; ++c) fits = dtrial.place(N, tx, ty);
      }
      if (cfg_used + static_cast<size_t>(resolves) * N * N > cfg_capacity()) fits = false;
      if (!fits) return false;
    }
    const ModelGpu& ga = model_of(job.a);
    const ModelGpu& gb = model_of(job.b);
    ji.a = &ga;
    const Vec3 &n = patch.n, &u = patch.u, &v = patch.v;
    const Window& w = patch.window;
    // Triangle lists (the mesh heights: with the faces in reach).
    const std::vector<uint32_t>& la = height_faces(patch.tris_a, patch.reach_a, mode, list_a);
    const std::vector<uint32_t>& lb = height_faces(patch.tris_b, patch.reach_b, mode, list_b);
    const int oa = static_cast<int>(trisv.size());
    trisv.insert(trisv.end(), la.begin(), la.end());
    const int ob = static_cast<int>(trisv.size());
    trisv.insert(trisv.end(), lb.begin(), lb.end());
    const int na = static_cast<int>(la.size()), nb = static_cast<int>(lb.size());
    const bool mesh_a = mesh && job.a->surface.ready, mesh_b = mesh && job.b->surface.ready;
    // A placement drawn by the mesh program or the face raster.
    auto draw = [&](int p, bool is_a, const PlacementParams& pp, int S, double cull) {
      if (is_a ? mesh_a : mesh_b)
        set_mesh(p, is_a ? *job.a : *job.b, is_a ? la : lb, pp, S, w, is_a, cull);
      else
        render_places.push_back(p);
    };
    // B (min heights), then A at configuration 0.
    int bx = 0, by = 0, ax0 = 0, ay0 = 0;
    shelf.place(N, bx, by);
    const PlacementParams ppb = placement_params(*job.b, plan.world_from_b, n, u, v, w, 0, mode);
    double blo, bhi;
    height_range(gb, ppb, lb, blo, bhi, mesh);
    draw(add_place(gb, ppb, w, N, false, bx, by, ob, nb, plan.cull_b, blo, bhi), false, ppb, N, plan.cull_b);
    shelf.place(SA, ax0, ay0);
    const PlacementParams ppa = placement_params(*job.a, plan.world_from_a[0], n, u, v, w, b, mode);
    double alo, ahi;
    height_range(ga, ppa, la, alo, ahi, mesh);
    // Configurations move A by about a grid texel: two of margin.
    alo -= 2 * w.cell, ahi += 2 * w.cell;
    const double cull_a = plan.seeded || mesh ? plan.cull_a : std::numeric_limits<double>::quiet_NaN();
    draw(add_place(ga, ppa, w, SA, true, ax0, ay0, oa, na, cull_a, alo, ahi), true, ppa, SA, cull_a);
    ji.R = std::max(ahi, bhi) - std::min(alo, blo);
    ji.first_slot = static_cast<int>(slotv.size() / kSL);
    add_slot(0, ax0, ay0, b, 0, 0, 0, bx, by, N, true, ji.R);
    if (plan.seeded) {
      ji.resolve_place = static_cast<int>(place_model.size());
      for (int c = 1; c < 11; ++c) {
        const int m = plan.shift_m;
        if (m > 0 && c <= 4) {
          const int di = c == 1 ? m : c == 2 ? -m : 0, dj = c == 3 ? m : c == 4 ? -m : 0;
          add_slot(0, ax0, ay0, b, di, dj, 0, bx, by, N, false, ji.R);
          continue;
        }
        const PlacementParams ppc = placement_params(*job.a, plan.world_from_a[c], n, u, v, w, 0, HeightMode::surface);
        const int p = add_place(ga, ppc, w, N, true, 0, 0, oa, na, std::numeric_limits<double>::quiet_NaN(), alo, ahi);
        const ResolveMotion rm = resolve_motion(plan.world_from_a[c], plan.world_from_a[0], n, u, v, w);
        double* d = &pdv[static_cast<size_t>(p) * kPD];
        const double r8[8] = {rm.gx0, rm.gxi, rm.gxj, rm.gxh, rm.gy0, rm.gyi, rm.gyj, rm.gyh};
        std::copy(r8, r8 + 8, d + PD_RM);
        int* ip = &piv[static_cast<size_t>(p) * kPI];
        ip[PI_SEED_BORDER] = b, ip[PI_SEED_X] = ax0, ip[PI_SEED_Y] = ay0;
        ip[PI_OUT_OFFSET] = static_cast<int>(cfg_used);
        add_slot(2, 0, 0, 0, 0, 0, static_cast<int>(cfg_used), bx, by, N, false, ji.R);
        cfg_used += static_cast<size_t>(N) * N;
        ++ji.resolve_count;
      }
    } else {
      for (int c = 1; c < 11; ++c) {
        if (mesh_shift && c <= 4) {
          const int m = plan.shift_m;
          const int di = c == 1 ? m : c == 2 ? -m : 0, dj = c == 3 ? m : c == 4 ? -m : 0;
          add_slot(0, ax0, ay0, b, di, dj, 0, bx, by, N, false, ji.R);
          continue;
        }
        int tx = 0, ty = 0;
        shelf.place(N, tx, ty);
        const PlacementParams ppc = placement_params(*job.a, plan.world_from_a[c], n, u, v, w, 0, mode);
        const double cull_c = mesh ? cull_a : std::numeric_limits<double>::quiet_NaN();
        draw(add_place(ga, ppc, w, N, true, tx, ty, oa, na, cull_c, alo, ahi), true, ppc, N, cull_c);
        add_slot(1, tx, ty, 0, 0, 0, 0, bx, by, N, false, ji.R);
      }
    }
    batch.push_back(ji);
    return true;
  }

  size_t cfg_capacity() const { return cfg.bytes / 8; }

  void bind_model(const ModelGpu& m) {
    glBindTextureUnit(0, m.atlas);
    glBindTextureUnit(1, m.ok);
  }

  void flush(const ForceOptions& fo, DepthGradient* out) {
    if (batch.empty()) return;
    auto t0 = Clock::now();
    const size_t nslots = slotv.size() / kSL;
    ensure(tris, std::max<size_t>(4, trisv.size() * 4));
    ensure(pd, pdv.size() * 8);
    ensure(pi, piv.size() * 4);
    ensure(pf, pfv.size() * 4);
    ensure(slots, slotv.size() * 4);
    ensure(ranges, rangev.size() * 8);
    ensure(results, nslots * kRS * 8);
    ensure(queries, nslots * 4);
    ensure(meshb, std::max<size_t>(16, meshv.size() * 4));
    ensure(meshdb, std::max<size_t>(16, meshd.size() * 8));
    if (!meshv.empty()) glNamedBufferSubData(meshb.id, 0, static_cast<GLsizeiptr>(meshv.size() * 4), meshv.data());
    if (!meshd.empty()) glNamedBufferSubData(meshdb.id, 0, static_cast<GLsizeiptr>(meshd.size() * 8), meshd.data());
    if (trisv.size()) glNamedBufferSubData(tris.id, 0, static_cast<GLsizeiptr>(trisv.size() * 4), trisv.data());
    glNamedBufferSubData(pd.id, 0, static_cast<GLsizeiptr>(pdv.size() * 8), pdv.data());
    glNamedBufferSubData(pi.id, 0, static_cast<GLsizeiptr>(piv.size() * 4), piv.data());
    glNamedBufferSubData(pf.id, 0, static_cast<GLsizeiptr>(pfv.size() * 4), pfv.data());
    glNamedBufferSubData(slots.id, 0, static_cast<GLsizeiptr>(slotv.size() * 4), slotv.data());
    glNamedBufferSubData(ranges.id, 0, static_cast<GLsizeiptr>(rangev.size() * 8), rangev.data());
    GLuint model_bufs[4] = {buf_verts, buf_faces, buf_uvs, buf_surf};
    for (int k = 0; k < 4; ++k) glBindBufferBase(GL_SHADER_STORAGE_BUFFER, k, model_bufs[k]);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 4, tris.id);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 5, pd.id);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 6, pi.id);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 7, pf.id);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 8, cfg.id);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 9, slots.id);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 10, results.id);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 11, ranges.id);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 12, queries.id);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 13, meshb.id);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 14, meshdb.id);
    if (opt.profile) glFinish();
    stats.upload_us += us_since(t0);

    // Draw: every height tile of the batch into the render target.
    t0 = Clock::now();
    glBindVertexArray(vao);
    glBindFramebuffer(GL_FRAMEBUFFER, fbo);
    clear_depth(shelf.rows());
    glDepthFunc(GL_GREATER);
    glUseProgram(prog_raster);
    const GLint loc_place = loc.raster_place;
    glUniform2f(loc.raster_target, static_cast<float>(target), static_cast<float>(target));
    for (int p : render_places) {
      const int count = piv[static_cast<size_t>(p) * kPI + PI_TRI_COUNT];
      if (count <= 0) continue;
      bind_model(*place_model[static_cast<size_t>(p)]);
      glUniform1i(loc_place, p);
      glDrawArrays(GL_TRIANGLES, 0, 6 * count);
      ++stats.tiles;
    }
    if (!mesh_places.empty()) {  // the mesh heights: one point per atlas quad, into the same tiles
      glUseProgram(prog_mesh);
      glUniform2f(loc.mesh_target, static_cast<float>(target), static_cast<float>(target));
      for (const auto& [p, items] : mesh_places) {
        if (items <= 0) continue;
        bind_model(*place_model[static_cast<size_t>(p)]);
        glUniform1i(loc.mesh_place, p);
        glDrawArrays(GL_POINTS, 0, items);
        ++stats.tiles;
        stats.mesh_quads += items;
      }
    }
    if (opt.profile) glFinish();
    stats.draw_us += us_since(t0);

    // Resolve: A's re-solved configurations, one dispatch per patch.
    t0 = Clock::now();
    glBindTextureUnit(2, tex_h);
    glBindTextureUnit(3, tex_seed);
    glBindTextureUnit(4, tex_jac);
    glBindTextureUnit(5, tex_depth);
    glUseProgram(prog_resolve);
    const GLint loc_first = loc.resolve_first;
    bool any_resolve = false;
    for (const JobInfo& ji : batch) {
      if (ji.resolve_count <= 0) continue;
      bind_model(*ji.a);
      glUniform1i(loc_first, ji.resolve_place);
      glDispatchCompute(static_cast<GLuint>((ji.N + 7) / 8), static_cast<GLuint>((ji.N + 7) / 8),
                        static_cast<GLuint>(ji.resolve_count));
      any_resolve = true;
    }
    if (any_resolve) glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    if (opt.profile) glFinish();
    stats.resolve_us += us_since(t0);

    // Reduce (or search).
    t0 = Clock::now();
    const bool occl = opt.search == MaxSearch::occlusion;
    if (occl) occlusion_search(nslots);
    glUseProgram(prog_reduce);
    glUniform1i(loc.reduce_first, 0);
    glUniform1i(loc.reduce_region, occl ? 1 : 0);
    glDispatchCompute(static_cast<GLuint>(nslots), 1, 1);
    glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
    if (opt.profile) glFinish();
    stats.reduce_us += us_since(t0);

    // Read back: the one wait of the batch.
    t0 = Clock::now();
    resultv.resize(nslots * kRS);
    glGetNamedBufferSubData(results.id, 0, static_cast<GLsizeiptr>(resultv.size() * 8), resultv.data());
    ++stats.round_trips;
    ++stats.batches;
    stats.readback_us += us_since(t0);
    if (GLenum e = glGetError(); e != GL_NO_ERROR)
      throw GlError("GL depth backend: GL error 0x" + [&] {
        char b[16];
        std::snprintf(b, sizeof b, "%04x", e);
        return std::string(b);
      }() + " during a frame");

    for (const JobInfo& ji : batch) {
      DepthGradient& g = out[ji.job];
      g = DepthGradient{};
      g.lin_step = ji.plan.lin_step;
      g.ang_step = ji.plan.ang_step;
      const double q = std::ldexp(2.0 * ji.R, -opt.occlusion_steps);
      quantum[static_cast<size_t>(ji.job)] = occl ? q : 0.0;
      for (int c = 0; c < 11; ++c) {
        const double* r = &resultv[static_cast<size_t>(ji.first_slot + c) * kRS];
        const bool covered = r[1] > 0.5;
        if (!covered) {
          g.delta_at[c] = -kInf;
        } else if (occl) {
          g.delta_at[c] = 0.5 * (r[10] + r[11]) * 2.0 * ji.R - ji.R;
        } else {
          g.delta_at[c] = r[0];
        }
      }
      const double* r0 = &resultv[static_cast<size_t>(ji.first_slot) * kRS];
      const int cnt = static_cast<int>(r0[2]);
      if (g.delta_at[0] > -kInf && cnt > 0 && r0[3] > 0) {
        g.region_texels = cnt;
        g.region_center[0] = r0[4] / r0[3];
        g.region_center[1] = r0[5] / r0[3];
        g.region_lo[0] = r0[6], g.region_lo[1] = r0[7];
        g.region_hi[0] = r0[8] + 1, g.region_hi[1] = r0[9] + 1;
      }
      finish_depth_gradient(g);
    }
    (void)fo;
  }

  // The bound framebuffer's depth cleared to 0 (uncovered) over its first
  // `rows` rows (the used shelves: clearing all of it costs more than a small
  // frame on a software renderer), then the depth test on.
  void clear_depth(int rows) {
    glViewport(0, 0, target, target);
    glEnable(GL_SCISSOR_TEST);
    glScissor(0, 0, target, std::max(rows, 1));
    glDepthMask(GL_TRUE);
    glClearDepth(0.0);
    glClear(GL_DEPTH_BUFFER_BIT);
    glDisable(GL_SCISSOR_TEST);
    glEnable(GL_DEPTH_TEST);
  }

  void occlusion_search(size_t nslots) {
    if (query_ids.size() < nslots) {
      const size_t old = query_ids.size();
      query_ids.resize(std::max(nslots, 2 * old));
      glGenQueries(static_cast<GLsizei>(query_ids.size() - old), query_ids.data() + old);
      if (old) ++stats.buffer_growths;
    }
    // The differences, scaled into the depth buffer.
    glBindFramebuffer(GL_FRAMEBUFFER, diff_fbo);
    clear_depth(diff_shelf.rows());
    glDepthFunc(GL_ALWAYS);
    glBindTextureUnit(2, tex_h);
    glBindTextureUnit(5, tex_depth);
    glUseProgram(prog_diff);
    GLint loc_slot = loc.diff_slot;
    glUniform2f(loc.diff_target, static_cast<float>(target), static_cast<float>(target));
    glUniform1i(loc.diff_mode, 0);
    for (size_t s = 0; s < nslots; ++s) {
      glUniform1i(loc_slot, static_cast<GLint>(s));
      glDrawArrays(GL_TRIANGLE_STRIP, 0, 4);
    }
    // The search: step 0 the coverage query, then occlusion_steps halvings,
    // each one query per slot; results go to the query buffer on the GPU and
    // a compute pass halves the intervals there (no read-back until the end).
    glDepthMask(GL_FALSE);
    glDepthFunc(GL_LESS);
    glBindBuffer(GL_QUERY_BUFFER, queries.id);
    for (int step = 0; step <= opt.occlusion_steps; ++step) {
      glUseProgram(prog_query);
      loc_slot = loc.query_slot;
      glUniform2f(loc.query_target, static_cast<float>(target), static_cast<float>(target));
      glUniform1i(loc.query_mode, 1);
      glUniform1i(loc.query_cov, step == 0 ? 1 : 0);
      for (size_t s = 0; s < nslots; ++s) {
        glBeginQuery(GL_ANY_SAMPLES_PASSED, query_ids[s]);
        glUniform1i(loc_slot, static_cast<GLint>(s));
        glDrawArrays(GL_TRIANGLE_STRIP, 0, 4);
        glEndQuery(GL_ANY_SAMPLES_PASSED);
        ++stats.occlusion_queries;
      }
      for (size_t s = 0; s < nslots; ++s)
        glGetQueryObjectuiv(query_ids[s], GL_QUERY_RESULT, reinterpret_cast<GLuint*>(static_cast<uintptr_t>(4 * s)));
      glMemoryBarrier(GL_QUERY_BUFFER_BARRIER_BIT | GL_SHADER_STORAGE_BARRIER_BIT);
      glUseProgram(prog_search);
      glUniform1i(loc.search_first, 0);
      glUniform1i(loc.search_count, static_cast<GLint>(nslots));
      glUniform1i(loc.search_step, step);
      glDispatchCompute(static_cast<GLuint>((nslots + 63) / 64), 1, 1);
      glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_QUERY_BUFFER_BARRIER_BIT);
    }
    glBindBuffer(GL_QUERY_BUFFER, 0);
    glBindFramebuffer(GL_FRAMEBUFFER, fbo);
  }
};

GlDepthBackend::GlDepthBackend(Context& context, const std::vector<const Model*>& models, const GlDepthOptions& options)
    : impl_(std::make_unique<Impl>()) {
  Impl& I = *impl_;
  I.opt = options;
  const ContextInfo& info = context.info();
  if (!info.compute_shader) throw GlError("GL depth backend: the context has no compute shaders (GL 4.3)");
  if (!info.query_buffer_object) throw GlError("GL depth backend: the context has no query buffer objects (GL 4.4)");
  if (options.occlusion_steps < 1 || options.occlusion_steps > 23)
    throw std::invalid_argument("GL depth backend: occlusion_steps must be 1..23 (a float depth holds 24 bits)");
  if (options.target_size < 64 || options.target_size > info.max_texture_size)
    throw std::invalid_argument("GL depth backend: target_size must be 64.." + std::to_string(info.max_texture_size));

  // Models: meshes concatenated into four buffers, one atlas texture each.
  std::vector<double> verts;
  std::vector<uint32_t> faces;
  std::vector<float> uvs, surf;
  for (const Model* m : models) {
    bool seen = false;
    for (const auto& g : I.models) seen = seen || g.model == m;
    if (seen || !m) continue;
    if (m->atlas.width > info.max_texture_size || m->atlas.height > info.max_texture_size)
      throw GlError("GL depth backend: " + m->path + ": atlas " + std::to_string(m->atlas.width) + " x " +
                    std::to_string(m->atlas.height) + " exceeds this GL's texture limit " +
                    std::to_string(info.max_texture_size));
    Impl::ModelGpu g;
    g.model = m;
    g.vert_base = static_cast<int>(verts.size() / 3);
    g.face_base = static_cast<int>(faces.size() / 3);
    g.face_count = static_cast<int>(m->faces.size());
    Vec3 lo = Vec3::Constant(kInf), hi = -lo;
    for (const Vec3& p : m->vertices) {
      verts.insert(verts.end(), {p.x(), p.y(), p.z()});
      lo = lo.cwiseMin(p), hi = hi.cwiseMax(p);
    }
    g.diag = m->vertices.empty() ? 1.0 : (hi - lo).norm();
    for (size_t f = 0; f < m->faces.size(); ++f) {
      for (int c = 0; c < 3; ++c) {
        faces.push_back(m->faces[f][c]);
        uvs.push_back(m->uvs[f][c].x());
        uvs.push_back(m->uvs[f][c].y());
      }
      if (m->surface.ready) {
        const SurfaceMap::Face& sf = m->surface.faces[f];
        surf.insert(surf.end(), {sf.axis.x(), sf.axis.y(), sf.axis.z(), sf.along, sf.across, sf.reach});
      } else {
        surf.insert(surf.end(), {0.f, 0.f, 1.f, 0.f, 0.f, 0.f});
      }
    }
    const int W = std::max(m->atlas.width, 1), H = std::max(m->atlas.height, 1);
    g.atlas = make_texture(GL_RGBA32F, W, H);
    if (m->atlas.width > 0 && m->atlas.height > 0) {
      glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
      glTextureSubImage2D(g.atlas, 0, 0, 0, W, H, GL_RGBA, GL_FLOAT, m->atlas.rgba.data());
    }
    g.ok = make_texture(GL_R8UI, W, H);
    if (m->surface.ready && m->surface.quad_ok.size() == static_cast<size_t>(W) * H + SurfaceMap::kQuadOkPadding) {
      glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
      glTextureSubImage2D(g.ok, 0, 0, 0, W, H, GL_RED_INTEGER, GL_UNSIGNED_BYTE, m->surface.quad_ok.data());
      glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
    }
    I.models.push_back(g);
  }
  auto upload = [](GLuint& id, const void* data, size_t bytes) {
    glCreateBuffers(1, &id);
    glNamedBufferStorage(id, static_cast<GLsizeiptr>(std::max<size_t>(bytes, 16)), nullptr, GL_DYNAMIC_STORAGE_BIT);
    if (bytes) glNamedBufferSubData(id, 0, static_cast<GLsizeiptr>(bytes), data);
  };
  upload(I.buf_verts, verts.data(), verts.size() * 8);
  upload(I.buf_faces, faces.data(), faces.size() * 4);
  upload(I.buf_uvs, uvs.data(), uvs.size() * 4);
  upload(I.buf_surf, surf.data(), surf.size() * 4);

  I.make_targets(options.target_size);
  // Frame buffers sized for 32 patches of N = 128 with 22 placements each;
  // a larger frame grows them once (stats.buffer_growths).
  I.ensure(I.tris, 1u << 20);
  I.ensure(I.pd, 32 * 22 * kPD * 8);
  I.ensure(I.pi, 32 * 22 * kPI * 4);
  I.ensure(I.pf, 32 * 22 * kPF * 4);
  I.ensure(I.slots, 32 * 11 * kSL * 4);
  I.ensure(I.ranges, 32 * 11 * 8);
  I.ensure(I.results, 32 * 11 * kRS * 8);
  I.ensure(I.queries, 32 * 11 * 4);
  I.ensure(I.meshb, 1u << 16);
  I.ensure(I.meshdb, 1u << 16);
  I.ensure(I.cfg, static_cast<size_t>(options.target_size) * options.target_size * 8);
  I.stats.buffer_growths = 0;
  I.query_ids.resize(32 * 11);
  glGenQueries(static_cast<GLsizei>(I.query_ids.size()), I.query_ids.data());
  glCreateVertexArrays(1, &I.vao);
  glClipControl(GL_LOWER_LEFT, GL_ZERO_TO_ONE);

  I.prog_raster =
      make_program("height raster", {{GL_VERTEX_SHADER, {"raster.vert"}}, {GL_FRAGMENT_SHADER, {"raster.frag"}}});
  I.prog_resolve = make_program("re-solve", {{GL_COMPUTE_SHADER, {"resolve.comp"}}});
  I.prog_reduce = make_program("reduction", {{GL_COMPUTE_SHADER, {"slots.glsl", "reduce.comp"}}});
  I.prog_diff = make_program("difference", {{GL_VERTEX_SHADER, {"slots.glsl", "quad.vert"}},
                                            {GL_FRAGMENT_SHADER, {"slots.glsl", "diff.frag"}}});
  I.prog_query = make_program("occlusion query",
                              {{GL_VERTEX_SHADER, {"slots.glsl", "quad.vert"}}, {GL_FRAGMENT_SHADER, {"empty.frag"}}});
  I.prog_search = make_program("search step", {{GL_COMPUTE_SHADER, {"search.comp"}}});
  I.prog_mesh = make_program("mesh heights", {{GL_VERTEX_SHADER, {"mesh.glsl", "mesh.vert"}},
                                              {GL_GEOMETRY_SHADER, {"mesh.geom"}},
                                              {GL_FRAGMENT_SHADER, {"mesh.glsl", "mesh.frag"}}});
  auto& L = I.loc;
  L.raster_place = glGetUniformLocation(I.prog_raster, "u_place");
  L.raster_target = glGetUniformLocation(I.prog_raster, "u_target");
  L.resolve_first = glGetUniformLocation(I.prog_resolve, "u_first_place");
  L.reduce_first = glGetUniformLocation(I.prog_reduce, "u_first_slot");
  L.reduce_region = glGetUniformLocation(I.prog_reduce, "u_region_only");
  L.diff_slot = glGetUniformLocation(I.prog_diff, "u_slot");
  L.diff_target = glGetUniformLocation(I.prog_diff, "u_target");
  L.diff_mode = glGetUniformLocation(I.prog_diff, "u_depth_mode");
  L.query_slot = glGetUniformLocation(I.prog_query, "u_slot");
  L.query_target = glGetUniformLocation(I.prog_query, "u_target");
  L.query_mode = glGetUniformLocation(I.prog_query, "u_depth_mode");
  L.query_cov = glGetUniformLocation(I.prog_query, "u_coverage");
  L.search_first = glGetUniformLocation(I.prog_search, "u_first_slot");
  L.search_count = glGetUniformLocation(I.prog_search, "u_count");
  L.search_step = glGetUniformLocation(I.prog_search, "u_step");
  L.mesh_place = glGetUniformLocation(I.prog_mesh, "u_place");
  L.mesh_target = glGetUniformLocation(I.prog_mesh, "u_target");
  if (GLenum e = glGetError(); e != GL_NO_ERROR)
    throw GlError("GL depth backend: GL error " + std::to_string(e) + " while setting up");
}

GlDepthBackend::~GlDepthBackend() = default;

void GlDepthBackend::evaluate(const DepthJob* jobs, int count, const ForceOptions& opt, DepthGradient* out) {
  Impl& I = *impl_;
  if (opt.shortcut)
    throw std::invalid_argument(
        "the GL backend does not implement the Sec. 5.2 shortcut (--shortcut / shortcut = true); use the CPU backend");
  const auto t0 = Clock::now();
  const uint64_t growths = I.stats.buffer_growths;
  I.stats = GlDepthStats{};
  I.stats.buffer_growths = growths;
  I.quantum.assign(static_cast<size_t>(std::max(count, 0)), 0.0);
  I.begin_batch();
  for (int k = 0; k < count; ++k) {
    if (I.try_add(jobs[k], k, opt, out[k])) continue;
    I.flush(opt, out);
    I.begin_batch();
    if (I.try_add(jobs[k], k, opt, out[k])) continue;
    // One patch larger than the render target: grow it (once per size).
    const int N = jobs[k].patch->window.resolution;
    int need = I.target;
    while (need < 4 * (N + 2 * DepthScratch::kReservedBorder)) need *= 2;
    I.make_targets(need);
    I.ensure(I.cfg, static_cast<size_t>(need) * need * 8);
    ++I.stats.buffer_growths;
    I.begin_batch();
    if (!I.try_add(jobs[k], k, opt, out[k]))
      throw std::invalid_argument("GL depth backend: a patch of N = " + std::to_string(N) + " does not fit a " +
                                  std::to_string(need) + " render target");
  }
  I.flush(opt, out);
  I.stats.total_us = us_since(t0);
}

const GlDepthStats& GlDepthBackend::stats() const { return impl_->stats; }
const GlDepthOptions& GlDepthBackend::options() const { return impl_->opt; }
double GlDepthBackend::quantum(int job) const {
  return job >= 0 && static_cast<size_t>(job) < impl_->quantum.size() ? impl_->quantum[static_cast<size_t>(job)] : 0.0;
}

}  // namespace hrt::gl
