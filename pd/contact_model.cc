#include "pd/contact_model.h"

#include <algorithm>

namespace hapticpd::pd {
namespace {

void SetValidity(const GeometryModel& probe, double depth, const ContactModelOptions& o,
                 ContactModel* m) {
  m->validity_radius = o.validity_fraction * probe.mesh().bounding_radius() + depth;
  m->validity_angle = m->validity_radius / std::max(probe.radius_about_com(), 1e-12);
}

void Reset(const Pose& X_WA, ContactModel* m) {
  m->outcome = ContactOutcome::kSeparated;
  m->rows.clear();
  m->deepest = -1;
  m->depth = 0;
  m->pd_translation_W.setZero();
  m->X_WA_target = X_WA;
  m->target_stiffness = 0;
  m->target_rotational_stiffness = 0;
  m->generalized = false;
  m->sigma = 0;
  m->rotation_angle = 0;
  m->rotation_axis_W.setZero();
  m->wrench = Wrench{};
}

}  // namespace

void EmptyContactModel(const GeometryModel& probe, const Pose& X_WA,
                       const ContactModelOptions& options, ContactModel* out) {
  Reset(X_WA, out);
  out->c_W = X_WA * probe.mass().p_MC;
  SetValidity(probe, 0, options, out);
}

void BuildContactModel(const GeometryModel& probe, const Pose& X_WA,
                       const std::vector<SceneBody>& bodies, const ScenePdResult& result,
                       const ContactModelOptions& options, ContactModel* out) {
  Reset(X_WA, out);
  out->c_W = X_WA * probe.mass().p_MC;
  bool failed = false, capped = false;
  for (std::size_t i = 0; i < bodies.size() && i < result.bodies.size(); ++i) {
    if (i < result.tested.size() && !result.tested[i]) continue;  // the broad phase skipped it
    const PenetrationResult& r = result.bodies[i];
    if (r.status == PdStatus::kFailed) failed = true;
    if (r.status == PdStatus::kPenetratingCapReached) capped = true;
    if (r.status != PdStatus::kPenetratingSolved && r.status != PdStatus::kPenetratingCapReached) {
      continue;
    }
    const Material& mat = bodies[i].material;
    auto add = [&](const Vec3& p, const Vec3& n, double depth) {
      if (!(depth > 0)) return;
      out->rows.push_back(ContactRow{p, n, depth, static_cast<int>(i), mat});
    };
    // No regions (PDg, or PDt without them): one row at the centre of mass
    // along the answer's translation (for PDg the translation's length, not
    // sqrt(sigma), is how far it moves the centre of mass).
    if (const double len = r.translation_W.norm(); r.regions.empty() && len > 0) {
      add(out->c_W, r.translation_W / len, len);
    }
    for (const ContactRegion& g : r.regions) add(g.p_W, g.n_W, g.depth);
  }
  out->outcome = failed             ? ContactOutcome::kFailed
                 : capped           ? ContactOutcome::kCapReached
                 : result.colliding ? ContactOutcome::kPenetrating
                                    : ContactOutcome::kSeparated;
  out->wrench = result.wrench;
  if (result.deepest >= 0 && static_cast<std::size_t>(result.deepest) < bodies.size()) {
    const PenetrationResult& d = result.bodies[static_cast<std::size_t>(result.deepest)];
    const Material& mat = bodies[static_cast<std::size_t>(result.deepest)].material;
    out->deepest = result.deepest;
    out->depth = d.depth;
    out->pd_translation_W = d.translation_W;
    out->X_WA_target = d.X_WA_result;
    out->target_stiffness = mat.stiffness;
    out->target_rotational_stiffness = mat.rotational_stiffness;
    if (d.mode == PdMode::kGeneralized) {
      out->generalized = true;
      out->sigma = d.sigma;
      out->rotation_angle = d.rotation_angle;
      out->rotation_axis_W = d.rotation_axis_W;
    }
  }
  SetValidity(probe, out->depth, options, out);
}

}  // namespace hapticpd::pd
