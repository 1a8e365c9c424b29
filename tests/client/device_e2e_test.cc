// The device side end to end over gRPC: a hapticpd server
// in-process on 127.0.0.1, a Session, and a ServoLoop closed through the
// simulated hand, ticked at 1 kHz in real time by the test thread. The thin
// plate never flips the force while the hand is inside it; a closed path in
// a static scene puts at most a small epsilon of energy into the hand; a
// stalled update stream (no answers for 200 ms) fades the force and it comes
// back afterwards. Assertions are on what the loop rendered, counted in
// servo ticks, never on wall-clock performance.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include "client/session.h"
#include "device/servo_loop.h"
#include "device/simulated_device.h"
#include "tests/client/session_rig.h"
#include "tests/test_util.h"

namespace hapticpd {
namespace {

using device::HandScript;
using device::Pose;
using device::TickRecord;
using device::Vec3;
using testing::kProbeRadius;
using testing::Rig;
using testing::RunTicks;

TEST(DeviceE2e, ThinPlateForceNeverFlipsInside) {
  // A 4 mm plate centred on z = 0 (thinner than the sphere probe's 2 cm
  // diameter); the hand starts 5 mm above it and goes 8 cm down: its 300 N/m
  // spring then beats the device's 12 N limit and drags the handle through
  // the plate, then back up.
  Rig rig;
  // Stiff (20 kN/m): the device's 12 N sink the proxy 0.6 mm, far from the
  // mid-plane where penetration depth flips (the soft default would let the
  // proxy's centre reach it: 12 N / 1 kN/m = 12 mm = radius + half plate).
  testing::AddBody(*rig.server, "plate:0.2,0.2,0.004", "plate", testing::MakePose(0, 0, 0), 20000);
  constexpr double kTop = 0.002;
  device::ScriptParams sp;
  sp.script = HandScript::kPlate;
  sp.X_DS = Pose::FromTranslation(Vec3(0, 0, kTop + kProbeRadius + 0.005));
  sp.travel = 0.08;
  sp.duration_s = 2.5;
  rig.Connect(sp);
  // A tick the machine delays by over 3 ms (under TSan on 2 busy cores:
  // one CI run pulled the hand down by 33 mN inside the plate) lets the
  // simulated hand move on in real time while the proxy takes one step: the
  // coupling stretches and its damper tugs for a few tens of ms. The check
  // of the force on the hand skips the ticks of that window
  // (testing::LateTickWindow, as the session test does); the contact force on the proxy and the
  // proxy's side of the plate are checked on every tick.
  testing::LateTickWindow late_window;
  int settling = 0;
  int inside = 0, below = 0;
  double max_fz = 0, min_fz_inside = 1e9, min_proxy_z = 1e9, min_handle_z = 1e9;
  double min_contact_fz = 1e9;
  RunTicks(*rig.loop, 2600, [&](const TickRecord& r) {
    const bool after_late = late_window(r);
    const double fz = r.F_cmd_D.force.z();  // on the hand: +z pushes back up
    max_fz = std::max(max_fz, fz);
    min_contact_fz = std::min(min_contact_fz, r.wrench_ir.head<3>().z());  // on the proxy (W)
    // The handle's sphere reaches into (or through) the plate.
    if (r.X_WH.t.z() - kProbeRadius < kTop) {
      ++inside;
      if (after_late) {
        ++settling;
      } else {
        min_fz_inside = std::min(min_fz_inside, fz);
      }
      if (r.X_WH.t.z() < -kTop) ++below;  // its centre under the plate's bottom face
    }
    min_proxy_z = std::min(min_proxy_z, r.proxy.X_WP.t.z());
    min_handle_z = std::min(min_handle_z, r.X_WH.t.z());
    return true;
  });
  ASSERT_GT(inside, 300) << "the hand never reached the plate";
  EXPECT_EQ(rig.session->stats().bad_updates, 0u);
  EXPECT_LE(max_fz, 12.0 + 1e-9) << "over the device's force limit";
  // Real time under a sanitizer on two busy cores: the server can starve for
  // longer than the IR's stale limit, the proxy is then held on the handle
  // (the link-loss path) and may come back below the plate. Bounds only
  // here; the release preset checks the rest.
  if (testing::kSanitized) return;
  EXPECT_GT(below, 100) << "the hand never went through the plate; lowest handle centre "
                        << min_handle_z << ", max force " << max_fz << ", min inside "
                        << min_fz_inside;
  EXPECT_GT(max_fz, 1.0);
  // Never pulls the hand down (through) while it is inside or under the
  // plate: the proxy stays on the top side, so the push is always up. As the
  // hand rises out of the plate the proxy follows it freely (no drag: free
  // space feels free), so the force there is the 10 g proxy's inertia as the
  // released contact lets it catch up with the accelerating hand (10.7-10.9
  // mN measured, since the contact wrench follows the proxy without the
  // blend's lag), give or take the coupling damper's tug after a delayed
  // tick. 20 mN is under anything a hand feels and under the free-space
  // bound; a proxy pulled through pulls by hundreds of mN.
  EXPECT_GT(min_fz_inside, -2e-2) << late_window.late_ticks() << " ticks delayed by over 3 ms";
  EXPECT_GT(inside - settling, inside / 10)
      << "too many delayed ticks for the check to mean much (" << late_window.late_ticks() << ")";
  // The contact itself pushes the proxy up (+z) or not at all, on every tick.
  EXPECT_GE(min_contact_fz, 0.0);
  EXPECT_GT(min_proxy_z, 0.0) << "the proxy popped through the plate";
}

TEST(DeviceE2e, ClosedLoopInStaticScenePutsAtMostEpsilonIntoTheHand) {
  // The `loop` script: down into the box and back to its start along a
  // closed path (also turning), so a passive rendering returns no more
  // energy than the hand put in.
  Rig rig;
  testing::AddBox(*rig.server);
  device::ScriptParams sp = testing::Script(HandScript::kLoop, kProbeRadius + 0.003, 2.5, 0.012);
  rig.Connect(sp);
  double work_in = 0;  // energy the hand spent pushing into the contact (J)
  device::Vec3 last_v = Vec3::Zero();
  device::Vec3 last_F = Vec3::Zero();
  RunTicks(*rig.loop, 2700, [&](const TickRecord& r) {
    const Vec3 v = rig.loop->config().X_WD.R * r.state.v_DH_D;
    work_in += std::max(0.0, -1e-3 * last_F.dot(0.5 * (v + last_v)));
    last_v = v;
    last_F = r.F_cmd_W.force;
    return true;
  });
  rig.session->Stop();
  const device::ServoStats& st = rig.loop->stats();
  const double e = st.energy_into_hand_j;
  // Epsilon: 2% of the work the hand did against the contact, plus 1e-4 J.
  // A passive rendering returns at most what it was given (e <= 0 up to
  // the work estimate's discretisation); the proxy, the coupling's damper
  // and the unilateral rows dissipate, so a leak of a few per cent of the
  // input is already an active (unstable-trending) loop, while 1e-4 J
  // covers the midpoint-rule error of the per-tick energy sums.
  const double eps = 0.02 * work_in + 1e-4;
  std::printf(
      "loop: max force %.2f N, hand pushed %.4f J into the contact, got %.5f J back "
      "(energy into the hand); epsilon = 2%% of the input + 1e-4 J = %.5f J\n",
      st.max_force, work_in, e, eps);
  EXPECT_GT(st.max_force, 1.0) << "the loop never pressed into the box";
  EXPECT_GT(rig.session->stats().contact_updates, 50u);
  EXPECT_LT(e, eps);
  EXPECT_GT(st.passivity_min_j, -eps);
}

TEST(DeviceE2e, StalledUpdateStreamFadesAndRecovers) {
  // The hand holds the sphere 6 mm into the box: a steady push out. Then no
  // answer reaches the loop for 200 ms (Session::StallUpdatesFor: the
  // server keeps answering, the session withholds them), and then they
  // flow again.
  Rig rig;
  testing::AddBox(*rig.server);
  device::ServoConfig config;
  // Engage at once although the hand starts in contact.
  config.startup.quiet_force = 1e3;
  config.startup.quiet_torque = 1e3;
  rig.Connect(testing::Script(HandScript::kHold, kProbeRadius - 0.006, 100), config);
  double f_before = 0;
  RunTicks(*rig.loop, 1200, [&](const TickRecord& r) {
    f_before = r.F_cmd_D.force.z();
    return true;
  });
  ASSERT_GT(f_before, 0.5) << "no steady contact force before the stall";

  rig.session->StallUpdatesFor(0.2);
  struct Seen {
    bool new_ir;
    double force, contact, link;
    std::int64_t time_ns;
  };
  std::vector<Seen> seen;
  seen.reserve(1500);
  bool back = false;
  RunTicks(*rig.loop, 1500, [&](const TickRecord& r) {
    seen.push_back({r.new_ir, r.F_cmd_D.force.norm(), r.wrench_ir.norm(), r.link_gain, r.time_ns});
    // Contact rendered again at most of its former strength.
    back = seen.size() > 200 && r.wrench_ir(2) > 0.1 && r.F_cmd_D.force.z() > 0.75 * f_before;
    return !back;
  });
  // The stall as the loop saw it: it began at tick 0 (the last answer came
  // before) and ends with the first IR after it. Measured on the loop's
  // clock, not in ticks: RunTicks does not catch up after a tick the
  // machine delayed (TSan on a loaded runner), so 200 ms may hold fewer
  // than 200 ticks.
  auto ms_since_begin = [&](std::size_t i) {
    return 1e-6 * static_cast<double>(seen[i].time_ns - seen[0].time_ns);
  };
  // An answer already on its way to the loop when the stall began (handed
  // to the IR mailbox, not yet taken) may still arrive in its first ticks
  // (seen under ASan): the gap is the one after the first 10 ms.
  std::size_t gap_end = 0;
  while (gap_end < seen.size() && (!seen[gap_end].new_ir || ms_since_begin(gap_end) < 10.0)) {
    ++gap_end;
  }
  ASSERT_LT(gap_end, seen.size()) << "answers never came back";
  ASSERT_GE(ms_since_begin(gap_end), 150.0) << "no stall seen (" << gap_end << " ticks); withheld "
                                            << rig.session->stats().withheld_updates;
  // From 50 ms after the last answer the commanded force is below 1 mN
  // (stale at 20 ms, faded over the next 20 ms; see the server-loss test
  // for the threshold) and stays there until answers come again.
  double max_in_gap = 0;
  std::size_t checked = 0;
  for (std::size_t i = 0; i < gap_end; ++i) {
    if (ms_since_begin(i) < 50.0) continue;
    max_in_gap = std::max(max_in_gap, seen[i].force);
    ++checked;
  }
  EXPECT_GT(checked, 50u) << "too few ticks in the stall to judge it";
  EXPECT_LT(max_in_gap, 1e-3) << "force during the stall (ticks 0-" << gap_end << ", "
                              << ms_since_begin(gap_end) << " ms)";
  EXPECT_EQ(seen[gap_end - 1].link, 0.0);
  // And then it recovers, ramped rather than stepped.
  EXPECT_TRUE(back) << "contact force did not come back after the stall";
  // No step: at most 15% of the force per on-time tick (the 20 ms fade is 5%
  // per tick; the rest is the proxy moving meanwhile). The fade-out runs in
  // real time, so a tick the machine delayed (a loaded CI runner) may fade
  // in proportion to its lateness; such ticks are allowed that much more.
  double worst = 0;  // largest per-tick change over its allowance
  for (std::size_t i = 1; i < seen.size(); ++i) {
    const double dt = 1e-9 * static_cast<double>(seen[i].time_ns - seen[i - 1].time_ns);
    // 1.5 x the 20 ms default fade (5% per ms).
    const double allowed = testing::FadeStepAllowance(dt, 0.15, 0.075) * f_before;
    worst = std::max(worst, std::abs(seen[i].force - seen[i - 1].force) / allowed);
  }
  EXPECT_LT(worst, 1.0) << "a force step beyond 15% of the force per on-time tick";
  const client::SessionStats st = rig.session->stats();
  // The server kept answering through the stall (81 answers in a 100 ms
  // stall in a release run; TSan on a loaded runner: 35 in 200 ms).
  EXPECT_GT(st.withheld_updates, 10u) << "the server stopped answering during the stall";
  EXPECT_EQ(st.connects, 1u) << "a stall is not a disconnect";
  EXPECT_EQ(st.disconnects, 0u);
}

}  // namespace
}  // namespace hapticpd
