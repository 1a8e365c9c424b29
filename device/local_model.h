// The device side's local contact model (model-mediated rendering): the
// server streams, besides its PD answers, a patch of every body's triangles
// near the probe; this module holds the patch and runs PD on it at the
// proxy's newest pose on its own thread, so the contact is rendered from the
// true surface at the pose the hand is at now, not the one it was at a round
// trip ago. Plain C++: the network Session (client/session.h) decodes the
// wire's GeometryPatch into a PatchDelta and hands it here.
//
// Which model answers (one rule, evaluated at every local step):
//   1. The patch answers when it covers the probe: the corners of the
//      probe's bounding box (its mesh frame) lie in the patch's region, and
//      in the cover of every body it holds (the body's pose taken at the
//      current server time), so no triangle the probe can touch is missing. The answer is PD on
//      the held triangles in the session's mode, through pd::BuildContactModel
//      (the server's rule), at the newest proxy sample.
//   2. Where the patch finds no contact but the server's newest answer (still
//      fresh, valid at this pose, and at least as deep as the probe's
//      thinnest extent) does, the server's answer is rendered: the probe may
//      be wholly inside a body, where no surface crosses it. A shallower
//      server contact is an old pose's: the patch knows better.
//   3. Where the patch does not cover the probe (no patch yet, the probe
//      outran it, a rejected patch, the stream quiet for longer than
//      `patch_quiet_s`, or broken), the server's answers are rendered as they
//      arrive, exactly as without a local model; with neither, the IR goes
//      stale and the servo loop fades the contact out. Under a patch the
//      probe has outrun, an answer is held back while the probe is outside
//      its validity region (it is for a pose the probe has left): the last
//      local IR stays, and fades as the probe leaves its validity.
// The server's answer seeds the local query: a body's query state starts
// afresh whenever its patch model is rebuilt, and then starts from the
// server's newest answer (its deepest row as a remembered contact, PDt's
// motion coherence), not from nothing.
// The server's answer is the reference the local one is checked against:
// when an answer arrives for a proxy sample the local model also answered,
// their deepest rows are compared (LocalModelStats::reference_*); a
// disagreement beyond 0.1 mm plus 5 % says the patch and the scene differ
// (or the two methods found different contact configurations).
// The servo loop counts per tick which source its IR came from
// (IntermediateRep::source, ServoStats).
//
// Threads: the network side calls Offer* (one thread at a time for each
// mailbox); the worker (Start, or Step for simulated time) is the only
// writer of the servo loop's IR mailbox. The servo loop itself is untouched:
// it still reads one mailbox.
#pragma once

#include <array>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include "device/ir.h"
#include "device/mailbox.h"
#include "device/servo_loop.h"
#include "device/stats.h"
#include "pd/contact_model.h"
#include "pd/scene_pd.h"

namespace hapticpd::device {

/// One body's part of a patch (the wire's BodyPatch, decoded).
struct PatchBodyDelta {
  std::string id;
  std::uint64_t key = 0;  ///< the body's geometry; a new key starts from nothing
  std::uint32_t triangle_count = 0;
  std::uint32_t vertex_count = 0;
  /// Where the body is: X_WB + velocity x (t - pose_time_ns), t on the
  /// server's clock.
  Pose X_WB;
  Vec3 v_W = Vec3::Zero();
  Vec3 w_W = Vec3::Zero();
  std::int64_t pose_time_ns = 0;
  pd::Material material;  ///< effective (probe and body in series)
  Vec3 cover_center_B = Vec3::Zero();
  double cover_radius = 0;
  std::vector<std::uint32_t> vertex_indices;
  std::vector<Vec3> vertices;
  std::vector<std::uint32_t> triangle_indices;
  std::vector<std::array<std::uint32_t, 3>> triangles;
  std::vector<std::uint32_t> dropped_triangles;
  bool truncated = false;
};

/// A patch (the wire's GeometryPatch, decoded): a delta on what is held.
struct PatchDelta {
  std::uint64_t sequence = 0;
  std::uint64_t scene_revision = 0;
  std::int64_t server_time_ns = 0;
  Vec3 center_W = Vec3::Zero();  ///< the region: every body reaching into it is held
  double radius = 0;
  std::vector<PatchBodyDelta> bodies;
  std::vector<std::string> dropped_bodies;
  std::size_t wire_bytes = 0;  ///< the message's size on the wire (statistics)
};

struct PatchLimits {
  std::size_t max_triangles_per_body = 8192;
  std::size_t max_bodies = 256;
};

/// The body pose of a patch at server time t (p + v dt; orientation turned
/// by w dt in W).
Pose PatchBodyPoseAt(const PatchBodyDelta& b, std::int64_t t_ns);

/// An immutable view of what is held, with every body's model built: what
/// the local model answers from while the next patch is applied and built.
struct PatchView {
  struct Body {
    PatchBodyDelta meta;      // pose, material, cover (no arrays)
    pd::ModelPtr model;       // null: the body holds no triangle
    std::uint64_t build = 0;  // changes with every rebuilt model
  };
  Vec3 center_W = Vec3::Zero();
  double radius = 0;
  std::vector<Body> bodies;
  /// True when every point (W) lies in the region and in the cover of
  /// every body at server time t.
  bool Covers(std::span<const Vec3> points_W, std::int64_t server_t_ns) const;
  /// The bodies holding triangles as PD bodies at server time t, and their
  /// build keys (a new key: the body's coherence cache must be reset).
  void Bodies(std::int64_t server_t_ns, std::vector<pd::SceneBody>* out,
              std::vector<std::uint64_t>* keys) const;
};

/// What the client holds: per body, triangles and vertices by their stable
/// index, its pose, material and cover. Not thread-safe (one thread owns it).
class PatchStore {
 public:
  explicit PatchStore(const PatchLimits& limits = {}) : limits_(limits) {}

  /// Applies `delta` whole, or not at all: returns "" or the problem (one
  /// line naming it: an index out of range, a non-finite coordinate, a
  /// triangle naming a vertex not held, a body over the size limit, a
  /// sequence not newer than the last).
  std::string Apply(const PatchDelta& delta);
  /// Forgets everything (stream broken, quiet too long).
  void Clear();
  bool empty() const { return !have_patch_; }
  std::uint64_t scene_revision() const { return scene_revision_; }
  std::size_t triangles_held() const;
  std::size_t bodies_held() const { return bodies_.size(); }

  /// The view of what is held (null when nothing is): models of bodies
  /// whose triangles changed are rebuilt here (allocates; milliseconds for
  /// thousands of triangles).
  std::shared_ptr<const PatchView> View();
  /// View()->Bodies (tests).
  void Bodies(std::int64_t server_t_ns, std::vector<pd::SceneBody>* out,
              std::vector<std::uint64_t>* keys);

  /// View()->Covers (tests).
  bool Covers(std::span<const Vec3> points_W, std::int64_t server_t_ns);

 private:
  struct Body {
    PatchBodyDelta meta;  // pose, material, cover (no arrays)
    std::unordered_map<std::uint32_t, std::array<std::uint32_t, 3>> tris;
    struct Vertex {
      Vec3 p;
      std::uint32_t refs = 0;  // held triangles using it
    };
    std::unordered_map<std::uint32_t, Vertex> verts;
    bool dirty = true;
    pd::ModelPtr model;
    std::uint64_t build = 0;  // bumps with every rebuilt model
  };
  std::string Check(const PatchDelta& d) const;
  PatchLimits limits_;
  bool have_patch_ = false;
  std::uint64_t sequence_ = 0;
  std::uint64_t scene_revision_ = 0;
  Vec3 center_W_ = Vec3::Zero();
  double radius_ = 0;
  std::vector<std::pair<std::string, Body>> bodies_;
};

/// Which model an IR came from (IntermediateRep::source).
inline constexpr std::uint8_t kIrSourceServer = 0;
inline constexpr std::uint8_t kIrSourceLocal = 1;

struct LocalModelOptions {
  pd::PdMode mode = pd::PdMode::kTranslational;
  bool torque = true;  ///< the scene declares torque (rows carry moments)
  pd::PenetrationRequest request;
  double validity_fraction = 0.1;  ///< pd::ContactModelOptions
  /// An open stream that brings nothing (no answer, no patch) for this
  /// long drops the patch: the scene may have changed unseen.
  double patch_quiet_s = 1.0;
  /// A server answer older than this (from its arrival) is not used by
  /// rule 2 (the servo loop's IR staleness, IrEvalParams::max_age_s).
  double server_fresh_s = 0.020;
  PatchLimits limits;
};

struct LocalModelStats {
  std::uint64_t patches = 0;        ///< applied
  std::uint64_t bad_patches = 0;    ///< rejected (the local model then stays off until reset)
  std::uint64_t patch_bytes = 0;    ///< wire bytes of the patches offered
  std::uint64_t steps = 0;          ///< proxy samples answered
  std::uint64_t local_answers = 0;  ///< rule 1
  std::uint64_t server_deeper = 0;  ///< rule 2
  std::uint64_t uncovered = 0;      ///< rule 3
  /// Fresh local query states (a new patch body) seeded with the server's
  /// answer.
  std::uint64_t seeded = 0;
  std::uint64_t drops = 0;             ///< patches dropped (stream broken or quiet)
  std::size_t triangles_held = 0;      ///< now
  std::size_t max_triangles_held = 0;  ///< the most at once
  double compute_p50_us = 0, compute_p99_us = 0, compute_max_us = 0;
  double rate_hz = 0;  ///< local answers per second of the worker's run
  /// Server answers compared with the local answer to the same sample, how
  /// many disagreed, and the depth difference (mm).
  std::uint64_t reference_checks = 0;
  std::uint64_t reference_disagreements = 0;
  double reference_diff_p99_mm = 0, reference_diff_max_mm = 0;
  std::string last_problem;
};

class LocalContactModel {
 public:
  /// `probe` must be the model the server built for the session (same
  /// shape or mesh); X_PA the proxy frame's pose of its mesh frame.
  LocalContactModel(pd::ModelPtr probe, const Pose& X_PA, const LocalModelOptions& options);
  ~LocalContactModel();
  LocalContactModel(const LocalContactModel&) = delete;
  LocalContactModel& operator=(const LocalContactModel&) = delete;

  // --- network side
  /// Queues a patch for the worker (never dropped; the worker applies or
  /// rejects it whole). `now_ns`: the loop clock at arrival.
  void OfferPatch(PatchDelta delta, std::int64_t now_ns);
  /// A patch that could not even be decoded (counted; the local model is
  /// off until Reset).
  void RejectPatch(const std::string& problem);
  /// The server's newest answer, decoded (receive_time_ns set).
  void OfferServerIr(const IntermediateRep& ir);
  /// The proxy's newest sample (the network thread forwards what it takes
  /// from the servo loop).
  void OfferSample(const ProxySample& sample);
  /// server steady clock - loop clock (ns), estimated from round trips.
  void SetServerClockOffset(std::int64_t offset_ns) {
    offset_ns_.store(offset_ns, std::memory_order_relaxed);
  }
  /// The stream broke or a new one starts: drop the patch (and re-enable
  /// the local model after a rejected patch).
  void Reset();

  // --- worker
  /// One step at loop time now_ns: without Start, applies queued patches
  /// and builds their models first; then answers the newest sample by the
  /// rule above into `out`. Returns true when it published an IR.
  bool Step(std::int64_t now_ns, IrMailbox* out);
  /// Runs Step on a thread whenever a sample or answer arrives, and applies
  /// patches and builds their models on a second thread (a patch of
  /// thousands of triangles takes milliseconds to build: meanwhile the
  /// previous view answers), until Stop.
  void Start(IrMailbox* out, const Clock* clock = &SteadyClock::Instance());
  void Stop();

  LocalModelStats stats() const;

 private:
  bool Covered(const Pose& X_WP, std::int64_t server_t);
  /// Seeds a fresh PDt query state with the server's newest answer (its
  /// deepest row as a remembered contact); false without one.
  bool Seed(const Pose& X_WB, pd::PdQueryData* data) const;
  /// Applies queued patches, resets and the quiet-stream drop to the store
  /// and publishes its view (the builder thread, or Step without Start).
  void ApplyQueued(std::int64_t now_ns);
  void AnswerLocal(const ProxySample& x, std::int64_t now_ns, std::int64_t server_t,
                   IntermediateRep* ir);

  const pd::ModelPtr probe_;
  std::array<Vec3, 8> corners_A_;  // the probe's bounding box, mesh frame
  std::array<Vec3, 8> corners_W_;
  double thinnest_ = 0;  // m, the probe's smallest bounding-box extent
  const Pose X_PA_;
  const Pose X_AP_;
  const LocalModelOptions options_;

  LatestMailbox<ProxySample> samples_;
  LatestMailbox<IntermediateRep> server_;
  std::atomic<std::int64_t> offset_ns_{0};
  std::atomic<bool> reset_{false};         // for the store (ApplyQueued)
  std::atomic<bool> reset_worker_{false};  // for the worker's server answer
  std::atomic<std::int64_t> last_message_ns_{0};

  std::mutex queue_mu_;
  std::deque<PatchDelta> queue_;
  std::string undecodable_;  // set by RejectPatch (under queue_mu_)
  std::uint64_t offered_bytes_ = 0;

  std::condition_variable_any queue_cv_;  // wakes the builder

  // Wakes the worker (Start) when a sample or an answer is offered.
  void Wake();
  std::mutex wake_mu_;
  bool wake_ = false;     // under wake_mu_
  bool waiting_ = false;  // under wake_mu_: the worker sleeps on wake_cv_
  std::condition_variable wake_cv_;

  // Builder state (ApplyQueued).
  PatchStore store_;
  bool disabled_ = false;  // a patch was rejected: server answers only
  // The newest view, handed from the builder to the worker.
  std::mutex view_mu_;
  std::shared_ptr<const PatchView> view_;
  bool background_ = false;  // Start() runs ApplyQueued on its own thread
  std::jthread builder_;

  // Worker state.
  std::shared_ptr<const PatchView> view_now_;
  bool have_sample_ = false;
  ProxySample sample_;
  bool have_server_ = false;
  IntermediateRep server_ir_;
  bool server_ir_published_ = false;
  std::vector<pd::SceneBody> bodies_;
  std::vector<std::uint64_t> keys_, data_keys_;
  pd::ScenePdData data_;
  pd::ScenePdResult result_;
  pd::ContactModel model_;
  std::int64_t first_step_ns_ = -1, last_step_ns_ = 0;
  // The local answers' deepest rows by sample sequence, for the reference
  // check against the server's answers (which arrive a round trip later).
  struct Answered {
    std::uint64_t sequence = 0;
    double depth = 0;
  };
  static constexpr std::size_t kAnswered = 1024;
  std::array<Answered, kAnswered> answered_{};

  mutable std::mutex stats_mu_;
  LocalModelStats stats_;
  Histogram compute_us_ = Histogram::LogScale(1, 1e7, 16);
  Histogram reference_diff_um_ = Histogram::LogScale(1, 1e6, 16);

  std::jthread thread_;
};

/// The IR of a contact model answered at proxy sample `x` (rows, and the
/// PDg target when the model is generalized and in contact). Moments are
/// left out when `torque` is false. receive_time_ns is left to the caller.
void IrFromContactModel(const pd::ContactModel& m, const ProxySample& x, const Pose& X_AP,
                        bool torque, IntermediateRep* ir);

}  // namespace hapticpd::device
