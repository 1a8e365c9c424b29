#include "pd/scene_pd.h"

#include <chrono>

namespace hapticpd::pd {

void ComputeScenePdt(const GeometryModel& A, const Pose& X_WA, std::span<const SceneBody> bodies,
                     const PenetrationRequest& request, ScenePdData* data, ScenePdResult* result) {
  ComputeScenePd(PdMode::kTranslational, A, X_WA, bodies, request, data, result);
}

void ComputeScenePd(PdMode mode, const GeometryModel& A, const Pose& X_WA,
                    std::span<const SceneBody> bodies, const PenetrationRequest& request,
                    ScenePdData* data, ScenePdResult* result, WrenchTerms terms) {
  const auto t0 = std::chrono::steady_clock::now();
  const bool pdg = mode == PdMode::kGeneralized;
  if (!pdg && data->per_body.size() != bodies.size()) data->Resize(bodies.size());
  if (pdg && data->per_body_pdg.size() != bodies.size()) data->per_body_pdg.resize(bodies.size());
  result->bodies.resize(bodies.size());
  result->tested.resize(bodies.size());
  result->wrench = Wrench{};
  result->deepest = -1;
  result->colliding = false;
  const Vec3 cA = X_WA * A.mesh().bounds().Center();
  const double rA = A.mesh().bounding_radius();
  const Vec3 p_WAcm = X_WA * A.mass().p_MC;
  double deepest = -1;
  for (std::size_t i = 0; i < bodies.size(); ++i) {
    const SceneBody& body = bodies[i];
    PenetrationResult& r = result->bodies[i];
    const GeometryModel& B = *body.model;
    const Vec3 cB = body.X_WB * B.mesh().bounds().Center();
    const double reach = rA + B.mesh().bounding_radius();
    // Broad phase: bounding spheres apart means no contact. (Containment of
    // B in A is impossible then too.)
    if ((cA - cB).squaredNorm() > reach * reach * (1 + 1e-12)) {
      result->tested[i] = false;
      ResetPenetrationResult(mode, X_WA, &r);
      r.status = PdStatus::kSeparated;
      continue;
    }
    result->tested[i] = true;
    if (pdg) {
      ComputePdg(A, X_WA, B, body.X_WB, request, &data->per_body_pdg[i], &r);
    } else {
      ComputePdt(A, X_WA, B, body.X_WB, request, &data->per_body[i], &r);
    }
    if (r.status == PdStatus::kSeparated || r.status == PdStatus::kFailed) continue;
    result->colliding = true;
    const Wrench w = PdWrench(r, body.material, p_WAcm, terms);
    result->wrench.force += w.force;
    result->wrench.torque += w.torque;
    if (r.depth > deepest) {
      deepest = r.depth;
      result->deepest = static_cast<int>(i);
    }
  }
  result->time_us =
      std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace hapticpd::pd
