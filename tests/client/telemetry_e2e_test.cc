// Device telemetry end to end: a simulated hand pressing into a box through
// the servo loop and a Session to an in-process server, an observer with
// include_contacts and include_telemetry. Every servo tick the session
// sent reaches the observer (none lost without the emulated link; with it,
// what the link dropped is counted), with the fail-safe state, the contact
// source, the rates and the poses; the probe's contact rows are drawn
// while it presses, and the session is announced before its telemetry and
// removed after its last.
#include <gtest/gtest.h>

#include <map>

#include "tests/client/session_rig.h"
#include "tests/server/watcher.h"

namespace hapticpd::testing {
namespace {

/// What an observer received about one session.
struct Relayed {
  std::uint64_t samples = 0;  // commanded samples
  std::uint64_t lost = 0;     // the last samples_lost reported
  std::uint64_t ticks_server = 0, ticks_faded = 0;
  std::uint64_t server_samples = 0;  // the server's penalty force, per answer
  std::map<v1::FailSafeState, int> fail_safe;
  double max_servo_rate = 0, max_update_rate = 0, max_force = 0;
  bool poses = false;
  bool contact_rows = false;
  bool announced_first = true;  // no telemetry or probe before SessionsChanged added
  bool removed = false;
  bool telemetry_after_removed = false;
};

Relayed Collect(const std::vector<v1::SceneEvent>& events, const std::string& id) {
  Relayed r;
  bool added = false;
  for (const v1::SceneEvent& e : events) {
    if (Added(e, id)) added = true;
    if (Removed(e, id)) r.removed = true;
    for (const v1::ProbeState& p : e.poses().probes()) {
      if (p.session_id() != id) continue;
      r.announced_first = r.announced_first && added;
      if (p.rows_size() > 0 && p.body_ids_size() > 0 && p.body_ids(0) == "box") {
        r.contact_rows = true;
      }
    }
    for (const v1::SessionTelemetry& st : e.telemetry().sessions()) {
      if (st.session_id() != id) continue;
      r.announced_first = r.announced_first && added;
      r.telemetry_after_removed = r.telemetry_after_removed || r.removed;
      r.server_samples += static_cast<std::uint64_t>(st.server().force_size());
      r.max_update_rate = std::max(r.max_update_rate, st.update_rate_hz());
      if (!st.has_device()) continue;
      const v1::DeviceTelemetry& d = st.device();
      r.samples += static_cast<std::uint64_t>(d.commanded().force_size());
      for (float f : d.commanded().force()) r.max_force = std::max<double>(r.max_force, f);
      r.lost = d.commanded().samples_lost();
      r.ticks_server += d.ticks_server();
      r.ticks_faded += d.ticks_faded();
      ++r.fail_safe[d.fail_safe()];
      r.max_servo_rate = std::max(r.max_servo_rate, d.servo_rate_hz());
      r.poses = r.poses || (d.has_handle_pose() && d.has_proxy_pose());
    }
  }
  return r;
}

/// Runs a press into the box for `ticks` servo ticks under a Session with
/// `options`, watched from before it starts; returns what the observer got
/// and the session's statistics.
void PressAndWatch(const std::function<void(client::SessionOptions*)>& adjust, int ticks,
                   Relayed* relayed, client::SessionStats* stats, std::uint64_t* loop_ticks) {
  Rig rig;
  AddBox(*rig.server);
  auto scenes = v1::SceneService::NewStub(grpc::CreateChannel(
      "127.0.0.1:" + std::to_string(rig.server->port()), grpc::InsecureChannelCredentials()));
  Watcher w(*scenes, /*contacts=*/true, /*telemetry=*/true);
  client::SessionOptions o = Options(rig.server->port());
  if (adjust) adjust(&o);
  rig.session = std::make_unique<client::Session>(o);
  rig.session->Connect();
  // The sphere starts 5 mm above the box and presses 15 mm into it.
  rig.device = std::make_unique<device::SimulatedDevice>(
      Script(device::HandScript::kPress, 0.005 + kProbeRadius, 1e-3 * ticks),
      &device::SteadyClock::Instance());
  rig.device->Open();
  device::ServoConfig config;
  config.X_PA = rig.session->X_PA();
  rig.loop = std::make_unique<device::ServoLoop>(rig.device.get(), config);
  rig.session->Start(rig.loop.get());
  RunTicks(*rig.loop, ticks, nullptr);
  rig.session->Stop();  // the last samples go before the stream ends
  *stats = rig.session->stats();
  *loop_ticks = rig.loop->live().ticks.load();
  const std::string id = stats->session_id;
  ASSERT_TRUE(w.WaitFor([&](const v1::SceneEvent& e) { return Removed(e, id); }));
  *relayed = Collect(w.events(), id);
}

TEST(DeviceTelemetry, EveryTickTheSessionSentReachesTheObserver) {
  Relayed r;
  client::SessionStats st;
  std::uint64_t ticks = 0;
  PressAndWatch(nullptr, 1500, &r, &st, &ticks);
  ASSERT_EQ(ticks, 1500u);
  // Every tick: sent up the stream (or taken before the stream started),
  // none lost, and every one sent reached the observer.
  EXPECT_EQ(st.telemetry_samples_sent + st.telemetry_samples_discarded, ticks);
  EXPECT_EQ(st.telemetry_samples_lost, 0u);
  EXPECT_GT(st.telemetry_sent, 10u);
  EXPECT_EQ(r.samples, st.telemetry_samples_sent);
  EXPECT_EQ(r.lost, 0u);
  EXPECT_EQ(r.ticks_server + r.ticks_faded, r.samples);
  EXPECT_GT(r.ticks_server, 0u);
  // The start-up and then full output; pressing, the hand felt a force.
  EXPECT_GT(r.fail_safe[v1::FAIL_SAFE_STATE_OK], 0);
  EXPECT_GT(r.max_force, 0.5);
  EXPECT_GT(r.max_servo_rate, 0);
  EXPECT_GT(r.max_update_rate, 0);
  EXPECT_GT(r.server_samples, 0u);
  EXPECT_TRUE(r.poses);
  EXPECT_TRUE(r.contact_rows);
  EXPECT_TRUE(r.announced_first);
  EXPECT_FALSE(r.telemetry_after_removed);
}

TEST(DeviceTelemetry, WhatTheEmulatedLinkDropsIsCountedLost) {
  Relayed r;
  client::SessionStats st;
  std::uint64_t ticks = 0;
  PressAndWatch(
      [](client::SessionOptions* o) {
        client::LinkOptions link;
        link.delay_ms = 5;
        link.loss = 0.3;
        link.seed = 7;
        o->link = link;
      },
      1500, &r, &st, &ticks);
  ASSERT_EQ(ticks, 1500u);
  EXPECT_GT(st.link.telemetry.lost, 0u);
  EXPECT_GT(st.telemetry_samples_lost, 0u);
  EXPECT_EQ(st.telemetry_samples_sent + st.telemetry_samples_lost + st.telemetry_samples_discarded,
            ticks);
  EXPECT_EQ(r.samples, st.telemetry_samples_sent);
  EXPECT_EQ(r.lost, st.telemetry_samples_lost);
}

TEST(DeviceTelemetry, TurnedOffSendsNone) {
  Relayed r;
  client::SessionStats st;
  std::uint64_t ticks = 0;
  PressAndWatch([](client::SessionOptions* o) { o->telemetry = false; }, 300, &r, &st, &ticks);
  EXPECT_EQ(st.telemetry_sent, 0u);
  EXPECT_EQ(r.samples, 0u);
  // The observer still gets the server's own side.
  EXPECT_GT(r.server_samples, 0u);
}

}  // namespace
}  // namespace hapticpd::testing
