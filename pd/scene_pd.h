// PD of one probe against a scene of several bodies: a bounding-sphere broad
// phase skips far bodies, PD runs against each body the probe may touch, and
// the penalty wrenches are summed into one.
#pragma once

#include <span>
#include <vector>

#include "pd/material.h"
#include "pd/pdg.h"
#include "pd/pdt.h"

namespace hapticpd::pd {

struct SceneBody {
  ModelPtr model;
  Pose X_WB;
  Material material;
};

/// Per-session state: one PdQueryData (PDt) and one PdgQueryData (PDg)
/// coherence cache per body; only the method in use grows its own.
class ScenePdData {
 public:
  /// Sizes the per-body state; call when the body list changes.
  void Resize(std::size_t bodies) { per_body.resize(bodies); }
  std::vector<PdQueryData> per_body;
  std::vector<PdgQueryData> per_body_pdg;
};

struct ScenePdResult {
  std::vector<PenetrationResult> bodies;  ///< one per scene body
  std::vector<bool> tested;               ///< false when the broad phase skipped the body
  Wrench wrench;                          ///< summed penalty wrench on the probe (W, about its CoM)
  int deepest = -1;                       ///< index of the deepest body, -1 when none collides
  bool colliding = false;
  double time_us = 0;
};

/// Translational PD of probe A against every body. Resizes `data` and
/// `result` to the body count (allocation happens only when it changes).
void ComputeScenePdt(const GeometryModel& A, const Pose& X_WA, std::span<const SceneBody> bodies,
                     const PenetrationRequest& request, ScenePdData* data, ScenePdResult* result);

/// PD of probe A against every body by either method: PDt as above, or PDg
/// (ComputePdg per body; the wrench is the sum of PdgWrench over the bodies,
/// `deepest` the body with the largest sqrt(sigma)). `terms` kForceOnly (a
/// scene without torque) sums the forces only: result->wrench.torque is zero
/// and no torque term is computed (PdWrench).
void ComputeScenePd(PdMode mode, const GeometryModel& A, const Pose& X_WA,
                    std::span<const SceneBody> bodies, const PenetrationRequest& request,
                    ScenePdData* data, ScenePdResult* result,
                    WrenchTerms terms = WrenchTerms::kForceAndTorque);

}  // namespace hapticpd::pd
