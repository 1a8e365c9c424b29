// The feel through a slow link with the local contact model, in real time
// (ctest label `timing`: client_timing_tests, release preset only). The
// same scripted hands as `hapticpd bench delay` (client/bench/delay.h: a
// press into a box, a slide over the bunny or a torus knot, a twist in a
// slot) run at 0, 50, 100 and 200 ms one way (+-20 % jitter) and are judged
// as ratios to the 0 ms run of the same invocation, never on time:
//   - press and slide at 50 and 100 ms: peak force within 10 %, felt
//     stiffness within 15 %, the proxy's deepest penetration within 0.5 mm;
//   - twist at 50 and 100 ms: peak torque within 15 %;
//   - press and slide at 200 ms: at least 70 % of the peak force;
//   - free space: at most 0.1 N on the free ticks of every run (the goal
//     is 0.05 N; real time on a loaded machine needs the margin);
//   - passive: every run's passivity observer above minus the delay
//     tests' tolerance, and within it of its 0 ms run's (the delay adds no
//     energy).
// With server answers only (the local model off) the proxy of the same
// press at 100 ms sinks 10-11 mm into the box (2.8 mm at 0 ms): the last
// test shows the model is what keeps the surface.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <iostream>

#include "client/bench/delay.h"

namespace hapticpd {
namespace {

std::string ModelsDir() {
  const std::filesystem::path dir = HAPTICPD_MODELS_DIR;
  return std::filesystem::exists(dir / "stanford-bunny.obj") ? dir.string() : std::string();
}

TEST(LocalModelDelay, FeelAtFiftyToTwoHundredMsMatchesZero) {
  bench::DelayBenchOptions o;
  o.delays_ms = {0, 50, 100, 200};
  o.models = ModelsDir();
  const bench::DelayReport report = bench::RunDelayBench(o, nullptr);
  bench::PrintDelay(std::cout, report);
  ASSERT_EQ(report.runs.size(), 12u);
  int judged = 0;
  for (const bench::DelayGoal& g : report.goals) {
    // Free space is judged below with a real-time margin: a tick the
    // machine delays lets the hand run ahead of the proxy (0.04-0.047 N
    // measured on the loaded build machine; 0.006 N in simulated time,
    // tests/device/free_space_test.cc).
    if (g.name.rfind("free space", 0) == 0) continue;
    EXPECT_TRUE(g.met) << g.name << ": " << g.figures;
    ++judged;
  }
  EXPECT_EQ(judged, 18);
  for (const bench::DelayRun& r : report.runs) {
    // At 200 ms a probe that outruns its patch gets late server answers,
    // for poses it has left; they must not push it in free space.
    EXPECT_LE(r.free_drag, 0.1) << r.script << " at " << r.delay_ms << " ms: free-space drag";
    EXPECT_GT(r.contact_ticks, 100) << r.script << " at " << r.delay_ms << " ms never touched";
    if (r.contact_ticks > 0) {
      EXPECT_GT(r.from_patch, 0.9) << r.script << " at " << r.delay_ms
                                   << " ms: the local patch answered too few contact ticks";
    }
  }
}

TEST(LocalModelDelay, WithoutTheLocalModelThePressIsSoftAtOneHundredMs) {
  bench::DelayBenchOptions o;
  o.delays_ms = {0, 100};
  o.scripts = {"press"};
  o.local_model = false;
  const bench::DelayReport report = bench::RunDelayBench(o, nullptr);
  ASSERT_EQ(report.runs.size(), 2u);
  const bench::DelayRun& r0 = report.runs[0];
  const bench::DelayRun& r100 = report.runs[1];
  std::printf(
      "server answers only: peak %.2f N at 0 ms, %.2f N at 100 ms; proxy depth %.2f mm, %.2f mm\n",
      r0.peak_force, r100.peak_force, 1e3 * r0.proxy_max_depth, 1e3 * r100.proxy_max_depth);
  EXPECT_EQ(r100.from_patch, 0.0);
  // The peak force without the model swings from run to run (0.4-3 N: the
  // rows fade and return); the proxy sinking into the box does not (10-11
  // mm measured against 2.8 mm at 0 ms).
  EXPECT_GT(r100.proxy_max_depth, r0.proxy_max_depth + 0.002);
}

}  // namespace
}  // namespace hapticpd
