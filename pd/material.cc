#include "pd/material.h"

namespace hapticpd::pd {

// PenaltyWrench itself lives in pdt.cc (next to the region clustering).
Vec3 PenaltyForce(const PenetrationResult& result, const Material& material) {
  if (result.status == PdStatus::kSeparated || result.status == PdStatus::kFailed) {
    return Vec3::Zero();
  }
  if (result.regions.empty()) return material.stiffness * result.translation_W;
  Vec3 f = Vec3::Zero();
  for (const ContactRegion& r : result.regions) f += material.stiffness * r.local_depth_W;
  return f;
}

}  // namespace hapticpd::pd
