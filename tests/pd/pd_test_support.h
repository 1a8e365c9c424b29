// Helpers shared by the PD test suites (PDt, PDg, stability): request
// presets, the non-convex test pairs, independent FCL verification of PD
// answers, an independent brute-force separating-axis PDt for convex
// polytopes, and the consistency of a PDt result's three views.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "pd/mesh.h"
#include "pd/penetration.h"
#include "pd/queries.h"
#include "pd/shapes.h"
#include "tests/alloc_counter.h"
#include "tests/oracles/fcl_oracle.h"

namespace hapticpd::pd {

/// A request without motion coherence: every query is a cold start.
inline PenetrationRequest ColdRequest() {
  PenetrationRequest req;
  req.use_coherence = false;
  return req;
}

struct NonConvexCase {
  const char* name;
  Mesh a, b;
  double spread;  ///< NearSurfacePose spread (m)
};

inline std::vector<NonConvexCase> NonConvexCases() {
  std::vector<NonConvexCase> v;
  v.push_back({"box-torus", shapes::Box(Vec3(0.01, 0.01, 0.04)), shapes::Torus(), 0.005});
  v.push_back({"stick-torusknot", shapes::Stick(), shapes::TorusKnot(), 0.004});
  v.push_back({"spoon-cup", shapes::Spoon(), shapes::Cup(), 0.004});
  v.push_back({"torus-cup", shapes::Torus(0.03, 0.01, 24, 12), shapes::Cup(), 0.004});
  return v;
}

/// Independent contact check of a PD answer along its own motion, the rigid
/// interpolating motion (InterpolateRigid about A's centre of mass `p_AC`)
/// from the query pose X_WA to the answer: pushed a tiny fraction `rel` of
/// that motion further, the probe is free; pulled back by the same fraction,
/// it collides (FCL boolean collide). For PDt the motion is the translation.
inline void ExpectRealContactAlongMotion(const testing::FclModel& fa, const testing::FclModel& fb,
                                         const Pose& X_WB, const Pose& X_WA, const Vec3& p_AC,
                                         const PenetrationResult& r, double rel = 1e-6) {
  ASSERT_GT(r.depth, 0);
  const Pose out = InterpolateRigid(X_WA, r.X_WA_result, p_AC, 1 + rel);
  const Pose in = InterpolateRigid(X_WA, r.X_WA_result, p_AC, 1 - rel);
  EXPECT_FALSE(testing::FclCollide(fa, out, fb, X_WB))
      << "answer is an over-push: not free when pushed out";
  EXPECT_TRUE(testing::FclCollide(fa, in, fb, X_WB))
      << "answer is not a contact: free when pulled in";
}

/// The PDt form: pushed out along the PD translation by a fraction of the
/// depth, free; pulled in by the same fraction, colliding.
inline void ExpectRealContact(const testing::FclModel& fa, const testing::FclModel& fb,
                              const Pose& X_WB, const PenetrationResult& r, double rel = 1e-6) {
  ASSERT_GT(r.depth, 0);
  const Vec3 u = r.translation_W / r.depth;
  const double step = std::max(rel * r.depth, 1e-12);
  const Pose out{r.X_WA_result.R, r.X_WA_result.t + u * step};
  const Pose in{r.X_WA_result.R, r.X_WA_result.t - u * step};
  EXPECT_FALSE(testing::FclCollide(fa, out, fb, X_WB))
      << "answer is an over-push: not free when pushed out";
  EXPECT_TRUE(testing::FclCollide(fa, in, fb, X_WB))
      << "answer is not a contact: free when pulled in";
}

/// Heap allocations made by `query(pose)` over `poses` after two warm-up
/// passes over the same poses (so that coherence caches and every buffer,
/// the caller's result vectors included, have seen their working sizes).
template <class Query>
std::size_t AllocationsAfterWarmUp(const std::vector<Pose>& poses, Query query) {
  for (int pass = 0; pass < 2; ++pass) {
    for (const Pose& X : poses) query(X);
  }
  testing::CountAllocations counter;
  for (const Pose& X : poses) query(X);
  return counter.count();
}

// Exact PDt of two convex polytopes by brute force over every candidate axis
// (face normals of both, cross products of every edge pair); written
// independently of pd/convex.cc (no Gauss-map pruning, supports by scan).
inline double BruteForceConvexPdt(const Mesh& a, const Pose& X_WA, const Mesh& b, const Pose& X_WB,
                                  Vec3* dir) {
  std::vector<Vec3> va, vb, axes;
  for (const Vec3& v : a.vertices()) va.push_back(X_WA * v);
  for (const Vec3& v : b.vertices()) vb.push_back(X_WB * v);
  for (const Vec3& n : a.face_normals()) axes.push_back(X_WA.R * n);
  for (const Vec3& n : b.face_normals()) axes.push_back(X_WB.R * n);
  for (const Edge& ea : a.edges()) {
    const Vec3 da = X_WA.R * (a.vertices()[ea.v[1]] - a.vertices()[ea.v[0]]);
    for (const Edge& eb : b.edges()) {
      const Vec3 c = da.cross(X_WB.R * (b.vertices()[eb.v[1]] - b.vertices()[eb.v[0]]));
      if (c.norm() > 1e-12) axes.push_back(c.normalized());
    }
  }
  double best = std::numeric_limits<double>::infinity();
  for (const Vec3& axis : axes) {
    for (double sign : {1.0, -1.0}) {
      const Vec3 u = sign * axis;
      double max_b = -std::numeric_limits<double>::infinity();
      double min_a = std::numeric_limits<double>::infinity();
      for (const Vec3& p : vb) max_b = std::max(max_b, u.dot(p));
      for (const Vec3& p : va) min_a = std::min(min_a, u.dot(p));
      if (max_b - min_a < best) {
        best = max_b - min_a;
        *dir = u;
      }
    }
  }
  return best;
}

// The three views of one answer agree: depth, PD vector and result pose.
inline void ExpectConsistent(const Pose& X_WA, const PenetrationResult& r) {
  EXPECT_NEAR(r.translation_W.norm(), r.depth, 1e-12 * (1 + r.depth));
  EXPECT_LT((r.X_WA_result.t - X_WA.t - r.translation_W).norm(), 1e-12 * (1 + X_WA.t.norm()));
  EXPECT_LT((r.X_WA_result.R - X_WA.R).norm(), 1e-12);  // PDt never rotates
}

}  // namespace hapticpd::pd
