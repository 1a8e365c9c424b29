// device::Histogram: quantiles of linear and log-scale histograms, and what
// happens beyond the range.

#include <gtest/gtest.h>

#include <cmath>

#include "device/stats.h"

namespace hapticpd::device {
namespace {

TEST(Histogram, LinearQuantilesAreBinUpperEdges) {
  Histogram h(0, 100, 100);
  for (int i = 1; i <= 100; ++i) h.Add(i - 0.5);  // one sample per bin
  EXPECT_DOUBLE_EQ(h.Quantile(0.5), 50);
  EXPECT_DOUBLE_EQ(h.Quantile(0.99), 99);
  EXPECT_DOUBLE_EQ(h.Quantile(1.0), 99.5);  // capped by the maximum
  EXPECT_DOUBLE_EQ(h.mean(), 50);
}

TEST(Histogram, LogScaleKeepsItsRelativeResolutionFromMicrosecondsToSeconds) {
  // Round trips of 150 us on loopback and of 50 ms and 2 s over a slow
  // link: each quantile within one bin (2^(1/32) - 1, 2.2 %) above the
  // true value.
  const double resolution = std::exp2(1.0 / 32) - 1;
  for (const double value : {150.0, 50'000.0, 2'000'000.0}) {
    Histogram h = Histogram::LogScale(1, 1e8, 32);
    for (int i = 0; i < 99; ++i) h.Add(value);
    h.Add(value * 3);  // one slow sample: the maximum
    const double p50 = h.Quantile(0.5);
    EXPECT_GE(p50, value) << value;
    EXPECT_LE(p50, value * (1 + resolution)) << value;
    EXPECT_LE(h.Quantile(0.99), value * (1 + resolution)) << value;
    EXPECT_DOUBLE_EQ(h.Quantile(1.0), value * 3) << value;
  }
}

TEST(Histogram, LogScaleSamplesAtOrBelowTheBottomLandInTheFirstBin) {
  Histogram h = Histogram::LogScale(1, 1000, 8);
  h.Add(0);
  h.Add(-5);
  h.Add(1);
  EXPECT_EQ(h.count(), 3u);
  EXPECT_DOUBLE_EQ(h.Quantile(0.5), 1);  // the first bin's upper edge
}

TEST(Histogram, SamplesBeyondTheRangeReadAsItsTopCappedByTheMaximum) {
  Histogram linear(0, 100, 10);
  linear.Add(500);
  linear.Add(700);
  EXPECT_DOUBLE_EQ(linear.Quantile(0.5), 100);
  EXPECT_DOUBLE_EQ(linear.max(), 700);
  Histogram log = Histogram::LogScale(1, 1000, 8);  // top edge 1024
  log.Add(5000);
  EXPECT_DOUBLE_EQ(log.Quantile(0.5), 1024);
  EXPECT_DOUBLE_EQ(log.max(), 5000);
}

}  // namespace
}  // namespace hapticpd::device
