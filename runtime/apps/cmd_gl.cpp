// `hrt gl-info [--json]`: makes the headless OpenGL 4.5 core context the GL
// backend of the penetration query will use (hrt/gl_context.h: an EGL device,
// else Mesa's surfaceless platform) and says what it is: platform, renderer,
// versions, whether it is a hardware renderer, and the features the backend
// needs (compute shaders, query buffer objects). Exit 7 with one line naming
// what is missing when no context can be made.
#include <cstdio>
#include <memory>
#include <string>

#include <nlohmann/json.hpp>

#include "commands.h"
#include "hrt/gl_context.h"

namespace hrt_cli {

void register_gl_info(CLI::App& app) {
  auto json = std::make_shared<bool>(false);
  CLI::App* sub = app.add_subcommand("gl-info", "Make the headless OpenGL 4.5 context (EGL) and describe it");
  sub->add_flag("--json", *json, "Print the description as JSON");
  sub->callback([json]() {
    std::unique_ptr<hrt::gl::Context> ctx;
    try {
      ctx = hrt::gl::Context::create();
    } catch (const hrt::gl::GlError& e) {
      throw Exit(kGl, std::string("error: ") + e.what());
    }
    const hrt::gl::ContextInfo& i = ctx->info();
    if (*json) {
      nlohmann::json j = {{"platform", i.platform},
                          {"egl_version", i.egl_version},
                          {"gl_version", i.gl_version},
                          {"gl_major", i.gl_major},
                          {"gl_minor", i.gl_minor},
                          {"glsl_version", i.glsl_version},
                          {"renderer", i.renderer},
                          {"vendor", i.vendor},
                          {"hardware", i.hardware},
                          {"compute_shader", i.compute_shader},
                          {"query_buffer_object", i.query_buffer_object},
                          {"max_texture_size", i.max_texture_size},
                          {"max_compute_work_group_invocations", i.max_compute_work_group_invocations}};
      std::printf("%s\n", j.dump(2).c_str());
      return;
    }
    std::printf("OpenGL %s (GLSL %s) on %s, %s renderer, via EGL %s (%s platform)\n", i.gl_version.c_str(),
                i.glsl_version.c_str(), i.renderer.c_str(), i.hardware ? "a hardware" : "a software",
                i.egl_version.c_str(), i.platform.c_str());
    std::printf("  compute shaders %s, query buffer objects %s, max texture %d, max compute invocations %d\n",
                i.compute_shader ? "yes" : "no", i.query_buffer_object ? "yes" : "no", i.max_texture_size,
                i.max_compute_work_group_invocations);
  });
}

}  // namespace hrt_cli
