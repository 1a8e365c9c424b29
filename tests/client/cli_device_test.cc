// `hapticpd device` and `hapticpd demo` as a user runs them (through popen):
// JSON statistics against a server running in this process, one-line errors
// with a non-zero exit on bad input, and the demo's report and files.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

#include "tests/cli_runner.h"
#include "tests/server/server_harness.h"

namespace hapticpd {
namespace {

using testing::RunCli;
using testing::RunResult;

int Lines(const std::string& s) {
  int n = 0;
  for (char c : s) n += c == '\n';
  return n;
}

TEST(DeviceCli, PressPrintsJsonStatistics) {
  testing::ServerHarness h(testing::Transport::kTcp);
  auto stub = h.Scenes();
  ASSERT_TRUE(
      testing::AddShape(*stub, "default", "box:0.1,0.1,0.05", "box", testing::MakePose(0, 0, 0))
          .ok());
  const std::string server = "--server 127.0.0.1:" + std::to_string(h.server().port());
  const RunResult r = RunCli("device " + server +
                             " --scene default --probe shape:sphere:0.01,2 --mode pdt "
                             "--simulated press --duration 2 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  for (const char* key : {"loop_hz", "period_p99_us", "late_ticks", "updates", "rtt_p50_us",
                          "rtt_p99_us", "max_force", "max_dforce", "energy_j"}) {
    EXPECT_TRUE(j.contains(key)) << key;
  }
  EXPECT_GT(j["updates"].get<double>(), 100);
  EXPECT_GT(j["contact_updates"].get<double>(), 10);
  EXPECT_GT(j["max_force"].get<double>(), 0.5);  // the default start is above the box
  EXPECT_EQ(j["bad_updates"].get<int>(), 0);
  EXPECT_LE(j["rtt_p50_us"].get<double>(), j["rtt_p99_us"].get<double>());
}

TEST(DeviceCli, BadInputIsOneLineAndNonZero) {
  testing::ServerHarness h(testing::Transport::kTcp);
  const std::string base =
      "device --server 127.0.0.1:" + std::to_string(h.server().port()) + " --duration 0.5 ";
  for (const std::string args : {
           "--scene nope --probe shape:stick --simulated press",     // missing scene
           "--scene default --probe shape:stick --simulated dance",  // unknown script
           "--scene default --simulated press",                      // no probe
           "--scene default --probe shape:stick --probe-body b --simulated press",
           "--scene default --probe shape:stick --mode pd --simulated press",
           "--scene default --probe shape:stick",                   // no device
           "--scene default --probe shape:blob --simulated press",  // server refuses
           "--scene default --probe shape:stick --simulated press --start 1,2",
       }) {
    const RunResult r = RunCli(base + args);
    EXPECT_NE(r.exit_code, 0) << args;
    EXPECT_EQ(Lines(r.err), 1) << args << ":\n" << r.err;
    EXPECT_EQ(r.err.rfind("hapticpd: ", 0), 0u) << r.err;
  }
  const RunResult r = RunCli(
      "device --server 127.0.0.1:1 --timeout 1 --scene default --probe shape:stick "
      "--simulated press --duration 0.5");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.err.find("cannot reach"), std::string::npos) << r.err;
}

TEST(DemoCli, ReportsAndWritesTraceAndPlot) {
  const std::filesystem::path out =
      std::filesystem::temp_directory_path() / ("hapticpd_demo_test_" + std::to_string(::getpid()));
  std::filesystem::remove_all(out);
  const RunResult r = RunCli("demo --duration 1.5 --out '" + out.string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err << r.out;
  EXPECT_NE(r.out.find("PDt"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("PDg"), std::string::npos) << r.out;
  std::ifstream csv(out / "trace.csv");
  std::string header;
  ASSERT_TRUE(std::getline(csv, header));
  EXPECT_EQ(header, "mode,t_s,px,py,pz,fx,fy,fz,tx,ty,tz");
  int pdt = 0, pdg = 0;
  for (std::string line; std::getline(csv, line);) {
    pdt += line.rfind("pdt,", 0) == 0;
    pdg += line.rfind("pdg,", 0) == 0;
  }
  EXPECT_GT(pdt, 1000);
  EXPECT_GT(pdg, 1000);
  std::ifstream svg(out / "force.svg");
  std::ostringstream ss;
  ss << svg.rdbuf();
  EXPECT_NE(ss.str().find("<svg"), std::string::npos);
  EXPECT_NE(ss.str().find("</svg>"), std::string::npos);
  std::filesystem::remove_all(out);
}

}  // namespace
}  // namespace hapticpd
