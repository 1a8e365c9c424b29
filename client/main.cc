// hapticpd: one executable, one subcommand per job.
#include <spdlog/spdlog.h>

#include "client/bench/bench_cli.h"
#include "client/commands.h"

int main(int argc, char** argv) {
  CLI::App app{"hapticpd: networked 6-DoF haptic rendering with penetration depth", "hapticpd"};
  hapticpd::cli::SetUpApp(app, "hapticpd");
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
  return hapticpd::cli::RunApp(app, "hapticpd", argc, argv);
}
