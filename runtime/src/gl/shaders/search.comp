// One step of the occlusion search for every slot, on the GPU: the query
// result (any sample of the threshold quad passed GL_LESS, i.e. some
// difference lies above the midpoint) halves the slot's interval. Step 0 is
// the coverage query (threshold 0) and starts the interval at [0, 1].
layout(local_size_x = 64) in;
layout(std430, binding = 10) buffer Results { double results[]; };
layout(std430, binding = 12) readonly buffer Queries { uint queries[]; };
uniform int u_first_slot;
uniform int u_count;
uniform int u_step;

void main() {
  int k = int(gl_GlobalInvocationID.x);
  if (k >= u_count) return;
  int s = u_first_slot + k;
  int r = s * 16;
  bool passed = queries[k] != 0u;
  if (u_step == 0) {
    results[r + 1] = passed ? 1.0lf : 0.0lf;
    results[r + 10] = 0.0lf;
    results[r + 11] = 1.0lf;
    return;
  }
  double mid = 0.5lf * (results[r + 10] + results[r + 11]);
  if (passed) results[r + 10] = mid;
  else results[r + 11] = mid;
}
