// hapticpd bench table1|accuracy|peers: what accuracy costs in time, on the
// seed paper's benchmarks (client/bench/). Prints tables (or JSON) and,
// for accuracy, writes Pareto plots as SVG.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <iostream>
#include <memory>
#include <string>

#include "client/bench/accuracy.h"
#include "client/bench/peers.h"
#include "client/bench/scenarios.h"
#include "client/bench/table1.h"
#include "client/commands.h"

namespace hapticpd::cli {
namespace {

struct BenchOptions {
  std::string models;
  bool models_given = false;
  int frames = 0;
  bool json = false;
  bool tiny = false;
  std::string csv;
  std::string svg_dir;
  int poses = 12;
  std::uint64_t seed = 1;
  std::string command_line;
};

std::string DefaultModels() {
  const char* env = std::getenv("HAPTICPD_MODELS_DIR");
  return env != nullptr && *env != '\0' ? env : "../shared/models";
}

/// The models folder to use ("" when absent and not asked for explicitly).
std::string ResolveModels(const std::string& sub, const BenchOptions& o) {
  const std::string dir = o.models_given ? o.models : DefaultModels();
  if (std::filesystem::is_directory(dir)) return dir;
  if (o.models_given) {
    throw CommandError("bench " + sub + ": --models: '" + dir + "' is not a directory");
  }
  return "";
}

std::vector<bench::Benchmark> Prepare(const std::string& sub, const BenchOptions& o,
                                      std::ostream& notes) {
  const std::string models = ResolveModels(sub, o);
  if (models.empty() && !o.tiny) {
    notes << "NOTE: shared models folder '" << DefaultModels()
          << "' not found: procedural stand-ins replace the bunny and the statue\n";
  }
  std::vector<bench::Benchmark> benchmarks = bench::BuildBenchmarks(models, o.tiny);
  for (bench::Benchmark& b : benchmarks) {
    bench::MakeTrajectory(&b, o.frames);
    notes << "== " << b.name << ": " << b.probe_name << " (" << b.probe->mesh().num_triangles()
          << " triangles) vs " << b.scene_name << " (" << b.scene->mesh().num_triangles()
          << " triangles), " << b.frames.size() << " frames at 1 kHz\n";
    for (const std::string& n : b.notes) notes << "   " << n << "\n";
  }
  return benchmarks;
}

void RunTable1Cmd(const BenchOptions& o) {
  // With --json the notes go to stderr so that stdout is one JSON document.
  std::ostream& notes = o.json ? std::cerr : std::cout;
  const auto benchmarks = Prepare("table1", o, notes);
  const auto rows = bench::RunTable1(benchmarks);
  if (!o.csv.empty()) {
    try {
      bench::WriteTable1Csv(o.csv, rows);
    } catch (const std::runtime_error& e) {
      throw CommandError(std::string("bench table1: --csv: ") + e.what());
    }
  }
  if (o.json) {
    std::cout << bench::ToJson(rows).dump(2) << "\n";
  } else {
    bench::PrintTable1(std::cout, rows);
    if (!o.csv.empty()) std::cout << "CSV written to " << o.csv << "\n";
  }
}

void RunPeersCmd(const BenchOptions& o) {
  std::ostream& notes = o.json ? std::cerr : std::cout;
  const auto benchmarks = Prepare("peers", o, notes);
  const auto rows = bench::RunPeers(benchmarks);
  if (o.json) {
    std::cout << bench::ToJson(rows).dump(2) << "\n";
  } else {
    bench::PrintPeers(std::cout, rows);
  }
}

void RunAccuracyCmd(const BenchOptions& o) {
  if (!o.svg_dir.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(o.svg_dir, ec);
    if (!std::filesystem::is_directory(o.svg_dir)) {
      throw CommandError("bench accuracy: --svg: cannot create folder '" + o.svg_dir + "'");
    }
  }
  bench::AccuracyOptions a;
  a.models = ResolveModels("accuracy", o);
  a.frames = o.frames;
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
    const std::time_t now = std::time(nullptr);
    char date[64];
    std::strftime(date, sizeof(date), "%Y-%m-%d %H:%M UTC", std::gmtime(&now));
    written = bench::WriteAccuracySvgs(
        o.svg_dir, report, std::string("hapticpd bench accuracy, ") + date + ": " + o.command_line);
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

}  // namespace

void RegisterBench(CLI::App& app) {
  auto* bench = app.add_subcommand(
      "bench", "Measure PD time and accuracy on the seed's benchmarks, beside peers (FCL, Bullet)");
  bench->require_subcommand(1);
  auto add_common = [](CLI::App* cmd, const std::shared_ptr<BenchOptions>& o, int frames) {
    o->frames = frames;
    cmd->add_option("--models", o->models,
                    "Folder with stanford-bunny.obj and beast.obj (default $HAPTICPD_MODELS_DIR "
                    "or ../shared/models; without them procedural stand-ins are used)")
        ->type_name("DIR")
        ->each([o](const std::string&) { o->models_given = true; });
    cmd->add_option("--frames", o->frames, "Frames of each 1 kHz trajectory")
        ->check(CLI::Range(8, 1000000))
        ->capture_default_str();
    cmd->add_flag("--json", o->json, "Print JSON (notes go to stderr)");
    cmd->add_flag("--tiny", o->tiny,
                  "Small procedural meshes instead of the benchmarks (for tests: seconds, not "
                  "minutes)");
  };
  {
    auto o = std::make_shared<BenchOptions>();
    auto* cmd = bench->add_subcommand(
        "table1",
        "The seed's Table 1 on this machine: per benchmark and mode p50/p99/max time, "
        "mean contacts and iterations, the seed's numbers beside them");
    add_common(cmd, o, 2000);
    cmd->add_option("--csv", o->csv, "Also write the table as CSV")->type_name("FILE");
    cmd->callback([o] { RunTable1Cmd(*o); });
  }
  {
    auto o = std::make_shared<BenchOptions>();
    auto* cmd = bench->add_subcommand(
        "accuracy",
        "Error against ground truth vs p50 time for PDt and PDg, sweeping iteration cap, "
        "contact epsilon, coherence and mesh resolution; Pareto plots with --svg");
    add_common(cmd, o, 500);
    cmd->add_option("--svg", o->svg_dir, "Write accuracy_pdt.svg and accuracy_pdg.svg here")
        ->type_name("DIR");
    cmd->add_option("--poses", o->poses, "Reference poses per benchmark (ground truth is costly)")
        ->check(CLI::Range(1, 1000))
        ->capture_default_str();
    cmd->add_option("--seed", o->seed, "Seed of the sampling bounds")->capture_default_str();
    cmd->callback([o] {
      // For the plots' titles: the command that made them.
      o->command_line = "hapticpd bench accuracy";
      if (o->models_given) o->command_line += " --models " + o->models;
      o->command_line += " --frames " + std::to_string(o->frames) + " --poses " +
                         std::to_string(o->poses) + " --seed " + std::to_string(o->seed);
      if (o->tiny) o->command_line += " --tiny";
      if (!o->svg_dir.empty()) o->command_line += " --svg " + o->svg_dir;
      RunAccuracyCmd(*o);
    });
  }
  {
    auto o = std::make_shared<BenchOptions>();
    auto* cmd = bench->add_subcommand(
        "peers",
        "Our PDt against FCL all-contacts collide, GJK/EPA on convex hulls (Bullet, "
        "FCL) and one boolean collision query, on the same poses; ratios and errors");
    add_common(cmd, o, 1000);
    cmd->callback([o] { RunPeersCmd(*o); });
  }
}

}  // namespace hapticpd::cli
