// The GL backend's entry points in a build without it (-DHRT_WITH_GL=OFF:
// no libepoxy, no EGL). Context::create throws GlError, so select_backend
// (select.cpp) gives the CPU backend for "cpu" and "auto" and the one-line
// error for "gl", as on a machine without OpenGL 4.5; nothing else can be
// reached without a Context.
#include <string>

#include "hrt/gl_context.h"
#include "hrt/gl_depth.h"

namespace hrt::gl {
namespace {
constexpr const char* kWithout =
    "this hrt was built without the GL backend (HRT_WITH_GL=OFF; rebuild with -DHRT_WITH_GL=ON and libepoxy)";
}  // namespace

struct GlDepthBackend::Impl {
  GlDepthStats stats;
  GlDepthOptions opt;
};

std::unique_ptr<Context> Context::create() { throw GlError(kWithout); }
Context::~Context() = default;
void Context::make_current() { throw GlError(kWithout); }

GlDepthBackend::GlDepthBackend(Context&, const std::vector<const Model*>&, const GlDepthOptions&) {
  throw GlError(kWithout);
}
GlDepthBackend::~GlDepthBackend() = default;
void GlDepthBackend::evaluate(const DepthJob*, int, const ForceOptions&, DepthGradient*) { throw GlError(kWithout); }
const GlDepthStats& GlDepthBackend::stats() const { return impl_->stats; }
const GlDepthOptions& GlDepthBackend::options() const { return impl_->opt; }
double GlDepthBackend::quantum(int) const { return 0.0; }

}  // namespace hrt::gl
