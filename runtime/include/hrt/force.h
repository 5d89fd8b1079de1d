// The texture force model (paper Eq. 3-6) on one contact patch: from the
// directional penetration depth and its gradient (hrt/depth.h) to the wrench
// on the probe A and the opposite one on B.
//
// Eq. 5: (F_u F_v F_n T_u T_v T_n) = -k max(delta, 0) grad delta, the force
// of the energy U = k max(delta, 0)^2 / 2 (Eq. 3 clamped: a patch with
// delta <= 0 gives no force); Eq. 6 maps it to the world with the columns
// (u v n). The rotations of Eq. 7 are about A's centre of mass c_A, so the
// torque is A's body torque about c_A. Conventions: docs/bundle-format.md
// (n from A into B, delta > 0 means overlap, the force on A along -n).
#pragma once

#include "hrt/contact.h"
#include "hrt/depth.h"
#include "hrt/math.h"
#include "hrt/model.h"

namespace hrt {

// The force model on a patch from its DepthGradient (what
// compute_patch_wrench does after compute_depth_gradient): patch.covered,
// delta, grad, curvature (second differences of Eq. 7), the contact region
// and the wrench (Eq. 5-6); the undersampling warning as compute_patch_wrench
// counts it.
void apply_depth_gradient(const Model& A, const Model& B, ContactPatch& patch, const DepthGradient& g,
                          const ForceOptions& opt, DepthWarnings* warnings = nullptr, bool* warned = nullptr);

// The whole force model for one patch: fills patch.delta, grad, covered,
// force and torque (on A, world; torque about A's centre of mass
// A.mass.center_of_mass placed by pose_a). An uncovered patch gets delta = 0,
// grad = (0, 0, 1, 0, 0, 0), covered = false and no wrench.
// `warnings` (optional) counts the Sec. 7.2 undersampling once per patch
// lifetime: the caller keeps one bool per tracked patch and passes it as
// `warned` (set to true the first time it is counted); with warned ==
// nullptr every call that undersamples counts.
void compute_patch_wrench(const Model& A, const Pose& pose_a, const Model& B, const Pose& pose_b, ContactPatch& patch,
                          const ForceOptions& opt, DepthScratch& scratch, DepthWarnings* warnings = nullptr,
                          bool* warned = nullptr);

// Eq. 5-6 alone: force and torque on A (world) from delta and its gradient.
void wrench_from_gradient(const ContactPatch& patch, double delta, const Vec6& grad, double stiffness, Vec3& force,
                          Vec3& torque);

// The opposite wrench on B about B's centre of mass c_b, given A's (force F,
// torque T_a about c_a): (-F, -T_a - (c_a - c_b) x F).
void wrench_on_b(const Vec3& force_a, const Vec3& torque_a, const Vec3& c_a, const Vec3& c_b, Vec3& force_b,
                 Vec3& torque_b);

}  // namespace hrt
