#include "client/bench/cold.h"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <ostream>
#include <random>
#include <utility>

#include "client/bench/ground_truth.h"
#include "client/bench/svg.h"
#include "pd/convex_hull.h"
#include "pd/enum_names.h"
#include "pd/pdg.h"
#include "pd/pdt.h"
#include "pd/queries.h"
#include "pd/shapes.h"
#include "tests/oracles/bullet_oracle.h"
#include "tests/pd/random_poses.h"

namespace hapticpd::bench {

namespace {

double Diagonal(const pd::GeometryModel& m) { return m.mesh().bounds().Size().norm(); }

bool Penetrates(const pd::PenetrationResult& r) { return Penetrating(r.status) && r.depth > 0; }

std::string LoadAverage() {
  std::ifstream in("/proc/loadavg");
  std::string a, b, c;
  if (!(in >> a >> b >> c)) return "unknown";
  return fmt::format("{} {} {}", a, b, c);
}

}  // namespace

std::vector<ColdPair> BuildColdPairs(const std::string& models_dir, bool procedural_only,
                                     std::vector<std::string>* notes) {
  std::vector<ColdPair> out;
  auto add = [&](const std::string& name, const std::string& probe_name, pd::Mesh probe,
                 const std::string& scene_name, pd::Mesh scene) {
    ColdPair p;
    p.name = name;
    p.probe_name = probe_name;
    p.scene_name = scene_name;
    p.probe = pd::MakeModel(std::move(probe));
    p.scene = pd::MakeModel(std::move(scene));
    p.convex = p.probe->convex() && p.scene->convex();
    if (notes != nullptr) {
      auto kind = [](const pd::GeometryModel& m) {
        return m.convex() ? "convex" : m.closed() ? "closed" : "open";
      };
      notes->push_back(fmt::format("{}: {} ({} triangles, {}) vs {} ({} triangles, {})", p.name,
                                   probe_name, p.probe->mesh().num_triangles(), kind(*p.probe),
                                   scene_name, p.scene->mesh().num_triangles(), kind(*p.scene)));
    }
    out.push_back(std::move(p));
  };
  const std::filesystem::path dir(models_dir);
  auto model = [&](const char* file) -> std::filesystem::path {
    const auto p = dir / file;
    return !procedural_only && !models_dir.empty() && std::filesystem::exists(p)
               ? p
               : std::filesystem::path();
  };
  const auto bunny = model("stanford-bunny.obj");
  const auto spot = model("spot.obj");
  const auto beast = model("beast.obj");
  if (!procedural_only && (bunny.empty() || spot.empty() || beast.empty()) && notes != nullptr) {
    notes->push_back(fmt::format(
        "NOTE: shared models missing in '{}': the pairs that need them are left out{}", models_dir,
        bunny.empty() && spot.empty() && beast.empty() ? " (procedural shapes only)" : ""));
  }
  int skipped = 0;
  if (!bunny.empty()) {
    add("stick-bunny", "stick", pd::shapes::Stick(), "bunny 69K", pd::LoadMesh(bunny.string()));
  }
  if (!spot.empty() && !bunny.empty()) {
    // Spot is 1.7 m tall: scaled to 7 cm, a probe the size of the bunny's head.
    add("spot-bunny", "spot x0.04", Scaled(pd::LoadMesh(spot.string()), 0.04, "spot x0.04"),
        "bunny 69K", pd::LoadMesh(bunny.string()));
  }
  if (!bunny.empty() && !beast.empty()) {
    const pd::Mesh full = Scaled(pd::LoadMesh(beast.string()), 1.0 / 500, "beast/500");
    add("bunny5k-beast20k", "bunny decimated 5K",
        Decimate(pd::LoadMesh(bunny.string()), 5000, "bunny 5K", &skipped),
        "beast/500 decimated 20K", Decimate(full, 20000, "beast 20K", &skipped));
  }
  if (!spot.empty() && !beast.empty()) {
    add("spot-beast64k", "spot x0.1", Scaled(pd::LoadMesh(spot.string()), 0.1, "spot x0.1"),
        "beast/500 64K", Scaled(pd::LoadMesh(beast.string()), 1.0 / 500, "beast/500"));
    add("spot1k-spot", "spot x0.04 decimated 1K",
        Decimate(Scaled(pd::LoadMesh(spot.string()), 0.04, "spot"), 1000, "spot 1K", &skipped),
        "spot x0.1", Scaled(pd::LoadMesh(spot.string()), 0.1, "spot x0.1"));
  }
  namespace s = pd::shapes;
  add("box-torus", "box 2x2x8 cm", s::Box(Vec3(0.01, 0.01, 0.04)), "torus", s::Torus());
  add("stick-torusknot", "stick", s::Stick(), "torus knot", s::TorusKnot());
  add("spoon-cup", "spoon", s::Spoon(), "cup", s::Cup());
  add("torus-cup", "torus", s::Torus(0.03, 0.01, 24, 12), "cup", s::Cup());
  add("hammer-torusknot", "hammer", s::Hammer(2), "torus knot 25 cm",
      s::TorusKnot(2, 3, 0.25, 0.06, 420, 24));
  add("box-sphere", "box 6x4x2 cm", s::Box(Vec3(0.03, 0.02, 0.01)), "sphere", s::Sphere(0.05, 3));
  add("spoonhull-cuphull", "hull of spoon", pd::ConvexHull(s::Spoon().vertices(), "spoon hull"),
      "hull of cup", pd::ConvexHull(s::Cup().vertices(), "cup hull"));
  return out;
}

// ---------------------------------------------------------------------------
// Verification

ColdVerifier::ColdVerifier(const ColdPair& pair)
    : pair_(pair), fa_(pair.probe->mesh()), fb_(pair.scene->mesh()) {}

bool ColdVerifier::Free(const Pose& X_WA) {
  if (testing::FclCollide(fa_, X_WA, fb_, Pose::Identity())) return false;
  // FCL found no surface crossing: only containment is left to rule out.
  pd::CollisionRequest req;
  req.containment = true;
  return !pd::Collide(*pair_.probe, X_WA, *pair_.scene, Pose::Identity(), req, &collision_,
                      &scratch_);
}

ContactCheck ColdVerifier::Check(const Pose& X_WA, const pd::PenetrationResult& r, double rel) {
  ContactCheck c;
  const Vec3& p_AC = pair_.probe->mass().p_MC;
  c.free_out = Free(pd::InterpolateRigid(X_WA, r.X_WA_result, p_AC, 1 + rel));
  c.colliding_in = !Free(pd::InterpolateRigid(X_WA, r.X_WA_result, p_AC, 1 - rel));
  return c;
}

// ---------------------------------------------------------------------------
// Poses and references

std::vector<ColdPose> MakeColdPoses(const std::vector<ColdPair>& pairs, const ColdOptions& o,
                                    std::ostream* log) {
  std::vector<ColdPose> out;
  for (std::size_t pi = 0; pi < pairs.size(); ++pi) {
    const ColdPair& pair = pairs[pi];
    std::mt19937_64 rng(o.seed * 1000003 + pi);
    ColdVerifier verify(pair);
    std::unique_ptr<testing::BulletHull> ha, hb;
    if (pair.convex) {
      ha = std::make_unique<testing::BulletHull>(pair.probe->mesh());
      hb = std::make_unique<testing::BulletHull>(pair.scene->mesh());
    }
    const double diag = Diagonal(*pair.probe);
    const pd::MassProperties& mp = pair.probe->mass();
    const auto& verts = pair.scene->mesh().vertices();
    std::uniform_int_distribution<std::size_t> pick(0, verts.size() - 1);
    std::normal_distribution<double> n(0, 1);
    BoundOptions bo;
    bo.accept = [&verify](const Pose& Y) { return verify.Free(Y); };
    int made = 0, attempts = 0;
    const auto t0 = std::chrono::steady_clock::now();
    while (made < o.poses && attempts < 60 * o.poses) {
      ++attempts;
      const Quat q = testing::RandomRotation(rng);
      ColdPose cp;
      cp.pair = pair.name;
      cp.q_WA = q;
      cp.X_WA = Pose::FromQuaternion(q, Vec3::Zero());
      const Vec3 offset = Vec3(n(rng), n(rng), n(rng)) * (0.15 * diag);
      cp.X_WA.t = verts[pick(rng)] + offset - cp.X_WA.R * mp.p_MC;
      if (!verify.Colliding(cp.X_WA)) continue;
      const double far = o.max_depth_fraction * diag;
      if (pair.convex) {
        const testing::EpaResult e =
            testing::BulletPenetration(*ha, cp.X_WA, *hb, Pose::Identity());
        if (!e.penetrating || e.depth > far) continue;
        cp.pdt_reference = e.depth;
        cp.pdt_reference_dir_W = e.normal_W.normalized();
        cp.pdt_exact = true;
      } else {
        Vec3 u;
        const double d =
            PdtUpperBound(verify.fa(), cp.X_WA, verify.fb(), far, rng, o.pdt_directions, bo, &u);
        if (d >= 1e300) continue;
        cp.pdt_reference = d;
        cp.pdt_reference_dir_W = u;
      }
      cp.depth_fraction = cp.pdt_reference / diag;
      if (cp.depth_fraction < o.min_depth_fraction) continue;
      const std::vector<Pose> seed{
          Pose{cp.X_WA.R, cp.X_WA.t + cp.pdt_reference_dir_W * cp.pdt_reference}};
      const double g = PdgUpperBound(verify.fa(), mp, cp.X_WA, verify.fb(), cp.pdt_reference, rng,
                                     o.pdg_rotations, o.pdg_directions, kColdPdgMaxAngle, seed, bo);
      cp.pdg_reference = std::min(g, cp.pdt_reference);
      out.push_back(cp);
      ++made;
    }
    if (log != nullptr) {
      *log << fmt::format("cold: {}: {} poses from {} draws, references in {:.1f} s\n", pair.name,
                          made, attempts, Us(t0, std::chrono::steady_clock::now()) / 1e6);
    }
  }
  return out;
}

nlohmann::json ColdPosesToJson(const std::vector<ColdPose>& poses, const ColdOptions& o) {
  nlohmann::json j;
  j["description"] =
      "Cold-query reference poses (hapticpd-bench cold --write-reference): probe pose "
      "[tx,ty,tz,qw,qx,qy,qz] against the scene at the identity; pdt_reference is Bullet's "
      "GJK/EPA on convex pairs (pdt_exact) and otherwise a directional-sampling upper bound "
      "(FCL); pdg_reference a sampled rigid-motion upper bound (sqrt sigma)";
  j["seed"] = o.seed;
  j["pdt_directions"] = o.pdt_directions;
  j["pdg_rotations"] = o.pdg_rotations;
  j["pdg_directions"] = o.pdg_directions;
  j["pdg_max_angle"] = kColdPdgMaxAngle;
  j["poses"] = nlohmann::json::array();
  for (const ColdPose& p : poses) {
    nlohmann::json e;
    e["pair"] = p.pair;
    const Quat& q = p.q_WA;
    e["pose"] = {p.X_WA.t.x(), p.X_WA.t.y(), p.X_WA.t.z(), q.w(), q.x(), q.y(), q.z()};
    e["depth_fraction"] = p.depth_fraction;
    e["pdt_reference"] = p.pdt_reference;
    e["pdt_exact"] = p.pdt_exact;
    e["pdt_reference_dir"] = {p.pdt_reference_dir_W.x(), p.pdt_reference_dir_W.y(),
                              p.pdt_reference_dir_W.z()};
    e["pdg_reference"] = p.pdg_reference;
    j["poses"].push_back(e);
  }
  return j;
}

std::vector<ColdPose> ColdPosesFromJson(const nlohmann::json& j) {
  std::vector<ColdPose> out;
  for (const auto& e : j.at("poses")) {
    ColdPose p;
    p.pair = e.at("pair").get<std::string>();
    const auto& v = e.at("pose");
    p.q_WA = Quat(v[3].get<double>(), v[4].get<double>(), v[5].get<double>(), v[6].get<double>());
    p.X_WA = Pose::FromQuaternion(p.q_WA,
                                  Vec3(v[0].get<double>(), v[1].get<double>(), v[2].get<double>()));
    p.depth_fraction = e.at("depth_fraction").get<double>();
    p.pdt_reference = e.at("pdt_reference").get<double>();
    p.pdt_exact = e.at("pdt_exact").get<bool>();
    const auto& d = e.at("pdt_reference_dir");
    p.pdt_reference_dir_W = Vec3(d[0].get<double>(), d[1].get<double>(), d[2].get<double>());
    p.pdg_reference = e.at("pdg_reference").get<double>();
    out.push_back(p);
  }
  return out;
}

// ---------------------------------------------------------------------------
// Queries

namespace {
constexpr std::pair<ColdKind, const char*> kColdKindNames[] = {
    {ColdKind::kPdt, "pdt"}, {ColdKind::kPdg, "pdg"}, {ColdKind::kPdgBudget, "pdg-budget"}};
}  // namespace

const char* ToString(ColdKind k) { return EnumName<kColdKindNames>(k, "?"); }

namespace {

/// PDt from the reference's basin: a free pose just outside the reference
/// goes through the motion-coherence cache first.
double RatioFromReferenceBasin(const ColdPair& pair, ColdVerifier& verify, const ColdPose& p) {
  pd::PdQueryData data;
  pd::PenetrationRequest req;
  pd::PenetrationResult r;
  for (double push : {1e-3, 1e-2, 5e-2}) {
    const Pose Y{p.X_WA.R, p.X_WA.t + p.pdt_reference_dir_W * (p.pdt_reference * (1 + push))};
    if (!verify.Free(Y)) continue;
    pd::ComputePdt(*pair.probe, Y, *pair.scene, Pose::Identity(), req, &data, &r);
    pd::ComputePdt(*pair.probe, p.X_WA, *pair.scene, Pose::Identity(), req, &data, &r);
    return Penetrates(r) ? r.depth / p.pdt_reference : 0;
  }
  return 0;
}

/// How far the reference's line stays free beyond the reference (m), when
/// 0.1 % further out collides: bisection between the free reference and that
/// colliding pose. 0 when 0.1 % further out is free.
double ReferenceFreeWidth(ColdVerifier& verify, const ColdPose& p) {
  auto at = [&](double s) { return Pose{p.X_WA.R, p.X_WA.t + p.pdt_reference_dir_W * s}; };
  double lo = p.pdt_reference, hi = p.pdt_reference * (1 + 1e-3);
  if (verify.Free(at(hi))) return 0;
  for (int i = 0; i < 30; ++i) {
    const double mid = 0.5 * (lo + hi);
    (verify.Free(at(mid)) ? lo : hi) = mid;
  }
  return lo - p.pdt_reference;
}

}  // namespace

std::vector<ColdAnswer> RunColdQueries(const std::vector<ColdPair>& pairs,
                                       const std::vector<ColdPose>& poses, bool diagnose,
                                       int cold_directions, int turn_starts, bool interior_cull,
                                       int local_search) {
  std::vector<ColdAnswer> out;
  std::map<std::string, const ColdPair*> by_name;
  for (const ColdPair& p : pairs) by_name[p.name] = &p;
  std::map<std::string, std::unique_ptr<ColdVerifier>> verifiers;
  pd::PenetrationRequest cold;
  cold.use_coherence = false;
  cold.cold_start_directions = cold_directions;
  cold.pdg_cold_turn_starts = turn_starts;
  cold.cold_interior_cull = interior_cull;
  cold.pdg_cold_local_search = local_search;
  pd::PenetrationRequest cold_unbudgeted = cold;
  cold_unbudgeted.pdg_iteration_budget = 0;
  pd::PdQueryData pdt_data;
  pd::PdgQueryData pdg_data;
  for (const ColdPose& p : poses) {
    const auto it = by_name.find(p.pair);
    if (it == by_name.end()) continue;
    const ColdPair& pair = *it->second;
    auto& verify = verifiers[p.pair];
    if (!verify) verify = std::make_unique<ColdVerifier>(pair);
    auto answer = [&](ColdKind kind, const pd::PenetrationResult& r, double us) {
      ColdAnswer a;
      a.pair = p.pair;
      a.kind = kind;
      a.depth_fraction = p.depth_fraction;
      a.status = r.status;
      a.depth = r.depth;
      a.iterations = r.iterations;
      a.us = us;
      a.exact_reference = kind == ColdKind::kPdt && p.pdt_exact;
      a.reference = kind == ColdKind::kPdt ? p.pdt_reference : p.pdg_reference;
      a.ratio = a.reference > 0 ? r.depth / a.reference : 0;
      if (Penetrates(r)) a.check = verify->Check(p.X_WA, r);
      return a;
    };
    pd::PenetrationResult rt, rg;
    pdt_data.ResetCoherence();
    auto t0 = std::chrono::steady_clock::now();
    pd::ComputePdt(*pair.probe, p.X_WA, *pair.scene, Pose::Identity(), cold, &pdt_data, &rt);
    ColdAnswer at = answer(ColdKind::kPdt, rt, Us(t0, std::chrono::steady_clock::now()));
    if (diagnose && Penetrates(rt) && at.ratio > 1.01) {
      const double c = rt.translation_W.normalized().dot(p.pdt_reference_dir_W);
      at.angle_deg = std::acos(std::clamp(c, -1.0, 1.0)) * 180 / M_PI;
      at.ratio_from_reference_basin = RatioFromReferenceBasin(pair, *verify, p);
      if (!(at.ratio_from_reference_basin > 0))
        at.reference_free_width = ReferenceFreeWidth(*verify, p);
    }
    out.push_back(at);
    for (ColdKind kind : {ColdKind::kPdg, ColdKind::kPdgBudget}) {
      pdg_data.ResetCoherence();
      t0 = std::chrono::steady_clock::now();
      pd::ComputePdg(*pair.probe, p.X_WA, *pair.scene, Pose::Identity(),
                     kind == ColdKind::kPdg ? cold_unbudgeted : cold, &pdg_data, &rg);
      ColdAnswer ag = answer(kind, rg, Us(t0, std::chrono::steady_clock::now()));
      ag.above_pdt = Penetrates(rt) && rg.depth > rt.depth * (1 + 1e-9);
      out.push_back(ag);
    }
  }
  return out;
}

std::vector<ColdSummary> SummarizeCold(const std::vector<ColdAnswer>& answers) {
  std::vector<ColdSummary> out;
  for (ColdKind kind : {ColdKind::kPdt, ColdKind::kPdg, ColdKind::kPdgBudget}) {
    ColdSummary s;
    s.kind = kind;
    std::vector<double> ratios, us;
    for (const ColdAnswer& a : answers) {
      if (a.kind != kind) continue;
      ++s.count;
      us.push_back(a.us);
      if (!Penetrating(a.status) || !(a.depth > 0)) {
        ++s.failed;
        continue;
      }
      s.unverified += !a.check.ok();
      s.cap_reached += a.status == pd::PdStatus::kPenetratingCapReached;
      s.above_pdt += a.above_pdt;
      ratios.push_back(a.ratio);
      s.above_1_01 += a.ratio > 1.01;
      s.above_1_10 += a.ratio > 1.10;
    }
    s.ratio_median = Percentile(ratios, 0.5);
    s.ratio_p95 = Percentile(ratios, 0.95);
    s.ratio_max = Percentile(ratios, 1.0);
    s.p50_us = Percentile(us, 0.5);
    s.p99_us = Percentile(us, 0.99);
    s.max_us = Percentile(us, 1.0);
    out.push_back(s);
  }
  return out;
}

ColdReport RunCold(const ColdOptions& o, std::ostream* log) {
  ColdReport report;
  report.load_average = LoadAverage();
  if (log != nullptr) *log << "cold: load average at start " << report.load_average << "\n";
  const std::vector<ColdPair> pairs = BuildColdPairs(o.models, o.procedural_only, &report.notes);
  if (o.models.empty() && !o.procedural_only) {
    report.notes.push_back("NOTE: shared models not found: procedural shapes only");
  }
  report.notes.push_back(fmt::format(
      "references: PDt {} uniformly random directions + 4 x {} refinements (spreads 0.2, 0.05, "
      "0.01, 0.002), 40 bisections each, FCL collide + containment (convex pairs: Bullet "
      "GJK/EPA, exact); PDg min(PDt bound, {} rotations up to {:.2f} rad x {} directions + "
      "refinements); seed {}",
      o.pdt_directions, o.pdt_directions / 4, o.pdg_rotations, kColdPdgMaxAngle, o.pdg_directions,
      o.seed));
  if (o.poses_from.empty()) {
    report.poses = MakeColdPoses(pairs, o, log);
  } else {
    std::ifstream in(o.poses_from);
    if (!in) throw std::runtime_error("cannot read the pose set '" + o.poses_from + "'");
    nlohmann::json j;
    try {
      j = nlohmann::json::parse(in);
    } catch (const nlohmann::json::exception& e) {
      throw std::runtime_error("pose set '" + o.poses_from + "' is not JSON: " + e.what());
    }
    report.poses = ColdPosesFromJson(j);
    for (const ColdPose& pose : report.poses) {
      const bool known = std::any_of(pairs.begin(), pairs.end(),
                                     [&](const ColdPair& p) { return p.name == pose.pair; });
      if (!known) {
        throw std::runtime_error("pose set '" + o.poses_from + "' names pair '" + pose.pair +
                                 "', which is not built here (shared models missing?)");
      }
    }
    report.notes.push_back("poses and references read from " + o.poses_from);
  }
  report.answers = RunColdQueries(pairs, report.poses, true, o.cold_directions, o.turn_starts,
                                  o.interior_cull, o.local_search);
  report.notes.push_back(
      fmt::format("cold search escape directions per query: {}", o.cold_directions));
  report.notes.push_back(fmt::format("PDg turn starts per cold query: {}", o.turn_starts));
  report.notes.push_back(
      fmt::format("PDg local search candidates per unbudgeted cold query: {}", o.local_search));
  report.notes.push_back(fmt::format("interior cull of escape directions and turn starts: {}",
                                     o.interior_cull ? "on" : "off"));
  report.summary = SummarizeCold(report.answers);
  return report;
}

nlohmann::json ToJson(const ColdReport& report) {
  nlohmann::json j;
  j["load_average"] = report.load_average;
  j["notes"] = report.notes;
  j["summary"] = nlohmann::json::array();
  for (const ColdSummary& s : report.summary) {
    j["summary"].push_back({{"kind", ToString(s.kind)},
                            {"count", s.count},
                            {"failed", s.failed},
                            {"unverified", s.unverified},
                            {"cap_reached", s.cap_reached},
                            {"above_pdt", s.above_pdt},
                            {"ratio_median", s.ratio_median},
                            {"ratio_p95", s.ratio_p95},
                            {"ratio_max", s.ratio_max},
                            {"above_1_01", s.above_1_01},
                            {"above_1_10", s.above_1_10},
                            {"p50_us", s.p50_us},
                            {"p99_us", s.p99_us},
                            {"max_us", s.max_us}});
  }
  j["answers"] = nlohmann::json::array();
  for (const ColdAnswer& a : report.answers) {
    j["answers"].push_back({{"pair", a.pair},
                            {"kind", ToString(a.kind)},
                            {"depth_fraction", a.depth_fraction},
                            {"status", pd::ToString(a.status)},
                            {"depth", a.depth},
                            {"reference", a.reference},
                            {"exact_reference", a.exact_reference},
                            {"ratio", a.ratio},
                            {"iterations", a.iterations},
                            {"us", a.us},
                            {"verified", a.check.ok()},
                            {"above_pdt", a.above_pdt},
                            {"angle_deg", a.angle_deg},
                            {"ratio_from_reference_basin", a.ratio_from_reference_basin},
                            {"reference_free_width", a.reference_free_width}});
  }
  return j;
}

void PrintCold(std::ostream& os, const ColdReport& report) {
  os << "load average at start: " << report.load_average << "\n";
  for (const std::string& n : report.notes) os << n << "\n";
  os << fmt::format("{} poses\n\n", report.poses.size());
  os << fmt::format(
      "{:<11} {:>5} {:>6} {:>10} {:>4} {:>8} {:>8} {:>8} {:>6} {:>6} {:>9} {:>9} {:>9}\n", "query",
      "n", "failed", "unverified", "cap", "median", "p95", "max", ">1.01", ">1.10", "p50 us",
      "p99 us", "max us");
  for (const ColdSummary& s : report.summary) {
    os << fmt::format(
        "{:<11} {:>5} {:>6} {:>10} {:>4} {:>8.4f} {:>8.4f} {:>8.4f} {:>6} {:>6} {:>9.0f} {:>9.0f} "
        "{:>9.0f}\n",
        ToString(s.kind), s.count, s.failed, s.unverified, s.cap_reached, s.ratio_median,
        s.ratio_p95, s.ratio_max, s.above_1_01, s.above_1_10, s.p50_us, s.p99_us, s.max_us);
  }
  int above = 0;
  for (const ColdSummary& s : report.summary) above += s.kind != ColdKind::kPdt ? s.above_pdt : 0;
  os << fmt::format("PDg answers with sigma > PDt^2: {}\n", above);
  os << "\nper pair (ratio median / max / count > 1.01 / count > 1.10 of n):\n";
  std::map<std::pair<std::string, int>, std::vector<double>> per;
  std::vector<std::string> order;
  for (const ColdAnswer& a : report.answers) {
    if (std::find(order.begin(), order.end(), a.pair) == order.end()) order.push_back(a.pair);
    if (Penetrating(a.status)) per[{a.pair, static_cast<int>(a.kind)}].push_back(a.ratio);
  }
  for (const std::string& name : order) {
    std::string line = fmt::format("  {:<18}", name);
    for (ColdKind kind : {ColdKind::kPdt, ColdKind::kPdg, ColdKind::kPdgBudget}) {
      const auto& v = per[{name, static_cast<int>(kind)}];
      const auto n101 = std::count_if(v.begin(), v.end(), [](double r) { return r > 1.01; });
      const auto n110 = std::count_if(v.begin(), v.end(), [](double r) { return r > 1.10; });
      line += fmt::format(" {} {:.4f} / {:.3f} / {} / {} of {} ", ToString(kind),
                          Percentile(v, 0.5), Percentile(v, 1.0), n101, n110, v.size());
    }
    os << line << "\n";
  }
  os << "\nPDt answers above 1.01x (angle to the reference's direction; ratio when started from "
        "the reference's basin):\n";
  for (const ColdAnswer& a : report.answers) {
    if (a.kind != ColdKind::kPdt || !(a.ratio > 1.01)) continue;
    std::string basin = "n/a (no penetrating answer from it)";
    if (a.ratio_from_reference_basin > 0) {
      basin = fmt::format("{:.4f}", a.ratio_from_reference_basin);
    } else if (a.reference_free_width > 0) {
      basin = fmt::format(
          "n/a (wedged: its line is free for {:.3g} um beyond it, {:.2g} % of its "
          "depth)",
          1e6 * a.reference_free_width, 100 * a.reference_free_width / a.reference);
    }
    os << fmt::format("  {:<18} depth {:5.1f}% ratio {:.4f} {} it {} angle {:5.1f} basin {}\n",
                      a.pair, 100 * a.depth_fraction, a.ratio, pd::ToString(a.status), a.iterations,
                      a.angle_deg, basin);
  }
}

void WriteColdSvg(const std::filesystem::path& path, const ColdReport& report,
                  const std::string& title) {
  svg::Figure fig;
  fig.title = title;
  const char* colors[] = {"#1f5fbf", "#d9480f", "#2b8a3e"};
  svg::Panel ratio, time;
  ratio.title = "answer / reference bound";
  time.title = "query time";
  ratio.x_label = time.x_label = "depth (reference / probe diagonal)";
  ratio.y_label = "ratio";
  time.y_label = "us";
  ratio.log_y = time.log_y = true;
  for (ColdKind kind : {ColdKind::kPdt, ColdKind::kPdg, ColdKind::kPdgBudget}) {
    svg::Series r, t;
    r.label = t.label = ToString(kind);
    r.color = t.color = colors[static_cast<int>(kind)];
    r.line = t.line = false;
    for (const ColdAnswer& a : report.answers) {
      if (a.kind != kind) continue;
      t.x.push_back(a.depth_fraction);
      t.y.push_back(std::max(a.us, 1.0));
      if (!Penetrating(a.status) || !(a.ratio > 0)) continue;
      r.x.push_back(a.depth_fraction);
      r.y.push_back(a.ratio);
    }
    ratio.series.push_back(std::move(r));
    time.series.push_back(std::move(t));
  }
  ratio.notes.push_back("ratio 1: the answer equals the bound (exact on convex pairs)");
  fig.panels.push_back(std::move(ratio));
  fig.panels.push_back(std::move(time));
  svg::Write(path, fig);
}

}  // namespace hapticpd::bench
