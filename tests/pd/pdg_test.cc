// PDg: the exact in-projection QP against brute-force enumeration; every
// answer verified independently with FCL along its own rigid motion; never
// above PDt; rotation found where it is the cheap way out (stick in a slot,
// L-shape hooked on a post) with the expected torque; hard cases (half turns,
// sphere-like probes with ill-defined principal axes, scale, containment);
// metamorphic relations; coherent trajectories; no allocation after warm-up;
// the probe inertia override (heavier rotation: less of it); force-only
// wrenches for scenes without torque.
#include "pd/pdg.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <limits>
#include <random>
#include <utility>
#include <vector>

#include "client/bench/scenarios.h"
#include "pd/scene_pd.h"
#include "pd/shapes.h"
#include "tests/alloc_counter.h"
#include "tests/oracles/fcl_oracle.h"
#include "tests/pd/pd_query_runs.h"
#include "tests/pd/pd_test_support.h"
#include "tests/pd/random_poses.h"
#include "tests/pd/table_one_benchmark.h"
#include "tests/test_util.h"

namespace hapticpd::pd {
namespace {

using testing::FclModel;
using testing::NearSurfacePose;

// --------------------------------------------------------------------------
// The QP

// Brute force: the KKT point over every subset of at most six rows with
// linearly independent normals (z = M^-1 A_S^T mu, A_S M^-1 A_S^T mu = b_S,
// multipliers 2 mu >= 0, every row satisfied); the smallest objective among
// them is the optimum (strictly convex problem). +inf if none.
double BruteForceQp(const std::vector<Constraint6>& rows, const Vec6& m, Vec6* z_best) {
  const int n = static_cast<int>(rows.size());
  double best = std::numeric_limits<double>::infinity();
  const Vec6 minv = m.cwiseInverse();
  for (unsigned mask = 0; mask < (1u << n); ++mask) {
    const int k = __builtin_popcount(mask);
    if (k > 6) continue;
    Eigen::MatrixXd A(k, 6);
    Eigen::VectorXd b(k);
    int r = 0;
    for (int i = 0; i < n; ++i) {
      if (mask & (1u << i)) {
        A.row(r) = rows[i].a.transpose();
        b[r++] = rows[i].b;
      }
    }
    Vec6 z = Vec6::Zero();
    if (k > 0) {
      const Eigen::MatrixXd G = A * minv.asDiagonal() * A.transpose();
      Eigen::FullPivLU<Eigen::MatrixXd> lu(G);
      if (lu.rank() < k) continue;
      const Eigen::VectorXd mu = lu.solve(b);
      if ((mu.array() < -1e-12).any()) continue;
      z = minv.asDiagonal() * A.transpose() * mu;
    }
    bool feasible = true;
    for (const Constraint6& c : rows) feasible = feasible && c.a.dot(z) >= c.b - 1e-10;
    if (!feasible) continue;
    const double f = z.dot(m.asDiagonal() * z);
    if (f < best) {
      best = f;
      *z_best = z;
    }
  }
  return best;
}

TEST(PdgQp, MatchesBruteForceOnRandomFeasibleProblems) {
  std::mt19937_64 rng(testing::TestSeed());
  std::normal_distribution<double> nd(0, 1);
  std::uniform_int_distribution<int> count(1, 11);
  MetricQp qp;
  std::vector<double> lambda;
  for (int trial = 0; trial < testing::TestCount(300); ++trial) {
    Vec6 m;
    for (int i = 0; i < 6; ++i) m[i] = std::exp(2 * nd(rng));  // weights over ~4 decades
    // Feasible by construction: every row holds at a random z0.
    Vec6 z0;
    for (int i = 0; i < 6; ++i) z0[i] = nd(rng);
    std::vector<Constraint6> rows(count(rng));
    for (Constraint6& c : rows) {
      for (int i = 0; i < 6; ++i) c.a[i] = nd(rng);
      c.b = c.a.dot(z0) - std::abs(nd(rng));
    }
    if (trial % 5 == 0 && rows.size() > 2) {
      rows[1] = rows[0];            // duplicate row
      rows[2].a = 3.0 * rows[0].a;  // parallel row, looser or tighter
      rows[2].b = 3.0 * rows[0].b - 0.1;
    }
    qp.Clear();
    for (const Constraint6& c : rows) qp.Add(c.a, c.b);
    Vec6 z;
    ASSERT_EQ(qp.Solve(m, &z, &lambda), QpStatus::kSolved) << "trial " << trial;
    Vec6 z_ref;
    const double ref = BruteForceQp(rows, m, &z_ref);
    ASSERT_TRUE(std::isfinite(ref)) << "trial " << trial;
    const double f = z.dot(m.asDiagonal() * z);
    EXPECT_NEAR(f, ref, 1e-9 * (1 + ref)) << "trial " << trial;
    EXPECT_LT((z - z_ref).norm(), 1e-6 * (1 + z_ref.norm())) << "trial " << trial;
    // KKT: feasibility, 2 M z = sum lambda_i a_i, lambda >= 0, complementarity.
    Vec6 grad = Vec6::Zero();
    for (std::size_t i = 0; i < rows.size(); ++i) {
      EXPECT_GE(rows[i].a.dot(z), rows[i].b - 1e-9 * (1 + std::abs(rows[i].b)));
      EXPECT_GE(lambda[i], 0);
      EXPECT_NEAR(lambda[i] * (rows[i].a.dot(z) - rows[i].b), 0, 1e-8 * (1 + lambda[i]));
      grad += lambda[i] * rows[i].a;
    }
    EXPECT_LT((grad - 2 * m.asDiagonal() * z).norm(), 1e-7 * (1 + (m.asDiagonal() * z).norm()))
        << "trial " << trial;
  }
}

TEST(PdgQp, DegenerateVertexWithMoreThanSixActiveRows) {
  // Ten rows all active at the optimum z* = (1, 1, 0, 0, 0, 0)/...: a
  // degenerate vertex the active set must not cycle on.
  const Vec6 m = Vec6::Ones();
  MetricQp qp;
  std::vector<Constraint6> rows;
  const Vec6 target = (Vec6() << 1, 1, 0, 0, 0, 0).finished();
  std::mt19937_64 rng(testing::TestSeed() + 1);
  std::normal_distribution<double> nd(0, 1);
  rows.push_back({target, target.squaredNorm()});
  for (int k = 0; k < 9; ++k) {
    // Rows through z* whose half-spaces contain the segment towards 2 z*.
    Vec6 a = target;
    for (int i = 2; i < 6; ++i) a[i] = nd(rng);
    rows.push_back({a, a.dot(target)});
  }
  for (const Constraint6& c : rows) qp.Add(c.a, c.b);
  Vec6 z;
  ASSERT_EQ(qp.Solve(m, &z), QpStatus::kSolved);
  Vec6 z_ref;
  const double ref = BruteForceQp(rows, m, &z_ref);
  EXPECT_NEAR(z.squaredNorm(), ref, 1e-9);
  EXPECT_LT((z - target).norm(), 1e-9);
}

TEST(PdgQp, ReportsInfeasibility) {
  MetricQp qp;
  const Vec6 a = (Vec6() << 0, 0, 0, 1, 0, 0).finished();
  qp.Add(a, 1.0);
  qp.Add(-a, 1.0);  // x >= 1 and x <= -1
  Vec6 z;
  EXPECT_EQ(qp.Solve(Vec6::Ones(), &z), QpStatus::kInfeasible);
  qp.Clear();
  qp.Add(a, -1.0);
  qp.Add(-a, -1.0);  // |x| <= 1: the origin
  EXPECT_EQ(qp.Solve(Vec6::Ones(), &z), QpStatus::kSolved);
  EXPECT_EQ(z.norm(), 0);
  qp.Clear();
  EXPECT_EQ(qp.Solve(Vec6::Ones(), &z), QpStatus::kSolved);  // no rows
  EXPECT_EQ(z.norm(), 0);
}

// --------------------------------------------------------------------------
// Verification helpers

// Checks every PDg answer the same way: consistent fields, a real contact
// along its own motion (FCL), and never above the PDt answer at the same pose
// (sigma measured in the metric of `request`).
void ExpectVerifiedPdg(const GeometryModel& A, const Pose& X_WA, const Pose& X_WB,
                       const FclModel& fa, const FclModel& fb, const PenetrationResult& r,
                       double pdt_depth, const PenetrationRequest& request = ColdRequest()) {
  ASSERT_NE(r.status, PdStatus::kFailed) << r.failure;
  ASSERT_NE(r.status, PdStatus::kSeparated);
  EXPECT_EQ(r.mode, PdMode::kGeneralized);
  ASSERT_TRUE(r.X_WA_result.R.allFinite() && r.X_WA_result.t.allFinite());
  EXPECT_NEAR(r.depth, std::sqrt(r.sigma), 1e-12 * (1 + r.depth));
  EXPECT_LE(r.depth, pdt_depth * (1 + 1e-9)) << "PDg above PDt";
  // The reported sigma, translation and rotation describe the result pose.
  const MassProperties& mp = A.mass();
  const Vec6 z = RelativeConfiguration(mp, X_WA, r.X_WA_result);
  EXPECT_NEAR(z.cwiseProduct(z).dot(PdgMetricDiagonal(mp, request)), r.sigma,
              1e-9 * r.sigma + 1e-18);
  EXPECT_LT((r.X_WA_result * mp.p_MC - X_WA * mp.p_MC - r.translation_W).norm(),
            1e-9 * (1 + r.depth));
  const Mat3 R_rel = Eigen::AngleAxisd(r.rotation_angle, r.rotation_axis_W).toRotationMatrix();
  EXPECT_LT((R_rel * X_WA.R - r.X_WA_result.R).norm(), 1e-9);
  EXPECT_NEAR(r.rotation_axis_W.norm(), 1, 1e-12);
  EXPECT_FALSE(r.features.empty());
  ExpectRealContactAlongMotion(fa, fb, X_WB, X_WA, mp.p_MC, r);
}

// --------------------------------------------------------------------------
// Random poses: verified, never above PDt

struct PairCase {
  const char* name;
  Mesh a, b;
  double spread;
};

std::vector<PairCase> AllCases() {
  std::vector<PairCase> v;
  v.push_back(
      {"box-box", shapes::Box(Vec3(0.1, 0.02, 0.05)), shapes::Box(Vec3(0.3, 0.2, 0.15)), 0.05});
  v.push_back(
      {"capsule-box", shapes::Capsule(0.05, 0.1, 8, 2), shapes::Box(Vec3(0.3, 0.1, 0.2)), 0.05});
  for (NonConvexCase& c : NonConvexCases()) {
    v.push_back({c.name, std::move(c.a), std::move(c.b), c.spread});
  }
  return v;
}

TEST(PdgRandom, EveryAnswerIsAVerifiedContactNoDeeperThanPdt) {
  std::mt19937_64 rng(testing::TestSeed());
  const int count = testing::TestCount(25);
  ForEachPair(AllCases(), [&](const ProbeAndScene& ps, const PairCase& c) {
    const GeometryModel& A = *ps.A;
    const GeometryModel& B = *ps.B;
    PdgQueryData data;
    PdQueryData pdt_data;
    PenetrationResult r, pdt;
    int penetrating = 0, rotated = 0;
    double ratio_sum = 0;
    for (int i = 0; i < count; ++i) {
      const Pose X_WB = Pose::FromQuaternion(testing::RandomRotation(rng), Vec3(0.1, -0.2, 0.3));
      const Pose X_WA = X_WB * NearSurfacePose(A, B, rng, c.spread);
      ComputePdg(A, X_WA, B, X_WB, ColdRequest(), &data, &r);
      ComputePdt(A, X_WA, B, X_WB, ColdRequest(), &pdt_data, &pdt);
      if (r.status == PdStatus::kSeparated) {
        EXPECT_EQ(pdt.status, PdStatus::kSeparated);
        EXPECT_FALSE(testing::FclCollide(ps.fa, X_WA, ps.fb, X_WB));
        continue;
      }
      ++penetrating;
      ASSERT_NE(pdt.status, PdStatus::kFailed) << pdt.failure;
      ExpectVerifiedPdg(A, X_WA, X_WB, ps.fa, ps.fb, r, pdt.depth);
      rotated += r.rotation_angle > 1e-6;
      ratio_sum += r.depth / pdt.depth;
    }
    EXPECT_GT(penetrating, count / 4);
    std::cout << "[ PDg/PDt ] " << c.name << ": " << penetrating << " penetrating, " << rotated
              << " with rotation, mean depth ratio " << ratio_sum / std::max(penetrating, 1)
              << "\n";
  });
}

// The iteration work budget: on poses whose unbudgeted query iterates three
// times or more, a budget of one test stops after the first iteration (the
// first always runs) with a verified contact, never above PDt.
TEST(PdgBudget, ABudgetStopsTheIterationsWithAVerifiedContact) {
  std::mt19937_64 rng(testing::TestSeed());
  int checked = 0;
  ForEachPair(AllCases(), [&](const ProbeAndScene& ps, const PairCase& c) {
    const GeometryModel& A = *ps.A;
    const GeometryModel& B = *ps.B;
    PdgQueryData data;
    PdQueryData pdt_data;
    PenetrationResult full, capped, pdt;
    PenetrationRequest unlimited = ColdRequest();
    unlimited.pdg_iteration_budget = 0;
    PenetrationRequest tight = ColdRequest();
    tight.pdg_iteration_budget = 1;
    for (int i = 0; i < testing::TestCount(25); ++i) {
      const Pose X_WA = NearSurfacePose(A, B, rng, c.spread);
      ComputePdg(A, X_WA, B, Pose::Identity(), unlimited, &data, &full);
      if (full.status == PdStatus::kSeparated || full.iterations < 3) continue;
      ComputePdg(A, X_WA, B, Pose::Identity(), tight, &data, &capped);
      ComputePdt(A, X_WA, B, Pose::Identity(), ColdRequest(), &pdt_data, &pdt);
      EXPECT_EQ(capped.status, PdStatus::kPenetratingCapReached);
      EXPECT_EQ(capped.iterations, 1);
      ExpectVerifiedPdg(A, X_WA, Pose::Identity(), ps.fa, ps.fb, capped, pdt.depth);
      ++checked;
    }
  });
  EXPECT_GT(checked, 5) << "too few poses that iterate three times or more";
}

TEST(PdgRandom, SharedBunnyAnswersAreVerifiedContacts) {
  HAPTICPD_REQUIRE_MODEL(path, "stanford-bunny.obj");
  const ProbeAndScene ps(MakeModel(shapes::Stick()), MakeModel(LoadMesh(path.string())));
  PdQueryData pdt_data;
  PenetrationResult pdt;
  const int penetrating = PenetratingNearSurface<PdgQuery>(
      ps, 0.003, testing::TestCount(12), [&](const Pose& X_WA, const PenetrationResult& r) {
        ComputePdt(*ps.A, X_WA, *ps.B, Pose::Identity(), ColdRequest(), &pdt_data, &pdt);
        ExpectVerifiedPdg(*ps.A, X_WA, Pose::Identity(), ps.fa, ps.fb, r, pdt.depth);
      });
  EXPECT_GT(penetrating, 3);
}

// --------------------------------------------------------------------------
// Rotation is the cheap way out

Mesh Union(const Mesh& a, const Mesh& b, const char* name) {
  std::vector<Vec3> v = a.vertices();
  std::vector<Triangle> t = a.triangles();
  const Index offset = static_cast<Index>(v.size());
  v.insert(v.end(), b.vertices().begin(), b.vertices().end());
  for (Triangle tri : b.triangles())
    t.push_back({tri[0] + offset, tri[1] + offset, tri[2] + offset});
  return Mesh::FromArrays(std::move(v), std::move(t), name);
}

Mesh BoxAt(const Vec3& lo, const Vec3& hi) {
  return shapes::Box(0.5 * (hi - lo)).Transformed(Pose::FromTranslation(0.5 * (lo + hi)));
}

struct RotationCase {
  PenetrationResult pdg, pdt;
  Wrench wrench;
};

RotationCase RunRotationCase(const GeometryModel& A, const Pose& X_WA, const GeometryModel& B) {
  RotationCase out;
  PdgQueryData data;
  PdQueryData pdt_data;
  ComputePdg(A, X_WA, B, Pose::Identity(), ColdRequest(), &data, &out.pdg);
  ComputePdt(A, X_WA, B, Pose::Identity(), ColdRequest(), &pdt_data, &out.pdt);
  const FclModel fa(A.mesh()), fb(B.mesh());
  ExpectVerifiedPdg(A, X_WA, Pose::Identity(), fa, fb, out.pdg, out.pdt.depth);
  Material m;
  m.stiffness = 800;
  m.rotational_stiffness = 0.3;
  out.wrench = PdWrench(out.pdg, m, X_WA * A.mass().p_MC);
  std::cout << "[ PDg vs PDt ] PDg " << out.pdg.depth << " m (rotation " << out.pdg.rotation_angle
            << " rad), PDt " << out.pdt.depth << " m, " << out.pdg.iterations << " iterations\n";
  // f = k (T_pd - T_o), tau = xi theta omega.
  EXPECT_LT((out.wrench.force - 800 * out.pdg.translation_W).norm(), 1e-9);
  EXPECT_LT((out.wrench.torque - 0.3 * out.pdg.rotation_angle * out.pdg.rotation_axis_W).norm(),
            1e-12);
  return out;
}

// A slot 2 cm wide between two walls (x < 0 and x > 0.02, z < 0); a 20 cm
// stick stands in it tilted by 0.1 rad about y, its lower end `depth` (2 mm)
// into the left wall.
struct StickInSlot {
  ModelPtr slot = MakeModel(Union(BoxAt(Vec3(-0.1, -0.1, -0.1), Vec3(0, 0.1, 0)),
                                  BoxAt(Vec3(0.02, -0.1, -0.1), Vec3(0.12, 0.1, 0)), "slot"));
  ModelPtr stick = MakeModel(shapes::Box(Vec3(0.005, 0.005, 0.1)));
  double depth = 0.002;
  Pose X_WA;
  StickInSlot() {
    const Mat3 R = Eigen::AngleAxisd(0.1, Vec3::UnitY()).toRotationMatrix();
    // Lower-left corner edge of the stick: (-0.005, *, -0.1) in its frame.
    const double corner_x = (R * Vec3(-0.005, 0, -0.1)).x();
    X_WA = Pose{R, Vec3(-depth - corner_x, 0, 0.02)};
  }
};

TEST(PdgRotation, LongStickPokedIntoASlotPivotsOut) {
  // Translating out costs the full 2 mm; pivoting about the centre of mass
  // (plus a little translation) moves the tip at 10 cm lever for about half
  // of that in the object norm.
  const StickInSlot c;
  const RotationCase rc = RunRotationCase(*c.stick, c.X_WA, *c.slot);
  const double depth = c.depth;
  EXPECT_NEAR(rc.pdt.depth, depth, 1e-9);
  EXPECT_LT(rc.pdg.depth, 0.8 * rc.pdt.depth) << "rotation should be much cheaper";
  // The answer pivots the lower end towards +x: a rotation about -y.
  EXPECT_GT(rc.pdg.rotation_angle, 1e-3);
  EXPECT_LT(rc.pdg.rotation_axis_W.y(), -0.9);
  EXPECT_LT(rc.wrench.torque.y(), 0);
  EXPECT_GT(rc.wrench.force.x(), 0);
}

TEST(PdgRotation, LShapeHookedOnAPostRotatesOff) {
  // A square post along z; an L-shape in the xy-plane (a 24 cm arm along x,
  // a hook at its +x end pointing down) wraps the post's +x+y corner: the
  // arm 3 mm into the post's top, the hook 3 mm into its side. Translation
  // must clear both (diagonal); the arm's share is cheaper by turning the
  // long arm about z, lifting its +x end.
  const ModelPtr post = MakeModel(shapes::Box(Vec3(0.01, 0.01, 0.1)));
  const double dx = 0.003, dy = 0.003;
  const ModelPtr hook =
      MakeModel(Union(BoxAt(Vec3(-0.2, 0.01 - dy, -0.01), Vec3(0.04 - dx, 0.03 - dy, 0.01)),
                      BoxAt(Vec3(0.01 - dx, -0.05, -0.01), Vec3(0.03 - dx, 0.02 - dy, 0.01)), "L"));
  const RotationCase rc = RunRotationCase(*hook, Pose::Identity(), *post);
  EXPECT_LT(rc.pdg.depth, 0.95 * rc.pdt.depth) << "rotation should be cheaper";
  // Lifting the +x end: a rotation about +z, pushed out towards +x and +y.
  EXPECT_GT(rc.pdg.rotation_angle, 1e-3);
  EXPECT_GT(rc.pdg.rotation_axis_W.z(), 0.9);
  EXPECT_GT(rc.wrench.torque.z(), 0);
  EXPECT_GT(rc.wrench.force.x(), 0);
}

// --------------------------------------------------------------------------
// The probe's inertia override (a scene file's probe mass and inertia)

TEST(PdgInertiaOverride, TheMeshsOwnInertiaPerMassChangesNothing) {
  // Units: the mesh's unit-density moments over its volume are its inertia
  // per mass, so that override must reproduce the default answer.
  const StickInSlot c;
  const MassProperties& mp = c.stick->mass();
  PenetrationRequest same = ColdRequest();
  same.principal_inertia_over_mass = Vec3(mp.principal_moments / mp.norm_measure);
  EXPECT_LT((PdgMetricDiagonal(mp, same) - ObjectNormMetric(mp).diagonal()).norm(),
            1e-12 * ObjectNormMetric(mp).diagonal().norm());
  PdgQueryData d0, d1;
  PenetrationResult r0, r1;
  ComputePdg(*c.stick, c.X_WA, *c.slot, Pose::Identity(), ColdRequest(), &d0, &r0);
  ComputePdg(*c.stick, c.X_WA, *c.slot, Pose::Identity(), same, &d1, &r1);
  ASSERT_EQ(r0.status, PdStatus::kPenetratingSolved) << r0.failure;
  ASSERT_EQ(r1.status, PdStatus::kPenetratingSolved) << r1.failure;
  EXPECT_NEAR(r1.sigma, r0.sigma, 1e-9 * r0.sigma);
  EXPECT_NEAR(r1.rotation_angle, r0.rotation_angle, 1e-6 * r0.rotation_angle);
}

TEST(PdgInertiaOverride, AHeavierRotationPivotsLessAndTranslatesMore) {
  // The stick in the slot pivots out by default (rotation is cheap). With
  // rotational weights 4 I/m ten times the mesh's largest, rotation costs
  // more: the answer turns less and translates more (towards PDt's straight
  // push), still a verified contact no deeper than PDt in its own metric.
  const StickInSlot c;
  const MassProperties& mp = c.stick->mass();
  const double heavy = 10 * mp.principal_moments.maxCoeff() / mp.norm_measure;  // m^2
  PenetrationRequest req = ColdRequest();
  req.principal_inertia_over_mass = Vec3::Constant(heavy);
  EXPECT_DOUBLE_EQ(PdgMetricDiagonal(mp, req)[0], 4 * heavy);
  EXPECT_DOUBLE_EQ(PdgMetricDiagonal(mp, req)[2], 4 * heavy);
  EXPECT_DOUBLE_EQ(PdgMetricDiagonal(mp, req)[3], 1);

  PdgQueryData d0, d1;
  PdQueryData dt;
  PenetrationResult r0, r1, pdt;
  ComputePdg(*c.stick, c.X_WA, *c.slot, Pose::Identity(), ColdRequest(), &d0, &r0);
  ComputePdg(*c.stick, c.X_WA, *c.slot, Pose::Identity(), req, &d1, &r1);
  ComputePdt(*c.stick, c.X_WA, *c.slot, Pose::Identity(), ColdRequest(), &dt, &pdt);
  const FclModel fa(c.stick->mesh()), fb(c.slot->mesh());
  ExpectVerifiedPdg(*c.stick, c.X_WA, Pose::Identity(), fa, fb, r0, pdt.depth);
  ExpectVerifiedPdg(*c.stick, c.X_WA, Pose::Identity(), fa, fb, r1, pdt.depth, req);
  std::cout << "[ PDg inertia ] default: rotation " << r0.rotation_angle << " rad, translation "
            << r0.translation_W.norm() << " m; heavy: rotation " << r1.rotation_angle
            << " rad, translation " << r1.translation_W.norm() << " m; PDt " << pdt.depth << " m\n";
  EXPECT_GT(r0.rotation_angle, 1e-3);
  EXPECT_LT(r1.rotation_angle, 0.5 * r0.rotation_angle);
  EXPECT_GT(r1.translation_W.norm(), r0.translation_W.norm());
  EXPECT_LE(r1.translation_W.norm(), pdt.depth * (1 + 1e-9));
  // The heavier metric never makes the same motion cheaper.
  EXPECT_GE(r1.sigma, r0.sigma * (1 - 1e-9));
}

TEST(PdgInertiaOverride, InvalidOverrideFailsNamingTheField) {
  const StickInSlot c;
  for (const Vec3& bad : {Vec3(1e-3, 0, 1e-3), Vec3(-1, -1, -1),
                          Vec3(1, std::numeric_limits<double>::quiet_NaN(), 1)}) {
    PenetrationRequest req = ColdRequest();
    req.principal_inertia_over_mass = bad;
    PdgQueryData d;
    PenetrationResult r;
    ComputePdg(*c.stick, c.X_WA, *c.slot, Pose::Identity(), req, &d, &r);
    EXPECT_EQ(r.status, PdStatus::kFailed);
    EXPECT_NE(r.failure.find("principal_inertia_over_mass"), std::string::npos) << r.failure;
  }
}

// --------------------------------------------------------------------------
// Force only (a scene without torque)

void ExpectForceOnlyMatches(const PenetrationResult& r, const Material& m, const Vec3& p_WAcm) {
  const Wrench full = PdWrench(r, m, p_WAcm);
  const Wrench force = PdWrench(r, m, p_WAcm, WrenchTerms::kForceOnly);
  EXPECT_GT(full.torque.norm(), 0) << "the case must have a torque to skip";
  EXPECT_GT(full.force.norm(), 0);
  EXPECT_EQ(force.force, full.force);
  EXPECT_EQ(force.torque, Vec3::Zero());
}

TEST(PdForceOnly, SameForceAndZeroTorqueForPdtAndPdg) {
  const StickInSlot c;
  Material m;
  m.stiffness = 800;
  m.rotational_stiffness = 0.3;
  const Vec3 p_WAcm = c.X_WA * c.stick->mass().p_MC;
  {
    SCOPED_TRACE("PDt with regions");
    PdQueryData d;
    PenetrationResult r;
    ComputePdt(*c.stick, c.X_WA, *c.slot, Pose::Identity(), ColdRequest(), &d, &r);
    ASSERT_FALSE(r.regions.empty());
    ExpectForceOnlyMatches(r, m, p_WAcm);
    EXPECT_EQ(PenaltyForce(r, m), PenaltyWrench(r, m, p_WAcm).force);
    PenetrationResult no_regions = r;  // the fallback f = k d
    no_regions.regions.clear();
    EXPECT_EQ(PenaltyForce(no_regions, m), PenaltyWrench(no_regions, m, p_WAcm).force);
  }
  {
    SCOPED_TRACE("PDg");
    PdgQueryData d;
    PenetrationResult r;
    ComputePdg(*c.stick, c.X_WA, *c.slot, Pose::Identity(), ColdRequest(), &d, &r);
    ExpectForceOnlyMatches(r, m, p_WAcm);
  }
  PenetrationResult separated;
  separated.status = PdStatus::kSeparated;
  separated.translation_W = Vec3(1, 2, 3);
  EXPECT_EQ(PenaltyForce(separated, m), Vec3::Zero());
}

TEST(PdForceOnly, ScenePdSumsTheSameForceWithoutTorque) {
  const StickInSlot c;
  // The slot, and a box far away that the broad phase skips.
  const std::vector<SceneBody> bodies = {{c.slot, Pose::Identity(), Material{}},
                                         {MakeModel(shapes::Box(Vec3(0.01, 0.01, 0.01))),
                                          Pose::FromTranslation(Vec3(0, 0, 0.5)), Material{}}};
  for (PdMode mode : {PdMode::kTranslational, PdMode::kGeneralized}) {
    SCOPED_TRACE(ToString(mode));
    ScenePdData d0, d1;
    ScenePdResult full, force;
    ComputeScenePd(mode, *c.stick, c.X_WA, bodies, ColdRequest(), &d0, &full);
    ComputeScenePd(mode, *c.stick, c.X_WA, bodies, ColdRequest(), &d1, &force,
                   WrenchTerms::kForceOnly);
    ASSERT_TRUE(full.colliding);
    EXPECT_GT(full.wrench.torque.norm(), 0);
    EXPECT_EQ(force.wrench.force, full.wrench.force);
    EXPECT_EQ(force.wrench.torque, Vec3::Zero());
    EXPECT_EQ(force.deepest, full.deepest);
  }
}

// A body the broad phase skips gets a fresh result: nothing of an earlier
// query on the same ScenePdResult stays behind (a failure text, query
// counts, PDg's rotation), in either mode.
TEST(ScenePd, ABodyTheBroadPhaseSkipsKeepsNothingOfTheLastQuery) {
  const StickInSlot c;
  const std::vector<SceneBody> bodies = {{c.slot, Pose::Identity(), Material{}}};
  const Pose X_far = Pose::FromTranslation(Vec3(5, 0, 0));
  Pose X_nan = c.X_WA;
  X_nan.t.x() = std::numeric_limits<double>::quiet_NaN();
  for (PdMode mode : {PdMode::kTranslational, PdMode::kGeneralized}) {
    SCOPED_TRACE(ToString(mode));
    for (const Pose& before : {c.X_WA, X_nan}) {
      ScenePdData d;
      ScenePdResult r;
      ComputeScenePd(mode, *c.stick, before, bodies, ColdRequest(), &d, &r);
      ASSERT_TRUE(r.tested[0]);
      const PenetrationResult& b = r.bodies[0];
      // The earlier query left something a stale copy would keep.
      EXPECT_TRUE(!b.failure.empty() || b.collision_queries > 0 ||
                  b.rotation_axis_W != Vec3::UnitZ())
          << ToString(b.status);
      ComputeScenePd(mode, *c.stick, X_far, bodies, ColdRequest(), &d, &r);
      ASSERT_FALSE(r.tested[0]);
      const PenetrationResult& a = r.bodies[0];
      EXPECT_EQ(a.status, PdStatus::kSeparated);
      EXPECT_EQ(a.mode, mode);
      EXPECT_EQ(a.failure, "");
      EXPECT_EQ(a.depth, 0);
      EXPECT_EQ(a.translation_W, Vec3::Zero());
      EXPECT_EQ(a.X_WA_result.t, X_far.t);
      EXPECT_EQ(a.X_WA_result.R, X_far.R);
      EXPECT_TRUE(a.features.empty());
      EXPECT_TRUE(a.regions.empty());
      EXPECT_EQ(a.iterations, 0);
      EXPECT_EQ(a.time_us, 0);
      EXPECT_EQ(a.collision_queries, 0);
      EXPECT_EQ(a.ccd_queries, 0);
      EXPECT_EQ(a.sigma, 0);
      EXPECT_EQ(a.rotation_angle, 0);
      EXPECT_EQ(a.rotation_axis_W, Vec3::UnitZ());
      EXPECT_FALSE(r.colliding);
    }
  }
}

// --------------------------------------------------------------------------
// Hard cases

TEST(PdgHardCases, QueryRotationsThroughAHalfTurnAreFiniteAndContinuous) {
  const ModelPtr A = MakeModel(shapes::Box(Vec3(0.05, 0.02, 0.01)));
  const ModelPtr B = MakeModel(shapes::Box(Vec3(0.2, 0.2, 0.05)));
  const FclModel fa(A->mesh()), fb(B->mesh());
  const Vec3 axis = Vec3(0.2, 1, 0.1).normalized();
  std::vector<double> depths;
  std::vector<Pose> answers;
  for (double delta : {-1e-4, -1e-7, 0.0, 1e-7, 1e-4}) {
    SCOPED_TRACE(delta);
    const Pose X_WA{Eigen::AngleAxisd(M_PI + delta, axis).toRotationMatrix(),
                    Vec3(0.13, 0.02, 0.06)};
    PdgQueryData data;
    PdQueryData pdt_data;
    PenetrationResult r, pdt;
    ComputePdg(*A, X_WA, *B, Pose::Identity(), ColdRequest(), &data, &r);
    ComputePdt(*A, X_WA, *B, Pose::Identity(), ColdRequest(), &pdt_data, &pdt);
    ExpectVerifiedPdg(*A, X_WA, Pose::Identity(), fa, fb, r, pdt.depth);
    depths.push_back(r.depth);
    answers.push_back(r.X_WA_result);
  }
  for (std::size_t i = 1; i < depths.size(); ++i) {
    // 1e-4 rad moves a point at most 5.4e-6 m: the depth moves by as much.
    EXPECT_NEAR(depths[i], depths[i - 1], 2e-5) << i;
    EXPECT_LT((answers[i].t - answers[i - 1].t).norm(), 1e-3) << i;
  }
}

TEST(PdgHardCases, SphereLikeProbeIgnoresItsArbitraryPrincipalAxes) {
  // A cube's inertia is isotropic: the eigensolver alone would return any
  // axes, and a 1e-9 stretch along the diagonal turned them by 55 degrees
  // (and the cold start's directions with them: 21 of 120 answers moved, up
  // to 22%). The answers must not move with such a change, and the object
  // norm must not see which axes were chosen. A change that small can still
  // flip a discrete decision of the local iteration (a feature pair within
  // the contact tolerance or not): over 1,669 poses (--long, seven seeds) 4
  // answers moved, by 3.6e-5 to 6.5%; at most 1% of the answers may.
  const ModelPtr B = MakeModel(shapes::Torus());
  const FclModel fb(B->mesh());
  const ModelPtr cube = MakeModel(shapes::Box(Vec3(0.01, 0.01, 0.01)));
  const ModelPtr stretched = MakeModel(shapes::Box(Vec3(0.01 * (1 + 1e-9), 0.01, 0.01)));
  const ModelPtr diagonal = [] {
    const Mesh box = shapes::Box(Vec3(0.01, 0.01, 0.01));
    std::vector<Vec3> V = box.vertices();
    const Vec3 d = Vec3(1, 1, 1).normalized();
    for (Vec3& v : V) v += 1e-9 * d.dot(v) * d;
    return MakeModel(Mesh::FromArrays(V, box.triangles(), "cube stretched along its diagonal"));
  }();
  // The same cube with its file frame N turned by X_NM: its axes in the
  // world are others than the cube's.
  const Pose X_NM =
      Pose::FromQuaternion(Quat(Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized())), Vec3::Zero());
  const ModelPtr turned = MakeModel(shapes::Box(Vec3(0.01, 0.01, 0.01)).Transformed(X_NM));
  ASSERT_GT((turned->mass().X_MB.R - X_NM.R * cube->mass().X_MB.R).norm(), 0.1);
  const ModelPtr ball = MakeModel(shapes::Sphere(0.01, 2));
  std::mt19937_64 rng(testing::TestSeed() + 11);
  int penetrating = 0, moved = 0;
  // Whether the answer r moved away from the cube's answer r1.
  auto moved_from = [](const PenetrationResult& r, const PenetrationResult& r1) {
    return std::abs(r.depth - r1.depth) > 1e-6 * r1.depth + 1e-9 ||
           (r.X_WA_result.t - r1.X_WA_result.t).norm() > 1e-5 * r1.depth + 1e-9;
  };
  for (int i = 0; i < testing::TestCount(12); ++i) {
    const Pose X_WA = NearSurfacePose(*cube, *B, rng, 0.004);
    PdgQueryData d1, d2, d3;
    PdQueryData pd1, pd3;
    PenetrationResult r1, r2, r3, t1, t3;
    ComputePdg(*cube, X_WA, *B, Pose::Identity(), ColdRequest(), &d1, &r1);
    if (r1.status == PdStatus::kSeparated) continue;
    ++penetrating;
    ComputePdg(*stretched, X_WA, *B, Pose::Identity(), ColdRequest(), &d2, &r2);
    ComputePdt(*cube, X_WA, *B, Pose::Identity(), ColdRequest(), &pd1, &t1);
    const FclModel fa(cube->mesh());
    ExpectVerifiedPdg(*cube, X_WA, Pose::Identity(), fa, fb, r1, t1.depth);
    ASSERT_NE(r2.status, PdStatus::kFailed);
    moved += moved_from(r2, r1);
    PdgQueryData d4;
    PenetrationResult r4;
    ComputePdg(*diagonal, X_WA, *B, Pose::Identity(), ColdRequest(), &d4, &r4);
    ASSERT_NE(r4.status, PdStatus::kFailed) << r4.failure;
    moved += moved_from(r4, r1);
    // The cube's answer measured in the turned cube's axes (its file frame
    // placed where the cube is) has the same sigma.
    const Vec6 z = RelativeConfiguration(turned->mass(), X_WA * X_NM.Inverse(),
                                         r1.X_WA_result * X_NM.Inverse());
    EXPECT_NEAR(z.cwiseProduct(z).dot(PdgMetricDiagonal(turned->mass(), ColdRequest())), r1.sigma,
                1e-9 * r1.sigma)
        << i;
    // A polyhedral ball gains almost nothing by turning: rotation is a small
    // share of its sigma (at most 6.3% over the 1,669 poses; its PDg can
    // still end well below PDt, 0.79 times once, in a better basin reached
    // by translation).
    ComputePdg(*ball, X_WA, *B, Pose::Identity(), ColdRequest(), &d3, &r3);
    if (r3.status == PdStatus::kSeparated) continue;
    ComputePdt(*ball, X_WA, *B, Pose::Identity(), ColdRequest(), &pd3, &t3);
    const FclModel fball(ball->mesh());
    ExpectVerifiedPdg(*ball, X_WA, Pose::Identity(), fball, fb, r3, t3.depth);
    EXPECT_LT(r3.sigma - r3.translation_W.squaredNorm(), 0.1 * r3.sigma) << i;
  }
  EXPECT_GT(penetrating, 3);
  EXPECT_LE(moved, 2 * penetrating / 100)
      << "of " << 2 * penetrating << " answers of the stretched cubes";
}

TEST(PdgHardCases, ScalesFromMillimetresToKilometres) {
  for (double scale : {1e-3, 1.0, 1e3}) {
    SCOPED_TRACE(scale);
    const ModelPtr A = MakeModel(shapes::Box(Vec3(1, 0.2, 0.1) * scale));
    const ModelPtr B = MakeModel(shapes::Box(Vec3(2, 2, 1) * scale));
    const Pose X_WA{Eigen::AngleAxisd(0.05, Vec3::UnitY()).toRotationMatrix(),
                    Vec3(0.3, 0.2, 1.1) * scale};
    PdgQueryData data;
    PdQueryData pdt_data;
    PenetrationResult r, pdt;
    ComputePdg(*A, X_WA, *B, Pose::Identity(), ColdRequest(), &data, &r);
    ComputePdt(*A, X_WA, *B, Pose::Identity(), ColdRequest(), &pdt_data, &pdt);
    const FclModel fa(A->mesh()), fb(B->mesh());
    ExpectVerifiedPdg(*A, X_WA, Pose::Identity(), fa, fb, r, pdt.depth);
    // A tilted bar dipping one end into a slab: turning it flat is cheaper.
    EXPECT_LT(r.depth, 0.9 * pdt.depth);
  }
}

TEST(PdgHardCases, ProbeInsideAClosedBodyWithoutSurfaceContact) {
  const ModelPtr big = MakeModel(shapes::Box(Vec3(1, 1, 1)));
  const ModelPtr small = MakeModel(shapes::Box(Vec3(0.1, 0.05, 0.02)));
  const Pose X_WA = Pose::FromTranslation(Vec3(0.7, 0.1, -0.2));
  PdgQueryData data;
  PdQueryData pdt_data;
  PenetrationResult r, pdt;
  ComputePdg(*small, X_WA, *big, Pose::Identity(), ColdRequest(), &data, &r);
  ComputePdt(*small, X_WA, *big, Pose::Identity(), ColdRequest(), &pdt_data, &pdt);
  const FclModel fa(small->mesh()), fb(big->mesh());
  ExpectVerifiedPdg(*small, X_WA, Pose::Identity(), fa, fb, r, pdt.depth);
  EXPECT_NEAR(pdt.depth, 0.4, 1e-9);
}

TEST(PdgHardCases, SeparatedAndFailedResultsAreClean) {
  const ModelPtr A = MakeModel(shapes::Box(Vec3(0.1, 0.1, 0.1)));
  PdgQueryData data;
  PenetrationResult r;
  ComputePdg(*A, Pose::FromTranslation(Vec3(1, 0, 0)), *A, Pose::Identity(), PenetrationRequest(),
             &data, &r);
  EXPECT_EQ(r.status, PdStatus::kSeparated);
  EXPECT_EQ(r.mode, PdMode::kGeneralized);
  EXPECT_EQ(r.depth, 0);
  EXPECT_EQ(r.sigma, 0);
  const Wrench w = PdgWrench(r, Material{});
  EXPECT_EQ(w.force.norm() + w.torque.norm(), 0);
  // Non-finite input: a failure with a reason, not garbage.
  Pose bad = Pose::Identity();
  bad.t.x() = std::nan("");
  ComputePdg(*A, bad, *A, Pose::Identity(), PenetrationRequest(), &data, &r);
  EXPECT_EQ(r.status, PdStatus::kFailed);
  EXPECT_NE(r.failure.find("finite"), std::string::npos) << r.failure;
}

// --------------------------------------------------------------------------
// Metamorphic

TEST(PdgMetamorphic, CommonRigidTransformMovesTheAnswer) {
  const ModelPtr A = MakeModel(shapes::Spoon());
  const ModelPtr B = MakeModel(shapes::Cup());
  const TransformRunCounts n = CommonRigidTransformRun<PdgQuery>(
      *A, *B, testing::TestSeed() + 7, testing::TestCount(12),
      [](const PenetrationResult& r1, const PenetrationResult& r2, const Pose& G) {
        // Both runs see the same relative pose up to rounding; a knife-edge
        // tie of the cold start can still pick another local optimum (see
        // the PDt metamorphic test), so most, not all, must agree exactly.
        const bool same =
            std::abs(r2.depth - r1.depth) <= 1e-6 * r1.depth + 1e-9 &&
            (r2.translation_W - G.R * r1.translation_W).norm() <= 1e-5 * r1.depth + 1e-9 &&
            std::abs(r2.rotation_angle - r1.rotation_angle) <= 1e-5;
        if (!same) {
          EXPECT_NEAR(r2.depth, r1.depth, 0.03 * r1.depth);
        }
        return same;
      });
  EXPECT_GT(n.checked, 3);
  EXPECT_GE(n.identical, n.checked * 3 / 4);
}

// --------------------------------------------------------------------------
// Motion coherence and allocation

// A bar pressed into a slab while tilting and turning: coherent starts carry
// the rotation from frame to frame. Returns (frames, rotated frames, sum of
// PDg depths / sum of PDt depths); every answer is verified.
struct TrajectoryStats {
  int frames = 0, rotated = 0, above_pdt = 0;
  double worst_ratio = 0, sum_pdg = 0, sum_pdt = 0;
};

TrajectoryStats RunBarTrajectory(const PenetrationRequest& req, bool expect_below_pdt) {
  const ModelPtr A = MakeModel(shapes::Box(Vec3(0.06, 0.01, 0.01)));
  const ModelPtr B = MakeModel(shapes::Box(Vec3(0.3, 0.3, 0.1)));
  const FclModel fa(A->mesh()), fb(B->mesh());
  PdgQueryData data;
  PdQueryData pdt_data;  // fed the same sequence as PDg's own PDt start
  PenetrationResult r, pdt;
  TrajectoryStats st;
  for (int k = 0; k < 200; ++k) {
    const double s = k / 200.0;
    const Pose X_WA{
        Eigen::AngleAxisd(0.15 * std::sin(2 * M_PI * s), Vec3::UnitY()).toRotationMatrix() *
            Eigen::AngleAxisd(0.3 * s, Vec3::UnitZ()).toRotationMatrix(),
        Vec3(0.05 * s, 0.02, 0.1 + 0.012 - 0.008 * std::sin(M_PI * s))};
    ComputePdg(*A, X_WA, *B, Pose::Identity(), req, &data, &r);
    ComputePdt(*A, X_WA, *B, Pose::Identity(), req, &pdt_data, &pdt);
    if (r.status == PdStatus::kSeparated) {
      EXPECT_EQ(pdt.status, PdStatus::kSeparated);
      continue;
    }
    SCOPED_TRACE(k);
    ++st.frames;
    st.rotated += r.rotation_angle > 1e-4;
    st.above_pdt += r.depth > pdt.depth * (1 + 1e-9);
    st.worst_ratio = std::max(st.worst_ratio, r.depth / pdt.depth);
    st.sum_pdg += r.depth;
    st.sum_pdt += pdt.depth;
    ExpectVerifiedPdg(*A, X_WA, Pose::Identity(), fa, fb, r,
                      expect_below_pdt ? pdt.depth : std::numeric_limits<double>::infinity());
  }
  EXPECT_GT(data.coherence_size(), 0);
  return st;
}

TEST(PdgCoherence, WithThePdtStartEveryAnswerIsVerifiedAndNeverAbovePdt) {
  PenetrationRequest req;
  req.pdg_always_pdt_start = true;
  const TrajectoryStats st = RunBarTrajectory(req, true);
  EXPECT_GT(st.frames, 100);
  EXPECT_GT(st.rotated, st.frames / 2);
}

TEST(PdgCoherence, CoherentStartsAreVerifiedAndCloseToPdtOrBetter) {
  // Without the PDt start on every frame the answer follows its own local
  // optimum; it may end above PDt on a frame, not on the whole.
  const TrajectoryStats st = RunBarTrajectory(PenetrationRequest(), false);
  std::cout << "[ coherent PDg ] " << st.frames << " frames, " << st.rotated << " rotated, "
            << st.above_pdt << " above PDt (worst " << st.worst_ratio
            << "x), sum PDg / sum PDt = " << st.sum_pdg / st.sum_pdt << "\n";
  EXPECT_GT(st.frames, 100);
  EXPECT_GT(st.rotated, st.frames / 2);
  EXPECT_LT(st.sum_pdg, st.sum_pdt);
  EXPECT_LE(st.above_pdt, st.frames / 5);
  EXPECT_LT(st.worst_ratio, 1.5);
}

// Frames 0..last of `b`'s trajectory through PDg and PDt side by side (each
// with its own coherence, as bench_pdg runs them): on_frame(i, pdg, pdt).
template <typename OnFrame>
void ReplayWithPdt(const bench::Benchmark& b, std::size_t last, const PenetrationRequest& request,
                   OnFrame&& on_frame) {
  PdgQueryData data;
  PdQueryData pdt_data;
  PenetrationResult r, pdt;
  for (std::size_t i = 0; i <= last; ++i) {
    const Pose& X_WA = b.frames[i].X_WA;
    ComputePdg(*b.probe, X_WA, *b.scene, Pose::Identity(), request, &data, &r);
    ComputePdt(*b.probe, X_WA, *b.scene, Pose::Identity(), request, &pdt_data, &pdt);
    on_frame(i, r, pdt);
  }
}

// bench_pdg's hammer-vs-beast trajectory with the tip following the raw
// surface height (unlimited slope: at frame 1120 the ray passes an edge and
// the probe jumps 1 cm): at frame 1120 the coherent start
// (the previous answer, pushed out and swept back) comes out half as deep
// again as the answer it came from, in a worse basin; followed as is, PDg
// ended up to 1.6 times PDt's depth on frames 1120-1128 and stayed there.
// Such a start is now compared with PDt's answer. Replays the frames up to
// the episode (coherence depends on the history) with PDt alongside, as the
// benchmark does; from frame 1100 on every answer is verified with FCL and
// must not exceed PDt.
TEST(PdgCoherence, AStartThatLostItsBasinIsComparedWithPdt) {
  HAPTICPD_REQUIRE_MODEL(path, "beast.obj");
  const bench::Benchmark b =
      TableOneBenchmark(path, "hammer-beast20k", std::numeric_limits<double>::infinity());
  ASSERT_EQ(b.name, "hammer-beast20k");
  const FclModel fa(b.probe->mesh()), fb(b.scene->mesh());
  const PenetrationRequest request;
  int checked = 0;
  ReplayWithPdt(b, 1135, request,
                [&](std::size_t i, const PenetrationResult& r, const PenetrationResult& pdt) {
                  if (i < 1100 || r.status == PdStatus::kSeparated) return;
                  SCOPED_TRACE(i);
                  ++checked;
                  ExpectVerifiedPdg(*b.probe, b.frames[i].X_WA, Pose::Identity(), fa, fb, r,
                                    pdt.depth, request);
                });
  EXPECT_GT(checked, 30);
}

// bench_pdg's hammer-vs-beast trajectory (the default, continuous one): from
// frame 1132 on the coherent answer stays in a basin where the probe is
// turned while PDt's answer under the sliding probe gets shallower; without
// the periodic check against PDt it ended up to 1.36 times PDt's depth over
// 40 frames. With the check against PDt every 16th penetrating query (the
// default; it runs in the first cheap query once due) no answer is more than
// 10 % above PDt (1.058 when written); with the check off the drift is back
// (the check is what bounds it).
TEST(PdgCoherence, ThePeriodicPdtCheckBoundsTheDriftAbovePdt) {
  HAPTICPD_REQUIRE_MODEL(path, "beast.obj");
  const bench::Benchmark b = TableOneBenchmark(path, "hammer-beast20k");
  ASSERT_EQ(b.name, "hammer-beast20k");
  auto worst_ratio = [&](const PenetrationRequest& request) {
    double worst = 0;
    ReplayWithPdt(b, 1200, request,
                  [&](std::size_t i, const PenetrationResult& r, const PenetrationResult& pdt) {
                    if (r.status == PdStatus::kSeparated || !(pdt.depth > 0)) return;
                    EXPECT_TRUE(std::isfinite(r.depth)) << i;
                    worst = std::max(worst, r.depth / pdt.depth);
                  });
    return worst;
  };
  const PenetrationRequest checked;
  ASSERT_EQ(checked.pdg_pdt_check_period, 16);
  EXPECT_LT(worst_ratio(checked), 1.1);
  PenetrationRequest unchecked;
  unchecked.pdg_pdt_check_period = 0;
  EXPECT_GT(worst_ratio(unchecked), 1.2);
}

TEST(PdgAllocation, NoHeapAllocationAfterWarmUp) {
  if (!testing::CountAllocations::Available()) {
    GTEST_SKIP() << "allocation counting is off under sanitizers";
  }
  // Pressed down 0.1 mm and turned 2 mrad a frame.
  const std::size_t allocations = SpoonInCupAllocations<PdgQuery>([](const Pose& X0) {
    std::vector<Pose> poses;
    for (int k = 0; k < 40; ++k) {
      const Mat3 R = Eigen::AngleAxisd(0.002 * k, Vec3::UnitX()).toRotationMatrix() * X0.R;
      poses.push_back(Pose{R, X0.t + Vec3(0, 0, -0.0001 * k)});
    }
    return poses;
  });
  EXPECT_EQ(allocations, 0u);
}

}  // namespace
}  // namespace hapticpd::pd
