// Scalar, vector, pose and wrench aliases shared by every module.
//
// Conventions (see ../shared/docs/DESIGN.md "Contracts"):
//   * SI units: metres, kilograms, seconds, newtons.
//   * Frames are named in the Drake monogram style: `X_WB` is the pose of frame
//     B in frame W, `p_WQ` is point Q measured and expressed in W, `v_W` a
//     vector expressed in W.
//   * Poses are a rotation matrix plus translation; on the wire they are a
//     translation and a unit quaternion (w, x, y, z).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cmath>
#include <cstdint>

namespace hapticpd {

using Scalar = double;
using Vec2 = Eigen::Vector2d;
using Vec3 = Eigen::Vector3d;
using Vec6 = Eigen::Matrix<double, 6, 1>;
using Mat3 = Eigen::Matrix3d;
using Mat6 = Eigen::Matrix<double, 6, 6>;
using Quat = Eigen::Quaterniond;

/// The one unit-quaternion rule, wherever a rotation comes in as a
/// quaternion (RPCs, scene files, the CLI, replay files, the server's
/// answers on the device side): a norm within this of 1 is taken and
/// normalised; any other, and any non-finite one, is refused with an error
/// naming the field. Wide enough for a float's round trip and six printed
/// digits, narrow enough to catch components in the wrong order.
inline constexpr double kUnitQuaternionTolerance = 1e-3;

/// True when `q` passes the rule above (false for NaN and infinities).
inline bool IsUnitQuaternion(const Quat& q) {
  return std::abs(q.norm() - 1.0) <= kUnitQuaternionTolerance;
}

/// A rigid transform X_AB: maps coordinates in frame B to frame A,
/// p_A = R * p_B + t. `R` is orthonormal with det +1.
struct Pose {
  Mat3 R = Mat3::Identity();
  Vec3 t = Vec3::Zero();

  static Pose Identity() { return Pose{}; }
  static Pose FromTranslation(const Vec3& t) { return Pose{Mat3::Identity(), t}; }
  /// `q` need not be normalised; it is normalised here.
  static Pose FromQuaternion(const Quat& q, const Vec3& t) {
    return Pose{q.normalized().toRotationMatrix(), t};
  }

  Vec3 operator*(const Vec3& p) const { return R * p + t; }
  /// Composition: (X_AB * X_BC) = X_AC.
  Pose operator*(const Pose& o) const { return Pose{R * o.R, R * o.t + t}; }
  Pose Inverse() const {
    Mat3 Rt = R.transpose();
    return Pose{Rt, -(Rt * t)};
  }
  Vec3 Rotate(const Vec3& v) const { return R * v; }
  Quat Rotation() const { return Quat(R); }
};

/// A body frame X_WB carried `dt` seconds along the twist (v_W, w_W), both
/// in W: the translation moves by v dt, the orientation turns by the
/// rotation vector w dt (left-multiplied). The one definition of where a
/// moving body is, shared by the server's PD and the device's patches.
inline Pose MovedPose(const Pose& X_WB, const Vec3& v_W, const Vec3& w_W, double dt) {
  Pose X = X_WB;
  X.t += dt * v_W;
  const Vec3 theta = dt * w_W;
  const double angle = theta.norm();
  if (angle > 0) X.R = Eigen::AngleAxisd(angle, theta / angle).toRotationMatrix() * X.R;
  return X;
}

/// A force/torque pair; the frame and the point the torque is taken about are
/// part of the variable name (e.g. `F_Pcm_W`: on P about its centre of mass,
/// expressed in W).
struct Wrench {
  Vec3 force = Vec3::Zero();
  Vec3 torque = Vec3::Zero();
};

using Index = std::int32_t;

}  // namespace hapticpd
