#include "server/observers.h"

#include <algorithm>

#include "server/convert.h"

namespace hapticpd::server::internal {

using Clock = std::chrono::steady_clock;

void FillBody(const BodyState& b, bool include_mesh, v1::Body* out) {
  out->set_body_id(b.id);
  ToProto(b.X_WB, out->mutable_pose());
  ToProto(b.v_W, out->mutable_velocity()->mutable_linear());
  ToProto(b.w_W, out->mutable_velocity()->mutable_angular());
  ToProto(b.material, out->mutable_material());
  out->set_movable(b.movable);
  out->set_label(b.label);
  ToProto(*b.model, out->mutable_mesh_info());
  if (include_mesh) ToProto(b.model->mesh(), out->mutable_mesh());
}

void FillScene(const Scene& scene, const SceneSnapshot& snap, bool include_meshes, v1::Scene* out) {
  out->set_scene_id(scene.id());
  out->set_description(scene.description());
  out->set_revision(snap.revision);
  *out->mutable_config() = scene.config();
  for (const BodyState& b : snap.bodies) FillBody(b, include_meshes, out->add_bodies());
}

ObserverHub::ObserverHub(ScenePtr scene) : scene_(std::move(scene)) {
  // The sessions already running: their observers' telemetry starts now
  // (what they sent before is dropped). Done before the thread starts,
  // which is from then on the feeds' one consumer.
  probes_seen_ = scene_->probes_revision();
  scene_->CopySessions(&scratch_);
  const std::int64_t now_ns = NowNs();
  for (const auto& slot : scratch_) {
    slot->feed.Discard(now_ns);
    sessions_.push_back(HubSession{slot, false, nullptr});
  }
  scratch_.clear();
  thread_ = std::thread([this] { Loop(); });
}

ObserverHub::~ObserverHub() { Stop(); }

void ObserverHub::Add(WatchReactor* r) {
  {
    std::lock_guard lock(mu_);
    observers_.push_back(r);
  }
  scene_->changes().Notify();
}

void ObserverHub::Remove(WatchReactor* r) {
  std::lock_guard lock(mu_);
  std::erase(observers_, r);
}

void ObserverHub::Stop() {
  stop_.store(true);
  scene_->changes().Notify();
  if (thread_.joinable()) thread_.join();
}

bool ObserverHub::Idle() {
  std::lock_guard lock(mu_);
  return observers_.empty() && scene_->deleted();
}

void ObserverHub::Loop() {
  ChangeSignal& signal = scene_->changes();
  std::uint64_t seen = signal.count();
  auto next_telemetry = Clock::now();
  while (!stop_.load()) {
    const auto now = Clock::now();
    auto next = now + std::chrono::milliseconds(100);
    {
      std::lock_guard lock(mu_);
      const std::int64_t now_ns = NowNs();
      SyncSessions();
      if (!sessions_.empty()) {
        if (now >= next_telemetry) {
          PublishTelemetry(now_ns);
          next_telemetry = now + kTelemetryPeriod;
        }
        next = std::min(next, next_telemetry);
      }
      for (WatchReactor* r : observers_) next = std::min(next, r->Tick(now));
    }
    seen = signal.WaitFor(seen, std::max(next, now + std::chrono::microseconds(200)));
  }
}

void ObserverHub::SyncSessions() {
  if (const std::uint64_t rev = scene_->probes_revision(); rev != probes_seen_) {
    probes_seen_ = rev;
    scene_->CopySessions(&scratch_);
    std::vector<std::size_t> added;
    for (const auto& slot : scratch_) {
      const bool known = std::any_of(sessions_.begin(), sessions_.end(),
                                     [&](const HubSession& h) { return h.slot == slot; });
      if (known) continue;
      added.push_back(sessions_.size());
      sessions_.push_back(HubSession{slot, false, nullptr});
    }
    for (HubSession& h : sessions_) {
      if (std::find(scratch_.begin(), scratch_.end(), h.slot) == scratch_.end()) h.retired = true;
    }
    scratch_.clear();
    if (!added.empty()) Announce(added, {}, nullptr);
  }
  // Observers new to the hub get the whole list first (even when empty).
  for (WatchReactor* r : observers_) {
    if (!r->wants_contacts() || r->sessions_listed) continue;
    std::vector<std::size_t> all(sessions_.size());
    for (std::size_t i = 0; i < all.size(); ++i) all[i] = i;
    Announce(all, {}, r);
    r->sessions_listed = true;
  }
}

void ObserverHub::PublishTelemetry(std::int64_t now_ns) {
  const bool wanted = std::any_of(observers_.begin(), observers_.end(),
                                  [](const WatchReactor* r) { return r->wants_telemetry(); });
  std::shared_ptr<v1::Telemetry> batch;
  if (wanted) batch = std::make_shared<v1::Telemetry>();
  const std::uint64_t revision = scene_->snapshot()->revision;
  for (HubSession& h : sessions_) {
    if (!batch) {
      h.slot->feed.Discard(now_ns);
      continue;
    }
    v1::SessionTelemetry* st = batch->add_sessions();
    h.slot->feed.Take(now_ns, st);
    st->set_session_id(h.slot->session_id);
    st->set_scene_revision(revision);
  }
  if (batch) {
    const std::shared_ptr<const v1::Telemetry> shared = std::move(batch);
    for (WatchReactor* r : observers_) {
      if (r->wants_telemetry()) r->Enqueue(HubEvent{shared, {}});
    }
  }
  // Ended sessions had their last telemetry in this batch: now they go.
  std::vector<std::string> removed;
  std::erase_if(sessions_, [&](const HubSession& h) {
    if (h.retired) removed.push_back(h.slot->session_id);
    return h.retired;
  });
  if (!removed.empty()) Announce({}, removed, nullptr);
}

void ObserverHub::FillInfo(HubSession& s, bool with_mesh, v1::SessionInfo* out) {
  if (!with_mesh || !s.slot->probe) {
    *out = s.slot->info;
    return;
  }
  if (!s.with_mesh) {
    auto info = std::make_shared<v1::SessionInfo>(s.slot->info);
    ToProto(s.slot->probe->mesh(), info->mutable_probe_mesh());
    s.with_mesh = std::move(info);
  }
  *out = *s.with_mesh;
}

void ObserverHub::Announce(const std::vector<std::size_t>& added,
                           const std::vector<std::string>& removed, WatchReactor* only) {
  for (WatchReactor* r : observers_) {
    if (only != nullptr ? r != only : (!r->wants_contacts() || !r->sessions_listed)) continue;
    HubEvent e;
    for (const std::size_t i : added)
      FillInfo(sessions_[i], r->wants_meshes(), e.sessions.add_added());
    for (const std::string& id : removed) e.sessions.add_removed(id);
    r->Enqueue(std::move(e));
  }
}

void ObserverPublishers::Add(WatchReactor* r) {
  std::vector<std::unique_ptr<ObserverHub>> reaped;
  {
    std::lock_guard lock(mu_);
    if (stopped_) return;
    for (auto it = hubs_.begin(); it != hubs_.end();) {
      if (it->first != r->scene() && it->second->Idle()) {
        reaped.push_back(std::move(it->second));
        it = hubs_.erase(it);
      } else {
        ++it;
      }
    }
    auto& hub = hubs_[r->scene()];
    if (!hub) hub = std::make_unique<ObserverHub>(r->scene_ptr());
    hub->Add(r);
  }
  // Joined outside the lock: a hub thread may be finishing a reactor whose
  // OnDone calls Remove.
  for (auto& h : reaped) h->Stop();
}

void ObserverPublishers::Remove(WatchReactor* r) {
  std::lock_guard lock(mu_);
  if (auto it = hubs_.find(r->scene()); it != hubs_.end()) it->second->Remove(r);
}

void ObserverPublishers::Stop() {
  std::map<const Scene*, std::unique_ptr<ObserverHub>> hubs;
  {
    std::lock_guard lock(mu_);
    stopped_ = true;
    hubs.swap(hubs_);
  }
  for (auto& [scene, hub] : hubs) hub->Stop();
}

int ObserverPublishers::running() const {
  std::lock_guard lock(mu_);
  return static_cast<int>(hubs_.size());
}

namespace {
std::chrono::nanoseconds PeriodOf(double rate_hz) {
  if (rate_hz <= 0) rate_hz = 60;
  return std::chrono::nanoseconds(static_cast<std::int64_t>(1e9 / rate_hz));
}
}  // namespace

WatchReactor::WatchReactor(Core* core, grpc::CallbackServerContext* ctx, ScenePtr scene,
                           const v1::WatchRequest& request)
    : core_(core),
      ctx_(ctx),
      scene_(std::move(scene)),
      period_(PeriodOf(request.rate_hz())),
      include_meshes_(request.include_meshes()),
      include_contacts_(request.include_contacts()),
      include_telemetry_(request.include_telemetry()) {
  core_->Register(this);  // core_->observers was counted by SceneServiceImpl::Watch
  ++scene_->observers;
  if (include_contacts_) ++scene_->contact_watchers;
  GrpcHandOff(this);
  core_->publishers->Add(this);
}

Clock::time_point WatchReactor::Tick(Clock::time_point now) {
  std::unique_lock lock(mu_);
  if (finish_called_ || finish_wanted_ || stalled_) return now + std::chrono::hours(1);
  if (scene_->deleted()) {
    bool call = false;
    FinishLocked(
        grpc::Status(grpc::StatusCode::NOT_FOUND, "scene '" + scene_->id() + "' was deleted"),
        false, &call);
    lock.unlock();
    if (call) {
      GrpcStart(this, [this, s = finish_status_] { Finish(s); });
    }
    return now + std::chrono::hours(1);
  }
  // A write stuck for the idle timeout: the observer is frozen or its
  // connection half-open. Cancel the call (a status could not reach it) to
  // free its slot.
  auto stuck_at = Clock::time_point::max();
  if (const double idle_s = core_->limits.idle_timeout_s; in_flight_ && idle_s > 0) {
    stuck_at = write_started_ + std::chrono::nanoseconds(static_cast<std::int64_t>(idle_s * 1e9));
    if (now >= stuck_at && !stalled_) {
      stalled_ = true;
      core_->stats.observers_stalled.fetch_add(1, std::memory_order_relaxed);
      lock.unlock();
      Log()->info(
          "observer of scene '{}': a write has not completed for {:g} s (idle timeout): "
          "cancelled",
          scene_->id(), idle_s);
      ctx_->TryCancel();
      return now + std::chrono::hours(1);
    }
  }
  const SnapshotPtr snap = scene_->snapshot();
  const bool structural = last_ == nullptr || snap->structure_revision != last_->structure_revision;
  const bool pose_due = now >= next_pose_due_;
  const bool queued = !queue_.empty();
  if (!structural && !pose_due && !queued) return std::min(next_pose_due_, stuck_at);
  if (in_flight_) {
    // The observer has not taken the previous frame: skip this one.
    if (pose_due) {
      ++dropped_;
      core_->stats.observer_frames_dropped.fetch_add(1, std::memory_order_relaxed);
      next_pose_due_ = now + period_;
    }
    return std::min(next_pose_due_, stuck_at);
  }
  msg_.Clear();
  msg_.set_revision(snap->revision);
  msg_.set_server_time_ns(NowNs());
  msg_.set_frames_dropped(dropped_);
  msg_.set_observers(static_cast<std::uint32_t>(std::max(0, scene_->observers.load())));
  if (last_ == nullptr) {
    FillScene(*scene_, *snap, include_meshes_, msg_.mutable_snapshot());
  } else if (structural) {
    auto* ch = msg_.mutable_changes();
    for (const BodyState& b : snap->bodies) {
      const BodyState* old = last_->Find(b.id);
      if (old == nullptr || old->uid != b.uid) FillBody(b, include_meshes_, ch->add_added());
    }
    for (const BodyState& b : last_->bodies) {
      const BodyState* now_b = snap->Find(b.id);
      if (now_b == nullptr || now_b->uid != b.uid) ch->add_removed(b.id);
    }
  } else if (queued && !queue_.front().batch) {
    // Sessions changes are never dropped and go before pose frames, so a
    // probe is announced before it is drawn.
    v1::SessionsChanged* ch = msg_.mutable_sessions();
    ch->Swap(&queue_.front().sessions);
    queue_.pop_front();
    for (const auto& a : ch->added()) announced_.insert(a.session_id());
    for (const auto& id : ch->removed()) announced_.erase(id);
  } else if (queued && !(pose_due && !last_was_pose_)) {
    // A telemetry batch (taking turns with pose frames when both wait).
    v1::Telemetry* t = msg_.mutable_telemetry();
    t->CopyFrom(*queue_.front().batch);
    t->set_batches_dropped(batches_dropped_);
    queue_.pop_front();
    last_was_pose_ = false;
  } else {
    last_was_pose_ = true;
    auto* poses = msg_.mutable_poses();
    for (const BodyState& b : snap->bodies) {
      auto* bp = poses->add_bodies();
      bp->set_body_id(b.id);
      ToProto(b.X_WB, bp->mutable_pose());
      ToProto(b.v_W, bp->mutable_velocity()->mutable_linear());
      ToProto(b.w_W, bp->mutable_velocity()->mutable_angular());
    }
    scene_->CopyProbes(&probes_);
    for (const auto& p : probes_) {
      if (include_contacts_) {
        // Only sessions this observer was told of; their answers in full.
        if (announced_.count(p.session_id) == 0) continue;
        if (p.full && p.full->sequence() == p.sequence) {
          *poses->add_probes() = *p.full;
          continue;
        }
      }
      auto* ps = poses->add_probes();
      ps->set_session_id(p.session_id);
      ToProto(p.X_WA, ps->mutable_pose());
      ToProto(p.force_W, ps->mutable_force());
      ps->set_depth(p.depth);
      ps->set_sequence(p.sequence);
    }
    next_pose_due_ = now + period_;
  }
  last_ = snap;
  in_flight_ = true;
  write_started_ = now;
  core_->stats.observer_frames_sent.fetch_add(1, std::memory_order_relaxed);
  // Under mu_: a forced Finish (cancellation) cannot slip in between.
  GrpcStart(this, [&] { StartWrite(&msg_); });
  return next_pose_due_;
}

namespace {
/// `more` after `into`, as one change (a session added and removed before
/// it was sent cancels out).
void MergeSessions(v1::SessionsChanged* into, v1::SessionsChanged* more) {
  for (auto& a : *more->mutable_added()) into->add_added()->Swap(&a);
  for (const std::string& id : more->removed()) {
    auto* added = into->mutable_added();
    const auto it = std::find_if(added->begin(), added->end(),
                                 [&](const v1::SessionInfo& a) { return a.session_id() == id; });
    if (it != added->end()) {
      added->erase(it);
    } else {
      into->add_removed(id);
    }
  }
}
}  // namespace

void WatchReactor::Enqueue(HubEvent e) {
  std::lock_guard lock(mu_);
  if (finish_called_ || finish_wanted_) return;
  if (!e.batch) {
    // At most one sessions change between two batches.
    if (!queue_.empty() && !queue_.back().batch) {
      MergeSessions(&queue_.back().sessions, &e.sessions);
    } else {
      queue_.push_back(std::move(e));
    }
    return;
  }
  const auto is_batch = [](const HubEvent& q) { return q.batch != nullptr; };
  if (static_cast<std::size_t>(std::count_if(queue_.begin(), queue_.end(), is_batch)) >=
      kTelemetryQueueBatches) {
    // Fallen behind: the oldest batch goes, whole; sessions changes stay.
    auto next = queue_.erase(std::find_if(queue_.begin(), queue_.end(), is_batch));
    ++batches_dropped_;
    if (next != queue_.begin() && next != queue_.end() && !next->batch) {
      auto prev = std::prev(next);
      if (!prev->batch) {
        MergeSessions(&prev->sessions, &next->sessions);
        queue_.erase(next);
      }
    }
  }
  queue_.push_back(std::move(e));
}

void WatchReactor::FinishLocked(const grpc::Status& status, bool force, bool* call_finish) {
  *call_finish = false;
  if (finish_called_) return;
  if (!finish_wanted_) {
    finish_wanted_ = true;
    finish_status_ = status;
  }
  if (!in_flight_ || force) {
    finish_called_ = true;
    *call_finish = true;
  }
}

void WatchReactor::Stop(const grpc::Status& status) {
  bool call = false;
  {
    std::lock_guard lock(mu_);
    FinishLocked(status, false, &call);
  }
  if (call) {
    GrpcStart(this, [this, s = finish_status_] { Finish(s); });
  }
}

void WatchReactor::OnWriteDone(bool ok) {
  const Reaction reaction(this);
  bool call = false;
  {
    std::lock_guard lock(mu_);
    in_flight_ = false;
    if (!ok) {
      FinishLocked(grpc::Status(grpc::StatusCode::CANCELLED, "observer went away"), true, &call);
    } else if (finish_wanted_) {
      FinishLocked(finish_status_, true, &call);
    }
  }
  if (call) {
    GrpcStart(this, [this, s = finish_status_] { Finish(s); });
  } else {
    scene_->changes().Notify();  // a structural change may be waiting for this observer
  }
}

void WatchReactor::OnCancel() {
  const Reaction reaction(this);
  bool call = false;
  {
    std::lock_guard lock(mu_);
    FinishLocked(grpc::Status::CANCELLED, true, &call);
  }
  if (call) {
    GrpcStart(this, [this, s = finish_status_] { Finish(s); });
  }
}

void WatchReactor::OnDone() {
  GrpcTakeOver(this);
  core_->publishers->Remove(this);
  if (include_contacts_) --scene_->contact_watchers;
  --scene_->observers;
  --core_->observers;
  core_->Unregister(this);
  delete this;
}

}  // namespace hapticpd::server::internal
