#include "client/bench/peers.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <ostream>

#include "pd/convex_hull.h"
#include "pd/queries.h"
#include "tests/oracles/bullet_oracle.h"
#include "tests/oracles/fcl_oracle.h"

namespace hapticpd::bench {

namespace {

using Clock = std::chrono::steady_clock;

/// Times `query` on every frame; it returns whether it found a collision and
/// writes a depth (negative: none).
PeerRow TimePeer(const Benchmark& b, const std::string& method, bool gives_depth,
                 const std::vector<FrameOutcome>& ours,
                 const std::function<bool(const Pose&, double*, int*)>& query) {
  PeerRow row;
  row.benchmark = b.name;
  row.method = method;
  row.gives_depth = gives_depth;
  std::vector<double> us, err, signed_err;
  long contacts = 0;
  for (std::size_t i = 0; i < b.frames.size(); ++i) {
    double depth = -1;
    int n = 0;
    const auto t0 = Clock::now();
    const bool hit = query(b.frames[i].X_WA, &depth, &n);
    us.push_back(Us(t0, Clock::now()));
    ++row.frames;
    row.colliding += hit;
    contacts += n;
    if (gives_depth && Penetrating(ours[i].status) && ours[i].depth > 0) {
      const double d = std::max(0.0, depth);
      err.push_back(std::abs(d - ours[i].depth) / ours[i].depth);
      signed_err.push_back((d - ours[i].depth) / ours[i].depth);
    }
  }
  row.p50_us = Percentile(us, 0.5);
  row.p99_us = Percentile(us, 0.99);
  row.mean_contacts = MeanOver(static_cast<double>(contacts), row.colliding);
  row.compared = static_cast<int>(err.size());
  row.err_median = Percentile(err, 0.5);
  row.err_p90 = Percentile(err, 0.9);
  row.err_max = Percentile(err, 1.0);
  row.signed_median = Percentile(signed_err, 0.5);
  return row;
}

}  // namespace

std::vector<PeerRow> RunPeers(const std::vector<Benchmark>& benchmarks) {
  std::vector<PeerRow> rows;
  for (const Benchmark& b : benchmarks) {
    const Pose I = Pose::Identity();
    const std::vector<FrameOutcome> ours =
        ReplayPd(*b.probe, *b.scene, b.frames, pd::PdMode::kTranslational, {});
    const std::size_t first = rows.size();
    {
      const TimingSummary t = Summarize(ours, false);
      PeerRow row;
      row.benchmark = b.name;
      row.method = "hapticpd-pdt";
      row.gives_depth = true;
      row.frames = t.frames;
      row.colliding = t.penetrating;
      row.p50_us = t.p50_us;
      row.p99_us = t.p99_us;
      row.mean_contacts = t.mean_contacts;
      rows.push_back(row);
    }
    const testing::FclModel fa(b.probe->mesh()), fb(b.scene->mesh());
    rows.push_back(
        TimePeer(b, "fcl-all-contacts", false, ours, [&](const Pose& X, double*, int* n) {
          *n = testing::FclContacts(fa, X, fb, I);
          return *n > 0;
        }));
    // Bullet's support function walks every point it is given: give it the
    // hull's vertices only (FCL's Convex is built from the hull too).
    const pd::Mesh hull_a = pd::ConvexHull(b.probe->mesh().vertices());
    const pd::Mesh hull_b = pd::ConvexHull(b.scene->mesh().vertices());
    const testing::BulletHull ba(hull_a), bb(hull_b);
    rows.push_back(
        TimePeer(b, "bullet-gjk-epa-hulls", true, ours, [&](const Pose& X, double* d, int*) {
          const testing::EpaResult r = testing::BulletPenetration(ba, X, bb, I);
          *d = r.penetrating ? r.depth : 0;
          return r.penetrating;
        }));
    const testing::FclConvex ca(b.probe->mesh()), cb(b.scene->mesh());
    rows.push_back(
        TimePeer(b, "fcl-gjk-epa-hulls", true, ours, [&](const Pose& X, double* d, int*) {
          const testing::FclPenetration r = testing::FclConvexPenetration(ca, X, cb, I);
          *d = r.depth;
          return r.colliding;
        }));
    pd::QueryScratch scratch;
    pd::CollisionResult collision;
    const pd::CollisionRequest request;
    rows.push_back(TimePeer(b, "hapticpd-collide", false, ours, [&](const Pose& X, double*, int*) {
      return pd::Collide(*b.probe, X, *b.scene, I, request, &collision, &scratch);
    }));
    rows.push_back(TimePeer(b, "fcl-collide", false, ours, [&](const Pose& X, double*, int*) {
      return testing::FclCollide(fa, X, fb, I);
    }));
    const double ours_p50 = rows[first].p50_us;
    for (std::size_t k = first; k < rows.size(); ++k) {
      rows[k].ratio_p50 = ours_p50 > 0 ? rows[k].p50_us / ours_p50 : 0;
    }
  }
  return rows;
}

nlohmann::json ToJson(const std::vector<PeerRow>& rows) {
  nlohmann::json out = nlohmann::json::array();
  for (const PeerRow& r : rows) {
    nlohmann::json j = {{"benchmark", r.benchmark},
                        {"method", r.method},
                        {"frames", r.frames},
                        {"colliding_frames", r.colliding},
                        {"p50_us", r.p50_us},
                        {"p99_us", r.p99_us},
                        {"ratio_p50_to_pdt", r.ratio_p50},
                        {"mean_contacts", r.mean_contacts}};
    if (r.gives_depth && r.method != "hapticpd-pdt") {
      j["depth_error_vs_pdt"] = {{"compared_frames", r.compared},
                                 {"median", r.err_median},
                                 {"p90", r.err_p90},
                                 {"max", r.err_max},
                                 {"signed_median", r.signed_median}};
    }
    out.push_back(j);
  }
  return out;
}

void PrintPeers(std::ostream& os, const std::vector<PeerRow>& rows) {
  char buf[512];
  std::snprintf(buf, sizeof(buf), "%-16s %-22s %6s %6s %9s %9s %8s %9s | %9s %9s %9s %9s\n",
                "benchmark", "method", "frames", "coll", "p50 us", "p99 us", "x PDt", "contacts",
                "err med", "err p90", "err max", "signed");
  os << buf;
  for (const PeerRow& r : rows) {
    std::snprintf(buf, sizeof(buf), "%-16s %-22s %6d %6d %9.1f %9.1f %8.2f %9.1f",
                  r.benchmark.c_str(), r.method.c_str(), r.frames, r.colliding, r.p50_us, r.p99_us,
                  r.ratio_p50, r.mean_contacts);
    os << buf;
    if (r.gives_depth && r.method != "hapticpd-pdt") {
      std::snprintf(buf, sizeof(buf), " | %8.1f%% %8.1f%% %8.1f%% %+8.1f%%\n", 100 * r.err_median,
                    100 * r.err_p90, 100 * r.err_max, 100 * r.signed_median);
      os << buf;
    } else {
      os << " |\n";
    }
  }
  os << "coll = frames reported colliding (PDt: penetrating); x PDt = p50 / our PDt p50; "
        "err = |depth - PDt| / PDt over the frames our PDt penetrates (signed: median of "
        "(depth - PDt) / PDt; hull EPA ignores the shapes' concavities, FCL 0.7's contact depth is "
        "unreliable even on convex shapes)\n";
}

}  // namespace hapticpd::bench
