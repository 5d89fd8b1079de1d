// A haptic session: the probe A as a rigid body (hrt/dynamics.h)
// driven by the contact wrench of hrt::frame, friction and a virtual
// coupling to the device's target pose; objects B static or kinematic
// (following trajectories). One step() is one simulation frame.
//
// A Session owns the Scene's dynamic State, the probe's BodyState and the
// per-patch friction and fade tables, all preallocated: step() allocates
// nothing of its own (FCL's narrow phase does, see hrt/scene.h).
//
// One step(t, h, target):
//   1. poses: A at the position the body state predicts for the end of the
//      frame (x + h v, its orientation as it is), each B from its trajectory
//      at t;
//   2. frame(): contact patches and their texture wrenches (Eq. 5-9);
//   3. materials: each patch's wrench scaled to its pair's stiffness k
//      (the force model is linear in k); a patch the safety checks refused
//      fades out over fade_time from its last accepted wrench instead of
//      stepping to zero; a probe deeper than its patches can be trusted
//      gets its objects' deep fallback instead (src/contact/frame.cpp: the
//      penalty k/2 O^2 of the deepest piece pair along its remembered axis,
//      scaled to the pair's k like a patch, in K with its gradient, no
//      friction), and the patches it replaced give nothing (no fade);
//   4. friction (Coulomb, static and dynamic coefficients) on each patch's
//      tangent plane, from the patch's normal force F_n = -F . n, acting at
//      the centre of its contact region: solved inside the implicit step at
//      the velocity level (hrt/dynamics.h, FrictionRow): a patch sticks
//      (zero relative tangential velocity after the step) while the force
//      that takes is within mu_s F_n, else slips with mu_d F_n. The tipping
//      moment of friction is taken up by the contact region's centre of
//      pressure when the region is wide enough (session.cpp says why);
//   5. the implicit step (step_body) with K = contact stiffness (k of each
//      pair) + coupling, and the friction rows;
//   6. the device command: W0 = the coupling's reaction on the device
//      (its spring, and its damper on the velocity relative to the target's,
//      the finite difference of consecutive targets), K_eff = K_c - K_c (K_c + K)^-1 K_c (capped at the device's
//      stiffness), for DeviceLoop's multirate model.
#pragma once

#include <cstdint>
#include <vector>

#include "hrt/device_loop.h"
#include "hrt/dynamics.h"
#include "hrt/scene.h"
#include "hrt/trajectory.h"

namespace hrt {

// Contact material of a pair (A, B), or the scene's default.
struct Material {
  double stiffness = 0.0;  // k, N/m; 0: the scene's force.stiffness
  double mu_static = 0.0;  // Coulomb coefficients (mu_dynamic <= mu_static)
  double mu_dynamic = 0.0;
};

struct SessionOptions {
  double density = 1000.0;       // kg/m^3 of the probe (mass properties scale with it)
  Vec3 gravity = Vec3::Zero();   // m/s^2; off by default: a haptic probe is held
  Coupling coupling;             // gains (N/m, N s/m, N m/rad, N m s/rad); see default_coupling
  bool coupling_enabled = true;  // false: a free body (tests, the tilted-plate experiment)
  // Friction: off by default. Sec. 6's roughness experiments (Fig. 7, 8) are
  // frictionless, and a stick-slip anchor needs a material the user chose
  // (mu); with it on, textures stop feeling like ice.
  bool friction = false;
  Material material;                // default for every pair
  std::vector<Material> materials;  // per object b (index = object; [0] unused); empty: the default
  double fade_time = 0.02;          // s: a refused patch's wrench fades to zero over this time
  // Evaluate the contact at the predicted position x + h v (translation
  // only) and linearize the step about it (session.cpp): without it the contact of a moving probe,
  // and the device command made from it, lag one frame behind (measured on
  // the grating slide at 100 Hz: the command's stiffness then predicts the
  // next 10 ms worse than holding the wrench does).
  bool predict = true;
  // Longest prediction h v (m). A probe faster than max_prediction / h (1 m/s
  // at 1 kHz, 0.1 m/s at 100 Hz: an impact or a scripted jump; the session
  // tests slide at 20 mm/s) is predicted this far along v only: the linearization is local, and a
  // prediction a whole frame of such a motion ahead can land beyond an
  // object thinner than that (a 4 mm block jumping 10 mm into the 6 mm slab
  // of the session tests moves 8.6 mm in its first frame: predicted 8.6 mm
  // further, it was past the slab and felt nothing).
  double max_prediction = 1e-3;
  // Caps of the device-side stiffness K_eff (the device's limits).
  double max_device_stiffness = 2000.0;       // N/m
  double max_device_angular_stiffness = 5.0;  // N m/rad
};

// Coupling gains from a device's limits: k_lin = its max_stiffness, k_ang =
// its max_angular_stiffness, dampers critically damping the probe (mass m,
// the largest principal inertia I): b = 2 sqrt(k m) (capped so that
// h b / m stays below 1 at 1 kHz).
Coupling default_coupling(const DeviceInfo& device, const RigidBody& probe);

// What one step did (all world/scene frame; energies in J).
struct SessionFrame {
  double t = 0.0, h = 0.0;
  uint64_t frame = 0;
  Pose target;                   // coupling target (probe object frame)
  Pose probe;                    // probe pose after the step
  Vec6 contact = Vec6::Zero();   // texture contact wrench on A (after materials and fades), torque about c_A
  Vec6 friction = Vec6::Zero();  // friction wrench on A
  Vec6 coupling = Vec6::Zero();  // coupling wrench on A (after the step)
  Vec6 device = Vec6::Zero();    // W0 of the device command (scene frame)
  int patches = 0, sticking = 0, slipping = 0, refused = 0, fading = 0;
  int deep = 0;  // objects whose deep fallback acted (counted in State::warnings too)
  double kinetic = 0.0, coupling_energy = 0.0, contact_energy = 0.0, gravity_energy = 0.0;
  double friction_energy = 0.0;  // 0: velocity-level friction stores no energy (the column is kept)
  StageTimings timings;          // of frame()
  double dynamics_us = 0.0;      // materials, friction, step, command
};

class Session {
 public:
  // `scene` must outlive the session. initial[b] are the objects' poses at
  // t = 0 (size = scene.size()); the probe starts at rest at initial[0].
  Session(const Scene& scene, const SessionOptions& options, const std::vector<Pose>& initial);

  // Object b (>= 1) follows `trajectory` (kept by pointer; nullptr: static
  // at its initial pose).
  void set_trajectory(int b, const Trajectory* trajectory);

  // One frame of length h (s) ending at session time t, towards `target`.
  const SessionFrame& step(double t, double h, const Pose& target);
  // The device command of the last step (DeviceLoop::publish).
  const DeviceCommand& command() const { return command_; }
  const SessionFrame& last() const { return last_; }

  const Scene& scene() const { return scene_; }
  const State& state() const { return state_; }
  // Where the depth query runs (hrt/depth_backend.h; non-owning, must
  // outlive the session; null: the CPU code inline, the default).
  void set_depth_backend(DepthBackend* backend) { state_.depth_backend = backend; }
  const RigidBody& body() const { return body_; }
  const BodyState& body_state() const { return body_state_; }
  BodyState& body_state() { return body_state_; }
  const SessionOptions& options() const { return options_; }

 private:
  struct PatchMemory {  // per tracked patch id, in A's and B's frames
    uint64_t id = 0;
    int object_b = -1;
    bool active = false;
    Vec6 last_wrench = Vec6::Zero();  // last accepted texture wrench (world, about c_A)
    double fade = 0.0;                // 1 = live, decreasing while refused
    uint64_t seen = 0;                // frame it was last seen
  };
  const Material& material(int b) const;
  PatchMemory* memory_for(uint64_t id, int b);

  const Scene& scene_;
  SessionOptions options_;
  State state_;
  RigidBody body_;
  BodyState body_state_;
  std::vector<Pose> initial_;
  std::vector<const Trajectory*> trajectories_;
  std::vector<PatchMemory> memory_;    // capacity 2 x max_patches
  std::vector<FrictionRow> friction_;  // one per patch with friction (capacity max_patches)
  std::vector<int> friction_patch_;
  size_t num_friction_ = 0;
  SessionFrame last_;
  DeviceCommand command_;
  uint64_t frames_ = 0;
  Pose prev_target_;
  bool have_prev_target_ = false;
};

}  // namespace hrt
