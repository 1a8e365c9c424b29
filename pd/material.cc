#include "pd/material.h"

namespace hapticpd::pd {

namespace {
bool Touching(const PenetrationResult& result) {
  return result.status != PdStatus::kSeparated && result.status != PdStatus::kFailed;
}
}  // namespace

Vec3 PenaltyForce(const PenetrationResult& result, const Material& material) {
  if (!Touching(result)) return Vec3::Zero();
  if (result.regions.empty()) return material.stiffness * result.translation_W;
  Vec3 f = Vec3::Zero();
  for (const ContactRegion& r : result.regions) f += material.stiffness * r.local_depth_W;
  return f;
}

Wrench PenaltyWrench(const PenetrationResult& result, const Material& material,
                     const Vec3& p_WAcm) {
  Wrench w;
  w.force = PenaltyForce(result, material);
  if (!Touching(result)) return w;
  for (const ContactRegion& r : result.regions) {
    w.torque += (r.p_W - p_WAcm).cross(material.stiffness * r.local_depth_W);
  }
  return w;
}

}  // namespace hapticpd::pd
