// The math types every part of the runtime shares: vectors and matrices
// (Eigen), the pose of a bundle's object frame, rotation vectors. A header of
// its own so that a part needing a pose (a device, the device loop) does not
// include the model, the contact or the JSON headers.
//
// Conventions (docs/bundle-format.md): meters, radians; a pose maps a
// bundle's object frame into the world, p_world = rotation * p_object +
// position; quaternions are written x, y, z, w outside the code.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace hrt {

using Vec2f = Eigen::Vector2f;
using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;
using Vec6 = Eigen::Matrix<double, 6, 1>;  // a wrench (force, torque) or a twist (linear, angular)
using Mat6 = Eigen::Matrix<double, 6, 6>;

// Pose of a bundle's object frame in the world: p_world = rotation * p_object + position.
struct Pose {
  Vec3 position = Vec3::Zero();
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();  // unit; written x, y, z, w outside

  Eigen::Isometry3d iso() const {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = rotation.toRotationMatrix();
    T.translation() = position;
    return T;
  }
};

// Rotation vector (angle times axis) of a unit quaternion, the short way
// (q and -q are the same rotation; the short one keeps |angle| <= pi), and
// its inverse, the quaternion of a rotation vector.
Vec3 rotation_vector(Eigen::Quaterniond q);
Eigen::Quaterniond exp_rotation(const Vec3& r);

}  // namespace hrt
