// The servo loop's per-tick sample ring (device/spsc_ring.h, ServoLoop::
// samples()): order, overflow counted and never blocking, one producer and
// one consumer on two threads, and in simulated time (ManualClock) every
// tick's commanded force, contact source and fail-safe state, with no
// allocation in the tick.
#include <gtest/gtest.h>

#include <atomic>
#include <map>
#include <thread>
#include <vector>

#include "device/servo_loop.h"
#include "device/spsc_ring.h"
#include "tests/alloc_counter.h"
#include "tests/device/rig.h"

namespace hapticpd::device {
namespace {

using testing::BoxScene;
using testing::CubeProbe;
using testing::kBoxTop;
using testing::Rig;
using testing::StartAbove;

ScriptParams PressScript(double duration = 3) {
  ScriptParams p;
  p.script = HandScript::kPress;
  p.X_DS = StartAbove(kBoxTop, 0.005);
  p.duration_s = duration;
  return p;
}

std::vector<TickSample> Drain(SampleRing& ring) {
  std::vector<TickSample> out;
  TickSample s;
  while (ring.Pop(&s)) out.push_back(s);
  return out;
}

TEST(SpscRing, KeepsOrderAndCountsWhatAFullRingRefuses) {
  SpscRing<int> ring(3);
  EXPECT_EQ(ring.capacity(), 3u);
  int v = 0;
  EXPECT_FALSE(ring.Pop(&v));
  for (int i = 1; i <= 5; ++i) EXPECT_EQ(ring.Push(i), i <= 3) << i;
  EXPECT_EQ(ring.lost(), 2u);
  EXPECT_EQ(ring.size(), 3u);
  // The oldest are kept: a full ring refuses the new value, never overwrites.
  ASSERT_TRUE(ring.Pop(&v));
  EXPECT_EQ(v, 1);
  EXPECT_TRUE(ring.Push(6));  // room again, across the wrap
  for (int want : {2, 3, 6}) {
    ASSERT_TRUE(ring.Pop(&v));
    EXPECT_EQ(v, want);
  }
  EXPECT_FALSE(ring.Pop(&v));
  EXPECT_EQ(ring.lost(), 2u);
  EXPECT_EQ(ring.pushed(), 4u);
}

TEST(SpscRing, OneProducerOneConsumerThreadInOrder) {
  SpscRing<std::uint64_t> ring(64);
  constexpr std::uint64_t kN = 200'000;
  std::atomic<bool> done{false};
  std::thread producer([&] {
    for (std::uint64_t i = 1; i <= kN; ++i) ring.Push(i);
    done = true;
  });
  std::uint64_t last = 0, taken = 0, v = 0;
  bool in_order = true;
  for (;;) {
    const bool finished = done.load();
    while (ring.Pop(&v)) {
      in_order = in_order && v > last;
      last = v;
      ++taken;
    }
    if (finished) break;
  }
  producer.join();
  EXPECT_TRUE(in_order);
  // Every value was either taken or counted lost: nothing vanished.
  EXPECT_EQ(taken + ring.lost(), kN);
}

TEST(ServoSamples, EveryTickInOrderWithItsForceSourceAndFailSafeState) {
  Rig rig(PressScript(), CubeProbe(), BoxScene());
  std::map<FailSafe, int> states;
  std::vector<FailSafe> sequence;  // the states in the order they came, repeats merged
  std::uint64_t faded = 0, server = 0, local = 0;
  std::int64_t last_time = -1;
  int ticks = 0;
  rig.Run(1.5, [&](const TickRecord& r) {
    ++ticks;
    // Drained every tick here, so each sample is this tick's.
    const std::vector<TickSample> s = Drain(rig.loop->samples());
    ASSERT_EQ(s.size(), 1u);
    EXPECT_EQ(s[0].time_ns, r.time_ns);
    EXPECT_GT(s[0].time_ns, last_time);
    last_time = s[0].time_ns;
    EXPECT_FLOAT_EQ(s[0].force, static_cast<float>(r.F_cmd_W.force.norm()));
    EXPECT_FLOAT_EQ(s[0].torque, static_cast<float>(r.F_cmd_W.torque.norm()));
    EXPECT_EQ(s[0].source, r.source);
    EXPECT_EQ(s[0].fail_safe, r.fail_safe);
    if (r.ir.have_ir) {
      EXPECT_NEAR(s[0].ir_age_ms, r.ir.age_s * 1e3, 1e-3);
    } else {
      EXPECT_LT(s[0].ir_age_ms, 0);
    }
    faded += s[0].source == TickSource::kFaded;
    server += s[0].source == TickSource::kServer;
    local += s[0].source == TickSource::kLocal;
    ++states[s[0].fail_safe];
    if (sequence.empty() || sequence.back() != s[0].fail_safe) sequence.push_back(s[0].fail_safe);
  });
  EXPECT_EQ(ticks, 1500);
  EXPECT_EQ(rig.loop->samples().lost(), 0u);
  // The loop's own per-source counters agree with the samples.
  EXPECT_EQ(faded, rig.loop->stats().ticks_faded);
  EXPECT_EQ(server, rig.loop->stats().ticks_server);
  EXPECT_EQ(local, 0u);
  EXPECT_GT(server, 1000u);
  // Start-up: waiting (no IR, then the quiet wait), the ramp, then full output.
  ASSERT_GE(sequence.size(), 3u);
  EXPECT_EQ(sequence[0], FailSafe::kWaiting);
  EXPECT_EQ(sequence[1], FailSafe::kRamping);
  EXPECT_EQ(sequence[2], FailSafe::kOk);
  // The ramp takes ramp_time_s (0.2 s: 200 ticks, give or take one).
  EXPECT_NEAR(states[FailSafe::kRamping], 200, 2);
}

TEST(ServoSamples, ALinkLossFadesThenGoesStaleThenRampsBack) {
  Rig rig(PressScript(), CubeProbe(), BoxScene());
  rig.Run(1.0);  // into contact, full output
  Drain(rig.loop->samples());
  // The IR stream stalls for 100 ms (stale after 20 ms, faded out 20 ms
  // later), then resumes.
  std::vector<FailSafe> sequence;
  rig.Run(
      0.5,
      [&](const TickRecord&) {
        for (const TickSample& s : Drain(rig.loop->samples())) {
          if (sequence.empty() || sequence.back() != s.fail_safe) sequence.push_back(s.fail_safe);
        }
      },
      [](double t) { return t > 1.1 && t <= 1.2; });
  const std::vector<FailSafe> want = {FailSafe::kOk, FailSafe::kFading, FailSafe::kStale,
                                      FailSafe::kRamping, FailSafe::kOk};
  EXPECT_EQ(sequence, want);
}

TEST(ServoSamples, AFullRingCountsLostTicksAndKeepsTheOldest) {
  ServoConfig config;
  config.sample_ring_capacity = 16;
  Rig rig(PressScript(), CubeProbe(), BoxScene(), config);
  std::vector<std::int64_t> times;
  rig.Run(0.1, [&](const TickRecord& r) { times.push_back(r.time_ns); });
  ASSERT_EQ(times.size(), 100u);
  EXPECT_EQ(rig.loop->samples().lost(), 84u);
  const std::vector<TickSample> s = Drain(rig.loop->samples());
  ASSERT_EQ(s.size(), 16u);
  for (std::size_t i = 0; i < s.size(); ++i) EXPECT_EQ(s[i].time_ns, times[i]);
  // Drained, it takes ticks again.
  rig.Run(0.005);
  EXPECT_EQ(Drain(rig.loop->samples()).size(), 5u);
  EXPECT_EQ(rig.loop->samples().lost(), 84u);
}

TEST(ServoSamples, TickDoesNotAllocateWhileTheRingFillsAndOverflows) {
  if (!hapticpd::testing::CountAllocations::Available()) GTEST_SKIP() << "sanitizer build";
  ServoConfig config;
  config.sample_ring_capacity = 256;
  Rig rig(PressScript(), CubeProbe(), BoxScene(), config);
  rig.Run(0.9);
  Drain(rig.loop->samples());
  const std::uint64_t lost_before = rig.loop->samples().lost();
  std::size_t allocations = 0;
  for (int i = 0; i < 500; ++i) {  // fills the ring, then overflows it
    rig.clock.Set((++rig.tick) * 1'000'000);
    {
      hapticpd::testing::CountAllocations count;
      rig.loop->Tick(rig.clock.NowNs());
      allocations += count.count();
    }
    rig.source->Pump(rig.loop.get(), rig.clock.NowNs());
  }
  EXPECT_EQ(rig.loop->samples().lost() - lost_before, 244u);
  EXPECT_EQ(allocations, 0u);
}

}  // namespace
}  // namespace hapticpd::device
