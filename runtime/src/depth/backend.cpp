// The CPU backend behind hrt/depth_backend.h's interface, and the parsers of
// the backend choice and the heights mode.
#include "hrt/depth_backend.h"

namespace hrt {

void CpuDepthBackend::evaluate(const DepthJob* jobs, int count, const ForceOptions& opt, DepthGradient* out) {
  for (int k = 0; k < count; ++k)
    out[k] =
        compute_depth_gradient(*jobs[k].a, jobs[k].pose_a, *jobs[k].b, jobs[k].pose_b, *jobs[k].patch, opt, scratch_);
}

bool parse_backend_choice(const std::string& text, BackendChoice& out) {
  if (text == "cpu")
    out = BackendChoice::cpu;
  else if (text == "gl")
    out = BackendChoice::gl;
  else if (text == "auto")
    out = BackendChoice::automatic;
  else
    return false;
  return true;
}

const char* to_string(HeightMode mode) {
  return mode == HeightMode::coarse ? "coarse" : mode == HeightMode::mesh ? "mesh" : "surface";
}

bool parse_height_mode(const std::string& name, HeightMode& out) {
  for (HeightMode m : {HeightMode::surface, HeightMode::coarse, HeightMode::mesh})
    if (name == to_string(m)) {
      out = m;
      return true;
    }
  return false;
}

}  // namespace hrt
