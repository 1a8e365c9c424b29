// The PD side of one device session, without the network: from the hello
// (after the caller has authenticated it and found its scene) to the probe
// model and the Welcome, and then from each probe pose to its ContactUpdate
// (scene sync, PD, the contact model of pd/contact_model.h, the last check
// before a motor). The gRPC reactor in session.cc owns the mailbox, the
// writer and the threads; this class is what it calls, and what the tests
// call without a server.
#pragma once

#include <grpcpp/support/status.h>

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "hapticpd/v1/haptic.pb.h"
#include "pd/contact_model.h"
#include "pd/scene_pd.h"
#include "server/patch_builder.h"
#include "server/scene.h"
#include "server/server.h"

namespace hapticpd::server::internal {

inline constexpr std::uint32_t kProtocolVersion = 1;

/// A probe pose taken from the session's mailbox.
struct MailPose {
  std::uint64_t sequence = 0;
  Pose X_WA;
  std::int64_t client_time_ns = 0;
  std::int64_t rx_ns = 0;  ///< server steady clock when received
  /// The client's reported round trip (us), >= 0 and at most
  /// kMaxRoundTripUs; 0 when not known or not usable.
  double round_trip_us = 0;
};

/// Longest round trip (us) a patch's margin is sized for; longer reports
/// count as this.
inline constexpr double kMaxRoundTripUs = 10e6;
/// Largest PatchRequest.min_margin (m) a hello may ask for.
inline constexpr double kMaxPatchMinMargin = 1.0;

/// ProbePose.round_trip_us as a MailPose takes it: a non-finite or negative
/// report is "not known" (0), a longer one than kMaxRoundTripUs is cut.
double SanitizeRoundTripUs(double us);

/// What one answer did, for the caller's counters, log and observers.
struct AnswerInfo {
  bool pd_ran = false;  ///< a PD query ran (false: mode none, or no contact effect)
  double time_us = 0;   ///< its time
  bool torque = true;   ///< the answer carries torque terms
  /// Non-null: the answer was withheld (CONTACT_STATUS_WITHHELD), and why.
  const char* withheld = nullptr;
  Vec3 force_W = Vec3::Zero();  ///< the force sent
  double depth = 0;             ///< the depth sent
};

class SessionWorker {
 public:
  SessionWorker(const Limits& limits, std::string session_id);

  /// Checks the hello against `scene` (already resolved and authorised by
  /// the caller), builds the probe model and fills the Welcome. Errors name
  /// the hello's field. Does not register anything with the scene.
  grpc::Status Start(const v1::Hello& hello, const ScenePtr& scene, v1::Welcome* welcome);

  /// The answer to pose `p`: PD against the scene's current snapshot, the
  /// contact model, encoded as a ContactUpdate; an answer holding a
  /// non-finite number or a force (torque) over the limits is replaced by
  /// zero force and no rows (CONTACT_STATUS_WITHHELD).
  /// Moving bodies are where PoseAt puts them at p.rx_ns.
  AnswerInfo Answer(const MailPose& p, std::uint32_t superseded, v1::ContactUpdate* u);

  /// The session's next geometry patch, after the answer to `p`: false when
  /// the hello did not ask for patches or none is due (see
  /// PatchBuilder::Build). Each patch is a delta on the ones before: the
  /// caller must send every one, in order; it asks again only once the
  /// previous one is written.
  bool Patch(const MailPose& p, v1::GeometryPatch* out);
  bool patches_enabled() const { return patches_ != nullptr; }
  const PatchBuilder* patch_builder() const { return patches_.get(); }

  /// Minimum time between answers (Hello.max_rate_hz); zero: unlimited.
  std::chrono::nanoseconds min_period() const { return min_period_; }
  int mode() const { return mode_; }
  const pd::ModelPtr& probe() const { return probe_; }

 private:
  void SyncBodies(const SnapshotPtr& snap);
  /// Puts the moving bodies where they are at `t_ns`.
  void MoveBodies(std::int64_t t_ns);
  grpc::Status StartPatches(const v1::Hello& h);
  /// Replaces `u` by the withheld answer when it is unfit; returns why.
  const char* Withhold(v1::ContactUpdate* u) const;

  const Limits limits_;
  const std::string session_id_;
  ScenePtr scene_;
  int mode_ = v1::PD_MODE_UNSPECIFIED;
  bool torque_ = true;    // the scene declares torque (or declares nothing)
  bool needs_pd_ = true;  // the scene declares an effect at the contact regions
  pd::ModelPtr probe_;
  std::uint64_t probe_uid_ = 0;
  pd::Material probe_material_;
  bool has_probe_material_ = false;
  std::chrono::nanoseconds min_period_{0};
  SnapshotPtr synced_;
  std::vector<pd::SceneBody> bodies_;
  std::vector<std::string> body_ids_;
  std::vector<std::uint64_t> uids_;
  std::vector<const BodyState*> states_;  ///< in synced_, per body
  bool any_moving_ = false;
  std::unique_ptr<PatchBuilder> patches_;
  std::vector<PatchBody> patch_bodies_;
  pd::ScenePdData pd_data_;
  pd::ScenePdResult result_;
  pd::PenetrationRequest request_;
  pd::ContactModel model_;
};

}  // namespace hapticpd::server::internal
