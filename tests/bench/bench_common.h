// Command line, main loop, summaries and printing shared by the PD benchmark
// programs (bench_pdt, bench_pdg). The benchmark pairs, their trajectories and the statistics
// helpers live in client/bench/scenarios.h, shared with `hapticpd bench`
// and `hapticpd-bench`.
#pragma once

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <string>
#include <vector>

#include "client/bench/scenarios.h"
#include "pd/penetration.h"
#include "tests/oracles/fcl_oracle.h"

namespace hapticpd::bench {

/// Command line shared by the PD benchmarks.
struct BenchArgs {
  std::string models;      ///< folder of the shared models
  std::string csv;         ///< summary CSV
  std::string frames_csv;  ///< per-frame CSV (empty: none)
  std::string benchmark;   ///< run only this benchmark (empty: all)
  int num_frames = 2000;
  double max_slope = kTrajectoryMaxSlope;  ///< MakeTrajectory's
};

/// Parses [--models DIR] [--frames N] [--csv FILE] [--frames-csv FILE]
/// [--benchmark NAME] [--max-slope S]
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
    } else if (const char* v = value("--benchmark")) {
      args->benchmark = v;
    } else if (const char* v = value("--frames")) {
      args->num_frames = std::max(8, std::atoi(v));
    } else if (const char* v = value("--max-slope")) {
      if (const std::string problem = ParseMaxSlope(v, &args->max_slope); !problem.empty()) {
        std::cerr << program << ": --max-slope: " << problem << "\n";
        return false;
      }
    } else {
      std::cerr << "usage: " << program
                << " [--models DIR] [--frames N] [--csv FILE] [--frames-csv FILE] "
                   "[--benchmark NAME] [--max-slope S (>= 0, inf)]\n";
      return false;
    }
  }
  return true;
}

/// Builds the benchmark's trajectory and prints its heading and notes.
inline void StartBenchmark(Benchmark* b, int num_frames, double max_slope) {
  MakeTrajectory(b, num_frames, max_slope);
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

/// The command line, the benchmarks and the per-frame CSV of a run.
struct BenchRun {
  BenchArgs args;
  std::vector<Benchmark> benchmarks;
  std::ofstream per_frame;  ///< never opened without --frames-csv
};

/// Starts a run of `program`: parses the command line over the defaults
/// `models` and `<program>.csv` (false, with the usage printed, on a bad
/// one), builds the benchmarks, opens the per-frame CSV with its
/// `frames_csv_header` line when asked and sets fixed notation on std::cout.
inline bool StartRun(int argc, char** argv, const char* program, const char* models,
                     const char* frames_csv_header, BenchRun* run) {
  run->args.models = models;
  run->args.csv = std::string(program) + ".csv";
  if (!ParseBenchArgs(argc, argv, program, &run->args)) return false;
  run->benchmarks = BuildBenchmarks(run->args.models, false, run->args.benchmark);
  if (run->benchmarks.empty()) {
    std::cerr << program << ": no benchmark named '" << run->args.benchmark << "'\n";
    return false;
  }
  if (!run->args.frames_csv.empty()) {
    run->per_frame.open(run->args.frames_csv);
    run->per_frame << frames_csv_header;
  }
  std::cout << std::fixed;
  return true;
}

/// Replays every benchmark of `run` in turn: prints its heading (with its
/// trajectory built), `replay(b, &records)` times it and returns its
/// summary, and `report(b, records, summary)` prints what the program shows
/// per benchmark. With a per-frame CSV, each record `r` (with `status` and
/// `depth`) gets a row: benchmark, frame, phase, commanded press, status and
/// depth, then what `write_frame(csv, r)` adds. Returns the summaries.
template <class Summary, class Record, class Replay, class Report, class WriteFrame>
std::vector<Summary> ReplayAll(BenchRun* run, Replay replay, Report report,
                               WriteFrame write_frame) {
  std::vector<Summary> summaries;
  for (Benchmark& b : run->benchmarks) {
    StartBenchmark(&b, run->args.num_frames, run->args.max_slope);
    std::vector<Record> records;
    summaries.push_back(replay(b, &records));
    report(b, records, summaries.back());
    if (!run->per_frame.is_open()) continue;
    for (std::size_t i = 0; i < records.size(); ++i) {
      const Record& r = records[i];
      run->per_frame << std::setprecision(9) << b.name << "," << i << ","
                     << PhaseName(b.frames[i].phase) << "," << b.frames[i].commanded << ","
                     << pd::ToString(r.status) << "," << r.depth;
      write_frame(run->per_frame, r);
    }
  }
  return summaries;
}

/// Times FCL's mesh-mesh collide with all contacts on every frame's pose of
/// `b` (the peer the PD benchmarks compare with, measured in the same run):
/// each record's `us` (µs) and `contacts`. `records` has one entry a frame.
template <class Record>
void TimeFclAllContacts(const Benchmark& b, const Pose& X_WB, std::vector<Record>* records,
                        double Record::*us, int Record::*contacts) {
  const hapticpd::testing::FclModel fcl_probe(b.probe->mesh()), fcl_scene(b.scene->mesh());
  for (std::size_t i = 0; i < b.frames.size(); ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    const int n = hapticpd::testing::FclContacts(fcl_probe, b.frames[i].X_WA, fcl_scene, X_WB);
    const auto t1 = std::chrono::steady_clock::now();
    (*records)[i].*us = Us(t0, t1);
    (*records)[i].*contacts = n;
  }
}

/// Indices of the `k` records with the largest time `us` (µs), slowest first.
template <class Record>
std::vector<std::size_t> SlowestFrames(const std::vector<Record>& records, double Record::*us,
                                       std::size_t k) {
  std::vector<double> times;
  for (const Record& r : records) times.push_back(r.*us);
  return Slowest(times, k);
}

/// Starts the line of slow frame `i` of `b`: its index and phase.
inline std::ostream& PrintSlowFrameStart(const Benchmark& b, std::size_t i) {
  return std::cout << "   slow frame " << i << " (" << PhaseName(b.frames[i].phase) << "): ";
}

/// Time budget of one servo frame (µs, 1 kHz).
inline constexpr double kFrameBudgetUs = 1000;

/// The summary fields every PD benchmark reports for its timed query; each
/// benchmark's Summary adds its own.
struct SummaryBase {
  std::string name;
  std::size_t probe_tris = 0, scene_tris = 0;
  int frames = 0, penetrating = 0, cap_reached = 0, failed = 0, over_budget = 0;
  double p50 = 0, p99 = 0, p999 = 0, max = 0;     ///< time of the query (µs)
  double mean_iterations = 0, mean_contacts = 0;  ///< over the penetrating frames
  bool goal_met = false;
};

/// Starts the summary of `b` replayed over `frames` frames.
inline void BeginSummary(const Benchmark& b, std::size_t frames, SummaryBase* s) {
  s->name = b.name;
  s->probe_tris = b.probe->mesh().num_triangles();
  s->scene_tris = b.scene->mesh().num_triangles();
  s->frames = static_cast<int>(frames);
}

/// Counts a frame whose query took `us` (µs) and ended with `status`.
inline void CountFrame(double us, pd::PdStatus status, SummaryBase* s) {
  if (us > kFrameBudgetUs) ++s->over_budget;
  if (status == pd::PdStatus::kPenetratingCapReached) ++s->cap_reached;
  if (status == pd::PdStatus::kFailed) ++s->failed;
}

/// Ends the summary: the percentiles of the query times `us` (µs, every
/// frame), the means of `iterations` and `contacts` (sums over the
/// penetrating frames) and whether p50 and p99 meet the goal (µs).
inline void FinishSummary(const std::vector<double>& us, long iterations, long contacts,
                          double goal_p50_us, double goal_p99_us, SummaryBase* s) {
  s->p50 = Percentile(us, 0.5);
  s->p99 = Percentile(us, 0.99);
  s->p999 = Percentile(us, 0.999);
  s->max = Percentile(us, 1.0);
  s->mean_iterations = MeanOver(static_cast<double>(iterations), s->penetrating);
  s->mean_contacts = MeanOver(static_cast<double>(contacts), s->penetrating);
  s->goal_met = s->p50 <= goal_p50_us && s->p99 <= goal_p99_us;
}

/// The leading columns of the summary table's heading (no line end).
inline void PrintTableHeadStart() {
  std::cout << std::left << std::setw(17) << "benchmark" << std::right << std::setw(7) << "tris A"
            << std::setw(8) << "tris B" << std::setw(7) << "frames" << std::setw(6) << "pen"
            << std::setw(9) << "p50" << std::setw(9) << "p99" << std::setw(9) << "p99.9"
            << std::setw(9) << "max" << std::setw(6) << ">1ms" << std::setw(7) << "iters"
            << std::setw(9) << "contacts";
}

/// The leading columns of `s`'s table row (no line end); leaves the
/// precision at 1.
inline void PrintTableRowStart(const SummaryBase& s) {
  std::cout << std::left << std::setw(17) << s.name << std::right << std::setw(7) << s.probe_tris
            << std::setw(8) << s.scene_tris << std::setw(7) << s.frames << std::setw(6)
            << s.penetrating << std::setprecision(1) << std::setw(9) << s.p50 << std::setw(9)
            << s.p99 << std::setw(9) << s.p999 << std::setw(9) << s.max << std::setw(6)
            << s.over_budget << std::setprecision(2) << std::setw(7) << s.mean_iterations
            << std::setprecision(1) << std::setw(9) << s.mean_contacts;
}

/// The leading columns of the summary CSV's heading for the query named
/// `query` (`pdt`, `pdg`), without the line end.
inline std::string CsvHeadStart(const std::string& query) {
  return "benchmark,probe_triangles,scene_triangles,frames,penetrating_frames," + query +
         "_p50_us," + query + "_p99_us," + query + "_p999_us," + query +
         "_max_us,frames_over_1ms,mean_iterations,mean_contacts";
}

/// The leading columns of `s`'s summary CSV row (no line end).
inline void WriteCsvRowStart(std::ostream& out, const SummaryBase& s) {
  out << std::setprecision(6) << s.name << "," << s.probe_tris << "," << s.scene_tris << ","
      << s.frames << "," << s.penetrating << "," << s.p50 << "," << s.p99 << "," << s.p999 << ","
      << s.max << "," << s.over_budget << "," << s.mean_iterations << "," << s.mean_contacts;
}

/// The closing line: where the CSVs went.
inline void PrintCsvWritten(const std::string& csv, const std::string& frames_csv) {
  std::cout << "CSV written to " << csv;
  if (!frames_csv.empty()) std::cout << ", per-frame CSV to " << frames_csv;
  std::cout << "\n";
}

}  // namespace hapticpd::bench
