// `hapticpd-bench accuracy`: what accuracy costs in time. For PDt and PDg on
// each benchmark (client/bench/scenarios.h), one point per setting of what
// trades one for the other — iteration cap, contact tolerance epsilon,
// motion coherence on/off, cold-start directions, mesh resolution — with the
// p50 time over the penetrating frames of the 1 kHz trajectory on one axis
// and the error against ground truth on a sample of those frames on the
// other.
//
// Ground truth:
//   * convex pairs (hulls of the spoon and the cup): the exact PDt by
//     separating axes (pd/convex.h), cross-checked with Bullet's GJK/EPA;
//   * non-convex PDt: the best known upper bound = the smallest of a dense
//     directional-sampling bound (FCL collide, client/bench/ground_truth.h)
//     and every setting's answer verified free by FCL;
//   * PDg: the same with a sampled 6-D bound (rotations about the centre of
//     mass times translation directions) under the object norm.
// Error = (answer - reference) / reference, >= 0 against an upper bound
// (answers below it were verified free, so they are the reference), and
// |answer - reference| / reference against the exact value or, for mesh
// resolution, against the full-resolution reference.
#pragma once

#include <nlohmann/json.hpp>

#include <cstdint>
#include <filesystem>
#include <iosfwd>
#include <string>
#include <vector>

#include "client/bench/scenarios.h"

namespace hapticpd::bench {

struct AccuracyOptions {
  std::string models;  ///< folder of the shared models ("" or missing: stand-ins)
  int frames = 500;    ///< trajectory length per benchmark
  double max_slope = kTrajectoryMaxSlope;  ///< MakeTrajectory's
  int poses = 12;     ///< reference poses per benchmark (expensive ground truth)
  bool tiny = false;  ///< small procedural meshes (tests)
  std::uint64_t seed = 1;
  int pdt_directions = 200;  ///< directional samples per PDt reference
  int pdg_rotations = 16;    ///< rotation samples per PDg reference
  int pdg_directions = 10;   ///< translation directions per rotation
};

struct AccuracyPoint {
  std::string benchmark, mode, sweep, setting;
  bool is_default = false;
  std::string reference;  ///< "exact" or "best-upper-bound" or "full-resolution"
  int poses = 0;
  double p50_us = 0, p99_us = 0, mean_iterations = 0;
  double err_mean = 0, err_median = 0, err_max = 0;  ///< relative (1 = 100 %)
  int failed = 0;      ///< reference poses the setting did not find penetrating
  int unverified = 0;  ///< answers FCL did not confirm free (nudged out by 1e-5)
  std::size_t scene_triangles = 0;
};

struct AccuracyReport {
  std::vector<AccuracyPoint> points;
  std::vector<std::string> notes;
  // Convex cross-check: exact separating-axis PDt vs Bullet's GJK/EPA.
  int convex_poses = 0;
  double bullet_vs_exact_max = 0;  ///< max |Bullet - exact| / exact
  // Non-convex PDt: poses where the default answer beats the pure sampling
  // bound, and the median of default / sampling bound.
  int pdt_reference_poses = 0, default_below_sampling = 0;
  double default_over_sampling_median = 0;
  int pdg_reference_poses = 0, pdg_default_below_sampling = 0;
  double pdg_default_over_sampling_median = 0;
};

/// Runs every sweep; progress lines go to `log` (may be null).
AccuracyReport RunAccuracy(const AccuracyOptions& options, std::ostream* log);

nlohmann::json ToJson(const AccuracyReport& report);
void PrintAccuracy(std::ostream& os, const AccuracyReport& report);
/// Writes DIR/accuracy_pdt.svg and DIR/accuracy_pdg.svg (Pareto plots, one
/// panel per benchmark, one point per setting, defaults ringed); `title`
/// goes into each file (date, command). Returns the paths.
std::vector<std::filesystem::path> WriteAccuracySvgs(const std::filesystem::path& dir,
                                                     const AccuracyReport& report,
                                                     const std::string& title);

}  // namespace hapticpd::bench
