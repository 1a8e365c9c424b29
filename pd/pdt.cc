#include "pd/pdt.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <numbers>
#include <utility>

#include "pd/convex.h"
#include "pd/enum_names.h"
#include "pd/material.h"

namespace hapticpd::pd {

// Each name table next to its ToString; namespace-scope constexpr has internal linkage.
constexpr std::pair<PdStatus, const char*> kPdStatusNames[] = {
    {PdStatus::kSeparated, "separated"},
    {PdStatus::kPenetratingSolved, "penetrating-solved"},
    {PdStatus::kPenetratingCapReached, "penetrating-cap-reached"},
    {PdStatus::kFailed, "failed"}};
const char* ToString(PdStatus s) { return EnumName<kPdStatusNames>(s, "unknown"); }

constexpr std::pair<PdMode, const char*> kPdModeNames[] = {{PdMode::kTranslational, "pdt"},
                                                           {PdMode::kGeneralized, "pdg"}};
const char* ToString(PdMode m) { return EnumName<kPdModeNames>(m, "unknown"); }

void ResetPenetrationResult(PdMode mode, const Pose& X_WA, PenetrationResult* result) {
  std::vector<ContactFeature> features = std::move(result->features);
  std::vector<ContactRegion> regions = std::move(result->regions);
  std::string failure = std::move(result->failure);
  features.clear();
  regions.clear();
  failure.clear();
  *result = PenetrationResult{};
  result->features = std::move(features);
  result->regions = std::move(regions);
  result->failure = std::move(failure);
  result->mode = mode;
  result->X_WA_result = X_WA;
}

bool FailOnNonFinitePoses(PdMode mode, const Pose& X_WA, const Pose& X_WB,
                          PenetrationResult* result) {
  if (X_WA.R.allFinite() && X_WA.t.allFinite() && X_WB.R.allFinite() && X_WB.t.allFinite()) {
    return false;
  }
  ResetPenetrationResult(mode, X_WA, result);  // status kFailed
  result->failure = "non-finite pose (probe or scene body)";
  return true;
}

PdQueryData::PdQueryData() {
  // Generous first sizes so typical sessions never grow them; they still
  // grow (once) if a query needs more.
  scratch.stack.reserve(1024);
  scratch.heap.reserve(4096);
  collision.pairs.reserve(16);
  ccd.features.reserve(1024);
  best_features.reserve(1024);
  cold_answer_features.reserve(1024);
  cold_contact_features.reserve(1024);
  planes.reserve(1024);
  contact_space_B.reserve(1024);
  carried_planes.reserve(1024);
  cluster_of.reserve(1024);
}

void PdQueryData::Remember(const CoherenceEntry& e) {
  coherence[coherence_head_] = e;
  coherence_head_ = (coherence_head_ + 1) % kCoherenceSlots;
  coherence_size_ = std::min(coherence_size_ + 1, kCoherenceSlots);
}

// ---------------------------------------------------------------------------
// The in-projection QP

void SolveMinNormQp(const std::vector<ContactPlane>& planes, const Vec3& x0, Vec3* x_out) {
  // Primal active set (Nocedal & Wright, Alg. 16.3) for min 1/2 |x|^2.
  // Working set W holds at most 3 linearly independent constraints, since a
  // blocking constraint always has n . p < 0 for a step p in W's null space.
  Vec3 x = x0;
  std::array<int, 3> W{};
  int nw = 0;
  const int m = static_cast<int>(planes.size());
  const double scale = std::max(1e-300, x0.norm());
  for (int iter = 0; iter < 64 + 4 * m; ++iter) {
    // Step to the minimiser of |x + p|^2 on the working set's subspace.
    Vec3 p;
    Eigen::Vector3d lambda = Eigen::Vector3d::Zero();
    if (nw == 0) {
      p = -x;
    } else {
      Eigen::Matrix<double, 3, Eigen::Dynamic, 0, 3, 3> N(3, nw);
      for (int k = 0; k < nw; ++k) N.col(k) = planes[W[k]].n;
      const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, 3, 3> G = N.transpose() * N;
      const Eigen::Matrix<double, Eigen::Dynamic, 1, 0, 3, 1> l = G.ldlt().solve(N.transpose() * x);
      const Vec3 proj = N * l;  // component of x in span(N)
      p = -(x - proj);
      lambda.head(nw) = l;
    }
    if (p.norm() <= 1e-13 * scale) {
      // x = N lambda at the subspace minimum: optimal when lambda >= 0.
      int worst = -1;
      double most_negative = -1e-14 * scale;
      for (int k = 0; k < nw; ++k) {
        if (lambda[k] < most_negative) {
          most_negative = lambda[k];
          worst = k;
        }
      }
      if (worst < 0) {
        *x_out = x;
        return;
      }
      W[worst] = W[nw - 1];
      --nw;
      continue;
    }
    // Longest feasible step along p.
    double alpha = 1.0;
    int blocking = -1;
    for (int i = 0; i < m; ++i) {
      bool in_w = false;
      for (int k = 0; k < nw; ++k) in_w = in_w || W[k] == i;
      if (in_w) continue;
      const double np = planes[i].n.dot(p);
      if (np >= -1e-15 * p.norm()) continue;
      const double slack = std::max(0.0, planes[i].n.dot(x) - planes[i].b);
      const double a = slack / -np;
      if (a < alpha) {
        alpha = a;
        blocking = i;
      }
    }
    x += alpha * p;
    if (blocking >= 0 && nw < 3) W[nw++] = blocking;
  }
  // The cap: the last feasible iterate.
  *x_out = x;
}

// ---------------------------------------------------------------------------
// Regions and wrench

void BuildRegions(const std::vector<FeaturePair>& features, const Vec3& d_W, double radius,
                  std::vector<int>* cluster_of, std::vector<ContactRegion>* regions) {
  regions->clear();
  cluster_of->assign(features.size(), -1);
  const double r2 = radius > 0 ? radius * radius : std::numeric_limits<double>::infinity();
  // Greedy clustering: a contact joins the first region whose normal is
  // within ~14 degrees and whose mean point is within `radius`. Clustering by
  // normal keeps one planar contact one region (its corners would otherwise
  // each add k d and multiply the force); the radius separates distinct
  // patches that happen to share a normal far apart on a large probe.
  for (std::size_t i = 0; i < features.size(); ++i) {
    const FeaturePair& f = features[i];
    if (!(f.n_W.squaredNorm() > 0.5)) continue;  // no contact plane
    const Vec3 p = f.p_WA - d_W;                 // the probe's point at the query pose
    int found = -1;
    for (std::size_t r = 0; r < regions->size(); ++r) {
      const ContactRegion& reg = (*regions)[r];
      const Vec3 seed = reg.p_W / reg.contacts;
      if ((seed - p).squaredNorm() <= r2 && reg.n_W.normalized().dot(f.n_W) > 0.97) {
        found = static_cast<int>(r);
        break;
      }
    }
    if (found < 0) {
      regions->push_back({});
      found = static_cast<int>(regions->size()) - 1;
    }
    ContactRegion& reg = (*regions)[found];
    reg.p_W += p;  // sums, normalised below
    reg.n_W += f.n_W;
    ++reg.contacts;
    (*cluster_of)[i] = found;
  }
  std::size_t out = 0;
  for (std::size_t r = 0; r < regions->size(); ++r) {
    ContactRegion reg = (*regions)[r];
    reg.p_W /= reg.contacts;
    const double len = reg.n_W.norm();
    if (len <= 1e-12) continue;
    reg.n_W /= len;
    reg.depth = std::max(0.0, d_W.dot(reg.n_W));
    reg.local_depth_W = reg.depth * reg.n_W;
    if (reg.depth <= 0) continue;  // a region the answer moves away from
    (*regions)[out++] = reg;
  }
  regions->resize(out);
}

// ---------------------------------------------------------------------------
// PDt

namespace {

using Clock = std::chrono::steady_clock;

Pose Shifted(const Pose& X, const Vec3& x) { return Pose{X.R, X.t + x}; }

// The core works in B's frame: B sits at the identity (kX_BB), and every
// offset, point and normal below is in B's frame (the queries' "W" is B).
struct PdtContext {
  const GeometryModel& A;
  const Pose& X_BA;
  const GeometryModel& B;
  const PenetrationRequest& request;
  PdQueryData& data;
  double eps;  // absolute contact tolerance (m)
  int collision_queries = 0;
  int ccd_queries = 0;
};

double Size(const PdtContext& c) { return std::min(c.A.mesh().size(), c.B.mesh().size()); }

bool Colliding(PdtContext& c, const Vec3& x) {
  CollisionRequest req;
  ++c.collision_queries;
  return Collide(c.A, Shifted(c.X_BA, x), c.B, kX_BB, req, &c.data.collision, &c.data.scratch);
}

enum class SweepOutcome : std::uint8_t { kStartColliding, kHit, kMiss };

// CCD from x_from to x_to; on a hit returns the contact offset and fills
// data.ccd.features. With `check_start` the start may overlap B (reported as
// kStartColliding, decided inside the same traversal); without, it must be
// known to be free.
SweepOutcome SweepFrom(PdtContext& c, const Vec3& x_from, const Vec3& x_to, Vec3* x_contact,
                       bool check_start, bool start_likely_overlaps = false) {
  CcdRequest req;
  req.feature_tolerance = c.eps;
  req.check_start = check_start;
  req.start_crossing_first = start_likely_overlaps;
  ++c.ccd_queries;
  if (!TranslationalCcd(c.A, Shifted(c.X_BA, x_from), x_to - x_from, c.B, kX_BB, req, &c.data.ccd,
                        &c.data.scratch)) {
    return c.data.ccd.start_colliding ? SweepOutcome::kStartColliding : SweepOutcome::kMiss;
  }
  *x_contact = x_from + c.data.ccd.toi * (x_to - x_from);
  return SweepOutcome::kHit;
}

// Sweep from a start known to be free.
bool Sweep(PdtContext& c, const Vec3& x_from, const Vec3& x_to, Vec3* x_contact) {
  return SweepFrom(c, x_from, x_to, x_contact, false) == SweepOutcome::kHit;
}

// A free offset far enough along unit u that the bounding spheres are apart.
Vec3 OutsideAlong(const PdtContext& c, const Vec3& u) {
  const Vec3 cA = c.X_BA * c.A.mesh().bounds().Center();
  const Vec3 cB = c.B.mesh().bounds().Center();
  const double rA = c.A.mesh().bounding_radius(), rB = c.B.mesh().bounding_radius();
  // Need |cA + s u - cB| > rA + rB: s = (cB - cA).u + sqrt(...) suffices, take
  // a simple sufficient value.
  const double s = (cB - cA).dot(u) + (cB - cA).norm() + rA + rB + 2 * c.eps;
  return u * std::max(s, 2 * c.eps);
}

// Which pushes of the stored configurations CoherentStart tries.
enum class Pushes : std::uint8_t {
  kAll,      // both pushes of the two nearest entries
  kFarOnly,  // the nearest entry's farther push only
};

// Out-projection from the motion-coherence cache: a contact offset reached
// by sweeping from a stored configuration (pushed out a little along its
// direction) to the query pose, or false. The sweep itself checks that its
// start is free.
bool CoherentStart(PdtContext& c, Pushes pushes, Vec3* x_contact) {
  PdQueryData& d = c.data;
  if (!c.request.use_coherence || d.coherence_size_ == 0) return false;
  const Vec3& p_BAo = c.X_BA.t;
  // Try the two entries nearest to the current pose.
  int order[2] = {-1, -1};
  double dist[2] = {std::numeric_limits<double>::infinity(),
                    std::numeric_limits<double>::infinity()};
  for (int i = 0; i < d.coherence_size_; ++i) {
    const double di = (d.coherence[i].p_BAo - p_BAo).squaredNorm();
    if (di < dist[0]) {
      order[1] = order[0];
      dist[1] = dist[0];
      order[0] = i;
      dist[0] = di;
    } else if (di < dist[1]) {
      order[1] = i;
      dist[1] = di;
    }
  }
  const int entries = pushes == Pushes::kAll ? 2 : 1;
  for (int k = 0; k < entries && order[k] >= 0; ++k) {
    const PdQueryData::CoherenceEntry& e = d.coherence[order[k]];
    // A stored contact is touching: push it out a little along its direction.
    for (double push : {2.0, 20.0}) {
      if (pushes == Pushes::kFarOnly && push < 20.0) continue;
      const Vec3 p_B = e.p_BAo + e.dir_B * (push * c.eps);
      const Vec3 x = p_B - c.X_BA.t;
      switch (SweepFrom(c, x, Vec3::Zero(), x_contact, true)) {
        case SweepOutcome::kHit:
          return true;
        case SweepOutcome::kMiss:
          return false;  // free start, yet nothing between it and the query pose
        case SweepOutcome::kStartColliding:
          break;
      }
      if (e.dir_B.squaredNorm() == 0) break;
    }
  }
  // The probe moved deeper than a small push undoes (or turned): pull it
  // straight back along the nearest entry's direction from outside both
  // bounding spheres, one sweep instead of a cold start's thirteen.
  if (order[0] >= 0 && d.coherence[order[0]].dir_B.squaredNorm() > 0) {
    const Vec3& u = d.coherence[order[0]].dir_B;
    return SweepFrom(c, OutsideAlong(c, u), Vec3::Zero(), x_contact, false) == SweepOutcome::kHit;
  }
  return false;
}

// Contact-space coherence: in-project onto the previous answer's local
// contact space (moved to this query) and out-project from just outside the
// result towards the query pose. While the probe slides, this lands next to
// the new answer with one sweep. Skipped after a large turn, where the
// stored planes no longer describe the contact.
SweepOutcome ContactSpaceStart(PdtContext& c, Vec3* x_contact) {
  PdQueryData& d = c.data;
  if (!c.request.use_coherence || !d.contact_space_valid_ || d.contact_space_B.empty()) {
    return SweepOutcome::kMiss;
  }
  const double cos_turn = 0.5 * ((d.contact_space_R_BA.transpose() * c.X_BA.R).trace() - 1);
  if (cos_turn < std::cos(0.05)) return SweepOutcome::kMiss;
  const Vec3& p = c.X_BA.t;
  d.planes.clear();
  for (const ContactPlane& q : d.contact_space_B) d.planes.push_back({q.n, q.b - q.n.dot(p)});
  Vec3 x_star;
  SolveMinNormQp(d.planes, d.contact_space_p_BAo - p, &x_star);
  const double len = x_star.norm();
  if (!(len > 0)) return SweepOutcome::kMiss;
  return SweepFrom(c, x_star * (1 + 2 * c.eps / len), Vec3::Zero(), x_contact, true);
}

// Adds a plane, merging a near-parallel one (keeping the tightest).
void AddPlane(const ContactPlane& q, std::vector<ContactPlane>* planes) {
  for (ContactPlane& p : *planes) {
    if (p.n.dot(q.n) > 1 - 1e-8) {
      p.b = std::max(p.b, q.b);
      return;
    }
  }
  planes->push_back(q);
}

// Builds the local contact space from CCD features at contact offset x_c.
void BuildPlanes(const std::vector<FeaturePair>& features, const Vec3& x_c,
                 std::vector<ContactPlane>* planes) {
  planes->clear();
  for (const FeaturePair& f : features) {
    const Vec3& n = f.n_W;
    if (!(n.squaredNorm() > 0.5)) continue;  // degenerate normal: dropped
    // Gap at x: g + n.(x - x_c) >= 0.
    AddPlane({n, n.dot(x_c) - f.signed_distance}, planes);
  }
}

// The 13 fixed escape directions of the plain cold start: the centroid
// direction and both bodies' principal axes.
std::array<Vec3, kColdStartDirections> FixedColdDirections(const PdtContext& c, double size) {
  Vec3 u0 = c.X_BA * c.A.mass().p_MC - c.B.mesh().bounds().Center();
  u0 = u0.norm() < 1e-12 * size ? Vec3(Vec3::UnitZ()) : Vec3(u0.normalized());
  std::array<Vec3, kColdStartDirections> dirs;
  dirs[0] = u0;
  for (int k = 0; k < 3; ++k) {
    dirs[1 + 2 * k] = c.B.mass().X_MB.R.col(k);
    dirs[2 + 2 * k] = -dirs[1 + 2 * k];
    dirs[7 + 2 * k] = c.X_BA.R * c.A.mass().X_MB.R.col(k);
    dirs[8 + 2 * k] = -dirs[7 + 2 * k];
  }
  return dirs;
}

// Steps 2-5 from the contact `*best_io` (its features in
// data.best_features), then the final check; leaves the answer in *best_io
// and its features in data.best_features.
PdStatus Refine(PdtContext& c, Vec3* best_io, int* iterations) {
  Vec3& best = *best_io;
  // 2-5. Iterate: local contact space, in-projection, classification.
  PdStatus status = PdStatus::kPenetratingCapReached;
  c.data.carried_planes.clear();
  for (int it = 0; it < c.request.max_iterations; ++it) {
    *iterations = it + 1;
    BuildPlanes(c.data.best_features, best, &c.data.planes);
    if (c.data.planes.empty()) {
      status = PdStatus::kPenetratingSolved;
      break;
    }
    // After a blocked step, the planes we were sliding along still bound
    // the free space (we moved from them into free space until something
    // else blocked us): together they describe the crevice, which one set
    // alone would zig-zag in.
    for (const ContactPlane& q : c.data.carried_planes) AddPlane(q, &c.data.planes);
    Vec3 x_star;
    SolveMinNormQp(c.data.planes, best, &x_star);
    const double best_norm = best.norm();
    const double target = best_norm * (1 - c.request.improvement_tolerance) - 0.1 * c.eps;
    Vec3 x_new;
    bool improved = false;
    bool blocked = false;
    if (x_star.norm() < target) {
      // Slide from the best contact (backed off to its free side) towards
      // x*. Blocked on the way: that contact is the candidate (x* itself
      // collides, as it does most of the time on curved or crowded
      // surfaces). Not blocked: x* is free, and the out-projection from it
      // towards the query pose is the candidate.
      Vec3 n_avg = Vec3::Zero();
      for (const FeaturePair& f : c.data.best_features) n_avg += f.n_W;
      n_avg = n_avg.norm() > 1e-12 ? n_avg.normalized() : best.normalized();
      SweepOutcome back = SweepFrom(c, best + n_avg * (2 * c.eps), x_star, &x_new, true);
      if (back == SweepOutcome::kStartColliding) {
        back = SweepFrom(c, best + best.normalized() * (2 * c.eps), x_star, &x_new, true);
      }
      if (back == SweepOutcome::kHit && x_new.norm() < target) {
        improved = true;
        c.data.carried_planes.swap(c.data.planes);
        blocked = true;
      } else if (SweepFrom(c, x_star, Vec3::Zero(), &x_new, back != SweepOutcome::kMiss) ==
                 SweepOutcome::kHit) {
        // (toi = 0 means x* itself is a contact; its features still refine
        // the local contact space on the next iteration.)
        improved = x_new.norm() < best_norm;
      }
    }
    if (!blocked) c.data.carried_planes.clear();
    // x* satisfies every local plane at once: exact where the free space is
    // locally their intersection (a crevice). At a convex ridge or corner of
    // the contact space free space is their union, x* stays at the corner,
    // and coherence would hold the answer there frame after frame. So the
    // shallowest single plane's projection is tried too (just outside it:
    // on it the probe would touch, which counts as colliding).
    if (!improved && c.data.planes.size() > 1) {
      const ContactPlane* pick = nullptr;
      for (const ContactPlane& p : c.data.planes) {
        if (p.b > 0 && p.b < target && (pick == nullptr || p.b < pick->b)) pick = &p;
      }
      if (pick != nullptr &&
          SweepFrom(c, (pick->b + 2 * c.eps) * pick->n, Vec3::Zero(), &x_new, true) ==
              SweepOutcome::kHit &&
          x_new.norm() < target) {
        improved = true;
        c.data.carried_planes.clear();
      }
    }
    if (!improved) {
      status = PdStatus::kPenetratingSolved;  // no improvement: local optimum
      break;
    }
    best = x_new;
    c.data.best_features = c.data.ccd.features;
  }

  // Final check: just beyond the answer along its own direction the probe
  // must be free. A contact reached sideways (a pocket of free space, or an
  // iteration stopped early) can fail this; then take the first contact on
  // the answer's line coming from outside, which is free beyond by
  // construction.
  // When every contact normal has a clear positive component along the
  // answer, moving further out opens every contact to first order and the
  // collision query is skipped.
  bool outward = false;
  if (best.norm() > 0) {
    const Vec3 u = best.normalized();
    int planes = 0;
    for (const FeaturePair& f : c.data.best_features) {
      if (!(f.n_W.squaredNorm() > 0.5)) continue;  // no contact plane
      ++planes;
      if (f.n_W.dot(u) <= 0.05) planes = -1 << 20;
    }
    outward = planes > 0;
  }
  if (best.norm() > 0 && !outward) {
    const Vec3 u = best.normalized();
    const double push = std::max(1e-7 * best.norm(), 1e-12 * Size(c));
    Vec3 x_line;
    if (Colliding(c, best + u * push) && Sweep(c, OutsideAlong(c, u), Vec3::Zero(), &x_line)) {
      best = x_line;
      c.data.best_features = c.data.ccd.features;
    }
  }
  return status;
}

// The cold search's k-th escape direction of `count`: the fixed ones, then
// a Fibonacci sphere lattice of the rest (computed, not stored: nothing is
// allocated).
Vec3 ColdDirection(const std::array<Vec3, kColdStartDirections>& fixed, int k, int count) {
  if (k < kColdStartDirections) return fixed[k];
  const int n = count - kColdStartDirections;
  const int i = k - kColdStartDirections;
  const double z = 1 - (2 * i + 1.0) / n;
  const double r = std::sqrt(std::max(0.0, 1 - z * z));
  const double phi = i * 2.39996322972865332;  // the golden angle
  return {r * std::cos(phi), r * std::sin(phi), z};
}

// Around the best answer: kColdLocalDirections directions on each of the
// cones of these half-angles (radians), widest first.
constexpr std::array<double, 3> kColdLocalSpreads = {0.3, 0.1, 0.03};
constexpr int kColdLocalDirections = 8;

// The j-th direction around unit w.
Vec3 LocalDirection(const Vec3& w, int j) {
  const int cone = j / kColdLocalDirections;
  const int i = j % kColdLocalDirections;
  const Vec3 e1 = w.unitOrthogonal();
  const Vec3 e2 = w.cross(e1);
  const double phi = i * (2 * std::numbers::pi / kColdLocalDirections) + 0.5 * cone;
  return (w + kColdLocalSpreads[cone] * (std::cos(phi) * e1 + std::sin(phi) * e2)).normalized();
}

// A direction more than 135 degrees from the best answer whose start
// collides is tried once more from this fraction of the start's depth.
constexpr double kColdPocketCos = -0.70710678118654752;  // cos 135 degrees
constexpr double kColdPocketStart = 0.75;

// Cold search: out-projections along request.cold_start_directions escape
// directions and then around the best answer, each refined to its local
// optimum; the shallowest answer wins. Once a contact is known, a
// direction's sweep starts just inside its depth instead of outside the
// bounding spheres: a start that collides drops the direction (nothing
// shallower lies that way), so most directions cost one early-out collision
// test, the sweeps that run are short, and a free start there also reaches
// free pockets that a sweep from outside never meets. A colliding start on
// the far side of the body from that contact gets a second start a quarter
// closer in: the line may cross a free pocket short of its depth and collide
// again beyond it. With data.cold_search_bound every sweep starts at that
// depth.
//
// With request.cold_contacts_first (and more than one direction) the escape
// directions are first swept for their contacts alone, and the shallowest
// contacts are refined before the directions are swept again from just
// inside the refined answer, each new contact refined at once: a contact
// refined early is most often beaten by a later one, and refining the most
// promising one first spares most of those refinements. The second sweep
// of the directions still finds the free pockets that only a start inside
// the refined depth reaches. Leaves the answer in *best, its features in
// data.best_features; false when no direction reached a contact.
bool ColdSearch(PdtContext& c, Vec3* best, PdStatus* status, int* iterations) {
  PdQueryData& d = c.data;
  const std::array<Vec3, kColdStartDirections> fixed = FixedColdDirections(c, Size(c));
  const int count = std::clamp(c.request.cold_start_directions, 1, kMaxColdSearchDirections);
  const int local =
      count > 1 ? static_cast<int>(kColdLocalSpreads.size()) * kColdLocalDirections : 0;
  bool have_best = false;
  double best_norm = d.cold_search_bound;
  // A's sample points in B's frame at the query pose, when B has inside
  // cells: a start that puts one of them in such a cell collides (A's
  // surface crosses B's, or the component of A that a containment test
  // looks at lies inside B), so its direction is dropped at once.
  std::array<Vec3, GeometryModel::kSamplePoints> samples;
  std::size_t sample_count = 0;
  if (c.request.cold_interior_cull && !c.B.interior().empty()) {
    for (const Vec3& p : c.A.sample_points()) samples[sample_count++] = c.X_BA * p;
  }
  // The other way round, when A has inside cells: points of B's surface in
  // them at the query pose (in A's frame). A start that leaves one of them
  // in such a cell collides too (B's surface crosses A's, or the component
  // of B a containment test looks at lies inside A). Against an open scene
  // this is the only cull.
  std::array<Vec3, GeometryModel::kSamplePoints> enclosed;
  std::size_t enclosed_count = 0;
  if (c.request.cold_interior_cull) {
    enclosed_count =
        static_cast<std::size_t>(PointsEnclosedBy(c.A, c.X_BA, c.B, enclosed, &d.scratch));
    const Pose X_AB = c.X_BA.Inverse();
    for (std::size_t k = 0; k < enclosed_count; ++k) enclosed[k] = X_AB * enclosed[k];
  }
  // The outcome of a sweep from the start x_from (not known to be free)
  // towards the query pose.
  auto sweep_in_from = [&](const Vec3& x_from, Vec3* x_out) {
    if (c.B.interior().AnyInside(std::span(samples.data(), sample_count), x_from) ||
        c.A.interior().AnyInside(std::span(enclosed.data(), enclosed_count),
                                 -(c.X_BA.R.transpose() * x_from))) {
      return SweepOutcome::kStartColliding;
    }
    return SweepFrom(c, x_from, Vec3::Zero(), x_out, true, true);
  };
  // The contact along escape direction u, swept from just inside depth
  // `bound` (from outside the bounding spheres while it is infinite); a
  // colliding start on the far side of the body from contact `*near` gets
  // a second start closer in. Leaves the start used in *start.
  auto contact_along = [&](const Vec3& u, double bound, const Vec3* near, Vec3* start, Vec3* x) {
    if (!std::isfinite(bound)) {
      *start = OutsideAlong(c, u);
      return Sweep(c, *start, Vec3::Zero(), x);
    }
    // Only a contact shallower than the bound by the iteration's own
    // improvement tolerance is worth a refinement.
    const double reach = bound * (1 - c.request.improvement_tolerance);
    *start = u * reach;
    // Most of these starts overlap (a shallower contact is rare).
    SweepOutcome o = sweep_in_from(*start, x);
    if (o == SweepOutcome::kStartColliding && near != nullptr &&
        u.dot(*near) < kColdPocketCos * bound) {
      // The far side of the body the contact leaves by: its start just
      // inside that depth can lie past a free pocket (the probe between a
      // bunny's ears), so one more start closer in.
      *start = u * (kColdPocketStart * reach);
      o = sweep_in_from(*start, x);
    }
    return o == SweepOutcome::kHit;
  };
  // Refines the contact x a sweep has just reached (its features in
  // data.ccd) and keeps it when it beats the best answer.
  auto refine_contact = [&](Vec3 x) {
    d.cold_answer_features.swap(d.best_features);  // keep the best answer's
    d.best_features = d.ccd.features;
    d.cold_contact_features = d.ccd.features;
    const Vec3 x_contact = x;
    int its = 0;
    PdStatus s = Refine(c, &x, &its);
    *iterations += its;
    if (x.norm() > x_contact.norm()) {
      // The refinement ended deeper than it began (its final check found the
      // answer not free beyond and fell back to the line's contact from
      // outside): the swept contact itself is free beyond, as the sweep came
      // through free space along its direction.
      x = x_contact;
      d.best_features.swap(d.cold_contact_features);
      s = PdStatus::kPenetratingSolved;
    }
    if (x.norm() < best_norm) {
      best_norm = x.norm();
      *best = x;
      *status = s;
      have_best = true;
    } else {
      d.best_features.swap(d.cold_answer_features);  // back to the best answer's
    }
  };
  if (c.request.cold_contacts_first && count > 1) {
    // Each contact found lies inside the one before (its start does), so
    // they come shallowest last.
    d.cold_contacts.clear();
    double bound = best_norm;
    for (int k = 0; k < count; ++k) {
      Vec3 start, x;
      if (!contact_along(ColdDirection(fixed, k, count), bound,
                         d.cold_contacts.empty() ? nullptr : &d.cold_contacts.back().x, &start,
                         &x)) {
        continue;
      }
      d.cold_contacts.push_back({start, x});
      bound = x.norm();
    }
    // Shallowest first, while a contact can still beat the refined answer.
    for (auto it = d.cold_contacts.rbegin(); it != d.cold_contacts.rend(); ++it) {
      if (it->x.norm() >= best_norm * (1 - c.request.improvement_tolerance)) break;
      Vec3 x;
      // The same sweep again (its start is known to be free), for the
      // contact's features.
      if (Sweep(c, it->start, Vec3::Zero(), &x)) refine_contact(x);
    }
  }
  for (int k = 0; k < count + local; ++k) {
    if (k >= count && !have_best) break;
    const Vec3 u =
        k < count ? ColdDirection(fixed, k, count) : LocalDirection(best->normalized(), k - count);
    Vec3 start, x;
    if (contact_along(u, best_norm, have_best ? best : nullptr, &start, &x)) refine_contact(x);
  }
  return have_best;
}

}  // namespace

namespace {

// The algorithm proper, in B's frame: A at X_BA, B at the identity. The
// result's "_W" fields hold B-frame values until ComputePdt maps them.
void PdtCore(const GeometryModel& A, const Pose& X_BA, const GeometryModel& B,
             const PenetrationRequest& request, PdQueryData* data, PenetrationResult* result,
             Clock::time_point t0) {
  ResetPenetrationResult(PdMode::kTranslational, X_BA, result);
  const double size = std::min(A.mesh().size(), B.mesh().size());
  PdtContext c{A, X_BA, B, request, *data, std::max(request.contact_epsilon, 1e-12) * size};
  auto finish = [&](PdStatus status) {
    result->status = status;
    result->collision_queries = c.collision_queries;
    result->ccd_queries = c.ccd_queries;
    result->time_us = std::chrono::duration<double, std::micro>(Clock::now() - t0).count();
  };

  if (!Colliding(c, Vec3::Zero())) {
    data->contact_space_valid_ = false;
    if (request.use_coherence) {
      data->Remember({X_BA.t, X_BA.R, Vec3::Zero()});
    }
    finish(PdStatus::kSeparated);
    return;
  }

  // 1. Free start and out-projection.
  Vec3 best = Vec3::Zero();
  bool have_best = false;
  // Contact-space start; when its in-projection collides, the probe has
  // moved into the surface faster than the stored contact can follow (or
  // the stored planes miss a contact that is about to close): the small
  // push-outs of stored configurations would collide too, so only the
  // nearest one's farther push is tried before the pull-back along the
  // stored direction. That push still lands next to the answer where a probe
  // slides along a groove; the pull-back from outside lands several
  // iterations away.
  Vec3 x_c;
  const SweepOutcome from_space = ContactSpaceStart(c, &x_c);
  if (from_space == SweepOutcome::kHit) {
    best = x_c;
    have_best = true;
    data->best_features = data->ccd.features;
  } else if (CoherentStart(
                 c, from_space == SweepOutcome::kStartColliding ? Pushes::kFarOnly : Pushes::kAll,
                 &x_c)) {
    best = x_c;
    have_best = true;
    data->best_features = data->ccd.features;
  }
  bool exact = false;
  if (!have_best && request.convex_shortcut && A.convex() && B.convex()) {
    // Cold start between convex polytopes: the exact answer directly. The
    // iteration would only confirm it (each of its sweeps meets every
    // contact feature again), so it is skipped.
    const ConvexPdtResult cr =
        ConvexPdt(A.mesh(), *A.gauss_arcs(), X_BA, B.mesh(), *B.gauss_arcs(), kX_BB);
    if (cr.overlapping) {
      ProximityRequest preq;
      preq.tolerance = c.eps;
      ProximityResult pres;
      pres.pairs.swap(data->best_features);
      Proximity(A, Shifted(X_BA, cr.translation_W), B, kX_BB, preq, &pres, &data->scratch);
      data->best_features.swap(pres.pairs);
      best = cr.translation_W;
      have_best = true;
      exact = true;
    }
  }
  int iterations = 0;
  PdStatus status = PdStatus::kPenetratingCapReached;
  if (exact) {
    status = PdStatus::kPenetratingSolved;
  } else if (have_best) {
    status = Refine(c, &best, &iterations);
  } else if (!ColdSearch(c, &best, &status, &iterations)) {
    result->failure = "no contact found along the out-projection from a free start";
    finish(PdStatus::kFailed);
    return;
  }
  result->iterations = iterations;
  result->translation_W = best;
  result->depth = best.norm();
  result->X_WA_result = Shifted(X_BA, best);
  for (const FeaturePair& f : data->best_features) {
    if (f.n_W.squaredNorm() > 0.5) result->features.push_back({f.type, f.a, f.b, f.p_WB, f.n_W});
  }
  if (request.compute_regions) {
    BuildRegions(data->best_features, best, request.region_radius * A.mesh().size(),
                 &data->cluster_of, &result->regions);
  }
  if (request.use_coherence) {
    BuildPlanes(data->best_features, best, &data->planes);
    data->contact_space_B.clear();
    for (const ContactPlane& q : data->planes) {
      data->contact_space_B.push_back({q.n, q.b + q.n.dot(X_BA.t)});
    }
    data->contact_space_R_BA = X_BA.R;
    data->contact_space_p_BAo = X_BA.t + best;
    data->contact_space_valid_ = !data->contact_space_B.empty();
    data->Remember({result->X_WA_result.t, X_BA.R,
                    result->depth > 0 ? Vec3(best / result->depth) : Vec3(Vec3::Zero())});
  }
  finish(status);
}

}  // namespace

void ComputePdt(const GeometryModel& A, const Pose& X_WA, const GeometryModel& B, const Pose& X_WB,
                const PenetrationRequest& request, PdQueryData* data, PenetrationResult* result) {
  const auto t0 = Clock::now();
  if (FailOnNonFinitePoses(PdMode::kTranslational, X_WA, X_WB, result)) {
    result->time_us = std::chrono::duration<double, std::micro>(Clock::now() - t0).count();
    return;
  }
  // Work in B's frame: the answer then depends only on the relative pose, so
  // a common rigid motion of probe and scene moves the answer with it (up to
  // the rounding of X_BA), and the coherence cache is naturally relative to B.
  const Pose X_BA = X_WB.Inverse() * X_WA;
  PdtCore(A, X_BA, B, request, data, result, t0);
  result->translation_W = X_WB.R * result->translation_W;
  result->X_WA_result = X_WB * result->X_WA_result;
  for (ContactFeature& f : result->features) {
    f.p_W = X_WB * f.p_W;
    f.n_W = X_WB.R * f.n_W;
  }
  for (ContactRegion& r : result->regions) {
    r.p_W = X_WB * r.p_W;
    r.n_W = X_WB.R * r.n_W;
    r.local_depth_W = X_WB.R * r.local_depth_W;
  }
  result->rotation_axis_W = X_WB.R * result->rotation_axis_W;
}

}  // namespace hapticpd::pd
