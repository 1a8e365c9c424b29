// FCL 0.7 as an independent oracle for tests and as a peer in benchmarks.
// Only boolean collide and distance are trusted (../shared/docs/PEERS.md):
// FCL's contact penetration depth and its CCD are not.
#pragma once

#include <memory>

#include "pd/mesh.h"
#include "pd/types.h"

namespace hapticpd::testing {

/// An FCL OBBRSS model of a mesh. Not thread-safe: queries move its one
/// collision object (a model used as both A and B in one call is not supported).
/// An FCL OBBRSS model of a mesh (OBBRSS: with AABB or RSS FCL refits both
/// models on every mesh-mesh query, PEERS.md).
class FclModel {
 public:
  explicit FclModel(const pd::Mesh& mesh);
  ~FclModel();
  FclModel(const FclModel&) = delete;
  FclModel& operator=(const FclModel&) = delete;

  struct Impl;
  Impl& impl() const { return *impl_; }

 private:
  std::unique_ptr<Impl> impl_;
};

/// Do the surfaces intersect? (FCL does not detect containment.)
bool FclCollide(const FclModel& a, const Pose& X_WA, const FclModel& b, const Pose& X_WB);

/// Number of contacts with all contacts enabled (capped at max_contacts):
/// the "per-triangle-pair depths" substitute users reach for.
int FclContacts(const FclModel& a, const Pose& X_WA, const FclModel& b, const Pose& X_WB,
                int max_contacts = 100000);

/// FCL's convex shape (fcl::Convex) of a mesh's convex hull, for its
/// GJK/EPA penetration query (the peer `hapticpd-bench peers` compares with).
class FclConvex {
 public:
  explicit FclConvex(const pd::Mesh& mesh);  ///< convex hull of the vertices
  ~FclConvex();
  FclConvex(const FclConvex&) = delete;
  FclConvex& operator=(const FclConvex&) = delete;
  struct Impl;
  Impl& impl() const { return *impl_; }

 private:
  std::unique_ptr<Impl> impl_;
};

struct FclPenetration {
  bool colliding = false;
  double depth = 0;  ///< FCL's contact penetration depth (unreliable in 0.7, PEERS.md)
};

/// Collide of the two hulls with one contact requested (libccd GJK/EPA).
FclPenetration FclConvexPenetration(const FclConvex& a, const Pose& X_WA, const FclConvex& b,
                                    const Pose& X_WB);

/// Surface distance (0 when they intersect).
double FclDistance(const FclModel& a, const Pose& X_WA, const FclModel& b, const Pose& X_WB);

}  // namespace hapticpd::testing
