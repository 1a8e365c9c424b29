#include "tests/oracles/bullet_oracle.h"

#include <BulletCollision/CollisionShapes/btConvexHullShape.h>
#include <BulletCollision/NarrowPhaseCollision/btGjkEpa2.h>
#include <LinearMath/btConvexHullComputer.h>

#include <algorithm>

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

BulletHullSummary BulletConvexHull(std::span<const Vec3> points) {
  std::vector<double> coords;
  coords.reserve(3 * points.size());
  for (const Vec3& p : points) coords.insert(coords.end(), {p.x(), p.y(), p.z()});
  btConvexHullComputer hull;
  hull.compute(coords.data(), 3 * sizeof(double), static_cast<int>(points.size()), 0, 0);
  BulletHullSummary out;
  for (int i = 0; i < hull.original_vertex_index.size(); ++i) {
    out.input_vertices.push_back(hull.original_vertex_index[i]);
  }
  std::sort(out.input_vertices.begin(), out.input_vertices.end());
  out.faces = hull.faces.size();
  // Bullet's own vertices are rounded to its fixed-point grid; use the input
  // points they came from.
  auto at = [&](int v) { return points[hull.original_vertex_index[v]]; };
  for (int f = 0; f < hull.faces.size(); ++f) {
    // Fan over the face's counter-clockwise boundary.
    const btConvexHullComputer::Edge* first = &hull.edges[hull.faces[f]];
    const Vec3 a = at(first->getSourceVertex());
    for (const btConvexHullComputer::Edge* e = first->getNextEdgeOfFace();
         e->getTargetVertex() != first->getSourceVertex(); e = e->getNextEdgeOfFace()) {
      out.volume += a.dot(at(e->getSourceVertex()).cross(at(e->getTargetVertex()))) / 6;
    }
  }
  return out;
}

}  // namespace hapticpd::testing
