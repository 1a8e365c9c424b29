// PDt on convex hulls of the procedural shapes (pd/convex_hull.h): over
// seeded random penetrating poses, ComputePdt equals the exact
// separating-axis value (an independent brute-force SAT, cross-checked with
// pd/convex.cc's pruned SAT and with Bullet's EPA), every answer is a contact
// verified with FCL, and swapping probe and scene negates the PD vector. The
// general contact-space iteration is run on the same pairs with the convex
// shortcut disabled.
#include <gtest/gtest.h>

#include <algorithm>
#include <iostream>
#include <random>
#include <string>

#include "pd/convex.h"
#include "pd/convex_hull.h"
#include "pd/pdt.h"
#include "pd/shapes.h"
#include "tests/oracles/bullet_oracle.h"
#include "tests/oracles/fcl_oracle.h"
#include "tests/pd/pd_test_support.h"
#include "tests/pd/random_poses.h"
#include "tests/test_util.h"

namespace hapticpd::pd {
namespace {

using testing::FclModel;
using testing::RandomRotation;

// Low resolutions keep the brute-force SAT (all edge pairs, supports by scan)
// cheap; the hulls still have tens of vertices and many face orientations.
Mesh HullOf(const std::string& spec) {
  return ConvexHull(shapes::MakeShape(spec).vertices(), "hull of " + spec);
}

struct HullPair {
  const char* name;
  std::string a, b;  // HullOf specs, or "box:..." as is
};

Mesh Build(const std::string& spec) {
  return spec.rfind("box", 0) == 0 ? shapes::MakeShape(spec) : HullOf(spec);
}

std::vector<HullPair> Pairs() {
  return {
      {"torus-spoon", "torus:0.06,0.02,16,8", "spoon:1"},
      {"hammer-box", "hammer:1", "box:0.04,0.03,0.05"},
      {"torusknot-cup", "torusknot:2,3,0.05,0.008,48,6", "cup:1"},
      {"cup-torus", "cup:1", "torus:0.06,0.02,16,8"},
      {"box-torusknot", "box:0.02,0.05,0.01", "torusknot:2,3,0.05,0.008,48,6"},
      {"spoon-hammer", "spoon:1", "hammer:1"},
  };
}

// A at a random orientation with its centre of mass near B's, Gaussian
// offset of `spread` metres: about half the poses penetrate.
Pose RandomPoseNear(const GeometryModel& A, const GeometryModel& B, const Pose& X_WB,
                    std::mt19937_64& rng, double spread) {
  std::normal_distribution<double> n(0, 1);
  Pose X = Pose::FromQuaternion(RandomRotation(rng), Vec3::Zero());
  X.t = X_WB * B.mass().p_MC + Vec3(n(rng), n(rng), n(rng)) * spread - X.R * A.mass().p_MC;
  return X;
}

TEST(PdtConvexHull, EqualsExactSeparatingAxisValueOnHullsOfShapes) {
  std::mt19937_64 rng(testing::TestSeed());
  const int count = testing::TestCount(testing::kSanitized ? 20 : 80);
  double worst_fast = 0, worst_sat = 0, worst_epa = 0, worst_swap = 0;
  int total = 0, general_exact = 0, general_total = 0;
  double worst_general = 0;
  std::string worst_case;
  for (const HullPair& pair : Pairs()) {
    SCOPED_TRACE(pair.name);
    const ModelPtr A = MakeModel(Build(pair.a));
    const ModelPtr B = MakeModel(Build(pair.b));
    ASSERT_TRUE(A->convex() && B->convex());
    const testing::BulletHull ha(A->mesh()), hb(B->mesh());
    const FclModel fa(A->mesh()), fb(B->mesh());
    const double spread = 0.2 * (A->radius_about_com() + B->radius_about_com());
    PdQueryData data, swapped, general;
    // Iterate to convergence: the default improvement_tolerance (1e-4) alone
    // stops up to 1e-4 relative above the optimum.
    PenetrationRequest general_req = ColdRequest();
    general_req.convex_shortcut = false;
    general_req.improvement_tolerance = 1e-12;
    general_req.max_iterations = 50;
    PenetrationResult r, rs, rg;
    int penetrating = 0, bullet_gave_up = 0;
    for (int i = 0; i < count; ++i) {
      SCOPED_TRACE(i);
      const Pose X_WB = Pose::FromQuaternion(RandomRotation(rng), Vec3(0.01, -0.02, 0.03));
      const Pose X_WA = RandomPoseNear(*A, *B, X_WB, rng, spread);
      Vec3 dir;
      const double exact = BruteForceConvexPdt(A->mesh(), X_WA, B->mesh(), X_WB, &dir);
      ComputePdt(*A, X_WA, *B, X_WB, ColdRequest(), &data, &r);
      if (exact <= 1e-9) {
        EXPECT_TRUE(r.status == PdStatus::kSeparated || r.depth <= 1e-9) << exact;
        continue;
      }
      ++penetrating;
      ASSERT_NE(r.status, PdStatus::kFailed) << r.failure;
      // The answer (convex shortcut) against the brute-force SAT value.
      EXPECT_NEAR(r.depth, exact, 1e-6 * exact);
      worst_fast = std::max(worst_fast, std::abs(r.depth - exact) / exact);
      // pd/convex.cc's pruned SAT agrees with the brute force.
      const ConvexPdtResult sat = ConvexPdt(A->mesh(), X_WA, B->mesh(), X_WB);
      EXPECT_NEAR(sat.depth, exact, 1e-9 * exact);
      worst_sat = std::max(worst_sat, std::abs(sat.depth - exact) / exact);
      // Bullet's EPA, to its own convergence tolerance (it stops early on
      // polytopes with many vertices: 2.8e-3 relative seen with seed 1).
      const testing::EpaResult epa = BulletPenetration(ha, X_WA, hb, X_WB);
      if (epa.penetrating) {
        EXPECT_NEAR(epa.depth, exact, 5e-3 * exact) << "Bullet EPA disagrees with the SAT value";
        worst_epa = std::max(worst_epa, std::abs(epa.depth - exact) / exact);
      } else {
        ++bullet_gave_up;
      }
      ExpectRealContact(fa, fb, X_WB, r);
      ExpectConsistent(X_WA, r);
      // Swapping probe and scene negates the PD vector.
      ComputePdt(*B, X_WB, *A, X_WA, ColdRequest(), &swapped, &rs);
      EXPECT_LT((rs.translation_W + r.translation_W).norm(), 1e-6 * exact);
      worst_swap = std::max(worst_swap, (rs.translation_W + r.translation_W).norm() / exact);
      // The general contact-space iteration from a cold start: never below
      // the exact value (its answers are verified contacts); usually equal.
      ComputePdt(*A, X_WA, *B, X_WB, general_req, &general, &rg);
      ASSERT_NE(rg.status, PdStatus::kFailed) << rg.failure;
      ASSERT_NE(rg.status, PdStatus::kSeparated);
      EXPECT_GE(rg.depth, exact * (1 - 1e-9));
      ExpectRealContact(fa, fb, X_WB, rg);
      ++general_total;
      const double rel = (rg.depth - exact) / exact;
      general_exact += rel <= 1e-6;
      if (rel > worst_general) {
        worst_general = rel;
        worst_case = std::string(pair.name) + " pose " + std::to_string(i) + " (" +
                     std::to_string(rg.iterations) + " iterations)";
      }
    }
    total += penetrating;
    EXPECT_GT(penetrating, count / 4);
    EXPECT_LE(bullet_gave_up, penetrating / 20 + 1);
  }
  std::cout << "[ PDt hulls ] " << total << " penetrating poses; max rel. error: shortcut "
            << worst_fast << ", pd/convex.cc SAT " << worst_sat << ", Bullet EPA " << worst_epa
            << ", swap " << worst_swap << "; general path exact in " << general_exact << "/"
            << general_total << ", worst +" << worst_general * 100 << "% at " << worst_case
            << ", seed " << testing::TestSeed() << "\n";
  // The general path falls into local optima of the contact space on convex
  // pairs too (measured: 82% exact, worst +12.7%, seed 20261121); this guards
  // against it getting worse, the convex shortcut above is what is exact.
  EXPECT_GE(general_exact, general_total * 6 / 10);
}

}  // namespace
}  // namespace hapticpd::pd
