// Accuracy of cold PD queries (no motion coherence) on a stored pose set:
// tests/data/cold/procedural.json holds seeded deep poses on the procedural
// pairs of `hapticpd-bench cold` with reference bounds computed by FCL
// sampling (Bullet GJK/EPA on the convex pairs), written by
//   hapticpd-bench cold --procedural --poses 6 --seed 22
//       --write-reference tests/data/cold/procedural.json
// Each answer is verified with FCL here, and the ratio distribution must
// meet the thresholds the cold start meets today (tests/bench/README.md,
// "Cold queries"); they are to be tightened as the cold start improves.
// Run twice: with the default cold search (PenetrationRequest's
// cold_start_directions, kColdSearchDirections) and with its 13 fixed
// directions only, the weaker search, which fails the default thresholds.
// Presets: every preset (pd_tests).
#include <gtest/gtest.h>

#include <fstream>
#include <string>

#include "client/bench/cold.h"

namespace hapticpd::bench {
namespace {

struct ColdThresholds {
  double median, p95, max;
  int above_1_01, above_1_10;
};

// What the cold search meets today on the 42 stored poses (measured values
// with the ratios rounded up): lower these as it improves.
constexpr ColdThresholds kColdPdt{1.001, 1.002, 1.03, 2, 0};
constexpr ColdThresholds kColdPdg{1.001, 1.24, 20.9, 11, 4};
constexpr ColdThresholds kColdPdgBudget{1.001, 1.24, 20.9, 15, 5};
// With the 13 fixed escape directions only (no sphere lattice). These fail
// the thresholds above: PDt p95 1.015, max 1.38, 3 above 1.01, 1 above 1.10.
constexpr int kFixedDirections = pd::kColdStartDirections;
constexpr ColdThresholds kFixedPdt{1.001, 1.015, 1.38, 3, 1};
constexpr ColdThresholds kFixedPdg{1.001, 1.24, 20.9, 11, 4};
constexpr ColdThresholds kFixedPdgBudget{1.001, 1.24, 20.9, 15, 5};

class ColdAccuracy : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    std::ifstream in(std::string(HAPTICPD_TESTDATA_DIR) + "/cold/procedural.json");
    ASSERT_TRUE(in) << "tests/data/cold/procedural.json is missing";
    poses_ = new std::vector<ColdPose>(ColdPosesFromJson(nlohmann::json::parse(in)));
    pairs_ = new std::vector<ColdPair>(BuildColdPairs("", true, nullptr));
    answers_ = new std::vector<ColdAnswer>(RunColdQueries(*pairs_, *poses_, false));
    fixed_answers_ =
        new std::vector<ColdAnswer>(RunColdQueries(*pairs_, *poses_, false, kFixedDirections));
  }
  static void TearDownTestSuite() {
    delete fixed_answers_;
    delete answers_;
    delete pairs_;
    delete poses_;
  }

  /// Every answer of `kind` is a verified contact, and the distribution of
  /// answer / reference meets `t`.
  static void ExpectKind(ColdKind kind, const ColdThresholds& t,
                         const std::vector<ColdAnswer>* answers = answers_) {
    ASSERT_NE(answers, nullptr);
    ASSERT_FALSE(answers->empty());
    for (const ColdAnswer& a : *answers) {
      if (a.kind != kind) continue;
      SCOPED_TRACE(a.pair + " " + ToString(kind) + " at depth " + std::to_string(a.depth_fraction));
      ASSERT_TRUE(Penetrating(a.status)) << pd::ToString(a.status);
      EXPECT_TRUE(a.check.free_out) << "not free when pushed out";
      EXPECT_TRUE(a.check.colliding_in) << "not colliding when pulled back";
      EXPECT_FALSE(a.above_pdt) << "sqrt(sigma) above the cold PDt answer";
      if (a.exact_reference) {
        EXPECT_NEAR(a.ratio, 1, 1e-6) << "convex pair: exact PDt expected";
      }
    }
    for (const ColdSummary& s : SummarizeCold(*answers)) {
      if (s.kind != kind) continue;
      EXPECT_EQ(s.count, static_cast<int>(poses_->size()));
      EXPECT_LE(s.ratio_median, t.median);
      EXPECT_LE(s.ratio_p95, t.p95);
      EXPECT_LE(s.ratio_max, t.max);
      EXPECT_LE(s.above_1_01, t.above_1_01);
      EXPECT_LE(s.above_1_10, t.above_1_10);
    }
  }

  static std::vector<ColdPose>* poses_;
  static std::vector<ColdPair>* pairs_;
  static std::vector<ColdAnswer>* answers_;
  static std::vector<ColdAnswer>* fixed_answers_;
};

std::vector<ColdPose>* ColdAccuracy::poses_ = nullptr;
std::vector<ColdPair>* ColdAccuracy::pairs_ = nullptr;
std::vector<ColdAnswer>* ColdAccuracy::answers_ = nullptr;
std::vector<ColdAnswer>* ColdAccuracy::fixed_answers_ = nullptr;

TEST_F(ColdAccuracy, StoredSetCoversEveryProceduralPair) {
  ASSERT_NE(poses_, nullptr);
  for (const ColdPair& p : *pairs_) {
    int n = 0;
    for (const ColdPose& c : *poses_) n += c.pair == p.name;
    EXPECT_GT(n, 0) << p.name;
  }
}

TEST_F(ColdAccuracy, Pdt) { ExpectKind(ColdKind::kPdt, kColdPdt); }
TEST_F(ColdAccuracy, PdgWithoutBudget) { ExpectKind(ColdKind::kPdg, kColdPdg); }
TEST_F(ColdAccuracy, PdgWithBudget) { ExpectKind(ColdKind::kPdgBudget, kColdPdgBudget); }
TEST_F(ColdAccuracy, PdtFixedDirectionsOnly) {
  ExpectKind(ColdKind::kPdt, kFixedPdt, fixed_answers_);
}
TEST_F(ColdAccuracy, PdgWithoutBudgetFixedDirectionsOnly) {
  ExpectKind(ColdKind::kPdg, kFixedPdg, fixed_answers_);
}
TEST_F(ColdAccuracy, PdgWithBudgetFixedDirectionsOnly) {
  ExpectKind(ColdKind::kPdgBudget, kFixedPdgBudget, fixed_answers_);
}

}  // namespace
}  // namespace hapticpd::bench
