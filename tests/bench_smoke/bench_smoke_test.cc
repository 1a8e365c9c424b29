// The code paths of `hapticpd bench` and `hapticpd-bench` (client/bench/) on
// tiny inputs: small procedural meshes and a few frames, so that they cannot
// rot. Asserts
// structure and sanity (fields present, errors >= 0, reference bounds not
// below exact answers), never wall-clock time. `bench delay` runs in real
// time by nature; its tests look at the output's structure only.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>
#include <regex>
#include <set>
#include <sstream>
#include <stdexcept>

#include "client/bench/accuracy.h"
#include "client/bench/ground_truth.h"
#include "client/bench/peers.h"
#include "client/bench/scenarios.h"
#include "client/bench/svg.h"
#include "client/bench/table1.h"
#include "pd/convex.h"
#include "pd/pdg.h"
#include "pd/pdt.h"
#include "pd/shapes.h"
#include "tests/cli_runner.h"
#include "tests/oracles/fcl_oracle.h"
#include "tests/test_util.h"

namespace hapticpd::bench {
namespace {

/// Runs the executable at `path`, with HAPTICPD_MODELS_DIR set to `models`
/// unless empty.
testing::RunResult RunWithModels(const std::string& path, const std::string& args,
                                 const std::string& models) {
  if (models.empty()) return testing::RunExecutable(path, args);
  const char* old = std::getenv("HAPTICPD_MODELS_DIR");
  const std::string saved = old != nullptr ? old : "";
  ::setenv("HAPTICPD_MODELS_DIR", models.c_str(), 1);
  testing::RunResult r = testing::RunExecutable(path, args);
  if (old != nullptr) {
    ::setenv("HAPTICPD_MODELS_DIR", saved.c_str(), 1);
  } else {
    ::unsetenv("HAPTICPD_MODELS_DIR");
  }
  return r;
}

/// Runs hapticpd (bench table1, bench delay).
testing::RunResult RunCli(const std::string& args, const std::string& models = "") {
  return RunWithModels(HAPTICPD_CLI_PATH, args, models);
}

/// Runs hapticpd-bench (peers, accuracy, cold: the benchmarks with the oracles).
testing::RunResult RunBenchCli(const std::string& args, const std::string& models = "") {
  return RunWithModels(HAPTICPD_BENCH_CLI_PATH, args, models);
}

std::vector<Benchmark> TinyBenchmarks(int frames) {
  std::vector<Benchmark> b = BuildBenchmarks("", /*tiny=*/true);
  for (Benchmark& x : b) MakeTrajectory(&x, frames);
  return b;
}

TEST(BenchScenarios, TinyBenchmarksHaveTrajectoriesThatPress) {
  const std::vector<Benchmark> benchmarks = TinyBenchmarks(24);
  ASSERT_EQ(benchmarks.size(), 3u);
  std::set<std::string> names;
  for (const Benchmark& b : benchmarks) {
    names.insert(b.name);
    EXPECT_EQ(b.frames.size(), 24u);
    EXPECT_LT(b.scene->mesh().num_triangles(), 2000u) << b.name;
    const auto out = ReplayPd(*b.probe, *b.scene, b.frames, pd::PdMode::kTranslational, {});
    const TimingSummary s = Summarize(out, false);
    EXPECT_EQ(s.frames, 24);
    EXPECT_GT(s.penetrating, 0) << b.name << ": the trajectory never presses in";
    EXPECT_LT(s.penetrating, 24) << b.name << ": the trajectory never leaves the surface";
    EXPECT_EQ(s.failed, 0);
    EXPECT_LE(s.p50_us, s.p99_us);
    EXPECT_LE(s.p99_us, s.max_us);
  }
  EXPECT_EQ(names, (std::set<std::string>{"stick-bunny", "spoon-cup", "hammer-beast20k"}));
}

// The Table-1 trajectories on the shared models: with the default slope
// limit the tip moves like a hand sliding on the surface (well under a
// millimetre a frame, 1 m/s); following the raw height under it, the hammer
// jumps centimetres where the downward ray passes an edge of the statue.
// Release preset only: under the sanitizers loading and decimating the shared
// models alone takes about 25 s, and the trajectory code is plain geometry
// (the PD code on these trajectories runs under them in pd_tests).
TEST(BenchScenarios, SharedModelTrajectoriesHaveNoJumpsUnlessAskedFor) {
  if (testing::kSanitized) GTEST_SKIP() << "release preset only (shared models are slow to load)";
  HAPTICPD_REQUIRE_MODEL(beast, "beast.obj");
  std::vector<Benchmark> benchmarks = BuildBenchmarks(beast.parent_path().string());
  ASSERT_EQ(benchmarks.size(), 3u);
  auto largest_step = [](const Benchmark& b) {
    double step = 0;
    for (std::size_t i = 1; i < b.frames.size(); ++i) {
      // The tip is where the probe's pose takes the same body point each
      // frame; the motion of the probe's origin bounds it well enough here,
      // with the slow tilt's share (10 degrees over 2,000 frames) tiny.
      step = std::max(step, (b.frames[i].X_WA.t - b.frames[i - 1].X_WA.t).norm());
    }
    return step;
  };
  for (Benchmark& b : benchmarks) {
    SCOPED_TRACE(b.name);
    MakeTrajectory(&b, 2000);
    EXPECT_LT(largest_step(b), 1e-3);
  }
  Benchmark& hammer = benchmarks.at(2);
  ASSERT_EQ(hammer.name, "hammer-beast20k");
  MakeTrajectory(&hammer, 2000, std::numeric_limits<double>::infinity());
  EXPECT_GT(largest_step(hammer), 0.05);
  EXPECT_THROW(MakeTrajectory(&hammer, 2000, -1), std::invalid_argument);
}

TEST(BenchScenarios, MaxSlopeIsANumberAtLeastZeroOrInf) {
  double slope = -7;
  EXPECT_EQ(ParseMaxSlope("0.5", &slope), "");
  EXPECT_EQ(slope, 0.5);
  EXPECT_EQ(ParseMaxSlope("inf", &slope), "");
  EXPECT_TRUE(std::isinf(slope));
  for (const char* bad : {"", "x", "1x", "-1", "nan"}) {
    slope = 3;
    EXPECT_EQ(ParseMaxSlope(bad, &slope),
              std::string("must be a number >= 0 (inf: no limit), got '") + bad + "'")
        << bad;
    EXPECT_EQ(slope, 3) << bad;
  }
}

TEST(BenchScenarios, PercentileIsNearestRank) {
  EXPECT_EQ(Percentile({}, 0.5), 0);
  EXPECT_EQ(Percentile({3, 1, 2}, 0.5), 2);
  EXPECT_EQ(Percentile({3, 1, 2}, 1.0), 3);
  EXPECT_EQ(Percentile({3, 1, 2}, 0.0), 1);
}

TEST(BenchTable1, RowsPerBenchmarkAndModeWithSeedNumbers) {
  const auto rows = RunTable1(TinyBenchmarks(16));
  ASSERT_EQ(rows.size(), 6u);
  for (const Table1Row& r : rows) {
    EXPECT_TRUE(r.mode == "pdt" || r.mode == "pdg");
    EXPECT_EQ(r.timing.frames, 16);
    EXPECT_GT(r.timing.penetrating, 0);
    EXPECT_GT(r.timing.mean_contacts, 0);
    EXPECT_GE(r.timing.mean_iterations, 1);
    EXPECT_GT(r.seed_ms, 0) << r.benchmark;
    EXPECT_TRUE(r.stand_in || r.benchmark == "spoon-cup");
  }
  const nlohmann::json j = ToJson(rows);
  ASSERT_TRUE(j.is_array());
  for (const auto& o : j) {
    for (const char* key : {"benchmark", "mode", "triangles", "frames", "p50_us", "p99_us",
                            "max_us", "mean_contacts", "mean_iterations", "seed_ms"}) {
      EXPECT_TRUE(o.contains(key)) << key;
    }
  }
  const auto csv = std::filesystem::temp_directory_path() / "hapticpd_bench_smoke_table1.csv";
  WriteTable1Csv(csv.string(), rows);
  std::ifstream f(csv);
  int lines = 0;
  for (std::string line; std::getline(f, line);) ++lines;
  EXPECT_EQ(lines, 7);
  std::filesystem::remove(csv);
}

TEST(BenchGroundTruth, SampledBoundsOnAConvexPairBracketTheExactAnswer) {
  const pd::ModelPtr A = pd::MakeModel(pd::shapes::Box(Vec3(0.02, 0.03, 0.04)));
  const pd::ModelPtr B = pd::MakeModel(pd::shapes::Box(Vec3(0.1, 0.1, 0.05)));
  const testing::FclModel fa(A->mesh()), fb(B->mesh());
  const Pose X{Eigen::AngleAxisd(0.3, Vec3(1, 2, 3).normalized()).toRotationMatrix(),
               Vec3(0.01, -0.02, 0.075)};
  const double exact = pd::ConvexPdt(A->mesh(), X, B->mesh(), Pose::Identity()).depth;
  ASSERT_GT(exact, 0.001);
  std::mt19937_64 rng(testing::TestSeed());
  const double far = 1.0;
  // Plain sampling: never below the exact answer, close above it.
  const double sampled = SampledUpperBound(fa, X, fb, far, rng, 200);
  EXPECT_GE(sampled, exact * (1 - 1e-9));
  EXPECT_LE(sampled, exact * 1.05);
  // Pruned sampling seeded with the answer's direction: as good as the seed.
  const Vec3 t = pd::ConvexPdt(A->mesh(), X, B->mesh(), Pose::Identity()).translation_W;
  const std::vector<Vec3> seeds{t};
  BoundOptions o;
  o.seed_directions = seeds;
  int accepted = 0;
  o.accept = [&accepted](const Pose&) {
    ++accepted;
    return true;
  };
  const double pruned = PdtUpperBound(fa, X, fb, far, rng, 50, o);
  EXPECT_GE(pruned, exact * (1 - 1e-9));
  EXPECT_LE(pruned, exact * (1 + 1e-6));
  EXPECT_GT(accepted, 0);
  // A check that rejects everything leaves no bound.
  o.accept = [](const Pose&) { return false; };
  EXPECT_GE(PdtUpperBound(fa, X, fb, far, rng, 20, o), 1e300);
  // PDg: a rigid motion may rotate too, so sqrt(sigma) <= PDt; never 0.
  o.accept = nullptr;
  const std::vector<Pose> seed_poses{Pose{X.R, X.t + t}};
  const double pdg = PdgUpperBound(fa, A->mass(), X, fb, far, rng, 8, 6, 0.3, seed_poses, o);
  EXPECT_LE(pdg, exact * (1 + 1e-6));
  EXPECT_GT(pdg, 0);
  pd::PdgQueryData data;
  pd::PenetrationResult r;
  pd::ComputePdg(*A, X, *B, Pose::Identity(), {}, &data, &r);
  // The bound is not absurdly low: PDg's answer is a local optimum, and on
  // this pair the sampled bound ends 0.83-1.02 times its depth over seeds
  // 1-30, so a bound under 0.75 of it would mean the sampling accepted
  // poses that are not separating.
  EXPECT_GE(pdg, r.depth * 0.75) << "exact PDt " << exact << " PDg status "
                                 << pd::ToString(r.status) << " iterations " << r.iterations;
}

TEST(BenchAccuracy, TinySweepHasEveryKindOfPointAndSaneErrors) {
  AccuracyOptions o;
  o.tiny = true;
  o.frames = 24;
  o.poses = 2;
  o.pdt_directions = 16;
  o.pdg_rotations = 2;
  o.pdg_directions = 2;
  o.seed = testing::TestSeed();
  const AccuracyReport r = RunAccuracy(o, nullptr);
  std::set<std::string> sweeps;
  int defaults = 0;
  for (const AccuracyPoint& p : r.points) {
    sweeps.insert(p.sweep);
    defaults += p.is_default;
    EXPECT_GE(p.err_mean, 0) << p.benchmark << " " << p.setting;
    EXPECT_GE(p.err_max, p.err_median) << p.benchmark << " " << p.setting;
    EXPECT_GT(p.poses, 0) << p.benchmark << " " << p.setting;
    EXPECT_GT(p.p50_us, 0);
    if (p.reference == "best-upper-bound") {
      // Every answer was checked by FCL; against the best known bound no
      // setting is below it, and the default finds every pose.
      EXPECT_EQ(p.unverified, 0) << p.benchmark << " " << p.setting;
    }
    if (p.is_default) {
      EXPECT_EQ(p.failed, 0) << p.benchmark << " " << p.mode;
    }
    if (p.benchmark == "convex-spoon-cup" && p.is_default) {
      EXPECT_EQ(p.reference, "exact");
      EXPECT_LE(p.err_max, 1e-9);  // the separating-axis answer is exact
    }
  }
  EXPECT_EQ(defaults, 7);  // 3 benchmarks x (PDt, PDg) + the convex pair
  for (const char* s : {"default", "iteration cap", "contact epsilon", "coherence",
                        "mesh resolution", "iteration (no convex shortcut)"}) {
    EXPECT_TRUE(sweeps.count(s)) << s;
  }
  EXPECT_GT(r.convex_poses, 0);
  EXPECT_LT(r.bullet_vs_exact_max, 1e-6);  // Bullet's EPA agrees with the exact answer
  const nlohmann::json j = ToJson(r);
  ASSERT_TRUE(j.contains("points"));
  for (const char* key : {"benchmark", "mode", "sweep", "setting", "default", "p50_us",
                          "error_mean", "error_max", "reference"}) {
    EXPECT_TRUE(j["points"][0].contains(key)) << key;
  }
  // Pareto plots: one marker per point of the mode, the defaults ringed.
  const auto dir = std::filesystem::temp_directory_path() / "hapticpd_bench_smoke_svg";
  std::filesystem::create_directories(dir);
  const auto paths = WriteAccuracySvgs(dir, r, "title: hapticpd bench accuracy --tiny");
  ASSERT_EQ(paths.size(), 2u);
  std::ifstream f(paths[0]);
  std::stringstream ss;
  ss << f.rdbuf();
  const std::string svg = ss.str();
  std::size_t circles = 0, ringed = 0;
  for (std::size_t at = svg.find("<circle"); at != std::string::npos;
       at = svg.find("<circle", at + 1)) {
    ++circles;
  }
  for (std::size_t at = svg.find("stroke-width=\"2\""); at != std::string::npos;
       at = svg.find("stroke-width=\"2\"", at + 1)) {
    ++ringed;
  }
  const auto pdt_points = std::count_if(r.points.begin(), r.points.end(),
                                        [](const AccuracyPoint& p) { return p.mode == "pdt"; });
  EXPECT_EQ(circles, static_cast<std::size_t>(pdt_points));
  EXPECT_EQ(ringed, 4u);  // PDt defaults: three benchmarks and the convex pair
  EXPECT_NE(svg.find("title: hapticpd bench accuracy --tiny"), std::string::npos);
  std::filesystem::remove_all(dir);
}

TEST(BenchPeers, EveryPeerOnEveryBenchmarkWithRatiosAndErrors) {
  const auto rows = RunPeers(TinyBenchmarks(16));
  ASSERT_EQ(rows.size(), 3u * 6u);
  for (const PeerRow& r : rows) {
    EXPECT_EQ(r.frames, 16);
    EXPECT_GT(r.p50_us, 0);
    EXPECT_GT(r.ratio_p50, 0);
    if (r.method == "hapticpd-pdt") {
      EXPECT_DOUBLE_EQ(r.ratio_p50, 1.0);
    }
    if (r.gives_depth && r.method != "hapticpd-pdt") {
      EXPECT_GT(r.compared, 0) << r.method;
      EXPECT_GE(r.err_median, 0);
      EXPECT_GE(r.err_max, r.err_p90);
    }
    // Hulls contain the shapes: their GJK/EPA sees at least every collision.
    if (r.method.find("hulls") != std::string::npos) {
      const auto ours = std::find_if(rows.begin(), rows.end(), [&](const PeerRow& x) {
        return x.benchmark == r.benchmark && x.method == "hapticpd-collide";
      });
      ASSERT_NE(ours, rows.end());
      EXPECT_GE(r.colliding, ours->colliding) << r.benchmark << " " << r.method;
    }
    if (r.method == "fcl-all-contacts") {
      EXPECT_GT(r.mean_contacts, 0);
    }
  }
  const nlohmann::json j = ToJson(rows);
  EXPECT_TRUE(j[2].contains("depth_error_vs_pdt"));
}

TEST(BenchSvg, RendersTitlePanelsAndEscapesText) {
  svg::Figure fig;
  fig.title = "a < b & c";
  svg::Panel& p = fig.panels.emplace_back();
  p.title = "panel";
  p.log_x = p.log_y = true;
  svg::Series& s = p.series.emplace_back();
  s.line = false;
  s.x = {1, 10, 100};
  s.y = {0.1, 1, 10};
  s.point_labels = {"one", "two", "three"};
  s.highlight = {false, true, false};
  const std::string out = svg::Render(fig);
  EXPECT_EQ(out.rfind("<svg", 0), 0u);
  EXPECT_NE(out.find("</svg>"), std::string::npos);
  EXPECT_NE(out.find("a &lt; b &amp; c"), std::string::npos);
  EXPECT_EQ(out.find("a < b"), std::string::npos);
  EXPECT_NE(out.find(">two</text>"), std::string::npos);
}

// Point labels: none overlaps another label or marker, every label is on
// the plot or listed beside it, and the legend sits right of the plot.
TEST(BenchSvg, PointLabelsNeverOverlapAndCrowdedOnesAreListedBesideThePlot) {
  svg::Figure fig;
  svg::Panel& p = fig.panels.emplace_back();
  p.log_x = p.log_y = true;
  svg::Series& s = p.series.emplace_back();
  s.label = "settings";
  s.line = false;
  for (int i = 0; i < 30; ++i) {  // a tight cluster and a few loners
    s.x.push_back(i < 24 ? 100 + i : 10 * (i - 23));
    s.y.push_back(i < 24 ? 0.01 : 1.0 / (i - 22));
    s.point_labels.push_back("setting " + std::to_string(i));
  }
  const std::string out = svg::Render(fig);
  const double plot_right = fig.width - 200;  // the legend column is at least 200 px wide
  struct Label {
    double x, y;
    std::string text;
  };
  std::vector<Label> on_plot;
  int beside = 0;
  const std::regex text_re(
      R"re(<text x="([-0-9.e]+)" y="([-0-9.e]+)" font-size="9"[^>]*>([^<]*)</text>)re");
  for (auto it = std::sregex_iterator(out.begin(), out.end(), text_re);
       it != std::sregex_iterator(); ++it) {
    const double x = std::stod((*it)[1]), y = std::stod((*it)[2]);
    if (x >= plot_right) {
      ++beside;
    } else {
      on_plot.push_back({x, y, (*it)[3]});
    }
  }
  EXPECT_EQ(static_cast<int>(on_plot.size()) + beside, 30);
  EXPECT_GT(beside, 0) << "24 labels cannot all fit around one spot";
  EXPECT_GE(on_plot.size(), 6u);
  // Boxes as the renderer estimates them (0.58 em a character, 11 px high).
  for (std::size_t i = 0; i < on_plot.size(); ++i) {
    for (std::size_t j = i + 1; j < on_plot.size(); ++j) {
      const Label &a = on_plot[i], &b = on_plot[j];
      const double wa = 0.58 * 9 * a.text.size(), wb = 0.58 * 9 * b.text.size();
      const bool overlap =
          a.x < b.x + wb && b.x < a.x + wa && a.y - 9 < b.y + 2 && b.y - 9 < a.y + 2;
      EXPECT_FALSE(overlap) << a.text << " overlaps " << b.text;
    }
  }
  const std::size_t legend = out.find(">settings</text>");
  ASSERT_NE(legend, std::string::npos);
  const std::size_t tag = out.rfind("<text x=\"", legend);
  EXPECT_GE(std::stod(out.substr(tag + 9)), plot_right) << "the legend covers the plot";
}

TEST(BenchSvg, ParetoFrontierIsTheStaircaseOfTheNonDominatedPoints) {
  svg::Figure fig;
  svg::Panel& p = fig.panels.emplace_back();
  p.pareto_frontier = true;
  p.x_min = p.y_min = 0;
  p.x_max = p.y_max = 10;
  svg::Series& s = p.series.emplace_back();
  s.line = false;
  s.x = {1, 2, 3, 4, 5};
  s.y = {5, 3, 4, 1, 2};  // (3, 4) and (5, 2) are dominated
  const std::string out = svg::Render(fig);
  const std::size_t at = out.find("stroke-dasharray=\"4,3\" points=\"");
  ASSERT_NE(at, std::string::npos);
  const std::size_t begin = out.find("points=\"", at) + 8;
  const std::string points = out.substr(begin, out.find('"', begin) - begin);
  std::istringstream is(points);
  std::vector<std::string> pairs{std::istream_iterator<std::string>(is), {}};
  EXPECT_EQ(pairs.size(), 5u) << points;  // three points and the two corners between them
  EXPECT_NE(out.find(">Pareto frontier</text>"), std::string::npos);
}

TEST(BenchSvg, BandsShadeTheirIntervalsWithOneLegendEntry) {
  svg::Figure fig;
  svg::Panel& p = fig.panels.emplace_back();
  p.bands = {{1, 2}, {4, 6}};
  p.band_label = "in contact";
  svg::Series& s = p.series.emplace_back();
  s.x = {0, 10};
  s.y = {0, 1};
  const std::string out = svg::Render(fig);
  int shaded = 0;
  for (std::size_t at = out.find("fill=\"#f3e3b5\""); at != std::string::npos;
       at = out.find("fill=\"#f3e3b5\"", at + 1)) {
    ++shaded;
  }
  EXPECT_EQ(shaded, 3);  // two bands and the legend swatch
  EXPECT_NE(out.find(">in contact</text>"), std::string::npos);
}

// ---------------------------------------------------------------------------
// The command line

TEST(BenchCli, Table1JsonIsAnArrayWithTheDocumentedFields) {
  const auto r = RunCli("bench table1 --tiny --frames 12 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  ASSERT_EQ(j.size(), 6u);
  for (const char* key : {"benchmark", "mode", "triangles", "frames", "p50_us", "p99_us", "max_us",
                          "mean_contacts", "mean_iterations"}) {
    EXPECT_TRUE(j[0].contains(key)) << key;
  }
  EXPECT_EQ(j[0]["frames"], 12);
}

TEST(BenchCli, Table1SaysWhenStandInsReplaceTheModels) {
  const auto r = RunCli("bench table1 --frames 8 --csv /dev/null", "/nonexistent-hapticpd-models");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("NOTE: shared models folder"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("bunny stand-in"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("seed ms"), std::string::npos) << r.out;
}

TEST(BenchCli, AnExplicitModelsFolderThatIsMissingIsAnError) {
  const auto r = RunCli("bench table1 --frames 8 --models /nonexistent-hapticpd-models");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.err.find("--models"), std::string::npos) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
}

TEST(BenchCli, AccuracyWritesTheSvgsAndPeersPrintsJson) {
  const auto dir = std::filesystem::temp_directory_path() / "hapticpd_bench_cli_svg";
  std::filesystem::remove_all(dir);
  const auto a =
      RunBenchCli("accuracy --tiny --frames 16 --poses 1 --json --svg '" + dir.string() + "'");
  ASSERT_EQ(a.exit_code, 0) << a.err;
  const nlohmann::json j = nlohmann::json::parse(a.out);
  EXPECT_GT(j["points"].size(), 20u);
  EXPECT_EQ(j["svg"].size(), 2u);
  EXPECT_TRUE(std::filesystem::exists(dir / "accuracy_pdt.svg"));
  EXPECT_TRUE(std::filesystem::exists(dir / "accuracy_pdg.svg"));
  std::filesystem::remove_all(dir);
  const auto p = RunBenchCli("peers --tiny --frames 8 --json");
  ASSERT_EQ(p.exit_code, 0) << p.err;
  EXPECT_EQ(nlohmann::json::parse(p.out).size(), 18u);
}

TEST(BenchCli, BadArgumentsGetOneLineAndANonZeroExit) {
  for (const char* args :
       {"bench", "bench table1 --frames 0", "bench table1 --frames abc", "bench accuracy --poses 0",
        "bench peers --bogus", "bench accuracy --tiny --frames 8 --svg /proc/hapticpd-no/such",
        "bench table1 --tiny --frames 8 --max-slope x",
        "bench table1 --tiny --frames 8 --max-slope -1"}) {
    const auto r = RunCli(args);
    EXPECT_NE(r.exit_code, 0) << args;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << args << ": " << r.err;
    EXPECT_EQ(r.err.rfind("hapticpd: ", 0), 0u) << args << ": " << r.err;
  }
}

// hapticpd links no oracle: `bench accuracy|peers|cold` say in one line
// which executable runs them.
TEST(BenchCli, TheOracleBenchmarksNameHapticpdBench) {
  for (const char* sub : {"accuracy", "peers", "cold"}) {
    const auto r = RunCli(std::string("bench ") + sub + " --tiny --frames 8 --json");
    EXPECT_NE(r.exit_code, 0) << sub;
    EXPECT_TRUE(r.out.empty()) << sub << ": " << r.out;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << sub << ": " << r.err;
    EXPECT_EQ(r.err.rfind("hapticpd: bench " + std::string(sub), 0), 0u) << r.err;
    EXPECT_NE(r.err.find("run hapticpd-bench " + std::string(sub)), std::string::npos) << r.err;
  }
}

TEST(BenchOracleCli, BadArgumentsGetOneLineAndANonZeroExit) {
  for (const char* args :
       {"", "table1", "accuracy --poses 0", "peers --bogus", "peers --frames 0",
        "accuracy --tiny --frames 8 --svg /proc/hapticpd-no/such", "cold --poses 0",
        "cold --models /nonexistent-hapticpd-models", "cold --out /proc/hapticpd-no/such",
        "peers --tiny --frames 8 --max-slope 1x", "accuracy --tiny --frames 8 --max-slope nan"}) {
    const auto r = RunBenchCli(args);
    EXPECT_NE(r.exit_code, 0) << args;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << args << ": " << r.err;
    EXPECT_EQ(r.err.rfind("hapticpd-bench: ", 0), 0u) << args << ": " << r.err;
  }
}

// `bench delay` runs in real time; a tiny run (two delays, two short
// scripts, the torus knot for the slide) checks the output's structure and
// the plot, never the figures' values or the time taken.
TEST(BenchCli, DelayJsonHasEveryRunFieldAndGoalAndWritesThePlot) {
  const auto dir = std::filesystem::temp_directory_path() / "hapticpd_bench_cli_delay";
  std::filesystem::remove_all(dir);
  const auto r = RunCli(
      "bench delay --delays 0,20 --scripts press,slide,twist --time-scale 0.2 "
      "--json --out '" +
          dir.string() + "'",
      "/nonexistent-hapticpd-models");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["slide_body"], "torusknot");
  ASSERT_EQ(j["runs"].size(), 6u);
  std::set<std::string> scripts;
  for (const nlohmann::json& run : j["runs"]) {
    scripts.insert(run["script"].get<std::string>());
    for (const char* key : {"delay_ms",
                            "jitter_ms",
                            "ticks",
                            "contact_ticks",
                            "peak_force_n",
                            "mean_force_n",
                            "peak_torque_nm",
                            "stiffness_n_per_m",
                            "felt_surface_m",
                            "surface_error_m",
                            "handle_max_depth_m",
                            "proxy_max_depth_m",
                            "passivity_min_j",
                            "passivity_tolerance_j",
                            "energy_into_hand_j",
                            "free_drag_n",
                            "free_ticks",
                            "patch_bytes_per_s",
                            "answered",
                            "rtt_p50_ms",
                            "updates",
                            "late_ticks"}) {
      EXPECT_TRUE(run.contains(key)) << key;
    }
    EXPECT_GT(run["ticks"].get<int>(), 0);
    // The local contact model is on: patches stream, and it answers most
    // contact ticks.
    EXPECT_GT(run["patch_bytes_per_s"].get<double>(), 0.0) << "no patches streamed";
    EXPECT_TRUE(run.contains("local_rate_hz") && run.contains("local_p99_us"));
    EXPECT_EQ(run["jitter_ms"].get<double>(), 0.2 * run["delay_ms"].get<double>());
    if (run["contact_ticks"].get<int>() > 0) {
      const auto& a = run["answered"];
      EXPECT_NEAR(a["server_rows"].get<double>() + a["local_patch"].get<double>() +
                      a["faded"].get<double>() + a["no_rows"].get<double>(),
                  1.0, 1e-9);
      EXPECT_GT(a["local_patch"].get<double>(), 0.0) << run.dump();
    }
  }
  EXPECT_EQ(scripts, (std::set<std::string>{"press", "slide", "twist"}));
  // Without 50/100/200 ms runs only the goals that hold for any delay.
  ASSERT_EQ(j["goals"].size(), 3u);
  for (const nlohmann::json& g : j["goals"]) {
    EXPECT_TRUE(g.contains("met") && g.contains("figures")) << g.dump();
  }
  std::ifstream svg(dir / "delay_force.svg");
  ASSERT_TRUE(svg.good());
  std::stringstream text;
  text << svg.rdbuf();
  for (const char* want : {"<svg", "press", "slide", "twist", "0 ms", "20 ms", "bench delay"}) {
    EXPECT_NE(text.str().find(want), std::string::npos) << want;
  }
  std::filesystem::remove_all(dir);
}

TEST(BenchCli, DelayTableNamesTheGoalsAndTheStandIn) {
  const auto dir = std::filesystem::temp_directory_path() / "hapticpd_bench_cli_delay_table";
  const auto r = RunCli("bench delay --delays 0,50 --scripts press,slide --time-scale 0.1 --out '" +
                            dir.string() + "'",
                        "/nonexistent-hapticpd-models");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* want : {"torus knot", "press", "slide", "peak N", "k N/m", "goals",
                           "50 ms: peak force within 10% of 0 ms", "free space <= 0.05 N",
                           "passive everywhere", "delay_force.svg"}) {
    EXPECT_NE(r.out.find(want), std::string::npos) << want << "\n" << r.out;
  }
  std::filesystem::remove_all(dir);
}

TEST(BenchCli, DelayBadArgumentsGetOneLineAndANonZeroExit) {
  for (const char* args :
       {"bench delay --delays -5", "bench delay --delays abc", "bench delay --delays 0,,5",
        "bench delay --delays 20000", "bench delay --scripts nope", "bench delay --scripts ''",
        "bench delay --time-scale 0", "bench delay --models /nonexistent-hapticpd-models",
        "bench delay --out /proc/hapticpd-no/such"}) {
    const auto r = RunCli(args);
    EXPECT_NE(r.exit_code, 0) << args;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << args << ": " << r.err;
    EXPECT_EQ(r.err.rfind("hapticpd: ", 0), 0u) << args << ": " << r.err;
  }
}

}  // namespace
}  // namespace hapticpd::bench
