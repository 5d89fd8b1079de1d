// Probe dynamics (paper Sec. 3.3, 6.1, 7.1): the probe A as a
// 6-DoF rigid body driven by the contact wrench of hrt::frame and a virtual
// coupling to the device pose (Adams and Hannaford), integrated by linearized
// backward Euler so that stiff contact stays stable at haptic time steps.
//
// State: the centre of mass x (world), the orientation q (object frame in the
// world, as hrt::Pose), the linear velocity v and the angular velocity w
// (world). Wrenches are (force, torque about the centre of mass), world.
//
// One step of length h solves, for the velocity change dv (6-vector),
//   (M - h D - h^2 K) dv = h (f + h K v),
// the backward-Euler step of M dv/dt = f(x, v) linearized about the current
// state: f the total wrench (contact + coupling + gravity), K = df/dx its
// stiffness (contact: -k sum over patches of g g^T, the Gauss-Newton Hessian
// of the energy k delta^2 / 2 with g = grad delta in world twist coordinates,
// negative semi-definite; coupling: -k_c), D = df/dv its damping (coupling:
// -b_c), M = diag(m I, I_world). Then v += dv, x += h v, q = exp(h w) q.
// Stability: for a linear spring k on a mass m, symplectic (semi-implicit)
// Euler is stable only for k < 4 m / h^2; this step is unconditionally stable
// (its amplification factor 1 / (1 + h^2 k / m) in magnitude is below 1 for
// every k > 0), so the contact can be as stiff as the texture needs.
// Nothing here allocates.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "hrt/contact.h"
#include "hrt/math.h"
#include "hrt/model.h"
#include "hrt/scene.h"

namespace hrt {

struct RigidBody {
  double mass = 1.0;                   // kg
  Mat3 inertia = Mat3::Identity();     // kg m^2 about the centre of mass, in the object frame
  Vec3 center_of_mass = Vec3::Zero();  // object frame, m

  // From a bundle's mass properties at `density` (kg/m^3; the manifest's
  // figures are at mass.density and scale linearly).
  static RigidBody from_model(const Model& m, double density);
};

struct BodyState {
  Vec3 x = Vec3::Zero();                                  // centre of mass, world, m
  Eigen::Quaterniond q = Eigen::Quaterniond::Identity();  // object frame in the world
  Vec3 v = Vec3::Zero();                                  // m/s, world
  Vec3 w = Vec3::Zero();                                  // rad/s, world

  // The pose of the object frame (hrt::Pose) for a body whose centre of mass
  // lies at c (object frame).
  Pose pose(const Vec3& c) const;
  static BodyState at_pose(const Pose& p, const Vec3& c);
};

// Spring-damper between the device pose (target) and the probe's pose, in
// N/m, N s/m, N m/rad, N m s/rad. Both poses are of the probe's object frame;
// the spring acts at the centre of mass (translation) and on the rotation
// vector of q_target q^-1 (rotation); the damper on the velocity of the
// probe relative to the target's (Adams and Hannaford: a probe following a
// hand at constant speed feels no drag from the damper).
struct Coupling {
  double k_lin = 0, b_lin = 0, k_ang = 0, b_ang = 0;
};

struct StepInput {
  double h = 1e-3;                        // s
  Vec6 contact = Vec6::Zero();            // contact wrench on A (force, torque about its centre of mass), world
  Mat6 contact_stiffness = Mat6::Zero();  // d(contact wrench)/d(x, rotation), negative semi-definite
  Pose target;                            // device pose mapped into the scene (object frame of A)
  Vec6 target_velocity =
      Vec6::Zero();             // its linear velocity (of the point at A's centre of mass) and angular velocity, world
  Vec3 gravity = Vec3::Zero();  // m/s^2 (default off: a haptic probe is held)
};

// rotation_vector and exp_rotation: hrt/math.h.

// The coupling wrench on the body at state s towards `target` (world, torque
// about the centre of mass).
Vec6 coupling_wrench(const RigidBody& body, const Coupling& c, const BodyState& s, const Pose& target,
                     const Vec6& target_velocity = Vec6::Zero());

// -k sum over the covered patches with delta > 0 of g g^T, g = the gradient
// of delta in world twist coordinates (translation, rotation about A's centre
// of mass): the contact stiffness for StepInput (state.patches after frame()).
Mat6 contact_stiffness(const State& state, double k);

// Coulomb friction at one contact, solved inside the step (velocity level).
// J's two rows map the body's velocity (v, w) to the tangential velocity of
// A's contact point along the two tangents t1, t2: [t_i^T, (r x t_i)^T];
// v_b: B's velocity there along them. The solve finds friction forces F (N,
// along t1, t2; the wrench J^T F) such that, after the step, each sticking
// contact's relative tangential velocity is zero with |F| <= limit_static;
// a contact whose required force exceeds that slips, with |F| =
// limit_dynamic (mu_d F_n) along the force it needed: Coulomb's law, with no
// spring and no damper to tune, stable at any time step because it is part
// of the implicit step. Projected Gauss-Seidel over the contacts.
struct FrictionRow {
  Eigen::Matrix<double, 2, 6> J = Eigen::Matrix<double, 2, 6>::Zero();
  Eigen::Vector2d v_b = Eigen::Vector2d::Zero();
  double limit_static = 0.0, limit_dynamic = 0.0;   // N
  Eigen::Vector2d force = Eigen::Vector2d::Zero();  // out
  bool slipping = false;                            // out
};

// One linearized backward-Euler step (see the header comment), with the
// friction rows (may be null when count is 0) solved in it.
void step_body(const RigidBody& body, const Coupling& c, const StepInput& in, BodyState& s,
               FrictionRow* friction = nullptr, int friction_count = 0);

}  // namespace hrt
