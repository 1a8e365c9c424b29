#include <OpenMesh/Core/System/config.h>
#include <spdlog/version.h>
#include <Eigen/Core>

#include <iostream>

#include "client/commands.h"

namespace hapticpd::cli {

void RegisterVersion(CLI::App& app) {
  auto* cmd = app.add_subcommand("version", "Print the hapticpd version and library versions");
  cmd->callback([] {
    std::cout << "hapticpd " << HAPTICPD_VERSION << "\n"
              << "  Eigen " << EIGEN_WORLD_VERSION << "." << EIGEN_MAJOR_VERSION << "."
              << EIGEN_MINOR_VERSION << ", OpenMesh " << OM_GET_VER << "." << OM_GET_MAJ
              << ", spdlog " << SPDLOG_VER_MAJOR << "." << SPDLOG_VER_MINOR << "."
              << SPDLOG_VER_PATCH << ", compiled with " << __VERSION__ << "\n";
  });
}

}  // namespace hapticpd::cli
