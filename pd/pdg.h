// Generalized penetration depth under the object norm (PolyDepth++;
// ../shared/docs/ALGORITHMS.md "PDg").
//
//   PDg(A, B) = min sigma(q_o, q) over rigid poses q of A that do not overlap B,
//   sigma(q0, q1) = (1/V) * integral over A of |x(q1) - x(q0)|^2 dV
//                 = z^T M z,  z = (v, t),  M = diag(4 Ixx/V, 4 Iyy/V, 4 Izz/V, 1, 1, 1).
// (I the unit-density principal moments, V the volume: I/V is the probe's
// mean squared distance from its centre of mass per axis pair. A probe whose
// real mass distribution differs from a uniform solid, e.g. a scene file's
// `inertia` override, sets PenetrationRequest::principal_inertia_over_mass
// and M uses 4 I/m instead: PdgMetricDiagonal.)
//
// Configuration coordinates z (relative to the query pose q_o), in A's body
// frame Ab (centre of mass C, principal axes; MassProperties::X_MB) at q_o:
//   * v: vector part of the unit quaternion (w >= 0) of the body-frame
//     relative rotation, R_WAb(q) = R_WAb(q_o) * R(v);
//   * t: displacement of the centre of mass, p_WC(q) = p_WC(q_o) + R_WAb(q_o) t.
// The answer is a contact configuration found by continuous collision
// detection and checked along the rigid motion from q_o (centre of mass on a
// straight line, constant angular velocity: InterpolateRigid): pushed a hair
// further along that motion the probe is free, pulled back a hair it
// collides. It is an upper bound of the exact PDg and locally optimal. When
// the iteration starts from the PDt answer (no usable coherence, or
// PenetrationRequest::pdg_always_pdt_start) it never ends above PDt
// (keep-the-best); from a motion-coherent start it follows its own local
// optimum, which is usually lower and occasionally higher than PDt's
// (PenetrationRequest::pdg_pdt_check_period compares it with PDt's every
// that many queries).
//
// Out-projection (a free pose back to the contact space towards q_o) is exact
// translational CCD of the centre of mass at the rotation reached, and a
// rotation sweep (bisection with collision queries, then translational CCD)
// only when the rotation alone separates the probe: see OutProject in pdg.cc
// for why (cost).
//
// Result conventions (pd/penetration.h, mode kGeneralized):
//   * depth = sqrt(sigma) (m), sigma (m^2);
//   * translation_W = p_WC(result) - p_WC(query): the centre-of-mass
//     displacement T_pd - T_o in W (so X_WA_result.t != X_WA.t + translation_W
//     when the answer rotates);
//   * X_WA_result: the full answer pose of A's mesh frame (rotation included);
//   * rotation_angle in [0, pi] and unit rotation_axis_W: R_WA(result) =
//     AngleAxis(rotation_angle, rotation_axis_W) * R_WA(query), i.e. the
//     rotation about C that, with the translation, separates the probe;
//   * features: contact feature pairs at the answer (points on B, normals
//     from B towards A, W); regions are not computed for PDg (its wrench is
//     the spring to the answer pose, PdgWrench).
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "pd/geometry_model.h"
#include "pd/material.h"
#include "pd/pdt.h"
#include "pd/penetration.h"
#include "pd/queries.h"

namespace hapticpd::pd {

// ---------------------------------------------------------------------------
// The in-projection QP

/// A half-space a . z >= b in the 6-D configuration space z = (v, t).
struct Constraint6 {
  Vec6 a = Vec6::Zero();
  double b = 0;
};

enum class QpStatus : std::uint8_t {
  kSolved,      ///< z is the exact minimiser (KKT conditions hold)
  kInfeasible,  ///< the constraints admit no point; z is left at the last iterate
  kCapReached,  ///< iteration cap (a safeguard; not reached on sane input)
};

/// Exact solver of the small strictly convex QP of the PDg in-projection:
///
///   min z^T diag(m) z   subject to   a_i . z >= b_i,   z in R^6,  m > 0,
///
/// by the dual active-set method of Goldfarb and Idnani (1983) on the scaled
/// variable y = diag(sqrt(m)) z: it starts at the unconstrained minimum z = 0
/// and adds the most violated constraint while dropping those whose
/// multiplier would turn negative, so it needs no feasible start, keeps the
/// active set linearly independent (at most six rows; degenerate and
/// duplicate rows are handled) and terminates with the exact optimum or a
/// proof of infeasibility. No allocation once Reserve() covers the row count.
class MetricQp {
 public:
  void Reserve(std::size_t rows) { rows_.reserve(rows); }
  void Clear() { rows_.clear(); }
  /// Adds a . z >= b. Rows with a ~ 0 are dropped (0 >= b is either trivially
  /// true or unsatisfiable noise).
  void Add(const Vec6& a, double b);
  std::size_t size() const { return rows_.size(); }

  /// Solves with the diagonal metric `m` (all entries > 0). On kSolved, `z`
  /// is the minimiser and `multipliers` (if given, size() entries) the KKT
  /// multipliers of the rows (>= 0, zero for inactive rows).
  QpStatus Solve(const Vec6& m, Vec6* z, std::vector<double>* multipliers = nullptr);

 private:
  struct Row {
    Vec6 a;  ///< scaled and normalised: a_i diag(1/sqrt(m)) / |.|
    double b;
    double scale;  ///< |a_i diag(1/sqrt(m))|, to map multipliers back
  };
  std::vector<Constraint6> rows_;
  std::vector<Row> scaled_;
};

// ---------------------------------------------------------------------------
// The object norm

/// sigma of the relative configuration z = (v, t) for `mp` (ALGORITHMS.md).
double ObjectNormSquared(const MassProperties& mp, const Vec6& z);

/// The diagonal of the metric M that PDg uses for a probe with mass
/// properties `mp` under `request`: ObjectNormMetric(mp) (rotational weights
/// 4 I/V of the uniform solid), or with request.principal_inertia_over_mass
/// = (Ixx, Iyy, Izz)/m (m^2) the rotational weights 4 Ixx/m, 4 Iyy/m,
/// 4 Izz/m; the translational weights are 1 either way. sigma = z^T M z.
Vec6 PdgMetricDiagonal(const MassProperties& mp, const PenetrationRequest& request);

/// z of the pose X_WA1 of A's mesh frame relative to X_WA0 (both in the same
/// frame W), with the quaternion taken in the hemisphere w >= 0.
Vec6 RelativeConfiguration(const MassProperties& mp, const Pose& X_WA0, const Pose& X_WA1);

/// Inverse of RelativeConfiguration: the pose of A's mesh frame at z. A
/// vector part with |v| > 1 (outside the chart) is clamped to |v| = 1.
Pose PoseAtConfiguration(const MassProperties& mp, const Pose& X_WA0, const Vec6& z);

// ---------------------------------------------------------------------------
// PDg

/// Per-session, per-(probe, body) mutable state of PDg: the SE(3) motion
/// coherence cache, the PDt state used for the PDt start, and every scratch
/// buffer. Reuse one across frames; after warm-up nothing is allocated. Never
/// share between threads.
class PdgQueryData {
 public:
  PdgQueryData();

  /// Forget the motion-coherence caches (SE(3) and PDt), e.g. after a teleport.
  void ResetCoherence() {
    coherence_size_ = 0;
    pdt.ResetCoherence();
  }
  int coherence_size() const { return coherence_size_; }

  // --- internal state below; public for the algorithm's translation unit.
  struct CoherenceEntry {
    Pose X_BA_query;        ///< probe pose (mesh frame) relative to B at a past query
    Pose X_BA_answer;       ///< its answer (== query for a free pose)
    Vec6 z = Vec6::Zero();  ///< the answer's configuration relative to its query
    bool contact = false;
    double sigma = 0;  ///< the answer's sigma (0 for a free pose)
  };
  static constexpr int kCoherenceSlots = 8;
  std::array<CoherenceEntry, kCoherenceSlots> coherence;
  int coherence_head_ = 0;
  int coherence_size_ = 0;
  int queries_since_pdt_ = 0;  ///< penetrating queries since PDt last ran
  void Remember(const CoherenceEntry& e);

  PdQueryData pdt;               ///< PDt's own session state (the PDt start)
  PenetrationResult pdt_result;  ///< the PDt answer of the current query
  QueryScratch scratch;
  CollisionResult collision;
  CcdResult ccd;
  ProximityResult proximity;
  std::vector<FeaturePair> best_features;
  std::vector<TrianglePair> best_pairs;     ///< triangle pairs near the best contact
  std::vector<FeaturePair> extra_features;  ///< a non-improving contact's pairs
  MetricQp qp;
};

/// Generalized PD of probe A at X_WA against body B at X_WB (mode
/// kGeneralized; conventions above and in pd/penetration.h). Uses request
/// fields like ComputePdt (contact_epsilon, max_iterations,
/// improvement_tolerance, use_coherence, cold_start_directions for the PDt
/// start), pdg_iteration_budget (a work bound on the iterations) and
/// principal_inertia_over_mass for its metric (PdgMetricDiagonal;
/// result.sigma is measured in it); compute_regions and region_radius are
/// ignored. A non-finite or non-positive inertia override fails (kFailed).
void ComputePdg(const GeometryModel& A, const Pose& X_WA, const GeometryModel& B, const Pose& X_WB,
                const PenetrationRequest& request, PdgQueryData* data, PenetrationResult* result);

/// Wrench of a PDg result (seed eqs. 10-11): f = k (T_pd - T_o) at the
/// probe's centre of mass (k = material.stiffness, T the centre of mass) and
/// tau = xi theta omega (xi = material.rotational_stiffness, theta and omega
/// the answer's rotation angle and axis): both push the probe towards the
/// answer pose. W frame, torque about the centre of mass at the query pose.
/// Zero for a separated or failed result. kForceOnly leaves the torque zero.
Wrench PdgWrench(const PenetrationResult& result, const Material& material,
                 WrenchTerms terms = WrenchTerms::kForceAndTorque);

/// The wrench of any PD result: PdgWrench for mode kGeneralized, otherwise
/// PenaltyWrench (regions) about `p_WAcm`, or with kForceOnly PenaltyForce
/// (the same force, torque zero and not computed).
Wrench PdWrench(const PenetrationResult& result, const Material& material, const Vec3& p_WAcm,
                WrenchTerms terms = WrenchTerms::kForceAndTorque);

}  // namespace hapticpd::pd
