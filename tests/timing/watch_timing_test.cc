// A Watch observer with include_telemetry that stops reading: once its
// transport is full its telemetry batches queue, and past about 2 s it
// loses whole oldest batches (counted in batches_dropped), while a device
// session at 1 kHz keeps every pose answered and another observer loses
// nothing. About real time (seconds of stalling), so label `timing`:
// release preset only.
#include <chrono>
#include <string>
#include <thread>

#include "tests/server/server_harness.h"
#include "tests/server/watcher.h"
#include "tests/test_util.h"

namespace hapticpd::testing {
namespace {

TEST(WatchTiming, AStalledTelemetryObserverLosesWholeBatchesAndSlowsNoSession) {
  ServerHarness h(Transport::kTcp);
  auto scenes = h.Scenes();
  // Many bodies make pose frames big, so the stalled reader's transport
  // buffers fill quickly.
  for (int i = 0; i < 60; ++i) {
    ASSERT_TRUE(AddShape(*scenes, "default", "box:0.01,0.01,0.01", "b" + std::to_string(i),
                         MakePose(1 + 0.03 * i, 0, 0))
                    .ok());
  }
  ASSERT_TRUE(AddShape(*scenes, "default", "box:0.1,0.1,0.05", "floor", MakePose(0, 0, 0)).ok());
  // The stalled observer: reads the snapshot, then nothing until the end.
  auto ctx = Ctx();
  v1::WatchRequest req;
  req.set_scene_id("default");
  req.set_rate_hz(1000);
  req.set_include_contacts(true);
  req.set_include_telemetry(true);
  auto stalled = scenes->Watch(ctx.get(), req);
  v1::SceneEvent ev;
  ASSERT_TRUE(stalled->Read(&ev));
  ASSERT_TRUE(ev.has_snapshot());
  Watcher fast(*scenes, true, true);

  // A device session for 8 s at about 1 kHz, in lock step (each pose
  // answered before the next is sent), with 50 samples of telemetry every
  // 50 poses.
  auto haptics = h.Haptics();
  Session s(*haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello()).ok());
  constexpr std::uint64_t kPoses = 8000;
  auto next = std::chrono::steady_clock::now();
  std::uint64_t telemetry_seq = 0;
  for (std::uint64_t k = 1; k <= kPoses; ++k) {
    ASSERT_TRUE(s.Send(k, MakePose(0, 0, 0.055)));
    const auto u = s.Next();
    ASSERT_TRUE(u);
    ASSERT_EQ(u->sequence(), k);  // every pose answered: nothing superseded
    if (k % 50 == 0) {
      v1::CoupleRequest t;
      t.mutable_telemetry()->set_sequence(++telemetry_seq);
      v1::WrenchSamples* c = t.mutable_telemetry()->mutable_commanded();
      c->set_start_time_ns(static_cast<std::int64_t>(k) * 1'000'000);
      for (int i = 0; i < 50; ++i) {
        c->add_offset_us(static_cast<std::uint32_t>(1000 * i));
        c->add_force(1);
        c->add_torque(0);
      }
      ASSERT_TRUE(s.Write(t));
    }
    next += std::chrono::milliseconds(1);
    std::this_thread::sleep_until(next);
    if (std::chrono::steady_clock::now() - next > std::chrono::milliseconds(5)) {
      next = std::chrono::steady_clock::now();  // no catch-up bursts
    }
  }
  s.ExpectCleanEnd();
  EXPECT_GE(h.server().counts().updates_sent, kPoses);

  // The stalled observer reads again: it lost whole batches, counted.
  std::uint64_t dropped = 0;
  while (dropped == 0 && stalled->Read(&ev)) {
    if (ev.has_telemetry()) dropped = ev.telemetry().batches_dropped();
  }
  EXPECT_GT(dropped, 0u) << "a stalled observer never lost a telemetry batch";
  ctx->TryCancel();
  stalled->Finish();
  // The reading observer lost none, and got every sample (the session's
  // last batch goes out before it is announced removed).
  const std::string id = s.welcome().session_id();
  ASSERT_TRUE(fast.WaitFor([&](const v1::SceneEvent& e) { return Removed(e, id); }));
  fast.Stop();
  std::uint64_t samples = 0;
  for (const v1::SceneEvent& e : fast.events()) {
    if (!e.has_telemetry()) continue;
    EXPECT_EQ(e.telemetry().batches_dropped(), 0u);
    for (const auto& st : e.telemetry().sessions()) {
      samples += static_cast<std::uint64_t>(st.device().commanded().force_size());
    }
  }
  EXPECT_EQ(samples, 50 * telemetry_seq);
}

}  // namespace
}  // namespace hapticpd::testing
