// `hapticpd demo --scene FILE.json` as a user runs it (through popen): the
// committed example scene (procedural shapes only), its PD mode and effects,
// and a bad scene file's one-line error naming the key and the file.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "tests/cli_runner.h"

namespace hapticpd::testing {
namespace {

namespace fs = std::filesystem;

fs::path SceneDir() { return fs::path(__FILE__).parent_path().parent_path() / "data" / "scenes"; }

fs::path TempDir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / (name + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

TEST(DemoSceneCli, PenOnDeskRunsItsModeAndEffects) {
  const fs::path out = TempDir("hapticpd_demo_scene");
  const std::string scene = (SceneDir() / "pen_on_desk.json").string();
  const RunResult r =
      RunCli("demo --scene '" + scene + "' --duration 1.5 --out '" + out.string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err << r.out;
  EXPECT_NE(r.out.find("scene 'desk' from"), std::string::npos) << r.out;
  // The file says "mode": "pdt": no PDg run.
  EXPECT_NE(r.out.find("PDt"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("PDg"), std::string::npos) << r.out;
  // No torque declared: the 3-DoF contact stage, then the declared effects.
  EXPECT_NE(r.out.find("servo effects: contact(force) > friction > damping > texture > weight"),
            std::string::npos)
      << r.out;
  std::ifstream csv(out / "trace.csv");
  std::string line;
  ASSERT_TRUE(std::getline(csv, line));
  int rows = 0;
  double max_torque = 0, max_fx = 0, max_fz = 0;
  while (std::getline(csv, line)) {
    std::vector<double> v;
    std::stringstream ss(line.substr(line.find(',') + 1));
    for (std::string cell; std::getline(ss, cell, ',');) v.push_back(std::stod(cell));
    ASSERT_EQ(v.size(), 10u) << line;  // t, p, f, tau
    ++rows;
    max_fx = std::max(max_fx, std::abs(v[4]));
    max_fz = std::max(max_fz, v[6]);
    max_torque = std::max({max_torque, std::abs(v[7]), std::abs(v[8]), std::abs(v[9])});
  }
  EXPECT_GT(rows, 1000);
  EXPECT_GT(max_fz, 0.5);    // pushed up by the desk
  EXPECT_GT(max_fx, 0.1);    // friction against the slide
  EXPECT_EQ(max_torque, 0);  // 3-DoF: no torque ever commanded
  fs::remove_all(out);
}

TEST(DemoSceneCli, BadSceneFileIsOneLineNamingKeyAndFile) {
  const fs::path dir = TempDir("hapticpd_demo_bad");
  const fs::path bad = dir / "bad.json";
  std::ofstream(bad) << R"({"effects": ["contact", "wobble"]})";
  const RunResult r = RunCli("demo --scene '" + bad.string() + "' --duration 1 --out '" +
                             (dir / "out").string() + "'");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  EXPECT_NE(r.err.find(bad.string() + ": effects[1]: unknown effect 'wobble'"), std::string::npos)
      << r.err;
  fs::remove_all(dir);
}

}  // namespace
}  // namespace hapticpd::testing
