#include "tests/oracles/fcl_oracle.h"

#include <fcl/fcl.h>

#include "pd/convex_hull.h"

namespace hapticpd::testing {

struct FclModel::Impl {
  std::shared_ptr<fcl::BVHModel<fcl::OBBRSSd>> geom;
  // Built once: constructing a CollisionObject walks every vertex to compute
  // its local AABB, which would otherwise be charged to each query.
  std::unique_ptr<fcl::CollisionObjectd> object;
};

FclModel::FclModel(const pd::Mesh& mesh) : impl_(std::make_unique<Impl>()) {
  std::vector<fcl::Vector3d> v(mesh.vertices().begin(), mesh.vertices().end());
  std::vector<fcl::Triangle> t;
  t.reserve(mesh.num_triangles());
  for (const auto& f : mesh.triangles()) t.emplace_back(f[0], f[1], f[2]);
  impl_->geom = std::make_shared<fcl::BVHModel<fcl::OBBRSSd>>();
  impl_->geom->beginModel(static_cast<int>(t.size()), static_cast<int>(v.size()));
  impl_->geom->addSubModel(v, t);
  impl_->geom->endModel();
  impl_->object = std::make_unique<fcl::CollisionObjectd>(impl_->geom);
}

FclModel::~FclModel() = default;

namespace {
fcl::Transform3d ToFcl(const Pose& X) {
  fcl::Transform3d T = fcl::Transform3d::Identity();
  T.linear() = X.R;
  T.translation() = X.t;
  return T;
}
fcl::CollisionObjectd& Place(const FclModel& m, const Pose& X) {
  m.impl().object->setTransform(ToFcl(X));
  m.impl().object->computeAABB();
  return *m.impl().object;
}
}  // namespace

bool FclCollide(const FclModel& a, const Pose& X_WA, const FclModel& b, const Pose& X_WB) {
  fcl::CollisionObjectd& oa = Place(a, X_WA);
  fcl::CollisionObjectd& ob = Place(b, X_WB);
  fcl::CollisionRequestd req;
  fcl::CollisionResultd res;
  fcl::collide(&oa, &ob, req, res);
  return res.isCollision();
}

int FclContacts(const FclModel& a, const Pose& X_WA, const FclModel& b, const Pose& X_WB,
                int max_contacts) {
  fcl::CollisionObjectd& oa = Place(a, X_WA);
  fcl::CollisionObjectd& ob = Place(b, X_WB);
  fcl::CollisionRequestd req(static_cast<std::size_t>(max_contacts), true);
  fcl::CollisionResultd res;
  fcl::collide(&oa, &ob, req, res);
  return static_cast<int>(res.numContacts());
}

double FclDistance(const FclModel& a, const Pose& X_WA, const FclModel& b, const Pose& X_WB) {
  fcl::CollisionObjectd& oa = Place(a, X_WA);
  fcl::CollisionObjectd& ob = Place(b, X_WB);
  fcl::DistanceRequestd req;
  req.enable_nearest_points = false;
  fcl::DistanceResultd res;
  fcl::distance(&oa, &ob, req, res);
  return std::max(0.0, res.min_distance);
}

struct FclConvex::Impl {
  std::shared_ptr<fcl::Convexd> geom;
  std::unique_ptr<fcl::CollisionObjectd> object;
};

FclConvex::FclConvex(const pd::Mesh& mesh) : impl_(std::make_unique<Impl>()) {
  const pd::Mesh hull = pd::ConvexHull(mesh.vertices());
  auto v =
      std::make_shared<std::vector<fcl::Vector3d>>(hull.vertices().begin(), hull.vertices().end());
  auto f = std::make_shared<std::vector<int>>();
  f->reserve(4 * hull.num_triangles());
  for (const auto& t : hull.triangles()) f->insert(f->end(), {3, t[0], t[1], t[2]});
  impl_->geom = std::make_shared<fcl::Convexd>(v, static_cast<int>(hull.num_triangles()), f);
  impl_->object = std::make_unique<fcl::CollisionObjectd>(impl_->geom);
}

FclConvex::~FclConvex() = default;

FclPenetration FclConvexPenetration(const FclConvex& a, const Pose& X_WA, const FclConvex& b,
                                    const Pose& X_WB) {
  a.impl().object->setTransform(ToFcl(X_WA));
  a.impl().object->computeAABB();
  b.impl().object->setTransform(ToFcl(X_WB));
  b.impl().object->computeAABB();
  fcl::CollisionRequestd req(1, true);
  fcl::CollisionResultd res;
  fcl::collide(a.impl().object.get(), b.impl().object.get(), req, res);
  FclPenetration out;
  out.colliding = res.isCollision();
  if (out.colliding && res.numContacts() > 0)
    out.depth = std::abs(res.getContact(0).penetration_depth);
  return out;
}

}  // namespace hapticpd::testing
