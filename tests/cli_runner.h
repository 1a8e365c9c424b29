// Runs the built `hapticpd` executable (or another, RunExecutable) as a user
// would (through the shell) and captures its exit code, stdout and stderr.
// The including test target defines HAPTICPD_CLI_PATH (hapticpd's path).
#pragma once

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

namespace hapticpd::testing {

struct RunResult {
  int exit_code = -1;
  std::string out;
  std::string err;
};

/// Runs the executable at `path` with ARGS (shell text, quote as in a
/// terminal), in the folder `cwd` when one is given.
inline RunResult RunExecutable(const std::string& path, const std::string& args,
                               const std::filesystem::path& cwd = {}) {
  static std::atomic<int> counter{0};
  const std::filesystem::path err_path =
      std::filesystem::temp_directory_path() / ("hapticpd_cli_test_" + std::to_string(::getpid()) +
                                                "_" + std::to_string(counter++) + ".err");
  std::string cmd = std::string("'") + path + "' " + args + " 2>'" + err_path.string() + "'";
  if (!cwd.empty()) cmd = "cd '" + cwd.string() + "' && " + cmd;
  RunResult r;
  FILE* pipe = ::popen(cmd.c_str(), "r");
  if (pipe == nullptr) {
    ADD_FAILURE() << "popen failed for: " << cmd;
    return r;
  }
  char buf[4096];
  std::size_t n = 0;
  while ((n = std::fread(buf, 1, sizeof(buf), pipe)) > 0) r.out.append(buf, n);
  const int status = ::pclose(pipe);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  std::ifstream err(err_path);
  std::ostringstream ss;
  ss << err.rdbuf();
  r.err = ss.str();
  std::filesystem::remove(err_path);
  return r;
}

/// Runs `hapticpd ARGS` (in `cwd` when one is given).
inline RunResult RunCli(const std::string& args, const std::filesystem::path& cwd = {}) {
  return RunExecutable(HAPTICPD_CLI_PATH, args, cwd);
}

}  // namespace hapticpd::testing
