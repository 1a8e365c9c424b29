// Test runs shared by the PDt and PDg suites (tests/pd/pdt_test.cc,
// tests/pd/pdg_test.cc): the same poses, queries and counts for either
// query, with the checks that differ passed in by the test.
#pragma once

#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <vector>

#include "pd/pdg.h"
#include "pd/pdt.h"
#include "pd/shapes.h"
#include "tests/pd/pd_test_support.h"
#include "tests/pd/random_poses.h"
#include "tests/test_util.h"

namespace hapticpd::pd {

/// A query function (ComputePdt, ComputePdg) with its query data as a type,
/// so that one run can take either.
template <class DataT,
          void (*Compute)(const GeometryModel&, const Pose&, const GeometryModel&, const Pose&,
                          const PenetrationRequest&, DataT*, PenetrationResult*)>
struct PdQuery {
  using Data = DataT;
  void operator()(const GeometryModel& A, const Pose& X_WA, const GeometryModel& B,
                  const Pose& X_WB, const PenetrationRequest& request, Data* data,
                  PenetrationResult* result) const {
    Compute(A, X_WA, B, X_WB, request, data, result);
  }
};
using PdtQuery = PdQuery<PdQueryData, &ComputePdt>;
using PdgQuery = PdQuery<PdgQueryData, &ComputePdg>;

/// A probe A and a scene B with their FCL models (for independent checks).
struct ProbeAndScene {
  ProbeAndScene(ModelPtr a, ModelPtr b) : A(std::move(a)), B(std::move(b)) {}
  ModelPtr A, B;
  testing::FclModel fa{A->mesh()}, fb{B->mesh()};
};

/// Calls `fn(ps, c)` for each case `c` (a name, meshes `a` and `b`), `ps`
/// its probe and scene, under a trace of the case's name; stops at the first
/// fatal failure.
template <class Case, class Fn>
void ForEachPair(std::vector<Case> cases, Fn fn) {
  for (Case& c : cases) {
    SCOPED_TRACE(c.name);
    const ProbeAndScene ps(MakeModel(std::move(c.a)), MakeModel(std::move(c.b)));
    fn(ps, c);
    if (::testing::Test::HasFatalFailure()) return;
  }
}

/// Cold queries of `ps.A` at `count` seeded poses near `ps.B`'s surface
/// (NearSurfacePose with `spread` m, seed TestSeed()), B at the identity.
/// Calls `check(X_WA, result)` on every answer that is not separated and
/// returns how many there were; stops at the first fatal failure.
template <class Query, class Check>
int PenetratingNearSurface(const ProbeAndScene& ps, double spread, int count, Check check) {
  std::mt19937_64 rng(testing::TestSeed());
  typename Query::Data data;
  PenetrationResult r;
  int penetrating = 0;
  for (int i = 0; i < count; ++i) {
    const Pose X_WA = testing::NearSurfacePose(*ps.A, *ps.B, rng, spread);
    Query()(*ps.A, X_WA, *ps.B, Pose::Identity(), ColdRequest(), &data, &r);
    if (r.status == PdStatus::kSeparated) continue;
    ++penetrating;
    check(X_WA, r);
    if (::testing::Test::HasFatalFailure()) break;
  }
  return penetrating;
}

/// How a common-rigid-transform run went.
struct TransformRunCounts {
  int checked = 0;    ///< poses where the untransformed answer penetrates
  int identical = 0;  ///< of those, answers that moved with the transform exactly
};

/// The metamorphic run: cold queries of A at `count` seeded poses near B's
/// surface (4 mm spread, seed `seed`), once with B at the identity and once
/// with both bodies moved by a common random rigid transform G. A separated
/// answer must stay separated; for the others `same(r1, r2, G)` says whether
/// the transformed answer r2 is r1 moved by G (and checks r2 when it is not).
template <class Query, class Same>
TransformRunCounts CommonRigidTransformRun(const GeometryModel& A, const GeometryModel& B,
                                           std::uint64_t seed, int count, Same same) {
  std::mt19937_64 rng(seed);
  typename Query::Data d1, d2;
  PenetrationResult r1, r2;
  TransformRunCounts n;
  for (int i = 0; i < count; ++i) {
    const Pose X_WA = testing::NearSurfacePose(A, B, rng, 0.004);
    const Pose G = Pose::FromQuaternion(testing::RandomRotation(rng), Vec3(0.3, -1.2, 2.0));
    Query()(A, X_WA, B, Pose::Identity(), ColdRequest(), &d1, &r1);
    Query()(A, G * X_WA, B, G, ColdRequest(), &d2, &r2);
    if (r1.status == PdStatus::kSeparated) {
      EXPECT_EQ(r2.status, PdStatus::kSeparated);
      continue;
    }
    ++n.checked;
    n.identical += same(r1, r2, G);
  }
  return n;
}

/// Heap allocations of the query (with motion coherence, one query data
/// throughout) on a spoon pressed into a cup along `make_poses(X0)`, X0 a
/// seeded pose touching the cup, after warm-up (AllocationsAfterWarmUp).
template <class Query, class MakePoses>
std::size_t SpoonInCupAllocations(MakePoses make_poses) {
  const ModelPtr A = MakeModel(shapes::Spoon());
  const ModelPtr B = MakeModel(shapes::Cup());
  typename Query::Data data;
  const PenetrationRequest req;
  PenetrationResult r;
  std::mt19937_64 rng(testing::TestSeed());
  const std::vector<Pose> poses = make_poses(testing::NearSurfacePose(*A, *B, rng, 0.0));
  return AllocationsAfterWarmUp(
      poses, [&](const Pose& X) { Query()(*A, X, *B, Pose::Identity(), req, &data, &r); });
}

}  // namespace hapticpd::pd
