// Lock-free server statistics: counters and a log-scale histogram of PD
// compute times, written by PD workers without allocation or locks and read
// by the status thread.
#pragma once

#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>

namespace hapticpd::server::internal {

/// Histogram of durations in microseconds: 8 buckets per octave from 1 µs to
/// ~1 s (bucket upper bounds grow by 2^(1/8), ~9 %).
class LatencyHistogram {
 public:
  static constexpr int kBuckets = 8 * 20 + 2;
  void Add(double us) {
    int b = 0;
    if (us > 1) b = std::min(kBuckets - 1, 1 + static_cast<int>(std::log2(us) * 8));
    counts_[b].fetch_add(1, std::memory_order_relaxed);
  }
  /// Copies and clears (the counts since the previous call).
  std::array<std::uint64_t, kBuckets> Drain() {
    std::array<std::uint64_t, kBuckets> out{};
    for (int i = 0; i < kBuckets; ++i) out[i] = counts_[i].exchange(0, std::memory_order_relaxed);
    return out;
  }
  /// Upper bound (µs) of the bucket holding quantile q of `h`; 0 when empty.
  static double Quantile(const std::array<std::uint64_t, kBuckets>& h, double q) {
    std::uint64_t total = 0;
    for (auto c : h) total += c;
    if (total == 0) return 0;
    const auto target = static_cast<std::uint64_t>(std::ceil(q * static_cast<double>(total)));
    std::uint64_t acc = 0;
    for (int i = 0; i < kBuckets; ++i) {
      acc += h[i];
      if (acc >= target) return i == 0 ? 1.0 : std::exp2(static_cast<double>(i) / 8.0);
    }
    return std::exp2(static_cast<double>(kBuckets - 1) / 8.0);
  }

 private:
  std::array<std::atomic<std::uint64_t>, kBuckets> counts_{};
};

struct Stats {
  std::atomic<std::uint64_t> updates_sent{0};
  std::atomic<std::uint64_t> updates_replaced{0};  ///< unsent answers replaced by newer ones
  std::atomic<std::uint64_t> patches_sent{0};      ///< geometry patches written
  std::atomic<std::uint64_t> patch_bytes{0};       ///< their serialized size
  std::atomic<std::uint64_t> poses_superseded{0};  ///< poses replaced before PD started
  std::atomic<std::uint64_t> observer_frames_sent{0};
  std::atomic<std::uint64_t> observer_frames_dropped{0};
  std::atomic<std::uint64_t> pd_calls{0};          ///< scene PD queries run
  std::atomic<std::uint64_t> torque_skipped{0};    ///< answers without torque terms
  std::atomic<std::uint64_t> updates_withheld{0};  ///< answers replaced (CONTACT_STATUS_WITHHELD)
  std::atomic<std::uint64_t> sessions_idle_ended{0};  ///< sessions ended by the idle timeout
  std::atomic<std::uint64_t> observers_stalled{0};    ///< observers cancelled for a stuck write
  LatencyHistogram compute_us;
};

}  // namespace hapticpd::server::internal
