// select_backend (hrt/gl_depth.h): cpu, gl, or auto with the start-up probe.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include "hrt/gl_depth.h"
#include "hrt/scene.h"

namespace hrt::gl {
namespace {

// A synthetic patch for the probe: A's lowest faces over B's highest, along
// -z, A placed so that its bounding box's bottom centre sits 1 % of B's
// height inside B's top centre. It need not be a physical contact: it times
// the same work a real patch of these models costs (both backends rasterize
// the same triangles over the same window).
bool probe_job(const Model& A, const Model& B, int N, ContactPatch& patch, Pose& pa, Pose& pb) {
  if (A.vertices.empty() || B.vertices.empty() || N <= 0) return false;
  Vec3 alo = Vec3::Constant(std::numeric_limits<double>::infinity()), ahi = -alo, blo = alo, bhi = -alo;
  for (const Vec3& p : A.vertices) alo = alo.cwiseMin(p), ahi = ahi.cwiseMax(p);
  for (const Vec3& p : B.vertices) blo = blo.cwiseMin(p), bhi = bhi.cwiseMax(p);
  const double side = std::min({ahi.x() - alo.x(), ahi.y() - alo.y(), bhi.x() - blo.x(), bhi.y() - blo.y()});
  if (!(side > 0)) return false;
  pb = Pose{};
  pa = Pose{};
  const Vec3 top_b(0.5 * (blo.x() + bhi.x()), 0.5 * (blo.y() + bhi.y()), bhi.z());
  const Vec3 bottom_a(0.5 * (alo.x() + ahi.x()), 0.5 * (alo.y() + ahi.y()), alo.z());
  pa.position = top_b - bottom_a - Vec3(0, 0, 0.01 * (bhi.z() - blo.z()));
  patch = ContactPatch{};
  patch.object_b = 1;
  patch.n = Vec3(0, 0, -1);
  patch.u = Vec3(1, 0, 0);
  patch.v = patch.n.cross(patch.u);  // {u, v, n} right-handed
  patch.window.resolution = N;
  patch.window.cell = 0.5 * side / N;
  patch.window.origin = top_b - 0.5 * N * patch.window.cell * (patch.u + patch.v);
  for (uint32_t f = 0; f < A.faces.size(); ++f)
    if (A.face_normals[f].dot(patch.n) > 0.5) patch.tris_a.push_back(f);
  for (uint32_t f = 0; f < B.faces.size(); ++f)
    if (B.face_normals[f].dot(patch.n) < -0.5) patch.tris_b.push_back(f);
  return !patch.tris_a.empty() && !patch.tris_b.empty();
}

double median_us(DepthBackend& backend, const DepthJob* jobs, int count, const ForceOptions& opt, int reps) {
  std::vector<DepthGradient> out(static_cast<size_t>(count));
  std::vector<double> t;
  for (int r = 0; r < reps + 1; ++r) {  // the first is a warm-up
    const auto t0 = std::chrono::steady_clock::now();
    backend.evaluate(jobs, count, opt, out.data());
    const auto t1 = std::chrono::steady_clock::now();
    if (r > 0) t.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
  }
  std::sort(t.begin(), t.end());
  return t[t.size() / 2];
}

}  // namespace

// Here, not in context.cpp, so that a build without GL (src/gl/none) has it too.
bool is_software_renderer(const std::string& r) {
  for (const char* s : {"llvmpipe", "softpipe", "SwiftShader", "Software Rasterizer"})
    if (r.find(s) != std::string::npos) return true;
  return false;
}

BackendSelection select_backend(BackendChoice choice, const std::vector<const Model*>& models,
                                const SceneOptions& scene_options, const GlDepthOptions& gl_options) {
  BackendSelection sel;
  // Options only the CPU backend implements (GlDepthBackend::evaluate would
  // refuse the first patch): gl is refused here, auto keeps to the cpu.
  const char* cpu_only = scene_options.force.shortcut ? "the Sec. 5.2 shortcut" : nullptr;
  if (cpu_only && choice == BackendChoice::gl)
    throw std::invalid_argument(std::string("the gl backend does not implement ") + cpu_only + "; use the cpu backend");
  if (cpu_only && choice == BackendChoice::automatic) {
    sel.backend = std::make_unique<CpuDepthBackend>();
    sel.message = std::string("backend: auto -> cpu (") + cpu_only + " is implemented by the CPU backend only)";
    return sel;
  }
  if (choice == BackendChoice::cpu) {
    sel.backend = std::make_unique<CpuDepthBackend>();
    sel.message = "backend: cpu";
    return sel;
  }
  if (choice == BackendChoice::gl) {
    sel.context = Context::create();  // throws GlError naming what is missing
    sel.backend = std::make_unique<GlDepthBackend>(*sel.context, models, gl_options);
    sel.message = "backend: gl on " + sel.context->info().renderer;
    return sel;
  }
  // auto
  std::unique_ptr<Context> ctx;
  try {
    ctx = Context::create();
  } catch (const GlError& e) {
    sel.backend = std::make_unique<CpuDepthBackend>();
    sel.message = std::string("backend: auto -> cpu (no GL context: ") + e.what() + ")";
    return sel;
  }
  const char* force_probe = std::getenv("HRT_GL_PROBE");
  const bool always = force_probe && std::strcmp(force_probe, "always") == 0;
  if (!ctx->info().hardware && !always) {
    sel.backend = std::make_unique<CpuDepthBackend>();
    sel.message = "backend: auto -> cpu (" + ctx->info().renderer + " is a software renderer)";
    return sel;
  }
  std::unique_ptr<GlDepthBackend> gl;
  try {
    gl = std::make_unique<GlDepthBackend>(*ctx, models, gl_options);
  } catch (const GlError& e) {
    sel.backend = std::make_unique<CpuDepthBackend>();
    sel.message = std::string("backend: auto -> cpu (") + e.what() + ")";
    return sel;
  }
  // The probe: a 7-patch frame (the paper's Fig. 9 scene has up to 7) of
  // the synthetic patch, 15 timed repetitions on each backend, medians.
  ContactPatch patch;
  Pose pa, pb;
  const bool have =
      models.size() >= 2 && probe_job(*models[0], *models[1], scene_options.force.resolution, patch, pa, pb);
  if (!have) {
    sel.backend = std::make_unique<CpuDepthBackend>();
    sel.message = "backend: auto -> cpu (no probe patch could be made from the first two models)";
    return sel;
  }
  std::vector<DepthJob> jobs(7);
  for (DepthJob& j : jobs) j = DepthJob{models[0], models[1], pa, pb, &patch};
  ForceOptions opt = scene_options.force;
  opt.shortcut = false;
  CpuDepthBackend cpu;
  const double t_cpu = median_us(cpu, jobs.data(), 7, opt, 15);
  const double t_gl = median_us(*gl, jobs.data(), 7, opt, 15);
  char buf[160];
  std::snprintf(buf, sizeof buf, "probe, 7 patches at N = %d: gl %.0f us, cpu %.0f us", opt.resolution, t_gl, t_cpu);
  if (t_gl < t_cpu) {
    sel.context = std::move(ctx);
    sel.backend = std::move(gl);
    sel.message = "backend: auto -> gl on " + sel.context->info().renderer + " (" + buf + ")";
  } else {
    sel.backend = std::make_unique<CpuDepthBackend>();
    sel.message = "backend: auto -> cpu (" + std::string(buf) + ")";
  }
  return sel;
}

}  // namespace hrt::gl
