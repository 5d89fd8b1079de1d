// The GLSL backend of the penetration query (paper Sec. 5.2).
//
// Per frame, for all contact patches at once:
//   1. upload    the patches' placements and triangle lists (one buffer
//                update each; the atlases went up once, at construction);
//   2. draw      each patch's height maps rendered into tiles of one render
//                target (Fig. 5): B's coarse triangles and A's at
//                configuration 0 (and, when the CPU rasterizes them, A's other
//                configurations), orthographic along n over the window's
//                lattice. The fragment shader repeats the CPU's arithmetic
//                (src/depth/raster.cpp): the same coverage rule, the atlas
//                read with texelFetch and bilinear weights in the shader, the
//                surface mode's fixed point with the same start and stop; the
//                depth test keeps A's highest and B's lowest point per texel;
//                heights are written as doubles relative to n . window origin;
//   3. resolve   A's rotated configurations re-solved from configuration 0's
//                seeds (compute shader, as resolve_heights);
//   4. reduce    delta at the 11 configurations, by one of
//                  compute    a compute-shader max reduction per (patch,
//                             configuration), exact up to the heights' own
//                             rounding (default);
//                  occlusion  the paper's search: differences scaled into a
//                             depth buffer, then `occlusion_steps` passes of
//                             one occlusion query per (patch, configuration),
//                             all in parallel, the query results kept on the
//                             GPU (ARB_query_buffer_object) and the intervals
//                             updated by a compute shader; delta within one
//                             depth quantum 2 R / 2^steps (R per patch: the
//                             span of its heights);
//                and the contact region of configuration 0 (compute);
//   5. read back the results: one round trip per batch (a frame is one batch
//                unless its tiles overflow the render target).
// Then finish_depth_gradient on the CPU, as the CPU backend does.
//
// Everything (programs, textures, buffers) is made at construction for the
// scene's options; a frame allocates nothing unless it needs more triangle or
// placement room than any before (counted in GlDepthStats::buffer_growths).
// The context must be current on the calling thread.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "hrt/depth_backend.h"
#include "hrt/gl_context.h"

namespace hrt {
struct SceneOptions;
}

namespace hrt::gl {

enum class MaxSearch { compute, occlusion };

struct GlDepthOptions {
  MaxSearch search = MaxSearch::compute;
  // Binary-search passes of the occlusion search (the paper's 16-bit depth
  // buffer: 16). 1..23: the thresholds k / 2^steps must be exact in a float
  // depth (24 bits of mantissa).
  int occlusion_steps = 16;
  // Side of the square render target the tiles are packed into (texels).
  // A frame whose tiles do not fit runs in several batches.
  int target_size = 1024;
  // Wait for the GPU after each stage so that GlDepthStats splits the time
  // (benchmarks); off, only the total and the read-back are timed.
  bool profile = false;
};

// Of the last evaluate() call (times in microseconds, wall clock).
struct GlDepthStats {
  double upload_us = 0, draw_us = 0, resolve_us = 0, reduce_us = 0, readback_us = 0, total_us = 0;
  int batches = 0;         // render-target fills
  int round_trips = 0;     // waits for GPU results (read-backs)
  int tiles = 0;           // height tiles rendered
  int64_t mesh_quads = 0;  // atlas quads submitted by the mesh heights (HeightMode::mesh)
  int occlusion_queries = 0;
  uint64_t buffer_growths = 0;  // since construction
};

class GlDepthBackend final : public DepthBackend {
 public:
  // `models`: every model the scene can evaluate (atlases and meshes are
  // uploaded here, once). Throws GlError when the context lacks what the
  // backend needs (compute shaders, fp64, query buffer objects).
  GlDepthBackend(Context& context, const std::vector<const Model*>& models, const GlDepthOptions& options = {});
  ~GlDepthBackend() override;

  const char* name() const override { return "gl"; }
  // Throws std::invalid_argument for opt.shortcut (the Sec. 5.2 resampling
  // shortcut is implemented by the CPU backend only) and for a model not
  // given at construction.
  void evaluate(const DepthJob* jobs, int count, const ForceOptions& opt, DepthGradient* out) override;

  const GlDepthStats& stats() const;
  const GlDepthOptions& options() const;
  // The occlusion search's depth quantum for a patch of the last frame (m):
  // 2 R / 2^occlusion_steps; 0 for the compute reduction.
  double quantum(int job) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// The backend `hrt query|bench|run` use for a choice (BackendChoice):
//   cpu   the CPU backend;
//   gl    a context (Context::create) and GlDepthBackend; throws GlError with
//         the line naming what is missing;
//   auto  GL only when the context is on a hardware renderer and the GL
//         backend beats the CPU in a short probe (a synthetic patch of the
//         first two models, timed on both), else the CPU. llvmpipe is never
//         probed (it is a CPU rasterizer); HRT_GL_PROBE=always probes it
//         anyway (tests).
// `message` says which was chosen and why, in one line.
struct BackendSelection {
  std::unique_ptr<Context> context;
  std::unique_ptr<DepthBackend> backend;
  std::string message;
};
BackendSelection select_backend(BackendChoice choice, const std::vector<const Model*>& models,
                                const SceneOptions& scene_options, const GlDepthOptions& gl_options = {});

}  // namespace hrt::gl
