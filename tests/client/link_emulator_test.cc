// The emulated wide-area link (client/link_emulator.h) on a manual clock:
// delivery after the delay, jitter within its bounds and actually spread,
// order kept, the loss fraction over many messages with a fixed seed, the
// same schedule for the same seed, overflow, Clear, and the flags'
// one-line errors. No wall clock anywhere.
#include "client/link_emulator.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

namespace hapticpd::client {
namespace {

constexpr std::int64_t kMs = 1'000'000;

LinkOptions Link(double delay_ms, double jitter_ms, double loss, std::uint64_t seed = 7) {
  LinkOptions o;
  o.delay_ms = delay_ms;
  o.jitter_ms = jitter_ms;
  o.loss = loss;
  o.seed = seed;
  return o;
}

TEST(LinkEmulator, DeliversAfterTheDelayAndNotBefore) {
  DelayLine<int> line(Link(50, 0, 0), kLinkDown);
  ASSERT_TRUE(line.Send(1, 10 * kMs));
  int got = 0;
  EXPECT_FALSE(line.Receive(60 * kMs - 1, &got));
  EXPECT_EQ(line.NextDueNs(), 60 * kMs);
  EXPECT_TRUE(line.Receive(60 * kMs, &got));
  EXPECT_EQ(got, 1);
  EXPECT_FALSE(line.Receive(1000 * kMs, &got));
  EXPECT_EQ(line.NextDueNs(), std::numeric_limits<std::int64_t>::max());
  const LinkCounters c = line.counters();
  EXPECT_EQ(c.sent, 1u);
  EXPECT_EQ(c.delivered, 1u);
  EXPECT_EQ(c.lost, 0u);
}

TEST(LinkEmulator, ZeroDelayDeliversAtOnce) {
  DelayLine<int> line(Link(0, 0, 0), kLinkUp);
  ASSERT_TRUE(line.Send(5, 3 * kMs));
  int got = 0;
  EXPECT_TRUE(line.Receive(3 * kMs, &got));
  EXPECT_EQ(got, 5);
}

// Messages far enough apart (100 ms) never wait for one another: each
// one's delay is its own draw, within delay +- jitter and spread over that
// range. One message a millisecond, as the servo loop publishes poses:
// order is kept, a message waits for a slower one before it, and none is
// earlier than delay - jitter or later than delay + jitter after its send.
TEST(LinkEmulator, JitterStaysInItsBoundsAndOrderIsKept) {
  constexpr double kDelay = 50, kJitter = 10;
  {
    LinkSchedule schedule(Link(kDelay, kJitter, 0), kLinkUp);
    double lo = 1e9, hi = -1e9;
    for (int i = 0; i < 20000; ++i) {
      const std::int64_t send = i * 100 * kMs;
      const auto due = schedule.Admit(send);
      ASSERT_TRUE(due.has_value());
      const double delay_ms = static_cast<double>(*due - send) / kMs;
      ASSERT_GE(delay_ms, kDelay - kJitter - 1e-9) << i;
      ASSERT_LE(delay_ms, kDelay + kJitter + 1e-9) << i;
      lo = std::min(lo, delay_ms);
      hi = std::max(hi, delay_ms);
    }
    EXPECT_LT(lo, kDelay - 0.99 * kJitter);
    EXPECT_GT(hi, kDelay + 0.99 * kJitter);
  }
  LinkSchedule schedule(Link(kDelay, kJitter, 0), kLinkUp);
  std::int64_t previous = std::numeric_limits<std::int64_t>::min();
  int held = 0;
  for (int i = 0; i < 20000; ++i) {
    const std::int64_t send = i * kMs;
    const auto due = schedule.Admit(send);
    ASSERT_TRUE(due.has_value());
    ASSERT_GE(*due, previous) << "message " << i << " overtook the one before";
    const double delay_ms = static_cast<double>(*due - send) / kMs;
    ASSERT_GE(delay_ms, kDelay - kJitter - 1e-9) << i;
    ASSERT_LE(delay_ms, kDelay + kJitter + 1e-9) << i;
    if (*due == previous) ++held;
    previous = *due;
  }
  // Messages 1 ms apart with +-10 ms jitter: many wait behind a slower one.
  EXPECT_GT(held, 1000);

  // The same through a DelayLine on a manual clock: in order, each at its
  // due time.
  DelayLine<int> line(Link(kDelay, kJitter, 0), kLinkUp);
  for (int i = 0; i < 2000; ++i) ASSERT_TRUE(line.Send(i, i * kMs));
  int expected = 0;
  for (std::int64_t now = 0; now <= 2100 * kMs; now += kMs / 4) {
    int got = -1;
    while (line.Receive(now, &got)) {
      ASSERT_EQ(got, expected) << "out of order at " << now << " ns";
      ASSERT_GE(now, got * kMs + static_cast<std::int64_t>((kDelay - kJitter) * kMs));
      ++expected;
    }
  }
  EXPECT_EQ(expected, 2000);
}

TEST(LinkEmulator, LossFractionOverManyMessagesWithAFixedSeed) {
  for (const double loss : {0.01, 0.1, 0.5, 0.9}) {
    constexpr int kN = 100000;
    LinkOptions o = Link(20, 4, loss, 42);
    o.max_in_flight = kN;  // all of them may be in flight: no overflow
    DelayLine<int> line(o, kLinkDown);
    int kept = 0;
    for (int i = 0; i < kN; ++i) kept += line.Send(i, i * kMs) ? 1 : 0;
    const LinkCounters c = line.counters();
    EXPECT_EQ(c.sent, static_cast<std::uint64_t>(kN));
    EXPECT_EQ(c.lost + static_cast<std::uint64_t>(kept), static_cast<std::uint64_t>(kN));
    // Binomial: 5 standard deviations.
    const double sd = std::sqrt(kN * loss * (1 - loss));
    EXPECT_NEAR(static_cast<double>(c.lost), kN * loss, 5 * sd) << "loss " << loss;
    // What is not lost arrives, in order.
    int last = -1, got = 0, delivered = 0;
    while (line.Receive(std::numeric_limits<std::int64_t>::max(), &got)) {
      ASSERT_GT(got, last);
      last = got;
      ++delivered;
    }
    EXPECT_EQ(delivered, kept);
  }
}

TEST(LinkEmulator, NoLossMeansEveryMessage) {
  DelayLine<int> line(Link(5, 1, 0), kLinkUp);
  for (int i = 0; i < 10000; ++i) ASSERT_TRUE(line.Send(i, i * kMs));
  EXPECT_EQ(line.counters().lost, 0u);
  EXPECT_EQ(line.in_flight(), 10000u);
}

TEST(LinkEmulator, SameSeedSameScheduleAndDirectionsDiffer) {
  auto schedule = [](std::uint64_t seed, std::uint64_t stream) {
    LinkSchedule s(Link(50, 10, 0.2, seed), stream);
    std::vector<std::int64_t> out;
    for (int i = 0; i < 500; ++i) {
      const auto due = s.Admit(i * kMs);
      out.push_back(due ? *due : -1);
    }
    return out;
  };
  EXPECT_EQ(schedule(3, kLinkUp), schedule(3, kLinkUp));
  EXPECT_NE(schedule(3, kLinkUp), schedule(3, kLinkDown));
  EXPECT_NE(schedule(3, kLinkUp), schedule(4, kLinkUp));
}

TEST(LinkEmulator, OverflowDropsAndCounts) {
  LinkOptions o = Link(1000, 0, 0);
  o.max_in_flight = 3;
  DelayLine<int> line(o, kLinkUp);
  for (int i = 0; i < 5; ++i) line.Send(i, i * kMs);
  const LinkCounters c = line.counters();
  EXPECT_EQ(c.overflow, 2u);
  EXPECT_EQ(line.in_flight(), 3u);
}

TEST(LinkEmulator, ClearDiscardsWhatIsInFlightAndRestartsTheSchedule) {
  DelayLine<int> line(Link(100, 0, 0), kLinkDown);
  line.Send(1, 0);
  line.Send(2, kMs);
  line.Clear();
  EXPECT_EQ(line.in_flight(), 0u);
  EXPECT_EQ(line.counters().discarded, 2u);
  // A message on the new stream is not held behind the old ones' times.
  LinkSchedule s(Link(100, 50, 0), kLinkUp);
  ASSERT_TRUE(s.Admit(1000 * kMs).has_value());
  s.Restart();
  const auto due = s.Admit(0);
  ASSERT_TRUE(due.has_value());
  EXPECT_LE(*due, 150 * kMs);
}

TEST(LinkEmulator, WaitForReturnsWhenWokenOrTimedOut) {
  // No real waiting: a zero or negative wait returns at once, and Wake()
  // before a wait makes it return at once.
  DelayLine<int> line(Link(10, 0, 0), kLinkUp);
  line.WaitFor(std::chrono::nanoseconds(0));
  line.WaitFor(std::chrono::nanoseconds(-5));
  line.Wake();
  line.WaitFor(std::chrono::hours(1));
  SUCCEED();
}

TEST(LinkEmulator, OptionsProblemsNameTheFlag) {
  EXPECT_EQ(LinkOptionsProblem(Link(0, 0, 0)), "");
  EXPECT_EQ(LinkOptionsProblem(Link(10000, 10000, 0.999)), "");
  EXPECT_EQ(LinkOptionsProblem(Link(-5, 0, 0)), "--delay: expected 0 to 10000 ms, got -5");
  EXPECT_EQ(LinkOptionsProblem(Link(20000, 0, 0)), "--delay: expected 0 to 10000 ms, got 20000");
  EXPECT_EQ(LinkOptionsProblem(Link(std::nan(""), 0, 0)),
            "--delay: expected 0 to 10000 ms, got nan");
  EXPECT_EQ(LinkOptionsProblem(Link(20, 30, 0)), "--jitter: expected 0 to --delay (20 ms), got 30");
  EXPECT_EQ(LinkOptionsProblem(Link(20, -1, 0)), "--jitter: expected 0 to --delay (20 ms), got -1");
  EXPECT_EQ(LinkOptionsProblem(Link(20, 4, 1)), "--loss: expected a fraction in [0, 1), got 1");
  EXPECT_EQ(LinkOptionsProblem(Link(20, 4, -0.1)),
            "--loss: expected a fraction in [0, 1), got -0.1");
}

}  // namespace
}  // namespace hapticpd::client
