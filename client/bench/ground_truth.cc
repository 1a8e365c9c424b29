#include "client/bench/ground_truth.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "pd/pdg.h"

namespace hapticpd::bench {

using testing::FclCollide;

double DirectionalDepth(const FclModel& fa, const Pose& X, const FclModel& fb, const Vec3& u,
                        double far, int halvings) {
  if (FclCollide(fa, Pose{X.R, X.t + u * far}, fb, Pose::Identity())) return 1e300;
  double lo = 0, hi = far;
  for (int i = 0; i < halvings; ++i) {
    const double mid = 0.5 * (lo + hi);
    (FclCollide(fa, Pose{X.R, X.t + u * mid}, fb, Pose::Identity()) ? lo : hi) = mid;
  }
  return hi;
}

double SampledUpperBound(const FclModel& fa, const Pose& X, const FclModel& fb, double far,
                         std::mt19937_64& rng, int directions) {
  std::normal_distribution<double> n(0, 1);
  double best = 1e300;
  Vec3 best_u = Vec3::UnitZ();
  for (int k = 0; k < directions; ++k) {
    const Vec3 u = Vec3(n(rng), n(rng), n(rng)).normalized();
    const double d = DirectionalDepth(fa, X, fb, u, far);
    if (d < best) {
      best = d;
      best_u = u;
    }
  }
  for (double spread : {0.2, 0.05, 0.01}) {
    for (int k = 0; k < directions / 4; ++k) {
      const Vec3 u = (best_u + spread * Vec3(n(rng), n(rng), n(rng))).normalized();
      const double d = DirectionalDepth(fa, X, fb, u, far);
      if (d < best) {
        best = d;
        best_u = u;
      }
    }
  }
  return best;
}

namespace {

/// Tries direction u from pose X: the free depth along u when X moved by
/// s_max u is free (and the depth found is accepted), else 1e300. One
/// collide when the direction cannot beat s_max.
double TryDirection(const FclModel& fa, const Pose& X, const FclModel& fb, const Vec3& u,
                    double s_max, const BoundOptions& o) {
  if (!(s_max > 0)) return 1e300;
  if (FclCollide(fa, Pose{X.R, X.t + u * s_max}, fb, Pose::Identity())) return 1e300;
  const double s = DirectionalDepth(fa, X, fb, u, s_max, o.halvings);
  if (s >= 1e300) return 1e300;
  if (o.accept && !o.accept(Pose{X.R, X.t + u * s})) return 1e300;
  return s;
}

}  // namespace

double PdtUpperBound(const FclModel& fa, const Pose& X, const FclModel& fb, double far,
                     std::mt19937_64& rng, int directions, const BoundOptions& options,
                     Vec3* best_u_out) {
  std::normal_distribution<double> n(0, 1);
  double best = far;
  bool found = false;
  Vec3 best_u = Vec3::UnitZ();
  auto consider = [&](const Vec3& u) {
    const double d = TryDirection(fa, X, fb, u, best, options);
    if (d < best) {
      best = d;
      best_u = u;
      found = true;
    }
  };
  for (const Vec3& s : options.seed_directions) {
    if (s.norm() > 0) consider(s.normalized());
  }
  for (int k = 0; k < directions; ++k) consider(Vec3(n(rng), n(rng), n(rng)).normalized());
  for (double spread : {0.2, 0.05, 0.01, 0.002}) {
    for (int k = 0; k < directions / 4; ++k) {
      consider((best_u + spread * Vec3(n(rng), n(rng), n(rng))).normalized());
    }
  }
  if (best_u_out != nullptr) *best_u_out = best_u;
  return found ? best : 1e300;
}

double PdgUpperBound(const FclModel& fa, const pd::MassProperties& mp, const Pose& X,
                     const FclModel& fb, double far, std::mt19937_64& rng, int rotations,
                     int directions, double max_angle, std::span<const Pose> seed_poses,
                     const BoundOptions& options) {
  std::normal_distribution<double> n(0, 1);
  std::uniform_real_distribution<double> unit(0, 1);
  const Vec3 c_W = X * mp.p_MC;  // rotations are about the centre of mass
  double best_sigma = far * far;
  bool found = false;
  Mat3 best_dR = Mat3::Identity();
  Vec3 best_u = Vec3::UnitZ();
  // One rotation dR about the centre of mass: translation directions `us`.
  auto try_rotation = [&](const Mat3& dR, std::span<const Vec3> us) {
    const Pose Xr{dR * X.R, c_W + dR * (X.t - c_W)};
    const double sigma_rot = pd::ObjectNormSquared(mp, pd::RelativeConfiguration(mp, X, Xr));
    if (sigma_rot >= best_sigma) return;
    for (const Vec3& u0 : us) {
      if (!(u0.norm() > 0)) continue;
      const Vec3 u = u0.normalized();
      // sigma = sigma_rot + |t_C|^2 with t_C = s u: s can be at most this.
      const double s_max = std::sqrt(std::max(0.0, best_sigma - sigma_rot));
      const double s = TryDirection(fa, Xr, fb, u, s_max, options);
      if (s >= 1e300) continue;
      const Pose Xs{Xr.R, Xr.t + u * s};
      const double sigma = pd::ObjectNormSquared(mp, pd::RelativeConfiguration(mp, X, Xs));
      if (sigma < best_sigma) {
        best_sigma = sigma;
        best_dR = dR;
        best_u = u;
        found = true;
      }
    }
  };
  auto random_dirs = [&](int count, const Vec3& around, double spread) {
    std::vector<Vec3> us;
    us.push_back(around);
    for (int k = 0; k < count; ++k) {
      const Vec3 r(n(rng), n(rng), n(rng));
      us.push_back(spread > 0 ? (around + spread * r).normalized() : r.normalized());
    }
    return us;
  };
  auto random_rotation = [&](double angle) -> Mat3 {
    const Vec3 axis = Vec3(n(rng), n(rng), n(rng)).normalized();
    return Eigen::AngleAxisd(angle, axis).toRotationMatrix();
  };
  // Seeds: each seed pose's rotation, with its own translation direction.
  for (const Pose& s : seed_poses) {
    const Mat3 dR = s.R * X.R.transpose();
    const Vec3 t_C = s * mp.p_MC - c_W;
    try_rotation(dR, random_dirs(directions, t_C.norm() > 0 ? t_C : Vec3::UnitZ(), 0.1));
  }
  try_rotation(Mat3::Identity(), random_dirs(directions, best_u, 0));
  for (int k = 0; k < rotations; ++k) {
    try_rotation(random_rotation(max_angle * unit(rng)), random_dirs(directions, best_u, 0.5));
  }
  // Refine around the best rotation and direction.
  for (double spread : {0.3, 0.1, 0.03, 0.01}) {
    for (int k = 0; k < std::max(1, rotations / 2); ++k) {
      const Mat3 dR = random_rotation(spread * max_angle * unit(rng)) * best_dR;
      try_rotation(dR, random_dirs(std::max(2, directions / 4), best_u, spread));
    }
  }
  return found ? std::sqrt(best_sigma) : 1e300;
}

}  // namespace hapticpd::bench
