// The CPU backend behind hrt/depth_backend.h's interface, and the choice's
// parser.
#include "hrt/depth_backend.h"

namespace hrt {

void CpuDepthBackend::evaluate(const DepthJob* jobs, int count, const ForceOptions& opt, DepthGradient* out) {
  for (int k = 0; k < count; ++k)
    out[k] = compute_depth_gradient(*jobs[k].a, jobs[k].pose_a, *jobs[k].b, jobs[k].pose_b, *jobs[k].patch, opt,
                                    scratch_);
}

bool parse_backend_choice(const std::string& text, BackendChoice& out) {
  if (text == "cpu") out = BackendChoice::cpu;
  else if (text == "gl") out = BackendChoice::gl;
  else if (text == "auto") out = BackendChoice::automatic;
  else return false;
  return true;
}

}  // namespace hrt
