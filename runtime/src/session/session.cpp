// A haptic session: see hrt/session.h for the steps of one frame.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>

#include <Eigen/Cholesky>

#include "contact/scratch.h"
#include "hrt/session.h"

namespace hrt {

namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count();
}

// 1. The predicted pose's translation, h v (at most max_prediction), added
// to `predicted`; returns it as a twist.
Vec6 predict_translation(const double h, const SessionOptions& o, BodyState& predicted) {
  Vec6 shift = Vec6::Zero();
  if (o.predict) {
    Vec3 s = h * predicted.v;
    const double len = s.norm();
    if (len > o.max_prediction && len > 0) s *= std::max(o.max_prediction, 0.0) / len;
    predicted.x += s;
    shift.head<3>() = s;
  }
  return shift;
}

// 5. The friction rows' wrench after the step; counts the slipping and
// sticking rows.
Vec6 friction_wrench(const FrictionRow* rows, const size_t count, SessionFrame& out) {
  Vec6 friction = Vec6::Zero();
  for (size_t i = 0; i < count; ++i) {
    const FrictionRow& row = rows[i];
    const Vec6 fw = row.J.transpose() * row.force;
    if (fw.allFinite()) friction += fw;
    ++(row.slipping ? out.slipping : out.sticking);
  }
  return friction;
}

// 3. The texture wrench of patch p (world, about c_A), scaled to its
// material's stiffness kp, with the patch's fade memory (last_wrench, fade);
// adds the patch's stiffness to K and its energy to out.
Vec6 patch_wrench(const ContactPatch& p, const double kp, const double k_scene, const double h, const double fade_time,
                  const Vec6& shift, Vec6& last_wrench, double& fade, Mat6& K, SessionFrame& out) {
  Vec6 w = Vec6::Zero();
  if (p.deep_replaced) {
    // Its object's deep fallback (below) stands for it: no fade of a wrench
    // that pushed the wrong way or that the depth made meaningless.
    if (p.refused) ++out.refused;
    fade = 0.0;
  } else if (p.refused) {
    // Fade the last accepted wrench out instead of stepping to zero.
    ++out.refused;
    fade = std::max(0.0, fade - h / std::max(fade_time, 1e-9));
    if (fade > 0) {
      w = fade * last_wrench;
      ++out.fading;
    }
  } else if (p.covered) {
    w.head<3>() = (kp / k_scene) * p.force;
    w.tail<3>() = (kp / k_scene) * p.torque;
    if (!w.allFinite()) w.setZero();
    last_wrench = w;
    fade = 1.0;
    if (p.delta_force > 0) {
      // K = -k (g g^T + delta diag(H+)): the Gauss-Newton term, plus the
      // positive part of the Hessian's diagonal from Eq. 7's second
      // differences (in the patch's u, v, n axes). Without it a mode whose
      // gradient vanishes at rest, such as a flat face tilting on a flat
      // face (delta grows with |tilt| either way), is integrated
      // explicitly and rings undamped; the term keeps K negative
      // semi-definite.
      Vec6 g;
      g.head<3>() = p.grad[0] * p.u + p.grad[1] * p.v + p.grad[2] * p.n;
      g.tail<3>() = p.grad[3] * p.u + p.grad[4] * p.v + p.grad[5] * p.n;
      if (g.allFinite()) K.noalias() -= kp * g * g.transpose();
      // Energy of the current state (the frame saw the predicted one):
      // delta carried back along the gradient.
      const double d_now = std::max(0.0, p.delta_force - (g.allFinite() ? g.dot(shift) : 0.0));
      out.contact_energy += 0.5 * kp * d_now * d_now;
      const Vec3 axes[3] = {p.u, p.v, p.n};
      for (int i = 0; i < 6; ++i) {
        const double c = p.curvature[i];
        if (!(c > 0) || !std::isfinite(c)) continue;
        Vec6 e = Vec6::Zero();
        (i < 3 ? e.head<3>() : e.tail<3>()) = axes[i % 3];
        K.noalias() -= kp * p.delta_force * c * e * e.transpose();
      }
    }
  }
  return w;
}

// 4. Friction on the tangent plane of n, from the patch's normal force fn:
// one row of the step's Coulomb solve (hrt/dynamics.h, FrictionRow). x: the
// predicted centre of mass; tr (or null), position_b: B's trajectory and
// position.
void friction_row(const ContactPatch& p, const Material& mat, const double fn, const Vec3& x, const Trajectory* tr,
                  const double t, const Vec3& position_b, FrictionRow& row) {
  // Where friction acts: the centre of the contact region (the overlapping
  // texels' centroid), else the window's centre. Not p_a / p_b: for faces
  // in full contact those are an arbitrary point of the face (a corner,
  // often), whose lever arm would give friction a torque of its own.
  const double half = 0.5 * p.window.resolution * p.window.cell;
  const Vec3 c = p.contact_texels > 0 ? p.contact_center : Vec3(p.window.origin + half * (p.u + p.v));
  // The lever of the friction force about the centre of mass. Its part
  // along n gives friction a tipping moment, which in a real contact the
  // normal force balances by moving its centre of pressure towards the
  // leading edge; one penetration depth per patch (Eq. 9) cannot move it,
  // and the block would rock on its edges. When the contact region is wide
  // enough to hold that centre for any force inside the cone (mu_s |r_n|
  // <= its smallest half-extent) the tipping moment is taken up and the
  // lever is r's in-plane part (friction still turns the probe about n);
  // a narrow region (a tip, an edge) keeps the whole lever.
  Vec3 r = c - x;
  const double rn = r.dot(p.n);
  const double reach = std::min(std::min(-p.contact_lo_u, p.contact_hi_u), std::min(-p.contact_lo_v, p.contact_hi_v));
  if (p.contact_texels > 0 && mat.mu_static * std::abs(rn) <= reach) r -= rn * p.n;
  row.J.row(0) << p.u.transpose(), r.cross(p.u).transpose();
  row.J.row(1) << p.v.transpose(), r.cross(p.v).transpose();
  row.v_b.setZero();
  if (tr) {
    const Vec6 tw = tr->velocity(t);
    const Vec3 vb = tw.head<3>() + tw.tail<3>().cross(c - position_b);
    row.v_b << vb.dot(p.u), vb.dot(p.v);
  }
  row.limit_static = mat.mu_static * fn;
  row.limit_dynamic = std::min(mat.mu_dynamic, mat.mu_static) * fn;
}

// Energies of the state the frame saw (before the step).
void state_energies(const RigidBody& body, const BodyState& s, const Pose& target, const Coupling& c,
                    const Vec3& gravity, SessionFrame& out) {
  const Vec3 com = body.center_of_mass;
  const Mat3 R = s.q.toRotationMatrix();
  out.kinetic = 0.5 * body.mass * s.v.squaredNorm() + 0.5 * s.w.dot(R * body.inertia * R.transpose() * s.w);
  const Vec3 xt = target.position + target.rotation * com;
  const Vec3 rot = rotation_vector(target.rotation.normalized() * s.q.conjugate());
  out.coupling_energy = 0.5 * c.k_lin * (xt - s.x).squaredNorm() + 0.5 * c.k_ang * rot.squaredNorm();
  out.gravity_energy = -body.mass * gravity.dot(s.x);
}

// The target's velocity: the finite difference of consecutive targets
// (exact for a scripted device's linear segments; a real device's pose
// noise enters the damper, as it would through a physical one).
Vec6 target_velocity(const Pose& target, const Pose& prev, const bool have_prev, const double h, const Vec3& com) {
  Vec6 vt = Vec6::Zero();
  if (have_prev && h > 0) {
    const Vec3 xt = target.position + target.rotation * com;
    const Vec3 xp = prev.position + prev.rotation * com;
    vt.head<3>() = (xt - xp) / h;
    vt.tail<3>() = rotation_vector(target.rotation.normalized() * prev.rotation.normalized().conjugate()) / h;
    if (!vt.allFinite()) vt.setZero();
  }
  return vt;
}

// 6. The device command's stiffness: K_eff = K_c - K_c (K_c + K)^-1 K_c
// (K = -K here, positive), capped at the device's stiffness.
Mat6 device_stiffness(const Coupling& c, const Mat6& K, const SessionOptions& o) {
  Mat6 Kc = Mat6::Zero();
  Kc.topLeftCorner<3, 3>() = c.k_lin * Mat3::Identity();
  Kc.bottomRightCorner<3, 3>() = c.k_ang * Mat3::Identity();
  Mat6 Keff = Mat6::Zero();
  if (c.k_lin > 0 || c.k_ang > 0) {
    // (K_c + K) is singular only where K_c is (a zero gain): regularize those
    // modes by one, they are multiplied by zero rows of K_c anyway.
    Mat6 A = Kc - K;
    for (int i = 0; i < 6; ++i)
      if (Kc(i, i) <= 0) A(i, i) += 1.0;
    Keff = Kc - Kc * A.ldlt().solve(Kc);
    Keff = 0.5 * (Keff + Keff.transpose());
    // Cap at the device's stiffness (congruence keeps it PSD).
    Vec6 sdiag;
    const double sl = c.k_lin > o.max_device_stiffness ? std::sqrt(o.max_device_stiffness / c.k_lin) : 1.0;
    const double sa =
        c.k_ang > o.max_device_angular_stiffness ? std::sqrt(o.max_device_angular_stiffness / c.k_ang) : 1.0;
    sdiag << sl, sl, sl, sa, sa, sa;
    Keff = sdiag.asDiagonal() * Keff * sdiag.asDiagonal();
  }
  return Keff;
}

}  // namespace

Coupling default_coupling(const DeviceInfo& device, const RigidBody& probe) {
  Coupling c;
  c.k_lin = device.max_stiffness;
  c.k_ang = device.max_angular_stiffness;
  const double m = probe.mass;
  const double I = std::max(probe.inertia.diagonal().maxCoeff(), 1e-12);
  // Critical damping of the probe on the coupling spring; capped at
  // b h / m = 1 at h = 1 ms so the damper alone never dominates a
  // 1 kHz frame of a very light probe (the implicit step would stay
  // stable, but the probe would crawl behind the hand).
  c.b_lin = std::min(2.0 * std::sqrt(c.k_lin * m), m / 1e-3);
  c.b_ang = std::min(2.0 * std::sqrt(c.k_ang * I), I / 1e-3);
  return c;
}

Session::Session(const Scene& scene, const SessionOptions& options, const std::vector<Pose>& initial)
    : scene_(scene), options_(options), state_(scene), initial_(initial) {
  if (static_cast<int>(initial.size()) != scene.size())
    throw std::invalid_argument("session: " + std::to_string(initial.size()) + " initial poses for " +
                                std::to_string(scene.size()) + " objects");
  if (!(options.density > 0) || !std::isfinite(options.density))
    throw std::invalid_argument("session: density must be positive and finite");
  if (!options.materials.empty() && static_cast<int>(options.materials.size()) != scene.size())
    throw std::invalid_argument("session: materials must have one entry per object");
  body_ = RigidBody::from_model(scene.model(0), options.density);
  if (!(body_.mass > 0) || !std::isfinite(body_.mass) || !body_.inertia.allFinite() ||
      !(body_.inertia.diagonal().minCoeff() > 0))
    throw std::invalid_argument("session: the probe '" + scene.model(0).name +
                                "' has no usable mass properties (volume " +
                                std::to_string(scene.model(0).mass.volume) + " m^3)");
  body_state_ = BodyState::at_pose(initial[0], body_.center_of_mass);
  trajectories_.assign(static_cast<size_t>(scene.size()), nullptr);
  memory_.resize(2 * static_cast<size_t>(scene.options().cluster.max_patches));
  friction_.resize(static_cast<size_t>(scene.options().cluster.max_patches));
  friction_patch_.resize(friction_.size());
  for (int b = 0; b < scene.size(); ++b) state_.poses[static_cast<size_t>(b)] = initial[static_cast<size_t>(b)];
  // The deep fallback's results and scratch (frame() would size them on its
  // first frame): per object, and per pair like the State's other pair buffers.
  const size_t n = static_cast<size_t>(scene.size()), np = state_.pairs.size();
  FrameScratch& sc = *state_.scratch;
  state_.deep_active.assign(n, 0);
  state_.deep_overlap.assign(n, 0.0);
  state_.deep_axis.assign(n, Vec3::Zero());
  state_.deep_point.assign(n, Vec3::Zero());
  state_.deep_grad.assign(n, Vec6::Zero());
  state_.deep_wrench.assign(n, Vec6::Zero());
  state_.deep_pair.assign(n, -1);
  sc.free_last.assign(n, 0);
  sc.free_pose.assign(n, Pose{});
  sc.pair_axis.resize(np);
  sc.pair_axis_overlap.resize(np);
  sc.pair_flipped.resize(np);
  sc.pair_key.resize(np);
  sc.pair_sort.resize(np);
  sc.memory_key.resize(np);
  sc.memory_axis.resize(np);
}

void Session::set_trajectory(int b, const Trajectory* trajectory) {
  if (b < 1 || b >= scene_.size()) throw std::invalid_argument("session: trajectory for object " + std::to_string(b));
  trajectories_[static_cast<size_t>(b)] = trajectory;
}

const Material& Session::material(int b) const {
  return options_.materials.empty() ? options_.material : options_.materials[static_cast<size_t>(b)];
}

Session::PatchMemory* Session::memory_for(uint64_t id, int b) {
  PatchMemory* free_slot = nullptr;
  for (PatchMemory& m : memory_) {
    if (m.active && m.id == id && m.object_b == b) return &m;
    if (!m.active && !free_slot) free_slot = &m;
  }
  if (!free_slot) {  // every slot live (more tracked patches than 2 x max_patches): reuse the oldest
    free_slot = &memory_.front();
    for (PatchMemory& m : memory_)
      if (m.seen < free_slot->seen) free_slot = &m;
  }
  *free_slot = PatchMemory{};
  free_slot->id = id;
  free_slot->object_b = b;
  free_slot->active = true;
  return free_slot;
}

const SessionFrame& Session::step(double t, double h, const Pose& target) {
  SessionFrame& out = last_;
  out = SessionFrame{};
  out.t = t;
  out.h = h;
  out.frame = ++frames_;
  out.target = target;

  // 1. Poses at the start of the frame.
  const Vec3 com = body_.center_of_mass;
  // The contact is evaluated at the pose the probe is predicted to reach,
  // x + h v (and exp(h w) q), and the step is linearized about it (below):
  // a probe that follows a moving hand is then linearized where it will be,
  // not one frame behind, so the device command (W0, K_eff) describes the
  // new state. At rest the prediction is the current pose.
  BodyState predicted = body_state_;
  // Translation only: carrying the wrench back along K is exact where K is
  // the true Jacobian, and the rotational part of K is the weakest
  // approximation (a flat face tilting on a flat face has a kink there, see
  // below): predicted along it, the error would act as a negative damper.
  const Vec6 shift = predict_translation(h, options_, predicted);  // predicted - current, twist
  state_.poses[0] = predicted.pose(com);
  for (int b = 1; b < scene_.size(); ++b) {
    const Trajectory* tr = trajectories_[static_cast<size_t>(b)];
    state_.poses[static_cast<size_t>(b)] = tr ? tr->sample(t) : initial_[static_cast<size_t>(b)];
  }

  // 2. Contact patches and texture wrenches.
  frame(scene_, state_);
  out.timings = state_.timings;
  const auto t0 = std::chrono::steady_clock::now();

  // 3-4. Materials, fades, friction.
  const double k_scene = scene_.options().force.stiffness;
  Vec6 contact = Vec6::Zero();
  num_friction_ = 0;
  Mat6 K = Mat6::Zero();  // d(wrench)/d(twist), negative semi-definite
  for (int k = 0; k < state_.num_patches; ++k) {
    const ContactPatch& p = state_.patches[static_cast<size_t>(k)];
    const int b = p.object_b;
    const Material& mat = material(b);
    const double kp = mat.stiffness > 0 ? mat.stiffness : k_scene;
    PatchMemory* mem = memory_for(state_.patch_ids[static_cast<size_t>(k)], b);
    mem->seen = frames_;
    ++out.patches;
    const Vec6 w = patch_wrench(p, kp, k_scene, h, options_.fade_time, shift, mem->last_wrench, mem->fade, K, out);
    contact += w;

    const double fn = std::max(0.0, -w.head<3>().dot(p.n));
    if (!options_.friction || !(mat.mu_static > 0) || !(fn > 0) || num_friction_ >= friction_.size()) continue;
    friction_row(p, mat, fn, predicted.x, trajectories_[static_cast<size_t>(b)], t,
                 state_.poses[static_cast<size_t>(b)].position, friction_[num_friction_]);
    friction_patch_[num_friction_] = k;
    ++num_friction_;
  }
  for (PatchMemory& m : memory_)
    if (m.active && m.seen != frames_) m.active = false;  // the contact ended: forget its anchors

  // The deep fallback of each object (frame.cpp): U = k/2 O^2 along the
  // pair's axis, scaled to the pair's stiffness like a patch, with its
  // Gauss-Newton stiffness -k g g^T (exact in translation: O is linear in
  // it) and its energy carried back along g from the predicted pose.
  for (int b = 1; b < scene_.size() && state_.num_deep > 0; ++b) {
    if (!state_.deep_active[static_cast<size_t>(b)]) continue;
    const Material& mat = material(b);
    const double kp = mat.stiffness > 0 ? mat.stiffness : k_scene;
    const Vec6 w = (kp / k_scene) * state_.deep_wrench[static_cast<size_t>(b)];
    const Vec6& g = state_.deep_grad[static_cast<size_t>(b)];
    if (!w.allFinite() || !g.allFinite()) continue;
    contact += w;
    K.noalias() -= kp * g * g.transpose();
    const double o_now = std::max(0.0, state_.deep_overlap[static_cast<size_t>(b)] - g.dot(shift));
    out.contact_energy += 0.5 * kp * o_now * o_now;
    ++out.deep;
  }

  const Coupling c = options_.coupling_enabled ? options_.coupling : Coupling{};
  state_energies(body_, body_state_, target, c, options_.gravity, out);
  const Vec6 vt = target_velocity(target, prev_target_, have_prev_target_, h, com);
  prev_target_ = target;
  have_prev_target_ = true;

  // 5. The implicit step.
  StepInput in;
  in.h = h;
  // The wrench at the predicted pose carried back to the current one along
  // K, so that step_body's linearization (about the current state) is the
  // linearization about the prediction: f(x) ~ f(x_pred) + K (x - x_pred).
  in.contact = contact - K * shift;
  in.contact_stiffness = K;
  in.target = target;
  in.gravity = options_.gravity;
  in.target_velocity = vt;
  step_body(body_, c, in, body_state_, friction_.data(), static_cast<int>(num_friction_));
  out.contact = contact;
  out.friction = friction_wrench(friction_.data(), num_friction_, out);
  out.probe = body_state_.pose(com);
  out.coupling = coupling_wrench(body_, c, body_state_, target, vt);

  // 6. The device command: the reaction of the coupling on the handle, and
  // K_eff (device_stiffness).
  const Vec6 spring = -out.coupling;
  const Mat6 Keff = device_stiffness(c, K, options_);
  command_.time = t;
  command_.frame = frames_;
  command_.target_ref = target;
  command_.wrench = spring;
  command_.stiffness = Keff;
  command_.valid = spring.allFinite() && Keff.allFinite();
  if (!command_.valid) {
    command_.wrench.setZero();
    command_.stiffness.setZero();
  }
  out.device = command_.wrench;
  out.dynamics_us = seconds_since(t0);
  return out;
}

}  // namespace hrt
