// `hapticpd bench delay`: how the feel survives a slow link. The same
// scripted hands run at several one-way delays (each with +-20 % jitter,
// through the Session's emulated link, client/link_emulator.h) against an
// in-process server (loopback TCP), a device Session, a simulated device and
// the real servo loop in real time:
//   press  a vertical stick pressed into a box and back out;
//   slide  the stick down and across the bunny (a torus knot without the
//          shared models) on a vertical circle and back to the start;
//   twist  a horizontal stick between two boxes forming a slot, twisted
//          about the vertical and back.
// Each run's ticks are kept and measured afterwards against the true
// geometry (PDt of the probe at the handle's and at the proxy's pose, in
// process): peak and mean force, felt stiffness, penetrations, surface
// error against the 0 ms run, passivity, free-space drag, which model
// answered. The goals are judged as ratios to the 0 ms run.
#pragma once

#include <nlohmann/json.hpp>

#include <cstdint>
#include <filesystem>
#include <iosfwd>
#include <string>
#include <vector>

namespace hapticpd::bench {

struct DelayBenchOptions {
  std::vector<double> delays_ms = {0, 5, 20, 50, 100, 200};
  double jitter_fraction = 0.2;  ///< jitter = this * delay
  std::vector<std::string> scripts = {"press", "slide", "twist"};
  std::string models;       ///< folder with stanford-bunny.obj ("": the torus knot)
  double time_scale = 1.0;  ///< multiplies every script's duration (tests: small)
  std::uint64_t seed = 1;   ///< of the emulated link's draws
  /// Run the device sessions with the local contact model
  /// (client::SessionOptions::local_model); false: server answers only.
  bool local_model = true;
};

/// One script at one delay.
struct DelayRun {
  std::string script;
  double delay_ms = 0, jitter_ms = 0;
  int ticks = 0, contact_ticks = 0;  ///< contact: the handle's probe inside the true surface
  double peak_force = 0;             ///< N, commanded
  double mean_force = 0;             ///< N, over the contact ticks
  double peak_torque = 0;            ///< N m, commanded
  /// Felt stiffness (N/m): least-squares slope of |F| against the handle's
  /// penetration over the contact ticks; NaN with fewer than 20 of them,
  /// and for the twist (its figure is the torque).
  double stiffness = 0;
  /// Where the surface is felt (m below the true surface): the fit's zero
  /// crossing; error_surface against the 0 ms run of the same script.
  double felt_surface = 0, surface_error = 0;
  double handle_max_depth = 0;  ///< m, the handle's probe below the true surface
  double proxy_max_depth = 0;   ///< m, the proxy's probe below the true surface
  double passivity_min_j = 0, energy_into_hand_j = 0;
  double hand_work_in_j = 0;  ///< the hand's work pushing into the contact (the tolerance's scale)
  /// Max |F| on ticks with no active row, the proxy more than 1 mm from
  /// every body and the handle under 0.3 m/s; free_ticks of them.
  double free_drag = 0;
  int free_ticks = 0;
  double free_drag_t_s = 0;  ///< when the free-space maximum was commanded
  /// Free ticks left out: within 30 ticks of one the machine delayed by
  /// more than 3 ms (the hand moved on in real time; not the renderer's).
  int free_ticks_after_late = 0;
  double patch_bytes_per_s = 0;  ///< geometry patches streamed
  double local_rate_hz = 0;      ///< local model answers per second
  double local_p99_us = 0;       ///< local model PD time p99
  /// Which model answered on the contact ticks (fractions): the server's
  /// rows, the local geometry patch, rows faded (stale or outside their
  /// validity), or no row at all.
  double from_rows = 0, from_patch = 0, faded = 0, no_rows = 0;
  double rtt_p50_ms = 0;
  std::uint64_t updates = 0, late_ticks = 0;
  /// The trace for the plot: time (s), |F| (N), |tau| (N m), every 2 ticks.
  std::vector<float> t, force, torque;
};

struct DelayGoal {
  std::string name;
  bool met = false;
  std::string figures;
};

struct DelayReport {
  std::vector<DelayRun> runs;
  std::vector<DelayGoal> goals;
  std::vector<std::string> notes;  ///< scenes, probe, models used
  std::string slide_body;          ///< "stanford-bunny.obj" or "torusknot"
};

/// Runs every script at every delay; progress lines go to `log` (may be
/// null). Throws std::runtime_error on a setup failure.
DelayReport RunDelayBench(const DelayBenchOptions& options, std::ostream* log);

nlohmann::json ToJson(const DelayReport& report);
void PrintDelay(std::ostream& os, const DelayReport& report);
/// One SVG, one panel per script: force (twist: torque) against time with
/// the delays overlaid. `title` goes into the file (date, command).
void WriteDelaySvg(const std::filesystem::path& path, const DelayReport& report,
                   const std::string& title);

}  // namespace hapticpd::bench
