// Contact material of a scene body and the penalty wrench from a PD result.
#pragma once

#include <cstdint>

#include "pd/penetration.h"
#include "pd/types.h"

namespace hapticpd::pd {

struct Material {
  double stiffness = 1000.0;           ///< k, N/m (translational penalty)
  double rotational_stiffness = 0.05;  ///< xi, N m/rad (PDg rotation spring)
  double damping = 0.0;                ///< N s/m inside contact
  double static_friction = 0.0;        ///< mu_s
  double dynamic_friction = 0.0;       ///< mu_d
};

/// Penalty wrench on the probe from a PD result (seed eqs. 3-7 for PDt):
/// f = sum_i k d_i with d_i = (d . n_i) n_i over the contact regions, and
/// tau = sum_i (p_i - c) x f_i about the probe's centre of mass `p_WAcm` at
/// its query pose. Falls back to f = k d at the centre of mass when the result
/// has no regions. Zero wrench for a separated or failed result.
Wrench PenaltyWrench(const PenetrationResult& result, const Material& material, const Vec3& p_WAcm);

/// Which terms of a contact wrench to compute: a scene without torque (a
/// 3-DoF device) asks for the force only, and the torque stays zero without
/// being computed.
enum class WrenchTerms : std::uint8_t { kForceAndTorque, kForceOnly };

/// The force of PenaltyWrench alone (same value, no torque terms).
Vec3 PenaltyForce(const PenetrationResult& result, const Material& material);

}  // namespace hapticpd::pd
