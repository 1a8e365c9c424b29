// Command-line pieces shared by the two executables that run benchmarks:
// `hapticpd bench table1|delay` (client/cmd_bench.cc, no oracles) and
// `hapticpd-bench peers|accuracy|cold` (client/bench/bench_main.cc, which
// links FCL and Bullet). `command` is the command as the user typed it
// after the executable's name ("bench table1", "accuracy"), for errors.
#pragma once

#include <CLI/CLI.hpp>

#include <cstdint>
#include <memory>
#include <ostream>
#include <string>
#include <vector>

#include "client/bench/scenarios.h"

namespace hapticpd::cli {

/// The options of the benchmarks over the seed's three pairs (table1,
/// accuracy, peers).
struct BenchOptions {
  std::string models;
  bool models_given = false;
  int frames = 0;
  double max_slope = bench::kTrajectoryMaxSlope;  ///< MakeTrajectory's
  bool json = false;
  bool tiny = false;
  std::string csv;
  std::string svg_dir;
  int poses = 12;
  std::uint64_t seed = 1;
  std::string command_line;
};

/// $HAPTICPD_MODELS_DIR, else ../shared/models.
std::string DefaultModels();

/// The models folder to use ("" when absent and not asked for explicitly;
/// a CommandError when --models names no folder).
std::string ResolveModels(const std::string& command, const std::string& models, bool models_given);

/// The current time for plot titles, e.g. "2026-12-03 19:30 UTC".
std::string UtcNow();

/// Creates the output folder `dir` given by `option` (a CommandError when it
/// cannot).
void MakeOutputFolder(const std::string& command, const std::string& option,
                      const std::string& dir);

/// The seed's benchmarks with their trajectories, one note per benchmark
/// (and one when procedural stand-ins replace the shared models).
std::vector<bench::Benchmark> PrepareBenchmarks(const std::string& command, const BenchOptions& o,
                                                std::ostream& notes);

/// --models, --frames (default `frames`), --json, --tiny.
void AddCommonBenchOptions(CLI::App* cmd, const std::shared_ptr<BenchOptions>& o, int frames);

/// What both executables' `app` asks of its command line: one subcommand,
/// --help-all, and command-line errors as one line on stderr naming
/// `program`.
void SetUpApp(CLI::App& app, const std::string& program);

/// Parses the command line and runs the chosen subcommand; every error is one
/// line on stderr naming `program`. Returns the exit code.
int RunApp(CLI::App& app, const std::string& program, int argc, char** argv);

}  // namespace hapticpd::cli
