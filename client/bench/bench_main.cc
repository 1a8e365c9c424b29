// hapticpd-bench peers|accuracy|cold: the benchmarks that compare PD with the
// test oracles (FCL and Bullet, tests/oracles) or verify its answers with
// them. A separate executable so that the shipped `hapticpd` links neither;
// `hapticpd bench table1|delay` need no oracle and stay there. Prints tables
// (or JSON) and writes SVG plots (accuracy: Pareto plots; cold: one plot).
#include <spdlog/spdlog.h>

#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "client/bench/accuracy.h"
#include "client/bench/bench_cli.h"
#include "client/bench/cold.h"
#include "client/bench/peers.h"
#include "client/commands.h"
#include "pd/mesh.h"

namespace hapticpd::cli {
namespace {

void RunPeersCmd(const BenchOptions& o) {
  std::ostream& notes = o.json ? std::cerr : std::cout;
  const auto benchmarks = PrepareBenchmarks("peers", o, notes);
  const auto rows = bench::RunPeers(benchmarks);
  if (o.json) {
    std::cout << bench::ToJson(rows).dump(2) << "\n";
  } else {
    bench::PrintPeers(std::cout, rows);
  }
}

void RunAccuracyCmd(const BenchOptions& o) {
  if (!o.svg_dir.empty()) {
    MakeOutputFolder("accuracy", "--svg", o.svg_dir);
  }
  bench::AccuracyOptions a;
  a.models = ResolveModels("accuracy", o.models, o.models_given);
  a.frames = o.frames;
  a.max_slope = o.max_slope;
  a.poses = o.poses;
  a.tiny = o.tiny;
  a.seed = o.seed;
  if (o.tiny) {
    a.pdt_directions = 24;
    a.pdg_rotations = 3;
    a.pdg_directions = 3;
  }
  std::ostream& notes = o.json ? std::cerr : std::cout;
  if (a.models.empty() && !o.tiny) {
    notes << "NOTE: shared models folder '" << DefaultModels()
          << "' not found: procedural stand-ins replace the bunny and the statue\n";
  }
  const bench::AccuracyReport report = bench::RunAccuracy(a, &std::cerr);
  std::vector<std::filesystem::path> written;
  if (!o.svg_dir.empty()) {
    const std::string date = UtcNow();
    written = bench::WriteAccuracySvgs(
        o.svg_dir, report, std::string("hapticpd-bench accuracy, ") + date + ": " + o.command_line);
  }
  if (o.json) {
    nlohmann::json j = bench::ToJson(report);
    j["svg"] = nlohmann::json::array();
    for (const auto& p : written) j["svg"].push_back(p.string());
    std::cout << j.dump(2) << "\n";
  } else {
    bench::PrintAccuracy(std::cout, report);
    for (const auto& p : written) std::cout << "wrote " << p.string() << "\n";
  }
}

struct ColdCmdOptions {
  std::string models;
  bool models_given = false;
  bool json = false;
  bool procedural = false;
  std::string out = "hapticpd-bench-cold";
  std::string write_reference;
  std::string poses_from;
  int cold_directions = pd::PenetrationRequest{}.cold_start_directions;
  int turn_starts = pd::PenetrationRequest{}.pdg_cold_turn_starts;
  int local_search = pd::PenetrationRequest{}.pdg_cold_local_search;
  bool no_interior_cull = false;
  int poses = 16;
  std::uint64_t seed = 1;
};

void RunColdCmd(const ColdCmdOptions& o) {
  bench::ColdOptions c;
  c.models = o.procedural ? "" : ResolveModels("cold", o.models, o.models_given);
  c.procedural_only = o.procedural;
  c.poses = o.poses;
  c.seed = o.seed;
  c.poses_from = o.poses_from;
  c.cold_directions = o.cold_directions;
  c.turn_starts = o.turn_starts;
  c.local_search = o.local_search;
  c.interior_cull = !o.no_interior_cull;
  MakeOutputFolder("cold", "--out", o.out);
  const std::filesystem::path out(o.out);
  std::ostream& notes = o.json ? std::cerr : std::cout;
  bench::ColdReport report;
  try {
    report = bench::RunCold(c, &notes);
  } catch (const std::runtime_error& e) {
    throw CommandError(std::string("cold: ") + e.what());
  }
  std::string command = "hapticpd-bench cold --poses " + std::to_string(o.poses) + " --seed " +
                        std::to_string(o.seed);
  if (o.procedural) command += " --procedural";
  if (o.models_given) command += " --models " + o.models;
  if (!o.poses_from.empty()) command += " --poses-from " + o.poses_from;
  command += " --cold-directions " + std::to_string(o.cold_directions);
  command += " --turn-starts " + std::to_string(o.turn_starts);
  command += " --local-search " + std::to_string(o.local_search);
  if (o.no_interior_cull) command += " --no-interior-cull";
  const std::string date = UtcNow();
  const std::filesystem::path svg = out / "cold.svg";
  try {
    bench::WriteColdSvg(svg, report,
                        std::string("hapticpd-bench cold, ") + date + ": " + command +
                            ", load average " + report.load_average);
  } catch (const std::runtime_error& e) {
    throw CommandError(std::string("cold: ") + e.what());
  }
  if (!o.write_reference.empty()) {
    std::ofstream f(o.write_reference);
    f << bench::ColdPosesToJson(report.poses, c).dump(1) << "\n";
    if (!f) throw CommandError("cold: --write-reference: cannot write '" + o.write_reference + "'");
  }
  if (o.json) {
    nlohmann::json j = bench::ToJson(report);
    j["svg"] = svg.string();
    std::cout << j.dump(2) << "\n";
  } else {
    bench::PrintCold(std::cout, report);
    std::cout << "wrote " << svg.string() << "\n";
    if (!o.write_reference.empty()) std::cout << "wrote " << o.write_reference << "\n";
  }
}

void RegisterOracleBenches(CLI::App& app) {
  {
    auto o = std::make_shared<BenchOptions>();
    auto* cmd = app.add_subcommand(
        "accuracy",
        "Error against ground truth vs p50 time for PDt and PDg, sweeping iteration cap, "
        "contact epsilon, coherence and mesh resolution; Pareto plots with --svg");
    AddCommonBenchOptions(cmd, o, 500);
    cmd->add_option("--svg", o->svg_dir, "Write accuracy_pdt.svg and accuracy_pdg.svg here")
        ->type_name("DIR");
    cmd->add_option("--poses", o->poses, "Reference poses per benchmark (ground truth is costly)")
        ->check(CLI::Range(1, 1000))
        ->capture_default_str();
    cmd->add_option("--seed", o->seed, "Seed of the sampling bounds")->capture_default_str();
    cmd->callback([o] {
      // For the plots' titles: the command that made them.
      o->command_line = "hapticpd-bench accuracy";
      if (o->models_given) o->command_line += " --models " + o->models;
      o->command_line += " --frames " + std::to_string(o->frames) + " --poses " +
                         std::to_string(o->poses) + " --seed " + std::to_string(o->seed);
      if (o->max_slope != bench::kTrajectoryMaxSlope) {
        o->command_line += fmt::format(" --max-slope {}", o->max_slope);
      }
      if (o->tiny) o->command_line += " --tiny";
      if (!o->svg_dir.empty()) o->command_line += " --svg " + o->svg_dir;
      RunAccuracyCmd(*o);
    });
  }
  {
    auto o = std::make_shared<BenchOptions>();
    auto* cmd = app.add_subcommand(
        "peers",
        "Our PDt against FCL all-contacts collide, GJK/EPA on convex hulls (Bullet, "
        "FCL) and one boolean collision query, on the same poses; ratios and errors");
    AddCommonBenchOptions(cmd, o, 1000);
    cmd->callback([o] { RunPeersCmd(*o); });
  }
  {
    auto o = std::make_shared<ColdCmdOptions>();
    auto* cmd = app.add_subcommand(
        "cold",
        "Cold PDt and PDg (no motion coherence) at random deep poses with random rotations on "
        "shared-model and procedural pairs: every answer verified with FCL, the ratio to "
        "sampled upper bounds (exact on convex pairs), time; a plot");
    cmd->add_option("--models", o->models,
                    "Folder with stanford-bunny.obj, spot.obj and beast.obj (default "
                    "$HAPTICPD_MODELS_DIR or ../shared/models; without them procedural pairs "
                    "only)")
        ->type_name("DIR")
        ->each([o](const std::string&) { o->models_given = true; });
    cmd->add_flag("--json", o->json, "Print JSON (progress goes to stderr)");
    cmd->add_flag("--procedural", o->procedural, "Procedural pairs only (the stored test set)");
    cmd->add_option("--out", o->out, "Folder for cold.svg")->capture_default_str();
    cmd->add_option("--poses", o->poses, "Poses per pair")
        ->check(CLI::Range(1, 10000))
        ->capture_default_str();
    cmd->add_option("--seed", o->seed, "Seed of the poses and the sampling bounds")
        ->capture_default_str();
    cmd->add_option("--write-reference", o->write_reference,
                    "Also write the poses and their reference bounds as JSON (tests/data/cold/)")
        ->type_name("FILE");
    cmd->add_option("--poses-from", o->poses_from,
                    "Query a stored pose set (written by --write-reference) instead of drawing "
                    "poses: its reference bounds are reused instead of sampled again")
        ->type_name("FILE")
        ->check(CLI::ExistingFile);
    cmd->add_option("--cold-directions", o->cold_directions,
                    "Escape directions of each query's cold search "
                    "(PenetrationRequest::cold_start_directions: 1 the centroid direction only, "
                    "13 the fixed ones, more adds a sphere lattice)")
        ->check(CLI::Range(1, pd::kMaxColdSearchDirections))
        ->capture_default_str();
    cmd->add_option("--turn-starts", o->turn_starts,
                    "Turn starts of each cold PDg query (PenetrationRequest::pdg_cold_turn_starts: "
                    "0 none)")
        ->check(CLI::Range(0, pd::kPdgColdTurnStarts))
        ->capture_default_str();
    cmd->add_option("--local-search", o->local_search,
                    "Candidates of the local search of each unbudgeted cold PDg query "
                    "(PenetrationRequest::pdg_cold_local_search: 0 none)")
        ->check(CLI::Range(0, 10000))
        ->capture_default_str();
    cmd->add_flag("--no-interior-cull", o->no_interior_cull,
                  "Run the exact start check on every escape direction and turn start "
                  "(PenetrationRequest::cold_interior_cull off), to compare: the same answers "
                  "without the work budget");
    cmd->callback([o] { RunColdCmd(*o); });
  }
}

}  // namespace
}  // namespace hapticpd::cli

int main(int argc, char** argv) {
  CLI::App app{
      "hapticpd-bench: the benchmarks that compare PD with FCL and Bullet or verify it with "
      "them (peers, accuracy, cold); `hapticpd bench` runs table1 and delay",
      "hapticpd-bench"};
  hapticpd::cli::SetUpApp(app, "hapticpd-bench");
  hapticpd::cli::RegisterOracleBenches(app);
  spdlog::set_pattern("[%H:%M:%S.%e] [%^%l%$] %v");
  return hapticpd::cli::RunApp(app, "hapticpd-bench", argc, argv);
}
