// Bullet's GJK/EPA (double-precision build) on convex hulls: the convex-pair
// cross-check for PDt (PEERS.md: exact on 1,504 random box pairs).
#pragma once

#include <memory>
#include <span>
#include <vector>

#include "pd/mesh.h"
#include "pd/types.h"

namespace hapticpd::testing {

class BulletHull {
 public:
  explicit BulletHull(const pd::Mesh& mesh);  ///< convex hull of the vertices
  ~BulletHull();
  BulletHull(const BulletHull&) = delete;
  BulletHull& operator=(const BulletHull&) = delete;
  struct Impl;
  Impl& impl() const { return *impl_; }

 private:
  std::unique_ptr<Impl> impl_;
};

struct EpaResult {
  bool penetrating = false;
  double depth = 0;              ///< >= 0
  Vec3 normal_W = Vec3::Zero();  ///< direction to move A out of B
};

EpaResult BulletPenetration(const BulletHull& a, const Pose& X_WA, const BulletHull& b,
                            const Pose& X_WB);

/// Bullet's convex hull of a point set (btConvexHullComputer: Preparata-Hong
/// on coordinates rounded to a fixed-point grid, so nearly coplanar points may
/// merge; an independent reference for clouds in general position).
struct BulletHullSummary {
  std::vector<int> input_vertices;  ///< input indices of the hull vertices, sorted
  int faces = 0;                    ///< planar n-gons (coplanar triangles merged)
  double volume = 0;                ///< of Bullet's faces (fan-triangulated) over the input points
};
BulletHullSummary BulletConvexHull(std::span<const Vec3> points);

}  // namespace hapticpd::testing
