#include "client/session.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "proto/wire/convert.h"
#include "proto/wire/ranges.h"
#include "proto/wire/routing.h"
#include "proto/wire/status.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

namespace hapticpd::client {
namespace {

using device::IntermediateRep;
using device::IrRow;
using device::Pose;
using device::Vec3;

/// Finite, and no coordinate beyond 1e6 m (a hundred times the server's
/// coordinate range): larger numbers overflow in the servo loop's products.
bool Finite(const Vec3& v) { return v.allFinite() && v.cwiseAbs().maxCoeff() <= 1e6; }

/// Absent orientation means identity (proto3 default is all zeros).
bool ToPose(const v1::Pose& p, Pose* out) {
  const Vec3 t = wire::FromProtoUnchecked(p.position());
  if (!Finite(t)) return false;
  if (!p.has_orientation()) {
    *out = Pose::FromTranslation(t);
    return true;
  }
  const auto& q = p.orientation();
  const device::Quat quat(q.w(), q.x(), q.y(), q.z());
  if (!IsUnitQuaternion(quat)) return false;
  *out = Pose::FromQuaternion(quat, t);
  return true;
}

/// Errors retrying cannot fix (a bad hello, wrong credentials).
bool Fatal(grpc::StatusCode c) {
  return c == grpc::INVALID_ARGUMENT || c == grpc::UNAUTHENTICATED ||
         c == grpc::PERMISSION_DENIED || c == grpc::UNIMPLEMENTED;
}

}  // namespace

bool IrFromContactUpdate(const v1::ContactUpdate& u, const Pose& X_AP, std::int64_t receive_time_ns,
                         IntermediateRep* ir) {
  Pose X_WA_ref;
  if (!ToPose(u.pose_ref(), &X_WA_ref)) return false;
  ir->sequence = u.sequence();
  ir->sample_time_ns = u.client_time_ns();
  ir->receive_time_ns = receive_time_ns;
  ir->X_WP_ref = X_WA_ref * X_AP;
  ir->num_rows = 0;
  ir->use_target = false;
  ir->target_stiffness = 0;
  ir->target_rotational_stiffness = 0;
  ir->X_WP_target = ir->X_WP_ref;
  const Vec3 c = ir->X_WP_ref.t;
  for (const v1::ContactRow& r : u.rows()) {
    const Vec3 p = wire::FromProtoUnchecked(r.point());
    Vec3 n = wire::FromProtoUnchecked(r.normal());
    const double depth = r.depth(), k = r.stiffness();
    // Beyond these no server answer goes (its ranges: 1e4 m, 1e7 N/m);
    // past them the loop's products overflow.
    if (!Finite(p) || !Finite(n) || !std::isfinite(depth) || !std::isfinite(k) || k < 0 ||
        std::abs(depth) > 1e6 || k > 1e9) {
      return false;
    }
    // Normals should be unit; PDg rows built from the PD vector over the
    // object-norm depth are not quite, so normalise (a zero one is skipped).
    const double n_norm = n.norm();
    if (depth <= 0 || k == 0 || n_norm < 1e-9) continue;
    n /= n_norm;
    // The moment about the proxy origin, recomputed (it is the wire's
    // `moment` when the server's CoM and X_AP agree).
    // A server answering for a scene without torque sends no moments: the
    // row is then a pure force.
    IrRow row{p, n, r.has_moment() ? Vec3((p - c).cross(n)) : Vec3::Zero(), depth, k};
    row.static_friction =
        std::isfinite(r.static_friction()) ? std::max(0.0, r.static_friction()) : 0;
    row.dynamic_friction =
        std::isfinite(r.dynamic_friction()) ? std::max(0.0, r.dynamic_friction()) : 0;
    row.damping = std::isfinite(r.damping()) ? std::max(0.0, r.damping()) : 0;
    device::AddIrRow(row, ir);
  }
  const bool in_contact = u.status() == v1::CONTACT_STATUS_PENETRATING ||
                          u.status() == v1::CONTACT_STATUS_CAP_REACHED ||
                          u.status() == v1::CONTACT_STATUS_FAILED;
  if (u.sigma() > 0 && in_contact && u.target_stiffness() > 0) {
    Pose X_WA_target;
    if (!ToPose(u.target_pose(), &X_WA_target)) return false;
    if (!std::isfinite(u.target_stiffness()) || !std::isfinite(u.target_rotational_stiffness())) {
      return false;
    }
    ir->use_target = true;
    ir->X_WP_target = X_WA_target * X_AP;
    ir->target_stiffness = u.target_stiffness();
    ir->target_rotational_stiffness = std::max(0.0, u.target_rotational_stiffness());
  }
  ir->validity_radius = std::isfinite(u.validity_radius()) ? u.validity_radius() : 0;
  ir->validity_angle = std::isfinite(u.validity_angle()) ? u.validity_angle() : 0;
  ir->compute_time_us = u.compute_time_us();
  ir->source = device::kIrSourceServer;
  return true;
}

std::string PatchDeltaFromProto(const v1::GeometryPatch& g, std::size_t max_triangles_per_body,
                                device::PatchDelta* out) {
  out->sequence = g.sequence();
  out->scene_revision = g.scene_revision();
  out->server_time_ns = g.server_time_ns();
  out->center_W = wire::FromProtoUnchecked(g.center());
  out->radius = g.radius();
  out->wire_bytes = g.ByteSizeLong();
  out->bodies.clear();
  out->dropped_bodies.assign(g.dropped_bodies().begin(), g.dropped_bodies().end());
  const std::string where = fmt::format("patch {}", g.sequence());
  if (!Finite(out->center_W) || !std::isfinite(out->radius)) {
    return where + ": center or radius not finite";
  }
  out->bodies.resize(static_cast<std::size_t>(g.bodies_size()));
  for (int i = 0; i < g.bodies_size(); ++i) {
    const v1::BodyPatch& b = g.bodies(i);
    device::PatchBodyDelta& d = out->bodies[static_cast<std::size_t>(i)];
    const std::string field = fmt::format("{} bodies[{}] ('{}')", where, i, b.body_id());
    d.id = b.body_id();
    d.key = b.body_key();
    d.triangle_count = b.triangle_count();
    d.vertex_count = b.vertex_count();
    if (!ToPose(b.pose(), &d.X_WB)) return field + ".pose: not a finite pose";
    d.v_W = wire::FromProtoUnchecked(b.velocity().linear());
    d.w_W = wire::FromProtoUnchecked(b.velocity().angular());
    d.pose_time_ns = b.pose_time_ns();
    const v1::Material& m = b.material();
    d.material.stiffness = m.stiffness();
    d.material.rotational_stiffness = m.rotational_stiffness();
    d.material.damping = m.damping();
    d.material.static_friction = m.static_friction();
    d.material.dynamic_friction = m.dynamic_friction();
    d.cover_center_B = wire::FromProtoUnchecked(b.cover_center());
    d.cover_radius = b.cover_radius();
    d.truncated = b.truncated();
    if (!Finite(d.v_W) || !Finite(d.w_W) || !Finite(d.cover_center_B) ||
        !std::isfinite(d.cover_radius)) {
      return field + ": velocity or cover not finite";
    }
    if (b.vertices_size() != 3 * b.vertex_indices_size()) {
      return fmt::format("{}.vertices: {} numbers for {} vertex indices (3 each)", field,
                         b.vertices_size(), b.vertex_indices_size());
    }
    if (b.triangles_size() != 3 * b.triangle_indices_size()) {
      return fmt::format("{}.triangles: {} indices for {} triangle indices (3 each)", field,
                         b.triangles_size(), b.triangle_indices_size());
    }
    if (static_cast<std::size_t>(b.triangle_indices_size()) > max_triangles_per_body) {
      return fmt::format("{}: {} triangles, over the limit of {}", field, b.triangle_indices_size(),
                         max_triangles_per_body);
    }
    d.vertex_indices.assign(b.vertex_indices().begin(), b.vertex_indices().end());
    d.vertices.resize(d.vertex_indices.size());
    for (std::size_t k = 0; k < d.vertices.size(); ++k) {
      const int j = static_cast<int>(3 * k);
      d.vertices[k] = Vec3(b.vertices(j), b.vertices(j + 1), b.vertices(j + 2));
      if (!Finite(d.vertices[k])) {
        return fmt::format("{}.vertices: vertex {} not finite or beyond 1e6 m", field,
                           d.vertex_indices[k]);
      }
    }
    d.triangle_indices.assign(b.triangle_indices().begin(), b.triangle_indices().end());
    d.triangles.resize(d.triangle_indices.size());
    for (std::size_t k = 0; k < d.triangles.size(); ++k) {
      const int j = static_cast<int>(3 * k);
      d.triangles[k] = {b.triangles(j), b.triangles(j + 1), b.triangles(j + 2)};
    }
    d.dropped_triangles.assign(b.dropped_triangles().begin(), b.dropped_triangles().end());
  }
  return "";
}

struct Session::Stream {
  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<v1::HapticService::Stub> stub;
  grpc::ClientContext ctx;
  std::unique_ptr<grpc::ClientReaderWriter<v1::CoupleRequest, v1::CoupleResponse>> rw;
  std::atomic<bool> reader_done{false};
};

Session::Session(SessionOptions options, const device::Clock* clock)
    : options_(std::move(options)), clock_(clock) {
  if (options_.hello.protocol_version() == 0) options_.hello.set_protocol_version(1);
  if (options_.hello.client_name().empty()) options_.hello.set_client_name("hapticpd device");
  if (!options_.credentials) options_.credentials = grpc::InsecureChannelCredentials();
  if (!options_.local_model) counters_.local_model_note = "off";
  if (options_.local_model) {
    v1::PatchRequest* pr = options_.hello.mutable_patches();
    pr->set_enabled(true);
    pr->set_max_triangles_per_body(options_.patch_max_triangles);
    pr->set_min_margin(options_.patch_min_margin);
  }
  if (options_.link) {
    if (const std::string problem = LinkOptionsProblem(*options_.link); !problem.empty()) {
      throw SessionError("session: " + problem);
    }
    link_ = std::make_unique<Link>(*options_.link);
  }
}

Session::~Session() { Stop(); }

std::unique_ptr<Session::Stream> Session::Open(bool first, std::string* error,
                                               grpc::StatusCode* code) {
  auto s = std::make_unique<Stream>();
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);
  // A fresh channel per attempt with its own subchannels, so a restarted
  // server is found at once rather than after gRPC's own reconnect backoff.
  args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
  args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, 20);
  args.SetInt(GRPC_ARG_MIN_RECONNECT_BACKOFF_MS, 20);
  args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, 500);
  s->channel = grpc::CreateCustomChannel(options_.server, options_.credentials, args);
  const auto deadline =
      std::chrono::system_clock::now() +
      std::chrono::microseconds(static_cast<std::int64_t>(options_.connect_timeout_s * 1e6));
  *code = grpc::UNAVAILABLE;
  // In short slices, so that Stop() is prompt.
  for (;;) {
    const auto slice =
        std::min(deadline, std::chrono::system_clock::now() + std::chrono::milliseconds(50));
    if (s->channel->WaitForConnected(slice)) break;
    if (stopping_.load() || std::chrono::system_clock::now() >= deadline) {
      *error = "cannot reach " + options_.server;
      return nullptr;
    }
  }
  s->stub = v1::HapticService::NewStub(s->channel);
  if (!options_.token.empty()) s->ctx.AddMetadata("authorization", "Bearer " + options_.token);
  // Behind a balancer the header routes the stream to the scene's process.
  wire::AddSceneHeader(&s->ctx, options_.hello.scene_id());
  {
    std::lock_guard lock(ctx_mu_);
    if (stopping_.load()) {
      *error = "stopped";
      *code = grpc::CANCELLED;
      return nullptr;
    }
    live_ctx_ = &s->ctx;
  }
  auto clear_ctx = [&] {
    std::lock_guard lock(ctx_mu_);
    live_ctx_ = nullptr;
  };
  s->rw = s->stub->Couple(&s->ctx);
  v1::CoupleRequest req;
  *req.mutable_hello() = options_.hello;
  v1::CoupleResponse resp;
  // The welcome must come within the timeout: a watchdog cancels otherwise.
  std::jthread watchdog([&](std::stop_token st) {
    const auto end =
        std::chrono::steady_clock::now() +
        std::chrono::microseconds(static_cast<std::int64_t>(options_.connect_timeout_s * 1e6));
    while (!st.stop_requested() && std::chrono::steady_clock::now() < end) {
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    if (!st.stop_requested()) s->ctx.TryCancel();  // timed out
  });
  const bool ok = s->rw->Write(req) && s->rw->Read(&resp) && resp.has_welcome();
  watchdog.request_stop();
  watchdog.join();
  if (!ok) {
    const grpc::Status st = s->rw->Finish();
    clear_ctx();
    *code = st.ok() ? grpc::INTERNAL : st.error_code();
    *error = st.ok()
                 ? std::string("no welcome from the server")
                 : std::string(wire::StatusCodeName(st.error_code())) + ": " + st.error_message();
    return nullptr;
  }
  // The first welcome defines X_PA; later ones (same hello, same probe)
  // only bring a new session id.
  if (first) {
    welcome_ = resp.welcome();
  } else {
    std::lock_guard lock(stats_mu_);
    counters_.session_id = resp.welcome().session_id();
  }
  *code = grpc::OK;
  return s;
}

void Session::Connect() {
  std::string error;
  grpc::StatusCode code;
  first_ = Open(true, &error, &code);
  if (!first_) throw SessionError("session: " + error);
  Pose X_MB;
  if (!ToPose(welcome_.probe_body_frame(), &X_MB)) {
    throw SessionError("session: welcome.probe_body_frame is not a valid pose");
  }
  // P: the mesh frame moved to the centre of mass (axes kept, like
  // LocalPdIrSource), so the handle's orientation is the probe's.
  X_PA_ = Pose::FromTranslation(-X_MB.t);
  X_AP_ = X_PA_.Inverse();
  if (options_.local_model) StartLocalModel();
  std::lock_guard lock(stats_mu_);
  ++counters_.connects;
  counters_.session_id = welcome_.session_id();
}

void Session::StartLocalModel() {
  const v1::Hello& h = options_.hello;
  std::string note;
  std::optional<pd::Mesh> mesh;
  grpc::Status st;
  if (welcome_.mode() != v1::PD_MODE_PDT && welcome_.mode() != v1::PD_MODE_PDG) {
    note = "off: the session's mode computes no PD";
  } else if (h.probe_case() == v1::Hello::kProbeShape) {
    st = wire::MeshFromShape(h.probe_shape(), "hello.probe_shape", 20'000'000, &mesh);
  } else if (h.probe_case() == v1::Hello::kProbeMesh) {
    st = wire::MeshFromInline(h.probe_mesh(), "hello.probe_mesh", 20'000'000, &mesh);
  } else {
    note = "off: the probe is a scene body (the client has no copy of its mesh)";
  }
  if (!st.ok()) note = "off: " + st.error_message();
  if (note.empty() && mesh) {
    pd::ModelPtr probe = pd::MakeModel(std::move(*mesh));
    device::LocalModelOptions o;
    o.mode =
        welcome_.mode() == v1::PD_MODE_PDG ? pd::PdMode::kGeneralized : pd::PdMode::kTranslational;
    const device::EffectSet fx = EffectsFromSceneConfig(welcome_.scene_config());
    o.torque = fx.Has(device::Effect::kTorque);
    const v1::SceneConfig& c = welcome_.scene_config();
    if (c.probe_mass() > 0 && c.probe_inertia() > 0) {
      o.request.principal_inertia_over_mass = Vec3::Constant(c.probe_inertia() / c.probe_mass());
    }
    o.limits.max_triangles_per_body = options_.patch_max_triangles;
    local_ = std::make_unique<device::LocalContactModel>(std::move(probe), X_PA_, o);
    note = "on";
  }
  std::lock_guard lock(stats_mu_);
  counters_.local_model = local_ != nullptr;
  counters_.local_model_note = note;
}

void Session::Start(device::ServoLoop* loop) {
  if (thread_.joinable()) return;
  if (!first_) throw SessionError("session: Start() before Connect()");
  loop_ = loop;
  stopping_ = false;
  flush_requested_ = false;
  flush_done_ = false;
  if (local_) local_->Start(&loop_->ir_mailbox(), clock_);
  thread_ = std::jthread([this](std::stop_token st) { Run(st); });
}

void Session::Stop() {
  if (!thread_.joinable()) {
    first_.reset();
    return;
  }
  if (options_.telemetry && connected_.load()) {
    // The network thread sends the ring's last samples first (bounded wait).
    flush_requested_ = true;
    const auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(500);
    while (!flush_done_.load() && connected_.load() && std::chrono::steady_clock::now() < end) {
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
  }
  {
    std::lock_guard lock(ctx_mu_);
    stopping_ = true;
  }
  thread_.request_stop();
  thread_.join();
  thread_ = std::jthread();
  if (local_) local_->Stop();
}

void Session::StallUpdatesFor(double seconds) {
  stall_until_ns_.store(clock_->NowNs() + static_cast<std::int64_t>(seconds * 1e9),
                        std::memory_order_relaxed);
}

void Session::ReadLoop(Stream* s) {
  v1::CoupleResponse resp;
  while (s->rw->Read(&resp)) {
    if (resp.has_patch()) {
      // Patches are never withheld or lost: each is a delta on the last.
      const std::int64_t now = clock_->NowNs();
      if (link_) {
        link_->updates.Send(resp, now, /*may_lose=*/false);
      } else {
        AcceptPatch(resp.patch(), now);
      }
      continue;
    }
    if (!resp.has_update()) continue;
    const std::int64_t now = clock_->NowNs();
    if (now < stall_until_ns_.load(std::memory_order_relaxed)) {
      std::lock_guard lock(stats_mu_);
      ++counters_.withheld_updates;
      continue;
    }
    if (link_) {
      link_->updates.Send(resp, now);
    } else {
      Accept(resp.update(), now);
    }
  }
  s->reader_done = true;
}

void Session::Accept(const v1::ContactUpdate& u, std::int64_t now) {
  bool good;
  if (local_) {
    // The local model decides what the loop renders (device/local_model.h).
    good = IrFromContactUpdate(u, X_AP_, now, &server_ir_);
    if (good) local_->OfferServerIr(server_ir_);
  } else {
    device::IrMailbox& out = loop_->ir_mailbox();
    good = IrFromContactUpdate(u, X_AP_, now, &out.back());
    if (good) out.Publish();
  }
  // Round trip: from writing the pose (or, with an emulated link, offering
  // it to the link) to reading its answer (or taking it out of the link).
  const std::size_t slot = u.sequence() % kRing;
  double rtt_us = -1;
  std::int64_t sent = 0;
  if (sent_seq_[slot].load(std::memory_order_acquire) == u.sequence()) {
    sent = sent_ns_[slot].load(std::memory_order_relaxed);
    rtt_us = 1e-3 * static_cast<double>(now - sent);
  }
  if (rtt_us >= 0) {
    // The round trip the server sizes patches by (smoothed), and the server
    // clock's offset from the sample with the shortest round trip lately
    // (NTP's filter: its two one-way delays are the least uneven).
    const double prev = rtt_estimate_us_.load(std::memory_order_relaxed);
    rtt_estimate_us_.store(prev > 0 ? 0.9 * prev + 0.1 * rtt_us : rtt_us,
                           std::memory_order_relaxed);
    if (local_ && u.server_receive_time_ns() != 0 && u.server_send_time_ns() != 0 &&
        (best_rtt_us_ <= 0 || rtt_us <= best_rtt_us_ || ++since_best_ > 512)) {
      best_rtt_us_ = rtt_us;
      since_best_ = 0;
      const std::int64_t offset =
          ((u.server_receive_time_ns() - sent) + (u.server_send_time_ns() - now)) / 2;
      local_->SetServerClockOffset(offset);
      std::lock_guard lock(stats_mu_);
      counters_.server_clock_offset_ms = 1e-6 * static_cast<double>(offset);
    }
  }
  std::lock_guard lock(stats_mu_);
  ++counters_.updates;
  if (!good) ++counters_.bad_updates;
  if (u.rows_size() > 0) ++counters_.contact_updates;
  counters_.max_depth = std::max(counters_.max_depth, u.depth());
  if (rtt_us >= 0) {
    rtt_us_.Add(rtt_us);
    last_rtt_us_ = rtt_us;
  }
  compute_us_.Add(u.compute_time_us());
}

void Session::AcceptPatch(const v1::GeometryPatch& g, std::int64_t now) {
  {
    std::lock_guard lock(stats_mu_);
    ++counters_.patches_received;
  }
  if (!local_) return;
  device::PatchDelta d;
  const std::string problem = PatchDeltaFromProto(g, options_.patch_max_triangles, &d);
  if (problem.empty()) {
    local_->OfferPatch(std::move(d), now);
  } else {
    local_->RejectPatch(problem);
  }
}

void Session::DeliverLoop(const std::atomic<bool>& done) {
  v1::CoupleResponse m;
  while (!done.load()) {
    const std::int64_t now = clock_->NowNs();
    if (link_->updates.Receive(now, &m)) {
      if (m.has_patch()) {
        AcceptPatch(m.patch(), now);
      } else if (m.has_update()) {
        Accept(m.update(), now);
      }
      continue;
    }
    // Sleep until the next update is due (at most 2 ms, so `done` is seen).
    const std::int64_t wait = std::min<std::int64_t>(link_->updates.NextDueNs() - now, 2'000'000);
    link_->updates.WaitFor(std::chrono::nanoseconds(wait));
  }
}

bool Session::WritePose(Stream& s, const device::ProxySample& x, v1::CoupleRequest* req) {
  auto* p = req->mutable_pose();
  p->set_sequence(x.sequence);
  wire::ToProto(x.X_WA, p->mutable_pose());
  p->set_client_time_ns(x.time_ns);
  if (local_) p->set_round_trip_us(rtt_estimate_us_.load(std::memory_order_relaxed));
  if (!s.rw->Write(*req)) return false;
  std::lock_guard lock(stats_mu_);
  ++counters_.poses_sent;
  return true;
}

void Session::StartTelemetry(std::int64_t now) {
  // What the ring holds was taken while no stream was open.
  device::SampleRing& ring = loop_->samples();
  std::uint64_t discarded = 0;
  device::TickSample x;
  while (ring.Pop(&x)) ++discarded;
  if (tel_.carry) {
    ++discarded;
    tel_.carry.reset();
  }
  tel_.sequence = 0;
  tel_.ring_lost_base = ring.lost();
  tel_.link_lost = 0;
  tel_.last_ns = now;
  tel_.next_ns = now + static_cast<std::int64_t>(options_.telemetry_interval_s * 1e9);
  tel_.last_ticks = loop_->live().ticks.load(std::memory_order_relaxed);
  tel_.last_local_answers = 0;
  if (local_) {
    const device::LocalModelStats ls = local_->stats();
    tel_.last_local_answers = ls.local_answers + ls.server_deeper;
  }
  std::lock_guard lock(stats_mu_);
  tel_.last_updates = counters_.updates;
  counters_.telemetry_samples_discarded += discarded;
  counters_.telemetry_samples_lost = 0;
}

bool Session::WriteTelemetry(Stream& s, const v1::CoupleRequest& req) {
  if (!s.rw->Write(req)) return false;
  std::lock_guard lock(stats_mu_);
  ++counters_.telemetry_sent;
  counters_.telemetry_samples_sent +=
      static_cast<std::uint64_t>(req.telemetry().commanded().force_size());
  return true;
}

bool Session::TelemetryStep(Stream& s, std::int64_t now, const device::ProxySample* latest,
                            bool flush) {
  device::SampleRing& ring = loop_->samples();
  do {
    // With an emulated link, what is in flight goes first (in order).
    if (flush && link_) {
      while (link_->telemetry.Receive(std::numeric_limits<std::int64_t>::max(), &tel_.due)) {
        if (!WriteTelemetry(s, tel_.due)) return false;
      }
    }
    v1::CoupleRequest& req = tel_.req;
    req.Clear();
    v1::DeviceTelemetry* t = req.mutable_telemetry();
    t->set_sequence(++tel_.sequence);
    t->set_client_time_ns(now);
    // Every sample since the previous message, at most kMaxTelemetrySamples
    // and offsets that fit 32 bits of microseconds (the rest go next).
    v1::WrenchSamples* c = t->mutable_commanded();
    std::uint64_t by_source[4] = {0, 0, 0, 0};
    const auto take = [&](const device::TickSample& x) {
      if (c->force_size() == 0) c->set_start_time_ns(x.time_ns);
      const std::int64_t off = (x.time_ns - c->start_time_ns()) / 1000;
      if (c->force_size() >= wire::kMaxTelemetrySamples || off < 0 ||
          off > std::numeric_limits<std::uint32_t>::max()) {
        return false;
      }
      c->add_offset_us(static_cast<std::uint32_t>(off));
      c->add_force(x.force);
      c->add_torque(x.torque);
      ++by_source[static_cast<int>(x.source) & 3];
      tel_.latest = x;
      tel_.have_latest = true;
      return true;
    };
    if (tel_.carry && take(*tel_.carry)) tel_.carry.reset();
    device::TickSample x;
    while (!tel_.carry && c->force_size() < wire::kMaxTelemetrySamples && ring.Pop(&x)) {
      if (!take(x)) tel_.carry = x;
    }
    const std::uint64_t lost = ring.lost() - tel_.ring_lost_base + tel_.link_lost;
    c->set_samples_lost(lost);
    t->set_ticks_server(by_source[static_cast<int>(device::TickSource::kServer)]);
    t->set_ticks_local(by_source[static_cast<int>(device::TickSource::kLocal)]);
    t->set_ticks_faded(by_source[static_cast<int>(device::TickSource::kFaded)]);
    // Rates since the previous message.
    const double dt = 1e-9 * static_cast<double>(now - tel_.last_ns);
    const auto rate = [&](std::uint64_t n) {
      return dt > 0 ? std::min(static_cast<double>(n) / dt, wire::kTelemetryRateHz.hi) : 0.0;
    };
    const std::uint64_t ticks = loop_->live().ticks.load(std::memory_order_relaxed);
    t->set_servo_rate_hz(rate(ticks - tel_.last_ticks));
    tel_.last_ticks = ticks;
    if (local_) {
      const device::LocalModelStats ls = local_->stats();
      const std::uint64_t answers = ls.local_answers + ls.server_deeper;
      t->set_local_rate_hz(rate(answers - tel_.last_local_answers));
      tel_.last_local_answers = answers;
    }
    const auto ms = [](double v) { return std::clamp(v, 0.0, wire::kTelemetryMs.hi); };
    {
      std::lock_guard lock(stats_mu_);
      t->set_update_rate_hz(rate(counters_.updates - tel_.last_updates));
      tel_.last_updates = counters_.updates;
      t->set_round_trip_ms(ms(1e-3 * last_rtt_us_));
      counters_.telemetry_samples_lost = lost;
    }
    tel_.last_ns = now;
    if (options_.link) {
      t->set_emulated_delay_ms(options_.link->delay_ms);
      t->set_emulated_jitter_ms(options_.link->jitter_ms);
      t->set_emulated_loss(options_.link->loss);
    }
    if (tel_.have_latest) {
      const device::TickSample& l = tel_.latest;
      t->set_ir_age_ms(l.ir_age_ms >= 0 ? ms(l.ir_age_ms) : 0.0);
      t->set_fail_safe(static_cast<v1::FailSafeState>(l.fail_safe));
      t->set_source(static_cast<v1::ContactSource>(l.source));
    }
    if (latest != nullptr && latest->sequence > 0) {
      wire::ToProto(latest->X_WH, t->mutable_handle_pose());
      wire::ToProto(latest->X_WA, t->mutable_proxy_pose());
    }
    if (link_ && !flush) {
      const auto n = static_cast<std::uint64_t>(c->force_size());
      if (!link_->telemetry.Send(req, now)) tel_.link_lost += n;  // next message reports it
    } else if (!WriteTelemetry(s, req)) {
      return false;
    }
  } while (flush && (tel_.carry || ring.size() > 0));
  return true;
}

void Session::Serve(Stream& s, std::stop_token st) {
  // A new stream is a new server session: its patches start from nothing.
  if (local_) local_->Reset();
  connected_ = true;
  std::thread reader([this, &s] { ReadLoop(&s); });
  std::atomic<bool> deliver_done{false};
  std::thread deliverer;
  if (link_) deliverer = std::thread([this, &deliver_done] { DeliverLoop(deliver_done); });
  device::ProxyMailbox& in = loop_->proxy_mailbox();
  v1::CoupleRequest req;
  const auto poll =
      std::chrono::nanoseconds(static_cast<std::int64_t>(options_.poll_interval_s * 1e9));
  device::ProxySample due;
  // The loop publishes one sample a period: an idle thread sleeps until one
  // poll interval before the next is due (or the next telemetry batch), then
  // polls, instead of waking every poll interval in between (most of this
  // thread's CPU). The interval early is for a late tick: its sample's time
  // is late, and the next tick keeps the loop's schedule.
  const std::int64_t poll_ns = poll.count();
  const std::int64_t period_ns =
      std::max(poll_ns, static_cast<std::int64_t>(loop_->config().period_s * 1e9));
  std::int64_t next_sample_ns = 0;
  const bool telemetry = options_.telemetry;
  const auto telemetry_period =
      static_cast<std::int64_t>(std::max(1e-3, options_.telemetry_interval_s) * 1e9);
  if (telemetry) StartTelemetry(clock_->NowNs());
  while (!st.stop_requested() && !s.reader_done.load()) {
    bool idle = true;
    if (telemetry && flush_requested_.load() && !flush_done_.load()) {
      // Stop(): the last samples go before the stream is ended.
      const bool ok = TelemetryStep(s, clock_->NowNs(), &in.front(), true);
      flush_done_ = true;
      if (!ok) break;
    }
    if (telemetry && !flush_done_.load()) {
      const std::int64_t now = clock_->NowNs();
      if (now >= tel_.next_ns) {
        idle = false;
        if (!TelemetryStep(s, now, &in.front(), false)) break;
        tel_.next_ns = std::max(tel_.next_ns + telemetry_period, now);
      }
      if (link_) {
        bool broken = false;
        while (link_->telemetry.Receive(clock_->NowNs(), &tel_.due)) {
          idle = false;
          if (!WriteTelemetry(s, tel_.due)) {
            broken = true;
            break;
          }
        }
        if (broken) break;
      }
    }
    if (in.Fetch()) {
      idle = false;
      const device::ProxySample& x = in.front();
      if (local_) local_->OfferSample(x);
      const std::int64_t now = clock_->NowNs();
      next_sample_ns = x.time_ns + period_ns;
      const std::size_t slot = x.sequence % kRing;
      sent_ns_[slot].store(now, std::memory_order_relaxed);
      sent_seq_[slot].store(x.sequence, std::memory_order_release);
      if (link_) {
        link_->poses.Send(x, now);
      } else if (!WritePose(s, x, &req)) {
        break;
      }
    }
    if (link_) {
      bool broken = false;
      while (link_->poses.Receive(clock_->NowNs(), &due)) {
        idle = false;
        if (!WritePose(s, due, &req)) {
          broken = true;
          break;
        }
      }
      if (broken) break;
    }
    if (idle) {
      std::int64_t wait_ns = poll_ns;
      if (!link_) {  // the emulated link's deliveries are due at any time
        std::int64_t until = next_sample_ns;
        if (telemetry && !flush_done_.load()) until = std::min(until, tel_.next_ns);
        wait_ns = std::clamp(until - poll_ns - clock_->NowNs(), poll_ns, period_ns);
      }
      std::this_thread::sleep_for(std::chrono::nanoseconds(wait_ns));
    }
  }
  connected_ = false;
  // The scene may change unseen while the stream is down.
  if (local_) local_->Reset();
  // Nothing this stream brought is rendered any more: the fade starts now.
  if (!st.stop_requested()) loop_->RequestLinkLost();
  if (st.stop_requested()) {
    s.rw->WritesDone();  // the server then ends the stream with OK
    // Bounded: cancel if the server does not finish promptly.
    const auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(500);
    while (!s.reader_done.load() && std::chrono::steady_clock::now() < end) {
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
  }
  s.ctx.TryCancel();
  reader.join();
  if (deliverer.joinable()) {
    deliver_done = true;
    link_->updates.Wake();
    deliverer.join();
    // What was still in flight belonged to this stream.
    link_->poses.Clear();
    link_->updates.Clear();
    link_->telemetry.Clear();
  }
  const grpc::Status status = s.rw->Finish();
  {
    std::lock_guard lock(ctx_mu_);
    live_ctx_ = nullptr;
  }
  if (!st.stop_requested()) {
    std::lock_guard lock(stats_mu_);
    ++counters_.disconnects;
    counters_.last_error = status.ok() ? std::string("stream ended")
                                       : std::string(wire::StatusCodeName(status.error_code())) +
                                             ": " + status.error_message();
    spdlog::warn("session: disconnected ({}); reconnecting", counters_.last_error);
  }
}

void Session::Run(std::stop_token st) {
  // Stop() cancels whatever call blocks this thread.
  std::stop_callback on_stop(st, [this] {
    std::lock_guard lock(ctx_mu_);
    if (live_ctx_ != nullptr) live_ctx_->TryCancel();
  });
  std::unique_ptr<Stream> s = std::move(first_);
  double backoff = options_.backoff_initial_s;
  while (!st.stop_requested()) {
    if (s) {
      Serve(*s, st);
      s.reset();
      backoff = options_.backoff_initial_s;
      continue;
    }
    std::string error;
    grpc::StatusCode code;
    s = Open(false, &error, &code);
    if (s) {
      loop_->RequestResetContact();
      std::lock_guard lock(stats_mu_);
      ++counters_.connects;
      spdlog::info("session: reconnected to {} (session {})", options_.server,
                   counters_.session_id);
      continue;
    }
    {
      std::lock_guard lock(stats_mu_);
      ++counters_.failed_attempts;
      counters_.last_error = error;
    }
    if (Fatal(code)) {
      spdlog::error("session: {}; giving up", error);
      return;
    }
    // Sleep the backoff in small steps so Stop() is prompt.
    const auto end = std::chrono::steady_clock::now() +
                     std::chrono::microseconds(static_cast<std::int64_t>(backoff * 1e6));
    while (!st.stop_requested() && std::chrono::steady_clock::now() < end) {
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    backoff = std::min(options_.backoff_max_s, 2 * backoff);
  }
}

SessionStats Session::stats() const {
  std::lock_guard lock(stats_mu_);
  SessionStats s = counters_;
  s.rtt_samples = rtt_us_.count();
  s.rtt_p50_us = rtt_us_.Quantile(0.5);
  s.rtt_p99_us = rtt_us_.Quantile(0.99);
  s.rtt_max_us = rtt_us_.max();
  s.rtt_mean_us = rtt_us_.mean();
  s.server_compute_p50_us = compute_us_.Quantile(0.5);
  s.server_compute_p99_us = compute_us_.Quantile(0.99);
  if (local_) s.local = local_->stats();
  if (link_) {
    s.link.active = true;
    s.link.poses = link_->poses.counters();
    s.link.updates = link_->updates.counters();
    s.link.telemetry = link_->telemetry.counters();
  }
  return s;
}

device::EffectSet EffectsFromSceneConfig(const v1::SceneConfig& c) {
  if (!c.declared()) return device::EffectSet::ContactAndTorque();
  device::EffectSet s;
  for (int e : c.effects()) {
    switch (e) {
      case v1::EFFECT_CONTACT:
        s = s.With(device::Effect::kContact);
        break;
      case v1::EFFECT_DAMPING:
        s = s.With(device::Effect::kDamping);
        break;
      case v1::EFFECT_FRICTION:
        s = s.With(device::Effect::kFriction);
        break;
      case v1::EFFECT_WEIGHT:
        s = s.With(device::Effect::kWeight);
        break;
      case v1::EFFECT_TEXTURE:
        s = s.With(device::Effect::kTexture);
        break;
      case v1::EFFECT_TORQUE:
        s = s.With(device::Effect::kTorque);
        break;
      default:
        break;  // unknown (newer server): not rendered
    }
  }
  return s;
}

device::EffectParams EffectParamsFromSceneConfig(const v1::SceneConfig& c) {
  device::EffectParams p;
  if (c.has_gravity()) p.gravity = Vec3(c.gravity().x(), c.gravity().y(), c.gravity().z());
  if (c.probe_mass() > 0) p.probe_mass = c.probe_mass();
  if (c.texture_amplitude() > 0) p.texture_amplitude = c.texture_amplitude();
  if (c.texture_frequency() > 0) p.texture_frequency = c.texture_frequency();
  return p;
}

}  // namespace hapticpd::client
