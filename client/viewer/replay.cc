#include "client/viewer/replay.h"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <optional>

#include "client/viewer/http_server.h"
#include "hapticpd/v1/scene.grpc.pb.h"
#include "pd/geometry_model.h"
#include "proto/wire/convert.h"
#include "proto/wire/routing.h"
#include "proto/wire/scene_file.h"

namespace hapticpd::viewer {
namespace {

using wire::ToProto;

[[noreturn]] void Fail(const std::filesystem::path& file, const std::string& what) {
  throw ViewerError(fmt::format("replay {}: {}", file.string(), what));
}

/// A mesh named like `device --probe` takes it (a file, or shape:SPEC), or a
/// scene-file body's shape or file. `base` resolves a relative file that is
/// not found from the working directory (the recording's folder).
pd::Mesh LoadNamedMesh(const std::filesystem::path& file, const std::string& what,
                       const std::string& shape, std::string path,
                       const std::filesystem::path& base) {
  if (!shape.empty()) {
    std::optional<pd::Mesh> mesh;
    if (const grpc::Status s =
            wire::MeshFromShape(shape, what, wire::kDefaultMaxShapeTriangles, &mesh);
        !s.ok()) {
      Fail(file, s.error_message());
    }
    return std::move(*mesh);
  }
  if (!std::filesystem::exists(path) && std::filesystem::path(path).is_relative() &&
      std::filesystem::exists(base / path)) {
    path = (base / path).string();
  }
  try {
    return pd::LoadMesh(path);
  } catch (const std::exception& e) {
    Fail(file, fmt::format("{} '{}' cannot be read: {}", what, path, e.what()));
  }
}

void AddBody(v1::Scene* scene, const v1::BodySpec& spec, pd::Mesh mesh) {
  v1::Body* b = scene->add_bodies();
  b->set_body_id(spec.body_id());
  *b->mutable_pose() = spec.pose();
  *b->mutable_velocity() = spec.velocity();
  *b->mutable_material() = spec.material();
  b->set_movable(spec.movable());
  b->set_label(spec.label());
  const pd::ModelPtr model = pd::MakeModel(std::move(mesh));
  ToProto(*model, b->mutable_mesh_info());
  ToProto(model->mesh(), b->mutable_mesh());
}

v1::Scene SceneFromFile(const std::filesystem::path& file, const std::string& scene_file) {
  wire::SceneFile sf;
  try {
    sf = wire::ParseSceneFile(scene_file);
  } catch (const std::exception& e) {
    Fail(file, fmt::format("--scene-file: {}", e.what()));
  }
  v1::Scene scene;
  scene.set_scene_id(sf.scene_id);
  scene.set_description(sf.description);
  scene.set_revision(1);
  *scene.mutable_config() = sf.config;
  for (const wire::SceneFileBody& b : sf.bodies) {
    AddBody(&scene, b.spec,
            LoadNamedMesh(file, fmt::format("body '{}'", b.spec.body_id()), b.shape, b.mesh_path,
                          std::filesystem::path(scene_file).parent_path()));
  }
  return scene;
}

v1::Scene SceneFromServer(const std::filesystem::path& file, const ReplaySources& src,
                          const std::string& scene_id, const std::string& server) {
  if (scene_id.empty() || server.empty()) {
    Fail(file, "the recording names no scene or server to fetch the scene from; pass --scene-file");
  }
  if (!src.make_channel) Fail(file, "no channel to the server");
  grpc::ClientContext ctx;
  if (!src.server_token.empty()) ctx.AddMetadata("authorization", "Bearer " + src.server_token);
  wire::AddSceneHeader(&ctx, scene_id);
  ctx.set_deadline(std::chrono::system_clock::now() +
                   std::chrono::milliseconds(static_cast<int>(1000 * src.timeout_s)));
  v1::GetSceneRequest req;
  req.set_scene_id(scene_id);
  req.set_include_meshes(true);
  v1::Scene scene;
  auto stub = v1::SceneService::NewStub(src.make_channel(server));
  if (const grpc::Status s = stub->GetScene(&ctx, req, &scene); !s.ok()) {
    Fail(file, fmt::format("the scene '{}' cannot be fetched from {} ({}); pass --scene-file "
                           "with the scene the session was recorded against",
                           scene_id, server, s.error_message()));
  }
  return scene;
}

v1::PdMode ModeFromName(const std::string& mode) {
  if (mode == "pdt") return v1::PD_MODE_PDT;
  if (mode == "pdg") return v1::PD_MODE_PDG;
  if (mode == "none") return v1::PD_MODE_NONE;
  return v1::PD_MODE_UNSPECIFIED;
}

v1::ContactSource SourceOf(std::uint8_t source) {
  switch (source) {
    case 1:
      return v1::CONTACT_SOURCE_SERVER;
    case 2:
      return v1::CONTACT_SOURCE_LOCAL;
    default:
      return v1::CONTACT_SOURCE_FADED;
  }
}

}  // namespace

ReplayInput LoadReplay(const std::filesystem::path& file, const ReplaySources& src) {
  ReplayInput in;
  in.file = file.string();
  try {
    in.recording = device::LoadRecording(file);
  } catch (const std::exception& e) {
    throw ViewerError(fmt::format("replay: {}", e.what()));
  }
  const device::Recording& rec = in.recording;
  if (rec.version < 2 || rec.ticks.size() != rec.samples.size()) {
    Fail(file,
         "a version 1 recording holds the handle only (no proxy, scene or contacts); "
         "record with `hapticpd device --record`");
  }
  if (rec.samples.empty()) Fail(file, "the recording has no ticks");
  try {
    in.X_WD = rec.Header("X_WD").empty() ? Pose{} : device::ParsePoseValue(rec.Header("X_WD"));
  } catch (const std::exception& e) {
    Fail(file, fmt::format("header X_WD: {}", e.what()));
  }

  const std::string scene_id = src.scene_id.empty() ? rec.Header("scene") : src.scene_id;
  const std::string server = src.server.empty() ? rec.Header("server") : src.server;
  in.scene = src.scene_file.empty() ? SceneFromServer(file, src, scene_id, server)
                                    : SceneFromFile(file, src.scene_file);
  if (!scene_id.empty()) in.scene.set_scene_id(scene_id);

  v1::SessionInfo& s = in.session;
  s.set_session_id(ReplayPlayer::kSessionId);
  s.set_client_name(fmt::format("replay of {}", file.filename().string()));
  s.set_mode(ModeFromName(rec.Header("mode")));
  const std::string probe = src.probe.empty() ? rec.Header("probe") : src.probe;
  if (probe.empty()) Fail(file, "the recording names no probe; pass --probe");
  if (probe.rfind("body:", 0) == 0) {
    const std::string id = probe.substr(5);
    const auto& bodies = in.scene.bodies();
    const auto it = std::find_if(bodies.begin(), bodies.end(),
                                 [&](const v1::Body& b) { return b.body_id() == id; });
    if (it == bodies.end()) {
      Fail(file, fmt::format("the probe is the body '{}', which the scene has not", id));
    }
    s.set_probe_body_id(id);
    *s.mutable_probe_mesh_info() = it->mesh_info();
  } else {
    const bool shape = probe.rfind("shape:", 0) == 0;
    pd::Mesh mesh = LoadNamedMesh(file, "the probe", shape ? probe.substr(6) : "",
                                  shape ? "" : probe, file.parent_path());
    const pd::ModelPtr model = pd::MakeModel(std::move(mesh));
    ToProto(*model, s.mutable_probe_mesh_info());
    ToProto(model->mesh(), s.mutable_probe_mesh());
  }
  return in;
}

ReplayPlayer::ReplayPlayer(ReplayInput input, bool loop) : in_(std::move(input)), loop_(loop) {
  const auto& samples = in_.recording.samples;
  if (!samples.empty()) {
    t_first_ = samples.front().t_s;
    duration_s_ = samples.back().t_s - t_first_;
  }
  finished_ = samples.empty();
}

std::int64_t ReplayPlayer::TimeNs(double t_rec_s) const {
  return static_cast<std::int64_t>(std::llround(1e9 * (epoch_s_ + t_rec_s - t_first_)));
}

v1::SceneEvent ReplayPlayer::Event() const {
  v1::SceneEvent ev;
  ev.set_revision(in_.scene.revision());
  ev.set_observers(1);
  return ev;
}

void ReplayPlayer::Begin(std::vector<v1::SceneEvent>* out) {
  v1::SceneEvent snap = Event();
  *snap.mutable_snapshot() = in_.scene;
  out->push_back(std::move(snap));
  v1::SceneEvent sessions = Event();
  *sessions.mutable_sessions()->add_added() = in_.session;
  out->push_back(std::move(sessions));
}

void ReplayPlayer::AddPoseFrame(std::size_t i, std::vector<v1::SceneEvent>* out) const {
  const device::TrajectorySample& sample = in_.recording.samples[i];
  const device::RecordedTick& tick = in_.recording.ticks[i];
  v1::SceneEvent ev = Event();
  ev.set_server_time_ns(TimeNs(sample.t_s));
  v1::ProbeState* p = ev.mutable_poses()->add_probes();
  p->set_session_id(kSessionId);
  ToProto(tick.X_WA, p->mutable_pose());
  // The wrench commanded on the handle pushes it out of contact as the
  // penalty wrench pushes the probe: shown in W.
  ToProto(Vec3(in_.X_WD.R * sample.F_cmd_D.force), p->mutable_force());
  ToProto(Vec3(in_.X_WD.R * sample.F_cmd_D.torque), p->mutable_torque());
  double depth = 0;
  for (int r = 0; r < tick.num_rows; ++r) {
    const device::RecordedRow& row = tick.rows[static_cast<std::size_t>(r)];
    v1::ContactRow* cr = p->add_rows();
    ToProto(row.p_W, cr->mutable_point());
    ToProto(row.n_W, cr->mutable_normal());
    cr->set_depth(row.depth);
    depth = std::max(depth, row.depth);
  }
  p->set_depth(depth);
  p->set_sequence(i + 1);
  p->set_status(tick.num_rows > 0 ? v1::CONTACT_STATUS_PENETRATING : v1::CONTACT_STATUS_SEPARATED);
  p->set_mode(in_.session.mode());
  out->push_back(std::move(ev));
}

void ReplayPlayer::FlushTelemetry(std::vector<v1::SceneEvent>* out) {
  if (batch_begin_ >= next_) return;
  const auto& samples = in_.recording.samples;
  const auto& ticks = in_.recording.ticks;
  v1::SceneEvent ev = Event();
  ev.set_server_time_ns(TimeNs(samples[next_ - 1].t_s));
  v1::SessionTelemetry* t = ev.mutable_telemetry()->add_sessions();
  t->set_session_id(kSessionId);
  t->set_scene_revision(in_.scene.revision());
  v1::DeviceTelemetry* d = t->mutable_device();
  d->set_sequence(++telemetry_seq_);
  d->set_client_time_ns(TimeNs(samples[next_ - 1].t_s));
  v1::WrenchSamples* w = d->mutable_commanded();
  const std::int64_t t0 = TimeNs(samples[batch_begin_].t_s);
  w->set_start_time_ns(t0);
  std::uint64_t by_source[4] = {0, 0, 0, 0};
  for (std::size_t i = batch_begin_; i < next_; ++i) {
    w->add_offset_us(static_cast<std::uint32_t>((TimeNs(samples[i].t_s) - t0) / 1000));
    w->add_force(static_cast<float>(samples[i].F_cmd_D.force.norm()));
    w->add_torque(static_cast<float>(samples[i].F_cmd_D.torque.norm()));
    ++by_source[std::min<std::uint8_t>(ticks[i].source, 3)];
  }
  d->set_ticks_server(by_source[1]);
  d->set_ticks_local(by_source[2]);
  d->set_ticks_faded(by_source[0] + by_source[3]);
  d->set_source(SourceOf(ticks[next_ - 1].source));
  const double span = samples[next_ - 1].t_s - samples[batch_begin_].t_s;
  const std::size_t n = next_ - batch_begin_;
  if (n > 1 && span > 0) d->set_servo_rate_hz(static_cast<double>(n - 1) / span);
  ToProto(in_.X_WD * samples[next_ - 1].state.X_DH, d->mutable_handle_pose());
  ToProto(ticks[next_ - 1].X_WA, d->mutable_proxy_pose());
  batch_begin_ = next_;
  out->push_back(std::move(ev));
}

void ReplayPlayer::AdvanceTo(double play_s, std::vector<v1::SceneEvent>* out) {
  if (finished_) return;
  const auto& samples = in_.recording.samples;
  if (next_ == samples.size() && loop_ && play_s >= epoch_s_ + duration_s_ + kLoopPauseS) {
    epoch_s_ += duration_s_ + kLoopPauseS;  // the next pass, later on the same clock
    next_ = batch_begin_ = 0;
    ++loops_;
  }
  const double t_rec = t_first_ + (play_s - epoch_s_);
  const std::size_t before = next_;
  while (next_ < samples.size() && samples[next_].t_s <= t_rec) ++next_;
  const bool at_end = next_ == samples.size();
  if (next_ > batch_begin_ && (at_end || play_s - last_batch_play_s_ >= kTelemetryPeriodS)) {
    FlushTelemetry(out);
    last_batch_play_s_ = play_s;
  }
  if (next_ > before) AddPoseFrame(next_ - 1, out);
  if (at_end && !loop_) finished_ = true;
}

}  // namespace hapticpd::viewer
