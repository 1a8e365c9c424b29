// The Table-1 benchmarks on the shared models, as bench_pdt and bench_pdg
// replay them, for the pd tests that follow a stretch of a trajectory.
#pragma once

#include <filesystem>
#include <string>
#include <utility>

#include "client/bench/scenarios.h"

namespace hapticpd::pd {

/// One of the Table-1 benchmarks (bench::BuildBenchmarks's `name`, its
/// shared model in `model`'s folder) with bench_pdt's and bench_pdg's
/// 2,000-frame trajectory (bench::MakeTrajectory's `max_slope`).
inline bench::Benchmark TableOneBenchmark(const std::filesystem::path& model,
                                          const std::string& name,
                                          double max_slope = bench::kTrajectoryMaxSlope) {
  bench::Benchmark b =
      std::move(bench::BuildBenchmarks(model.parent_path().string(), false, name).at(0));
  bench::MakeTrajectory(&b, 2000, max_slope);
  return b;
}

}  // namespace hapticpd::pd
