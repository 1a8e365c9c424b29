// hapticpd bench table1|delay: what PD costs in time on the seed paper's
// benchmarks (client/bench/table1.h), and how the feel survives a slow link
// (client/bench/delay.h, with a force plot). The benchmarks that need the
// test oracles (FCL, Bullet) are a separate executable, hapticpd-bench
// (client/bench/bench_main.cc): `hapticpd bench peers|accuracy|cold` only
// say so, in one line, so that hapticpd links neither.
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>

#include "client/bench/bench_cli.h"
#include "client/bench/delay.h"
#include "client/bench/scenarios.h"
#include "client/bench/table1.h"
#include "client/commands.h"

namespace hapticpd::cli {
namespace {

void RunTable1Cmd(const BenchOptions& o) {
  // With --json the notes go to stderr so that stdout is one JSON document.
  std::ostream& notes = o.json ? std::cerr : std::cout;
  const auto benchmarks = PrepareBenchmarks("bench table1", o, notes);
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
  d.models = ResolveModels("bench delay", o.models, o.models_given);
  MakeOutputFolder("bench delay", "--out", o.out);
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
      "bench",
      "Measure PD time on the seed's benchmarks and the feel over a slow link (the benchmarks "
      "against FCL and Bullet are hapticpd-bench peers|accuracy|cold)");
  bench->require_subcommand(1);
  {
    auto o = std::make_shared<BenchOptions>();
    auto* cmd = bench->add_subcommand(
        "table1",
        "The seed's Table 1 on this machine: per benchmark and mode p50/p99/max time, "
        "mean contacts and iterations, the seed's numbers beside them");
    AddCommonBenchOptions(cmd, o, 2000);
    cmd->add_option("--csv", o->csv, "Also write the table as CSV")->type_name("FILE");
    cmd->callback([o] { RunTable1Cmd(*o); });
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
  // The benchmarks that need the oracles: hapticpd does not link FCL or
  // Bullet, so these only name the executable that runs them. Whatever
  // follows them on the command line is left unparsed.
  for (const char* name : {"accuracy", "peers", "cold"}) {
    const std::string sub = name;
    auto* cmd = bench->add_subcommand(
        sub, "Moved to hapticpd-bench " + sub +
                 " (needs the FCL and Bullet oracles, which hapticpd does not link)");
    cmd->prefix_command();
    cmd->callback([sub] {
      throw CommandError("bench " + sub +
                         " needs the FCL and Bullet oracles, which hapticpd does not link; run "
                         "hapticpd-bench " +
                         sub + " (built beside hapticpd: build/<preset>/hapticpd-bench)");
    });
  }
}

}  // namespace hapticpd::cli
