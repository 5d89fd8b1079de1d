// Headless OpenGL 4.5 core context through EGL: see hrt/gl_context.h.
#include <epoxy/egl.h>
#include <epoxy/gl.h>

#include <cstdlib>
#include <cstring>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "hrt/gl_context.h"

namespace hrt::gl {

namespace {

std::string egl_error_name(EGLint e) {
  switch (e) {
    case EGL_SUCCESS: return "EGL_SUCCESS";
    case EGL_NOT_INITIALIZED: return "EGL_NOT_INITIALIZED";
    case EGL_BAD_ACCESS: return "EGL_BAD_ACCESS";
    case EGL_BAD_ALLOC: return "EGL_BAD_ALLOC";
    case EGL_BAD_ATTRIBUTE: return "EGL_BAD_ATTRIBUTE";
    case EGL_BAD_CONFIG: return "EGL_BAD_CONFIG";
    case EGL_BAD_CONTEXT: return "EGL_BAD_CONTEXT";
    case EGL_BAD_DISPLAY: return "EGL_BAD_DISPLAY";
    case EGL_BAD_MATCH: return "EGL_BAD_MATCH";
    case EGL_BAD_PARAMETER: return "EGL_BAD_PARAMETER";
    default: return "EGL error " + std::to_string(e);
  }
}

bool has_word(const char* list, const char* word) {
  if (!list) return false;
  const size_t n = std::strlen(word);
  for (const char* p = list; (p = std::strstr(p, word)) != nullptr; p += n)
    if ((p == list || p[-1] == ' ') && (p[n] == ' ' || p[n] == '\0')) return true;
  return false;
}

const char* str(GLenum name) {
  const GLubyte* s = glGetString(name);
  return s ? reinterpret_cast<const char*>(s) : "";
}

// EGL does not count eglInitialize calls: one eglTerminate ends every context
// on the display, and the contexts of one process share it (one display per
// EGL device, one surfaceless display). So the live Contexts per display are
// counted, and a display is terminated only when none is left on it (several
// scenes with the GL backend in one process: the Python module).
std::mutex g_displays_mutex;
std::map<EGLDisplay, int> g_display_contexts;

void retain_display(EGLDisplay dpy) {
  std::lock_guard<std::mutex> lock(g_displays_mutex);
  ++g_display_contexts[dpy];
}

// Terminates `dpy` unless a live Context uses it; `drop`: one of them ends.
void release_display(EGLDisplay dpy, bool drop = false) {
  std::lock_guard<std::mutex> lock(g_displays_mutex);
  auto it = g_display_contexts.find(dpy);
  if (it != g_display_contexts.end() && drop && --it->second == 0) g_display_contexts.erase(it);
  if (g_display_contexts.count(dpy) == 0) eglTerminate(dpy);
}

// Initializes `dpy`, makes a 4.5 core context current on it, fills `info`.
// Returns the context, or nullptr with `why` set (the display is terminated).
EGLContext try_display(EGLDisplay dpy, const char* platform, ContextInfo& info, std::string& why) {
  EGLint major = 0, minor = 0;
  if (dpy == EGL_NO_DISPLAY || !eglInitialize(dpy, &major, &minor)) {
    why = std::string(platform) + ": eglInitialize failed (" + egl_error_name(eglGetError()) + ")";
    return nullptr;
  }
  if (!eglBindAPI(EGL_OPENGL_API)) {
    why = std::string(platform) + ": no desktop OpenGL API (" + egl_error_name(eglGetError()) + ")";
    release_display(dpy);
    return nullptr;
  }
  // No surface is ever drawn to (framebuffer objects only): any config with
  // OpenGL, or none at all where EGL_KHR_no_config_context is offered.
  const EGLint cattr[] = {EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT, EGL_NONE};
  EGLConfig cfg = nullptr;
  EGLint n = 0;
  eglChooseConfig(dpy, cattr, &cfg, 1, &n);
  const bool no_config = has_word(eglQueryString(dpy, EGL_EXTENSIONS), "EGL_KHR_no_config_context");
  if (n < 1 && !no_config) {
    why = std::string(platform) + ": no EGL config with OpenGL";
    release_display(dpy);
    return nullptr;
  }
  const EGLint attr[] = {
      EGL_CONTEXT_MAJOR_VERSION,           4,       EGL_CONTEXT_MINOR_VERSION, 5, EGL_CONTEXT_OPENGL_PROFILE_MASK,
      EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
  EGLContext ctx = eglCreateContext(dpy, n >= 1 ? cfg : EGL_NO_CONFIG_KHR, EGL_NO_CONTEXT, attr);
  if (ctx == EGL_NO_CONTEXT) {
    why = std::string(platform) + ": no OpenGL 4.5 core context (" + egl_error_name(eglGetError()) + ")";
    release_display(dpy);
    return nullptr;
  }
  if (!eglMakeCurrent(dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, ctx)) {
    why = std::string(platform) + ": the context cannot be made current without a surface (" +
          egl_error_name(eglGetError()) + ")";
    eglDestroyContext(dpy, ctx);
    release_display(dpy);
    return nullptr;
  }
  info = ContextInfo{};
  info.platform = platform;
  info.egl_version = std::to_string(major) + "." + std::to_string(minor);
  if (const char* v = eglQueryString(dpy, EGL_VENDOR)) info.egl_version += std::string(" ") + v;
  info.gl_version = str(GL_VERSION);
  info.renderer = str(GL_RENDERER);
  info.vendor = str(GL_VENDOR);
  info.glsl_version = str(GL_SHADING_LANGUAGE_VERSION);
  glGetIntegerv(GL_MAJOR_VERSION, &info.gl_major);
  glGetIntegerv(GL_MINOR_VERSION, &info.gl_minor);
  info.hardware = !is_software_renderer(info.renderer);
  const int v = info.gl_major * 10 + info.gl_minor;
  info.compute_shader = v >= 43 || epoxy_has_gl_extension("GL_ARB_compute_shader");
  info.query_buffer_object = v >= 44 || epoxy_has_gl_extension("GL_ARB_query_buffer_object");
  glGetIntegerv(GL_MAX_TEXTURE_SIZE, &info.max_texture_size);
  if (info.compute_shader)
    glGetIntegerv(GL_MAX_COMPUTE_WORK_GROUP_INVOCATIONS, &info.max_compute_work_group_invocations);
  if (v < 45) {
    why = std::string(platform) + ": the context is OpenGL " + info.gl_version + ", 4.5 is needed";
    eglMakeCurrent(dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    eglDestroyContext(dpy, ctx);
    release_display(dpy);
    return nullptr;
  }
  return ctx;
}

}  // namespace

std::unique_ptr<Context> Context::create() {
  const char* forced = std::getenv("HRT_EGL_PLATFORM");
  const std::string only = forced ? forced : "";
  if (!only.empty() && only != "device" && only != "surfaceless")
    throw GlError("HRT_EGL_PLATFORM=" + only + ": not a platform (device or surfaceless)");
  const char* client = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
  if (!client) throw GlError("EGL: no client extensions (libEGL without EGL_EXT_client_extensions; install libegl1)");
  std::unique_ptr<Context> out(new Context());
  std::vector<std::string> tried;

  // 1. EGL devices (a GPU), keeping a hardware renderer.
  if (only != "surfaceless" && has_word(client, "EGL_EXT_device_enumeration") &&
      has_word(client, "EGL_EXT_platform_device")) {
    EGLDeviceEXT devices[16];
    EGLint count = 0;
    if (eglQueryDevicesEXT(16, devices, &count)) {
      for (EGLint i = 0; i < count; ++i) {
        EGLDisplay dpy = eglGetPlatformDisplayEXT(EGL_PLATFORM_DEVICE_EXT, devices[i], nullptr);
        std::string why;
        ContextInfo info;
        EGLContext ctx = try_display(dpy, "device", info, why);
        if (!ctx) {
          tried.push_back(why + " (device " + std::to_string(i) + ")");
          continue;
        }
        if (info.hardware || only == "device") {
          retain_display(dpy);
          out->display_ = dpy;
          out->context_ = ctx;
          out->info_ = info;
          return out;
        }
        tried.push_back("device " + std::to_string(i) + ": " + info.renderer + " is a software renderer");
        eglMakeCurrent(dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
        eglDestroyContext(dpy, ctx);
        release_display(dpy);
      }
    } else {
      tried.push_back("device: eglQueryDevicesEXT failed");
    }
  } else if (only != "surfaceless") {
    tried.push_back("device: no EGL_EXT_device_enumeration / EGL_EXT_platform_device");
  }

  // 2. Mesa's surfaceless platform (llvmpipe without a GPU).
  if (only != "device") {
    if (has_word(client, "EGL_MESA_platform_surfaceless")) {
      EGLDisplay dpy = eglGetPlatformDisplayEXT(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr);
      std::string why;
      ContextInfo info;
      if (EGLContext ctx = try_display(dpy, "surfaceless", info, why)) {
        retain_display(dpy);
        out->display_ = dpy;
        out->context_ = ctx;
        out->info_ = info;
        return out;
      }
      tried.push_back(why);
    } else {
      tried.push_back("surfaceless: no EGL_MESA_platform_surfaceless (Debian: libegl-mesa0)");
    }
  }
  std::string msg = "EGL: no OpenGL 4.5 core context";
  for (const std::string& t : tried) msg += "; " + t;
  throw GlError(msg + " (Debian: libegl-mesa0 libgl1-mesa-dri, or an NVIDIA driver)");
}

Context::~Context() {
  EGLDisplay dpy = static_cast<EGLDisplay>(display_);
  if (!dpy) return;
  eglMakeCurrent(dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
  if (context_) eglDestroyContext(dpy, static_cast<EGLContext>(context_));
  release_display(dpy, true);
}

void Context::make_current() {
  if (!eglMakeCurrent(static_cast<EGLDisplay>(display_), EGL_NO_SURFACE, EGL_NO_SURFACE,
                      static_cast<EGLContext>(context_)))
    throw GlError("EGL: eglMakeCurrent failed (" + egl_error_name(eglGetError()) + ")");
}

}  // namespace hrt::gl
