// End-to-end tests of the `hapticpd` executable: runs the built binary
// (HAPTICPD_CLI_PATH) through the shell and checks exit codes, stdout (JSON
// where asked) and the one-line error on stderr.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "tests/cli_runner.h"
#include "tests/readme_table.h"
#include "tests/test_util.h"

namespace hapticpd::testing {
namespace {

nlohmann::json Json(const RunResult& r) {
  try {
    return nlohmann::json::parse(r.out);
  } catch (const std::exception& e) {
    ADD_FAILURE() << "stdout is not JSON (" << e.what() << "):\n" << r.out;
    return {};
  }
}

/// Bad input: non-zero exit, nothing on stdout, exactly one line on stderr
/// that contains `what`.
void ExpectOneLineError(const std::string& args, const std::string& what) {
  SCOPED_TRACE("hapticpd " + args);
  const RunResult r = RunCli(args);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_EQ(r.out, "");
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << "stderr: " << r.err;
  EXPECT_FALSE(r.err.empty() || r.err.back() != '\n') << "stderr: " << r.err;
  EXPECT_NE(r.err.find(what), std::string::npos) << "stderr: " << r.err;
  EXPECT_EQ(r.err.rfind("hapticpd: ", 0), 0u) << "stderr: " << r.err;
}

// Two boxes with unit half extents; the probe at x = 1.5 overlaps the scene
// box by 0.5 along x, and 1.5 along y and z: PDt = 0.5 along +x.
constexpr char kBoxes[] = "pd --probe shape:box:1,1,1 --scene shape:box:1,1,1";
constexpr double kTol = 1e-9;

TEST(CliTest, Version) {
  const RunResult r = RunCli("version");
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_EQ(r.out.rfind("hapticpd ", 0), 0u) << r.out;
  EXPECT_EQ(r.err, "");
}

TEST(CliTest, MeshInfoHelp) {
  const RunResult r = RunCli("mesh-info --help");
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_NE(r.out.find("--shape"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("--json"), std::string::npos) << r.out;
}

TEST(CliTest, MeshInfoJson) {
  const RunResult r = RunCli("mesh-info --shape box:0.1,0.2,0.3 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = Json(r);
  EXPECT_EQ(j.value("triangles", 0), 12);
  EXPECT_EQ(j.value("vertices", 0), 8);
  EXPECT_TRUE(j.value("watertight", false));
  EXPECT_NEAR(j.value("volume", 0.0), 0.2 * 0.4 * 0.6, 1e-12);
}

TEST(CliTest, MeshInfoFile) {
  const RunResult r =
      RunCli(std::string("mesh-info '") + HAPTICPD_TESTDATA_DIR + "/good/tetra.obj' --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(Json(r).value("triangles", 0), 4);
}

TEST(CliTest, PdHelpDocumentsDeepestBody) {
  const RunResult r = RunCli("pd --help");
  EXPECT_EQ(r.exit_code, 0);
  for (const char* s :
       {"--probe", "--scene", "--pose", "--scene-pose", "--mode", "--json", "--stiffness",
        "--epsilon", "--max-iterations", "--pdg-budget", "--cold-directions", "DEEPEST"}) {
    EXPECT_NE(r.out.find(s), std::string::npos) << s << " missing from:\n" << r.out;
  }
}

// A stored cold pose (tests/data/cold/procedural.json, hammer vs torus knot
// at 12.1 % of the hammer's size) whose reference, an upper bound sampled
// with FCL in 2,000 directions and refined, is 0.0395515 m. The centroid
// direction alone ends in another basin 2.67 times as deep; the default cold
// search ends within 1 %.
TEST(CliTest, PdColdSearchFindsTheShallowBasin) {
  const std::string cmd =
      "pd --probe shape:hammer:2 --scene shape:torusknot:2,3,0.25,0.06,420,24 --pose '"
      "0.16806746228033353 0.14968197841278252 -0.0315605302233079 0.22192018099856578 "
      "-0.8453027898745131 -0.41544160958579035 0.25223579389273104' --json";
  constexpr double kReference = 0.0395515236028198;
  const RunResult all = RunCli(cmd);
  ASSERT_EQ(all.exit_code, 0) << all.err;
  EXPECT_LE(Json(all)["depth"].get<double>(), 1.01 * kReference);
  const RunResult one = RunCli(cmd + " --cold-directions 1");
  ASSERT_EQ(one.exit_code, 0) << one.err;
  EXPECT_GT(Json(one)["depth"].get<double>(), 2 * kReference);
}

TEST(CliTest, PdBoxOverlapKnownDepth) {
  const RunResult r = RunCli(std::string(kBoxes) + " --pose '1.5 0 0 1 0 0 0' --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = Json(r);
  EXPECT_TRUE(j.value("colliding", false));
  EXPECT_EQ(j.value("mode", ""), "pdt");
  EXPECT_EQ(j.value("status", ""), "penetrating-solved");
  EXPECT_NEAR(j.value("depth", -1.0), 0.5, kTol);
  const auto t = j["translation"].get<std::vector<double>>();
  ASSERT_EQ(t.size(), 3u);
  EXPECT_NEAR(t[0], 0.5, kTol);
  EXPECT_NEAR(t[1], 0.0, kTol);
  EXPECT_NEAR(t[2], 0.0, kTol);
  const auto p = j["result_pose"].get<std::vector<double>>();
  ASSERT_EQ(p.size(), 7u);
  const double expected[7] = {2.0, 0, 0, 1, 0, 0, 0};
  for (int i = 0; i < 7; ++i) EXPECT_NEAR(p[i], expected[i], kTol) << "result_pose[" << i << "]";
  // Two boxes are convex: the exact separating-axis answer, no iteration.
  EXPECT_EQ(j.value("iterations", -1), 0);
  EXPECT_GE(j.value("contacts", 0), 1);
  EXPECT_GT(j.value("time_us", 0.0), 0.0);
  ASSERT_TRUE(j["regions"].is_array());
  EXPECT_FALSE(j["regions"].empty());
  EXPECT_GT(j["force"][0].get<double>(), 0.0);  // pushed out along +x
  ASSERT_EQ(j["bodies"].size(), 1u);
  const auto& b = j["bodies"][0];
  EXPECT_EQ(b.value("body", -1), 0);
  EXPECT_EQ(b.value("source", ""), "shape:box:1,1,1");
  EXPECT_EQ(b.value("status", ""), "penetrating-solved");
  EXPECT_NEAR(b.value("depth", -1.0), 0.5, kTol);
  EXPECT_FALSE(b.contains("failure"));
}

// One planar face contact is one region with the full depth, so the penalty
// force is k * 0.5 along +x; by symmetry there is no torque about the
// probe's centre of mass.
TEST(CliTest, PdBoxOverlapWrench) {
  const RunResult r =
      RunCli(std::string(kBoxes) + " --pose '1.5 0 0 1 0 0 0' --stiffness 2000 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = Json(r);
  EXPECT_EQ(j.value("stiffness", 0.0), 2000.0);
  const auto f = j["force"].get<std::vector<double>>();
  const auto tau = j["torque"].get<std::vector<double>>();
  ASSERT_EQ(f.size(), 3u);
  ASSERT_EQ(tau.size(), 3u);
  EXPECT_NEAR(f[0], 1000.0, 1e-6);
  EXPECT_NEAR(f[1], 0.0, 1e-6);
  EXPECT_NEAR(f[2], 0.0, 1e-6);
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(tau[i], 0.0, 1e-6) << "torque[" << i << "]";
  ASSERT_EQ(j["regions"].size(), 1u);
  const auto& reg = j["regions"][0];
  EXPECT_NEAR(reg.value("depth", -1.0), 0.5, kTol);
  EXPECT_NEAR(reg["normal"][0].get<double>(), 1.0, kTol);
  EXPECT_EQ(reg.value("body", -1), 0);
}

// The rotation of the probe does not matter for a cube rotated by 90 degrees
// about z; the translation is still 0.5 along +x.
TEST(CliTest, PdRotatedProbe) {
  const RunResult r = RunCli(
      std::string(kBoxes) + " --pose '1.5 0 0 0.70710678118654757 0 0 0.70710678118654757' --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = Json(r);
  EXPECT_EQ(j.value("status", ""), "penetrating-solved");
  EXPECT_NEAR(j.value("depth", -1.0), 0.5, kTol);
  EXPECT_NEAR(j["translation"][0].get<double>(), 0.5, kTol);
  const auto p = j["result_pose"].get<std::vector<double>>();
  ASSERT_EQ(p.size(), 7u);
  EXPECT_NEAR(p[3], std::sqrt(0.5), 1e-12);
  EXPECT_NEAR(p[6], std::sqrt(0.5), 1e-12);
}

// Metamorphic: moving both bodies by the same translation changes nothing
// but the result pose.
TEST(CliTest, PdCommonTranslation) {
  const RunResult r = RunCli(std::string(kBoxes) +
                             " --pose '11.5 -3 2 1 0 0 0' --scene-pose '10 -3 2 1 0 0 0' --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = Json(r);
  EXPECT_EQ(j.value("status", ""), "penetrating-solved");
  EXPECT_NEAR(j.value("depth", -1.0), 0.5, kTol);
  EXPECT_NEAR(j["translation"][0].get<double>(), 0.5, kTol);
  EXPECT_NEAR(j["result_pose"][0].get<double>(), 12.0, kTol);
}

// PDg: a bar 2 m long tilted by 0.05 rad about y dips its +x end 0.05 m into
// a slab. Turning it flat (about -y) is cheaper than lifting it, so
// sqrt(sigma) is below the PDt depth; the answer pose carries the rotation
// and the torque xi theta omega turns the +x end up (negative y component).
constexpr char kTiltedBar[] =
    "pd --probe shape:box:1,0.2,0.1 --scene shape:box:2,2,1 "
    "--pose '0.3 0.2 1.1 0.99968751627570263 0 0.024997395914712332 0'";

TEST(CliTest, PdgTiltedBarTurnsFlat) {
  const RunResult rt = RunCli(std::string(kTiltedBar) + " --json");
  const RunResult rg =
      RunCli(std::string(kTiltedBar) + " --mode pdg --rotational-stiffness 2 --json");
  ASSERT_EQ(rt.exit_code, 0) << rt.err;
  ASSERT_EQ(rg.exit_code, 0) << rg.err;
  const nlohmann::json t = Json(rt), g = Json(rg);
  EXPECT_EQ(g.value("mode", ""), "pdg");
  EXPECT_TRUE(g.value("colliding", false));
  EXPECT_FALSE(t.contains("sigma"));
  const double pdt = t.value("depth", -1.0), pdg = g.value("depth", -1.0);
  EXPECT_GT(pdg, 0.0);
  EXPECT_LT(pdg, 0.9 * pdt);
  EXPECT_NEAR(g.value("sigma", -1.0), pdg * pdg, 1e-12);
  const double angle = g.value("rotation_angle", -1.0);
  EXPECT_GT(angle, 0.01);
  const auto axis = g["rotation_axis"].get<std::vector<double>>();
  ASSERT_EQ(axis.size(), 3u);
  EXPECT_NEAR(std::hypot(axis[0], axis[1], axis[2]), 1.0, 1e-9);
  EXPECT_LT(axis[1], -0.9);
  // result_pose is the full answer: its quaternion differs from the input's
  // by the reported rotation.
  const auto p = g["result_pose"].get<std::vector<double>>();
  ASSERT_EQ(p.size(), 7u);
  EXPECT_NEAR(std::hypot(std::hypot(p[3], p[4]), std::hypot(p[5], p[6])), 1.0, 1e-9);
  const double dot = p[3] * 0.99968751627570263 + p[5] * 0.024997395914712332;
  EXPECT_NEAR(2 * std::acos(std::min(1.0, std::abs(dot))), angle, 1e-6);
  EXPECT_NEAR(g.value("rotational_stiffness", 0.0), 2.0, 0);
  const auto tau = g["torque"].get<std::vector<double>>();
  EXPECT_NEAR(tau[1], 2.0 * angle * axis[1], 1e-9);
  EXPECT_GT(g["force"][2].get<double>(), 0.0);
  ASSERT_EQ(g["bodies"].size(), 1u);
  EXPECT_NEAR(g["bodies"][0].value("sigma", -1.0), pdg * pdg, 1e-12);
  EXPECT_TRUE(g["bodies"][0].contains("rotation_axis"));
  // The human-readable form names the rotation.
  const RunResult rh = RunCli(std::string(kTiltedBar) + " --mode pdg");
  ASSERT_EQ(rh.exit_code, 0) << rh.err;
  for (const char* s : {"mode         pdg", "sigma", "rotation", "xi ="}) {
    EXPECT_NE(rh.out.find(s), std::string::npos) << s << " missing from:\n" << rh.out;
  }
}

TEST(CliTest, PdSeparated) {
  const RunResult r = RunCli(std::string(kBoxes) + " --pose '2.5 0 0 1 0 0 0' --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = Json(r);
  EXPECT_FALSE(j.value("colliding", true));
  EXPECT_EQ(j.value("status", ""), "separated");
  EXPECT_EQ(j.value("depth", -1.0), 0.0);
  EXPECT_EQ(j["translation"], nlohmann::json({0.0, 0.0, 0.0}));
  EXPECT_EQ(j["force"], nlohmann::json({0.0, 0.0, 0.0}));
  EXPECT_EQ(j["torque"], nlohmann::json({0.0, 0.0, 0.0}));
  EXPECT_EQ(j["result_pose"], nlohmann::json({2.5, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0}));
  EXPECT_TRUE(j["regions"].empty());
  ASSERT_EQ(j["bodies"].size(), 1u);
  EXPECT_EQ(j["bodies"][0].value("status", ""), "separated");
}

// Two scene bodies: the first (moved by --scene-pose to x = 0.3) overlaps the
// probe at x = -1.5 by 0.2, the second (identity) by 0.5. The top level
// reports the deeper one; the wrench and counters sum over both.
TEST(CliTest, PdTwoBodiesReportsDeepest) {
  const RunResult r = RunCli(std::string(kBoxes) +
                             " --scene shape:box:1,1,1 --scene-pose '0.3 0 0 1 0 0 0'"
                             " --pose '-1.5 0 0 1 0 0 0' --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = Json(r);
  ASSERT_EQ(j["bodies"].size(), 2u);
  const auto& b0 = j["bodies"][0];
  const auto& b1 = j["bodies"][1];
  EXPECT_NEAR(b0.value("depth", -1.0), 0.2, kTol);
  EXPECT_NEAR(b1.value("depth", -1.0), 0.5, kTol);
  EXPECT_NEAR(b0["translation"][0].get<double>(), -0.2, kTol);
  EXPECT_TRUE(j.value("colliding", false));
  EXPECT_EQ(j.value("deepest_body", -1), 1);
  EXPECT_NEAR(j.value("depth", -1.0), 0.5, kTol);
  EXPECT_NEAR(j["translation"][0].get<double>(), -0.5, kTol);
  EXPECT_NEAR(j["result_pose"][0].get<double>(), -2.0, kTol);
  EXPECT_EQ(j.value("iterations", 0), b0.value("iterations", 0) + b1.value("iterations", 0));
  EXPECT_EQ(j.value("contacts", 0), b0.value("contacts", 0) + b1.value("contacts", 0));
  EXPECT_LT(j["force"][0].get<double>(), 0.0);
  int regions_of[2] = {0, 0};
  for (const auto& reg : j["regions"]) ++regions_of[reg.value("body", 0)];
  EXPECT_EQ(regions_of[0], b0.value("regions", -1));
  EXPECT_EQ(regions_of[1], b1.value("regions", -1));
}

TEST(CliTest, PdMeshFileProbe) {
  // The tetrahedron's file frame is the probe frame: its pose is applied to
  // the file's coordinates. Far away from the box it is separated.
  const RunResult r = RunCli(std::string("pd --probe '") + HAPTICPD_TESTDATA_DIR +
                             "/good/tetra.obj' --scene shape:box --pose '5 5 5 1 0 0 0' --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_FALSE(Json(r).value("colliding", true));
}

TEST(CliTest, PdHumanReadable) {
  const RunResult r = RunCli(std::string(kBoxes) + " --pose '1.5 0 0 1 0 0 0'");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* s : {"colliding", "penetrating-solved", "depth", "0.5", "force", "torque",
                        "iterations", "body 0"}) {
    EXPECT_NE(r.out.find(s), std::string::npos) << s << " missing from:\n" << r.out;
  }
}

TEST(CliTest, PdBadInput) {
  const std::string ok_pose = " --pose '1.5 0 0 1 0 0 0'";
  ExpectOneLineError("pd --probe /nonexistent/probe.obj --scene shape:box" + ok_pose,
                     "/nonexistent/probe.obj: no such file");
  ExpectOneLineError("pd --probe shape:box --scene /nonexistent/scene.stl" + ok_pose,
                     "/nonexistent/scene.stl: no such file");
  ExpectOneLineError(std::string("pd --probe '") + HAPTICPD_TESTDATA_DIR +
                         "/bad/nan_vertex.obj' --scene shape:box" + ok_pose,
                     "non-finite");
  ExpectOneLineError("pd --probe shape:nosuchshape --scene shape:box" + ok_pose,
                     "unknown shape 'nosuchshape'");
  ExpectOneLineError(std::string(kBoxes) + " --pose '1.5 0 0 1 0 0'", "expected 7 numbers");
  ExpectOneLineError(std::string(kBoxes) + " --pose '1.5 0 0 1 0 0 0 0'", "got 8");
  ExpectOneLineError(std::string(kBoxes) + " --pose '1.5 0 0 1 0 0 1'",
                     "quaternion (w x y z) has norm 1.41421356, expected 1");
  ExpectOneLineError(std::string(kBoxes) + " --pose '1.5 0 0 1.002 0 0 0'",
                     "has norm 1.002, expected 1 (within 1e-3)");
  ExpectOneLineError(std::string(kBoxes) + " --pose '1.5 nan 0 1 0 0 0'",
                     "ty is nan, expected a finite number");
  ExpectOneLineError(std::string(kBoxes) + " --pose '1.5 0 0 inf 0 0 0'", "qw is inf");
  ExpectOneLineError(std::string(kBoxes) + " --pose '1.5 0 0 1 0 0 x'", "'x' is not a number");
  ExpectOneLineError(std::string(kBoxes) + " --pose '1.5;0 0 1 0 0 0'", "is not a number");
  ExpectOneLineError(std::string(kBoxes) + ok_pose + " --scene-pose '0 0 0 0.5 0 0 0'",
                     "--scene-pose 0: quaternion (w x y z) has norm 0.5");
  ExpectOneLineError(
      std::string(kBoxes) + ok_pose + " --scene-pose '0 0 0 1 0 0 0' --scene-pose '1 0 0 1 0 0 0'",
      "2 --scene-pose given for 1 --scene");
  ExpectOneLineError(std::string(kBoxes) + ok_pose + " --mode foo", "valid modes: pdt, pdg");
  ExpectOneLineError(std::string(kBoxes) + ok_pose + " --mode pdg --rotational-stiffness 0",
                     "--rotational-stiffness");
  ExpectOneLineError(std::string(kBoxes) + ok_pose + " --stiffness 0", "--stiffness");
  ExpectOneLineError(std::string(kBoxes) + ok_pose + " --stiffness -5", "positive");
  ExpectOneLineError(std::string(kBoxes) + ok_pose + " --epsilon -1e-4", "--epsilon");
  ExpectOneLineError(std::string(kBoxes) + ok_pose + " --epsilon nan", "--epsilon");
  ExpectOneLineError(std::string(kBoxes) + ok_pose + " --max-iterations 0", "--max-iterations");
  ExpectOneLineError(std::string(kBoxes) + ok_pose + " --mode pdg --pdg-budget -1",
                     "--pdg-budget: must be a non-negative integer");
  ExpectOneLineError(std::string(kBoxes) + ok_pose + " --mode pdg --pdg-budget 1e3", "got '1e3'");
  ExpectOneLineError(std::string(kBoxes) + ok_pose + " --cold-directions 0", "--cold-directions");
  ExpectOneLineError(std::string(kBoxes) + ok_pose + " --cold-directions 4097",
                     "--cold-directions must be at most 4096");
  ExpectOneLineError("pd --scene shape:box" + ok_pose, "--probe");
  ExpectOneLineError("pd --probe shape:box" + ok_pose, "--scene");
  ExpectOneLineError(std::string(kBoxes), "--pose");
  ExpectOneLineError(std::string(kBoxes) + ok_pose + " --no-such-flag", "--no-such-flag");
}

// tests/README.md "Bad input", "CLI": every row is a case here, its input
// and the whole line the user gets on stderr (exit code 1, nothing on
// stdout). Run from the repository root, so that the paths in the messages
// are the relative ones a user types. HAPTICPD_PRINT_TABLE=1 prints the rows
// (tests/update_tables.py).
TEST(CliTest, BadInputTable) {
  struct Case {
    std::string what;  // the bad input (README markdown)
    std::string args;
    std::string err;  // the whole of stderr but its newline
  };
  const std::string boxes_at = std::string(kBoxes) + " --pose ";
  const std::string box_scene = " --scene shape:box --pose '1.5 0 0 1 0 0 0'";
  // `mesh-info FILE`: the message names the file first.
  auto file = [](std::string what, const std::string& rel, const std::string& msg) {
    return Case{std::move(what), "mesh-info " + rel, "hapticpd: " + rel + ": " + msg};
  };
  const Case cases[] = {
      {"missing file", "pd --probe /nonexistent/probe.obj" + box_scene,
       "hapticpd: /nonexistent/probe.obj: no such file"},
      {"NaN in `--pose`", boxes_at + "'1.5 nan 0 1 0 0 0'",
       "hapticpd: --pose: ty is nan, expected a finite number"},
      {"quaternion not unit", boxes_at + "'1.5 0 0 1 0 0 1'",
       "hapticpd: --pose: quaternion (w x y z) has norm 1.41421356, expected 1 (within 1e-3)"},
      {"wrong number count", boxes_at + "'1.5 0 0 1 0 0'",
       "hapticpd: --pose: expected 7 numbers \"tx ty tz qw qx qy qz\", got 6"},
      {"unknown shape", "pd --probe shape:nosuchshape" + box_scene,
       "hapticpd: shape spec 'nosuchshape': unknown shape 'nosuchshape'; known shapes: box, "
       "sphere, capsule, cylinder, stick, torus, torusknot, plate, spoon, cup, hammer"},
      file("empty file", "tests/data/bad/empty.obj", "file is empty"),
      file("NaN vertex (OBJ)", "tests/data/bad/nan_vertex.obj",
           "line 3: vertex has a non-finite coordinate (v nan 1 0)"),
      file("infinite vertex (OFF)", "tests/data/bad/infinite_vertex.off",
           "line 4: vertex 1 has a non-finite coordinate (1e400)"),
      file("OBJ face corner without a vertex index (`f /x/`, also after a tab: `f<TAB>/x/`; "
           "OpenMesh's reader would abort the process)",
           "tests/fuzz/corpus/mesh_obj/crash-openmesh-face-assert-tab.obj",
           "line 1: face corner '/" + std::string(9, '?') +  // 9 bytes shown as '?'
               "/' does not start with a vertex index"),
      file("index out of range", "tests/data/bad/index_out_of_range.obj",
           "face 0 refers to vertex 8, out of range [0, 3)"),
      file("no faces", "tests/data/bad/no_faces.obj", "no faces found"),
      file("only degenerate faces", "tests/data/bad/degenerate_only.obj",
           "no non-degenerate triangles (the reader skipped all 2 face(s): repeated or invalid "
           "vertex indices)"),
      file("truncated OFF", "tests/data/bad/truncated.off",
           "line 5: vertex 2 has 2 numbers, expected 3"),
      file("truncated STL", "tests/data/bad/truncated.stl",
           "not a valid STL: binary header says 1000 triangles (50084 bytes) but the file has 184 "
           "bytes, and it is not ASCII STL"),
      file("garbage STL", "tests/data/bad/garbage.stl",
           "not a valid STL: binary header says 1303066130 triangles (65153306584 bytes) but the "
           "file has 600 bytes, and it is not ASCII STL"),
      file("truncated PLY", "tests/data/bad/truncated.ply",
           "truncated after line 12: the header promises 8 vertex elements, the file holds 3"),
      file("garbage PLY", "tests/data/bad/garbage.ply",
           "not a valid PLY: missing the 'ply' magic line"),
      file("unknown extension", "tests/data/bad/unknown.xyz",
           "unsupported extension '.xyz' (supported: .obj, .off, .stl, .ply)"),
  };
  const std::filesystem::path root =
      std::filesystem::path(HAPTICPD_TESTDATA_DIR).parent_path().parent_path();
  for (const Case& c : cases) {
    SCOPED_TRACE("hapticpd " + c.args);
    const RunResult r = RunCli(c.args, root);
    EXPECT_EQ(r.exit_code, 1);
    EXPECT_EQ(r.out, "");
    EXPECT_EQ(r.err, c.err + "\n");
    PrintTableRow({c.what}, c.err);
  }
}

// The network commands and `device` build their TLS credentials the same
// way: an unreadable CA file is one line naming it, before any connection.
TEST(CliTest, UnreadableTlsCaIsOneLineForEveryNetworkCommand) {
  const std::string ca = " --tls-ca /nonexistent/ca.pem";
  const std::string what = "--tls-ca: cannot open /nonexistent/ca.pem";
  ExpectOneLineError("scene list" + ca, what);
  ExpectOneLineError("device --scene s --probe shape:sphere:0.01" + ca, what);
}

}  // namespace
}  // namespace hapticpd::testing
