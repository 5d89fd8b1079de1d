// Probe dynamics: see hrt/dynamics.h.
#include <algorithm>
#include <cmath>

#include <Eigen/Cholesky>

#include "hrt/dynamics.h"

namespace hrt {

// Rotation vector of a unit quaternion (angle times axis), the short way.
Vec3 rotation_vector(Eigen::Quaterniond q) {
  if (q.w() < 0) q.coeffs() = -q.coeffs();
  const Vec3 im = q.vec();
  const double s = im.norm();
  if (s < 1e-12) return 2.0 * im;  // angle ~ 2 s
  return 2.0 * std::atan2(s, q.w()) * im / s;
}

Eigen::Quaterniond exp_rotation(const Vec3& r) {
  const double a = r.norm();
  if (a < 1e-12) return Eigen::Quaterniond(1.0, 0.5 * r.x(), 0.5 * r.y(), 0.5 * r.z()).normalized();
  return Eigen::Quaterniond(Eigen::AngleAxisd(a, r / a));
}

RigidBody RigidBody::from_model(const Model& m, double density) {
  RigidBody b;
  const double scale = m.mass.density > 0 ? density / m.mass.density : 1.0;
  b.mass = m.mass.volume * density;
  b.inertia = m.mass.inertia * scale;
  b.center_of_mass = m.mass.center_of_mass;
  return b;
}

Pose BodyState::pose(const Vec3& c) const {
  Pose p;
  p.rotation = q;
  p.position = x - (q * c);
  return p;
}

BodyState BodyState::at_pose(const Pose& p, const Vec3& c) {
  BodyState s;
  s.q = p.rotation.normalized();
  s.x = p.position + s.q * c;
  return s;
}

Vec6 coupling_wrench(const RigidBody& body, const Coupling& c, const BodyState& s, const Pose& target,
                     const Vec6& target_velocity) {
  const Vec3 xt = target.position + target.rotation * body.center_of_mass;
  const Vec3 rot = rotation_vector(target.rotation.normalized() * s.q.conjugate());  // world
  Vec6 f;
  f.head<3>() = c.k_lin * (xt - s.x) + c.b_lin * (target_velocity.head<3>() - s.v);
  f.tail<3>() = c.k_ang * rot + c.b_ang * (target_velocity.tail<3>() - s.w);
  return f;
}

Mat6 contact_stiffness(const State& st, double k) {
  Mat6 K = Mat6::Zero();
  for (int i = 0; i < st.num_patches; ++i) {
    const ContactPatch& p = st.patches[static_cast<size_t>(i)];
    if (!p.covered || p.refused || !(p.delta_force > 0)) continue;
    Vec6 g;
    g.head<3>() = p.grad[0] * p.u + p.grad[1] * p.v + p.grad[2] * p.n;
    g.tail<3>() = p.grad[3] * p.u + p.grad[4] * p.v + p.grad[5] * p.n;
    if (!g.allFinite()) continue;
    K.noalias() -= k * g * g.transpose();
  }
  return K;
}

void step_body(const RigidBody& body, const Coupling& c, const StepInput& in, BodyState& s, FrictionRow* friction,
               int friction_count) {
  const double h = in.h;
  const Mat3 R = s.q.toRotationMatrix();
  Mat6 M = Mat6::Zero();
  M.topLeftCorner<3, 3>() = body.mass * Mat3::Identity();
  M.bottomRightCorner<3, 3>() = R * body.inertia * R.transpose();

  Vec6 f = in.contact + coupling_wrench(body, c, s, in.target, in.target_velocity);
  f.head<3>() += body.mass * in.gravity;
  // Gyroscopic torque -w x (I w), explicit (small at haptic rates).
  f.tail<3>() -= s.w.cross(M.bottomRightCorner<3, 3>() * s.w);

  Mat6 K = in.contact_stiffness;
  K.topLeftCorner<3, 3>() -= c.k_lin * Mat3::Identity();
  K.bottomRightCorner<3, 3>() -= c.k_ang * Mat3::Identity();
  Mat6 D = Mat6::Zero();
  D.topLeftCorner<3, 3>() = -c.b_lin * Mat3::Identity();
  D.bottomRightCorner<3, 3>() = -c.b_ang * Mat3::Identity();

  Vec6 vel;
  vel << s.v, s.w;
  // M - h D - h^2 K is symmetric positive definite (M > 0, -D >= 0, -K >= 0).
  const Mat6 A = M - h * D - h * h * K;
  const Eigen::LDLT<Mat6> ldlt(A);
  const Vec6 rhs = h * (f + h * K * vel);
  Vec6 dv = ldlt.solve(rhs);
  if (!dv.allFinite()) return;  // never propagate NaN into the state

  if (friction_count > 0) {
    // dv(F) = dv0 + h A^-1 sum_k J_k^T F_k. Gauss-Seidel on each contact's
    // 2x2 block W_k = h J_k A^-1 J_k^T, projected on its friction cone.
    constexpr int kMaxContacts = 64, kIterations = 12;
    const int n = std::min(friction_count, kMaxContacts);
    Eigen::Matrix<double, 6, 2> AiJt[kMaxContacts];
    Eigen::Matrix2d Winv[kMaxContacts];
    bool usable[kMaxContacts];
    for (int k = 0; k < n; ++k) {
      FrictionRow& r = friction[k];
      r.force.setZero();
      r.slipping = false;
      AiJt[k] = ldlt.solve(r.J.transpose());
      const Eigen::Matrix2d W = h * r.J * AiJt[k];
      usable[k] = r.J.allFinite() && r.limit_static > 0 && std::abs(W.determinant()) > 1e-300;
      Winv[k] = usable[k] ? Eigen::Matrix2d(W.inverse()) : Eigen::Matrix2d::Zero();
    }
    for (int it = 0; it < kIterations; ++it) {
      for (int k = 0; k < n; ++k) {
        if (!usable[k]) continue;
        FrictionRow& r = friction[k];
        // Relative tangential velocity after the step with the current forces.
        const Eigen::Vector2d g = r.J * (vel + dv) - r.v_b;
        const Eigen::Vector2d prev = r.force;
        Eigen::Vector2d F = prev - Winv[k] * g;  // the force that makes it zero
        const double need = F.norm();
        r.slipping = need > r.limit_static;
        if (r.slipping) F *= r.limit_dynamic / need;
        r.force = F;
        dv += h * AiJt[k] * (F - prev);
      }
    }
    if (!dv.allFinite()) return;
  }
  vel += dv;
  s.v = vel.head<3>();
  s.w = vel.tail<3>();
  s.x += h * s.v;
  s.q = (exp_rotation(h * s.w) * s.q).normalized();
}

}  // namespace hrt
