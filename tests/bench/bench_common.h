// Command line and printing shared by the PD benchmark programs (bench_pdt,
// bench_pdg). The benchmark pairs, their trajectories and the statistics
// helpers live in client/bench/scenarios.h, shared with `hapticpd bench`.
#pragma once

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <string>
#include <vector>

#include "client/bench/scenarios.h"

namespace hapticpd::bench {

/// Command line shared by the PD benchmarks.
struct BenchArgs {
  std::string models;      ///< folder of the shared models
  std::string csv;         ///< summary CSV
  std::string frames_csv;  ///< per-frame CSV (empty: none)
  int num_frames = 2000;
};

/// Parses [--models DIR] [--frames N] [--csv FILE] [--frames-csv FILE]
/// (each also as --flag=VALUE) over the defaults in `*args`; prints the usage
/// of `program` and returns false on anything else.
inline bool ParseBenchArgs(int argc, char** argv, const char* program, BenchArgs* args) {
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&](const char* flag) -> const char* {
      const std::size_t n = std::strlen(flag);
      if (a.compare(0, n, flag) == 0 && a.size() > n && a[n] == '=') return argv[i] + n + 1;
      if (a == flag && i + 1 < argc) return argv[++i];
      return nullptr;
    };
    if (const char* v = value("--models")) {
      args->models = v;
    } else if (const char* v = value("--csv")) {
      args->csv = v;
    } else if (const char* v = value("--frames-csv")) {
      args->frames_csv = v;
    } else if (const char* v = value("--frames")) {
      args->num_frames = std::max(8, std::atoi(v));
    } else {
      std::cerr << "usage: " << program
                << " [--models DIR] [--frames N] [--csv FILE] [--frames-csv FILE]\n";
      return false;
    }
  }
  return true;
}

/// Builds the benchmark's trajectory and prints its heading and notes.
inline void StartBenchmark(Benchmark* b, int num_frames) {
  MakeTrajectory(b, num_frames);
  std::cout << "== " << b->name << ": probe " << b->probe_name << " ("
            << b->probe->mesh().num_triangles() << " triangles) vs " << b->scene_name << " ("
            << b->scene->mesh().num_triangles() << " triangles), " << b->frames.size()
            << " frames at 1 kHz\n";
  for (const auto& note : b->notes) std::cout << "   " << note << "\n";
}

/// Indices of the `k` largest values, largest first.
inline std::vector<std::size_t> Slowest(const std::vector<double>& us, std::size_t k) {
  std::vector<std::size_t> order(us.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  k = std::min(k, order.size());
  std::partial_sort(order.begin(), order.begin() + k, order.end(),
                    [&](std::size_t x, std::size_t y) { return us[x] > us[y]; });
  order.resize(k);
  return order;
}

}  // namespace hapticpd::bench
