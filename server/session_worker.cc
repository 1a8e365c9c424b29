#include "server/session_worker.h"

#include <algorithm>
#include <cmath>
#include <optional>

#include "proto/wire/ranges.h"
#include "server/convert.h"
#include "server/core.h"
#include "server/scene_file.h"

namespace hapticpd::server::internal {
namespace {

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

v1::ContactStatus StatusOf(pd::ContactOutcome o) {
  switch (o) {
    case pd::ContactOutcome::kSeparated:
      return v1::CONTACT_STATUS_SEPARATED;
    case pd::ContactOutcome::kPenetrating:
      return v1::CONTACT_STATUS_PENETRATING;
    case pd::ContactOutcome::kCapReached:
      return v1::CONTACT_STATUS_CAP_REACHED;
    case pd::ContactOutcome::kFailed:
      return v1::CONTACT_STATUS_FAILED;
  }
  return v1::CONTACT_STATUS_FAILED;
}

}  // namespace

SessionWorker::SessionWorker(const Limits& limits, std::string session_id)
    : limits_(limits), session_id_(std::move(session_id)) {}

grpc::Status SessionWorker::Start(const v1::Hello& h, const ScenePtr& scene, v1::Welcome* welcome) {
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
  if (auto s = wire::CheckRange(h.max_rate_hz(), wire::kMaxRateHz, "hello.max_rate_hz"); !s.ok()) {
    return s;
  }
  if (h.max_rate_hz() > 0) {
    min_period_ = std::chrono::nanoseconds(static_cast<std::int64_t>(1e9 / h.max_rate_hz()));
  }
  const std::size_t max_tris = limits_.max_mesh_triangles;
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
  if (mesh) probe_ = pd::MakeModel(std::move(*mesh));  // on the session's worker thread
  if (auto s = StartPatches(h); !s.ok()) return s;
  scene_ = scene;
  welcome->set_protocol_version(kProtocolVersion);
  welcome->set_session_id(session_id_);
  welcome->set_mode(static_cast<v1::PdMode>(mode_));
  ToProto(probe_->mass().X_MB, welcome->mutable_probe_body_frame());
  ToProto(*probe_, welcome->mutable_probe_mesh_info());
  welcome->set_probe_mass_per_density(probe_->mass().volume);
  welcome->set_scene_revision(scene_->snapshot()->revision);
  *welcome->mutable_scene_config() = config;
  return grpc::Status::OK;
}

double SanitizeRoundTripUs(double us) {
  if (!std::isfinite(us) || us < 0) return 0;
  return std::min(us, kMaxRoundTripUs);
}

grpc::Status SessionWorker::StartPatches(const v1::Hello& h) {
  if (!h.has_patches()) return grpc::Status::OK;
  const v1::PatchRequest& r = h.patches();
  static constexpr wire::Range kMinMargin{0, kMaxPatchMinMargin, "m"};
  if (auto s = wire::CheckRange(r.min_margin(), kMinMargin, "hello.patches.min_margin"); !s.ok()) {
    return s;
  }
  if (!r.enabled()) return grpc::Status::OK;
  const std::size_t server_limit = std::max<std::size_t>(1, limits_.max_patch_triangles);
  const std::size_t limit = r.max_triangles_per_body() == 0
                                ? server_limit
                                : std::min<std::size_t>(r.max_triangles_per_body(), server_limit);
  patches_ = std::make_unique<PatchBuilder>(probe_, limit, r.min_margin());
  return grpc::Status::OK;
}

/// Rebuilds the session's view of the scene when the snapshot changed: the
/// bodies (minus the probe's own), effective materials, and the per-body
/// coherence state carried over by body uid.
void SessionWorker::SyncBodies(const SnapshotPtr& snap) {
  if (snap == synced_) return;
  bodies_.clear();
  states_.clear();
  any_moving_ = false;
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
    states_.push_back(&b);
    any_moving_ = any_moving_ || Moving(b);
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

void SessionWorker::MoveBodies(std::int64_t t_ns) {
  if (!any_moving_) return;
  for (std::size_t i = 0; i < bodies_.size(); ++i) {
    if (Moving(*states_[i])) bodies_[i].X_WB = PoseAt(*states_[i], t_ns);
  }
}

bool SessionWorker::Patch(const MailPose& p, v1::GeometryPatch* out) {
  if (!patches_) return false;
  SyncBodies(scene_->snapshot());
  patch_bodies_.clear();
  for (std::size_t i = 0; i < bodies_.size(); ++i) {
    patch_bodies_.push_back({states_[i], &bodies_[i].material});
  }
  const PatchProbe probe{p.X_WA, p.rx_ns, p.round_trip_us * 1e-6};
  return patches_->Build(probe, synced_->revision, patch_bodies_, out);
}

AnswerInfo SessionWorker::Answer(const MailPose& p, std::uint32_t superseded,
                                 v1::ContactUpdate* u) {
  AnswerInfo info;
  info.torque = torque_;
  u->Clear();
  u->set_sequence(p.sequence);
  ToProto(p.X_WA, u->mutable_pose_ref());
  u->set_client_time_ns(p.client_time_ns);
  u->set_server_receive_time_ns(p.rx_ns);
  u->set_poses_superseded(superseded);
  const SnapshotPtr snap = scene_->snapshot();
  u->set_scene_revision(snap->revision);
  if (patches_) patches_->Observe(p.X_WA, p.client_time_ns, p.rx_ns);
  const pd::ContactModelOptions options;
  if (mode_ == v1::PD_MODE_NONE || !needs_pd_) {
    pd::EmptyContactModel(*probe_, p.X_WA, options, &model_);
    u->set_status(v1::CONTACT_STATUS_NONE);
    ToProto(p.X_WA, u->mutable_target_pose());
    u->set_validity_radius(model_.validity_radius);
    u->set_validity_angle(model_.validity_angle);
    return info;
  }
  SyncBodies(snap);
  MoveBodies(p.rx_ns);
  pd::ComputeScenePd(
      mode_ == v1::PD_MODE_PDG ? pd::PdMode::kGeneralized : pd::PdMode::kTranslational, *probe_,
      p.X_WA, bodies_, request_, &pd_data_, &result_,
      torque_ ? pd::WrenchTerms::kForceAndTorque : pd::WrenchTerms::kForceOnly);
  info.pd_ran = true;
  info.time_us = result_.time_us;
  pd::BuildContactModel(*probe_, p.X_WA, bodies_, result_, options, &model_);
  // Encode: rows reference their body by an index into body_ids (only the
  // bodies in contact are listed).
  int last_body = -1;
  std::uint32_t body_index = 0;
  for (const pd::ContactRow& r : model_.rows) {
    if (r.body != last_body) {
      body_index = static_cast<std::uint32_t>(u->body_ids_size());
      u->add_body_ids(body_ids_[static_cast<std::size_t>(r.body)]);
      last_body = r.body;
    }
    auto* row = u->add_rows();
    ToProto(r.p_W, row->mutable_point());
    ToProto(r.n_W, row->mutable_normal());
    row->set_depth(r.depth);
    // Without torque the rows are pure forces (zero moment arm).
    if (torque_) ToProto((r.p_W - model_.c_W).cross(r.n_W), row->mutable_moment());
    row->set_stiffness(r.material.stiffness);
    row->set_body_index(body_index);
    row->set_static_friction(r.material.static_friction);
    row->set_dynamic_friction(r.material.dynamic_friction);
    row->set_damping(r.material.damping);
  }
  ToProto(model_.wrench.force, u->mutable_force());
  if (torque_) ToProto(model_.wrench.torque, u->mutable_torque());
  ToProto(model_.X_WA_target, u->mutable_target_pose());
  if (model_.deepest >= 0) {
    u->set_depth(model_.depth);
    ToProto(model_.pd_translation_W, u->mutable_pd_translation());
    u->set_target_stiffness(model_.target_stiffness);
    if (torque_) u->set_target_rotational_stiffness(model_.target_rotational_stiffness);
    if (model_.generalized) {
      u->set_sigma(model_.sigma);
      u->set_rotation_angle(model_.rotation_angle);
      ToProto(model_.rotation_axis_W, u->mutable_rotation_axis());
    }
  }
  u->set_status(StatusOf(model_.outcome));
  u->set_validity_radius(model_.validity_radius);
  u->set_validity_angle(model_.validity_angle);
  u->set_compute_time_us(result_.time_us);
  info.withheld = Withhold(u);
  if (info.withheld == nullptr) {
    info.force_W = model_.wrench.force;
    info.depth = u->depth();
  }
  return info;
}

const char* SessionWorker::Withhold(v1::ContactUpdate* u) const {
  const char* why = UpdateProblem(*u, limits_.max_update_force, limits_.max_update_torque);
  if (why == nullptr) return nullptr;
  // Keep what identifies the answer (sequence, poses, times); the rest is
  // the answer of free space at pose_ref.
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
  pd::ContactModel empty;
  Pose X_WA;
  (void)FromProto(u->pose_ref(), "pose_ref", &X_WA);
  pd::EmptyContactModel(*probe_, X_WA, pd::ContactModelOptions{}, &empty);
  u->set_validity_radius(empty.validity_radius);
  u->set_validity_angle(empty.validity_angle);
  if (!std::isfinite(u->compute_time_us())) u->set_compute_time_us(0);
  u->set_status(v1::CONTACT_STATUS_WITHHELD);
  return why;
}

}  // namespace hapticpd::server::internal
