// Reference answers for the accuracy benchmark (`hapticpd-bench accuracy`)
// and the PD tests: upper bounds on PDt and PDg found by sampling free
// configurations with FCL's boolean collide (an implementation independent
// of pd/). Every returned bound is a configuration that FCL reports free
// (and, when a check is given, that the check accepts), so it is a true
// upper bound on the penetration depth up to FCL's verdict.
#pragma once

#include <functional>
#include <random>
#include <span>

#include "pd/mass_properties.h"
#include "pd/types.h"
#include "tests/oracles/fcl_oracle.h"

namespace hapticpd::bench {

using testing::FclModel;

/// Smallest free translation of A (pose X, B at the identity) along the unit
/// direction u, by bisection on [0, far] with FCL collide (`halvings`
/// halvings); 1e300 when X moved by far u still collides.
double DirectionalDepth(const FclModel& fa, const Pose& X, const FclModel& fb, const Vec3& u,
                        double far, int halvings = 40);

/// Upper bound on PDt by directional sampling: `directions` random
/// directions, then directions / 4 around the best at spreads 0.2, 0.05 and
/// 0.01. Returns 1e300 if no direction frees A within `far`.
double SampledUpperBound(const FclModel& fa, const Pose& X, const FclModel& fb, double far,
                         std::mt19937_64& rng, int directions);

struct BoundOptions {
  /// Directions tried first (e.g. answers of the methods under test, so that
  /// the sampling refines around them). Need not be unit.
  std::span<const Vec3> seed_directions;
  /// Accepts a candidate free pose (e.g. a containment-aware collision check:
  /// FCL does not see a probe wholly inside the scene). Empty: accept all.
  std::function<bool(const Pose&)> accept;
  int halvings = 40;
};

/// Directional sampling as SampledUpperBound, plus the seed directions, and
/// pruned: a direction is bisected only when it is free at the best depth
/// so far (one collide otherwise), so many more directions fit in the same
/// time. `*best_u` (optional) receives the best direction.
double PdtUpperBound(const FclModel& fa, const Pose& X, const FclModel& fb, double far,
                     std::mt19937_64& rng, int directions, const BoundOptions& options,
                     Vec3* best_u = nullptr);

/// Upper bound on PDg (the square root of the object-norm sigma, m): the
/// smallest sigma of a sampled free pose. Rotations about A's centre of mass
/// (the identity, the seed poses' rotations, `rotations` random ones up to
/// `max_angle` and refinements around the best), each with `directions`
/// translation directions (plus the seed poses' own), pruned as in
/// PdtUpperBound. `seed_poses` are full poses of A (e.g. PDg and PDt answers).
double PdgUpperBound(const FclModel& fa, const pd::MassProperties& mp, const Pose& X,
                     const FclModel& fb, double far, std::mt19937_64& rng, int rotations,
                     int directions, double max_angle, std::span<const Pose> seed_poses,
                     const BoundOptions& options);

}  // namespace hapticpd::bench
