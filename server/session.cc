// HapticService.Couple: one device session per stream, with a dedicated PD
// worker thread.
//
//   gRPC threads (OnReadDone)  --newest pose-->  mailbox (one slot)
//   worker: take newest pose, load scene snapshot, PD, build ContactUpdate
//   worker  --update-->  writer: at most one write in flight; an update not
//                        yet sent is replaced by a newer one
//   worker  --patch-->   writer: a geometry patch (sessions that asked for
//                        them) waits in its own slot, written before the
//                        pending update, and is never replaced: the worker
//                        cuts the next one only once it has been written
#include <grpcpp/grpcpp.h>

#include <cmath>
#include <condition_variable>
#include <thread>

#include "pd/scene_pd.h"
#include "proto/wire/ranges.h"
#include "proto/wire/routing.h"
#include "proto/wire/status.h"
#include "proto/wire/text.h"
#include "server/convert.h"
#include "server/scene_file.h"
#include "server/services.h"
#include "server/session_worker.h"

namespace hapticpd::server::internal {
namespace {

class CoupleReactor final : public grpc::ServerBidiReactor<v1::CoupleRequest, v1::CoupleResponse>,
                            public StoppableCall {
 public:
  CoupleReactor(Core* core, grpc::CallbackServerContext* ctx)
      : core_(core),
        ctx_(ctx),
        session_id_(fmt::format("s{}", NextSessionNumber())),
        worker_pd_(core->limits, session_id_),
        probe_slot_(std::make_shared<ProbeSlot>()) {
    probe_slot_->session_id = session_id_;
    core_->Register(this);
    if (auto s = core_->Gate(); !s.ok()) {
      Stop(s);
    } else if (auto s = core_->tokens.CheckAnyToken(*ctx_); !s.ok()) {
      Stop(s);
    } else if (core_->sessions.fetch_add(1) >= core_->limits.max_sessions) {
      --core_->sessions;
      Stop(grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                        "the server already runs its limit of " +
                            std::to_string(core_->limits.max_sessions) + " device sessions"));
    } else {
      counted_ = true;
    }
    worker_ = std::thread([this] { Run(); });
    GrpcStart(this, [&] { StartRead(&req_); });
  }

  void Stop(const grpc::Status& status) override {
    {
      std::lock_guard lock(mb_mu_);
      if (!stop_) {
        stop_ = true;
        stop_status_ = status;
      }
    }
    mb_cv_.notify_all();
  }
  const Scene* scene() const override { return scene_ptr_.load(); }

 private:
  static std::uint64_t NextSessionNumber() {
    static std::atomic<std::uint64_t> n{1};
    return n.fetch_add(1);
  }

  // ---- gRPC reactions -------------------------------------------------------

  void OnReadDone(bool ok) override {
    const Reaction reaction(this);
    if (!ok) {
      {
        std::lock_guard lock(mb_mu_);
        client_done_ = true;
      }
      mb_cv_.notify_all();
      return;
    }
    const std::int64_t rx = NowNs();
    grpc::Status bad;
    bool telemetry = false;
    {
      std::lock_guard lock(mb_mu_);
      idle_since_ns_ = std::max(idle_since_ns_, rx);
      if (req_.has_hello()) {
        if (hello_received_) {
          bad = InvalidArgument("hello", "sent twice (send it once, first)");
        } else {
          hello_received_ = true;
          hello_.Swap(req_.mutable_hello());
        }
      } else if (req_.has_pose()) {
        if (!hello_received_) {
          bad = grpc::Status(grpc::StatusCode::FAILED_PRECONDITION,
                             "pose: the first message must be a hello");
        } else {
          Pose X;
          bad = FromProto(req_.pose().pose(), "pose.pose", &X);
          if (bad.ok()) {
            const std::uint64_t seq = req_.pose().sequence();
            // A pose not newer than the last one taken (out of order or
            // repeated) is dropped.
            if (!have_last_seq_ || seq > last_seq_) {
              if (has_pose_) ++superseded_;
              has_pose_ = true;
              have_last_seq_ = true;
              last_seq_ = seq;
              pose_.sequence = seq;
              pose_.X_WA = X;
              pose_.client_time_ns = req_.pose().client_time_ns();
              pose_.rx_ns = rx;
              pose_.round_trip_us = SanitizeRoundTripUs(req_.pose().round_trip_us());
            }
          }
        }
      } else if (req_.has_telemetry()) {
        if (!hello_received_) {
          bad = grpc::Status(grpc::StatusCode::FAILED_PRECONDITION,
                             "telemetry: the first message must be a hello");
        } else {
          telemetry = true;
        }
      } else {
        bad = InvalidArgument("msg", "empty CoupleRequest (neither hello, pose nor telemetry)");
      }
    }
    // Telemetry is checked and handed to the observers' feed outside the
    // mailbox's lock (the worker takes poses under it).
    if (telemetry) {
      bad = CheckDeviceTelemetry(req_.telemetry(), last_telemetry_seq_);
      if (bad.ok()) {
        last_telemetry_seq_ = req_.telemetry().sequence();
        probe_slot_->feed.AddDevice(req_.mutable_telemetry());
      }
    }
    if (!bad.ok()) {
      Stop(bad);
      return;
    }
    mb_cv_.notify_all();
    GrpcStart(this, [&] { StartRead(&req_); });
  }

  void OnWriteDone(bool ok) override {
    const Reaction reaction(this);
    std::lock_guard lock(wr_mu_);
    in_flight_ = false;
    if (ok && sent_update_) core_->stats.updates_sent.fetch_add(1, std::memory_order_relaxed);
    if (sent_patch_) {
      patch_outstanding_ = false;
      if (ok) {
        core_->stats.patches_sent.fetch_add(1, std::memory_order_relaxed);
        core_->stats.patch_bytes.fetch_add(sent_patch_bytes_, std::memory_order_relaxed);
      }
    }
    if (!ok) {
      FinishLocked(grpc::Status(grpc::StatusCode::CANCELLED, "client went away"), true);
      Stop(grpc::Status::CANCELLED);
      return;
    }
    if (has_pending_patch_) {  // a patch goes before the (newer) pending update
      has_pending_patch_ = false;
      writing_.Swap(&pending_patch_);
      StartWriteLocked();
      return;
    }
    if (has_pending_) {  // also before a graceful finish: the last answer is delivered
      has_pending_ = false;
      writing_.Swap(&pending_);
      StartWriteLocked();
      return;
    }
    if (finish_wanted_) FinishLocked(finish_status_, true);
  }

  void OnCancel() override {
    const Reaction reaction(this);
    {
      std::lock_guard lock(wr_mu_);
      FinishLocked(grpc::Status::CANCELLED, true);
    }
    Stop(grpc::Status::CANCELLED);
  }

  void OnDone() override {
    GrpcTakeOver(this);
    Stop(grpc::Status::CANCELLED);
    {
      std::lock_guard lock(mb_mu_);
      done_ = true;  // a worker waiting for the end of an idle session returns
    }
    mb_cv_.notify_all();
    // gRPC runs OnDone on its executor for non-inline reactors, never inside
    // the worker's Finish; the check only guards against joining itself.
    if (worker_.joinable()) {
      if (worker_.get_id() == std::this_thread::get_id()) {
        worker_.detach();
      } else {
        worker_.join();
      }
    }
    if (scene_ && probe_slot_) scene_->RemoveProbe(probe_slot_.get());
    if (scene_) --scene_->sessions;
    if (counted_) --core_->sessions;
    core_->Unregister(this);
    Log()->info("session {} ended", session_id_);
    delete this;
  }

  // ---- writer ---------------------------------------------------------------

  void StartWriteLocked() {
    if (writing_.has_update()) writing_.mutable_update()->set_server_send_time_ns(NowNs());
    sent_update_ = writing_.has_update();
    sent_patch_ = writing_.has_patch();
    if (sent_patch_) sent_patch_bytes_ = writing_.ByteSizeLong();
    in_flight_ = true;
    GrpcStart(this, [&] { StartWrite(&writing_); });
  }

  /// Hands a message to the writer (swapping it out of *msg).
  void Send(v1::CoupleResponse* msg) {
    std::lock_guard lock(wr_mu_);
    if (finish_wanted_ || finish_called_) return;
    if (!in_flight_) {
      writing_.Swap(msg);
      StartWriteLocked();
    } else {
      if (has_pending_) core_->stats.updates_replaced.fetch_add(1, std::memory_order_relaxed);
      pending_.Swap(msg);
      has_pending_ = true;
    }
  }

  /// Hands a geometry patch to the writer (swapping it out of *msg). It is
  /// never replaced: the worker hands over the next one only once
  /// PatchOutstanding() is false.
  void SendPatch(v1::CoupleResponse* msg) {
    std::lock_guard lock(wr_mu_);
    if (finish_wanted_ || finish_called_) return;
    patch_outstanding_ = true;
    if (!in_flight_) {
      writing_.Swap(msg);
      StartWriteLocked();
    } else {
      pending_patch_.Swap(msg);
      has_pending_patch_ = true;
    }
  }

  /// A patch handed to the writer has not been written yet.
  bool PatchOutstanding() {
    std::lock_guard lock(wr_mu_);
    return patch_outstanding_;
  }

  /// Under wr_mu_: Finish once, after the write in flight (and, for OK, the
  /// pending answer) unless forced.
  void FinishLocked(const grpc::Status& status, bool force) {
    if (finish_called_) return;
    if (!finish_wanted_) {
      finish_wanted_ = true;
      finish_status_ = status;
      if (!status.ok()) {  // an error ends the stream without more answers
        has_pending_ = false;
        has_pending_patch_ = false;
      }
    }
    if (!in_flight_ || force) {
      finish_called_ = true;
      GrpcStart(this, [this, s = Bounded(finish_status_)] { Finish(s); });
    }
  }

  // ---- worker ---------------------------------------------------------------

  void Run() {
    grpc::Status end = Serve();
    if (!end.ok() && end.error_code() != grpc::StatusCode::CANCELLED) {
      Log()->info("session {} ends: {} {}", session_id_, wire::StatusCodeName(end.error_code()),
                  wire::Printable(end.error_message(), wire::kMaxStatusMessage));
    }
    {
      std::lock_guard lock(wr_mu_);
      // An idle client may not be reading either: do not wait for the write
      // in flight to finish first.
      FinishLocked(end, idle_);
    }
    if (!idle_) return;
    // A frozen client cannot take the status, and gRPC only ends the call
    // once it has: cancel it if it has not ended soon after.
    std::unique_lock lock(mb_mu_);
    if (!mb_cv_.wait_for(lock, std::chrono::seconds(1), [&] { return done_; })) {
      lock.unlock();
      ctx_->TryCancel();
    }
  }

  /// Waits until `ready` (under mb_mu_), a stop, or the idle timeout since
  /// idle_since_ns_. False when the caller must return *end.
  template <class Ready>
  bool WaitClient(std::unique_lock<std::mutex>& lock, Ready ready, grpc::Status* end) {
    const double idle_s = core_->limits.idle_timeout_s;
    for (;;) {
      if (stop_) {
        *end = stop_status_;
        return false;
      }
      if (ready()) return true;
      if (idle_s <= 0) {
        mb_cv_.wait(lock);
        continue;
      }
      const auto idle = std::chrono::nanoseconds(static_cast<std::int64_t>(idle_s * 1e9));
      const std::int64_t deadline_ns = idle_since_ns_ + idle.count();
      if (NowNs() >= deadline_ns) {
        idle_ = true;
        core_->stats.sessions_idle_ended.fetch_add(1, std::memory_order_relaxed);
        *end = grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED,
                            fmt::format("no message from the client for {:g} s (the server's "
                                        "idle timeout, serve --idle-timeout): session ended",
                                        idle_s));
        return false;
      }
      mb_cv_.wait_for(lock, std::chrono::nanoseconds(deadline_ns - NowNs()));
    }
  }

  /// The server has answered (the welcome or an update): the client's idle
  /// time starts now, not at the message it answered.
  void Answered() {
    const std::int64_t now = NowNs();
    std::lock_guard lock(mb_mu_);
    idle_since_ns_ = std::max(idle_since_ns_, now);
  }

  /// Waits for the hello or a stop; false on stop.
  grpc::Status WaitHello() {
    std::unique_lock lock(mb_mu_);
    grpc::Status end;
    if (!WaitClient(
            lock, [&] { return hello_received_ || client_done_; }, &end))
      return end;
    if (!hello_received_) return InvalidArgument("hello", "the stream ended before a hello");
    return grpc::Status::OK;
  }

  grpc::Status Hello() {
    const v1::Hello& h = hello_;
    if (h.protocol_version() != kProtocolVersion) {
      return grpc::Status(grpc::StatusCode::FAILED_PRECONDITION,
                          "hello.protocol_version: this server speaks version " +
                              std::to_string(kProtocolVersion) + ", the client asked for " +
                              std::to_string(h.protocol_version()));
    }
    ScenePtr scene;
    if (auto s = ResolveScene(core_, *ctx_, h.scene_id(), Role::kDevice, &scene); !s.ok()) {
      // The field is in the hello, unless the routing header disagrees with it.
      if ((s.error_code() == grpc::StatusCode::INVALID_ARGUMENT ||
           s.error_code() == grpc::StatusCode::NOT_FOUND) &&
          !s.error_message().starts_with(wire::kSceneHeader)) {
        return grpc::Status(s.error_code(), "hello." + s.error_message());
      }
      return s;
    }
    v1::CoupleResponse msg;
    if (auto s = worker_pd_.Start(h, scene, msg.mutable_welcome()); !s.ok()) return s;
    // The session is live from here.
    scene_ = scene;
    scene_ptr_.store(scene.get());
    ++scene_->sessions;
    v1::SessionInfo& info = probe_slot_->info;
    info.set_session_id(session_id_);
    info.set_client_name(wire::Printable(h.client_name()));
    info.set_mode(msg.welcome().mode());
    *info.mutable_probe_mesh_info() = msg.welcome().probe_mesh_info();
    if (h.probe_case() == v1::Hello::kProbeBodyId) info.set_probe_body_id(h.probe_body_id());
    probe_slot_->probe = worker_pd_.probe();
    scene_->AddProbe(probe_slot_);
    if (scene_->deleted()) {
      return grpc::Status(grpc::StatusCode::NOT_FOUND, "scene '" + scene_->id() + "' was deleted");
    }
    Send(&msg);
    Log()->info(
        "session {} on scene '{}': {} probe of {} triangles, mode {}{}", session_id_, scene_->id(),
        h.client_name().empty() ? "a" : wire::Printable(h.client_name()) + "'s",
        worker_pd_.probe()->mesh().num_triangles(), v1::PdMode_Name(h.mode()),
        h.probe_case() == v1::Hello::kProbeBodyId ? " (probe is body " + h.probe_body_id() + ")"
                                                  : std::string());
    return grpc::Status::OK;
  }

  /// One answer, with the server's counters and the observers' probe.
  void Compute(const MailPose& p, std::uint32_t superseded, v1::CoupleResponse* msg) {
    const AnswerInfo info = worker_pd_.Answer(p, superseded, msg->mutable_update());
    if (info.pd_ran) {
      core_->stats.compute_us.Add(info.time_us);
      core_->stats.pd_calls.fetch_add(1, std::memory_order_relaxed);
      if (!info.torque) core_->stats.torque_skipped.fetch_add(1, std::memory_order_relaxed);
    }
    if (info.withheld != nullptr) {
      core_->stats.updates_withheld.fetch_add(1, std::memory_order_relaxed);
      if (withheld_++ == 0) {
        Log()->warn(
            "session {}: an answer was withheld ({}); it and any later ones go out as "
            "zero force, no rows (CONTACT_STATUS_WITHHELD)",
            session_id_, info.withheld);
      }
    }
    PublishProbe(p, info.force_W, info.depth, msg->update());
  }

  /// Shows the answered probe pose to observers (a short lock, after PD),
  /// the answer in full while an observer asks for contacts, and the
  /// answer's wrench to the telemetry feed (wait-free).
  void PublishProbe(const MailPose& p, const Vec3& force_W, double depth,
                    const v1::ContactUpdate& u) {
    const auto norm = [](const v1::Vec3& v) {
      return std::sqrt(v.x() * v.x() + v.y() * v.y() + v.z() * v.z());
    };
    probe_slot_->feed.AddAnswer(NowNs(), norm(u.force()), norm(u.torque()));
    std::shared_ptr<v1::ProbeState> full;
    if (scene_->contact_watchers.load(std::memory_order_relaxed) > 0) {
      full = std::make_shared<v1::ProbeState>();
      full->set_session_id(session_id_);
      *full->mutable_pose() = u.pose_ref();
      *full->mutable_force() = u.force();
      full->set_depth(u.depth());
      full->set_sequence(p.sequence);
      *full->mutable_torque() = u.torque();
      full->set_status(u.status());
      *full->mutable_rows() = u.rows();
      *full->mutable_body_ids() = u.body_ids();
      *full->mutable_target_pose() = u.target_pose();
      full->set_mode(static_cast<v1::PdMode>(worker_pd_.mode()));
    }
    std::lock_guard lock(probe_slot_->mu);
    probe_slot_->valid = true;
    probe_slot_->X_WA = p.X_WA;
    probe_slot_->force_W = force_W;
    probe_slot_->depth = depth;
    probe_slot_->sequence = p.sequence;
    probe_slot_->full = std::move(full);
  }

  grpc::Status Serve() {
    if (auto s = WaitHello(); !s.ok()) return s;
    if (!counted_) {
      std::lock_guard lock(mb_mu_);
      return stop_status_;
    }
    if (auto s = Hello(); !s.ok()) return s;
    Answered();
    v1::CoupleResponse msg;
    v1::CoupleResponse patch_msg;
    auto next_allowed = std::chrono::steady_clock::now();
    for (;;) {
      MailPose p;
      std::uint32_t superseded = 0;
      {
        std::unique_lock lock(mb_mu_);
        grpc::Status end;
        if (!WaitClient(
                lock, [&] { return has_pose_ || client_done_; }, &end))
          return end;
        if (!has_pose_) return grpc::Status::OK;  // client half-closed, everything answered
        if (worker_pd_.min_period().count() > 0) {
          mb_cv_.wait_until(lock, next_allowed, [&] { return stop_; });
          if (stop_) return stop_status_;
        }
        p = pose_;
        has_pose_ = false;
        superseded = superseded_;
        superseded_ = 0;
      }
      if (superseded)
        core_->stats.poses_superseded.fetch_add(superseded, std::memory_order_relaxed);
      if (scene_->deleted()) {
        return grpc::Status(grpc::StatusCode::NOT_FOUND,
                            "scene '" + scene_->id() + "' was deleted");
      }
      if (worker_pd_.min_period().count() > 0)
        next_allowed = std::chrono::steady_clock::now() + worker_pd_.min_period();
      Compute(p, superseded, &msg);
      Send(&msg);
      Answered();
      if (worker_pd_.patches_enabled() && !PatchOutstanding() &&
          worker_pd_.Patch(p, patch_msg.mutable_patch())) {
        SendPatch(&patch_msg);
      }
    }
  }

  Core* core_;
  grpc::CallbackServerContext* ctx_;
  std::string session_id_;
  bool counted_ = false;
  std::thread worker_;
  v1::CoupleRequest req_;

  // Mailbox (mb_mu_): the hello, the newest pose, stop requests.
  std::mutex mb_mu_;
  std::condition_variable mb_cv_;
  bool stop_ = false;
  grpc::Status stop_status_;
  bool client_done_ = false;
  bool hello_received_ = false;
  v1::Hello hello_;
  bool has_pose_ = false;
  MailPose pose_;
  std::uint32_t superseded_ = 0;
  bool have_last_seq_ = false;
  /// The idle timeout counts from here: the client's last message or the
  /// end of the server's last answer, whichever is later. A client that
  /// waits for a slow answer before it sends again is not idle.
  std::int64_t idle_since_ns_ = NowNs();
  bool idle_ = false;  ///< the session ends for the idle timeout
  bool done_ = false;  ///< OnDone has run
  std::uint64_t last_seq_ = 0;
  std::uint64_t last_telemetry_seq_ = 0;  ///< the reader's own (reads never overlap)

  // Writer (wr_mu_).
  std::mutex wr_mu_;
  bool in_flight_ = false;
  bool sent_update_ = false;
  bool sent_patch_ = false;
  std::size_t sent_patch_bytes_ = 0;
  bool has_pending_ = false;
  bool has_pending_patch_ = false;
  bool patch_outstanding_ = false;  ///< handed to the writer, not yet written
  bool finish_wanted_ = false;
  bool finish_called_ = false;
  grpc::Status finish_status_;
  v1::CoupleResponse writing_;
  v1::CoupleResponse pending_;
  v1::CoupleResponse pending_patch_;

  // Worker-only state.
  SessionWorker worker_pd_;
  ScenePtr scene_;
  std::atomic<const Scene*> scene_ptr_{nullptr};
  std::shared_ptr<ProbeSlot> probe_slot_;
  std::uint64_t withheld_ = 0;
};

}  // namespace

grpc::ServerBidiReactor<v1::CoupleRequest, v1::CoupleResponse>* HapticServiceImpl::Couple(
    grpc::CallbackServerContext* ctx) {
  const ServiceCall call(this);
  return new CoupleReactor(core_, ctx);
}

}  // namespace hapticpd::server::internal
