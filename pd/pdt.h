// Translational penetration depth by iterative contact-space projection
// (PolyDepth; ../shared/docs/ALGORITHMS.md "PDt").
//
//   PDt(A, B) = min |d| such that A translated by d does not overlap B.
//
// The answer is a contact configuration verified by continuous collision
// detection (an upper bound of the exact PDt, locally optimal), with the
// contact features used there and, on request, contact regions with local
// depths. Conventions (frames, signs) are those of pd/penetration.h.
#pragma once

#include <array>
#include <limits>
#include <vector>

#include "pd/geometry_model.h"
#include "pd/penetration.h"
#include "pd/queries.h"

namespace hapticpd::pd {

/// A half-space n . x >= b in the probe's translation space (world frame,
/// relative to the query pose).
struct ContactPlane {
  Vec3 n = Vec3::Zero();
  double b = 0;
};

/// Per-session, per-(probe, body) mutable state: the motion-coherence cache
/// and every scratch buffer a query needs. Reuse one across frames; after
/// the first few queries nothing is allocated. Never share between threads.
class PdQueryData {
 public:
  PdQueryData();

  /// Forget the motion-coherence cache (e.g. after a teleport).
  void ResetCoherence() {
    coherence_size_ = 0;
    contact_space_valid_ = false;
  }
  int coherence_size() const { return coherence_size_; }

  // --- internal state below; public for the algorithm's translation unit.
  struct CoherenceEntry {
    Vec3 p_BAo = Vec3::Zero();  ///< probe origin in B's frame
    Mat3 R_BA = Mat3::Identity();
    Vec3 dir_B = Vec3::Zero();  ///< PD direction in B's frame (zero: a free pose)
  };
  static constexpr int kCoherenceSlots = 8;
  std::array<CoherenceEntry, kCoherenceSlots> coherence;
  int coherence_head_ = 0;
  int coherence_size_ = 0;
  void Remember(const CoherenceEntry& e);
  /// The last answer's local contact space, in B's frame and absolute:
  /// n . p_BAo >= b for the probe origin p_BAo, with the orientation it
  /// was found at and a point satisfying it (the answer). The next frame
  /// in-projects onto it before any sweep (contact-space coherence).
  std::vector<ContactPlane> contact_space_B;
  Mat3 contact_space_R_BA = Mat3::Identity();
  Vec3 contact_space_p_BAo = Vec3::Zero();
  bool contact_space_valid_ = false;

  QueryScratch scratch;
  CollisionResult collision;
  CcdResult ccd;
  std::vector<FeaturePair> best_features;
  std::vector<ContactPlane> planes;
  std::vector<ContactPlane> carried_planes;
  std::vector<int> cluster_of;
  /// Cold search: the best answer's features while another is refined.
  std::vector<FeaturePair> cold_answer_features;
  /// Cold search: the features of the contact being refined, as swept.
  std::vector<FeaturePair> cold_contact_features;
  /// Cold search, request.cold_contacts_first: the escape directions'
  /// contacts (offsets in B's frame) and the free starts they were swept
  /// from, deepest first.
  struct ColdContact {
    Vec3 start;
    Vec3 x;
  };
  std::vector<ColdContact> cold_contacts;
  /// Cold search: only answers shallower than this (m) are wanted; every
  /// direction's sweep starts at this depth (a colliding start drops the
  /// direction) instead of outside the bounding spheres. PDg sets it to the
  /// depth of the start it already has for the query it runs PDt in.
  double cold_search_bound = std::numeric_limits<double>::infinity();
};

/// B in its own frame: the PDt and PDg cores work in B's frame, B at the
/// identity.
inline const Pose kX_BB = Pose::Identity();

/// Solves min |x|^2 subject to n_i . x >= b_i (primal active set from the
/// feasible point `x0`; at most three independent constraints are active in
/// 3-D). *x is the exact minimiser or, should the iteration cap (64 + 4 per
/// plane) be reached on a degenerate plane set, the last feasible iterate.
/// Both serve PDt's callers alike: any feasible point is a valid target for
/// the next sweep, which the iteration then checks for improvement.
void SolveMinNormQp(const std::vector<ContactPlane>& planes, const Vec3& x0, Vec3* x);

/// Translational PD of probe A at X_WA against body B at X_WB.
void ComputePdt(const GeometryModel& A, const Pose& X_WA, const GeometryModel& B, const Pose& X_WB,
                const PenetrationRequest& request, PdQueryData* data, PenetrationResult* result);

/// Clusters the result's features into regions (used by ComputePdt when
/// request.compute_regions is set; exposed for PDg). `d_W` is the PD
/// translation; region points are moved back to the query pose.
void BuildRegions(const std::vector<FeaturePair>& features, const Vec3& d_W, double radius,
                  std::vector<int>* scratch, std::vector<ContactRegion>* regions);

}  // namespace hapticpd::pd
