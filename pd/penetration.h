// Penetration depth between a probe A and a scene body B: translational
// (PDt, PolyDepth) and generalized (PDg, PolyDepth++). Request and result
// types shared by both methods.
//
// Frames and signs:
//   * X_WA is the probe's pose in the world W, X_WB the scene body's. The
//     probe's mesh frame is whatever the model was built in; PDg works in the
//     probe's body frame (centre of mass, principal axes: MassProperties).
//   * The PD vector `translation_W` is the world displacement to apply to the
//     probe to separate it: X_WA_result.t = X_WA.t + translation_W (PDt).
//     depth = |translation_W| for PDt, sqrt(sigma) for PDg.
//   * Region normals n_W point from the scene towards the probe (the direction
//     the scene pushes the probe), local depths d_i = (d . n_i) n_i, and the
//     penalty force on the probe is f = sum k d_i.
//   * Torque is about the probe's centre of mass at its query pose, in W.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "pd/queries.h"
#include "pd/types.h"

namespace hapticpd::pd {

enum class PdMode : std::uint8_t { kTranslational, kGeneralized };

enum class PdStatus : std::uint8_t {
  kSeparated,              ///< no collision at the query pose: depth 0
  kPenetratingSolved,      ///< converged to a verified contact configuration
  kPenetratingCapReached,  ///< iteration cap (or PDg's work budget) hit; best verified contact
                           ///< returned
  kFailed,                 ///< no answer; `failure` says why
};

const char* ToString(PdStatus s);
const char* ToString(PdMode m);

/// The cold search's fixed escape directions: the centroid direction and
/// both bodies' +- principal axes.
inline constexpr int kColdStartDirections = 13;
/// The cold search's default number of escape directions: the fixed ones,
/// then a uniform sphere lattice of 128.
inline constexpr int kColdSearchDirections = kColdStartDirections + 128;
/// The most escape directions a cold search may be asked for.
inline constexpr int kMaxColdSearchDirections = 4096;
/// PDg's cold turn starts: 3 turn sizes times 14 axes.
inline constexpr int kPdgColdTurnStarts = 42;

struct PenetrationRequest {
  /// Contact tolerance as a fraction of the scene body's size (bounding-box
  /// diagonal, or the probe's if smaller): feature pairs closer than this at
  /// a contact configuration form the local contact space, and a sample this
  /// close to contact counts as "in contact".
  double contact_epsilon = 1e-4;
  /// Cap on projection iterations (each: in-projection, classification,
  /// re-projection).
  int max_iterations = 12;
  /// Relative improvement below which the iteration stops.
  double improvement_tolerance = 1e-4;
  /// PDg only: work budget of the iterations (steps 2-5, after the free
  /// start), in bounding-box pair and triangle pair tests (the counters of
  /// QueryScratch: unlike time, they do not depend on the machine's load). An
  /// iteration starts only while the work spent in the iterations plus the
  /// costliest iteration so far fits in the budget; the first always runs.
  /// A cold query's turn starts (pdg_cold_turn_starts) count against it.
  /// When it stops the query, the best verified contact so far is returned
  /// with kPenetratingCapReached, and motion coherence carries the
  /// optimisation on at the next query. It bounds the time of the deep
  /// queries where each iteration gains a fraction of a percent of sigma
  /// (what it costs in depth and saves in time: tests/bench/README.md,
  /// "PDg"). 0: no budget.
  std::uint64_t pdg_iteration_budget = 8000;
  /// Cluster contacts into regions with local depths (needed for force).
  bool compute_regions = true;
  /// Contacts whose normals agree within ~14 degrees form one region. With a
  /// positive radius (a fraction of the probe's size) such contacts farther
  /// apart than the radius form separate regions; 0 (default) clusters by
  /// normal only, so one planar contact is one region whatever its extent
  /// (each region adds k (d.n) n, so splitting a face contact into patches
  /// would multiply its force).
  double region_radius = 0;
  /// Use and update the motion-coherence cache in QueryData.
  bool use_coherence = true;
  /// Answer pairs of convex models (GeometryModel::convex) exactly with the
  /// separating-axis computation (pd/convex.h) instead of the general
  /// contact-space iteration. False runs the general iteration on them too
  /// (to compare the two, or to test the iteration on known answers).
  bool convex_shortcut = true;
  /// Cold start (nothing usable in the coherence cache) on non-convex
  /// models: how many escape directions the cold search tries. 1: the
  /// centroid direction only; up to kColdStartDirections: the first of the
  /// fixed directions (centroid, then both bodies' +- principal axes); more:
  /// the fixed ones and a uniform sphere lattice of the rest. Each direction
  /// whose out-projection beats the best answer so far is refined to its
  /// local optimum, and with more than one direction 24 more around the best
  /// answer follow. More directions find the right basin more often, at the
  /// cost of an early-out collision test each. Convex pairs start from the
  /// exact convex answer. At most kMaxColdSearchDirections.
  int cold_start_directions = kColdSearchDirections;
  /// Cold queries: an escape direction of PDt's cold search, or a PDg turn
  /// start, whose start puts one of the probe's sample points
  /// (GeometryModel::sample_points) in a cell wholly inside a closed scene
  /// (GeometryModel::interior), or leaves one of the scene's points found
  /// inside a closed probe at the query pose (PointsEnclosedBy) in a cell
  /// wholly inside the probe, is dropped without the exact start check,
  /// which would find that start colliding too. The answers are the
  /// same, for a few lookups instead of a search for a crossing triangle
  /// pair; under pdg_iteration_budget a budgeted PDg answer can improve, as
  /// the dropped starts spend none of it. False runs the exact check on
  /// every start (to compare the two).
  bool cold_interior_cull = true;
  /// Cold PDt search with more than one escape direction: sweep every
  /// direction for its contact first and refine the shallowest contacts,
  /// then sweep the directions again from just inside the refined answer,
  /// refining each new contact at once. False refines every contact that
  /// beats the best answer as soon as it is found (most of those
  /// refinements are beaten later): the answers are about as good, for more
  /// work (to compare the two).
  bool cold_contacts_first = true;
  /// PDg only: run PDt on every query and start from the better of its answer
  /// and the motion-coherent start (default: PDt only when coherence gives no
  /// start, or a start much deeper than the cached answer it came from: more
  /// than 1.2 times its depth plus 1% of the probe's size). Guarantees
  /// sqrt(sigma) <= |PDt| on every query at the price of a PDt; without
  /// coherence (use_coherence false) it always holds.
  bool pdg_always_pdt_start = false;
  /// PDg only, coherent runs: every this many penetrating queries PDt runs
  /// too (from its own coherence cache), after the iteration of the first
  /// query, once due, that has spent at most 2,000 box and triangle pair
  /// tests, and where PDt's answer is better the iteration goes on from it;
  /// 0: never. The coherent answer can stay in a basin where the probe is
  /// turned while PDt's answer, under the moving probe, gets shallower (on
  /// the hammer benchmark up to 1.36 times PDt's depth for 40 frames without
  /// the check, 1.06 times with it): this bounds how long such a drift lasts,
  /// for about one PDt every that many frames.
  int pdg_pdt_check_period = 16;
  /// PDg only, cold queries (nothing in the coherence cache: a one-shot
  /// query, the first of a run, or use_coherence false): how many turn
  /// starts follow the iteration from PDt's answer once it has converged, at
  /// most kPdgColdTurnStarts (all, the default); 0: none. Each turns the
  /// probe about one of its principal axes or diagonals by part of the best
  /// sigma so far, slides it along the best translation by the rest and,
  /// where that is free, out-projects and iterates from there: it finds the
  /// turns that free a wedged probe cheaply, which the local iteration from
  /// PDt's translation does not. Most cost one early-out collision test.
  /// They count against pdg_iteration_budget.
  int pdg_cold_turn_starts = kPdgColdTurnStarts;
  /// PDg only, cold queries without a work budget (pdg_iteration_budget 0,
  /// as one-shot queries run): after the turn starts, at most this many
  /// candidates of a local search around the best answer; 0: none. The
  /// iteration stops where the linearised contact space at the best contact
  /// admits no lower sigma, but the true one curves, and a pose a little
  /// turned and tilted from the best at a slightly lower sigma is often
  /// free. Each candidate costs about one early-out collision test; the
  /// search shrinks its steps after each colliding candidate and ends when
  /// they are small (typically after a few dozen). The turn starts' and the
  /// search's free candidates only lower the best contact, and the
  /// iteration goes on once from the lowest. The answers are
  /// deterministic.
  int pdg_cold_local_search = 200;
  /// PDg only, cold queries without a work budget: the iteration cap of
  /// each run of the iteration, instead of max_iterations. A deep
  /// cold query can gain a fraction of a percent of sigma per iteration for
  /// dozens of iterations; with a budget, the budget decides.
  int pdg_cold_max_iterations = 48;
  /// PDg only: the probe's principal moments of inertia about its centre of
  /// mass divided by its mass (m^2), along the body frame's axes
  /// (MassProperties::X_MB), e.g. (I, I, I) / m for an isotropic override of
  /// a probe of mass m (kg) and inertia I (kg m^2). The object norm's
  /// rotational weights become 4 I/m instead of the mesh's unit-density
  /// 4 I/V (PdgMetricDiagonal, pd/pdg.h). Unset (default): the mesh's. Every
  /// entry must be finite and > 0 (otherwise PDg fails, naming this field).
  std::optional<Vec3> principal_inertia_over_mass;
};

/// One contact feature pair used at the answer.
struct ContactFeature {
  FeatureType type = FeatureType::kVertexFace;
  Index a = -1;
  Index b = -1;
  Vec3 p_W = Vec3::Zero();  ///< contact point (on B) at the result pose
  Vec3 n_W = Vec3::Zero();  ///< unit normal from B towards A
};

/// A cluster of contacts with one normal and a local penetration depth.
struct ContactRegion {
  Vec3 p_W = Vec3::Zero();            ///< representative point, at the query pose
  Vec3 n_W = Vec3::Zero();            ///< unit normal from B towards A
  double depth = 0;                   ///< d . n_i (m), >= 0
  Vec3 local_depth_W = Vec3::Zero();  ///< (d . n_i) n_i
  int contacts = 0;                   ///< feature pairs merged into this region
};

struct PenetrationResult {
  PdStatus status = PdStatus::kFailed;
  PdMode mode = PdMode::kTranslational;
  std::string failure;  ///< reason, only for kFailed (not filled on the hot path otherwise)
  double depth = 0;     ///< |translation| (PDt) or sqrt(sigma) (PDg), metres
  Vec3 translation_W = Vec3::Zero();
  Pose X_WA_result;  ///< probe pose at the answer (contact configuration)
  std::vector<ContactFeature> features;
  std::vector<ContactRegion> regions;
  int iterations = 0;  ///< summed over every answer the cold search refined
  double time_us = 0;
  /// Work done: collision queries and CCD sweeps (each a BVH traversal).
  int collision_queries = 0;
  int ccd_queries = 0;
  // PDg only.
  double sigma = 0;           ///< object-norm squared distance (m^2)
  double rotation_angle = 0;  ///< radians, of the rotation from X_WA to X_WA_result
  Vec3 rotation_axis_W = Vec3::UnitZ();
};

/// Makes `result` a fresh answer of `mode` for the probe at X_WA: every
/// field as default-constructed (status kFailed until the query sets it),
/// X_WA_result = X_WA. Keeps the capacity of its vectors and string, so a
/// reused result allocates nothing.
void ResetPenetrationResult(PdMode mode, const Pose& X_WA, PenetrationResult* result);

/// For PDt and PDg: true, with `result` reset to a failed answer of `mode`
/// saying "non-finite pose (probe or scene body)", when either pose holds a
/// NaN or an infinity; false (and `result` untouched) otherwise.
bool FailOnNonFinitePoses(PdMode mode, const Pose& X_WA, const Pose& X_WB,
                          PenetrationResult* result);

}  // namespace hapticpd::pd
