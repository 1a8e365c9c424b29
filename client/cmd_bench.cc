// hapticpd bench table1|accuracy|peers|cold: what accuracy costs in time, on the
// seed paper's benchmarks (client/bench/). Prints tables (or JSON) and,
// for accuracy, writes Pareto plots as SVG. hapticpd bench delay: how the
// feel survives a slow link (client/bench/delay.h), with a force plot.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>

#include "client/bench/accuracy.h"
#include "client/bench/cold.h"
#include "client/bench/delay.h"
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

/// The current time for plot titles, e.g. "2026-12-03 19:30 UTC".
std::string UtcNow() {
  const std::time_t now = std::time(nullptr);
  char date[64];
  std::strftime(date, sizeof(date), "%Y-%m-%d %H:%M UTC", std::gmtime(&now));
  return date;
}

/// Creates the output folder `dir` of `bench SUB` (given by `option`).
void MakeOutputFolder(const std::string& sub, const std::string& option, const std::string& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (!std::filesystem::is_directory(dir)) {
    throw CommandError("bench " + sub + ": " + option + ": cannot create folder '" + dir + "'");
  }
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
    MakeOutputFolder("accuracy", "--svg", o.svg_dir);
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
    const std::string date = UtcNow();
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

struct ColdCmdOptions {
  std::string models;
  bool models_given = false;
  bool json = false;
  bool procedural = false;
  std::string out = "hapticpd-bench-cold";
  std::string write_reference;
  std::string poses_from;
  int cold_directions = pd::PenetrationRequest{}.cold_start_directions;
  int poses = 16;
  std::uint64_t seed = 1;
};

void RunColdCmd(const ColdCmdOptions& o) {
  bench::ColdOptions c;
  {
    BenchOptions b;
    b.models = o.models;
    b.models_given = o.models_given;
    c.models = o.procedural ? "" : ResolveModels("cold", b);
  }
  c.procedural_only = o.procedural;
  c.poses = o.poses;
  c.seed = o.seed;
  c.poses_from = o.poses_from;
  c.cold_directions = o.cold_directions;
  MakeOutputFolder("cold", "--out", o.out);
  const std::filesystem::path out(o.out);
  std::ostream& notes = o.json ? std::cerr : std::cout;
  bench::ColdReport report;
  try {
    report = bench::RunCold(c, &notes);
  } catch (const std::runtime_error& e) {
    throw CommandError(std::string("bench cold: ") + e.what());
  }
  std::string command = "hapticpd bench cold --poses " + std::to_string(o.poses) + " --seed " +
                        std::to_string(o.seed);
  if (o.procedural) command += " --procedural";
  if (o.models_given) command += " --models " + o.models;
  if (!o.poses_from.empty()) command += " --poses-from " + o.poses_from;
  command += " --cold-directions " + std::to_string(o.cold_directions);
  const std::string date = UtcNow();
  const std::filesystem::path svg = out / "cold.svg";
  try {
    bench::WriteColdSvg(svg, report,
                        std::string("hapticpd bench cold, ") + date + ": " + command +
                            ", load average " + report.load_average);
  } catch (const std::runtime_error& e) {
    throw CommandError(std::string("bench cold: ") + e.what());
  }
  if (!o.write_reference.empty()) {
    std::ofstream f(o.write_reference);
    f << bench::ColdPosesToJson(report.poses, c).dump(1) << "\n";
    if (!f)
      throw CommandError("bench cold: --write-reference: cannot write '" + o.write_reference + "'");
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

struct DelayCmdOptions {
  std::string models;
  bool models_given = false;
  bool json = false;
  std::string out = "hapticpd-bench-delay";
  std::string delays = "0,5,20,50,100,200";
  std::string scripts = "press,slide,twist";
  double time_scale = 1;
  std::uint64_t seed = 1;
  bool server_only = false;
};

std::vector<std::string> SplitCommas(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, ',')) out.push_back(item);
  return out;
}

void RunDelayCmd(const DelayCmdOptions& o) {
  bench::DelayBenchOptions d;
  d.delays_ms.clear();
  for (const std::string& item : SplitCommas(o.delays)) {
    std::size_t used = 0;
    double ms = -1;
    try {
      ms = std::stod(item, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used != item.size() || !(ms >= 0 && ms <= 10000)) {
      throw CommandError(
          "bench delay: --delays: expected comma-separated milliseconds in [0, "
          "10000], got '" +
          item + "'");
    }
    d.delays_ms.push_back(ms);
  }
  if (d.delays_ms.empty()) throw CommandError("bench delay: --delays: give at least one delay");
  d.scripts = SplitCommas(o.scripts);
  if (d.scripts.empty()) throw CommandError("bench delay: --scripts: give at least one script");
  for (const std::string& s : d.scripts) {
    if (s != "press" && s != "slide" && s != "twist") {
      throw CommandError("bench delay: --scripts: unknown script '" + s +
                         "' (press, slide, twist)");
    }
  }
  if (!(o.time_scale >= 0.05 && o.time_scale <= 20)) {
    throw CommandError("bench delay: --time-scale: expected 0.05 to 20");
  }
  d.time_scale = o.time_scale;
  d.seed = o.seed;
  d.local_model = !o.server_only;
  {
    BenchOptions b;
    b.models = o.models;
    b.models_given = o.models_given;
    d.models = ResolveModels("delay", b);
  }
  MakeOutputFolder("delay", "--out", o.out);
  const std::filesystem::path out(o.out);
  std::ostream& notes = o.json ? std::cerr : std::cout;
  notes << "hapticpd bench delay: " << d.delays_ms.size() << " delays x " << d.scripts.size()
        << " scripts in real time\n";
  bench::DelayReport report;
  try {
    report = bench::RunDelayBench(d, &notes);
  } catch (const std::exception& e) {
    throw CommandError(std::string("bench delay: ") + e.what());
  }
  std::string command = "hapticpd bench delay --delays " + o.delays + " --scripts " + o.scripts;
  if (o.time_scale != 1) command += " --time-scale " + std::to_string(o.time_scale);
  if (o.server_only) command += " --server-only";
  if (o.models_given) command += " --models " + o.models;
  const std::string date = UtcNow();
  const std::filesystem::path svg = out / "delay_force.svg";
  try {
    bench::WriteDelaySvg(svg, report,
                         std::string("hapticpd bench delay, ") + date + ": " + command);
  } catch (const std::runtime_error& e) {
    throw CommandError(std::string("bench delay: ") + e.what());
  }
  if (o.json) {
    nlohmann::json j = bench::ToJson(report);
    j["svg"] = svg.string();
    std::cout << j.dump(2) << "\n";
  } else {
    bench::PrintDelay(std::cout, report);
    std::cout << "wrote " << svg.string() << "\n";
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
  {
    auto o = std::make_shared<ColdCmdOptions>();
    auto* cmd = bench->add_subcommand(
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
    cmd->callback([o] { RunColdCmd(*o); });
  }
  {
    auto o = std::make_shared<DelayCmdOptions>();
    auto* cmd = bench->add_subcommand(
        "delay",
        "The same scripted hands (press a box, slide on the bunny, twist in a slot) at one-way "
        "delays with +-20% jitter, in real time through an in-process server and the emulated "
        "link: force, felt stiffness, penetration, passivity, free-space drag; goals against "
        "0 ms; a force plot");
    cmd->add_option("--models", o->models,
                    "Folder with stanford-bunny.obj (default $HAPTICPD_MODELS_DIR or "
                    "../shared/models; without it a torus knot is used)")
        ->type_name("DIR")
        ->each([o](const std::string&) { o->models_given = true; });
    cmd->add_flag("--json", o->json, "Print JSON (progress goes to stderr)");
    cmd->add_option("--out", o->out, "Folder for delay_force.svg")->capture_default_str();
    cmd->add_option("--delays", o->delays, "One-way delays (ms), comma-separated")
        ->capture_default_str();
    cmd->add_option("--scripts", o->scripts, "Scripts to run: press, slide, twist")
        ->capture_default_str();
    cmd->add_option("--time-scale", o->time_scale,
                    "Multiply every script's duration (smaller: faster, for tests)")
        ->capture_default_str();
    cmd->add_option("--seed", o->seed, "Seed of the emulated link's jitter")->capture_default_str();
    cmd->add_flag("--server-only", o->server_only,
                  "Run the device sessions without the local contact model (server answers only)");
    cmd->callback([o] { RunDelayCmd(*o); });
  }
}

}  // namespace hapticpd::cli
