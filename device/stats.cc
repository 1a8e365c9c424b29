#include "device/stats.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace hapticpd::device {

Histogram::Histogram(double lo, double hi, int bins)
    : lo_(lo), width_((hi - lo) / bins), bins_(static_cast<std::size_t>(bins), 0) {}

Histogram Histogram::LogScale(double lo, double hi, int per_octave) {
  const int octaves = std::max(1, static_cast<int>(std::ceil(std::log2(hi / lo))));
  Histogram h(lo, hi, 1 + octaves * per_octave);
  h.per_octave_ = per_octave;
  return h;
}

double Histogram::Edge(std::size_t i) const {
  if (per_octave_ > 0) return lo_ * std::exp2(static_cast<double>(i) / per_octave_);
  return lo_ + width_ * static_cast<double>(i + 1);
}

void Histogram::Add(double x) {
  if (count_ == 0) {
    max_ = min_ = x;
  } else {
    max_ = std::max(max_, x);
    min_ = std::min(min_, x);
  }
  ++count_;
  sum_ += x;
  sum_sq_ += x * x;
  // Log scale: bin 0 holds x <= lo, bin k the samples in (lo 2^((k-1)/n), lo 2^(k/n)].
  const double b = per_octave_ > 0 ? (x > lo_ ? std::ceil(std::log2(x / lo_) * per_octave_) : 0.0)
                                   : std::floor((x - lo_) / width_);
  const std::size_t i = b < 0 ? 0 : std::min(bins_.size() - 1, static_cast<std::size_t>(b));
  ++bins_[i];
}

void Histogram::Clear() {
  std::fill(bins_.begin(), bins_.end(), 0);
  count_ = 0;
  sum_ = sum_sq_ = max_ = min_ = 0;
}

double Histogram::mean() const { return count_ ? sum_ / static_cast<double>(count_) : 0; }

double Histogram::stddev() const {
  if (count_ < 2) return 0;
  const double n = static_cast<double>(count_);
  const double m = sum_ / n;
  return std::sqrt(std::max(0.0, sum_sq_ / n - m * m));
}

double Histogram::Quantile(double q) const {
  if (count_ == 0) return 0;
  const auto target = static_cast<std::uint64_t>(std::ceil(q * static_cast<double>(count_)));
  std::uint64_t seen = 0;
  for (std::size_t i = 0; i < bins_.size(); ++i) {
    seen += bins_[i];
    if (seen >= std::max<std::uint64_t>(1, target)) {
      return std::min(max_, Edge(i));
    }
  }
  return max_;
}

ServoStats::ServoStats()
    : period_us(0, 20000, 40000), compute_us(0, 2000, 20000), ir_age_ms(0, 1000, 10000) {}

void ServoStats::Clear() { *this = ServoStats(); }

std::string ServoStats::Summary() const {
  char buf[1024];
  std::snprintf(
      buf, sizeof(buf),
      "ticks %llu, period mean %.1f us std %.1f p50 %.1f p99 %.1f p99.9 %.1f max %.1f, late %llu\n"
      "tick compute p50 %.2f us p99 %.2f us max %.1f us\n"
      "IR updates %llu, age p50 %.2f ms p99 %.2f ms, stale ticks %llu, outside ticks %llu\n"
      "max force %.3f N torque %.4f N m, max dF %.4f N dtau %.5f N m per tick, clamped %llu\n"
      "energy into hand %.6f J, passivity observer min %.6f J, device errors %llu\n"
      "contact from: server %llu ticks, local patch %llu, none or faded %llu",
      static_cast<unsigned long long>(ticks), period_us.mean(), period_us.stddev(),
      period_us.Quantile(0.5), period_us.Quantile(0.99), period_us.Quantile(0.999), period_us.max(),
      static_cast<unsigned long long>(late_ticks), compute_us.Quantile(0.5),
      compute_us.Quantile(0.99), compute_us.max(), static_cast<unsigned long long>(ir_updates),
      ir_age_ms.Quantile(0.5), ir_age_ms.Quantile(0.99),
      static_cast<unsigned long long>(stale_ticks), static_cast<unsigned long long>(outside_ticks),
      max_force, max_torque, max_dforce, max_dtorque,
      static_cast<unsigned long long>(clamped_ticks), energy_into_hand_j, passivity_min_j,
      static_cast<unsigned long long>(device_errors), static_cast<unsigned long long>(ticks_server),
      static_cast<unsigned long long>(ticks_local), static_cast<unsigned long long>(ticks_faded));
  return buf;
}

}  // namespace hapticpd::device
