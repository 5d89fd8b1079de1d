// delta of each (patch, configuration) slot: max over the N x N texels
// covered by both of h_A - h_B (shifted_depth), and on configuration 0 the
// contact region (compute_depth_gradient: overlap-weighted centroid, box,
// count). One work group per slot.
layout(local_size_x = 256) in;
layout(std430, binding = 10) buffer Results { double results[]; };
#define RS_STRIDE 16
uniform int u_first_slot;
uniform int u_region_only;  // occlusion search: only the region here, delta from the search

shared double s_max[256], s_w[256], s_wi[256], s_wj[256];
shared int s_cnt[256], s_loi[256], s_loj[256], s_hii[256], s_hij[256];
shared int s_cov[256];

void main() {
  int s = u_first_slot + int(gl_WorkGroupID.x);
  int t = int(gl_LocalInvocationID.x);
  int N = slv(s, SL_N);
  bool region = slv(s, SL_REGION) != 0;
  if (u_region_only != 0 && !region) return;
  double m = 0.0lf, w = 0.0lf, wi = 0.0lf, wj = 0.0lf;
  int cov = 0, cnt = 0, loi = N, loj = N, hii = -1, hij = -1;
  for (int k = t; k < N * N; k += 256) {
    int i = k % N, j = k / N;
    double d;
    if (!slot_diff(s, i, j, d)) continue;
    m = cov == 0 ? d : max(m, d);
    cov = 1;
    if (region && d > 0.0lf) {
      ++cnt;
      w += d;
      wi += d * (double(i) + 0.5lf);
      wj += d * (double(j) + 0.5lf);
      loi = min(loi, i), hii = max(hii, i);
      loj = min(loj, j), hij = max(hij, j);
    }
  }
  s_max[t] = m, s_cov[t] = cov, s_w[t] = w, s_wi[t] = wi, s_wj[t] = wj;
  s_cnt[t] = cnt, s_loi[t] = loi, s_loj[t] = loj, s_hii[t] = hii, s_hij[t] = hij;
  barrier();
  for (int h = 128; h > 0; h >>= 1) {
    if (t < h) {
      int o = t + h;
      if (s_cov[o] != 0) {
        s_max[t] = s_cov[t] != 0 ? max(s_max[t], s_max[o]) : s_max[o];
        s_cov[t] = 1;
      }
      s_w[t] += s_w[o], s_wi[t] += s_wi[o], s_wj[t] += s_wj[o];
      s_cnt[t] += s_cnt[o];
      s_loi[t] = min(s_loi[t], s_loi[o]), s_loj[t] = min(s_loj[t], s_loj[o]);
      s_hii[t] = max(s_hii[t], s_hii[o]), s_hij[t] = max(s_hij[t], s_hij[o]);
    }
    barrier();
  }
  if (t == 0) {
    int r = s * RS_STRIDE;
    if (u_region_only == 0) {
      results[r] = s_max[0];
      results[r + 1] = double(s_cov[0]);
    }
    results[r + 2] = double(s_cnt[0]);
    results[r + 3] = s_w[0];
    results[r + 4] = s_wi[0];
    results[r + 5] = s_wj[0];
    results[r + 6] = double(s_loi[0]);
    results[r + 7] = double(s_loj[0]);
    results[r + 8] = double(s_hii[0]);
    results[r + 9] = double(s_hij[0]);
  }
}
