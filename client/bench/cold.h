// `hapticpd-bench cold`: how good and how fast cold PD queries are (no
// motion coherence: the first frame after an injection, a teleport, every
// one-shot `hapticpd pd`). Random deep poses with uniformly random
// rotations on probe/scene pairs from the shared models (open and closed,
// full and decimated) and the procedural shapes; each answer verified with
// FCL and compared with reference bounds computed independently of pd/:
//
//   * PDt: the directional-sampling upper bound of client/bench/ground_truth.h
//     (PdtUpperBound) at kColdPdtDirections uniformly random directions plus
//     kColdPdtDirections / 4 around the best at each of the spreads 0.2, 0.05,
//     0.01 and 0.002, each direction bisected 40 times with FCL's boolean
//     collide, a candidate accepted only when FCL finds it free and pd's
//     containment test finds neither body inside the other; on convex
//     pairs, the exact PDt of Bullet's GJK/EPA instead.
//   * PDg: the smaller of the PDt bound (a translation is a rigid motion) and
//     PdgUpperBound at kColdPdgRotations rotations about the centre of mass
//     (up to kColdPdgMaxAngle) times kColdPdgDirections translation
//     directions, refined around the best; and the cold PDt answer itself
//     (sigma <= PDt^2 must hold on every pose).
//
// A pose's depth is the PDt bound over the probe's bounding-box diagonal;
// poses deeper than `max_depth_fraction` are redrawn.
#pragma once

#include <nlohmann/json.hpp>

#include <cstdint>
#include <filesystem>
#include <iosfwd>
#include <string>
#include <vector>

#include "client/bench/scenarios.h"
#include "pd/penetration.h"
#include "tests/oracles/fcl_oracle.h"

namespace hapticpd::bench {

inline constexpr int kColdPdtDirections = 2000;
inline constexpr int kColdPdgRotations = 48;
inline constexpr int kColdPdgDirections = 24;
inline constexpr double kColdPdgMaxAngle = 0.5;  // rad

/// A probe/scene pair of the cold benchmark (B at the identity).
struct ColdPair {
  std::string name;
  std::string probe_name, scene_name;
  pd::ModelPtr probe, scene;
  bool convex = false;  ///< both convex: the exact PDt is the reference
};

/// The pairs: with the shared models in `models_dir` (empty or missing:
/// none) the model pairs, then the procedural pairs. `notes` (optional)
/// receives one line per pair and what replaced a missing model.
std::vector<ColdPair> BuildColdPairs(const std::string& models_dir, bool procedural_only,
                                     std::vector<std::string>* notes);

/// One pose of a pair with its reference bounds.
struct ColdPose {
  std::string pair;
  Quat q_WA = Quat::Identity();  ///< the rotation X_WA is built from (stored, so that the
                                 ///< pose round-trips through JSON bit for bit)
  Pose X_WA;
  double depth_fraction = 0;  ///< PDt reference / probe bounding-box diagonal
  double pdt_reference = 0;   ///< upper bound, or exact on convex pairs (m)
  bool pdt_exact = false;
  Vec3 pdt_reference_dir_W = Vec3::UnitZ();  ///< direction of the PDt reference
  double pdg_reference = 0;                  ///< best rigid-motion bound (m, sqrt sigma)
};

struct ColdOptions {
  std::string models;  ///< "" : procedural pairs only
  bool procedural_only = false;
  int poses = 16;  ///< per pair
  std::uint64_t seed = 1;
  double max_depth_fraction = 0.3;
  double min_depth_fraction = 0.01;
  int pdt_directions = kColdPdtDirections;
  int pdg_rotations = kColdPdgRotations;
  int pdg_directions = kColdPdgDirections;
  /// A stored pose set (ColdPosesToJson) to query instead of drawing new
  /// poses: its references are reused, so no sampling runs. Its pairs
  /// must all be among the pairs built.
  std::string poses_from;
  /// PenetrationRequest::cold_start_directions of every query.
  int cold_directions = pd::PenetrationRequest{}.cold_start_directions;
  /// PenetrationRequest::pdg_cold_turn_starts of every PDg query.
  int turn_starts = pd::PenetrationRequest{}.pdg_cold_turn_starts;
  /// PenetrationRequest::pdg_cold_local_search of every PDg query.
  int local_search = pd::PenetrationRequest{}.pdg_cold_local_search;
  /// PenetrationRequest::cold_interior_cull of every query.
  bool interior_cull = pd::PenetrationRequest{}.cold_interior_cull;
};

/// Draws `options.poses` colliding poses per pair (a uniformly random
/// rotation, the probe's centre of mass near a random scene vertex) whose
/// PDt reference is within the depth range, with their references.
std::vector<ColdPose> MakeColdPoses(const std::vector<ColdPair>& pairs, const ColdOptions& options,
                                    std::ostream* log);

/// The stored form of a pose set (tests/data/cold/): the options' densities
/// and every pose with its references.
nlohmann::json ColdPosesToJson(const std::vector<ColdPose>& poses, const ColdOptions& options);
std::vector<ColdPose> ColdPosesFromJson(const nlohmann::json& j);

/// Independent check of a PD answer along its own motion (InterpolateRigid
/// from the query pose to the answer, a translation for PDt): pushed `rel`
/// of the motion further out, free (FCL collide, and no containment by
/// pd's point-in-mesh test); pulled back by `rel`, colliding.
struct ContactCheck {
  bool free_out = false, colliding_in = false;
  bool ok() const { return free_out && colliding_in; }
};
class ColdVerifier {
 public:
  explicit ColdVerifier(const ColdPair& pair);
  ContactCheck Check(const Pose& X_WA, const pd::PenetrationResult& r, double rel = 1e-6);
  /// Free by FCL and not contained (FCL does not see containment).
  bool Free(const Pose& X_WA);
  bool Colliding(const Pose& X_WA) { return !Free(X_WA); }
  const testing::FclModel& fa() const { return fa_; }
  const testing::FclModel& fb() const { return fb_; }

 private:
  const ColdPair& pair_;
  testing::FclModel fa_, fb_;
  pd::QueryScratch scratch_;
  pd::CollisionResult collision_;
};

enum class ColdKind { kPdt, kPdg, kPdgBudget };
const char* ToString(ColdKind k);

/// One cold answer against its references.
struct ColdAnswer {
  std::string pair;
  ColdKind kind = ColdKind::kPdt;
  double depth_fraction = 0;
  pd::PdStatus status = pd::PdStatus::kFailed;
  double depth = 0, reference = 0, ratio = 0;
  bool exact_reference = false;
  int iterations = 0;
  double us = 0;
  ContactCheck check;
  bool above_pdt = false;  ///< PDg only: sqrt(sigma) > the cold PDt answer (1e-9 relative)
  /// PDt answers above 1.01x only: the angle (deg) between the answer's and
  /// the reference's directions, and the ratio reached when PDt starts from
  /// the reference's basin (a free pose just outside the reference, through
  /// the motion-coherence cache).
  double angle_deg = 0;
  double ratio_from_reference_basin = 0;
  /// When no free pose lies just outside the reference (pushed out by 0.1 %
  /// or more along its line): how far beyond it the line is free before the
  /// probe collides again (m). A reference wedged in such a sliver of free
  /// space is reached by the sampling bound's bisection, not from outside.
  double reference_free_width = 0;
};

/// The cold queries of each pose: PDt, PDg without the work budget (as the
/// one-shot command), PDg with the default budget. Each on its own query
/// data, coherence off, with `cold_directions` escape directions
/// (PenetrationRequest::cold_start_directions) and `turn_starts` PDg turn
/// starts (PenetrationRequest::pdg_cold_turn_starts), the interior cull as
/// `interior_cull` (PenetrationRequest::cold_interior_cull), `local_search`
/// candidates of unbudgeted PDg's local search
/// (PenetrationRequest::pdg_cold_local_search); time is the wall clock of
/// the call.
std::vector<ColdAnswer> RunColdQueries(
    const std::vector<ColdPair>& pairs, const std::vector<ColdPose>& poses, bool diagnose,
    int cold_directions = pd::PenetrationRequest{}.cold_start_directions,
    int turn_starts = pd::PenetrationRequest{}.pdg_cold_turn_starts,
    bool interior_cull = pd::PenetrationRequest{}.cold_interior_cull,
    int local_search = pd::PenetrationRequest{}.pdg_cold_local_search);

struct ColdSummary {
  ColdKind kind = ColdKind::kPdt;
  int count = 0, failed = 0, unverified = 0, cap_reached = 0, above_pdt = 0;
  double ratio_median = 0, ratio_p95 = 0, ratio_max = 0;
  int above_1_01 = 0, above_1_10 = 0;
  double p50_us = 0, p99_us = 0, max_us = 0;
};
std::vector<ColdSummary> SummarizeCold(const std::vector<ColdAnswer>& answers);

struct ColdReport {
  std::string load_average;  ///< /proc/loadavg at the start
  std::vector<std::string> notes;
  std::vector<ColdPose> poses;
  std::vector<ColdAnswer> answers;
  std::vector<ColdSummary> summary;
};

ColdReport RunCold(const ColdOptions& options, std::ostream* log);
nlohmann::json ToJson(const ColdReport& report);
void PrintCold(std::ostream& os, const ColdReport& report);
/// Ratio against depth for each kind, and time against depth; `title` goes
/// into the file.
void WriteColdSvg(const std::filesystem::path& path, const ColdReport& report,
                  const std::string& title);

}  // namespace hapticpd::bench
