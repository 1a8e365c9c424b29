#include "client/bench/accuracy.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <ostream>
#include <random>

#include "client/bench/ground_truth.h"
#include "client/bench/scenarios.h"
#include "client/bench/svg.h"
#include "pd/convex.h"
#include "pd/convex_hull.h"
#include "pd/pdg.h"
#include "pd/queries.h"
#include "pd/shapes.h"
#include "tests/oracles/bullet_oracle.h"
#include "tests/oracles/fcl_oracle.h"

namespace hapticpd::bench {

namespace {

constexpr double kNudge = 1e-5;  // answers are verified pushed this much further out

struct Setting {
  std::string sweep, label;
  pd::PenetrationRequest request;
  bool is_default = false;
};

std::vector<Setting> Settings(pd::PdMode mode, bool convex) {
  std::vector<Setting> out;
  const pd::PenetrationRequest def;
  out.push_back({"default", "default", def, true});
  pd::PenetrationRequest base = def;
  if (convex) base.convex_shortcut = false;  // the general iteration on convex pairs
  for (int cap : {1, 2, 4, 12, 32}) {
    if (cap == def.max_iterations && !convex) continue;  // that is the default
    pd::PenetrationRequest r = base;
    r.max_iterations = cap;
    out.push_back({convex ? "iteration (no convex shortcut)" : "iteration cap",
                   "cap " + std::to_string(cap), r, false});
  }
  if (convex) {
    pd::PenetrationRequest r = base;
    r.use_coherence = false;
    out.push_back({"iteration (no convex shortcut)", "no coherence", r, false});
    return out;
  }
  for (double eps : {1e-5, 1e-3, 1e-2}) {
    pd::PenetrationRequest r = base;
    r.contact_epsilon = eps;
    char buf[32];
    std::snprintf(buf, sizeof(buf), "eps %g", eps);
    out.push_back({"contact epsilon", buf, r, false});
  }
  {
    pd::PenetrationRequest r = base;
    r.use_coherence = false;
    out.push_back({"coherence", "coherence off", r, false});
    r.cold_start_directions = 1;
    out.push_back({"coherence", "coherence off, 1 start dir", r, false});
  }
  if (mode == pd::PdMode::kGeneralized) {
    pd::PenetrationRequest r = base;
    r.pdg_always_pdt_start = true;
    out.push_back({"coherence", "always PDt start", r, false});
    for (std::uint64_t budget : {std::uint64_t{0}, std::uint64_t{2000}, std::uint64_t{32000}}) {
      pd::PenetrationRequest rb = base;
      rb.pdg_iteration_budget = budget;
      out.push_back({"iteration work budget",
                     budget == 0 ? std::string("no budget") : "budget " + std::to_string(budget),
                     rb, false});
    }
  }
  return out;
}

/// Indices of `count` frames spread evenly over those where `outcomes`
/// penetrate.
std::vector<std::size_t> PickPoses(const std::vector<FrameOutcome>& outcomes, int count) {
  std::vector<std::size_t> pen;
  for (std::size_t i = 0; i < outcomes.size(); ++i) {
    if (Penetrating(outcomes[i].status) && outcomes[i].depth > 0) pen.push_back(i);
  }
  std::vector<std::size_t> out;
  if (pen.empty() || count <= 0) return out;
  for (int k = 0; k < count; ++k) {
    const std::size_t j = (2 * static_cast<std::size_t>(k) + 1) * pen.size() / (2 * count);
    if (out.empty() || out.back() != pen[j]) out.push_back(pen[j]);
  }
  return out;
}

struct Run {
  Setting setting;
  std::vector<FrameOutcome> outcomes;
  TimingSummary timing;
};

/// Free by FCL, and not inside the scene (FCL does not see containment).
struct FreeCheck {
  const Benchmark& b;
  const testing::FclModel& fa;
  const testing::FclModel& fb;
  pd::QueryScratch scratch;
  pd::CollisionResult collision;
  pd::CollisionRequest request;
  bool operator()(const Pose& X) {
    if (testing::FclCollide(fa, X, fb, Pose::Identity())) return false;
    return !pd::Collide(*b.probe, X, *b.scene, Pose::Identity(), request, &collision, &scratch);
  }
};

AccuracyPoint MakePoint(const Benchmark& b, const std::string& mode, const Run& run,
                        const std::vector<std::size_t>& poses, const std::vector<double>& reference,
                        const std::string& ref_kind, bool absolute,
                        const std::vector<bool>& unverified) {
  AccuracyPoint p;
  p.benchmark = b.name;
  p.mode = mode;
  p.sweep = run.setting.sweep;
  p.setting = run.setting.label;
  p.is_default = run.setting.is_default;
  p.reference = ref_kind;
  p.p50_us = run.timing.p50_us;
  p.p99_us = run.timing.p99_us;
  p.mean_iterations = run.timing.mean_iterations;
  p.scene_triangles = b.scene->mesh().num_triangles();
  std::vector<double> err;
  for (std::size_t k = 0; k < poses.size(); ++k) {
    if (!(reference[k] > 0) || reference[k] >= 1e300) continue;
    const FrameOutcome& o = run.outcomes[poses[k]];
    double e = 1;
    if (Penetrating(o.status)) {
      e = (o.depth - reference[k]) / reference[k];
      e = absolute ? std::abs(e) : std::max(0.0, e);
    } else {
      ++p.failed;
    }
    err.push_back(e);
    if (k < unverified.size() && unverified[k]) ++p.unverified;
  }
  p.poses = static_cast<int>(err.size());
  double sum = 0;
  for (double e : err) sum += e;
  p.err_mean = err.empty() ? 0 : sum / static_cast<double>(err.size());
  p.err_median = Percentile(err, 0.5);
  p.err_max = Percentile(err, 1.0);
  return p;
}

/// Non-convex case: all settings of one mode, references by sampling.
/// Returns the per-pose reference (for the resolution sweep).
std::vector<double> SweepNonConvex(const Benchmark& b, pd::PdMode mode, const AccuracyOptions& o,
                                   std::mt19937_64& rng, AccuracyReport* report,
                                   std::vector<std::size_t>* poses_out, std::ostream* log) {
  const bool pdt = mode == pd::PdMode::kTranslational;
  const std::string mode_name = pdt ? "pdt" : "pdg";
  std::vector<Run> runs;
  for (const Setting& s : Settings(mode, false)) {
    Run r{s, ReplayPd(*b.probe, *b.scene, b.frames, mode, s.request), {}};
    r.timing = Summarize(r.outcomes, true);
    runs.push_back(std::move(r));
  }
  const std::vector<std::size_t> poses = PickPoses(runs[0].outcomes, o.poses);
  *poses_out = poses;
  const testing::FclModel fa(b.probe->mesh()), fb(b.scene->mesh());
  FreeCheck free{b, fa, fb, {}, {}, {}};
  free.request.containment = true;
  const double far = 2 * (b.probe->mesh().size() + b.scene->mesh().size());
  const pd::MassProperties& mp = b.probe->mass();
  const Vec3 p_AC = mp.p_MC;
  // A PDt answer (translation) is a rigid motion too: a PDg candidate.
  std::vector<FrameOutcome> pdt_default;
  if (!pdt) pdt_default = ReplayPd(*b.probe, *b.scene, b.frames, pd::PdMode::kTranslational, {});
  std::vector<double> reference(poses.size(), 1e300);
  std::vector<std::vector<bool>> unverified(runs.size(), std::vector<bool>(poses.size(), false));
  std::vector<double> default_over_sampling;
  int below = 0;
  for (std::size_t k = 0; k < poses.size(); ++k) {
    const Pose& X = b.frames[poses[k]].X_WA;
    double best = 1e300;
    std::vector<Vec3> seed_dirs;
    std::vector<Pose> seed_poses;
    for (std::size_t s = 0; s < runs.size(); ++s) {
      const FrameOutcome& out = runs[s].outcomes[poses[k]];
      if (!Penetrating(out.status) || !(out.depth > 0)) continue;
      const Pose nudged = pdt ? Pose{X.R, X.t + out.translation_W * (1 + kNudge)}
                              : pd::InterpolateRigid(X, out.X_WA_result, p_AC, 1 + kNudge);
      if (free(nudged)) {
        best = std::min(best, out.depth * (1 + kNudge));
      } else {
        unverified[s][k] = true;
      }
      seed_dirs.push_back(out.translation_W);
      seed_poses.push_back(out.X_WA_result);
    }
    if (!pdt) {
      const FrameOutcome& t = pdt_default[poses[k]];
      if (Penetrating(t.status) && t.depth > 0) {
        const Pose moved{X.R, X.t + t.translation_W * (1 + kNudge)};
        if (free(moved)) best = std::min(best, t.depth * (1 + kNudge));
        seed_poses.push_back(Pose{X.R, X.t + t.translation_W});
      }
    }
    BoundOptions bo;
    bo.seed_directions = seed_dirs;
    bo.accept = [&free](const Pose& Y) { return free(Y); };
    const double sampled =
        pdt ? PdtUpperBound(fa, X, fb, far, rng, o.pdt_directions, bo)
            : PdgUpperBound(fa, mp, X, fb, far, rng, o.pdg_rotations, o.pdg_directions,
                            15.0 * M_PI / 180.0, seed_poses, bo);
    best = std::min(best, sampled);
    reference[k] = best;
    const FrameOutcome& def = runs[0].outcomes[poses[k]];
    if (sampled < 1e300 && Penetrating(def.status)) {
      default_over_sampling.push_back(def.depth / sampled);
      below += def.depth < sampled;
    }
  }
  if (pdt) {
    report->pdt_reference_poses += static_cast<int>(poses.size());
    report->default_below_sampling += below;
  } else {
    report->pdg_reference_poses += static_cast<int>(poses.size());
    report->pdg_default_below_sampling += below;
  }
  if (log != nullptr) {
    *log << "accuracy: " << b.name << " " << mode_name << ": " << runs.size() << " settings, "
         << poses.size() << " reference poses, default/sampling-bound median "
         << Percentile(default_over_sampling, 0.5) << "\n";
  }
  for (std::size_t s = 0; s < runs.size(); ++s) {
    report->points.push_back(MakePoint(b, mode_name, runs[s], poses, reference, "best-upper-bound",
                                       false, unverified[s]));
  }
  // Store the medians of default / sampling bound in the report (last wins
  // per mode; the notes list each benchmark's).
  char buf[200];
  std::snprintf(buf, sizeof(buf),
                "%s %s: default answer / pure sampling bound: median %.5f over %zu poses (%d below "
                "the bound)",
                b.name.c_str(), mode_name.c_str(), Percentile(default_over_sampling, 0.5),
                default_over_sampling.size(), below);
  report->notes.push_back(buf);
  return reference;
}

void SweepConvex(const AccuracyOptions& o, AccuracyReport* report, std::ostream* log) {
  Benchmark b;
  b.name = "convex-spoon-cup";
  b.probe_name = "hull of spoon";
  b.scene_name = "hull of cup";
  const int res = o.tiny ? 1 : 4;
  b.probe = pd::MakeModel(pd::ConvexHull(pd::shapes::Spoon(res).vertices(), "spoon hull"));
  b.scene = pd::MakeModel(pd::ConvexHull(pd::shapes::Cup(res).vertices(), "cup hull"));
  b.up = Vec3::UnitZ();
  b.tip_dir_A = Vec3::UnitX();
  b.slide = 0.006;
  MakeTrajectory(&b, o.frames, o.max_slope);
  std::vector<Run> runs;
  for (const Setting& s : Settings(pd::PdMode::kTranslational, true)) {
    Run r{s, ReplayPd(*b.probe, *b.scene, b.frames, pd::PdMode::kTranslational, s.request), {}};
    r.timing = Summarize(r.outcomes, true);
    runs.push_back(std::move(r));
  }
  const std::vector<std::size_t> poses = PickPoses(runs[0].outcomes, 4 * o.poses);
  const testing::BulletHull ba(b.probe->mesh()), bb(b.scene->mesh());
  std::vector<double> exact(poses.size());
  for (std::size_t k = 0; k < poses.size(); ++k) {
    const Pose& X = b.frames[poses[k]].X_WA;
    exact[k] = pd::ConvexPdt(b.probe->mesh(), X, b.scene->mesh(), Pose::Identity()).depth;
    const testing::EpaResult e = testing::BulletPenetration(ba, X, bb, Pose::Identity());
    if (exact[k] > 0) {
      report->bullet_vs_exact_max =
          std::max(report->bullet_vs_exact_max, std::abs(e.depth - exact[k]) / exact[k]);
    }
  }
  report->convex_poses += static_cast<int>(poses.size());
  for (const Run& r : runs) {
    report->points.push_back(MakePoint(b, "pdt", r, poses, exact, "exact", true, {}));
  }
  if (log != nullptr) {
    *log << "accuracy: " << b.name << ": " << poses.size() << " poses, Bullet EPA vs exact max "
         << report->bullet_vs_exact_max << "\n";
  }
}

/// Mesh resolution: the benchmark's scene decimated (and the full model),
/// the same poses, default settings; error against the full-resolution
/// reference.
void SweepResolution(const Benchmark& b, pd::PdMode mode, const std::vector<pd::ModelPtr>& scenes,
                     const std::vector<std::size_t>& poses, const std::vector<double>& reference,
                     AccuracyReport* report) {
  const std::string mode_name = mode == pd::PdMode::kTranslational ? "pdt" : "pdg";
  for (const pd::ModelPtr& scene : scenes) {
    Benchmark coarse = b;
    coarse.scene = scene;
    Run r{{"mesh resolution", std::to_string(scene->mesh().num_triangles()) + " tris", {}, false},
          ReplayPd(*b.probe, *scene, b.frames, mode, {}),
          {}};
    r.timing = Summarize(r.outcomes, true);
    report->points.push_back(
        MakePoint(coarse, mode_name, r, poses, reference, "full-resolution", true, {}));
  }
}

}  // namespace

AccuracyReport RunAccuracy(const AccuracyOptions& o, std::ostream* log) {
  AccuracyReport report;
  std::mt19937_64 rng(o.seed);
  std::vector<Benchmark> benchmarks = BuildBenchmarks(o.models, o.tiny);
  for (Benchmark& b : benchmarks) {
    for (const std::string& n : b.notes) report.notes.push_back(b.name + ": " + n);
    MakeTrajectory(&b, o.frames, o.max_slope);
    // Mesh resolution on the first benchmark (stick vs bunny): 1K, 5K, 20K
    // and the full model, decimated with OpenMesh.
    std::vector<pd::ModelPtr> coarse;
    if (&b == &benchmarks.front()) {
      const std::size_t full = b.scene->mesh().num_triangles();
      const std::vector<std::size_t> targets = o.tiny ? std::vector<std::size_t>{full / 4, full / 2}
                                                      : std::vector<std::size_t>{1000, 5000, 20000};
      for (std::size_t t : targets) {
        if (t >= full) continue;
        int skipped = 0;
        coarse.push_back(
            pd::MakeModel(Decimate(b.scene->mesh(), t, b.scene_name + " decimated", &skipped)));
      }
    }
    for (const pd::PdMode mode : {pd::PdMode::kTranslational, pd::PdMode::kGeneralized}) {
      std::vector<std::size_t> poses;
      const std::vector<double> reference = SweepNonConvex(b, mode, o, rng, &report, &poses, log);
      if (coarse.empty()) continue;
      // The full model too, so that the resolution series ends at it.
      std::vector<pd::ModelPtr> scenes = coarse;
      scenes.push_back(b.scene);
      SweepResolution(b, mode, scenes, poses, reference, &report);
    }
  }
  SweepConvex(o, &report, log);
  return report;
}

nlohmann::json ToJson(const AccuracyReport& r) {
  nlohmann::json points = nlohmann::json::array();
  for (const AccuracyPoint& p : r.points) {
    points.push_back({{"benchmark", p.benchmark},
                      {"mode", p.mode},
                      {"sweep", p.sweep},
                      {"setting", p.setting},
                      {"default", p.is_default},
                      {"reference", p.reference},
                      {"scene_triangles", p.scene_triangles},
                      {"poses", p.poses},
                      {"p50_us", p.p50_us},
                      {"p99_us", p.p99_us},
                      {"mean_iterations", p.mean_iterations},
                      {"error_mean", p.err_mean},
                      {"error_median", p.err_median},
                      {"error_max", p.err_max},
                      {"failed", p.failed},
                      {"unverified", p.unverified}});
  }
  return {{"points", points},
          {"notes", r.notes},
          {"convex_check",
           {{"poses", r.convex_poses}, {"bullet_vs_exact_max_relative", r.bullet_vs_exact_max}}},
          {"sampling_bound",
           {{"pdt_poses", r.pdt_reference_poses},
            {"pdt_default_below_bound", r.default_below_sampling},
            {"pdg_poses", r.pdg_reference_poses},
            {"pdg_default_below_bound", r.pdg_default_below_sampling}}}};
}

void PrintAccuracy(std::ostream& os, const AccuracyReport& r) {
  char buf[512];
  std::snprintf(buf, sizeof(buf), "%-18s %-4s %-30s %-28s %5s %9s %9s %6s %10s %10s %10s %4s %4s\n",
                "benchmark", "mode", "sweep", "setting", "poses", "p50 us", "p99 us", "iters",
                "err mean", "err med", "err max", "fail", "unv");
  os << buf;
  for (const AccuracyPoint& p : r.points) {
    std::snprintf(
        buf, sizeof(buf),
        "%-18s %-4s %-30s %-28s %5d %9.1f %9.1f %6.2f %9.4f%% %9.4f%% %9.4f%% %4d %4d%s\n",
        p.benchmark.c_str(), p.mode.c_str(), p.sweep.c_str(), p.setting.c_str(), p.poses, p.p50_us,
        p.p99_us, p.mean_iterations, 100 * p.err_mean, 100 * p.err_median, 100 * p.err_max,
        p.failed, p.unverified, p.is_default ? "  <- default" : "");
    os << buf;
  }
  os << "times over the penetrating frames of the trajectory; error against: the exact "
        "separating-axis PDt (convex pair), the best known upper bound (sampling and every "
        "setting's FCL-verified answer) or the full-resolution reference (mesh resolution); "
        "fail = reference poses not found penetrating (error counted as 100%); unv = answers "
        "FCL did not confirm free\n";
  std::snprintf(buf, sizeof(buf),
                "convex check: Bullet GJK/EPA vs exact separating axes, max relative difference "
                "%.2e over %d poses\n",
                r.bullet_vs_exact_max, r.convex_poses);
  os << buf;
  for (const std::string& n : r.notes) os << n << "\n";
}

std::vector<std::filesystem::path> WriteAccuracySvgs(const std::filesystem::path& dir,
                                                     const AccuracyReport& r,
                                                     const std::string& title) {
  static const char* kColors[] = {"#000000", "#1f5fbf", "#c0392b", "#27ae60",
                                  "#8e44ad", "#d35400", "#16a085"};
  constexpr double kFloor = 1e-4;  // % : zero error is drawn here
  std::vector<std::filesystem::path> out;
  for (const std::string mode : {"pdt", "pdg"}) {
    svg::Figure fig;
    fig.title = title;
    fig.panel_height = 300;
    fig.width = 900;
    std::vector<std::string> benchmarks;
    for (const AccuracyPoint& p : r.points) {
      if (p.mode == mode &&
          std::find(benchmarks.begin(), benchmarks.end(), p.benchmark) == benchmarks.end()) {
        benchmarks.push_back(p.benchmark);
      }
    }
    for (const std::string& bname : benchmarks) {
      svg::Panel& panel = fig.panels.emplace_back();
      panel.title = (mode == "pdt" ? "PDt" : "PDg") + std::string(" on ") + bname +
                    ": mean relative error (%) vs p50 time (us); default ringed";
      panel.x_label = "p50 time per query over penetrating frames (us, log)";
      panel.y_label = "mean error % (log; 0 drawn at 1e-4)";
      panel.log_x = panel.log_y = true;
      panel.y_min = kFloor;
      panel.pareto_frontier = true;
      std::map<std::string, std::size_t> by_sweep;
      for (const AccuracyPoint& p : r.points) {
        if (p.mode != mode || p.benchmark != bname) continue;
        auto it = by_sweep.find(p.sweep);
        if (it == by_sweep.end()) {
          it = by_sweep.emplace(p.sweep, panel.series.size()).first;
          svg::Series& s = panel.series.emplace_back();
          s.label = p.sweep + (p.reference == "exact"             ? " (vs exact)"
                               : p.reference == "full-resolution" ? " (vs full-res reference)"
                                                                  : "");
          s.color = kColors[it->second % 7];
          s.line = false;
        }
        svg::Series& s = panel.series[it->second];
        s.x.push_back(std::max(p.p50_us, 1e-3));
        s.y.push_back(std::max(100 * p.err_mean, kFloor));
        s.point_labels.push_back(p.setting);
        s.highlight.push_back(p.is_default);
      }
    }
    const std::filesystem::path path = dir / ("accuracy_" + mode + ".svg");
    svg::Write(path, fig);
    out.push_back(path);
  }
  return out;
}

}  // namespace hapticpd::bench
