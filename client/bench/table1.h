// `hapticpd bench table1`: the seed paper's Table 1 on this machine. Per
// benchmark (client/bench/scenarios.h) and mode (PDt, PDg): triangles,
// frames, p50/p99/max time over every frame of the 1 kHz trajectory (motion
// coherence on, default request), mean contacts and iterations over the
// penetrating frames, and the seed's numbers (ALGORITHMS.md) beside them.
#pragma once

#include <nlohmann/json.hpp>

#include <iosfwd>
#include <string>
#include <vector>

#include "client/bench/scenarios.h"

namespace hapticpd::bench {

struct Table1Row {
  std::string benchmark, mode;
  std::string probe, scene;
  std::size_t probe_triangles = 0, scene_triangles = 0;
  bool stand_in = false;
  TimingSummary timing;
  // The seed's Table 1 (dual Xeon, Windows XP).
  std::string seed_triangles;
  double seed_ms = 0, seed_contacts = 0;
};

/// Runs both modes on every benchmark (trajectories must be made).
std::vector<Table1Row> RunTable1(const std::vector<Benchmark>& benchmarks);

nlohmann::json ToJson(const std::vector<Table1Row>& rows);
void PrintTable1(std::ostream& os, const std::vector<Table1Row>& rows);
/// One CSV row per benchmark and mode; throws std::runtime_error naming the
/// file when it cannot be written.
void WriteTable1Csv(const std::string& path, const std::vector<Table1Row>& rows);

}  // namespace hapticpd::bench
