// `hapticpd-bench peers`: on the same poses (every frame of each benchmark's
// trajectory), our PDt against what a user would otherwise reach for:
//   * FCL mesh-mesh collide with all contacts (per-triangle-pair contacts,
//     the usual substitute for a penetration depth),
//   * GJK/EPA on the two convex hulls: Bullet's (btGjkEpaSolver2) and FCL's
//     (libccd, its contact penetration_depth): fast, but the hulls are not
//     the shapes, so their depth is wrong on non-convex pairs,
//   * one boolean collision query, ours and FCL's: the floor any PD method
//     pays.
// Times (p50/p99), ratios to our PDt p50, and each depth's relative error
// against our PDt answer on the frames where we find penetration.
#pragma once

#include <nlohmann/json.hpp>

#include <iosfwd>
#include <string>
#include <vector>

#include "client/bench/scenarios.h"

namespace hapticpd::bench {

struct PeerRow {
  std::string benchmark;
  std::string method;  ///< "hapticpd-pdt", "fcl-all-contacts", "bullet-epa-hull", ...
  bool gives_depth = false;
  int frames = 0;
  int colliding = 0;  ///< frames the method reports colliding / penetrating
  double p50_us = 0, p99_us = 0;
  double ratio_p50 = 0;      ///< p50 / our PDt p50
  double mean_contacts = 0;  ///< FCL all contacts only
  /// |depth - ours| / ours over frames where our PDt penetrates (depth
  /// methods only): median, 90th percentile, max; and the median signed
  /// (depth - ours) / ours.
  double err_median = 0, err_p90 = 0, err_max = 0, signed_median = 0;
  int compared = 0;
};

std::vector<PeerRow> RunPeers(const std::vector<Benchmark>& benchmarks);

nlohmann::json ToJson(const std::vector<PeerRow>& rows);
void PrintPeers(std::ostream& os, const std::vector<PeerRow>& rows);

}  // namespace hapticpd::bench
