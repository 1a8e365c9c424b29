// Observer fan-out. Each Watch call is a WatchReactor; each scene with
// observers has its own publisher thread (an ObserverHub) that visits the
// scene's observers when the scene changes or an observer's next pose frame
// is due, so a busy scene never delays another scene's observers. An observer's next frame is
// derived from the newest scene snapshot when it is ready to take one (latest value, never a
// queue): a slow observer has at most one write in flight and skips pose frames, and the hub never
// blocks on it, so it slows neither device sessions nor other observers.
#pragma once

#include <grpcpp/grpcpp.h>

#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <thread>
#include <vector>

#include "hapticpd/v1/scene.grpc.pb.h"
#include "server/core.h"

namespace hapticpd::server::internal {

/// Fills a v1::Body from a body state.
void FillBody(const BodyState& b, bool include_mesh, v1::Body* out);
/// Fills a v1::Scene from a snapshot.
void FillScene(const Scene& scene, const SceneSnapshot& snap, bool include_meshes, v1::Scene* out);

class WatchReactor;

/// Telemetry batches a watcher's queue holds (about 2 s at kTelemetryPeriod);
/// a watcher that falls further behind loses whole oldest batches.
inline constexpr std::size_t kTelemetryQueueBatches = 40;
/// How often the hub drains its sessions' telemetry feeds into a batch.
inline constexpr std::chrono::milliseconds kTelemetryPeriod{50};

/// What the hub queues for one observer, in order: SessionsChanged
/// (include_contacts; never dropped, consecutive ones merged) and Telemetry
/// batches (include_telemetry; shared by every observer of the scene,
/// dropped oldest first when the queue is full).
struct HubEvent {
  std::shared_ptr<const v1::Telemetry> batch;  ///< set: a telemetry batch
  v1::SessionsChanged sessions;                ///< else: a sessions change
};

/// The publisher of one scene: a thread that wakes on the scene's changes
/// and on its observers' pose-frame deadlines, and every kTelemetryPeriod
/// drains its device sessions' telemetry feeds.
class ObserverHub {
 public:
  explicit ObserverHub(ScenePtr scene);
  ~ObserverHub();
  void Add(WatchReactor* r);
  void Remove(WatchReactor* r);
  void Stop();
  /// No observer left and the scene deleted: the hub can be reaped.
  bool Idle();

 private:
  /// A device session as this hub shows it. An ended session stays
  /// (retired) until its last telemetry has gone out in a batch; only then
  /// is it announced removed.
  struct HubSession {
    std::shared_ptr<ProbeSlot> slot;
    bool retired = false;
    std::shared_ptr<const v1::SessionInfo> with_mesh;  ///< built on first need
  };
  void Loop();
  /// Under mu_: follows the scene's sessions, announces new ones and the
  /// whole list to observers that have not had it yet.
  void SyncSessions();
  /// Under mu_: drains every session's feed into one batch for the
  /// telemetry observers (or discards it), then announces retired sessions
  /// removed.
  void PublishTelemetry(std::int64_t now_ns);
  void FillInfo(HubSession& s, bool with_mesh, v1::SessionInfo* out);
  void Announce(const std::vector<std::size_t>& added, const std::vector<std::string>& removed,
                WatchReactor* only);

  ScenePtr scene_;
  std::mutex mu_;
  std::vector<WatchReactor*> observers_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
  // The hub thread's own.
  std::vector<HubSession> sessions_;
  std::uint64_t probes_seen_ = 0;
  std::vector<std::shared_ptr<ProbeSlot>> scratch_;
};

/// The per-scene publishers of a server: a scene's hub starts with its first
/// observer; hubs of deleted scenes are reaped once their observers are gone
/// (at the next Watch call, or at shutdown).
class ObserverPublishers {
 public:
  ObserverPublishers() = default;
  ~ObserverPublishers() { Stop(); }
  void Add(WatchReactor* r);
  void Remove(WatchReactor* r);
  /// Stops every hub (server shutdown); later Adds are ignored.
  void Stop();
  /// Publisher threads running.
  int running() const;

 private:
  mutable std::mutex mu_;
  std::map<const Scene*, std::unique_ptr<ObserverHub>> hubs_;
  bool stopped_ = false;
};

class WatchReactor final : public grpc::ServerWriteReactor<v1::SceneEvent>, public StoppableCall {
 public:
  WatchReactor(Core* core, grpc::CallbackServerContext* ctx, ScenePtr scene,
               const v1::WatchRequest& request);

  /// Called by the hub: writes the next frame if one is due and no write is
  /// in flight. Returns when the next pose frame is due.
  std::chrono::steady_clock::time_point Tick(std::chrono::steady_clock::time_point now);

  bool wants_contacts() const { return include_contacts_; }
  bool wants_telemetry() const { return include_telemetry_; }
  bool wants_meshes() const { return include_meshes_; }
  /// Called by the hub: queues a sessions change or a telemetry batch
  /// (bounded: see HubEvent).
  void Enqueue(HubEvent e);
  /// The hub's own flag: the whole session list has been queued.
  bool sessions_listed = false;

  void Stop(const grpc::Status& status) override;
  const Scene* scene() const override { return scene_.get(); }
  const ScenePtr& scene_ptr() const { return scene_; }

 private:
  void OnWriteDone(bool ok) override;
  void OnCancel() override;
  void OnDone() override;
  /// Under mu_: Finish once, now if no write is in flight, else after it.
  void FinishLocked(const grpc::Status& status, bool force, bool* call_finish);

  Core* core_;
  grpc::CallbackServerContext* ctx_;
  ScenePtr scene_;
  const std::chrono::nanoseconds period_;
  std::chrono::steady_clock::time_point write_started_{};  ///< of the write in flight
  bool stalled_ = false;  ///< cancelled for a write stuck over the idle timeout
  const bool include_meshes_;
  const bool include_contacts_;
  const bool include_telemetry_;
  std::mutex mu_;
  std::deque<HubEvent> queue_;
  std::uint64_t batches_dropped_ = 0;
  bool last_was_pose_ = false;
  std::set<std::string> announced_;  ///< sessions this observer was told of
  bool in_flight_ = false;
  bool finish_called_ = false;
  bool finish_wanted_ = false;
  grpc::Status finish_status_;
  SnapshotPtr last_;  ///< the snapshot the observer last saw (null: nothing sent)
  std::chrono::steady_clock::time_point next_pose_due_{};
  std::uint64_t dropped_ = 0;
  v1::SceneEvent msg_;
  std::vector<Scene::ProbeCopy> probes_;
};

}  // namespace hapticpd::server::internal
