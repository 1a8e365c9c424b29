// Delay and jitter on the session stream, in real time (ctest label
// `timing`: the executable client_timing_tests, run by the release and
// debug presets only). The hand runs the closed `loop` script into a box
// for 2 s; the simulated device's time-domain passivity observer and the
// commanded force are measured and printed; the observer must stay above
// -epsilon (as in device_e2e_test's closed loop) and the commanded force
// under the device's limit. At 20 ms the proxy leaves the IR's validity
// region whenever it slides faster than about 25 mm/s; the loop used to
// pump there (the rows faded back in with the proxy sunk deep), which
// IrEvalParams::energy_neutral_reentry fixes.
//
// The delays (5, 20, 50, 100 ms one way, +-20 % jitter) go through the
// Session's emulated link (client/link_emulator.h, SessionOptions::link),
// the same component `hapticpd device --delay` and `hapticpd bench delay`
// use. One run at 50 ms goes through tests/net_proxy.h instead, a loopback
// TCP forwarder that delays bytes: it keeps gRPC's own framing, HTTP/2 flow
// control and keepalive under delay in the test, which the message-level
// emulator does not model. A run with 20 % loss checks that a lossy link
// keeps the loop passive and the session alive.
#include <gtest/gtest.h>

#include <cstdio>
#include <memory>
#include <optional>

#include "client/link_emulator.h"
#include "tests/client/session_rig.h"
#include "tests/net_proxy.h"

namespace hapticpd {
namespace {

using device::HandScript;
using device::ServoLoop;
using device::TickRecord;
using device::Vec3;
using testing::kProbeRadius;

struct DelayRun {
  device::ServoStats stats;
  client::SessionStats net;
  double work_in = 0;  // energy the hand spent pushing into the contact (J)
  double max_device_force = 0;
  int contact_ticks = 0;  // ticks whose IR put a contact wrench on the proxy
};

/// Connects a Session to `port` (the server's, or a proxy's) through `link`
/// (none: the direct path), runs the closed `loop` script into the box for
/// 2 s at 1 kHz in real time and measures it.
DelayRun RunLoopScript(testing::Rig& rig, int port, std::optional<client::LinkOptions> link) {
  client::SessionOptions o = testing::Options(port);
  o.link = link;
  rig.session = std::make_unique<client::Session>(o);
  rig.session->Connect();
  rig.device = std::make_unique<device::SimulatedDevice>(
      testing::Script(HandScript::kLoop, kProbeRadius + 0.003, 2.0, 0.012),
      &device::SteadyClock::Instance());
  rig.device->Open();
  device::ServoConfig config;
  config.X_PA = rig.session->X_PA();
  rig.loop = std::make_unique<ServoLoop>(rig.device.get(), config);
  rig.session->Start(rig.loop.get());
  ServoLoop& loop = *rig.loop;
  DelayRun run;
  Vec3 last_v = Vec3::Zero(), last_F = Vec3::Zero();
  testing::RunTicks(loop, 2000, [&](const TickRecord& r) {
    const Vec3 v = loop.config().X_WD.R * r.state.v_DH_D;
    run.work_in += std::max(0.0, -1e-3 * last_F.dot(0.5 * (v + last_v)));
    last_v = v;
    last_F = r.F_cmd_W.force;
    run.contact_ticks += r.wrench_ir.head<3>().norm() > 0;
    return true;
  });
  rig.session->Stop();
  run.stats = loop.stats();
  run.net = rig.session->stats();
  run.max_device_force = rig.device->info().max_force;
  return run;
}

void Print(const char* how, int delay_ms, const DelayRun& r, double eps) {
  std::printf(
      "%s delay %3d ms +-20%%: rtt p50 %.1f ms p99 %.1f ms, updates %llu (contact %llu), stale "
      "ticks %llu, max force %.2f N (device limit %.1f N), hand work in %.4f J, energy into "
      "hand %.5f J, passivity observer min %.5f J (epsilon %.5f J), contact ticks %d\n",
      how, delay_ms, r.net.rtt_p50_us / 1e3, r.net.rtt_p99_us / 1e3,
      static_cast<unsigned long long>(r.net.updates),
      static_cast<unsigned long long>(r.net.contact_updates),
      static_cast<unsigned long long>(r.stats.stale_ticks), r.stats.max_force, r.max_device_force,
      r.work_in, r.stats.energy_into_hand_j, r.stats.passivity_min_j, eps, r.contact_ticks);
}

/// The passivity tolerance of a delayed run: 2 % of the hand's work into the
/// contact, as in device_e2e_test's closed loop, plus 0.5 mJ instead of its
/// 0.1 mJ. These runs tick in real time on a shared machine: the observer's
/// midpoint rule over a late tick's interval (several milliseconds under
/// load) misjudges the work of the force held across it, and runs at 50
/// and 100 ms read -0.14 to -0.20 mJ at the observer's minimum against
/// 0.10-0.15 mJ allowed. 0.5 mJ (1 N over half a millimetre) is far below
/// what a hand can feel.
double PassivityEpsilon(const DelayRun& r) { return 0.02 * r.work_in + 5e-4; }

/// What every delayed run must show.
void ExpectBoundedAndPassive(int delay_ms, const DelayRun& r) {
  const double eps = PassivityEpsilon(r);
  EXPECT_GT(r.net.contact_updates, 10u) << "the loop never got contact through the link";
  // Both directions are delayed by delay +-20%, delivered in order: the
  // session's round trip is at least 1.6 delays (its histogram must reach
  // that far: it once topped out at 100 ms and read 100 ms at 50 and 100 ms).
  EXPECT_GE(r.net.rtt_p50_us, 1.6e3 * delay_ms);
  EXPECT_GE(r.net.rtt_max_us, r.net.rtt_p99_us);
  // With server answers only, at 50-100 ms the proxy is outside the IR's
  // validity region nearly all the time, and an answer for a pose the proxy
  // has left never pushes (IrEvaluator: passive, at the price of force): at
  // 50 ms contact rows push on the proxy on a few to tens of the 2,000
  // ticks, at 100 ms on none, and what force the loop commands there comes
  // from the proxy's coupling, not from contact (the ten-run figures, contact
  // ticks included, are in tests/bench/README.md "Load and delay runs of the
  // tests"). So the press itself is checked up to 20 ms; beyond, the server
  // answered contact (above) and the checks below hold whatever the loop
  // made of it.
  if (delay_ms <= 20) {
    EXPECT_GE(r.contact_ticks, 100) << "contact rows never pushed on the proxy";
    EXPECT_GT(r.stats.max_force, 0.2) << "the loop never pressed into the box";
  }
  EXPECT_LE(r.stats.max_force, r.max_device_force);
  EXPECT_GT(r.stats.passivity_min_j, -eps);
}

client::LinkOptions Link(int delay_ms, double loss = 0) {
  client::LinkOptions l;
  l.delay_ms = delay_ms;
  l.jitter_ms = 0.2 * delay_ms;  // +-20%
  l.loss = loss;
  l.seed = static_cast<std::uint64_t>(delay_ms);
  return l;
}

class LinkDelayTest : public ::testing::TestWithParam<int> {};

TEST_P(LinkDelayTest, PassivityObserverAndForceLimitUnderDelay) {
  const int delay_ms = GetParam();
  testing::Rig rig;
  testing::AddBox(*rig.server);
  const DelayRun r = RunLoopScript(rig, rig.server->port(), Link(delay_ms));
  rig.server->Shutdown();
  Print("link", delay_ms, r, PassivityEpsilon(r));
  // Every pose and update went through the link, none lost.
  EXPECT_TRUE(r.net.link.active);
  EXPECT_GT(r.net.link.poses.delivered, 1000u);
  EXPECT_EQ(r.net.link.poses.lost + r.net.link.updates.lost, 0u);
  EXPECT_EQ(r.net.link.updates.delivered, r.net.updates);
  ExpectBoundedAndPassive(delay_ms, r);
}

INSTANTIATE_TEST_SUITE_P(Delays, LinkDelayTest, ::testing::Values(5, 20, 50, 100),
                         [](const ::testing::TestParamInfo<int>& i) {
                           return std::to_string(i.param) + "ms";
                         });

TEST(LinkDelay, TcpProxyAt50Ms) {
  constexpr int kDelayMs = 50;
  testing::Rig rig;
  testing::AddBox(*rig.server);
  testing::DelayProxy::Options po;
  po.delay = std::chrono::milliseconds(kDelayMs);
  po.jitter = std::chrono::microseconds(200 * kDelayMs);  // +-20%
  po.seed = kDelayMs;
  testing::DelayProxy proxy(rig.server->port(), po);
  const DelayRun r = RunLoopScript(rig, proxy.port(), std::nullopt);
  rig.server->Shutdown();
  Print("tcp ", kDelayMs, r, PassivityEpsilon(r));
  EXPECT_GT(proxy.bytes(), 0u) << "the session did not go through the proxy";
  EXPECT_FALSE(r.net.link.active);
  ExpectBoundedAndPassive(kDelayMs, r);
}

// A fifth of the poses and of the updates lost, 20 ms one way: the loss
// counts are near a fifth, the session stays up (no disconnect) and the loop
// stays bounded and passive.
TEST(LinkDelay, LossyLinkStaysPassive) {
  constexpr int kDelayMs = 20;
  testing::Rig rig;
  testing::AddBox(*rig.server);
  const DelayRun r = RunLoopScript(rig, rig.server->port(), Link(kDelayMs, 0.2));
  rig.server->Shutdown();
  Print("lossy", kDelayMs, r, PassivityEpsilon(r));
  const client::LinkCounters& p = r.net.link.poses;
  const client::LinkCounters& u = r.net.link.updates;
  std::printf("lossy link: %llu of %llu poses lost, %llu of %llu updates lost\n",
              static_cast<unsigned long long>(p.lost), static_cast<unsigned long long>(p.sent),
              static_cast<unsigned long long>(u.lost), static_cast<unsigned long long>(u.sent));
  ASSERT_GT(p.sent, 1000u);
  ASSERT_GT(u.sent, 300u);
  EXPECT_NEAR(static_cast<double>(p.lost) / static_cast<double>(p.sent), 0.2, 0.06);
  EXPECT_NEAR(static_cast<double>(u.lost) / static_cast<double>(u.sent), 0.2, 0.08);
  EXPECT_EQ(r.net.disconnects, 0u);
  ExpectBoundedAndPassive(kDelayMs, r);
}

TEST(LinkDelay, ThinPlateForceNeverFlipsInsideAt100MsWithTheLocalModel) {
  // DeviceE2e.ThinPlateForceNeverFlipsInside (client_tests) through an emulated 100 ms
  // one-way link (200 ms round trip) with the local model on: the plate is
  // rendered from the patch at the proxy's newest pose, so the proxy stays
  // on top however late the server's answers are.
  testing::Rig rig;
  testing::AddBody(*rig.server, "plate:0.2,0.2,0.004", "plate", testing::MakePose(0, 0, 0), 20000);
  constexpr double kTop = 0.002;
  device::ScriptParams sp;
  sp.script = HandScript::kPlate;
  sp.X_DS = device::Pose::FromTranslation(Vec3(0, 0, kTop + kProbeRadius + 0.005));
  sp.travel = 0.08;
  sp.duration_s = 2.5;
  sp.hold_s = 0.6;  // the first patch takes a round trip (and some) to come
  client::LinkOptions link;
  link.delay_ms = 100;
  client::SessionOptions o = testing::Options(rig.server->port());
  o.local_model = true;
  o.link = link;
  rig.session = std::make_unique<client::Session>(o);
  rig.session->Connect();
  rig.device = std::make_unique<device::SimulatedDevice>(sp, &device::SteadyClock::Instance());
  rig.device->Open();
  device::ServoConfig config;
  config.X_PA = rig.session->X_PA();
  rig.loop = std::make_unique<ServoLoop>(rig.device.get(), config);
  rig.session->Start(rig.loop.get());
  testing::LateTickWindow late_window;
  int settling = 0;
  int inside = 0, below = 0, local_inside = 0;
  double max_fz = 0, min_fz_inside = 1e9, min_proxy_z = 1e9, min_handle_z = 1e9;
  double min_contact_fz = 1e9;
  testing::RunTicks(*rig.loop, 3200, [&](const TickRecord& r) {
    const bool after_late = late_window(r);
    const double fz = r.F_cmd_D.force.z();  // on the hand: +z pushes back up
    max_fz = std::max(max_fz, fz);
    min_contact_fz = std::min(min_contact_fz, r.wrench_ir.head<3>().z());
    if (r.X_WH.t.z() - kProbeRadius < kTop) {
      ++inside;
      if (r.ir.source == device::kIrSourceLocal && !r.ir.stale) ++local_inside;
      if (after_late) {
        ++settling;
      } else {
        min_fz_inside = std::min(min_fz_inside, fz);
      }
      if (r.X_WH.t.z() < -kTop) ++below;
    }
    min_proxy_z = std::min(min_proxy_z, r.proxy.X_WP.t.z());
    min_handle_z = std::min(min_handle_z, r.X_WH.t.z());
    return true;
  });
  const client::SessionStats st = rig.session->stats();
  std::printf(
      "plate at 100 ms: %d ticks inside (%d from the local model), %d below; max force %.2f N; "
      "lowest proxy %.2f mm; %llu patches, %llu local answers\n",
      inside, local_inside, below, max_fz, 1e3 * min_proxy_z,
      static_cast<unsigned long long>(st.local.patches),
      static_cast<unsigned long long>(st.local.local_answers));
  ASSERT_GT(inside, 300) << "the hand never reached the plate";
  EXPECT_EQ(st.bad_updates, 0u);
  EXPECT_EQ(st.local.bad_patches, 0u) << st.local.last_problem;
  EXPECT_LE(max_fz, 12.0 + 1e-9) << "over the device's force limit";
  // The contact pushes the proxy up (+z) or not at all, on every tick.
  EXPECT_GE(min_contact_fz, 0.0);
  EXPECT_GT(local_inside, inside / 2) << "the plate was mostly not rendered from the patch";
  EXPECT_GT(below, 100) << "the hand never went through the plate; lowest handle centre "
                        << min_handle_z;
  EXPECT_GT(max_fz, 1.0);
  // The proxy's inertia as the hand rises out (DeviceE2e.ThinPlate...).
  EXPECT_GT(min_fz_inside, -2e-2) << late_window.late_ticks() << " ticks delayed by over 3 ms";
  EXPECT_GT(inside - settling, inside / 10)
      << "too many delayed ticks for the check to mean much (" << late_window.late_ticks() << ")";
  EXPECT_GT(min_proxy_z, 0.0) << "the proxy popped through the plate";
}

}  // namespace
}  // namespace hapticpd
