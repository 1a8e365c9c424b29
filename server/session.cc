// HapticService.Couple: one device session per stream, with a dedicated PD
// worker thread.
//
//   gRPC threads (OnReadDone)  --newest pose-->  mailbox (one slot)
//   worker: take newest pose, load scene snapshot, PD, build ContactUpdate
//   worker  --update-->  writer: at most one write in flight; an update not
//                        yet sent is replaced by a newer one
#include <grpcpp/grpcpp.h>

#include <cmath>
#include <condition_variable>
#include <thread>

#include "pd/scene_pd.h"
#include "proto/wire/ranges.h"
#include "proto/wire/text.h"
#include "server/convert.h"
#include "server/scene_file.h"
#include "server/services.h"

namespace hapticpd::server::internal {
namespace {

constexpr std::uint32_t kProtocolVersion = 1;

bool Finite(const v1::Vec3& v) {
  return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z());
}
bool Finite(const v1::Pose& p) {
  const v1::Quaternion& q = p.orientation();
  return Finite(p.position()) && std::isfinite(q.w()) && std::isfinite(q.x()) &&
         std::isfinite(q.y()) && std::isfinite(q.z());
}
double Norm(const v1::Vec3& v) { return std::sqrt(v.x() * v.x() + v.y() * v.y() + v.z() * v.z()); }

/// Why an answer must not reach a motor, or null when it may.
const char* UpdateProblem(const v1::ContactUpdate& u, double max_force, double max_torque) {
  if (!Finite(u.force()) || !Finite(u.torque())) return "non-finite force or torque";
  if (Norm(u.force()) > max_force) return "force over the server's --max-update-force";
  if (Norm(u.torque()) > max_torque) return "torque over the server's --max-update-torque";
  for (const v1::ContactRow& r : u.rows()) {
    if (!Finite(r.point()) || !Finite(r.normal()) || !Finite(r.moment()) ||
        !std::isfinite(r.depth()) || !std::isfinite(r.stiffness()) ||
        !std::isfinite(r.static_friction()) || !std::isfinite(r.dynamic_friction()) ||
        !std::isfinite(r.damping())) {
      return "a non-finite contact row";
    }
  }
  if (!Finite(u.pose_ref()) || !Finite(u.target_pose()) || !Finite(u.pd_translation()) ||
      !Finite(u.rotation_axis())) {
    return "a non-finite pose or PD vector";
  }
  for (double x : {u.depth(), u.validity_radius(), u.validity_angle(), u.target_stiffness(),
                   u.target_rotational_stiffness(), u.sigma(), u.rotation_angle()}) {
    if (!std::isfinite(x)) return "a non-finite depth, validity or stiffness";
  }
  return nullptr;
}

/// Two contact springs in series (probe and body material): k_p k_b / (k_p + k_b).
double SeriesStiffness(double kp, double kb) { return kp + kb > 0 ? kp * kb / (kp + kb) : 0.0; }

class CoupleReactor final : public grpc::ServerBidiReactor<v1::CoupleRequest, v1::CoupleResponse>,
                            public StoppableCall {
 public:
  CoupleReactor(Core* core, grpc::CallbackServerContext* ctx) : core_(core), ctx_(ctx) {
    core_->Register(this);
    session_id_ = std::to_string(NextSessionNumber());
    session_id_.insert(0, 1, 's');
    if (core_->shutting_down.load()) {
      Stop(core_->Unavailable());
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
    {
      std::lock_guard lock(mb_mu_);
      last_rx_ns_ = rx;
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
            if (have_last_seq_ && seq <= last_seq_) {
              ++stale_poses_;  // out of order or repeated: not newer than what we have
            } else {
              if (has_pose_) ++superseded_;
              has_pose_ = true;
              have_last_seq_ = true;
              last_seq_ = seq;
              pose_.sequence = seq;
              pose_.X_WA = X;
              pose_.client_time_ns = req_.pose().client_time_ns();
              pose_.rx_ns = rx;
            }
          }
        }
      } else {
        bad = InvalidArgument("msg", "empty CoupleRequest (neither hello nor pose)");
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
    if (!ok) {
      FinishLocked(grpc::Status(grpc::StatusCode::CANCELLED, "client went away"), true);
      Stop(grpc::Status::CANCELLED);
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

  /// Under wr_mu_: Finish once, after the write in flight (and, for OK, the
  /// pending answer) unless forced.
  void FinishLocked(const grpc::Status& status, bool force) {
    if (finish_called_) return;
    if (!finish_wanted_) {
      finish_wanted_ = true;
      finish_status_ = status;
      if (!status.ok()) has_pending_ = false;  // an error ends the stream without more answers
    }
    if (!in_flight_ || force) {
      finish_called_ = true;
      GrpcStart(this, [this, s = Bounded(finish_status_)] { Finish(s); });
    }
  }

  // ---- worker ---------------------------------------------------------------

  struct MailPose {
    std::uint64_t sequence = 0;
    Pose X_WA;
    std::int64_t client_time_ns = 0;
    std::int64_t rx_ns = 0;
  };

  void Run() {
    grpc::Status end = Serve();
    if (!end.ok() && end.error_code() != grpc::StatusCode::CANCELLED) {
      Log()->info("session {} ends: {} {}", session_id_, StatusCodeName(end.error_code()),
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
  /// the client's last message. False when the caller must return *end.
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
      const std::int64_t deadline_ns = last_rx_ns_ + idle.count();
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

  /// Waits for the hello or a stop; false on stop.
  grpc::Status WaitHello() {
    std::unique_lock lock(mb_mu_);
    grpc::Status end;
    if (!WaitClient(lock, [&] { return hello_received_ || client_done_; }, &end)) return end;
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
      if (s.error_code() == grpc::StatusCode::INVALID_ARGUMENT ||
          s.error_code() == grpc::StatusCode::NOT_FOUND) {
        return grpc::Status(s.error_code(), "hello." + s.error_message());
      }
      return s;
    }
    // The scene's declared effects and PD mode (a hello without a mode gets
    // the scene's); without torque, answers carry no torque terms.
    const v1::SceneConfig config = scene->config();
    const v1::PdMode hello_mode = h.mode() == v1::PD_MODE_UNSPECIFIED ? config.pd_mode() : h.mode();
    if (auto s = CheckModeSupported(hello_mode); !s.ok()) return s;
    mode_ = hello_mode;
    torque_ = SceneHasEffect(config, v1::EFFECT_TORQUE);
    // The scene's probe inertia override (mass and inertia both given; the
    // parser and CheckSceneConfig reject inertia without mass) replaces the
    // mesh's uniform-solid rotational weights of the PDg object norm.
    if (config.probe_mass() > 0 && config.probe_inertia() > 0) {
      request_.principal_inertia_over_mass =
          Vec3::Constant(config.probe_inertia() / config.probe_mass());
    }
    // Only effects at the contact regions need PD; weight alone does not.
    needs_pd_ =
        SceneHasEffect(config, v1::EFFECT_CONTACT) || SceneHasEffect(config, v1::EFFECT_FRICTION) ||
        SceneHasEffect(config, v1::EFFECT_DAMPING) || SceneHasEffect(config, v1::EFFECT_TEXTURE);
    if (h.has_material()) {
      if (auto s = FromProto(h.material(), "hello.material", &probe_material_); !s.ok()) return s;
      has_probe_material_ = true;
    }
    if (auto s = wire::CheckRange(h.max_rate_hz(), wire::kMaxRateHz, "hello.max_rate_hz");
        !s.ok()) {
      return s;
    }
    if (h.max_rate_hz() > 0) {
      min_period_ = std::chrono::nanoseconds(static_cast<std::int64_t>(1e9 / h.max_rate_hz()));
    }
    const std::size_t max_tris = core_->limits.max_mesh_triangles;
    std::optional<pd::Mesh> mesh;
    switch (h.probe_case()) {
      case v1::Hello::kProbeBodyId: {
        if (auto s = ValidateId(h.probe_body_id(), "hello.probe_body_id"); !s.ok()) return s;
        const SnapshotPtr snap = scene->snapshot();
        const BodyState* b = snap->Find(h.probe_body_id());
        if (b == nullptr) {
          return grpc::Status(grpc::StatusCode::NOT_FOUND, "hello.probe_body_id: scene '" +
                                                               scene->id() + "' has no body '" +
                                                               h.probe_body_id() + "'");
        }
        probe_ = b->model;
        probe_uid_ = b->uid;
        break;
      }
      case v1::Hello::kProbeMesh:
        if (auto s = MeshFromInline(h.probe_mesh(), "hello.probe_mesh", max_tris, &mesh); !s.ok())
          return s;
        break;
      case v1::Hello::kProbeShape:
        if (auto s = MeshFromShape(h.probe_shape(), "hello.probe_shape", max_tris, &mesh); !s.ok())
          return s;
        break;
      default:
        return InvalidArgument("hello.probe", "give probe_body_id, probe_mesh or probe_shape");
    }
    if (mesh) probe_ = pd::MakeModel(std::move(*mesh));  // on this worker, off the gRPC threads
    // The session is live from here.
    scene_ = scene;
    scene_ptr_.store(scene.get());
    ++scene_->sessions;
    probe_slot_ = std::make_shared<ProbeSlot>();
    probe_slot_->session_id = session_id_;
    scene_->AddProbe(probe_slot_);
    if (scene_->deleted()) {
      return grpc::Status(grpc::StatusCode::NOT_FOUND, "scene '" + scene_->id() + "' was deleted");
    }
    const pd::Mesh& pm = probe_->mesh();
    probe_radius_ = pm.bounding_radius();
    v1::CoupleResponse msg;
    auto* w = msg.mutable_welcome();
    w->set_protocol_version(kProtocolVersion);
    w->set_session_id(session_id_);
    w->set_mode(static_cast<v1::PdMode>(mode_));
    ToProto(probe_->mass().X_MB, w->mutable_probe_body_frame());
    auto* info = w->mutable_probe_mesh_info();
    info->set_triangles(static_cast<std::uint32_t>(pm.num_triangles()));
    info->set_vertices(static_cast<std::uint32_t>(pm.num_vertices()));
    info->set_watertight(pm.watertight());
    info->set_convex(probe_->convex());
    ToProto(pm.bounds().lo, info->mutable_aabb_min());
    ToProto(pm.bounds().hi, info->mutable_aabb_max());
    ToProto(probe_->mass().p_MC, info->mutable_center_of_mass());
    info->set_bounding_radius(pm.bounding_radius());
    w->set_probe_mass_per_density(probe_->mass().volume);
    w->set_scene_revision(scene_->snapshot()->revision);
    *w->mutable_scene_config() = config;
    Send(&msg);
    Log()->info("session {} on scene '{}': {} probe of {} triangles, mode {}{}", session_id_,
                scene_->id(),
                h.client_name().empty() ? "a" : wire::Printable(h.client_name()) + "'s",
                pm.num_triangles(), v1::PdMode_Name(h.mode()),
                h.probe_case() == v1::Hello::kProbeBodyId
                    ? " (probe is body " + h.probe_body_id() + ")"
                    : std::string());
    return grpc::Status::OK;
  }

  /// Rebuilds the session's view of the scene when the snapshot changed:
  /// the bodies (minus the probe's own), effective materials, and the
  /// per-body coherence state carried over by body uid.
  void SyncBodies(const SnapshotPtr& snap) {
    if (snap == synced_) return;
    bodies_.clear();
    std::vector<std::uint64_t> uids;
    std::vector<pd::PdQueryData> data;
    std::vector<pd::PdgQueryData> data_pdg;
    for (const BodyState& b : snap->bodies) {
      if (b.uid == probe_uid_) continue;
      pd::SceneBody sb{b.model, b.X_WB, b.material};
      if (has_probe_material_) {
        sb.material.stiffness = SeriesStiffness(probe_material_.stiffness, b.material.stiffness);
        sb.material.rotational_stiffness =
            SeriesStiffness(probe_material_.rotational_stiffness, b.material.rotational_stiffness);
      }
      bodies_.push_back(std::move(sb));
      uids.push_back(b.uid);
      body_ids_.resize(bodies_.size());
      body_ids_.back() = b.id;
      // Carry the body's coherence state over (by uid), for the method in use.
      const auto it = std::find(uids_.begin(), uids_.end(), b.uid);
      const auto k = static_cast<std::size_t>(it - uids_.begin());
      if (mode_ == v1::PD_MODE_PDG) {
        data_pdg.push_back(it != uids_.end() && k < pd_data_.per_body_pdg.size()
                               ? std::move(pd_data_.per_body_pdg[k])
                               : pd::PdgQueryData());
      } else {
        data.push_back(it != uids_.end() && k < pd_data_.per_body.size()
                           ? std::move(pd_data_.per_body[k])
                           : pd::PdQueryData());
      }
    }
    body_ids_.resize(bodies_.size());
    uids_ = std::move(uids);
    pd_data_.per_body = std::move(data);
    pd_data_.per_body_pdg = std::move(data_pdg);
    synced_ = snap;
  }

  void Compute(const MailPose& p, std::uint32_t superseded, v1::CoupleResponse* msg) {
    v1::ContactUpdate* u = msg->mutable_update();
    u->Clear();
    u->set_sequence(p.sequence);
    ToProto(p.X_WA, u->mutable_pose_ref());
    u->set_client_time_ns(p.client_time_ns);
    u->set_server_receive_time_ns(p.rx_ns);
    u->set_poses_superseded(superseded);
    const SnapshotPtr snap = scene_->snapshot();
    u->set_scene_revision(snap->revision);
    const double radius = 0.1 * probe_radius_;
    last_pose_ = p.X_WA;
    if (mode_ == v1::PD_MODE_NONE || !needs_pd_) {
      u->set_status(v1::CONTACT_STATUS_NONE);
      ToProto(p.X_WA, u->mutable_target_pose());
      u->set_validity_radius(radius);
      u->set_validity_angle(radius / std::max(probe_->radius_about_com(), 1e-12));
      PublishProbe(p, Vec3::Zero(), 0);
      return;
    }
    SyncBodies(snap);
    pd::ComputeScenePd(
        mode_ == v1::PD_MODE_PDG ? pd::PdMode::kGeneralized : pd::PdMode::kTranslational, *probe_,
        p.X_WA, bodies_, request_, &pd_data_, &result_,
        torque_ ? pd::WrenchTerms::kForceAndTorque : pd::WrenchTerms::kForceOnly);
    core_->stats.compute_us.Add(result_.time_us);
    core_->stats.pd_calls.fetch_add(1, std::memory_order_relaxed);
    if (!torque_) core_->stats.torque_skipped.fetch_add(1, std::memory_order_relaxed);
    const Vec3 c_W = p.X_WA * probe_->mass().p_MC;
    bool failed = false, capped = false;
    for (std::size_t i = 0; i < bodies_.size(); ++i) {
      const pd::PenetrationResult& r = result_.bodies[i];
      if (r.status == pd::PdStatus::kFailed) failed = true;
      if (r.status == pd::PdStatus::kPenetratingCapReached) capped = true;
      if (r.status != pd::PdStatus::kPenetratingSolved &&
          r.status != pd::PdStatus::kPenetratingCapReached) {
        continue;
      }
      const auto body_index = static_cast<std::uint32_t>(u->body_ids_size());
      u->add_body_ids(body_ids_[i]);
      const pd::Material& mat = bodies_[i].material;
      const double k = mat.stiffness;
      auto add_row = [&](const Vec3& p_W, const Vec3& n_W, double depth) {
        auto* row = u->add_rows();
        ToProto(p_W, row->mutable_point());
        ToProto(n_W, row->mutable_normal());
        row->set_depth(depth);
        // Without torque the rows are pure forces (zero moment arm).
        if (torque_) ToProto((p_W - c_W).cross(n_W), row->mutable_moment());
        row->set_stiffness(k);
        row->set_body_index(body_index);
        row->set_static_friction(mat.static_friction);
        row->set_dynamic_friction(mat.dynamic_friction);
        row->set_damping(mat.damping);
      };
      // No regions (PDg, or PDt without them): one row at the centre of mass
      // along the answer's translation (for PDg, depth = sqrt(sigma) is not
      // the translation's length: the row uses the translation itself).
      if (const double len = r.translation_W.norm(); r.regions.empty() && len > 0) {
        add_row(c_W, r.translation_W / len, len);
      }
      for (const pd::ContactRegion& reg : r.regions) add_row(reg.p_W, reg.n_W, reg.depth);
    }
    ToProto(result_.wrench.force, u->mutable_force());
    if (torque_) ToProto(result_.wrench.torque, u->mutable_torque());
    if (result_.deepest >= 0) {
      const pd::PenetrationResult& d = result_.bodies[result_.deepest];
      u->set_depth(d.depth);
      ToProto(d.translation_W, u->mutable_pd_translation());
      ToProto(d.X_WA_result, u->mutable_target_pose());
      u->set_target_stiffness(bodies_[result_.deepest].material.stiffness);
      if (torque_) {
        u->set_target_rotational_stiffness(bodies_[result_.deepest].material.rotational_stiffness);
      }
      if (d.mode == pd::PdMode::kGeneralized) {
        u->set_sigma(d.sigma);
        u->set_rotation_angle(d.rotation_angle);
        ToProto(d.rotation_axis_W, u->mutable_rotation_axis());
      }
    } else {
      ToProto(p.X_WA, u->mutable_target_pose());
    }
    u->set_status(failed              ? v1::CONTACT_STATUS_FAILED
                  : capped            ? v1::CONTACT_STATUS_CAP_REACHED
                  : result_.colliding ? v1::CONTACT_STATUS_PENETRATING
                                      : v1::CONTACT_STATUS_SEPARATED);
    // The rows are a linearisation around pose_ref; trust them over a tenth
    // of the probe's size beyond the current depth.
    const double linear = radius + u->depth();
    u->set_validity_radius(linear);
    u->set_validity_angle(linear / std::max(probe_->radius_about_com(), 1e-12));
    u->set_compute_time_us(result_.time_us);
    if (!Withhold(u)) PublishProbe(p, result_.wrench.force, u->depth());
  }

  /// The last line of defence before a motor: an answer holding a
  /// non-finite number, or a force or torque over the configured limit, is
  /// replaced by zero force and no rows (CONTACT_STATUS_WITHHELD), keeping
  /// what identifies it (sequence, poses, times). True when replaced.
  bool Withhold(v1::ContactUpdate* u) {
    const char* why = UpdateProblem(*u, core_->limits.max_update_force,
                                    core_->limits.max_update_torque);
    if (why == nullptr) return false;
    core_->stats.updates_withheld.fetch_add(1, std::memory_order_relaxed);
    if (withheld_++ == 0) {
      Log()->warn("session {}: an answer was withheld ({}); it and any later ones go out as "
                  "zero force, no rows (CONTACT_STATUS_WITHHELD)",
                  session_id_, why);
    }
    u->clear_rows();
    u->clear_body_ids();
    u->clear_force();
    u->clear_torque();
    *u->mutable_target_pose() = u->pose_ref();
    u->set_depth(0);
    u->clear_pd_translation();
    u->set_target_stiffness(0);
    u->set_target_rotational_stiffness(0);
    u->set_sigma(0);
    u->set_rotation_angle(0);
    u->clear_rotation_axis();
    const double radius = 0.1 * probe_radius_;
    u->set_validity_radius(radius);
    u->set_validity_angle(radius / std::max(probe_->radius_about_com(), 1e-12));
    if (!std::isfinite(u->compute_time_us())) u->set_compute_time_us(0);
    u->set_status(v1::CONTACT_STATUS_WITHHELD);
    PublishProbe(MailPose{u->sequence(), last_pose_, 0, 0}, Vec3::Zero(), 0);
    return true;
  }

  /// Shows the answered probe pose to observers (a short lock, after PD).
  void PublishProbe(const MailPose& p, const Vec3& force_W, double depth) {
    std::lock_guard lock(probe_slot_->mu);
    probe_slot_->valid = true;
    probe_slot_->X_WA = p.X_WA;
    probe_slot_->force_W = force_W;
    probe_slot_->depth = depth;
    probe_slot_->sequence = p.sequence;
  }

  grpc::Status Serve() {
    if (auto s = WaitHello(); !s.ok()) return s;
    if (!counted_) {
      std::lock_guard lock(mb_mu_);
      return stop_status_;
    }
    if (auto s = Hello(); !s.ok()) return s;
    v1::CoupleResponse msg;
    auto next_allowed = std::chrono::steady_clock::now();
    for (;;) {
      MailPose p;
      std::uint32_t superseded = 0;
      {
        std::unique_lock lock(mb_mu_);
        grpc::Status end;
        if (!WaitClient(lock, [&] { return has_pose_ || client_done_; }, &end)) return end;
        if (!has_pose_) return grpc::Status::OK;  // client half-closed, everything answered
        if (min_period_.count() > 0) {
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
      if (min_period_.count() > 0) next_allowed = std::chrono::steady_clock::now() + min_period_;
      Compute(p, superseded, &msg);
      Send(&msg);
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
  std::int64_t last_rx_ns_ = NowNs();  ///< the client's last message (the idle timeout)
  bool idle_ = false;                  ///< the session ends for the idle timeout
  bool done_ = false;                  ///< OnDone has run
  std::uint64_t last_seq_ = 0;
  std::uint64_t stale_poses_ = 0;

  // Writer (wr_mu_).
  std::mutex wr_mu_;
  bool in_flight_ = false;
  bool sent_update_ = false;
  bool has_pending_ = false;
  bool finish_wanted_ = false;
  bool finish_called_ = false;
  grpc::Status finish_status_;
  v1::CoupleResponse writing_;
  v1::CoupleResponse pending_;

  // Worker-only state.
  int mode_ = v1::PD_MODE_UNSPECIFIED;
  bool torque_ = true;    // the scene declares torque (or declares nothing)
  bool needs_pd_ = true;  // the scene declares an effect at the contact regions
  pd::ModelPtr probe_;
  std::uint64_t probe_uid_ = 0;
  double probe_radius_ = 0;
  pd::Material probe_material_;
  bool has_probe_material_ = false;
  std::chrono::nanoseconds min_period_{0};
  ScenePtr scene_;
  std::atomic<const Scene*> scene_ptr_{nullptr};
  std::shared_ptr<ProbeSlot> probe_slot_;
  SnapshotPtr synced_;
  std::vector<pd::SceneBody> bodies_;
  std::vector<std::string> body_ids_;
  std::vector<std::uint64_t> uids_;
  pd::ScenePdData pd_data_;
  pd::ScenePdResult result_;
  pd::PenetrationRequest request_;
  Pose last_pose_;
  std::uint64_t withheld_ = 0;
};

}  // namespace

grpc::ServerBidiReactor<v1::CoupleRequest, v1::CoupleResponse>* HapticServiceImpl::Couple(
    grpc::CallbackServerContext* ctx) {
  const ServiceCall call(this);
  return new CoupleReactor(core_, ctx);
}

}  // namespace hapticpd::server::internal
