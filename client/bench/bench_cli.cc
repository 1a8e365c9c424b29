#include "client/bench/bench_cli.h"

#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <iostream>
#include <system_error>

#include "client/commands.h"
#include "pd/mesh.h"

namespace hapticpd::cli {

std::string DefaultModels() {
  const char* env = std::getenv("HAPTICPD_MODELS_DIR");
  return env != nullptr && *env != '\0' ? env : "../shared/models";
}

std::string ResolveModels(const std::string& command, const std::string& models,
                          bool models_given) {
  const std::string dir = models_given ? models : DefaultModels();
  if (std::filesystem::is_directory(dir)) return dir;
  if (models_given) {
    throw CommandError(command + ": --models: '" + dir + "' is not a directory");
  }
  return "";
}

std::string UtcNow() {
  const std::time_t now = std::time(nullptr);
  char date[64];
  std::strftime(date, sizeof(date), "%Y-%m-%d %H:%M UTC", std::gmtime(&now));
  return date;
}

void MakeOutputFolder(const std::string& command, const std::string& option,
                      const std::string& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (!std::filesystem::is_directory(dir)) {
    throw CommandError(command + ": " + option + ": cannot create folder '" + dir + "'");
  }
}

std::vector<bench::Benchmark> PrepareBenchmarks(const std::string& command, const BenchOptions& o,
                                                std::ostream& notes) {
  const std::string models = ResolveModels(command, o.models, o.models_given);
  if (models.empty() && !o.tiny) {
    notes << "NOTE: shared models folder '" << DefaultModels()
          << "' not found: procedural stand-ins replace the bunny and the statue\n";
  }
  std::vector<bench::Benchmark> benchmarks = bench::BuildBenchmarks(models, o.tiny);
  for (bench::Benchmark& b : benchmarks) {
    bench::MakeTrajectory(&b, o.frames, o.max_slope);
    notes << "== " << b.name << ": " << b.probe_name << " (" << b.probe->mesh().num_triangles()
          << " triangles) vs " << b.scene_name << " (" << b.scene->mesh().num_triangles()
          << " triangles), " << b.frames.size() << " frames at 1 kHz\n";
    for (const std::string& n : b.notes) notes << "   " << n << "\n";
  }
  return benchmarks;
}

void AddCommonBenchOptions(CLI::App* cmd, const std::shared_ptr<BenchOptions>& o, int frames) {
  o->frames = frames;
  cmd->add_option("--models", o->models,
                  "Folder with stanford-bunny.obj and beast.obj (default $HAPTICPD_MODELS_DIR "
                  "or ../shared/models; without them procedural stand-ins are used)")
      ->type_name("DIR")
      ->each([o](const std::string&) { o->models_given = true; });
  cmd->add_option("--frames", o->frames, "Frames of each 1 kHz trajectory")
      ->check(CLI::Range(8, 1000000))
      ->capture_default_str();
  cmd->add_option("--max-slope", o->max_slope,
                  "Steepest surface the tip follows while sliding (rise over run; inf: the raw "
                  "height under it, which jumps at edges: a teleport of the probe)")
      ->check(CLI::Validator(
          [](std::string& s) {
            double slope = 0;
            return bench::ParseMaxSlope(s, &slope);
          },
          "SLOPE >= 0"))
      ->capture_default_str();
  cmd->add_flag("--json", o->json, "Print JSON (notes go to stderr)");
  cmd->add_flag("--tiny", o->tiny,
                "Small procedural meshes instead of the benchmarks (for tests: seconds, not "
                "minutes)");
}

void SetUpApp(CLI::App& app, const std::string& program) {
  app.require_subcommand(1);
  app.set_help_all_flag("--help-all", "Show help for every subcommand");
  // Command-line errors too get one line on stderr, like every other bad input.
  app.failure_message([program](const CLI::App*, const CLI::Error& e) {
    return program + ": " + e.what() + " (run with --help for usage)\n";
  });
}

int RunApp(CLI::App& app, const std::string& program, int argc, char** argv) {
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const CommandError& e) {
    std::cerr << program << ": " << e.what() << "\n";
    return 1;
  } catch (const pd::MeshError& e) {
    std::cerr << program << ": " << e.what() << "\n";
    return 1;
  } catch (const std::exception& e) {
    std::cerr << program << ": error: " << e.what() << "\n";
    return 1;
  }
  return 0;
}

}  // namespace hapticpd::cli
