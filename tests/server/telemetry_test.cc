// Device telemetry up the Couple stream and Watch's new options
// (include_contacts, include_telemetry): a malformed telemetry message ends
// the session naming its field; an observer that asks for nothing new gets
// what it always got; SessionsChanged when sessions start and end; a
// probe's contact rows while it presses into a body; the relayed samples,
// every one, in order; the observer count on every event.
#include <atomic>
#include <cmath>
#include <functional>
#include <limits>
#include <mutex>
#include <thread>
#include <vector>

#include "tests/server/server_harness.h"
#include "tests/server/watcher.h"
#include "tests/test_util.h"

namespace hapticpd::testing {
namespace {

/// A valid telemetry message with `n` samples starting at `t0_ns`, 1 ms
/// apart, force k * 0.01 N for sample k counted from `first`.
v1::CoupleRequest Telemetry(std::uint64_t sequence, int n, std::int64_t t0_ns, int first) {
  v1::CoupleRequest req;
  v1::DeviceTelemetry* t = req.mutable_telemetry();
  t->set_sequence(sequence);
  t->set_servo_rate_hz(1000);
  t->set_update_rate_hz(990);
  t->set_round_trip_ms(0.4);
  t->set_ir_age_ms(0.7);
  t->set_fail_safe(v1::FAIL_SAFE_STATE_OK);
  t->set_source(v1::CONTACT_SOURCE_SERVER);
  t->set_ticks_server(static_cast<std::uint64_t>(n));
  *t->mutable_handle_pose() = MakePose(0, 0, 0.2);
  *t->mutable_proxy_pose() = MakePose(0, 0, 0.2);
  v1::WrenchSamples* c = t->mutable_commanded();
  c->set_start_time_ns(t0_ns);
  for (int k = 0; k < n; ++k) {
    c->add_offset_us(static_cast<std::uint32_t>(1000 * k));
    c->add_force(0.01F * static_cast<float>(first + k));
    c->add_torque(0.001F);
  }
  return req;
}

class TelemetryTest : public ::testing::Test {
 protected:
  ServerHarness h{Transport::kInProcess};
  std::unique_ptr<v1::SceneService::Stub> scenes = h.Scenes();
  std::unique_ptr<v1::HapticService::Stub> haptics = h.Haptics();
};

TEST_F(TelemetryTest, AMalformedMessageEndsTheSessionNamingItsField) {
  const double nan = std::nan("");
  const double inf = std::numeric_limits<double>::infinity();
  struct Case {
    const char* field;
    std::function<void(v1::DeviceTelemetry*)> spoil;
  };
  const std::vector<Case> cases = {
      {"telemetry.sequence", [](v1::DeviceTelemetry* t) { t->set_sequence(0); }},
      {"telemetry.servo_rate_hz", [&](v1::DeviceTelemetry* t) { t->set_servo_rate_hz(nan); }},
      {"telemetry.update_rate_hz", [](v1::DeviceTelemetry* t) { t->set_update_rate_hz(-1); }},
      {"telemetry.local_rate_hz", [&](v1::DeviceTelemetry* t) { t->set_local_rate_hz(inf); }},
      {"telemetry.round_trip_ms", [&](v1::DeviceTelemetry* t) { t->set_round_trip_ms(nan); }},
      {"telemetry.ir_age_ms", [](v1::DeviceTelemetry* t) { t->set_ir_age_ms(-0.5); }},
      {"telemetry.emulated_delay_ms",
       [&](v1::DeviceTelemetry* t) { t->set_emulated_delay_ms(inf); }},
      {"telemetry.emulated_jitter_ms",
       [&](v1::DeviceTelemetry* t) { t->set_emulated_jitter_ms(nan); }},
      {"telemetry.emulated_loss", [](v1::DeviceTelemetry* t) { t->set_emulated_loss(1.5); }},
      {"telemetry.handle_pose",
       [&](v1::DeviceTelemetry* t) { t->mutable_handle_pose()->mutable_position()->set_x(nan); }},
      {"telemetry.proxy_pose",
       [](v1::DeviceTelemetry* t) { t->mutable_proxy_pose()->mutable_orientation()->set_w(3); }},
      {"telemetry.commanded", [](v1::DeviceTelemetry* t) { t->mutable_commanded()->add_force(1); }},
      {"telemetry.commanded",
       [](v1::DeviceTelemetry* t) {
         v1::WrenchSamples* c = t->mutable_commanded();
         for (int k = 0; k < 4097 - 3; ++k) {
           c->add_offset_us(static_cast<std::uint32_t>(5000 + k));
           c->add_force(1);
           c->add_torque(0);
         }
       }},
      {"telemetry.commanded.force[1]",
       [&](v1::DeviceTelemetry* t) {
         t->mutable_commanded()->set_force(1, static_cast<float>(nan));
       }},
      {"telemetry.commanded.torque[0]",
       [](v1::DeviceTelemetry* t) { t->mutable_commanded()->set_torque(0, -1); }},
      {"telemetry.commanded.offset_us[2]",
       [](v1::DeviceTelemetry* t) { t->mutable_commanded()->set_offset_us(2, 0); }},
  };
  ScopedExpectLogs logs;
  for (const Case& c : cases) {
    SCOPED_TRACE(c.field);
    Session s(*haptics);
    ASSERT_TRUE(s.Open(Session::DefaultHello()).ok());
    v1::CoupleRequest req = Telemetry(1, 3, 1'000'000, 0);
    c.spoil(req.mutable_telemetry());
    s.Write(req);
    EXPECT_FALSE(s.Next().has_value());
    const grpc::Status st = s.Finish();
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << st.error_message();
    // FIELD: or FIELD.sub: (a pose's position or orientation).
    const std::string& m = st.error_message();
    const std::size_t n = std::string(c.field).size();
    EXPECT_TRUE(m.rfind(c.field, 0) == 0 && m.size() > n && (m[n] == ':' || m[n] == '.')) << m;
  }
  // A sequence that does not increase.
  {
    Session s(*haptics);
    ASSERT_TRUE(s.Open(Session::DefaultHello()).ok());
    ASSERT_TRUE(s.Write(Telemetry(5, 2, 1'000'000, 0)));
    ASSERT_TRUE(s.Send(1, MakePose(0, 0, 0.5)));
    ASSERT_TRUE(s.Next().has_value());  // the valid one kept the session going
    s.Write(Telemetry(5, 2, 3'000'000, 2));
    EXPECT_FALSE(s.Next().has_value());
    const grpc::Status st = s.Finish();
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_EQ(st.error_message().rfind("telemetry.sequence:", 0), 0u) << st.error_message();
  }
  // Telemetry before the hello.
  {
    Session s(*haptics);
    s.Write(Telemetry(1, 2, 1'000'000, 0));
    v1::CoupleResponse resp;
    EXPECT_FALSE(s.Read(&resp));
    const grpc::Status st = s.Finish();
    EXPECT_EQ(st.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
    EXPECT_EQ(st.error_message().rfind("telemetry:", 0), 0u) << st.error_message();
  }
}

TEST_F(TelemetryTest, AnObserverThatAsksForNothingNewGetsWhatItAlwaysGot) {
  ASSERT_TRUE(AddShape(*scenes, "default", "box:0.1,0.1,0.05", "floor", MakePose(0, 0, 0)).ok());
  Watcher old(*scenes, false, false);
  Watcher viewer(*scenes, true, true);  // the new kinds are flowing meanwhile
  Session s(*haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello()).ok());
  std::uint64_t seq = 0;
  for (int i = 0; i < 200; ++i) {
    // Pressing 5 mm into the box: contact rows exist.
    ASSERT_TRUE(s.Send(++seq, MakePose(0, 0, 0.055)));
    ASSERT_TRUE(s.Next());
    if (i % 20 == 0) {
      ASSERT_TRUE(s.Write(Telemetry(seq, 20, static_cast<std::int64_t>(seq) * 1'000'000, i)));
    }
  }
  ASSERT_TRUE(viewer.WaitFor([](const v1::SceneEvent& e) { return e.has_telemetry(); }));
  ASSERT_TRUE(old.WaitFor([](const v1::SceneEvent& e) {
    return e.has_poses() && e.poses().probes_size() > 0 && e.poses().probes(0).depth() > 0;
  }));
  s.ExpectCleanEnd();
  old.Stop();
  const auto events = old.events();
  ASSERT_FALSE(events.empty());
  EXPECT_TRUE(events[0].has_snapshot());
  for (const v1::SceneEvent& e : events) {
    // Only the kinds it always had (snapshot, changes, poses) ...
    EXPECT_TRUE(e.has_snapshot() || e.has_changes() || e.has_poses()) << e.ShortDebugString();
    // ... and probes as they always were: pose, force, depth, sequence.
    for (const v1::ProbeState& p : e.poses().probes()) {
      EXPECT_FALSE(p.has_torque());
      EXPECT_EQ(p.status(), v1::CONTACT_STATUS_UNSPECIFIED);
      EXPECT_EQ(p.rows_size(), 0);
      EXPECT_EQ(p.body_ids_size(), 0);
      EXPECT_FALSE(p.has_target_pose());
      EXPECT_EQ(p.mode(), v1::PD_MODE_UNSPECIFIED);
    }
    // The observer count is on every event (an additive field it ignores).
    EXPECT_GE(e.observers(), 1u);
    EXPECT_LE(e.observers(), 2u);
  }
  EXPECT_EQ(events.back().observers(), 2u);
}

TEST_F(TelemetryTest, SessionsChangedWhenSessionsStartAndEnd) {
  Session first(*haptics);
  ASSERT_TRUE(first.Open(Session::DefaultHello()).ok());
  const std::string id1 = first.welcome().session_id();
  // A new observer: the snapshot, then every session (with its mesh when asked).
  Watcher w(*scenes, true, false, /*meshes=*/true);
  ASSERT_TRUE(w.WaitFor([&](const v1::SceneEvent& e) { return Added(e, id1); }));
  {
    const auto ev = w.events();
    ASSERT_GE(ev.size(), 2u);
    EXPECT_TRUE(ev[0].has_snapshot());
    ASSERT_TRUE(ev[1].has_sessions());
    ASSERT_EQ(ev[1].sessions().added_size(), 1);
    const v1::SessionInfo& info = ev[1].sessions().added(0);
    EXPECT_EQ(info.session_id(), id1);
    EXPECT_EQ(info.client_name(), "test");
    EXPECT_EQ(info.mode(), v1::PD_MODE_PDT);
    EXPECT_EQ(info.probe_mesh_info().triangles(), 320u);  // sphere:0.01,2
    EXPECT_EQ(info.probe_mesh().triangles_size(), 3 * 320);
    EXPECT_TRUE(info.probe_body_id().empty());
  }
  // Without meshes, and with no session yet: an empty list after the snapshot.
  Watcher plain(*scenes, true, false);
  {
    Session second(*haptics);
    ASSERT_TRUE(second.Open(Session::DefaultHello()).ok());
    const std::string id2 = second.welcome().session_id();
    ASSERT_TRUE(w.WaitFor([&](const v1::SceneEvent& e) { return Added(e, id2); }));
    ASSERT_TRUE(plain.WaitFor([&](const v1::SceneEvent& e) { return Added(e, id2); }));
    second.ExpectCleanEnd();
    ASSERT_TRUE(w.WaitFor([&](const v1::SceneEvent& e) { return Removed(e, id2); }));
  }
  for (const v1::SceneEvent& e : plain.events()) {
    for (const auto& a : e.sessions().added()) EXPECT_FALSE(a.has_probe_mesh());
  }
  first.ExpectCleanEnd();
  ASSERT_TRUE(w.WaitFor([&](const v1::SceneEvent& e) { return Removed(e, id1); }));
  ASSERT_TRUE(plain.WaitFor([&](const v1::SceneEvent& e) { return Removed(e, id1); }));
  // A probe is drawn only between its session's added and removed.
  for (const Watcher* x : {&w, &plain}) {
    std::set<std::string> known;
    for (const v1::SceneEvent& e : x->events()) {
      for (const auto& a : e.sessions().added()) known.insert(a.session_id());
      for (const auto& r : e.sessions().removed()) known.erase(r);
      for (const auto& p : e.poses().probes()) EXPECT_EQ(known.count(p.session_id()), 1u);
    }
  }
}

TEST_F(TelemetryTest, ContactRowsWhilePressingIntoABox) {
  ASSERT_TRUE(AddShape(*scenes, "default", "box:0.1,0.1,0.05", "floor", MakePose(0, 0, 0)).ok());
  Watcher w(*scenes, true, false);
  Session s(*haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello()).ok());
  const auto pressing = [](const v1::SceneEvent& e) {
    for (const auto& p : e.poses().probes()) {
      if (p.rows_size() > 0) return true;
    }
    return false;
  };
  std::uint64_t seq = 0;
  ASSERT_TRUE(WaitUntil([&] {
    // 5 mm into the box's top face.
    if (!s.Send(++seq, MakePose(0, 0, 0.055)) || !s.Next()) return true;
    for (const auto& e : w.events()) {
      if (pressing(e)) return true;
    }
    return false;
  }));
  s.ExpectCleanEnd();
  for (const v1::SceneEvent& e : w.events()) {
    if (!pressing(e)) continue;
    const v1::ProbeState& p = e.poses().probes(0);
    EXPECT_EQ(p.status(), v1::CONTACT_STATUS_PENETRATING);
    ASSERT_EQ(p.body_ids_size(), 1);
    EXPECT_EQ(p.body_ids(0), "floor");
    EXPECT_NEAR(p.rows(0).depth(), 0.005, 1e-3);
    EXPECT_NEAR(p.rows(0).normal().z(), 1, 1e-6);
    EXPECT_GT(p.force().z(), 0);
    EXPECT_TRUE(p.has_torque());
    EXPECT_TRUE(p.has_target_pose());
    EXPECT_EQ(p.mode(), v1::PD_MODE_PDT);
    return;
  }
}

TEST_F(TelemetryTest, EverySampleIsRelayedInOrderWithTheServersOwn) {
  Watcher w(*scenes, false, true);
  Watcher plain(*scenes, true, false);  // asks for contacts only: no telemetry
  Session s(*haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello()).ok());
  const std::string id = s.welcome().session_id();
  // 30 messages of 37 samples, 37 poses answered between each.
  constexpr int kMessages = 30, kPer = 37;
  std::uint64_t seq = 0;
  for (int m = 0; m < kMessages; ++m) {
    for (int k = 0; k < kPer; ++k) {
      ASSERT_TRUE(s.Send(++seq, MakePose(0, 0, 0.5)));
      ASSERT_TRUE(s.Next());
    }
    v1::CoupleRequest req = Telemetry(static_cast<std::uint64_t>(m + 1), kPer,
                                      std::int64_t{1'000'000'000} + m * kPer * 1'000'000, m * kPer);
    req.mutable_telemetry()->mutable_commanded()->set_samples_lost(static_cast<std::uint64_t>(m));
    ASSERT_TRUE(s.Write(req));
  }
  s.ExpectCleanEnd();
  // The session's last batch goes out before it is announced removed.
  Watcher* waiters[] = {&plain};
  for (Watcher* x : waiters) {
    ASSERT_TRUE(x->WaitFor([&](const v1::SceneEvent& e) { return Removed(e, id); }));
  }
  std::vector<float> forces;
  std::vector<std::int64_t> times;
  std::uint64_t server_samples = 0, last_sequence = 0, lost = 0, dropped = 0;
  double update_rate = 0;
  ASSERT_TRUE(WaitUntil([&] {
    forces.clear();
    times.clear();
    server_samples = 0;
    for (const v1::SceneEvent& e : w.events()) {
      EXPECT_FALSE(e.has_sessions());  // not asked for
      if (!e.has_telemetry()) continue;
      dropped = e.telemetry().batches_dropped();
      for (const v1::SessionTelemetry& st : e.telemetry().sessions()) {
        EXPECT_EQ(st.session_id(), id);
        server_samples += static_cast<std::uint64_t>(st.server().force_size());
        update_rate = std::max(update_rate, st.update_rate_hz());
        if (!st.has_device()) continue;
        const v1::WrenchSamples& c = st.device().commanded();
        EXPECT_EQ(c.offset_us_size(), c.force_size());
        EXPECT_EQ(c.torque_size(), c.force_size());
        for (int k = 0; k < c.force_size(); ++k) {
          forces.push_back(c.force(k));
          times.push_back(c.start_time_ns() + std::int64_t{1000} * c.offset_us(k));
        }
        last_sequence = st.device().sequence();
        lost = c.samples_lost();
      }
    }
    return forces.size() >= static_cast<std::size_t>(kMessages * kPer) && server_samples >= seq;
  }));
  // Every commanded sample, once, in order, at its time.
  ASSERT_EQ(forces.size(), static_cast<std::size_t>(kMessages * kPer));
  for (std::size_t k = 0; k < forces.size(); ++k) {
    ASSERT_FLOAT_EQ(forces[k], 0.01F * static_cast<float>(k)) << k;
    ASSERT_EQ(times[k], 1'000'000'000 + static_cast<std::int64_t>(k) * 1'000'000) << k;
  }
  EXPECT_EQ(last_sequence, static_cast<std::uint64_t>(kMessages));
  EXPECT_EQ(lost, static_cast<std::uint64_t>(kMessages - 1));  // the client's, relayed
  // The server's own penalty force: one sample per answer.
  EXPECT_EQ(server_samples, seq);
  EXPECT_GT(update_rate, 0);
  EXPECT_EQ(dropped, 0u);
  for (const v1::SceneEvent& e : plain.events()) EXPECT_FALSE(e.has_telemetry());
}

}  // namespace
}  // namespace hapticpd::testing
