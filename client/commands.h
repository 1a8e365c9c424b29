// Subcommands of the `hapticpd` executable. Each Register* function adds one
// CLI11 subcommand with its options and callback.
#pragma once

#include <CLI/CLI.hpp>

#include <string>
#include <vector>

#include "client/link_emulator.h"

namespace hapticpd::cli {

void RegisterVersion(CLI::App& app);
void RegisterMeshInfo(CLI::App& app);
void RegisterPd(CLI::App& app);
void RegisterServe(CLI::App& app);
void RegisterSceneOps(CLI::App& app);  // inject, move, remove, scene
void RegisterWatchCouple(CLI::App& app);
void RegisterDevice(CLI::App& app);  // device: the 1 kHz device side of a session
void RegisterDemo(CLI::App& app);    // demo: server + scene + simulated device in one process
void RegisterBench(CLI::App& app);   // bench table1|delay (peers|accuracy|cold: hapticpd-bench)
/// observe: a scene's Watch stream, one summary line a second (or JSON).
void RegisterObserve(CLI::App& app);

/// view: a scene in a browser (client/viewer/README.md).
void RegisterView(CLI::App& app);

/// --delay, --jitter, --loss (the emulated wide-area link of `device` and
/// `demo`) into `link`; checked by client::LinkOptionsProblem when run.
void AddLinkOptions(CLI::App* cmd, client::LinkOptions* link);

/// Thrown by a command to exit non-zero with a one-line reason on stderr.
struct CommandError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

/// The numbers of a vector option such as a pose: separated by commas,
/// whitespace or both ("0.5 0 0", "0.5,0,0", "0.5, 0, 0"), every pose option
/// of the command line alike. Each in strtod syntax, nan and inf included
/// (a caller that needs finite values checks, naming the component). A
/// token that is not a number, or an empty field between two commas, is a
/// CommandError naming `option`.
std::vector<double> ParseNumbers(const std::string& text, const std::string& option);

}  // namespace hapticpd::cli
