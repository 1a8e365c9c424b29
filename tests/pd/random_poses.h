// Seeded random poses shared by the pd test suites.
#pragma once

#include <random>

#include "pd/geometry_model.h"
#include "pd/types.h"

namespace hapticpd::testing {

/// Uniformly distributed rotation (normalised Gaussian quaternion).
inline Quat RandomRotation(std::mt19937_64& rng) {
  std::normal_distribution<double> n(0, 1);
  return Quat(n(rng), n(rng), n(rng), n(rng)).normalized();
}

/// A random orientation of A with its centre of mass near a random vertex of
/// B (Gaussian offset of `spread` metres), so that roughly half the poses
/// collide for a spread comparable to A's size.
inline Pose NearSurfacePose(const pd::GeometryModel& A, const pd::GeometryModel& B,
                            std::mt19937_64& rng, double spread) {
  std::uniform_int_distribution<std::size_t> pick(0, B.mesh().num_vertices() - 1);
  std::normal_distribution<double> n(0, 1);
  const Vec3 p = B.mesh().vertices()[pick(rng)];
  const Vec3 offset = Vec3(n(rng), n(rng), n(rng)) * spread;
  Pose X = Pose::FromQuaternion(RandomRotation(rng), Vec3::Zero());
  X.t = p + offset - X.R * A.mass().p_MC;
  return X;
}

}  // namespace hapticpd::testing
