// Servo-loop statistics (../shared/docs/HAPTICS.md "How we measure it").
// Histograms are sized at construction; adding a sample never allocates.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace hapticpd::device {

/// A fixed-bin histogram with running mean/std/max; samples beyond the range
/// land in the last bin (and still count for mean/std/max), so a quantile
/// that falls there reads as the range's top (capped by the maximum).
class Histogram {
 public:
  /// `bins` equal bins over [lo, hi].
  Histogram(double lo, double hi, int bins);
  /// Log-scale bins: `per_octave` bins per doubling from lo (> 0) up to at
  /// least hi, one more for samples <= lo; the relative resolution is
  /// 2^(1/per_octave) - 1 over the whole range (for latencies that span
  /// microseconds to seconds).
  static Histogram LogScale(double lo, double hi, int per_octave);
  void Add(double x);
  void Clear();
  std::uint64_t count() const { return count_; }
  double mean() const;
  double stddev() const;
  double max() const { return max_; }
  double min() const { return min_; }
  /// Upper edge of the bin holding quantile q in [0, 1] (0 when empty).
  double Quantile(double q) const;

 private:
  /// Upper edge of bin i.
  double Edge(std::size_t i) const;

  double lo_, width_;
  double per_octave_ = 0;  ///< > 0: log-scale bins
  std::vector<std::uint64_t> bins_;
  std::uint64_t count_ = 0;
  double sum_ = 0, sum_sq_ = 0, max_ = 0, min_ = 0;
};

struct ServoStats {
  ServoStats();
  void Clear();
  std::uint64_t ticks = 0;
  Histogram period_us;              ///< tick-to-tick interval
  Histogram compute_us;             ///< time spent inside Tick
  Histogram ir_age_ms;              ///< age of the IR rendered, per tick with an IR
  std::uint64_t late_ticks = 0;     ///< period exceeded nominal by more than half a period
  std::uint64_t ir_updates = 0;     ///< IRs taken from the mailbox
  std::uint64_t stale_ticks = 0;    ///< ticks rendering a stale IR
  std::uint64_t outside_ticks = 0;  ///< ticks with the proxy outside the IR's validity
  std::uint64_t clamped_ticks = 0;  ///< ticks whose coupling stretch was clamped
  std::uint64_t device_errors = 0;
  std::uint64_t nonfinite_resets =
      0;  ///< ticks whose proxy went non-finite (put back on the handle)
  /// Ticks by the model their contact came from: the server's answer, the
  /// local patch model, or none (no IR, or faded out to zero).
  std::uint64_t ticks_server = 0;
  std::uint64_t ticks_local = 0;
  std::uint64_t ticks_faded = 0;
  double max_force = 0;    ///< N, commanded
  double max_torque = 0;   ///< N m, commanded
  double max_dforce = 0;   ///< N per tick
  double max_dtorque = 0;  ///< N m per tick
  /// Energy the device put into the hand, sum T (F . v + tau . w) (J).
  double energy_into_hand_j = 0;
  /// Time-domain passivity observer (Hannaford & Ryu 2002): energy absorbed
  /// by the virtual environment, -energy_into_hand; a passive loop keeps it
  /// >= 0. Its minimum over the run:
  double passivity_min_j = 0;

  /// One line per metric, human readable.
  std::string Summary() const;
};

}  // namespace hapticpd::device
