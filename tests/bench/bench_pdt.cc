// PDt benchmark: replays scripted probe trajectories sampled at 1 kHz (1 ms
// per frame) that press into a scene's surface, slide while pressed and come
// back out, and times pd::ComputePdt on every frame with one PdQueryData per
// benchmark carried across frames (motion coherence, as in the servo loop).
// On the same poses it times FCL's mesh-mesh collide with all contacts
// enabled, the usual substitute for PD. The three benchmarks (the seed
// paper's) and their trajectories are set up in client/bench/scenarios.h.
//
// Prints per benchmark: triangles, frames, penetrating frames, PDt
// p50/p99/p99.9/max (µs), mean iterations and contacts, FCL all-contacts
// p50/p99 and the PDt/FCL ratio, against the goal p50 <= 100 µs and
// p99 <= 500 µs, and writes a summary CSV (--csv FILE, default bench_pdt.csv)
// and optionally one row per frame (--frames-csv FILE). No assertions on time.
//
//   ./build/release/tests/bench/bench_pdt [--models DIR] [--frames N] [--csv FILE]
//                                         [--frames-csv FILE] [--benchmark NAME]
// Under callgrind each PD call is a dump of its own (callgrind_frame.h).
//
// Without ../shared/models the bunny and the statue are replaced by
// procedural torus knots (and the output says so).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <limits>
#include <string>
#include <vector>

#include "pd/geometry_model.h"
#include "pd/pdt.h"
#include "pd/queries.h"
#include "pd/shapes.h"
#include "tests/bench/bench_common.h"
#include "tests/bench/callgrind_frame.h"

namespace hp = hapticpd;
namespace pd = hapticpd::pd;
using hp::Pose;
using hp::Vec3;

namespace {

constexpr double kGoalP50Us = 100;
constexpr double kGoalP99Us = 500;

using hp::bench::Benchmark;
using hp::bench::Percentile;
using hp::bench::Us;

// ---------------------------------------------------------------------------
// Replay

/// The heading of the per-frame CSV (--frames-csv).
constexpr char kFramesCsvHeader[] =
    "benchmark,frame,phase,commanded_m,status,depth_m,escape_m,iterations,contacts,"
    "pdt_us,fcl_contacts,fcl_us\n";

struct FrameRecord {
  double pdt_us = 0, fcl_us = 0;
  int iterations = 0, contacts = 0, fcl_contacts = 0;
  pd::PdStatus status = pd::PdStatus::kFailed;
  double depth = 0;
  /// Translation straight back along the pressing normal that separates the
  /// probe (exact CCD; NaN if not computed). The exact PDt never exceeds it.
  double escape = std::numeric_limits<double>::quiet_NaN();
  Vec3 translation = Vec3::Zero();
  /// The answer pose, nudged 1e-5 x the smaller size further along the PD
  /// direction, still collides: the answer is not a contact configuration.
  bool answer_not_free = false;
};

/// PDt's times, iterations and contacts in the base; the rest here.
struct Summary : hp::bench::SummaryBase {
  int not_free = 0;
  int fcl_colliding = 0, missed_vs_fcl = 0;
  double fcl_p50 = 0, fcl_p99 = 0, fcl_mean_contacts = 0;
  double max_depth = 0;
  /// Largest change of the PD vector between consecutive penetrating frames
  /// (m): the probe moves micrometres per frame, so a jump here is a force
  /// discontinuity the user feels.
  double max_jump = 0;
  int max_jump_frame = -1;
  int worse_than_escape = 0;  ///< frames with PDt depth > 1.001 x the escape along the normal
  double median_escape_ratio = 0, max_escape_ratio = 0;  ///< PDt depth / escape
};

Summary Replay(const Benchmark& b, std::vector<FrameRecord>* records) {
  const Pose X_WB = Pose::Identity();
  records->assign(b.frames.size(), {});
  pd::PdQueryData data;
  pd::PenetrationRequest request;
  pd::PenetrationResult result;
  for (std::size_t i = 0; i < b.frames.size(); ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    {
      const hp::bench::CallgrindFrame cg("pdt", i);
      pd::ComputePdt(*b.probe, b.frames[i].X_WA, *b.scene, X_WB, request, &data, &result);
    }
    const auto t1 = std::chrono::steady_clock::now();
    FrameRecord& r = (*records)[i];
    r.pdt_us = Us(t0, t1);
    r.iterations = result.iterations;
    r.contacts = static_cast<int>(result.features.size());
    r.status = result.status;
    r.depth = result.depth;
    r.translation = result.translation_W;
  }
  // Reference answer, untimed: the escape straight back along the normal.
  {
    pd::QueryScratch scratch;
    pd::CcdResult ccd;
    const pd::CcdRequest ccd_request;
    pd::CollisionResult collision;
    const pd::CollisionRequest collision_request;
    const double far = b.probe->mesh().size() + b.scene->mesh().size();
    const double nudge = 1e-5 * std::min(b.probe->mesh().size(), b.scene->mesh().size());
    for (std::size_t i = 0; i < b.frames.size(); ++i) {
      FrameRecord& r = (*records)[i];
      if (r.status == pd::PdStatus::kSeparated) continue;
      if (r.status != pd::PdStatus::kFailed && r.depth > 0) {
        Pose X = b.frames[i].X_WA;
        X.t += r.translation * (1 + nudge / r.depth);
        r.answer_not_free =
            pd::Collide(*b.probe, X, *b.scene, X_WB, collision_request, &collision, &scratch);
      }
      Pose X0 = b.frames[i].X_WA;
      X0.t += b.n_start * far;
      if (pd::Collide(*b.probe, X0, *b.scene, X_WB, collision_request, &collision, &scratch)) {
        continue;
      }
      const bool hit = pd::TranslationalCcd(*b.probe, X0, -far * b.n_start, *b.scene, X_WB,
                                            ccd_request, &ccd, &scratch);
      (*records)[i].escape = hit ? far * (1 - ccd.toi) : 0.0;
    }
  }
  hp::bench::TimeFclAllContacts(b, X_WB, records, &FrameRecord::fcl_us, &FrameRecord::fcl_contacts);

  Summary s;
  hp::bench::BeginSummary(b, records->size(), &s);
  std::vector<double> pdt, fcl, ratios;
  long iterations = 0, contacts = 0, fcl_contacts = 0;
  for (std::size_t i = 0; i < records->size(); ++i) {
    const FrameRecord& r = (*records)[i];
    pdt.push_back(r.pdt_us);
    fcl.push_back(r.fcl_us);
    hp::bench::CountFrame(r.pdt_us, r.status, &s);
    if (r.fcl_contacts > 0) {
      ++s.fcl_colliding;
      fcl_contacts += r.fcl_contacts;
      // FCL sees intersecting surfaces: PDt must not call that separated.
      if (r.status == pd::PdStatus::kSeparated) ++s.missed_vs_fcl;
    }
    if (r.status == pd::PdStatus::kSeparated) continue;
    ++s.penetrating;
    if (i > 0 && (*records)[i - 1].status != pd::PdStatus::kSeparated) {
      const double jump = (r.translation - (*records)[i - 1].translation).norm();
      if (jump > s.max_jump) {
        s.max_jump = jump;
        s.max_jump_frame = static_cast<int>(i);
      }
    }
    if (r.answer_not_free) ++s.not_free;
    iterations += r.iterations;
    contacts += r.contacts;
    s.max_depth = std::max(s.max_depth, r.depth);
    if (r.escape > 0) {
      ratios.push_back(r.depth / r.escape);
      s.max_escape_ratio = std::max(s.max_escape_ratio, r.depth / r.escape);
      if (r.depth > 1.001 * r.escape) ++s.worse_than_escape;
    }
  }
  hp::bench::FinishSummary(pdt, iterations, contacts, kGoalP50Us, kGoalP99Us, &s);
  s.fcl_p50 = Percentile(fcl, 0.5);
  s.fcl_p99 = Percentile(fcl, 0.99);
  s.fcl_mean_contacts = hp::bench::MeanOver(static_cast<double>(fcl_contacts), s.fcl_colliding);
  s.median_escape_ratio = Percentile(ratios, 0.5);
  return s;
}

}  // namespace

int main(int argc, char** argv) {
  hp::bench::BenchRun run;
  if (!hp::bench::StartRun(argc, argv, "bench_pdt", HAPTICPD_MODELS_DIR, kFramesCsvHeader, &run)) {
    return 2;
  }
  const std::vector<Summary> summaries = hp::bench::ReplayAll<Summary, FrameRecord>(
      &run, Replay,
      [&](const Benchmark& b, const std::vector<FrameRecord>& records, const Summary& s) {
        // The slowest frames, to see where the time goes.
        for (std::size_t i : hp::bench::SlowestFrames(records, &FrameRecord::pdt_us, 3)) {
          const FrameRecord& r = records[i];
          hp::bench::PrintSlowFrameStart(b, i)
              << std::setprecision(1) << r.pdt_us << " us, " << pd::ToString(r.status) << ", depth "
              << std::setprecision(3) << r.depth * 1e3 << " mm (escape along "
              << "the normal " << r.escape * 1e3 << " mm, commanded press "
              << b.frames[i].commanded * 1e3 << " mm), " << r.iterations << " iterations, "
              << r.contacts << " contacts\n";
        }
        if (s.failed > 0 || s.missed_vs_fcl > 0 || s.cap_reached > 0 || s.worse_than_escape > 0 ||
            s.not_free > 0) {
          std::cout << "   WARNING: " << s.failed << " failed, " << s.cap_reached
                    << " cap-reached, " << s.not_free
                    << " answers still colliding when nudged past the contact, " << s.missed_vs_fcl
                    << " frames FCL finds intersecting but PDt calls separated, "
                    << s.worse_than_escape
                    << " frames with a PDt depth above the escape straight back along the normal "
                    << "(worst " << std::setprecision(2) << s.max_escape_ratio << "x)\n";
        }
        if (s.max_jump_frame >= 0) {
          const auto& prev = records[s.max_jump_frame - 1];
          const auto& cur = records[s.max_jump_frame];
          std::cout << "   largest PD jump between consecutive frames: " << std::setprecision(3)
                    << s.max_jump * 1e3 << " mm at frame " << s.max_jump_frame << " (depth "
                    << prev.depth * 1e3 << " -> " << cur.depth * 1e3 << " mm, "
                    << pd::ToString(prev.status) << " -> " << pd::ToString(cur.status) << ")\n";
        }
      },
      [](std::ostream& csv, const FrameRecord& r) {
        csv << "," << r.escape << "," << r.iterations << "," << r.contacts << ","
            << std::setprecision(3) << r.pdt_us << "," << r.fcl_contacts << "," << r.fcl_us << "\n";
      });

  std::cout
      << "\nPDt per frame (us) vs FCL collide with all contacts on the same poses; goal p50 <= "
      << kGoalP50Us << " us, p99 <= " << kGoalP99Us << " us\n";
  hp::bench::PrintTableHeadStart();
  std::cout << std::setw(6) << "fail" << std::setw(6) << "cap" << std::setw(10) << "FCL p50"
            << std::setw(10) << "FCL p99" << std::setw(8) << "ratio" << std::setw(10) << "depth/esc"
            << std::setw(6) << ">esc"
            << "  goal\n";
  std::ofstream out(run.args.csv);
  out << hp::bench::CsvHeadStart("pdt")
      << ",failed,cap_reached,fcl_colliding_frames,missed_vs_fcl,fcl_mean_contacts,fcl_p50_us,"
         "fcl_p99_us,ratio_p50,answers_not_free,max_depth_m,max_pd_jump_m,median_depth_over_escape,"
         "max_depth_"
         "over_escape,"
         "frames_above_escape,goal_met\n";
  for (const Summary& s : summaries) {
    const double ratio = s.fcl_p50 > 0 ? s.p50 / s.fcl_p50 : 0;
    hp::bench::PrintTableRowStart(s);
    std::cout << std::setw(6) << s.failed << std::setw(6) << s.cap_reached << std::setw(10)
              << s.fcl_p50 << std::setw(10) << s.fcl_p99 << std::setprecision(2) << std::setw(8)
              << ratio << std::setw(10) << s.median_escape_ratio << std::setw(6)
              << s.worse_than_escape << "  " << (s.goal_met ? "met" : "NOT met") << "\n";
    hp::bench::WriteCsvRowStart(out, s);
    out << "," << s.failed << "," << s.cap_reached << "," << s.fcl_colliding << ","
        << s.missed_vs_fcl << "," << s.fcl_mean_contacts << "," << s.fcl_p50 << "," << s.fcl_p99
        << "," << ratio << "," << s.not_free << "," << s.max_depth << "," << s.max_jump << ","
        << s.median_escape_ratio << "," << s.max_escape_ratio << "," << s.worse_than_escape << ","
        << (s.goal_met ? 1 : 0) << "\n";
  }
  std::cout << "pen = frames PDt finds penetrating; iters, contacts = means over those; ratio = "
               "PDt p50 / FCL p50 (< 1: PDt faster); depth/esc = median PDt depth over the "
               "escape straight back along the pressing normal (exact CCD; the true PDt is never "
               "larger), >esc = frames where PDt exceeds that escape by over 0.1%\n";
  hp::bench::PrintCsvWritten(run.args.csv, run.args.frames_csv);
  return 0;
}
