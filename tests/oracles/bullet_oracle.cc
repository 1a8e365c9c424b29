#include "tests/oracles/bullet_oracle.h"

#include <BulletCollision/CollisionShapes/btConvexHullShape.h>
#include <BulletCollision/NarrowPhaseCollision/btGjkEpa2.h>

namespace hapticpd::testing {

struct BulletHull::Impl {
  btConvexHullShape shape;
};

BulletHull::BulletHull(const pd::Mesh& mesh) : impl_(std::make_unique<Impl>()) {
  for (const Vec3& v : mesh.vertices()) {
    impl_->shape.addPoint(btVector3(v.x(), v.y(), v.z()), false);
  }
  impl_->shape.recalcLocalAabb();
  impl_->shape.setMargin(0);
}

BulletHull::~BulletHull() = default;

namespace {
btTransform ToBt(const Pose& X) {
  btMatrix3x3 R(X.R(0, 0), X.R(0, 1), X.R(0, 2), X.R(1, 0), X.R(1, 1), X.R(1, 2), X.R(2, 0),
                X.R(2, 1), X.R(2, 2));
  return btTransform(R, btVector3(X.t.x(), X.t.y(), X.t.z()));
}
}  // namespace

EpaResult BulletPenetration(const BulletHull& a, const Pose& X_WA, const BulletHull& b,
                            const Pose& X_WB) {
  btGjkEpaSolver2::sResults res;
  EpaResult out;
  const btVector3 guess(1, 0, 0);
  if (btGjkEpaSolver2::Penetration(&a.impl().shape, ToBt(X_WA), &b.impl().shape, ToBt(X_WB), guess,
                                   res, false)) {
    out.penetrating = true;
    out.depth = -res.distance;
    // res.normal points from A to B; A moves the other way.
    out.normal_W = -Vec3(res.normal.x(), res.normal.y(), res.normal.z());
  }
  return out;
}

}  // namespace hapticpd::testing
