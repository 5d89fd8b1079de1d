// The texture force model (paper Eq. 3-6) on top of the depth and its
// gradient (src/depth). See hrt/depth.h.
#include <cmath>
#include <algorithm>
#include <limits>

#include "hrt/depth.h"
#include "hrt/force.h"

namespace hrt {

bool grid_undersamples(const Model& A, const Model& B, const Window& w) {
  // Sec. 7.2: the grid must sample the shortest relief either atlas can
  // represent (quality.min_wavelength = 2 atlas texels) at least twice per
  // wavelength, i.e. cell <= min_wavelength / 2. A bundle that records no
  // wavelength (0) imposes nothing.
  double lam = std::numeric_limits<double>::infinity();
  if (A.quality.min_wavelength > 0) lam = std::min(lam, A.quality.min_wavelength);
  if (B.quality.min_wavelength > 0) lam = std::min(lam, B.quality.min_wavelength);
  return w.cell > 0.5 * lam;
}

void wrench_from_gradient(const ContactPatch& patch, double delta, const Vec6& grad, double stiffness, Vec3& force,
                          Vec3& torque) {
  // U = k max(delta, 0)^2 / 2 (Eq. 3, no force when separated); Eq. 5:
  // (F, T)_uvn = -k delta grad delta; Eq. 6: world = (u v n) * uvn.
  const double s = -stiffness * std::max(delta, 0.0);
  force = s * (grad[0] * patch.u + grad[1] * patch.v + grad[2] * patch.n);
  torque = s * (grad[3] * patch.u + grad[4] * patch.v + grad[5] * patch.n);
}

void wrench_on_b(const Vec3& force_a, const Vec3& torque_a, const Vec3& c_a, const Vec3& c_b, Vec3& force_b,
                 Vec3& torque_b) {
  // Newton's third law about a common point: the wrench on B about c_A is
  // (-F, -T_a); moved to c_B, T_b = -T_a + (c_a - c_b) x (-F).
  force_b = -force_a;
  torque_b = -torque_a - (c_a - c_b).cross(force_a);
}

void compute_patch_wrench(const Model& A, const Pose& pose_a, const Model& B, const Pose& pose_b, ContactPatch& patch,
                          const ForceOptions& opt, DepthScratch& scratch, DepthWarnings* warnings, bool* warned) {
  const DepthGradient g = compute_depth_gradient(A, pose_a, B, pose_b, patch, opt, scratch);
  apply_depth_gradient(A, B, patch, g, opt, warnings, warned);
}

void apply_depth_gradient(const Model& A, const Model& B, ContactPatch& patch, const DepthGradient& g,
                          const ForceOptions& opt, DepthWarnings* warnings, bool* warned) {
  if (warnings && grid_undersamples(A, B, patch.window) && !(warned && *warned)) {
    ++warnings->undersampled_patches;
    if (warned) *warned = true;
  }
  if (warnings) warnings->uncovered_configurations += static_cast<uint64_t>(g.uncovered_configurations);
  patch.covered = g.covered;
  patch.contact_texels = 0;
  if (!g.covered) {
    patch.delta = 0.0;
    patch.grad << 0, 0, 1, 0, 0, 0;
    patch.curvature.setZero();
    patch.force.setZero();
    patch.torque.setZero();
    return;
  }
  patch.delta = g.delta;
  patch.grad = g.grad;
  {
    const double* D = g.delta_at;
    auto second = [&](int plus, int minus, double step) {
      if (!(step > 0) || !(D[plus] > -1e300) || !(D[minus] > -1e300)) return 0.0;
      const double c = (D[plus] + D[minus] - 2.0 * D[0]) / (step * step);
      return std::isfinite(c) ? c : 0.0;
    };
    patch.curvature << second(1, 2, g.lin_step), second(3, 4, g.lin_step), 0.0, second(5, 6, g.ang_step),
        second(7, 8, g.ang_step), second(9, 10, g.ang_step);
  }
  patch.contact_texels = g.region_texels;
  if (g.region_texels > 0) {
    const double c = patch.window.cell;
    patch.contact_center = patch.window.origin + c * g.region_center[0] * patch.u + c * g.region_center[1] * patch.v;
    patch.contact_lo_u = c * (g.region_lo[0] - g.region_center[0]);
    patch.contact_hi_u = c * (g.region_hi[0] - g.region_center[0]);
    patch.contact_lo_v = c * (g.region_lo[1] - g.region_center[1]);
    patch.contact_hi_v = c * (g.region_hi[1] - g.region_center[1]);
  }
  wrench_from_gradient(patch, g.delta, g.grad, opt.stiffness, patch.force, patch.torque);
}

}  // namespace hrt
