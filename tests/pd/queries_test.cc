// Collision, containment, proximity, distance and CCD: known answers on
// analytic shapes, brute force on small meshes, and FCL as the independent
// oracle on seeded random poses.
#include "pd/queries.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <set>
#include <tuple>

#include "pd/primitives.h"
#include "pd/shapes.h"
#include "tests/oracles/fcl_oracle.h"
#include "tests/pd/random_poses.h"
#include "tests/test_util.h"

namespace hapticpd::pd {
namespace {

using testing::FclCollide;
using testing::FclDistance;
using testing::FclModel;
using testing::NearSurfacePose;
using testing::RandomRotation;

Pose RotZ(double angle, const Vec3& t) {
  return Pose{Eigen::AngleAxisd(angle, Vec3::UnitZ()).toRotationMatrix(), t};
}

// --------------------------------------------------------------------------
// Known answers

TEST(Collide, BoxesAtKnownOffsets) {
  const ModelPtr box = MakeModel(shapes::Box(Vec3::Ones()));
  QueryScratch s;
  CollisionResult r;
  const CollisionRequest req;
  const Pose X_WB = RotZ(0.3, Vec3(5, -2, 1));
  for (double angle : {0.0, 0.2, M_PI / 4}) {
    // Along B's local x: touching at 2 (axis aligned) or at 1 + extent.
    const double reach = 1 + std::cos(angle) + std::sin(angle);
    for (double gap : {-0.1, -1e-6, 1e-6, 0.1}) {
      const Pose X_BA = RotZ(angle, Vec3(reach + gap, 0.0, 0.2));
      const bool hit = Collide(*box, X_WB * X_BA, *box, X_WB, req, &r, &s);
      EXPECT_EQ(hit, gap < 0) << "angle " << angle << " gap " << gap;
      if (gap > 0) {
        DistanceResult d;
        EXPECT_NEAR(Distance(*box, X_WB * X_BA, *box, X_WB, &d, &s), gap, 1e-12);
        EXPECT_NEAR((d.p_WA - d.p_WB).norm(), gap, 1e-12);
      }
    }
  }
}

TEST(Collide, TouchingCountsAsCollision) {
  const ModelPtr box = MakeModel(shapes::Box(Vec3::Ones()));
  QueryScratch s;
  CollisionResult r;
  EXPECT_TRUE(
      Collide(*box, Pose::FromTranslation(Vec3(2, 0, 0)), *box, Pose::Identity(), {}, &r, &s));
  EXPECT_TRUE(r.surfaces_intersect);
}

TEST(Collide, ContainmentWithoutSurfaceCrossing) {
  const ModelPtr big = MakeModel(shapes::Box(Vec3::Ones()));
  const ModelPtr small = MakeModel(shapes::Sphere(0.2, 2));
  QueryScratch s;
  CollisionResult r;
  const Pose inside = Pose::FromTranslation(Vec3(0.3, -0.2, 0.1));
  EXPECT_TRUE(Collide(*small, inside, *big, Pose::Identity(), {}, &r, &s));
  EXPECT_FALSE(r.surfaces_intersect);
  EXPECT_EQ(r.containment, Containment::kAInsideB);
  EXPECT_TRUE(Collide(*big, Pose::Identity(), *small, inside, {}, &r, &s));
  EXPECT_EQ(r.containment, Containment::kBInsideA);
  CollisionRequest no_containment;
  no_containment.containment = false;
  EXPECT_FALSE(Collide(*small, inside, *big, Pose::Identity(), no_containment, &r, &s));
  // FCL sees no collision here: it tests surfaces only.
  const FclModel fa(small->mesh()), fb(big->mesh());
  EXPECT_FALSE(FclCollide(fa, inside, fb, Pose::Identity()));
}

TEST(Collide, AllPairsMatchesBruteForce) {
  const ModelPtr a = MakeModel(shapes::Sphere(0.5, 2));
  const ModelPtr b = MakeModel(shapes::Box(Vec3::Ones(), 3));
  const Pose X_WA = Pose::FromQuaternion(Quat(0.9, 0.1, 0.3, 0.2), Vec3(0.9, 0.4, 0.2));
  QueryScratch s;
  CollisionRequest req;
  req.all_pairs = true;
  CollisionResult r;
  ASSERT_TRUE(Collide(*a, X_WA, *b, Pose::Identity(), req, &r, &s));
  std::set<std::pair<Index, Index>> got;
  for (const auto& p : r.pairs) got.insert({p.a, p.b});
  EXPECT_EQ(got.size(), r.pairs.size());  // no duplicates
  std::set<std::pair<Index, Index>> want;
  const auto& VA = a->mesh().vertices();
  const auto& VB = b->mesh().vertices();
  for (Index i = 0; i < static_cast<Index>(a->mesh().num_triangles()); ++i) {
    const auto& ta = a->mesh().triangles()[i];
    for (Index j = 0; j < static_cast<Index>(b->mesh().num_triangles()); ++j) {
      const auto& tb = b->mesh().triangles()[j];
      if (internal::TrianglesIntersect(X_WA * VA[ta[0]], X_WA * VA[ta[1]], X_WA * VA[ta[2]],
                                       VB[tb[0]], VB[tb[1]], VB[tb[2]])) {
        want.insert({i, j});
      }
    }
  }
  EXPECT_EQ(got, want);
  EXPECT_GT(want.size(), 10u);
}

TEST(PointInside, MatchesAnalyticShapes) {
  const ModelPtr box = MakeModel(shapes::Box(Vec3(1, 2, 3), 2));
  const double R = 0.06, r = 0.02;
  const ModelPtr torus = MakeModel(shapes::Torus(R, r, 96, 48));
  std::mt19937_64 rng(testing::TestSeed());
  std::uniform_real_distribution<double> u(-1.2, 1.2);
  QueryScratch s;
  int checked = 0;
  for (int i = 0; i < 2000; ++i) {
    const Vec3 p(u(rng), 2 * u(rng), 3 * u(rng));
    const bool in = std::abs(p.x()) < 1 && std::abs(p.y()) < 2 && std::abs(p.z()) < 3;
    EXPECT_EQ(PointInside(*box, p, &s), in) << p.transpose();
    const Vec3 q = p.cwiseQuotient(Vec3(1, 2, 3)) * 0.09;
    const double ring = std::hypot(std::hypot(q.x(), q.y()) - R, q.z());
    // Skip points within the tessellation error of the torus surface.
    if (std::abs(ring - r) < 2e-3 * r * 10) continue;
    EXPECT_EQ(PointInside(*torus, q, &s), ring < r) << q.transpose();
    ++checked;
  }
  EXPECT_GT(checked, 1500);
  // Points exactly on a face's plane through an edge are handled by re-casting.
  EXPECT_TRUE(PointInside(*box, Vec3(0, 0, 0), &s));
  EXPECT_TRUE(PointInside(*box, Vec3(0.5, 0, 0), &s));
}

// --------------------------------------------------------------------------
// Proximity against brute-force enumeration of all features

struct FeatureKey {
  int type;
  Index a, b;
  auto operator<=>(const FeatureKey&) const = default;
};

std::set<FeatureKey> BruteForceFeatures(const GeometryModel& A, const Pose& X_WA,
                                        const GeometryModel& B, double tol) {
  std::set<FeatureKey> out;
  const Mesh& ma = A.mesh();
  const Mesh& mb = B.mesh();
  for (Index v = 0; v < static_cast<Index>(ma.num_vertices()); ++v) {
    for (Index f = 0; f < static_cast<Index>(mb.num_triangles()); ++f) {
      if (mb.face_normals()[f].squaredNorm() == 0) continue;
      const auto& t = mb.triangles()[f];
      const Vec3 p = X_WA * ma.vertices()[v];
      const Vec3 q = internal::ClosestPointOnTriangle(p, mb.vertices()[t[0]], mb.vertices()[t[1]],
                                                      mb.vertices()[t[2]], nullptr);
      if ((p - q).norm() <= tol) out.insert({0, v, f});
    }
  }
  for (Index f = 0; f < static_cast<Index>(ma.num_triangles()); ++f) {
    const auto& t = ma.triangles()[f];
    for (Index v = 0; v < static_cast<Index>(mb.num_vertices()); ++v) {
      const Vec3 q = mb.vertices()[v];
      const Vec3 p = internal::ClosestPointOnTriangle(q, X_WA * ma.vertices()[t[0]],
                                                      X_WA * ma.vertices()[t[1]],
                                                      X_WA * ma.vertices()[t[2]], nullptr);
      if ((p - q).norm() <= tol) out.insert({1, f, v});
    }
  }
  for (Index i = 0; i < static_cast<Index>(ma.edges().size()); ++i) {
    const Edge& ea = ma.edges()[i];
    const Vec3 a0 = X_WA * ma.vertices()[ea.v[0]], a1 = X_WA * ma.vertices()[ea.v[1]];
    for (Index j = 0; j < static_cast<Index>(mb.edges().size()); ++j) {
      const Edge& eb = mb.edges()[j];
      const Vec3 &b0 = mb.vertices()[eb.v[0]], &b1 = mb.vertices()[eb.v[1]];
      const auto sc = internal::ClosestSegmentSegment(a0, a1, b0, b1);
      const Vec3 c = (a1 - a0).cross(b1 - b0);
      const bool interior = sc.s > kEdgeInterior && sc.s < 1 - kEdgeInterior &&
                            sc.t > kEdgeInterior && sc.t < 1 - kEdgeInterior;
      if (std::sqrt(sc.dist_sq) <= tol && interior &&
          c.norm() > 1e-9 * (a1 - a0).norm() * (b1 - b0).norm()) {
        out.insert({2, i, j});
      }
    }
  }
  return out;
}

TEST(Proximity, MatchesBruteForceAndNormalsPointFromBToA) {
  const ModelPtr a = MakeModel(shapes::Torus(0.06, 0.02, 16, 8));
  const ModelPtr b = MakeModel(shapes::Sphere(0.08, 2));
  std::mt19937_64 rng(testing::TestSeed());
  QueryScratch s;
  ProximityResult r;
  int nonempty = 0;
  for (int i = 0; i < 20; ++i) {
    const Pose X_WA = NearSurfacePose(*a, *b, rng, 0.03);
    ProximityRequest req;
    req.tolerance = 0.01;
    Proximity(*a, X_WA, *b, Pose::Identity(), req, &r, &s);
    std::set<FeatureKey> got;
    for (const FeaturePair& fp : r.pairs) {
      got.insert({static_cast<int>(fp.type), fp.a, fp.b});
      EXPECT_LE(fp.distance, req.tolerance * (1 + 1e-12));
      // Unit, or zero for an edge-edge pair without a contact plane.
      if (fp.type == FeatureType::kEdgeEdge && fp.n_W.squaredNorm() == 0) continue;
      EXPECT_NEAR(fp.n_W.norm(), 1.0, 1e-12);
      EXPECT_NEAR((fp.p_WA - fp.p_WB).norm(), fp.distance, 1e-12);
      if (fp.type == FeatureType::kVertexFace) {
        EXPECT_LT((fp.n_W - b->mesh().face_normals()[fp.b]).norm(), 1e-12);
      }
    }
    EXPECT_EQ(got.size(), r.pairs.size()) << "duplicate feature pairs";
    EXPECT_EQ(got, BruteForceFeatures(*a, X_WA, *b, req.tolerance));
    nonempty += !got.empty();
  }
  EXPECT_GT(nonempty, 5);
}

TEST(Proximity, BoxRestingOnBoxGivesUpwardNormals) {
  const ModelPtr box = MakeModel(shapes::Box(Vec3(1, 1, 1)));
  QueryScratch s;
  ProximityResult r;
  ProximityRequest req;
  req.tolerance = 1e-3;
  const Pose X_WA = Pose::FromTranslation(Vec3(0.3, 0.2, 2.0005));
  Proximity(*box, X_WA, *box, Pose::Identity(), req, &r, &s);
  ASSERT_FALSE(r.pairs.empty());
  for (const FeaturePair& fp : r.pairs) {
    EXPECT_NEAR(fp.distance, 5e-4, 1e-12);
    EXPECT_NEAR(fp.signed_distance, 5e-4, 1e-12);
    EXPECT_GT(fp.n_W.z(), 0.999) << static_cast<int>(fp.type);
  }
}

TEST(Proximity, EdgeOverAFlatEdgeTakesTheFaceNormal) {
  // A box's edge, tilted 10 degrees, passes 10 um above the diagonal of
  // another box's top face (an edge between two coplanar triangles). Their
  // edge-edge pair is a face contact: its normal is the face's, not the
  // edges' cross product (tilted 10 degrees, which as a contact plane would
  // hold a PD answer at a wrong local optimum).
  const ModelPtr b = MakeModel(shapes::Box(Vec3(0.5, 0.5, 0.5)));
  const Mesh& mb = b->mesh();
  Index diagonal = -1;
  for (Index e = 0; e < static_cast<Index>(mb.edges().size()); ++e) {
    const Edge& edge = mb.edges()[e];
    if (edge.f[0] >= 0 && edge.f[1] >= 0 && mb.face_normals()[edge.f[0]].z() > 0.999 &&
        mb.face_normals()[edge.f[1]].z() > 0.999) {
      diagonal = e;
    }
  }
  ASSERT_GE(diagonal, 0);
  const Vec3 p0 = mb.vertices()[mb.edges()[diagonal].v[0]];
  const Vec3 p1 = mb.vertices()[mb.edges()[diagonal].v[1]];
  const Vec3 across = Vec3::UnitZ().cross(p1 - p0).normalized();  // horizontal, across it
  const ModelPtr a = MakeModel(shapes::Box(Vec3(0.3, 0.01, 0.01)));
  // A's long axis tilted 10 degrees up and turned across the diagonal, rolled
  // so that one long edge is lowest; that edge's middle goes 10 um above the
  // diagonal's middle.
  const double tilt = 10 * M_PI / 180;
  const Mat3 R = Eigen::Quaterniond::FromTwoVectors(
                     Vec3::UnitX(), (std::cos(tilt) * across + std::sin(tilt) * Vec3::UnitZ()))
                     .toRotationMatrix() *
                 Eigen::AngleAxisd(M_PI / 5, Vec3::UnitX()).toRotationMatrix();
  Vec3 edge_mid_A(0, 0.01, 0.01);
  for (const double y : {-0.01, 0.01}) {
    for (const double z : {-0.01, 0.01}) {
      if ((R * Vec3(0, y, z)).z() < (R * edge_mid_A).z()) edge_mid_A = Vec3(0, y, z);
    }
  }
  const double gap = 1e-5;
  const Pose X_WA{R, 0.5 * (p0 + p1) + Vec3(0, 0, gap) - R * edge_mid_A};
  QueryScratch s;
  ProximityResult r;
  ProximityRequest req;
  req.tolerance = 1e-4;
  Proximity(*a, X_WA, *b, Pose::Identity(), req, &r, &s);
  int over_diagonal = 0;
  for (const FeaturePair& fp : r.pairs) {
    if (fp.type != FeatureType::kEdgeEdge || fp.b != diagonal) continue;
    ++over_diagonal;
    EXPECT_NEAR(fp.distance, gap * std::cos(tilt), 1e-12);  // the lines are skew
    EXPECT_LT((fp.n_W - Vec3::UnitZ()).norm(), 1e-12) << fp.n_W.transpose();
  }
  EXPECT_EQ(over_diagonal, 1);
}

// --------------------------------------------------------------------------
// FCL as oracle on random poses

struct Pair {
  const char* name;
  Mesh a;
  Mesh b;
  double spread;
};

std::vector<Pair> OraclePairs() {
  std::vector<Pair> pairs;
  pairs.push_back({"stick-torusknot", shapes::Stick(), shapes::TorusKnot(), 0.02});
  pairs.push_back({"spoon-cup", shapes::Spoon(), shapes::Cup(), 0.02});
  pairs.push_back({"hammer-torus", shapes::Hammer(), shapes::Torus(), 0.03});
  pairs.push_back({"plate-sphere", shapes::ThinPlate(), shapes::Sphere(), 0.05});
  return pairs;
}

void CheckAgainstFcl(const std::string& name, const GeometryModel& A, const GeometryModel& B,
                     double spread, int count, std::uint64_t seed) {
  SCOPED_TRACE(name);
  const FclModel fa(A.mesh()), fb(B.mesh());
  std::mt19937_64 rng(seed);
  QueryScratch s;
  CollisionResult r;
  CollisionRequest req;
  req.containment = false;  // FCL tests surfaces only
  int hits = 0, disagreements = 0;
  double worst_dist_err = 0;
  for (int i = 0; i < count; ++i) {
    const Pose X_WA = NearSurfacePose(A, B, rng, spread);
    const bool ours = Collide(A, X_WA, B, Pose::Identity(), req, &r, &s);
    const bool fcl = FclCollide(fa, X_WA, fb, Pose::Identity());
    hits += ours;
    if (ours != fcl) {
      // A disagreement is acceptable only for touching contact within
      // round-off: measure the distance both ways.
      const double d = FclDistance(fa, X_WA, fb, Pose::Identity());
      if (d > 1e-9 * B.mesh().size()) ++disagreements;
    }
    if (!ours) {
      const double d = Distance(A, X_WA, B, Pose::Identity(), nullptr, &s);
      const double dref = FclDistance(fa, X_WA, fb, Pose::Identity());
      worst_dist_err = std::max(worst_dist_err, std::abs(d - dref));
    }
  }
  EXPECT_EQ(disagreements, 0);
  EXPECT_LT(worst_dist_err, 1e-9 * B.mesh().size()) << "distance disagrees with FCL";
  EXPECT_GT(hits, count / 10) << "poses should exercise collisions";
  EXPECT_LT(hits, count * 9 / 10) << "poses should exercise separation";
}

TEST(FclOracle, CollisionAndDistanceOnProceduralPairs) {
  const int count = testing::TestCount(150);
  for (Pair& p : OraclePairs()) {
    const ModelPtr a = MakeModel(std::move(p.a));
    const ModelPtr b = MakeModel(std::move(p.b));
    CheckAgainstFcl(p.name, *a, *b, p.spread, count, testing::TestSeed());
  }
}

TEST(FclOracle, StickAgainstBunny) {
  HAPTICPD_REQUIRE_MODEL(path, "stanford-bunny.obj");
  const ModelPtr bunny = MakeModel(LoadMesh(path.string()));
  // The stick scaled to the bunny (the bunny is ~0.15 m across).
  const ModelPtr stick = MakeModel(shapes::Stick());
  CheckAgainstFcl("stick-bunny", *stick, *bunny, 0.06, testing::TestCount(100),
                  testing::TestSeed());
}

// --------------------------------------------------------------------------
// Continuous collision

// The swept box test prunes the CCD traversal: it must never reject a time
// at which the boxes (inflated by the margin) overlap, and its entry time must
// not come after such a time. Checked against the exact 15-axis static test
// at sampled times over seeded random boxes, rotations and sweeps.
TEST(SweptBoxes, NeverMissesAnOverlapAndEntersNoLater) {
  std::mt19937_64 rng(20261122);
  std::uniform_real_distribution<double> u(-1, 1), h(0.01, 0.5);
  const int cases = testing::TestCount(4000);
  int overlapping = 0;
  for (int n = 0; n < cases; ++n) {
    BvhNode a, b;
    a.center = Vec3(u(rng), u(rng), u(rng));
    b.center = Vec3(u(rng), u(rng), u(rng));
    a.half = Vec3(h(rng), h(rng), h(rng));
    b.half = Vec3(h(rng), h(rng), h(rng));
    const Pose X_BA{RandomRotation(rng).toRotationMatrix(), Vec3(u(rng), u(rng), u(rng))};
    const Vec3 sweep = 2.0 * Vec3(u(rng), u(rng), u(rng));
    const double margin = n % 3 == 0 ? 0.05 : 0.0;
    const double t_max = n % 2 == 0 ? 1.0 : 0.5;
    const internal::SweptBoxFrame sf(X_BA, sweep);
    double t_enter = -1;
    const bool may = internal::BoxesSweptEnter(sf, a, b, t_max, &t_enter, margin);
    for (int k = 0; k <= 64; ++k) {
      const double t = t_max * k / 64.0;
      const internal::BoxFrame f(Pose{X_BA.R, X_BA.t + t * sweep});
      if (!internal::BoxesOverlap(f, a, b, margin, Vec3::Zero())) continue;
      ++overlapping;
      ASSERT_TRUE(may) << "case " << n << ": boxes overlap at t = " << t;
      ASSERT_LE(t_enter, t + 1e-12) << "case " << n;
      break;
    }
  }
  EXPECT_GT(overlapping, cases / 10);  // the sample exercises both outcomes
}

TEST(TranslationalCcd, KnownAnswerBoxes) {
  const ModelPtr box = MakeModel(shapes::Box(Vec3::Ones()));
  QueryScratch s;
  CcdResult r;
  CcdRequest req;
  req.feature_tolerance = 1e-9;
  // From x = 5 moving by -6: contact when x = 2, i.e. t = 0.5.
  const Pose X_WB = RotZ(0.7, Vec3(1, 2, 3));
  ASSERT_TRUE(TranslationalCcd(*box, X_WB * Pose::FromTranslation(Vec3(5, 0.5, 0.2)),
                               X_WB.R * Vec3(-6, 0, 0), *box, X_WB, req, &r, &s));
  EXPECT_NEAR(r.toi, 0.5, 1e-12);
  ASSERT_FALSE(r.features.empty());
  for (const FeaturePair& fp : r.features) {
    EXPECT_LT((fp.n_W - X_WB.R * Vec3::UnitX()).norm(), 1e-9);
  }
  // Rotated 45 degrees: an edge of A meets a face of B at x = 1 + sqrt(2).
  ASSERT_TRUE(TranslationalCcd(*box, X_WB * RotZ(M_PI / 4, Vec3(5, 0.1, 0)),
                               X_WB.R * Vec3(-4, 0, 0), *box, X_WB, req, &r, &s));
  EXPECT_NEAR(r.toi, (5 - 1 - std::sqrt(2.0)) / 4, 1e-12);
  // Moving away: no hit. Already touching: toi 0.
  EXPECT_FALSE(TranslationalCcd(*box, Pose::FromTranslation(Vec3(3, 0, 0)), Vec3(1, 0, 0), *box,
                                Pose::Identity(), req, &r, &s));
  EXPECT_TRUE(TranslationalCcd(*box, Pose::FromTranslation(Vec3(2, 0, 0)), Vec3(1, 0, 0), *box,
                               Pose::Identity(), req, &r, &s));
  EXPECT_EQ(r.toi, 0.0);
  // Grazing, parallel faces sliding past each other at exactly touching.
  EXPECT_TRUE(TranslationalCcd(*box, Pose::FromTranslation(Vec3(-5, 0, 2)), Vec3(10, 0, 0), *box,
                               Pose::Identity(), req, &r, &s));
  EXPECT_NEAR(r.toi, 0.3, 1e-12);
}

// First time in [0,1] at which FCL reports a collision, by dense sampling and
// bisection (independent of our CCD); 2 if never.
double FclFirstContact(const FclModel& fa, const Pose& X0, const Vec3& d, const FclModel& fb,
                       int samples) {
  double prev = 0;
  for (int k = 0; k <= samples; ++k) {
    const double t = static_cast<double>(k) / samples;
    if (FclCollide(fa, Pose{X0.R, X0.t + t * d}, fb, Pose::Identity())) {
      if (k == 0) return 0;
      double lo = prev, hi = t;
      for (int it = 0; it < 50; ++it) {
        const double mid = 0.5 * (lo + hi);
        (FclCollide(fa, Pose{X0.R, X0.t + mid * d}, fb, Pose::Identity()) ? hi : lo) = mid;
      }
      return hi;
    }
    prev = t;
  }
  return 2;
}

TEST(TranslationalCcd, MatchesBisectionWithFclCollide) {
  const ModelPtr a = MakeModel(shapes::Spoon());
  const ModelPtr b = MakeModel(shapes::Cup());
  const FclModel fa(a->mesh()), fb(b->mesh());
  std::mt19937_64 rng(testing::TestSeed());
  std::normal_distribution<double> n(0, 1);
  QueryScratch s;
  CcdResult r;
  CcdRequest req;
  const int count = testing::TestCount(60);
  int hits = 0;
  const double scale = b->mesh().size();
  for (int i = 0; i < count; ++i) {
    // Start outside the bounds, aim at a random point of B.
    Pose X0 = NearSurfacePose(*a, *b, rng, 0.0);
    const Vec3 dir = Vec3(n(rng), n(rng), n(rng)).normalized();
    X0.t += dir * 2 * scale;
    const Vec3 d = -dir * 3 * scale + Vec3(n(rng), n(rng), n(rng)) * 0.01;
    const bool hit = TranslationalCcd(*a, X0, d, *b, Pose::Identity(), req, &r, &s);
    const double t_ref = FclFirstContact(fa, X0, d, fb, 400);
    if (!hit) {
      EXPECT_EQ(t_ref, 2) << "CCD missed a contact FCL finds at t=" << t_ref;
      continue;
    }
    ++hits;
    // Ours can only be earlier than the sampled answer (sampling may step
    // over a grazing first contact); when both see the same contact they
    // agree to bisection precision.
    EXPECT_LE(r.toi, t_ref + 1e-9);
    const Pose Xc{X0.R, X0.t + r.toi * d};
    EXPECT_LT(FclDistance(fa, Xc, fb, Pose::Identity()), 1e-9 * scale) << "not a contact";
    if (r.toi > 1e-6) {
      const Pose Xe{X0.R, X0.t + (r.toi - 1e-6) * d};
      EXPECT_FALSE(FclCollide(fa, Xe, fb, Pose::Identity())) << "contact before toi";
    }
  }
  EXPECT_GT(hits, count / 3);
}

TEST(TranslationalCcd, StartCheckAgreesWithFclAndKeepsTheTimeOfImpact) {
  // Starts spread from deep inside to just outside the cup's surface, swept
  // in random directions: with check_start the CCD must call a start
  // colliding exactly when FCL finds the surfaces intersecting (or, for the
  // one containment start below, when the spoon lies wholly inside), and on
  // a free start give the same answer as the CCD without the check; the
  // depth-first crossing search first (start_crossing_first) changes none
  // of it.
  const ModelPtr a = MakeModel(shapes::Spoon());
  const ModelPtr b = MakeModel(shapes::Cup());
  const FclModel fa(a->mesh()), fb(b->mesh());
  std::mt19937_64 rng(testing::TestSeed() + 3);
  std::normal_distribution<double> n(0, 1);
  QueryScratch s;
  CcdResult checked, plain, first;
  CcdRequest req_checked, req_plain;
  req_checked.check_start = true;
  req_checked.feature_tolerance = req_plain.feature_tolerance = 1e-5;
  CcdRequest req_first = req_checked;
  req_first.start_crossing_first = true;
  const int count = testing::TestCount(80);
  int colliding = 0, free_hits = 0;
  for (int i = 0; i < count; ++i) {
    const Pose X0 = NearSurfacePose(*a, *b, rng, 0.01);
    // Towards the cup's middle, give or take, so most free starts hit.
    const Vec3 d =
        ((b->mesh().bounds().Center() - X0.t).normalized() + 0.3 * Vec3(n(rng), n(rng), n(rng))) *
        0.05;
    const bool fcl = FclCollide(fa, X0, fb, Pose::Identity());
    const bool hit = TranslationalCcd(*a, X0, d, *b, Pose::Identity(), req_checked, &checked, &s);
    EXPECT_EQ(checked.start_colliding, fcl) << "pose " << i;
    const bool hit_first = TranslationalCcd(*a, X0, d, *b, Pose::Identity(), req_first, &first, &s);
    EXPECT_EQ(first.start_colliding, fcl) << "pose " << i;
    EXPECT_EQ(hit_first, hit) << "pose " << i;
    EXPECT_EQ(first.toi, checked.toi) << "pose " << i;
    EXPECT_EQ(first.features.size(), checked.features.size()) << "pose " << i;
    if (fcl) {
      EXPECT_FALSE(hit);
      ++colliding;
      continue;
    }
    const bool hit_plain = TranslationalCcd(*a, X0, d, *b, Pose::Identity(), req_plain, &plain, &s);
    ASSERT_EQ(hit, hit_plain) << "pose " << i;
    if (!hit) continue;
    ++free_hits;
    EXPECT_EQ(checked.toi, plain.toi);
    EXPECT_EQ(checked.features.size(), plain.features.size());
  }
  // Both branches exercised (measured: about a third of the starts collide
  // and a sixth are free and hit).
  EXPECT_GT(colliding, count / 10) << free_hits;
  EXPECT_GT(free_hits, count / 16) << colliding;
  // Containment without any surface crossing is a colliding start too.
  const ModelPtr big = MakeModel(shapes::Box(Vec3::Ones()));
  const ModelPtr small = MakeModel(shapes::Sphere(0.2, 2));
  const Pose inside = Pose::FromTranslation(Vec3(0.3, -0.2, 0.1));
  EXPECT_FALSE(TranslationalCcd(*small, inside, Vec3(0.1, 0, 0), *big, Pose::Identity(),
                                req_checked, &checked, &s));
  EXPECT_TRUE(checked.start_colliding);
  EXPECT_FALSE(TranslationalCcd(*small, inside, Vec3(0.1, 0, 0), *big, Pose::Identity(), req_first,
                                &first, &s));
  EXPECT_TRUE(first.start_colliding);
}

TEST(TranslationalCcd, StartCrossingFirstNeedsARealCrossing) {
  // Two triangles whose boxes overlap and which each straddle the other's
  // plane, yet do not meet: every cull of the depth-first crossing search
  // passes, and only the exact crossing test tells the start is free.
  const ModelPtr a = MakeModel(Mesh::FromArrays({Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0)},
                                                {Triangle{0, 1, 2}}, "flat triangle"));
  const ModelPtr b =
      MakeModel(Mesh::FromArrays({Vec3(0.8, 0.5, -1), Vec3(0.8, 0.5, 1), Vec3(1.5, 0.5, 0)},
                                 {Triangle{0, 1, 2}}, "upright triangle"));
  QueryScratch s;
  CcdRequest req;
  req.check_start = true;
  req.start_crossing_first = true;
  CcdResult r;
  // Moving A along +y: its edge x + y = 1 reaches B's edge x = 0.8 at y = 0.5
  // after 0.3.
  EXPECT_TRUE(
      TranslationalCcd(*a, Pose::Identity(), Vec3(0, 1, 0), *b, Pose::Identity(), req, &r, &s));
  EXPECT_FALSE(r.start_colliding);
  EXPECT_NEAR(r.toi, 0.3, 1e-9);
}

TEST(TranslationalCcd, NearPairsHoldEveryTrianglePairWithinTheToleranceAtContact) {
  // PDg checks its answers against these pairs instead of a full collision
  // query: every triangle pair closer than the feature tolerance at the
  // contact must be listed (brute force over all pairs of the two meshes).
  const ModelPtr a = MakeModel(shapes::Spoon());
  const ModelPtr b = MakeModel(shapes::Cup());
  const Mesh& ma = a->mesh();
  const Mesh& mb = b->mesh();
  std::mt19937_64 rng(testing::TestSeed() + 5);
  std::normal_distribution<double> n(0, 1);
  QueryScratch s;
  CcdResult r;
  CcdRequest req;
  const double tol = 1e-3 * mb.size();
  req.feature_tolerance = tol;
  req.near_pairs = true;
  const int count = testing::TestCount(12);
  int hits = 0;
  std::size_t most_within = 0;
  for (int i = 0; i < count; ++i) {
    Pose X0 = NearSurfacePose(*a, *b, rng, 0.01);
    const Vec3 d =
        ((mb.bounds().Center() - X0.t).normalized() + 0.3 * Vec3(n(rng), n(rng), n(rng))) * 0.05;
    if (!TranslationalCcd(*a, X0, d, *b, Pose::Identity(), req, &r, &s)) continue;
    ++hits;
    std::set<std::pair<Index, Index>> listed;
    for (const TrianglePair& p : r.near_pairs) listed.insert({p.a, p.b});
    std::size_t within = 0;
    for (Index fa = 0; fa < static_cast<Index>(ma.num_triangles()); ++fa) {
      std::array<Vec3, 3> ta;
      for (int k = 0; k < 3; ++k) ta[k] = r.X_WA_contact * ma.vertices()[ma.triangles()[fa][k]];
      const Vec3 lo = ta[0].cwiseMin(ta[1]).cwiseMin(ta[2]).array() - tol;
      const Vec3 hi = ta[0].cwiseMax(ta[1]).cwiseMax(ta[2]).array() + tol;
      for (Index fb = 0; fb < static_cast<Index>(mb.num_triangles()); ++fb) {
        const auto& V = mb.vertices();
        const Triangle& tb = mb.triangles()[fb];
        const Vec3 blo = V[tb[0]].cwiseMin(V[tb[1]]).cwiseMin(V[tb[2]]);
        const Vec3 bhi = V[tb[0]].cwiseMax(V[tb[1]]).cwiseMax(V[tb[2]]);
        if ((blo.array() > hi.array()).any() || (lo.array() > bhi.array()).any()) continue;
        const double d2 =
            internal::ClosestTriangleTriangle(ta[0], ta[1], ta[2], V[tb[0]], V[tb[1]], V[tb[2]])
                .dist_sq;
        if (d2 > tol * tol) continue;
        ++within;
        EXPECT_TRUE(listed.count({fa, fb})) << "sweep " << i << ": pair (" << fa << ", " << fb
                                            << ") at " << std::sqrt(d2) << " m not listed";
      }
    }
    EXPECT_GE(listed.size(), within);
    most_within = std::max(most_within, within);
  }
  EXPECT_GT(hits, count / 4);
  EXPECT_GT(most_within, 1u);  // contacts with several nearby pairs were met
  // Not asked for: none listed.
  req.near_pairs = false;
  for (int i = 0; i < 20; ++i) {
    Pose X0 = NearSurfacePose(*a, *b, rng, 0.01);
    const Vec3 d = (mb.bounds().Center() - X0.t).normalized() * 0.05;
    if (TranslationalCcd(*a, X0, d, *b, Pose::Identity(), req, &r, &s)) {
      EXPECT_TRUE(r.near_pairs.empty());
      break;
    }
  }
}

TEST(RigidCcd, ConservativeAdvancementStopsAtContact) {
  const ModelPtr a = MakeModel(shapes::Hammer());
  const ModelPtr b = MakeModel(shapes::Torus());
  const FclModel fa(a->mesh()), fb(b->mesh());
  std::mt19937_64 rng(testing::TestSeed());
  std::normal_distribution<double> n(0, 1);
  QueryScratch s;
  CcdResult r;
  CcdRequest req;
  req.distance_tolerance = 1e-6;
  // RigidCcd is a library query only (PDg re-projects by translation): fewer
  // motions under the sanitizers, where each costs seconds.
  const int count = testing::TestCount(testing::kSanitized ? 10 : 30);
  int hits = 0;
  for (int i = 0; i < count; ++i) {
    Pose X1 = NearSurfacePose(*a, *b, rng, 0.01);
    Pose X0 = X1;
    const Vec3 dir = Vec3(n(rng), n(rng), n(rng)).normalized();
    X0.t += dir * 0.3;
    X0.R = Eigen::AngleAxisd(0.8 * n(rng), Vec3(n(rng), n(rng), n(rng)).normalized()) * X1.R;
    if (FclCollide(fa, X0, fb, Pose::Identity())) continue;
    const bool hit = RigidCcd(*a, X0, X1, *b, Pose::Identity(), req, &r, &s);
    // Dense samples along the same motion: none before toi may collide.
    double first = 2;
    for (int k = 0; k <= 200; ++k) {
      const double t = k / 200.0;
      if (FclCollide(fa, InterpolateRigid(X0, X1, a->mass().p_MC, t), fb, Pose::Identity())) {
        first = t;
        break;
      }
    }
    if (!hit) {
      EXPECT_EQ(first, 2) << "missed a contact";
      continue;
    }
    ++hits;
    EXPECT_LE(r.toi, first);
    EXPECT_LE(FclDistance(fa, r.X_WA_contact, fb, Pose::Identity()), 1.01e-6);
    EXPECT_FALSE(FclCollide(fa, r.X_WA_contact, fb, Pose::Identity()));
  }
  EXPECT_GT(hits, 3);
}

TEST(RigidCcd, InterpolationEndsAndKeepsCentreOnALine) {
  const Pose X0 = Pose::FromQuaternion(Quat(1, 0.2, 0.1, 0), Vec3(1, 2, 3));
  const Pose X1 = Pose::FromQuaternion(Quat(0.3, 0.5, -0.2, 0.7), Vec3(-1, 0, 2));
  const Vec3 c(0.1, 0.2, -0.3);
  EXPECT_LT((InterpolateRigid(X0, X1, c, 0).R - X0.R).norm(), 1e-12);
  EXPECT_LT((InterpolateRigid(X0, X1, c, 1).R - X1.R).norm(), 1e-12);
  EXPECT_LT((InterpolateRigid(X0, X1, c, 1).t - X1.t).norm(), 1e-12);
  const Vec3 mid = InterpolateRigid(X0, X1, c, 0.5) * c;
  EXPECT_LT((mid - 0.5 * (X0 * c + X1 * c)).norm(), 1e-12);
}

// --------------------------------------------------------------------------
// Triangles within a sphere: the BVH walk against brute force

TEST(TrianglesWithinSphere, MatchesBruteForceOnATorusKnot) {
  const ModelPtr knot = MakeModel(shapes::TorusKnot());
  const Mesh& mesh = knot->mesh();
  std::mt19937_64 rng(testing::TestSeed());
  std::uniform_real_distribution<double> coord(-0.07, 0.07);
  std::uniform_real_distribution<double> radius(0.0, 0.04);
  QueryScratch scratch;
  std::vector<TriangleDistance> found;
  int nonempty = 0;
  const int n = testing::TestCount(300);
  for (int i = 0; i < n; ++i) {
    const Vec3 c(coord(rng), coord(rng), 0.3 * coord(rng));
    const double r = radius(rng);
    TrianglesWithinSphere(*knot, c, r, &found, &scratch);
    std::set<Index> brute;
    for (Index f = 0; f < static_cast<Index>(mesh.num_triangles()); ++f) {
      const Triangle& t = mesh.triangles()[f];
      const Vec3 q = internal::ClosestPointOnTriangle(
          c, mesh.vertices()[t[0]], mesh.vertices()[t[1]], mesh.vertices()[t[2]], nullptr);
      if ((q - c).norm() <= r) brute.insert(f);
    }
    std::set<Index> got;
    for (const TriangleDistance& td : found) {
      EXPECT_TRUE(got.insert(td.triangle).second) << "triangle " << td.triangle << " twice";
      EXPECT_LE(td.distance, r);
    }
    ASSERT_EQ(got, brute) << "query " << i << " at (" << c.transpose() << "), radius " << r;
    nonempty += !brute.empty();
  }
  EXPECT_GT(nonempty, n / 10);  // the queries do reach the surface
  // A sphere through a vertex holds its triangles; a negative radius nothing.
  const Vec3 v = mesh.vertices()[mesh.triangles()[7][1]];
  TrianglesWithinSphere(*knot, v, 0.0, &found, &scratch);
  EXPECT_TRUE(std::any_of(found.begin(), found.end(),
                          [](const TriangleDistance& td) { return td.triangle == 7; }));
  TrianglesWithinSphere(*knot, v, -1.0, &found, &scratch);
  EXPECT_TRUE(found.empty());
}

}  // namespace
}  // namespace hapticpd::pd
