// A headless OpenGL 4.5 core context through EGL: no
// window, no display server. Two ways in, tried in this order:
//   device       EGL_EXT_device_enumeration + EGL_EXT_platform_device: each
//                EGL device in turn (an NVIDIA GPU, a Mesa render node, Mesa's
//                software device), keeping the first that gives a context on
//                a hardware renderer;
//   surfaceless  EGL_MESA_platform_surfaceless (Mesa; llvmpipe when there is
//                no GPU, which is what CI has).
// HRT_EGL_PLATFORM=device|surfaceless forces one. Function pointers are
// loaded by libepoxy. The context is current on the thread that created it
// (make_current() moves it); GL calls are made on one thread only.
#pragma once

#include <memory>
#include <stdexcept>
#include <string>

namespace hrt::gl {

// One line naming what is missing ("EGL: no EGL_MESA_platform_surfaceless
// and no EGL device gave an OpenGL 4.5 core context (...)").
struct GlError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

struct ContextInfo {
  std::string platform;      // "device" or "surfaceless"
  std::string egl_version;   // e.g. "1.5 Mesa Project"
  std::string gl_version;    // GL_VERSION
  std::string renderer;      // GL_RENDERER
  std::string vendor;        // GL_VENDOR
  std::string glsl_version;  // GL_SHADING_LANGUAGE_VERSION
  int gl_major = 0, gl_minor = 0;
  bool hardware = false;             // not a software rasterizer (llvmpipe, softpipe, SwiftShader)
  bool compute_shader = false;       // GL 4.3 / ARB_compute_shader
  bool query_buffer_object = false;  // GL 4.4 / ARB_query_buffer_object
  int max_texture_size = 0;
  int max_compute_work_group_invocations = 0;
};

class Context {
 public:
  // Throws GlError when no OpenGL 4.5 core context can be made.
  static std::unique_ptr<Context> create();
  ~Context();
  Context(const Context&) = delete;
  Context& operator=(const Context&) = delete;

  const ContextInfo& info() const { return info_; }
  void make_current();  // on the calling thread (throws GlError)

 private:
  Context() = default;
  void* display_ = nullptr;  // EGLDisplay
  void* context_ = nullptr;  // EGLContext
  ContextInfo info_;
};

// True for the renderer strings of software rasterizers.
bool is_software_renderer(const std::string& renderer);

}  // namespace hrt::gl
