// Scenes and their immutable snapshots.
//
// A Scene publishes its state as an immutable SceneSnapshot through an atomic
// shared pointer: readers (PD workers, observers) load the current snapshot
// once per frame and never wait on a writer; writers (AddBody, MoveBody,
// RemoveBody) are serialised among themselves, copy the body list (meshes and
// BVHs are shared, never copied), change the copy and publish it.
#pragma once

#include <grpcpp/support/status.h>

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "hapticpd/v1/haptic.pb.h"
#include "hapticpd/v1/scene.pb.h"
#include "pd/geometry_model.h"
#include "pd/material.h"
#include "pd/types.h"
#include "server/telemetry.h"

namespace hapticpd::server {

struct BodyState {
  std::uint64_t uid = 0;  ///< unique in this server process, never reused
  std::string id;         ///< unique in the scene
  std::string label;
  pd::ModelPtr model;
  /// The body's motion: at server steady-clock time t it is at
  /// PoseAt(*this, t), X_WB carried along at v_W and turning at w_W from
  /// pose_time_ns on. Device sessions render it there and send the same
  /// four numbers in their geometry patches.
  Pose X_WB;                ///< at pose_time_ns
  Vec3 v_W = Vec3::Zero();  ///< linear velocity of the mesh frame's origin (m/s), W
  Vec3 w_W = Vec3::Zero();  ///< angular velocity (rad/s), W
  /// Server steady clock (ns) when X_WB was set; Scene::AddBody stamps it
  /// when left 0, Scene::MoveBody always.
  std::int64_t pose_time_ns = 0;
  pd::Material material;
  bool movable = false;
};

/// The body has a non-zero velocity (its pose changes with time).
bool Moving(const BodyState& b);
/// The body's pose at server steady-clock time `t_ns`: translation
/// X_WB.t + v_W dt, rotation exp([w_W] dt) X_WB.R (turned about W's axes),
/// dt = t_ns - pose_time_ns (negative before it). X_WB itself when at rest.
Pose PoseAt(const BodyState& b, std::int64_t t_ns);

struct SceneSnapshot {
  std::uint64_t revision = 0;            ///< bumps on every change
  std::uint64_t structure_revision = 0;  ///< bumps when a body is added or removed
  std::vector<BodyState> bodies;

  const BodyState* Find(const std::string& id) const;
};

using SnapshotPtr = std::shared_ptr<const SceneSnapshot>;

/// Wakes whoever waits for scene changes (the observer publisher).
class ChangeSignal {
 public:
  void Notify();
  /// Waits until notified after `seen` or until `deadline`; returns the
  /// current count.
  std::uint64_t WaitFor(std::uint64_t seen, std::chrono::steady_clock::time_point deadline);
  std::uint64_t count() const { return count_.load(); }

 private:
  std::mutex mu_;
  std::condition_variable cv_;
  std::atomic<std::uint64_t> count_{0};
};

/// A device session as observers see it: the latest answered probe pose
/// (under mu), what draws the session, and its telemetry feed.
struct ProbeSlot {
  std::string session_id;
  /// Set before the slot is added to its scene, then never changed: the
  /// session as SessionsChanged shows it (without the mesh) and its probe.
  v1::SessionInfo info;
  pd::ModelPtr probe;
  /// Telemetry for observers with include_telemetry (server/telemetry.h).
  TelemetryFeed feed;
  std::mutex mu;
  bool valid = false;
  Pose X_WA;
  Vec3 force_W = Vec3::Zero();
  double depth = 0;
  std::uint64_t sequence = 0;
  /// The latest answer in full (ProbeState with its contact rows), published
  /// only while an observer with include_contacts watches the scene
  /// (Scene::contact_watchers); null before.
  std::shared_ptr<const v1::ProbeState> full;
};

class Scene {
 public:
  Scene(std::string id, std::string description, ChangeSignal* signal);

  const std::string& id() const { return id_; }
  const std::string& description() const { return description_; }

  /// The current snapshot (never null). Lock-free for readers in practice.
  SnapshotPtr snapshot() const { return snapshot_.load(std::memory_order_acquire); }

  /// What a write hook sees: the change, after every check has passed and
  /// before it is published, under the scene's writer lock.
  struct WriteInfo {
    const BodyState* body = nullptr;  ///< the body added or moved (its new state)
    std::uint64_t revision = 0;       ///< the revision the change publishes
    std::uint64_t next_body_number = 1;
  };
  /// Makes a change durable (the state store) before it is published; a
  /// non-OK status drops the change and is the writer's result.
  using WriteHook = std::function<grpc::Status(const WriteInfo&)>;

  /// Adds a body; assigns "body-N" when body.id is empty. ALREADY_EXISTS on a
  /// duplicate id (the message names `id_field`), RESOURCE_EXHAUSTED beyond
  /// `max_bodies`.
  grpc::Status AddBody(BodyState body, std::size_t max_bodies, BodyState* added,
                       const std::string& id_field, const WriteHook& hook = {});
  /// NOT_FOUND, FAILED_PRECONDITION (static body) or OK with the new revision.
  grpc::Status MoveBody(const std::string& id, const Pose& X_WB, const Vec3* v_W, const Vec3* w_W,
                        std::uint64_t* revision, const WriteHook& hook = {});
  grpc::Status RemoveBody(const std::string& id, std::uint64_t* revision,
                          const WriteHook& hook = {});

  bool deleted() const { return deleted_.load(std::memory_order_acquire); }
  void MarkDeleted();
  /// MarkDeleted after `hook` succeeded, under the writer lock (no writer
  /// runs between them); NOT_FOUND when already deleted.
  grpc::Status MarkDeleted(const std::function<grpc::Status()>& hook);

  /// The number the next assigned "body-N" id starts from (restored from
  /// the state store, so that a restart does not hand out old ids again).
  std::uint64_t next_body_number() const;
  void set_next_body_number(std::uint64_t n);

  /// Notified on every change of this scene (its observer publisher waits on it).
  ChangeSignal& changes() { return changes_; }

  /// The scene's declared effects and PD mode (scene file or CreateScene).
  void set_config(const v1::SceneConfig& c) {
    std::lock_guard lock(config_mu_);
    config_ = c;
  }
  v1::SceneConfig config() const {
    std::lock_guard lock(config_mu_);
    return config_;
  }

  std::atomic<int> sessions{0};
  std::atomic<int> observers{0};
  /// Observers with include_contacts: while there is one, sessions publish
  /// their full answers (ProbeSlot::full).
  std::atomic<int> contact_watchers{0};

  /// A device session joins or leaves the scene's probes (wakes the
  /// scene's observers: SessionsChanged).
  void AddProbe(std::shared_ptr<ProbeSlot> slot);
  void RemoveProbe(const ProbeSlot* slot);
  /// Bumps when a probe is added or removed.
  std::uint64_t probes_revision() const { return probes_revision_.load(); }
  /// The device sessions' slots, in the order they joined.
  void CopySessions(std::vector<std::shared_ptr<ProbeSlot>>* out) const;
  /// Copies of the probes' latest states.
  struct ProbeCopy {
    std::string session_id;
    Pose X_WA;
    Vec3 force_W;
    double depth;
    std::uint64_t sequence;
    std::shared_ptr<const v1::ProbeState> full;  ///< ProbeSlot::full
  };
  void CopyProbes(std::vector<ProbeCopy>* out) const;

 private:
  void Publish(std::shared_ptr<SceneSnapshot> next);

  const std::string id_;
  const std::string description_;
  ChangeSignal* signal_;
  ChangeSignal changes_;
  std::atomic<SnapshotPtr> snapshot_;
  mutable std::mutex write_mu_;  // serialises writers; never taken by readers
  std::uint64_t next_body_number_ = 1;
  std::atomic<bool> deleted_{false};
  mutable std::mutex probes_mu_;
  std::vector<std::shared_ptr<ProbeSlot>> probes_;
  std::atomic<std::uint64_t> probes_revision_{0};
  mutable std::mutex config_mu_;
  v1::SceneConfig config_;
};

using ScenePtr = std::shared_ptr<Scene>;

/// All scenes of a server, by id.
class SceneRegistry {
 public:
  explicit SceneRegistry(ChangeSignal* signal) : signal_(signal) {}

  /// ALREADY_EXISTS, RESOURCE_EXHAUSTED (more than `max_scenes`) or OK.
  grpc::Status Create(const std::string& id, const std::string& description, std::size_t max_scenes,
                      ScenePtr* out);
  /// Create with the scene's config, after `hook` (which makes it durable)
  /// succeeded; nothing is created when it fails.
  grpc::Status Create(const std::string& id, const std::string& description,
                      const v1::SceneConfig& config, std::size_t max_scenes, ScenePtr* out,
                      const std::function<grpc::Status()>& hook);
  ScenePtr Get(const std::string& id) const;
  /// Removes the scene from the registry and marks it deleted; null when absent.
  ScenePtr Remove(const std::string& id);
  /// Remove after `hook` succeeded (NOT_FOUND when absent); `out` gets the scene.
  grpc::Status Remove(const std::string& id, const std::function<grpc::Status()>& hook,
                      ScenePtr* out);
  std::vector<ScenePtr> List() const;

  std::uint64_t NextBodyUid() { return next_uid_.fetch_add(1); }

 private:
  ChangeSignal* signal_;
  mutable std::mutex mu_;
  std::map<std::string, ScenePtr> scenes_;
  std::atomic<std::uint64_t> next_uid_{1};
};

}  // namespace hapticpd::server
