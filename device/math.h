// Small rotation helpers shared by the device side (internal).
#pragma once

#include <algorithm>
#include <cmath>

#include "device/haptic_device.h"

namespace hapticpd::device::internal {

inline Mat3 Skew(const Vec3& w) {
  Mat3 S;
  S << 0, -w.z(), w.y(), w.z(), 0, -w.x(), -w.y(), w.x(), 0;
  return S;
}

/// Rotation vector theta*u of R (shortest arc, theta in [0, pi]).
inline Vec3 LogRotation(const Mat3& R) {
  Quat q(R);
  if (q.w() < 0) q.coeffs() *= -1;
  const Vec3 v = q.vec();
  const double s = v.norm();
  if (s < 1e-12) return 2.0 * v;
  return v * (2.0 * std::atan2(s, q.w()) / s);
}

/// Rotation matrix of the rotation vector w (exponential map).
inline Mat3 ExpRotation(const Vec3& w) {
  const double a = w.norm();
  if (a < 1e-12) return Mat3::Identity() + Skew(w);
  return Eigen::AngleAxisd(a, w / a).toRotationMatrix();
}

/// Re-orthonormalises a rotation matrix that drifted by integration.
inline Mat3 Orthonormalize(const Mat3& R) { return Quat(R).normalized().toRotationMatrix(); }

/// Scales v down to at most `limit` in norm (limit <= 0: zero). A
/// non-finite v (or one whose norm overflows) gives zero: this is the last
/// step before a motor.
inline Vec3 ClampNorm(const Vec3& v, double limit) {
  if (limit <= 0) return Vec3::Zero();
  const double n = v.norm();
  if (!std::isfinite(n)) return Vec3::Zero();
  return n > limit ? Vec3(v * (limit / n)) : v;
}

/// Cubic smoothstep of u clamped to [0, 1].
inline double SmoothStep(double u) {
  u = std::clamp(u, 0.0, 1.0);
  return u * u * (3.0 - 2.0 * u);
}

}  // namespace hapticpd::device::internal
