// hapticpd: one executable, one subcommand per job.
#include <spdlog/spdlog.h>

#include <iostream>

#include "client/commands.h"
#include "pd/mesh.h"

int main(int argc, char** argv) {
  CLI::App app{"hapticpd: networked 6-DoF haptic rendering with penetration depth", "hapticpd"};
  app.require_subcommand(1);
  app.set_help_all_flag("--help-all", "Show help for every subcommand");
  // Command-line errors too get one line on stderr, like every other bad input.
  app.failure_message([](const CLI::App*, const CLI::Error& e) {
    return std::string("hapticpd: ") + e.what() + " (run with --help for usage)\n";
  });
  hapticpd::cli::RegisterVersion(app);
  hapticpd::cli::RegisterMeshInfo(app);
  hapticpd::cli::RegisterPd(app);
  hapticpd::cli::RegisterServe(app);
  hapticpd::cli::RegisterSceneOps(app);
  hapticpd::cli::RegisterWatchCouple(app);
  hapticpd::cli::RegisterDevice(app);
  hapticpd::cli::RegisterDemo(app);
  hapticpd::cli::RegisterBench(app);
  hapticpd::cli::RegisterObserve(app);
  hapticpd::cli::RegisterView(app);
  spdlog::set_pattern("[%H:%M:%S.%e] [%^%l%$] %v");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const hapticpd::cli::CommandError& e) {
    std::cerr << "hapticpd: " << e.what() << "\n";
    return 1;
  } catch (const hapticpd::pd::MeshError& e) {
    std::cerr << "hapticpd: " << e.what() << "\n";
    return 1;
  } catch (const std::exception& e) {
    std::cerr << "hapticpd: error: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
