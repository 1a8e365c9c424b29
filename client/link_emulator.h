// A wide-area link emulated in process, at the message level: a one-way
// delay with uniform jitter and independent message loss, in each direction
// of a device session (poses client -> server, ContactUpdates server ->
// client). It lets anyone feel and measure the system over a slow link
// without network tools (netem needs root and a real interface).
//
// Model, per direction: message i sent at s_i is lost with probability
// `loss`; otherwise it is delivered at
//   d_i = max(d_{i-1}, s_i + delay + U(-jitter, +jitter)),
// so messages keep their order (a stream, like TCP without the retransmits:
// a lost message is simply gone, the next pose or update supersedes it).
// The random draws come from a seeded generator of our own (not a standard
// distribution, whose output differs between standard libraries), so a seed
// gives the same schedule everywhere.
//
// The Session (client/session.h, SessionOptions::link) runs the emulation on
// its own threads; the servo loop still only sees its mailboxes.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <limits>
#include <mutex>
#include <optional>
#include <string>
#include <utility>

namespace hapticpd::client {

struct LinkOptions {
  double delay_ms = 0;   ///< one-way delay, each direction, in [0, 10000]
  double jitter_ms = 0;  ///< uniform +-jitter on the delay, in [0, delay_ms]
  double loss = 0;       ///< probability that a message is dropped, in [0, 1)
  std::uint64_t seed = 1;
  /// Messages in flight per direction beyond which new ones are dropped
  /// (counted as overflow), so a long delay cannot grow memory without
  /// bound: 10 s of 1 kHz poses is 10,000.
  std::size_t max_in_flight = 1 << 16;
};

/// "" when the options are valid; otherwise one line naming the CLI flag,
/// e.g. "--jitter: expected 0 to --delay (20 ms), got 30".
std::string LinkOptionsProblem(const LinkOptions& options);

/// What one direction did.
struct LinkCounters {
  std::uint64_t sent = 0;       ///< messages offered
  std::uint64_t lost = 0;       ///< dropped by the loss draw
  std::uint64_t overflow = 0;   ///< dropped because max_in_flight were in flight
  std::uint64_t delivered = 0;  ///< handed out by Receive
  std::uint64_t discarded = 0;  ///< in flight when the line was cleared (stream ended)
};

/// The schedule of one direction: per message, lost or its delivery time.
/// Deterministic for (seed, stream). Not thread-safe.
class LinkSchedule {
 public:
  /// `stream` separates the directions' random sequences.
  LinkSchedule(const LinkOptions& options, std::uint64_t stream);

  /// nullopt: the message is lost; else its delivery time (ns, same clock
  /// as send_ns), never earlier than the previous delivery. A message that
  /// may not be lost (`may_lose` false: a geometry patch, which the stream
  /// delivers reliably) still draws its loss, so the schedule of the others
  /// stays the seed's.
  std::optional<std::int64_t> Admit(std::int64_t send_ns, bool may_lose = true);
  /// Forgets the previous delivery time (a new stream starts empty).
  void Restart() { last_delivery_ns_ = std::numeric_limits<std::int64_t>::min(); }

 private:
  double Uniform();  // [0, 1)

  std::int64_t delay_ns_, jitter_ns_;
  double loss_;
  std::uint64_t state_;  // splitmix64
  std::int64_t last_delivery_ns_ = std::numeric_limits<std::int64_t>::min();
};

/// One direction of the link carrying messages of type T: any thread sends,
/// one thread receives. Thread-safe (a mutex held for a queue operation,
/// never while waiting on the network).
template <class T>
class DelayLine {
 public:
  DelayLine(const LinkOptions& options, std::uint64_t stream)
      : schedule_(options, stream), max_in_flight_(options.max_in_flight) {}

  /// Offers `message` to the link at `now_ns`; false if it was dropped
  /// (loss, unless `may_lose` is false, or overflow).
  bool Send(T message, std::int64_t now_ns, bool may_lose = true) {
    std::lock_guard lock(mu_);
    ++counters_.sent;
    const std::optional<std::int64_t> due = schedule_.Admit(now_ns, may_lose);
    if (!due) {
      ++counters_.lost;
      return false;
    }
    if (queue_.size() >= max_in_flight_) {
      ++counters_.overflow;
      return false;
    }
    queue_.emplace_back(*due, std::move(message));
    if (queue_.size() == 1) {  // a waiting receiver has a new deadline
      ++refills_;
      cv_.notify_all();
    }
    return true;
  }

  /// Takes the oldest message if it is due at `now_ns`.
  bool Receive(std::int64_t now_ns, T* out) {
    std::lock_guard lock(mu_);
    if (queue_.empty() || queue_.front().first > now_ns) return false;
    *out = std::move(queue_.front().second);
    queue_.pop_front();
    ++counters_.delivered;
    return true;
  }

  /// Delivery time of the oldest message in flight (INT64_MAX: none).
  std::int64_t NextDueNs() const {
    std::lock_guard lock(mu_);
    return queue_.empty() ? std::numeric_limits<std::int64_t>::max() : queue_.front().first;
  }

  /// Blocks for at most `max_wait`, or until a message enters an empty line
  /// or Wake() is called. Messages arrive in order of delivery time, so only
  /// a message entering an empty line can be due sooner than the one ahead.
  void WaitFor(std::chrono::nanoseconds max_wait) {
    std::unique_lock lock(mu_);
    if (woken_ || max_wait <= std::chrono::nanoseconds::zero()) {
      woken_ = false;
      return;
    }
    const std::uint64_t refills = refills_;
    cv_.wait_for(lock, max_wait, [&] { return woken_ || refills_ != refills; });
    woken_ = false;
  }
  /// Ends a WaitFor early (e.g. the stream is closing).
  void Wake() {
    std::lock_guard lock(mu_);
    woken_ = true;
    cv_.notify_all();
  }

  /// Drops everything in flight (counted as discarded) and restarts the
  /// schedule: a new stream starts empty.
  void Clear() {
    std::lock_guard lock(mu_);
    counters_.discarded += queue_.size();
    queue_.clear();
    schedule_.Restart();
  }

  std::size_t in_flight() const {
    std::lock_guard lock(mu_);
    return queue_.size();
  }
  LinkCounters counters() const {
    std::lock_guard lock(mu_);
    return counters_;
  }

 private:
  mutable std::mutex mu_;
  std::condition_variable cv_;
  LinkSchedule schedule_;
  std::size_t max_in_flight_;
  std::deque<std::pair<std::int64_t, T>> queue_;
  LinkCounters counters_;
  bool woken_ = false;
  std::uint64_t refills_ = 0;  // messages that entered an empty line
};

/// The stream numbers of the two directions (LinkSchedule's `stream`).
inline constexpr std::uint64_t kLinkUp = 1;    ///< poses, client -> server
inline constexpr std::uint64_t kLinkDown = 2;  ///< ContactUpdates and patches, server -> client
inline constexpr std::uint64_t kLinkTelemetry = 3;  ///< device telemetry, client -> server

/// One line describing the options, e.g. "50 ms +-10 ms one way, 1% loss".
std::string LinkDescription(const LinkOptions& options);

}  // namespace hapticpd::client
