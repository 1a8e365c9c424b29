// Accuracy of cold PD queries (no motion coherence) on a stored pose set:
// tests/data/cold/procedural.json holds seeded deep poses on the procedural
// pairs of `hapticpd-bench cold` with reference bounds computed by FCL
// sampling (Bullet GJK/EPA on the convex pairs), written by
//   hapticpd-bench cold --procedural --poses 6 --seed 22
//       --write-reference tests/data/cold/procedural.json
// Each answer is verified with FCL here, and the ratio distribution must
// meet the thresholds the cold start meets today (tests/bench/README.md,
// "Cold queries"); they are to be tightened as the cold start improves.
// Run four ways: with the defaults; with the cold search's 13 fixed
// directions only (the weaker PDt search, which fails the default PDt
// thresholds); without PDg's turn starts (which fails the default PDg
// thresholds: the test checks that it does); and without unbudgeted PDg's
// local search (which fails the unbudgeted PDg thresholds: checked too).
// The local search's answers are checked to repeat. The interior cull is checked
// against the exact start check it replaces, and refining the shallowest
// contacts first against refining every contact as it is found.
// Presets: every preset (pd_tests).
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <map>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>

#include "client/bench/cold.h"
#include "pd/pdg.h"
#include "pd/pdt.h"

namespace hapticpd::bench {
namespace {

struct ColdThresholds {
  double median, p95, max;
  int above_1_01, above_1_10;
};

// What the cold search meets today on the 42 stored poses (measured values
// with the ratios rounded up): lower these as it improves. Unbudgeted PDg's
// p95 differs between builds (the local search's path follows the last bits
// of floating point): 1.0030 in release, 1.0049 under ASan.
constexpr ColdThresholds kColdPdt{1.001, 1.001, 1.03, 1, 0};
constexpr ColdThresholds kColdPdg{1.001, 1.006, 20.3, 2, 1};
constexpr ColdThresholds kColdPdgBudget{1.001, 1.14, 20.4, 11, 3};
// With the 13 fixed escape directions only (no sphere lattice). These fail
// the thresholds above: PDt p95 1.0025, max 1.38, 2 above 1.01, 1 above 1.10.
constexpr int kFixedDirections = pd::kColdStartDirections;
constexpr ColdThresholds kFixedPdt{1.001, 1.003, 1.38, 2, 1};
constexpr ColdThresholds kFixedPdg{1.001, 1.006, 20.8, 2, 2};
constexpr ColdThresholds kFixedPdgBudget{1.001, 1.14, 20.9, 12, 3};

class ColdAccuracy : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    std::ifstream in(std::string(HAPTICPD_TESTDATA_DIR) + "/cold/procedural.json");
    ASSERT_TRUE(in) << "tests/data/cold/procedural.json is missing";
    poses_ = new std::vector<ColdPose>(ColdPosesFromJson(nlohmann::json::parse(in)));
    pairs_ = new std::vector<ColdPair>(BuildColdPairs("", true, nullptr));
  }
  static void TearDownTestSuite() {
    for (auto& [key, answers] : answers_) delete answers;
    answers_.clear();
    delete pairs_;
    delete poses_;
  }

  /// The answers on the stored poses with `directions` escape directions,
  /// `turn_starts` PDg turn starts and `local_search` candidates of
  /// unbudgeted PDg's local search, computed on first use (each test runs in
  /// its own process and needs one or two of the sets).
  static const std::vector<ColdAnswer>* Answers(
      int directions = pd::PenetrationRequest{}.cold_start_directions,
      int turn_starts = pd::PenetrationRequest{}.pdg_cold_turn_starts,
      int local_search = pd::PenetrationRequest{}.pdg_cold_local_search) {
    std::vector<ColdAnswer>*& a = answers_[{directions, turn_starts, local_search}];
    if (a == nullptr) {
      a = new std::vector<ColdAnswer>(
          RunColdQueries(*pairs_, *poses_, false, directions, turn_starts,
                         pd::PenetrationRequest{}.cold_interior_cull, local_search));
    }
    return a;
  }

  /// Every answer of `kind` is a verified contact, and the distribution of
  /// answer / reference meets `t`.
  static void ExpectKind(ColdKind kind, const ColdThresholds& t,
                         const std::vector<ColdAnswer>* answers = Answers()) {
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

  /// The pair a stored pose belongs to.
  static const ColdPair& PairOf(const ColdPose& pose) {
    const auto it = std::find_if(pairs_->begin(), pairs_->end(),
                                 [&](const ColdPair& p) { return p.name == pose.pair; });
    if (it == pairs_->end()) throw std::out_of_range("no pair " + pose.pair);
    return *it;
  }

  static std::vector<ColdPose>* poses_;
  static std::vector<ColdPair>* pairs_;
  static std::map<std::tuple<int, int, int>, std::vector<ColdAnswer>*> answers_;
};

std::vector<ColdPose>* ColdAccuracy::poses_ = nullptr;
std::vector<ColdPair>* ColdAccuracy::pairs_ = nullptr;
std::map<std::tuple<int, int, int>, std::vector<ColdAnswer>*> ColdAccuracy::answers_;

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
  ExpectKind(ColdKind::kPdt, kFixedPdt, Answers(kFixedDirections));
}
TEST_F(ColdAccuracy, PdgWithoutBudgetFixedDirectionsOnly) {
  ExpectKind(ColdKind::kPdg, kFixedPdg, Answers(kFixedDirections));
}
TEST_F(ColdAccuracy, PdgWithBudgetFixedDirectionsOnly) {
  ExpectKind(ColdKind::kPdgBudget, kFixedPdgBudget, Answers(kFixedDirections));
}

// The turn starts are what meet the PDg thresholds: without them every
// answer is still a verified contact, but more are far above the bound.
TEST_F(ColdAccuracy, PdgWithoutTurnStartsMissesTheThresholds) {
  const std::vector<ColdAnswer>* turnless = Answers(pd::kColdSearchDirections, 0);
  for (const auto& [kind, t] :
       {std::pair{ColdKind::kPdg, kColdPdg}, std::pair{ColdKind::kPdgBudget, kColdPdgBudget}}) {
    for (const ColdSummary& s : SummarizeCold(*turnless)) {
      if (s.kind != kind) continue;
      SCOPED_TRACE(ToString(kind));
      EXPECT_EQ(s.failed, 0);
      EXPECT_EQ(s.unverified, 0);
      EXPECT_GT(s.above_1_01, t.above_1_01);
      EXPECT_GT(s.above_1_10, t.above_1_10);
    }
  }
}

// Unbudgeted PDg's local search (PenetrationRequest::pdg_cold_local_search)
// is what meets the unbudgeted PDg thresholds: without it every answer is
// still a verified contact, but more are above the bound.
TEST_F(ColdAccuracy, PdgWithoutLocalSearchMissesTheThresholds) {
  const std::vector<ColdAnswer>* plain =
      Answers(pd::kColdSearchDirections, pd::kPdgColdTurnStarts, 0);
  for (const ColdSummary& s : SummarizeCold(*plain)) {
    if (s.kind != ColdKind::kPdg) continue;
    EXPECT_EQ(s.failed, 0);
    EXPECT_EQ(s.unverified, 0);
    EXPECT_GT(s.above_1_01, kColdPdg.above_1_01);
    EXPECT_GT(s.ratio_p95, kColdPdg.p95);
  }
}

// The answers of `compute` (ComputePdt or ComputePdg, with its query data
// type Data) at `pose` under `a` and `b`, each on fresh query data.
template <typename Data, typename Compute>
std::pair<pd::PenetrationResult, pd::PenetrationResult> AnswersUnder(
    Compute compute, const ColdPair& pair, const ColdPose& pose, const pd::PenetrationRequest& a,
    const pd::PenetrationRequest& b) {
  std::pair<pd::PenetrationResult, pd::PenetrationResult> r;
  Data data_a, data_b;
  compute(*pair.probe, pose.X_WA, *pair.scene, Pose::Identity(), a, &data_a, &r.first);
  compute(*pair.probe, pose.X_WA, *pair.scene, Pose::Identity(), b, &data_b, &r.second);
  return r;
}

// A cold query as one-shot queries run it: no coherence, no work budget.
pd::PenetrationRequest UnbudgetedCold() {
  pd::PenetrationRequest r;
  r.use_coherence = false;
  r.pdg_iteration_budget = 0;
  return r;
}

// The local search's generator has a fixed seed: a cold query asked twice,
// each time on fresh query data, gives the same answer bit for bit.
TEST_F(ColdAccuracy, PdgLocalSearchAnswersAreRepeatable) {
  const pd::PenetrationRequest request = UnbudgetedCold();
  int compared = 0;
  for (std::size_t i = 0; i < poses_->size(); i += 4) {
    const ColdPose& pose = (*poses_)[i];
    const ColdPair& pair = PairOf(pose);
    const auto [first, second] =
        AnswersUnder<pd::PdgQueryData>(pd::ComputePdg, pair, pose, request, request);
    ASSERT_EQ(first.status, second.status) << pose.pair << " pose " << i;
    EXPECT_EQ(first.sigma, second.sigma) << pose.pair << " pose " << i;
    EXPECT_EQ(first.X_WA_result.t, second.X_WA_result.t) << pose.pair << " pose " << i;
    EXPECT_EQ(first.X_WA_result.R, second.X_WA_result.R) << pose.pair << " pose " << i;
    ++compared;
  }
  EXPECT_GE(compared, 10);
}

// The interior cull (PenetrationRequest::cold_interior_cull) drops a start
// only where the exact check would find it colliding: every PDt answer and
// every unbudgeted PDg answer is the same with it off, bit for bit, and
// against the closed scenes PDt runs far fewer sweeps with it.
TEST_F(ColdAccuracy, InteriorCullKeepsEveryAnswerWithFewerSweeps) {
  const pd::PenetrationRequest on = UnbudgetedCold();
  pd::PenetrationRequest off = on;
  off.cold_interior_cull = false;
  long sweeps_on = 0, sweeps_off = 0;
  int closed_scene_poses = 0;
  for (const ColdPose& pose : *poses_) {
    const ColdPair& pair = PairOf(pose);
    SCOPED_TRACE(pair.name + " at depth " + std::to_string(pose.depth_fraction));
    const auto [t_on, t_off] = AnswersUnder<pd::PdQueryData>(pd::ComputePdt, pair, pose, on, off);
    ASSERT_EQ(t_on.status, t_off.status);
    EXPECT_EQ(t_on.translation_W, t_off.translation_W);
    if (pair.scene->closed() && !pair.convex) {
      ++closed_scene_poses;
      sweeps_on += t_on.ccd_queries;
      sweeps_off += t_off.ccd_queries;
    }
    const auto [r_on, r_off] = AnswersUnder<pd::PdgQueryData>(pd::ComputePdg, pair, pose, on, off);
    ASSERT_EQ(r_on.status, r_off.status);
    EXPECT_EQ(r_on.sigma, r_off.sigma);
    EXPECT_EQ(r_on.X_WA_result.t, r_off.X_WA_result.t);
  }
  ASSERT_GT(closed_scene_poses, 0);
  EXPECT_LT(sweeps_on, 0.6 * sweeps_off) << sweeps_on << " against " << sweeps_off;
}

// Sweeping every escape direction for its contact before refining any
// (PenetrationRequest::cold_contacts_first) refines the most promising
// contact first: the cold PDt search runs far fewer refinement iterations,
// and its answers are as good as those of refining every contact as it
// comes (no answer more than 1 % deeper, and as many shallower as deeper).
TEST_F(ColdAccuracy, ContactsFirstRefinesLessWithAnswersAsGood) {
  pd::PenetrationRequest first;
  first.use_coherence = false;
  pd::PenetrationRequest as_found = first;
  as_found.cold_contacts_first = false;
  long iterations_first = 0, iterations_as_found = 0;
  int deeper = 0, shallower = 0;
  for (const ColdPose& pose : *poses_) {
    const ColdPair& pair = PairOf(pose);
    if (pair.convex) continue;  // answered exactly, without the search
    SCOPED_TRACE(pair.name + " at depth " + std::to_string(pose.depth_fraction));
    const auto [a, b] = AnswersUnder<pd::PdQueryData>(pd::ComputePdt, pair, pose, first, as_found);
    ASSERT_TRUE(Penetrating(a.status)) << pd::ToString(a.status);
    ASSERT_TRUE(Penetrating(b.status)) << pd::ToString(b.status);
    iterations_first += a.iterations;
    iterations_as_found += b.iterations;
    EXPECT_LE(a.depth, 1.01 * b.depth);
    deeper += a.depth > b.depth * (1 + 1e-9);
    shallower += a.depth < b.depth * (1 - 1e-9);
  }
  std::printf(
      "refinement iterations %ld (contacts first) against %ld; answers deeper %d, "
      "shallower %d\n",
      iterations_first, iterations_as_found, deeper, shallower);
  EXPECT_LT(iterations_first, 0.8 * iterations_as_found);
  EXPECT_LE(deeper, shallower + 2);
}

}  // namespace
}  // namespace hapticpd::bench
