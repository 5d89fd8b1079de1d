// The headless OpenGL 4.5 core context (hrt/gl_context.h):
// made through EGL with no display server, on whatever this machine has (in
// CI: Mesa's llvmpipe through the surfaceless platform), and shown to be a
// working context by a round trip through the GPU: a float framebuffer
// cleared and read back exactly, and a compute shader whose output is read
// back.
#include <gtest/gtest.h>

#include <epoxy/gl.h>

#include <cstdlib>
#include <string>
#include <vector>

#include "env_guard.h"
#include "hrt/gl_context.h"

TEST(GlContext, MakesAnOpenGL45CoreContextThatRendersAndComputes) {
  std::unique_ptr<hrt::gl::Context> ctx = hrt::gl::Context::create();
  const hrt::gl::ContextInfo& i = ctx->info();
  std::printf("GL: %s on %s (%s platform, EGL %s)\n", i.gl_version.c_str(), i.renderer.c_str(), i.platform.c_str(),
              i.egl_version.c_str());
  EXPECT_GE(i.gl_major * 10 + i.gl_minor, 45);
  EXPECT_FALSE(i.renderer.empty());
  EXPECT_EQ(i.hardware, !hrt::gl::is_software_renderer(i.renderer));
  ASSERT_TRUE(i.compute_shader);
  EXPECT_TRUE(i.query_buffer_object);
  GLint profile = 0;
  glGetIntegerv(GL_CONTEXT_PROFILE_MASK, &profile);
  EXPECT_TRUE(profile & GL_CONTEXT_CORE_PROFILE_BIT);

  // A 4 x 4 RGBA32F framebuffer cleared to values float32 holds exactly.
  GLuint tex = 0, fbo = 0;
  glGenTextures(1, &tex);
  glBindTexture(GL_TEXTURE_2D, tex);
  glTexStorage2D(GL_TEXTURE_2D, 1, GL_RGBA32F, 4, 4);
  glGenFramebuffers(1, &fbo);
  glBindFramebuffer(GL_FRAMEBUFFER, fbo);
  glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, tex, 0);
  ASSERT_EQ(glCheckFramebufferStatus(GL_FRAMEBUFFER), static_cast<GLenum>(GL_FRAMEBUFFER_COMPLETE));
  const float c[4] = {0.25f, -1.5f, 1e-3f, 12345.5f};
  glClearBufferfv(GL_COLOR, 0, c);
  std::vector<float> px(4 * 16, 0.0f);
  glReadPixels(0, 0, 4, 4, GL_RGBA, GL_FLOAT, px.data());
  for (int k = 0; k < 16; ++k)
    for (int ch = 0; ch < 4; ++ch) EXPECT_EQ(px[4 * k + ch], c[ch]) << k << " " << ch;

  // A compute shader writing i * i + 0.5 for 256 invocations into a buffer.
  const char* src =
      "#version 450\n"
      "layout(local_size_x = 64) in;\n"
      "layout(std430, binding = 0) buffer Out { float v[]; };\n"
      "void main() { uint i = gl_GlobalInvocationID.x; v[i] = float(i * i) + 0.5; }\n";
  GLuint sh = glCreateShader(GL_COMPUTE_SHADER);
  glShaderSource(sh, 1, &src, nullptr);
  glCompileShader(sh);
  GLint ok = 0;
  glGetShaderiv(sh, GL_COMPILE_STATUS, &ok);
  ASSERT_TRUE(ok);
  GLuint prog = glCreateProgram();
  glAttachShader(prog, sh);
  glLinkProgram(prog);
  glGetProgramiv(prog, GL_LINK_STATUS, &ok);
  ASSERT_TRUE(ok);
  GLuint buf = 0;
  glGenBuffers(1, &buf);
  glBindBuffer(GL_SHADER_STORAGE_BUFFER, buf);
  glBufferData(GL_SHADER_STORAGE_BUFFER, 256 * sizeof(float), nullptr, GL_DYNAMIC_READ);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, buf);
  glUseProgram(prog);
  glDispatchCompute(4, 1, 1);
  glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
  std::vector<float> out(256, -1.0f);
  glGetBufferSubData(GL_SHADER_STORAGE_BUFFER, 0, 256 * sizeof(float), out.data());
  for (int k = 0; k < 256; ++k) EXPECT_EQ(out[static_cast<size_t>(k)], static_cast<float>(k * k) + 0.5f) << k;
  EXPECT_EQ(glGetError(), static_cast<GLenum>(GL_NO_ERROR));
  glDeleteBuffers(1, &buf);
  glDeleteProgram(prog);
  glDeleteShader(sh);
  glDeleteFramebuffers(1, &fbo);
  glDeleteTextures(1, &tex);
}

TEST(GlContext, SurfacelessPlatformWorksWhenForced) {
  EnvGuard g("HRT_EGL_PLATFORM", "surfaceless");
  std::unique_ptr<hrt::gl::Context> ctx = hrt::gl::Context::create();
  EXPECT_EQ(ctx->info().platform, "surfaceless");
  EXPECT_GE(ctx->info().gl_major * 10 + ctx->info().gl_minor, 45);
}

TEST(GlContext, AnUnknownForcedPlatformIsAClearError) {
  EnvGuard g("HRT_EGL_PLATFORM", "wayland");
  try {
    hrt::gl::Context::create();
    FAIL() << "no error";
  } catch (const hrt::gl::GlError& e) {
    EXPECT_EQ(std::string(e.what()), "HRT_EGL_PLATFORM=wayland: not a platform (device or surfaceless)");
  }
}
