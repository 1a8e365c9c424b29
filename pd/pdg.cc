#include "pd/pdg.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <span>
#include <string>
#include <utility>

#include "pd/primitives.h"

namespace hapticpd::pd {

// ---------------------------------------------------------------------------
// The in-projection QP (Goldfarb-Idnani dual active set, unit Hessian after
// scaling)

void MetricQp::Add(const Vec6& a, double b) {
  if (!a.allFinite() || !std::isfinite(b) || !(a.squaredNorm() > 0)) return;
  rows_.push_back({a, b});
}

namespace {

// Orthonormal basis Q (columns 0..q-1) and upper-triangular R of the active
// rows N = Q R by modified Gram-Schmidt with one re-orthogonalisation pass.
struct ActiveFactor {
  Eigen::Matrix<double, 6, 6> Q;
  Eigen::Matrix<double, 6, 6> R;
  int q = 0;
};

void Factor(const std::array<const Vec6*, 6>& cols, int q, ActiveFactor* f) {
  f->q = q;
  for (int j = 0; j < q; ++j) {
    Vec6 v = *cols[j];
    for (int k = 0; k < j; ++k) f->R(k, j) = 0;
    for (int pass = 0; pass < 2; ++pass) {
      for (int k = 0; k < j; ++k) {
        const double c = f->Q.col(k).dot(v);
        f->R(k, j) += c;
        v -= c * f->Q.col(k);
      }
    }
    const double n = v.norm();
    f->R(j, j) = n;
    f->Q.col(j) = n > 0 ? Vec6(v / n) : Vec6(Vec6::Zero());
  }
}

// Splits a into its component in span(active) (coefficients r in the active
// rows' basis, r = N^+ a) and the rest (returned).
Vec6 Project(const ActiveFactor& f, const Vec6& a, std::array<double, 6>* r) {
  Vec6 rest = a;
  std::array<double, 6> c{};
  for (int pass = 0; pass < 2; ++pass) {
    for (int k = 0; k < f.q; ++k) {
      const double ck = f.Q.col(k).dot(rest);
      c[k] += ck;
      rest -= ck * f.Q.col(k);
    }
  }
  for (int j = f.q - 1; j >= 0; --j) {  // back substitution R r = c
    double s = c[j];
    for (int k = j + 1; k < f.q; ++k) s -= f.R(j, k) * (*r)[k];
    (*r)[j] = s / f.R(j, j);
  }
  return rest;
}

}  // namespace

QpStatus MetricQp::Solve(const Vec6& m, Vec6* z_out, std::vector<double>* multipliers) {
  const Vec6 sinv = m.cwiseSqrt().cwiseInverse();
  scaled_.clear();
  double b_scale = 0;
  bool zero_row_violated = false;
  for (const Constraint6& c : rows_) {
    const Vec6 a = c.a.cwiseProduct(sinv);
    const double n = a.norm();
    if (!(n > 0) || !std::isfinite(n)) {
      scaled_.push_back({Vec6::Zero(), c.b, 0});
      zero_row_violated = zero_row_violated || c.b > 0;
      continue;
    }
    scaled_.push_back({a / n, c.b / n, n});
    b_scale = std::max(b_scale, std::abs(c.b / n));
  }
  if (multipliers) multipliers->assign(rows_.size(), 0.0);
  if (zero_row_violated) {
    z_out->setZero();
    return QpStatus::kInfeasible;
  }
  const int m_rows = static_cast<int>(scaled_.size());
  // Feasibility tolerance in the scaled space (units of sqrt(sigma)).
  const double tol = 1e-12 * std::max(b_scale, 1e-300);
  constexpr double kDependent = 1e-20;  // |rest|^2 of a unit row: in the active span

  Vec6 y = Vec6::Zero();
  std::array<int, 6> act{};
  std::array<double, 6> u{};
  std::array<const Vec6*, 6> cols{};
  int q = 0;
  ActiveFactor factor;
  auto drop = [&](int k) {
    for (int j = k; j + 1 < q; ++j) {
      act[j] = act[j + 1];
      u[j] = u[j + 1];
      cols[j] = cols[j + 1];
    }
    --q;
  };
  const int cap = 50 + 12 * (m_rows + 6);
  int steps = 0;
  QpStatus status = QpStatus::kCapReached;
  while (steps < cap) {
    // Most violated row not in the active set.
    int p = -1;
    double worst = -tol;
    for (int i = 0; i < m_rows; ++i) {
      if (scaled_[i].scale == 0) continue;
      const double s = scaled_[i].a.dot(y) - scaled_[i].b;
      if (s < worst) {
        bool active = false;
        for (int k = 0; k < q; ++k) active = active || act[k] == i;
        if (active) continue;
        worst = s;
        p = i;
      }
    }
    if (p < 0) {
      status = QpStatus::kSolved;
      break;
    }
    const Vec6& ap = scaled_[p].a;
    double up = 0;
    bool added = false;
    while (!added && steps < cap) {
      ++steps;
      Factor(cols, q, &factor);
      std::array<double, 6> r{};
      const Vec6 zdir = Project(factor, ap, &r);
      const double zz = zdir.squaredNorm();
      // Dual step length: the first active multiplier to reach zero.
      double t1 = std::numeric_limits<double>::infinity();
      int k_block = -1;
      for (int j = 0; j < q; ++j) {
        if (r[j] > 0) {
          const double ratio = u[j] / r[j];
          if (ratio < t1) {
            t1 = ratio;
            k_block = j;
          }
        }
      }
      const double sp = ap.dot(y) - scaled_[p].b;
      // With six active rows the null space is empty whatever rounding says.
      const double t2 =
          q < 6 && zz > kDependent ? -sp / zz : std::numeric_limits<double>::infinity();
      if (k_block < 0 && !std::isfinite(t2)) {
        *z_out = y.cwiseProduct(sinv);
        return QpStatus::kInfeasible;
      }
      const double t = std::min(t1, t2);
      if (std::isfinite(t2)) y += t * zdir;
      for (int j = 0; j < q; ++j) u[j] -= t * r[j];
      up += t;
      if (t2 <= t1) {
        act[q] = p;
        u[q] = up;
        cols[q] = &ap;
        ++q;
        added = true;
      } else {
        drop(k_block);
      }
    }
  }
  *z_out = y.cwiseProduct(sinv);
  if (multipliers && status == QpStatus::kSolved) {
    // Objective z^T M z = |y|^2 (not |y|^2 / 2) and rows were scaled by 1/scale.
    for (int k = 0; k < q; ++k) (*multipliers)[act[k]] = 2 * u[k] / scaled_[act[k]].scale;
  }
  return status;
}

// ---------------------------------------------------------------------------
// The object norm and the configuration chart

namespace {

Vec6 MetricDiagonal(const MassProperties& mp) { return ObjectNormMetric(mp).diagonal(); }

}  // namespace

double ObjectNormSquared(const MassProperties& mp, const Vec6& z) {
  return z.cwiseProduct(z).dot(MetricDiagonal(mp));
}

Vec6 PdgMetricDiagonal(const MassProperties& mp, const PenetrationRequest& request) {
  Vec6 m = MetricDiagonal(mp);
  if (request.principal_inertia_over_mass) m.head<3>() = 4 * *request.principal_inertia_over_mass;
  return m;
}

Vec6 RelativeConfiguration(const MassProperties& mp, const Pose& X_WA0, const Pose& X_WA1) {
  const Mat3 R_WAb0 = X_WA0.R * mp.X_MB.R;
  const Mat3 R_WAb1 = X_WA1.R * mp.X_MB.R;
  Quat q(R_WAb0.transpose() * R_WAb1);
  if (q.w() < 0) q.coeffs() = -q.coeffs();
  Vec6 z;
  z.head<3>() = q.vec();
  z.tail<3>() = R_WAb0.transpose() * (X_WA1 * mp.p_MC - X_WA0 * mp.p_MC);
  return z;
}

Pose PoseAtConfiguration(const MassProperties& mp, const Pose& X_WA0, const Vec6& z) {
  Vec3 v = z.head<3>();
  const double n2 = v.squaredNorm();
  double w = 0;
  if (n2 > 1) {
    v /= std::sqrt(n2);
  } else {
    w = std::sqrt(1 - n2);
  }
  const Mat3 R_WAb0 = X_WA0.R * mp.X_MB.R;
  const Mat3 R_WAb = R_WAb0 * Quat(w, v.x(), v.y(), v.z()).toRotationMatrix();
  Pose X;
  X.R = R_WAb * mp.X_MB.R.transpose();
  const Vec3 c = X_WA0 * mp.p_MC + R_WAb0 * z.tail<3>();
  X.t = c - X.R * mp.p_MC;
  return X;
}

// ---------------------------------------------------------------------------
// PDg

PdgQueryData::PdgQueryData() {
  scratch.stack.reserve(1024);
  scratch.heap.reserve(4096);
  collision.pairs.reserve(16);
  ccd.features.reserve(1024);
  proximity.pairs.reserve(1024);
  best_features.reserve(1024);
  best_pairs.reserve(8192);
  ccd.near_pairs.reserve(8192);
  extra_features.reserve(1024);
  qp.Reserve(2048);
  pdt_result.features.reserve(1024);
  pdt_result.regions.reserve(64);
}

void PdgQueryData::Remember(const CoherenceEntry& e) {
  coherence[coherence_head_] = e;
  coherence_head_ = (coherence_head_ + 1) % kCoherenceSlots;
  coherence_size_ = std::min(coherence_size_ + 1, kCoherenceSlots);
}

Wrench PdgWrench(const PenetrationResult& result, const Material& material, WrenchTerms terms) {
  Wrench w;
  if (result.status == PdStatus::kSeparated || result.status == PdStatus::kFailed) return w;
  w.force = material.stiffness * result.translation_W;
  if (terms == WrenchTerms::kForceAndTorque) {
    w.torque = material.rotational_stiffness * result.rotation_angle * result.rotation_axis_W;
  }
  return w;
}

Wrench PdWrench(const PenetrationResult& result, const Material& material, const Vec3& p_WAcm,
                WrenchTerms terms) {
  if (result.mode == PdMode::kGeneralized) return PdgWrench(result, material, terms);
  if (terms == WrenchTerms::kForceOnly) return Wrench{PenaltyForce(result, material), Vec3::Zero()};
  return PenaltyWrench(result, material, p_WAcm);
}

namespace {

using Clock = std::chrono::steady_clock;

// One query's fixed data. The core works in B's frame, as PDt's does: B sits
// at the identity (kX_BB), the answer depends only on the relative pose, and
// every pose, point and normal below is in B's frame (the queries' "W" is B).
struct PdgContext {
  const GeometryModel& A;
  const Pose& X_BA;  // query pose q_o
  const GeometryModel& B;
  const PenetrationRequest& request;
  PdgQueryData& data;
  double eps;   // contact tolerance (m): feature pairs closer than this are contacts
  Vec6 metric;  // diagonal of M
  Mat3 R_BAb0;  // body frame at the query pose
  Vec3 c0;      // centre of mass at the query pose
  // Cold: nothing cached to start from (a one-shot query, the first of a
  // run, or coherence off). A coherent run whose cached poses all collide
  // now is not: its frames keep their time for the servo rate.
  bool cold;
  // Iteration cap of each run of the iteration: pdg_cold_max_iterations on
  // a cold query without a work budget, else max_iterations.
  int max_iterations;
};

double Sigma(const PdgContext& c, const Vec6& z) { return z.cwiseProduct(z).dot(c.metric); }

Vec6 Z(const PdgContext& c, const Pose& X) { return RelativeConfiguration(c.A.mass(), c.X_BA, X); }

Pose At(const PdgContext& c, const Vec6& z) { return PoseAtConfiguration(c.A.mass(), c.X_BA, z); }

// Largest displacement of any point of A between two poses along the rigid
// interpolating motion (bound): |delta c| + theta r_max.
double MotionLength(const PdgContext& c, const Pose& X0, const Pose& X1) {
  const double ang = Eigen::AngleAxisd(X1.R * X0.R.transpose()).angle();
  return (X1 * c.A.mass().p_MC - X0 * c.A.mass().p_MC).norm() + ang * c.A.radius_about_com();
}

bool Colliding(PdgContext& c, const Pose& X) {
  CollisionRequest req;
  return Collide(c.A, X, c.B, kX_BB, req, &c.data.collision, &c.data.scratch);
}

enum class Sweep : std::uint8_t { kStartColliding, kHit, kMiss };

// Sweeps A by translation from X_from, at its rotation, until its centre of
// mass reaches X_to's (exact translational CCD). On a hit returns the
// contact pose (touching) with its feature pairs in data.ccd.features;
// otherwise *X_end is the free pose reached. With `check_start` (X_from not
// known to be free) the sweep decides whether X_from collides in its own
// traversal (kStartColliding), which costs much less than a separate Collide
// before it.
Sweep SweepTranslationFrom(PdgContext& c, const Pose& X_from, const Pose& X_to, Pose* X_contact,
                           Pose* X_end, bool check_start = true) {
  const Vec3& p_AC = c.A.mass().p_MC;
  const Vec3 d = X_to * p_AC - X_from * p_AC;
  CcdRequest req;
  req.feature_tolerance = c.eps;
  req.check_start = check_start;
  req.near_pairs = true;
  if (TranslationalCcd(c.A, X_from, d, c.B, kX_BB, req, &c.data.ccd, &c.data.scratch)) {
    *X_contact = c.data.ccd.X_WA_contact;
    return Sweep::kHit;
  }
  if (c.data.ccd.start_colliding) return Sweep::kStartColliding;
  *X_end = Pose{X_from.R, X_from.t + d};
  return Sweep::kMiss;
}

// The same from a pose known to be free.
bool SweepTranslation(PdgContext& c, const Pose& X_from, const Pose& X_to, Pose* X_contact,
                      Pose* X_end) {
  return SweepTranslationFrom(c, X_from, X_to, X_contact, X_end, false) == Sweep::kHit;
}

// Rotates A about its centre of mass from the free pose X_from towards the
// query rotation until it touches B, then closes the smallest remaining gap
// exactly by translational CCD. The motion ends at the query pose, which
// collides, so bisection on the motion's parameter with collision queries
// finds a free pose within a motion of eps / 2 of a colliding one. It need
// not be the first contact along the motion (a thin feature can pass in
// between), but any touching pose serves the out-projection. Conservative
// advancement (RigidCcd) would find the first contact, but its Distance
// queries slow down sharply near a contact on large meshes and its speed
// bound |dc| + theta r_max makes it crawl; a collision query stops at the
// first crossing pair.
bool SweepRotation(PdgContext& c, const Pose& X_from, Pose* X_contact) {
  const Vec3& p_AC = c.A.mass().p_MC;
  const Pose X_to{c.X_BA.R, X_from.t + X_from.R * p_AC - c.X_BA.R * p_AC};
  const double length = MotionLength(c, X_from, X_to);
  if (!(length > 0) || !Colliding(c, X_to)) return false;
  double lo = 0, hi = 1;
  for (int it = 0; it < 48 && (hi - lo) * length > 0.5 * c.eps; ++it) {
    const double mid = 0.5 * (lo + hi);
    (Colliding(c, InterpolateRigid(X_from, X_to, p_AC, mid)) ? hi : lo) = mid;
  }
  CcdResult& ccd = c.data.ccd;
  ccd.X_WA_contact = InterpolateRigid(X_from, X_to, p_AC, lo);
  ProximityRequest preq;
  preq.tolerance = c.eps;
  ProximityResult pres;
  pres.pairs.swap(ccd.features);
  Proximity(c.A, ccd.X_WA_contact, c.B, kX_BB, preq, &pres, &c.data.scratch);
  ccd.features.swap(pres.pairs);
  if (ccd.features.empty()) return false;
  const FeaturePair* closest = &c.data.ccd.features.front();
  for (const FeaturePair& f : c.data.ccd.features) {
    closest = f.distance < closest->distance ? &f : closest;
  }
  const Vec3 gap = closest->p_WB - closest->p_WA;
  const Pose X_s = c.data.ccd.X_WA_contact;
  CcdRequest req;
  req.feature_tolerance = c.eps;
  req.near_pairs = true;
  if (!TranslationalCcd(c.A, X_s, gap * (1 + 1e-6), c.B, kX_BB, req, &c.data.ccd,
                        &c.data.scratch)) {
    return false;
  }
  *X_contact = c.data.ccd.X_WA_contact;
  return true;
}

// Out-projection of the free pose X_free towards the query pose, sigma
// decreasing along the way: exact translational CCD of the centre of mass
// back to its query position at X_free's rotation; if the probe is still
// free there (the rotation alone separates it), a rotation sweep
// (SweepRotation) turning it back towards the query rotation.
//
// Deviation from the rigid-motion out-projection of ALGORITHMS.md: the
// motion is translation first, rotation only when needed, and the rotation
// sweep finds a touching pose, not necessarily the first contact. Rigid CCD
// steps before the translational finish cost several times as much for the
// same sigma (tests/bench/README.md, "Approaches tried"); the final contact
// is still checked along the rigid motion from q_o (Polish).
bool OutProject(PdgContext& c, const Pose& X_free, Pose* X_contact) {
  Pose X_end;
  if (SweepTranslation(c, X_free, c.X_BA, X_contact, &X_end)) return true;
  return SweepRotation(c, X_end, X_contact);
}

// OutProject from a pose not known to be free: kStartColliding when it
// collides (nothing else done), else whether a contact was reached.
Sweep OutProjectFrom(PdgContext& c, const Pose& X, Pose* X_contact) {
  Pose X_end;
  const Sweep s = SweepTranslationFrom(c, X, c.X_BA, X_contact, &X_end);
  if (s != Sweep::kMiss) return s;
  return SweepRotation(c, X_end, X_contact) ? Sweep::kHit : Sweep::kMiss;
}

// The rigid motion from the query pose to X, extended to parameter s
// (s = 1: X; s > 1: further along the same motion).
Pose AlongAnswer(const PdgContext& c, const Pose& X, double s) {
  return InterpolateRigid(c.X_BA, X, c.A.mass().p_MC, s);
}

// Linearised contact constraints at the contact pose X_c (configuration
// z_c): for each feature pair with unit normal n (B towards A), gap g and
// lever r = p - c(q_c),  dg = n . dc + (r x n) . dtheta_W  with
// dc = R_BAb0 dt and dtheta = R_BAb0 E(v_c) dv, so
// a = (E^T R_BAb0^T (r x n), R_BAb0^T n) and a . z >= a . z_c - max(g, 0).
// The gap is clamped at 0 so that z_c itself is feasible. Appends to data.qp.
void AddConstraints(PdgContext& c, const std::vector<FeaturePair>& features, const Pose& X_c,
                    const Vec6& z_c) {
  MetricQp& qp = c.data.qp;
  const Vec3 v = z_c.head<3>();
  // E blows up as w -> 0 (rotations near 180 degrees leave the chart); a
  // floor keeps the rows finite there, the CCD re-projection keeps answers
  // exact.
  const double w = std::max(std::sqrt(std::max(0.0, 1 - v.squaredNorm())), 1e-3);
  Mat3 vx;
  vx << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  const Mat3 E = 2 * (w * Mat3::Identity() + v * v.transpose() / w + vx);
  const Mat3 G = E.transpose() * c.R_BAb0.transpose();
  const Vec3 c_c = X_c * c.A.mass().p_MC;
  for (const FeaturePair& f : features) {
    const Vec3& n = f.n_W;
    if (!(n.squaredNorm() > 0.5)) continue;  // degenerate normal: dropped
    Vec6 a;
    a.head<3>() = G * (f.p_WA - c_c).cross(n);
    a.tail<3>() = c.R_BAb0.transpose() * n;
    qp.Add(a, a.dot(z_c) - std::max(f.signed_distance, 0.0));
  }
}

// PDt's contact features as feature pairs (touching: gap 0).
void FeaturesFromPdt(const PenetrationResult& r, std::vector<FeaturePair>* out) {
  out->clear();
  for (const ContactFeature& f : r.features) {
    FeaturePair p;
    p.type = f.type;
    p.a = f.a;
    p.b = f.b;
    p.p_WA = f.p_W;
    p.p_WB = f.p_W;
    p.n_W = f.n_W;
    out->push_back(p);
  }
}

struct Best {
  Pose X;
  Vec6 z = Vec6::Zero();
  double sigma = std::numeric_limits<double>::infinity();
  bool valid = false;
  /// data.best_pairs holds every triangle pair within eps at X (the pairs
  /// near the contact of the sweep that reached it).
  bool near_pairs = false;
};

void Accept(PdgContext& c, const Pose& X, Best* best) {
  best->X = X;
  best->z = Z(c, X);
  best->sigma = Sigma(c, best->z);
  best->valid = true;
  best->near_pairs = false;
}

// Accepts the contact X that the last sweep (data.ccd) reached, with its
// feature pairs and near triangle pairs.
void AcceptSwept(PdgContext& c, const Pose& X, Best* best) {
  Accept(c, X, best);
  c.data.best_features = c.data.ccd.features;
  // Swapped, not copied (thousands of pairs at a deep contact): the next
  // sweep clears ccd.near_pairs before filling it.
  std::swap(c.data.best_pairs, c.data.ccd.near_pairs);
  best->near_pairs = true;
}

// Free start from the SE(3) coherence cache: the two cached poses nearest to
// the query (object norm); a cached contact is pushed out a little further
// along its own motion, a cached free pose is used as is; the first that is
// free now is out-projected towards the query pose. *cached_sigma: the
// sigma of the cached answer the start came from (0 for a cached free pose).
bool CoherentStart(PdgContext& c, Pose* X_contact, double* cached_sigma) {
  PdgQueryData& d = c.data;
  if (!c.request.use_coherence || d.coherence_size_ == 0) return false;
  // The two entries nearest to the query pose under the object norm.
  std::array<double, PdgQueryData::kCoherenceSlots> dist{};
  std::array<int, PdgQueryData::kCoherenceSlots> order{};
  for (int i = 0; i < d.coherence_size_; ++i) {
    dist[i] = Sigma(c, Z(c, d.coherence[i].X_BA_query));
    order[i] = i;
  }
  const int tries = std::min(2, d.coherence_size_);
  std::partial_sort(order.begin(), order.begin() + tries, order.begin() + d.coherence_size_,
                    [&](int x, int y) { return dist[x] < dist[y]; });
  for (int k = 0; k < tries; ++k) {
    const PdgQueryData::CoherenceEntry& e = d.coherence[order[k]];
    *cached_sigma = e.contact ? e.sigma : 0.0;
    if (!e.contact) {
      const Sweep s = OutProjectFrom(c, e.X_BA_query, X_contact);
      if (s != Sweep::kStartColliding) return s == Sweep::kHit;
      continue;
    }
    // The cached answer's motion applied to the current query pose (follows
    // the probe as it turns), then the cached answer pose itself (stays put
    // relative to B), each pushed a little further along its motion.
    for (int variant = 0; variant < 2; ++variant) {
      const Pose X0 = variant == 0 ? c.X_BA : e.X_BA_query;
      const Pose X1 = variant == 0 ? At(c, e.z) : e.X_BA_answer;
      const double motion = MotionLength(c, X0, X1);
      if (!(motion > 0)) continue;
      for (double push : {2.0, 20.0}) {
        const Pose X_f = InterpolateRigid(X0, X1, c.A.mass().p_MC, 1 + push * c.eps / motion);
        const Sweep s = OutProjectFrom(c, X_f, X_contact);
        if (s != Sweep::kStartColliding) return s == Sweep::kHit;
      }
    }
  }
  return false;
}

// The answer must be a contact along its own motion from the query pose:
// pushed a hair further along it A must be free, pulled back a hair it must
// collide. Returns false when the push collides (the answer was reached
// sideways, into a pocket); a free pull-back means a better contact on the
// same ray, which is out-projected and checked again.
// First-order behaviour of the contact feature pairs at `best` under its own
// motion from the query pose: `opens_all` when moving further along the
// motion opens every pair (each normal has a clear positive component along
// its point's velocity), `closes_one` when moving back closes a touching pair.
void ClassifyAlongMotion(const PdgContext& c, const Best& best,
                         const std::vector<FeaturePair>& features, bool* opens_all,
                         bool* closes_one) {
  const Vec3 c1 = best.X * c.A.mass().p_MC;
  const Eigen::AngleAxisd aa(best.X.R * c.X_BA.R.transpose());
  const Vec3 omega = aa.angle() * aa.axis();
  const double touching = 1e-3 * c.eps;
  *opens_all = !features.empty();
  *closes_one = false;
  for (const FeaturePair& f : features) {
    const Vec3 v = (c1 - c.c0) + omega.cross(f.p_WA - c1);  // d p / d s at s = 1
    const double speed = v.norm();
    const double cosine = speed > 0 ? f.n_W.dot(v) / speed : 0.0;
    *opens_all = *opens_all && cosine > 0.05;
    *closes_one = *closes_one || (cosine > 0.05 && f.distance <= touching);
  }
}

// Whether one of the triangle pairs in data.best_pairs crosses with A at X.
// True means A collides at X; false decides nothing unless X is near best.
bool CrossesNearPair(PdgContext& c, const Pose& X_BA) {
  const Mesh& ma = c.A.mesh();
  const Mesh& mb = c.B.mesh();
  Index fa_last = -1;
  std::array<Vec3, 3> ta;
  for (const TrianglePair& p : c.data.best_pairs) {
    if (p.a != fa_last) {
      fa_last = p.a;
      for (int k = 0; k < 3; ++k) ta[k] = X_BA * ma.vertices()[ma.triangles()[p.a][k]];
    }
    const Triangle& tb = mb.triangles()[p.b];
    const auto& V = mb.vertices();
    if (internal::TrianglesIntersect(ta[0], ta[1], ta[2], V[tb[0]], V[tb[1]], V[tb[2]])) {
      return true;
    }
  }
  return false;
}

// Does A collide at X, a pose within `reach` (a bound on any point's
// displacement) of the contact `best`? Every triangle pair within eps at
// best is in data.best_pairs (when best.near_pairs), so for reach < eps only
// those pairs can cross at X (and a motion that short cannot enclose one
// mesh in the other without crossing): they are tested alone instead of a
// full Collide, which at a free pose near contact has to visit every
// nearby box pair.
bool CollidingNear(PdgContext& c, const Best& best, const Pose& X, double reach) {
  if (!best.near_pairs || !(reach < 0.5 * c.eps)) return Colliding(c, X);
  return CrossesNearPair(c, X);
}

bool Polish(PdgContext& c, Best* best) {
  constexpr double kPush = 1e-6;  // of the motion
  constexpr double kPull = 1e-9;
  constexpr int kRounds = 3;
  for (int round = 0;; ++round) {
    if (!(best->sigma > 0)) return true;
    bool opens_all = false, closes_one = false;
    ClassifyAlongMotion(c, *best, c.data.best_features, &opens_all, &closes_one);
    // The collision queries only where first order does not decide.
    if (!opens_all && CollidingNear(c, *best, AlongAnswer(c, best->X, 1 + kPush),
                                    kPush * MotionLength(c, c.X_BA, best->X))) {
      return false;
    }
    if (round == kRounds || closes_one) return true;
    const Pose X_in = AlongAnswer(c, best->X, 1 - kPull);
    Pose X_new;
    if (OutProjectFrom(c, X_in, &X_new) != Sweep::kHit || !(Sigma(c, Z(c, X_new)) < best->sigma)) {
      return true;
    }
    AcceptSwept(c, X_new, best);
  }
}

// An iteration's QP answer X_star back to the contact space. Free:
// out-project towards the query pose. In collision (the contact space curves
// away): keep X_star's rotation and back off by translation along the mean
// contact normal until free, then sweep back towards X_star (exact
// translational CCD); failing that, back off from the best contact (along
// the mean normal, else along the answer's motion) and sweep towards
// X_star's centre of mass. True with the contact in *X_new.
bool ReprojectQpAnswer(PdgContext& c, const Best& best, const Pose& X_star, Pose* X_new) {
  const Sweep from_star = OutProjectFrom(c, X_star, X_new);
  if (from_star != Sweep::kStartColliding) return from_star == Sweep::kHit;
  Vec3 n_avg = Vec3::Zero();
  for (const FeaturePair& f : c.data.best_features) n_avg += f.n_W;
  const bool have_normal = n_avg.norm() > 1e-12;
  Pose X_end;
  if (have_normal) {
    n_avg.normalize();
    for (double scale : {0.5, 2.0}) {
      const double back = scale * std::sqrt(best.sigma) + 2 * c.eps;
      const Pose X_back{X_star.R, X_star.t + n_avg * back};
      const Sweep s = SweepTranslationFrom(c, X_back, X_star, X_new, &X_end);
      if (s == Sweep::kHit) return true;
      if (s == Sweep::kMiss) break;
    }
  }
  Sweep s = Sweep::kStartColliding;
  if (have_normal) {
    Pose X_back = best.X;
    X_back.t += n_avg * (2 * c.eps);
    s = SweepTranslationFrom(c, X_back, X_star, X_new, &X_end);
  }
  if (s == Sweep::kStartColliding) {
    const double motion = MotionLength(c, c.X_BA, best.X);
    const Pose X_back = AlongAnswer(c, best.X, 1 + 2 * c.eps / std::max(motion, 1e-300));
    s = SweepTranslationFrom(c, X_back, X_star, X_new, &X_end);
  }
  return s == Sweep::kHit || (s == Sweep::kMiss && OutProject(c, X_end, X_new));
}

// Steps 2-5, iterated from the free start *best: linearised contact space,
// exact QP, re-projection; *best improves in place. A contact that brings no
// improvement still tells where the contact space curves away: its rows join
// the best contact's for up to two retries, and then the step is tried
// shorter (TryShorterSteps). Returns kPenetratingSolved at a
// local optimum, kPenetratingCapReached at the iteration cap or the work
// budget.
// The work budget of one query's iterations (PenetrationRequest::
// pdg_iteration_budget): box and triangle pair tests of its traversals (PDt's
// inside it included) since the first iteration began, the turn starts'
// sweeps and iterations included.
struct WorkBudget {
  std::uint64_t limit = 0;  // 0: none
  std::uint64_t start = 0, last = 0, costliest = 0;
  bool started = false;
};

std::uint64_t Work(const PdgContext& c) {
  return c.data.scratch.node_tests + c.data.scratch.triangle_tests + c.data.pdt.scratch.node_tests +
         c.data.pdt.scratch.triangle_tests;
}

// Whether the work so far plus the costliest iteration so far fits in the
// budget (the next iteration would likely not overrun it).
bool Fits(const PdgContext& c, const WorkBudget& b) {
  return b.limit == 0 || !b.started || Work(c) - b.start + b.costliest <= b.limit;
}

// Whether another iteration may start: it fits, or it is the query's first.
bool MayIterate(const PdgContext& c, WorkBudget* b) {
  const std::uint64_t now = Work(c);
  if (!b->started) {
    b->started = true;
    b->start = b->last = now;
    return true;
  }
  b->costliest = std::max(b->costliest, now - b->last);
  b->last = now;
  return Fits(c, *b);
}

// The QP step to z_star whose re-projection brought no improvement, tried
// at half and a quarter of its length: sigma is convex, so every point of
// the segment from best to z_star is below best's sigma, and nearer best
// the linearised contact space is nearer the true one (a long step
// overshoots where the contact space curves). True when a shorter step's
// contact improved *best (accepted). Cold queries only: in a coherent run
// the next frame's iteration goes on from this answer with fresh
// constraints, and the frame keeps its time for the servo rate.
bool TryShorterSteps(PdgContext& c, Best* best, const Vec6& z_star) {
  constexpr int kHalvings = 2;
  Vec6 dz = z_star - best->z;
  for (int h = 0; h < kHalvings; ++h) {
    dz *= 0.5;
    Pose X_new;
    if (ReprojectQpAnswer(c, *best, At(c, best->z + dz), &X_new) &&
        Sigma(c, Z(c, X_new)) < best->sigma * (1 - c.request.improvement_tolerance)) {
      AcceptSwept(c, X_new, best);
      return true;
    }
  }
  return false;
}

// The work (box and triangle pair tests) a coherent query may have spent
// before the periodic check against PDt runs in it: a quarter of the default
// budget.
constexpr std::uint64_t kPdtCheckWork = 2000;

PdStatus IterateContactSpace(PdgContext& c, Best* best, int* iterations, WorkBudget* budget) {
  PdStatus status = PdStatus::kPenetratingCapReached;
  bool have_extra = false;
  Pose X_extra;
  Vec6 z_extra = Vec6::Zero();
  int retries = 0;
  const int first = *iterations;
  for (int it = 0; it < c.max_iterations; ++it) {
    if (!MayIterate(c, budget)) break;  // the next iteration would likely overrun: cap reached
    *iterations = first + it + 1;
    if (best->sigma <= 0) {
      status = PdStatus::kPenetratingSolved;
      break;
    }
    c.data.qp.Clear();
    AddConstraints(c, c.data.best_features, best->X, best->z);
    if (have_extra) AddConstraints(c, c.data.extra_features, X_extra, z_extra);
    if (c.data.qp.size() == 0) {
      status = PdStatus::kPenetratingSolved;
      break;
    }
    Vec6 z_star;
    if (c.data.qp.Solve(c.metric, &z_star) != QpStatus::kSolved) {
      status = PdStatus::kPenetratingSolved;  // no better point in the local contact space
      break;
    }
    const double sigma_star = Sigma(c, z_star);
    if (sigma_star >= best->sigma * (1 - c.request.improvement_tolerance)) {
      status = PdStatus::kPenetratingSolved;  // best is optimal in its contact space
      break;
    }
    const Pose X_star = At(c, z_star);
    Pose X_new;
    const bool found = ReprojectQpAnswer(c, *best, X_star, &X_new);
    if (!found || Sigma(c, Z(c, X_new)) >= best->sigma * (1 - c.request.improvement_tolerance)) {
      if (found && retries < 2 && !c.data.ccd.features.empty()) {
        ++retries;
        have_extra = true;
        X_extra = X_new;
        z_extra = Z(c, X_new);
        c.data.extra_features = c.data.ccd.features;
        continue;
      }
      if (c.cold && TryShorterSteps(c, best, z_star)) continue;
      status = PdStatus::kPenetratingSolved;  // no improvement: local optimum
      break;
    }
    AcceptSwept(c, X_new, best);
  }
  return status;
}

// Cold PDg: starts that turn as well as slide. PDt's answer keeps the query
// rotation, and the contact-space iteration from it is local: where a turn
// about the centre of mass frees the probe far more cheaply (a probe wedged
// across a cavity, a handle through a rim) the iteration never gets there.
// Each candidate spends a fraction of the best sigma so far on a turn about
// one of the probe's principal axes or diagonals (kTurnFractions, largest
// first) and the rest on a slide along the best answer's translation. A
// candidate that is free is out-projected towards the query pose (its sigma
// only falls on the way), so it beats the best answer, and the iteration
// goes on from it. Most candidates collide and cost one early-out collision
// test. Every candidate slides: a turn about the centre of mass alone leaves
// a deep probe colliding.
constexpr std::array<double, 3> kTurnFractions{0.9, 0.5, 0.2};
constexpr int kTurnAxes = 14;  // 3 principal axes both ways, 8 diagonals
static_assert(kPdgColdTurnStarts == static_cast<int>(kTurnFractions.size()) * kTurnAxes);

// The k-th turn axis in the probe's principal frame (z's rotation part).
Vec3 TurnAxis(int k) {
  if (k < 6) return (k % 2 == 0 ? 1.0 : -1.0) * Vec3::Unit(k / 2);
  k -= 6;
  return Vec3(k & 1 ? -1 : 1, k & 2 ? -1 : 1, k & 4 ? -1 : 1).normalized();
}

// Whether A at X collides with B for certain (PenetrationRequest::
// cold_interior_cull), so the exact start check can be skipped: one of A's
// sample points lies in a cell wholly inside a closed B, or one of
// `enclosed` (points of B's surface, PointsEnclosedBy) in a cell wholly
// inside a closed A.
bool StartEnclosed(const PdgContext& c, const Pose& X, std::span<const Vec3> enclosed) {
  if (!c.request.cold_interior_cull) return false;
  if (!c.B.interior().empty()) {
    for (const Vec3& p : c.A.sample_points()) {
      if (c.B.interior().Inside(X * p)) return true;
    }
  }
  if (!enclosed.empty()) {
    const Pose X_AB = X.Inverse();
    for (const Vec3& p : enclosed) {
      if (c.A.interior().Inside(X_AB * p)) return true;
    }
  }
  return false;
}

// A cold start at X_start (not known to be free) out-projected towards the
// query pose; true when that gave a contact below *best, which is then
// accepted. Dropped before the exact start check where the interior cull
// (StartEnclosed, with `enclosed`) decides it collides, or, with
// `near_pairs_first`, where one of best's near triangle pairs crosses.
bool AcceptStart(PdgContext& c, Best* best, const Pose& X_start, std::span<const Vec3> enclosed,
                 bool near_pairs_first) {
  if (StartEnclosed(c, X_start, enclosed)) return false;
  if (near_pairs_first && best->near_pairs && CrossesNearPair(c, X_start)) return false;
  Pose X_contact;
  if (OutProjectFrom(c, X_start, &X_contact) != Sweep::kHit) return false;
  if (!(Sigma(c, Z(c, X_contact)) < best->sigma)) return false;
  AcceptSwept(c, X_contact, best);
  return true;
}

// `enclosed`: the scene's points inside a closed probe at the query pose
// (PointsEnclosedBy). With `iterate_each` the iteration goes on from every
// free candidate at once (within the work budget); without, the free
// candidates only lower *best and the caller iterates once from it.
// *accepted counts the free candidates.
PdStatus TurnStarts(PdgContext& c, Best* best, int* iterations, WorkBudget* budget, PdStatus status,
                    std::span<const Vec3> enclosed, bool iterate_each, int* accepted) {
  // A turn of at most about 29 degrees (|v| = sin(theta / 2)): the
  // linearised contact space is far from right beyond.
  constexpr double kMaxV = 0.25;
  int tried = 0;
  for (const double fraction : kTurnFractions) {
    for (int k = 0; k < kTurnAxes; ++k) {
      if (tried++ >= c.request.pdg_cold_turn_starts) return status;
      if (!Fits(c, *budget)) return PdStatus::kPenetratingCapReached;
      const Vec3 axis = TurnAxis(k);
      const double sigma0 = best->sigma * (1 - 1e-3);
      const double weight = axis.cwiseProduct(axis).dot(c.metric.head<3>());
      const double v = std::min(kMaxV, std::sqrt(fraction * sigma0 / weight));
      Vec6 z = Vec6::Zero();
      z.head<3>() = v * axis;
      const Vec3 t = best->z.tail<3>();
      if (t.norm() > 0) {
        z.tail<3>() = t.normalized() * std::sqrt(std::max(0.0, sigma0 - weight * v * v));
      }
      if (!AcceptStart(c, best, At(c, z), enclosed, false)) continue;
      ++*accepted;
      if (iterate_each) status = IterateContactSpace(c, best, iterations, budget);
    }
  }
  return status;
}

// Cold PDg without a work budget: a local search around the best answer.
// The iteration stops where the linearised contact space at the best
// contact admits no lower sigma, but the true contact space curves, and
// nearby poses at a slightly lower sigma are often free (on the cold
// benchmark's poses the answer was then 1-20 % above the sampled bound).
// Each candidate turns the best answer's rotation by a random vector of up
// to `scale` times kLocalTurn (in z's rotation part, sin(theta / 2)), tilts
// its translation direction by a random vector of about `scale` times
// kLocalTilt, and puts the probe on the level set at 0.999 of the best
// sigma; a free candidate is out-projected towards the query pose, so it
// beats the best answer. The scale grows after a free candidate and shrinks
// after one that collides (a (1+1) evolution strategy), and the search ends
// when it falls below kLocalEnd or after pdg_cold_local_search candidates.
// The generator's seed is fixed: the same query gives the same answer.
constexpr double kLocalTurn = 0.025;  // about 2.9 degrees at scale 1
constexpr double kLocalTilt = 0.03;   // rad, about, at scale 1
constexpr double kLocalGrow = 1.5;
constexpr double kLocalShrink = 0.85;
constexpr double kLocalEnd = 0.2;
constexpr double kLocalMaxScale = 10;

// SplitMix64 with Box-Muller normals: the same sequence with every standard
// library.
class LocalRandom {
 public:
  double Uniform() { return static_cast<double>(Next() >> 11) * 0x1.0p-53; }
  double Normal() {
    if (have_spare_) {
      have_spare_ = false;
      return spare_;
    }
    const double u1 = 1.0 - Uniform();  // (0, 1]
    const double u2 = Uniform();
    const double r = std::sqrt(-2 * std::log(u1));
    spare_ = r * std::sin(2 * kPi * u2);
    have_spare_ = true;
    return r * std::cos(2 * kPi * u2);
  }
  Vec3 Normal3() {
    const double x = Normal(), y = Normal();
    return Vec3(x, y, Normal());
  }

 private:
  static constexpr double kPi = 3.14159265358979323846;
  std::uint64_t Next() {
    std::uint64_t z = (state_ += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
  }
  std::uint64_t state_ = 0x5eed;
  double spare_ = 0;
  bool have_spare_ = false;
};

// Returns how many candidates were free (each lowered *best).
int LocalSearch(PdgContext& c, Best* best, std::span<const Vec3> enclosed) {
  LocalRandom rng;
  double scale = 1;
  int accepted = 0;
  for (int k = 0; k < c.request.pdg_cold_local_search && scale >= kLocalEnd; ++k) {
    const double sigma0 = best->sigma * (1 - 1e-3);
    const Vec3 turn = rng.Normal3().normalized() * (kLocalTurn * scale * rng.Uniform());
    const Vec3 tilt = rng.Normal3() * (kLocalTilt * scale);
    const double s = scale;
    scale *= kLocalShrink;  // undone below when the candidate is free
    Vec6 z = Vec6::Zero();
    z.head<3>() = best->z.head<3>() + turn;
    if (!(z.head<3>().norm() < 0.7)) continue;  // stay well inside the chart
    const double sigma_turn = Sigma(c, z);
    if (!(sigma_turn < sigma0)) continue;
    const Vec3 t = best->z.tail<3>();
    if (!(t.norm() > 0)) continue;
    z.tail<3>() = (t.normalized() + tilt).normalized() * std::sqrt(sigma0 - sigma_turn);
    // A candidate near the best contact mostly collides through one of its
    // triangle pairs: those are tried before the full start check.
    if (!AcceptStart(c, best, At(c, z), enclosed, true)) continue;
    ++accepted;
    scale = std::min(kLocalMaxScale, s * kLocalGrow);
  }
  return accepted;
}

// The answer `best` into *result (in the frame PdgCore works in).
void WriteAnswer(const PdgContext& c, const Best& best, PenetrationResult* result) {
  result->sigma = best.sigma;
  result->depth = std::sqrt(best.sigma);
  result->translation_W = c.R_BAb0 * best.z.tail<3>();
  result->X_WA_result = best.X;
  // Angle and axis from the whole quaternion of the relative rotation: from
  // z's vector part alone (w = sqrt(1 - |v|^2)) the angle near 180 degrees
  // is only good to about 1e-8.
  const Eigen::AngleAxisd aa(Quat(best.X.R * c.X_BA.R.transpose()));
  result->rotation_angle = aa.angle();
  if (aa.angle() > 0) result->rotation_axis_W = aa.axis();
  for (const FeaturePair& f : c.data.best_features) {
    result->features.push_back({f.type, f.a, f.b, f.p_WB, f.n_W});
  }
}

// The algorithm proper, in B's frame: A at X_BA, B at the identity. The
// result's "_W" fields hold B-frame values until ComputePdg maps them.
void PdgCore(const GeometryModel& A, const Pose& X_BA, const GeometryModel& B,
             const PenetrationRequest& request, PdgQueryData* data, PenetrationResult* result,
             Clock::time_point t0) {
  ResetPenetrationResult(PdMode::kGeneralized, X_BA, result);
  const double size = std::min(A.mesh().size(), B.mesh().size());
  const double eps = std::max(request.contact_epsilon, 1e-12) * size;
  const Mat3 R_BAb0 = X_BA.R * A.mass().X_MB.R;
  PdgContext c{A,
               X_BA,
               B,
               request,
               *data,
               eps,
               PdgMetricDiagonal(A.mass(), request),
               R_BAb0,
               X_BA * A.mass().p_MC,
               !request.use_coherence || data->coherence_size() == 0,
               request.max_iterations};
  if (c.cold && request.pdg_iteration_budget == 0) {
    c.max_iterations = request.pdg_cold_max_iterations;
  }
  auto finish = [&](PdStatus status) {
    result->status = status;
    result->time_us = std::chrono::duration<double, std::micro>(Clock::now() - t0).count();
  };

  const std::uint64_t work_at_start = Work(c);
  if (!Colliding(c, X_BA)) {
    if (request.use_coherence) data->Remember({X_BA, X_BA, Vec6::Zero(), false, 0.0});
    // Keep PDt's coherence in step when it runs every query.
    if (request.pdg_always_pdt_start) {
      ComputePdt(A, X_BA, B, kX_BB, request, &data->pdt, &data->pdt_result);
    }
    finish(PdStatus::kSeparated);
    return;
  }

  // 1. Free start: the SE(3) coherence cache, else the PDt answer (a contact
  // with the rotation unchanged).
  Best best, pdt_best;
  bool pdt_done = false;
  const PenetrationResult& pdt = data->pdt_result;
  auto run_pdt = [&](bool basin_lost) {
    PenetrationRequest pdt_request = request;
    pdt_request.compute_regions = false;
    // A lost basin inside a coherent run searches the fixed escape
    // directions only: the full cold search (the one-shot and first-frame
    // answer) costs several times more, and the next frames carry on from
    // whatever this one finds.
    // Only a PDt answer shallower than the start PDg already has can help:
    // the search's sweeps start at that depth.
    if (basin_lost) {
      pdt_request.cold_start_directions =
          std::min(pdt_request.cold_start_directions, kColdStartDirections);
      data->pdt.cold_search_bound = std::sqrt(best.sigma);
    }
    ComputePdt(A, X_BA, B, kX_BB, pdt_request, &data->pdt, &data->pdt_result);
    data->pdt.cold_search_bound = std::numeric_limits<double>::infinity();
    pdt_done = true;
    if (pdt.status == PdStatus::kPenetratingSolved ||
        pdt.status == PdStatus::kPenetratingCapReached) {
      Accept(c, pdt.X_WA_result, &pdt_best);
    }
  };
  // PDt as a start or a check: its answer replaces best where it is better
  // (returns whether it did), and the period of the check against PDt
  // starts again.
  auto try_pdt = [&](bool basin_lost) {
    data->queries_since_pdt_ = 0;
    run_pdt(basin_lost);
    if (!(pdt_best.valid && pdt_best.sigma < best.sigma)) return false;
    best = pdt_best;
    FeaturesFromPdt(pdt, &data->best_features);
    return true;
  };
  Pose X_coh;
  double cached_sigma = 0;
  if (CoherentStart(c, &X_coh, &cached_sigma)) AcceptSwept(c, X_coh, &best);
  // A coherent start much deeper than the answer it came from has lost that
  // answer's basin (the probe jumped, or the cached contact's way out closed
  // up): PDt's answer is tried too, else PDg can end far above PDt and stay
  // there for the frames that follow. PDt starts cold then: its own
  // coherence cache is as old as its last run, and from there it finds the
  // same worse basin.
  const double slack = 0.01 * A.mesh().size();
  const bool lost_basin =
      best.valid && std::sqrt(best.sigma) > 1.2 * std::sqrt(cached_sigma) + slack;
  if (lost_basin && !request.pdg_always_pdt_start) data->pdt.ResetCoherence();
  if (!best.valid || request.pdg_always_pdt_start || lost_basin) {
    try_pdt(lost_basin && !request.pdg_always_pdt_start);
  }
  if (!best.valid) {
    result->failure = pdt.status == PdStatus::kFailed
                          ? "no free start: " + pdt.failure
                          : "no free start (PDt found no contact, no coherent pose)";
    finish(PdStatus::kFailed);
    return;
  }

  WorkBudget budget;
  budget.limit = request.pdg_iteration_budget;
  PdStatus status = IterateContactSpace(c, &best, &result->iterations, &budget);
  if (c.cold && status != PdStatus::kPenetratingCapReached) {
    // With a work budget (the first frame of a run) the iteration goes on
    // from each free turn start at once, within the budget. Without (a
    // one-shot query) the turn starts and then the local search only lower
    // the best contact, and the iteration goes on once from the lowest.
    const bool unbudgeted = budget.limit == 0;
    std::array<Vec3, GeometryModel::kSamplePoints> enclosed;
    const int enclosed_count =
        request.cold_interior_cull && (request.pdg_cold_turn_starts > 0 ||
                                       (unbudgeted && request.pdg_cold_local_search > 0))
            ? PointsEnclosedBy(A, X_BA, B, enclosed, &data->scratch)
            : 0;
    const std::span<const Vec3> inside(enclosed.data(), enclosed_count);
    int found = 0;
    status =
        TurnStarts(c, &best, &result->iterations, &budget, status, inside, !unbudgeted, &found);
    if (unbudgeted) {
      found += LocalSearch(c, &best, inside);
      if (found > 0) status = IterateContactSpace(c, &best, &result->iterations, &budget);
    }
  }
  // The periodic check against PDt (pdg_pdt_check_period): once due, it runs
  // after the iteration of the first query that has spent little work (a
  // costly frame is not made costlier), and where PDt's answer is better the
  // iteration goes on from it.
  if (!pdt_done && request.pdg_pdt_check_period > 0 &&
      ++data->queries_since_pdt_ >= request.pdg_pdt_check_period &&
      Work(c) - work_at_start <= kPdtCheckWork && try_pdt(false)) {
    status = IterateContactSpace(c, &best, &result->iterations, &budget);
  }

  // Verified answer: a contact along its own motion; else the PDt answer.
  if (!Polish(c, &best)) {
    if (!pdt_done) run_pdt(false);
    if (pdt_best.valid) {
      best = pdt_best;
      FeaturesFromPdt(pdt, &data->best_features);
    }
  }

  WriteAnswer(c, best, result);
  if (request.use_coherence) data->Remember({X_BA, best.X, best.z, true, best.sigma});
  finish(status);
}

}  // namespace

void ComputePdg(const GeometryModel& A, const Pose& X_WA, const GeometryModel& B, const Pose& X_WB,
                const PenetrationRequest& request, PdgQueryData* data, PenetrationResult* result) {
  const auto t0 = Clock::now();
  if (FailOnNonFinitePoses(PdMode::kGeneralized, X_WA, X_WB, result)) {
    result->time_us = std::chrono::duration<double, std::micro>(Clock::now() - t0).count();
    return;
  }
  if (const auto& I = request.principal_inertia_over_mass;
      I && !(I->allFinite() && (I->array() > 0).all())) {
    ResetPenetrationResult(PdMode::kGeneralized, X_WA, result);
    result->status = PdStatus::kFailed;
    result->failure = "request.principal_inertia_over_mass: every entry must be finite and > 0";
    result->time_us = std::chrono::duration<double, std::micro>(Clock::now() - t0).count();
    return;
  }
  // Work in B's frame (as PDt): the answer depends only on the relative pose
  // and the coherence cache is naturally relative to B.
  const Pose X_BA = X_WB.Inverse() * X_WA;
  PdgCore(A, X_BA, B, request, data, result, t0);
  result->translation_W = X_WB.R * result->translation_W;
  result->X_WA_result = X_WB * result->X_WA_result;
  result->rotation_axis_W = X_WB.R * result->rotation_axis_W;
  for (ContactFeature& f : result->features) {
    f.p_W = X_WB * f.p_W;
    f.n_W = X_WB.R * f.n_W;
  }
}

}  // namespace hapticpd::pd
