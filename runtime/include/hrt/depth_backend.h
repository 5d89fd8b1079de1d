// Where the penetration query of a frame runs: the CPU code of
// hrt/depth.h (the reference), or the GLSL backend of hrt/gl_depth.h. Both
// compute, for each contact patch of a frame, the same DepthGradient
// (delta at the 11 configurations of Eq. 7, its gradient and the contact
// region); the force model (Eq. 5-7) and the safety checks then run on the
// CPU for either (apply_depth_gradient, frame()).
//
// frame() uses State::depth_backend when it is set (non-owning) and the CPU
// code inline otherwise; a backend evaluates all patches of a frame in one
// call, which is what lets the GL backend tile them into one render target.
#pragma once

#include <memory>
#include <string>

#include "hrt/depth.h"

namespace hrt {

// One patch of a frame for a backend: the two models, their poses and the
// patch's frozen contact data (n, u, v, window, triangle lists).
struct DepthJob {
  const Model* a = nullptr;
  const Model* b = nullptr;
  Pose pose_a, pose_b;
  const ContactPatch* patch = nullptr;
};

class DepthBackend {
 public:
  virtual ~DepthBackend() = default;
  // "cpu" or "gl".
  virtual const char* name() const = 0;
  // out[k] = compute_depth_gradient(jobs[k], opt) for k < count, as the CPU
  // computes it (the GL backend within the tolerances of docs/gl-backend.md).
  // Throws std::invalid_argument for options the backend does not implement.
  virtual void evaluate(const DepthJob* jobs, int count, const ForceOptions& opt, DepthGradient* out) = 0;
};

// The CPU code of hrt/depth.h behind the interface (one DepthScratch).
class CpuDepthBackend final : public DepthBackend {
 public:
  const char* name() const override { return "cpu"; }
  void evaluate(const DepthJob* jobs, int count, const ForceOptions& opt, DepthGradient* out) override;

 private:
  DepthScratch scratch_;
};

// The backend choice of `hrt query|bench|run --backend` and the scene file.
enum class BackendChoice { cpu, gl, automatic };
// "cpu", "gl", "auto" -> choice; false for anything else.
bool parse_backend_choice(const std::string& text, BackendChoice& out);

}  // namespace hrt
