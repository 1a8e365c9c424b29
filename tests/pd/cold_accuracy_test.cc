// Accuracy of cold PD queries (no motion coherence) on a stored pose set:
// tests/data/cold/procedural.json holds seeded deep poses on the procedural
// pairs of `hapticpd bench cold` with reference bounds computed by FCL
// sampling (Bullet GJK/EPA on the convex pairs), written by
//   hapticpd bench cold --procedural --poses 6 --seed 22
//       --write-reference tests/data/cold/procedural.json
// Each answer is verified with FCL here, and the ratio distribution must
// meet the thresholds the cold start meets today (tests/bench/README.md,
// "Cold queries"); they are to be tightened as the cold start improves.
// Run twice: with the default single cold-start seed (the servo loop's cold
// queries) and with all 13 seeds refined (the one-shot `hapticpd pd`).
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

// What the cold start meets today on the 42 stored poses (measured values
// with the ratios rounded up): lower these as it improves.
constexpr ColdThresholds kColdPdt{1.001, 1.27, 2.68, 6, 3};
constexpr ColdThresholds kColdPdg{1.001, 2.49, 21.7, 12, 5};
constexpr ColdThresholds kColdPdgBudget{1.001, 2.50, 21.7, 15, 6};
// With every cold-start seed refined (PenetrationRequest::cold_start_seeds
// 13). With one seed these fail: PDt max 2.67, 6 above 1.01, 3 above 1.10.
constexpr int kAllSeeds = pd::kColdStartDirections;
constexpr ColdThresholds kSeedsPdt{1.001, 1.01, 1.38, 2, 1};
constexpr ColdThresholds kSeedsPdg{1.001, 1.43, 20.4, 10, 4};
constexpr ColdThresholds kSeedsPdgBudget{1.001, 1.43, 20.4, 14, 5};

class ColdAccuracy : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    std::ifstream in(std::string(HAPTICPD_TESTDATA_DIR) + "/cold/procedural.json");
    ASSERT_TRUE(in) << "tests/data/cold/procedural.json is missing";
    poses_ = new std::vector<ColdPose>(ColdPosesFromJson(nlohmann::json::parse(in)));
    pairs_ = new std::vector<ColdPair>(BuildColdPairs("", true, nullptr));
    answers_ = new std::vector<ColdAnswer>(RunColdQueries(*pairs_, *poses_, false));
    seeded_answers_ =
        new std::vector<ColdAnswer>(RunColdQueries(*pairs_, *poses_, false, kAllSeeds));
  }
  static void TearDownTestSuite() {
    delete seeded_answers_;
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
  static std::vector<ColdAnswer>* seeded_answers_;
};

std::vector<ColdPose>* ColdAccuracy::poses_ = nullptr;
std::vector<ColdPair>* ColdAccuracy::pairs_ = nullptr;
std::vector<ColdAnswer>* ColdAccuracy::answers_ = nullptr;
std::vector<ColdAnswer>* ColdAccuracy::seeded_answers_ = nullptr;

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
TEST_F(ColdAccuracy, PdtAllSeeds) { ExpectKind(ColdKind::kPdt, kSeedsPdt, seeded_answers_); }
TEST_F(ColdAccuracy, PdgWithoutBudgetAllSeeds) {
  ExpectKind(ColdKind::kPdg, kSeedsPdg, seeded_answers_);
}
TEST_F(ColdAccuracy, PdgWithBudgetAllSeeds) {
  ExpectKind(ColdKind::kPdgBudget, kSeedsPdgBudget, seeded_answers_);
}

}  // namespace
}  // namespace hapticpd::bench
