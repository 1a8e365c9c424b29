#include "device/local_model.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <unordered_set>

#include <fmt/format.h>

namespace hapticpd::device {
namespace {

bool Finite(const Vec3& v) { return v.allFinite(); }

/// Coordinates and radii beyond this are not a scene (the wire's ranges
/// stop at 1e4 m); past it the loop's products could overflow.
constexpr double kMaxCoordinate = 1e6;

bool Sane(const Vec3& v) { return Finite(v) && v.cwiseAbs().maxCoeff() <= kMaxCoordinate; }

/// The deepest row of an IR at its reference pose (a PDg target: the
/// distance to it); 0 without contact.
double MaxRowDepth(const IntermediateRep& ir) {
  double d = 0;
  for (int i = 0; i < ir.num_rows; ++i) {
    d = std::max(d, ir.rows[static_cast<std::size_t>(i)].depth);
  }
  if (ir.use_target) d = std::max(d, (ir.X_WP_target.t - ir.X_WP_ref.t).norm());
  return d;
}

}  // namespace

Pose PatchBodyPoseAt(const PatchBodyDelta& b, std::int64_t t_ns) {
  if (b.v_W.isZero(0) && b.w_W.isZero(0)) return b.X_WB;
  return MovedPose(b.X_WB, b.v_W, b.w_W, 1e-9 * static_cast<double>(t_ns - b.pose_time_ns));
}

// --- PatchStore

std::string PatchStore::Check(const PatchDelta& d) const {
  if (have_patch_ && d.sequence <= sequence_) {
    return fmt::format("patch {} is not newer than patch {}", d.sequence, sequence_);
  }
  if (!Sane(d.center_W) || !std::isfinite(d.radius) || d.radius < 0 || d.radius > kMaxCoordinate) {
    return fmt::format("patch {}: region not finite or out of range", d.sequence);
  }
  std::unordered_set<std::string> seen;
  for (const PatchBodyDelta& b : d.bodies) {
    const std::string where = fmt::format("patch {} body '{}'", d.sequence, b.id);
    if (b.id.empty() || !seen.insert(b.id).second) return where + ": empty or repeated body id";
    if (!Sane(b.X_WB.t) || !b.X_WB.R.allFinite() || !Sane(b.v_W) || !Sane(b.w_W) ||
        !Sane(b.cover_center_B) || !std::isfinite(b.cover_radius) || b.cover_radius < 0 ||
        b.cover_radius > kMaxCoordinate) {
      return where + ": pose, velocity or cover not finite or out of range";
    }
    const pd::Material& m = b.material;
    for (double x :
         {m.stiffness, m.rotational_stiffness, m.damping, m.static_friction, m.dynamic_friction}) {
      if (!std::isfinite(x) || x < 0 || x > 1e9) return where + ": material out of range";
    }
    if (b.vertices.size() != b.vertex_indices.size() ||
        b.triangles.size() != b.triangle_indices.size()) {
      return where + ": index and value arrays of different lengths";
    }
    // What the body holds before this patch (nothing under a new key).
    const Body* held = nullptr;
    for (const auto& [id, body] : bodies_) {
      if (id == b.id && body.meta.key == b.key) held = &body;
    }
    std::unordered_set<std::uint32_t> new_verts;
    for (std::size_t i = 0; i < b.vertex_indices.size(); ++i) {
      if (b.vertex_indices[i] >= b.vertex_count) {
        return fmt::format("{}: vertex index {} out of range (the body has {})", where,
                           b.vertex_indices[i], b.vertex_count);
      }
      if (!Sane(b.vertices[i])) {
        return fmt::format("{}: vertex {} not finite or out of range", where, b.vertex_indices[i]);
      }
      new_verts.insert(b.vertex_indices[i]);
    }
    std::size_t count = held != nullptr ? held->tris.size() : 0;
    for (std::uint32_t t : b.dropped_triangles) {
      if (t >= b.triangle_count) {
        return fmt::format("{}: dropped triangle {} out of range (the body has {})", where, t,
                           b.triangle_count);
      }
      if (held != nullptr && held->tris.count(t) != 0 && count > 0) --count;
    }
    for (std::size_t i = 0; i < b.triangle_indices.size(); ++i) {
      if (b.triangle_indices[i] >= b.triangle_count) {
        return fmt::format("{}: triangle index {} out of range (the body has {})", where,
                           b.triangle_indices[i], b.triangle_count);
      }
      for (std::uint32_t v : b.triangles[i]) {
        if (v >= b.vertex_count) {
          return fmt::format("{}: triangle {} names vertex {} out of range (the body has {})",
                             where, b.triangle_indices[i], v, b.vertex_count);
        }
        if (new_verts.count(v) == 0 && (held == nullptr || held->verts.count(v) == 0)) {
          return fmt::format("{}: triangle {} names vertex {}, which is not held", where,
                             b.triangle_indices[i], v);
        }
      }
      if (held == nullptr || held->tris.count(b.triangle_indices[i]) == 0) ++count;
    }
    if (count > limits_.max_triangles_per_body) {
      return fmt::format("{}: {} triangles held, over the limit of {}", where, count,
                         limits_.max_triangles_per_body);
    }
  }
  if (bodies_.size() + d.bodies.size() > limits_.max_bodies + d.dropped_bodies.size() &&
      d.bodies.size() > limits_.max_bodies) {
    return fmt::format("patch {}: {} bodies, over the limit of {}", d.sequence, d.bodies.size(),
                       limits_.max_bodies);
  }
  return "";
}

std::string PatchStore::Apply(const PatchDelta& d) {
  if (std::string problem = Check(d); !problem.empty()) return problem;
  for (const std::string& id : d.dropped_bodies) {
    std::erase_if(bodies_, [&](const auto& e) { return e.first == id; });
  }
  for (const PatchBodyDelta& b : d.bodies) {
    auto it = std::find_if(bodies_.begin(), bodies_.end(),
                           [&](const auto& e) { return e.first == b.id; });
    if (it != bodies_.end() && it->second.meta.key != b.key) {
      bodies_.erase(it);
      it = bodies_.end();
    }
    if (it == bodies_.end()) {
      bodies_.emplace_back(b.id, Body{});
      it = std::prev(bodies_.end());
    }
    Body& body = it->second;
    // Metadata (no arrays).
    body.meta.id = b.id;
    body.meta.key = b.key;
    body.meta.triangle_count = b.triangle_count;
    body.meta.vertex_count = b.vertex_count;
    body.meta.X_WB = b.X_WB;
    body.meta.v_W = b.v_W;
    body.meta.w_W = b.w_W;
    body.meta.pose_time_ns = b.pose_time_ns;
    if (body.meta.material.stiffness != b.material.stiffness ||
        body.meta.material.damping != b.material.damping ||
        body.meta.material.static_friction != b.material.static_friction ||
        body.meta.material.dynamic_friction != b.material.dynamic_friction ||
        body.meta.material.rotational_stiffness != b.material.rotational_stiffness) {
      body.dirty = true;
    }
    body.meta.material = b.material;
    body.meta.cover_center_B = b.cover_center_B;
    body.meta.cover_radius = b.cover_radius;
    body.meta.truncated = b.truncated;
    for (std::uint32_t t : b.dropped_triangles) {
      auto ti = body.tris.find(t);
      if (ti == body.tris.end()) continue;
      for (std::uint32_t v : ti->second) {
        auto vi = body.verts.find(v);
        if (vi != body.verts.end() && --vi->second.refs == 0) body.verts.erase(vi);
      }
      body.tris.erase(ti);
      body.dirty = true;
    }
    for (std::size_t i = 0; i < b.vertex_indices.size(); ++i) {
      body.verts[b.vertex_indices[i]].p = b.vertices[i];
    }
    for (std::size_t i = 0; i < b.triangle_indices.size(); ++i) {
      if (!body.tris.emplace(b.triangle_indices[i], b.triangles[i]).second) continue;
      for (std::uint32_t v : b.triangles[i]) ++body.verts[v].refs;
      body.dirty = true;
    }
    // Vertices sent but used by no held triangle are not held.
    std::erase_if(body.verts, [](const auto& e) { return e.second.refs == 0; });
  }
  have_patch_ = true;
  sequence_ = d.sequence;
  scene_revision_ = d.scene_revision;
  center_W_ = d.center_W;
  radius_ = d.radius;
  return "";
}

void PatchStore::Clear() {
  bodies_.clear();
  have_patch_ = false;
  sequence_ = 0;
}

std::size_t PatchStore::triangles_held() const {
  std::size_t n = 0;
  for (const auto& e : bodies_) n += e.second.tris.size();
  return n;
}

std::shared_ptr<const PatchView> PatchStore::View() {
  if (!have_patch_) return nullptr;
  auto view = std::make_shared<PatchView>();
  view->center_W = center_W_;
  view->radius = radius_;
  static std::atomic<std::uint64_t> next_build{1};
  for (auto& [id, body] : bodies_) {
    if (body.dirty) {
      body.model.reset();
      body.dirty = false;
      if (!body.tris.empty()) {
        std::vector<Vec3> vertices;
        std::vector<pd::Triangle> triangles;
        std::unordered_map<std::uint32_t, hapticpd::Index> local;
        vertices.reserve(body.verts.size());
        triangles.reserve(body.tris.size());
        // Deterministic order (by stable index) so the same holding gives
        // the same mesh.
        std::vector<std::uint32_t> order;
        order.reserve(body.tris.size());
        for (const auto& t : body.tris) order.push_back(t.first);
        std::sort(order.begin(), order.end());
        for (std::uint32_t t : order) {
          pd::Triangle tri;
          const auto& src = body.tris.at(t);
          for (int k = 0; k < 3; ++k) {
            auto [it, added] = local.emplace(src[k], static_cast<hapticpd::Index>(vertices.size()));
            if (added) vertices.push_back(body.verts.at(src[k]).p);
            tri[k] = it->second;
          }
          triangles.push_back(tri);
        }
        try {
          body.model = pd::MakeModel(
              pd::Mesh::FromArrays(std::move(vertices), std::move(triangles), "patch:" + id));
        } catch (const std::exception&) {
          body.model.reset();  // e.g. only index-repeating triangles: nothing to touch
        }
      }
      body.build = next_build.fetch_add(1, std::memory_order_relaxed);
    }
    view->bodies.push_back(PatchView::Body{body.meta, body.model, body.build});
  }
  return view;
}

void PatchStore::Bodies(std::int64_t server_t_ns, std::vector<pd::SceneBody>* out,
                        std::vector<std::uint64_t>* keys) {
  out->clear();
  keys->clear();
  if (const auto view = View()) view->Bodies(server_t_ns, out, keys);
}

void PatchView::Bodies(std::int64_t server_t_ns, std::vector<pd::SceneBody>* out,
                       std::vector<std::uint64_t>* keys) const {
  out->clear();
  keys->clear();
  for (const Body& b : bodies) {
    if (!b.model) continue;
    out->push_back(pd::SceneBody{b.model, PatchBodyPoseAt(b.meta, server_t_ns), b.meta.material});
    keys->push_back(b.build);
  }
}

bool PatchView::Covers(std::span<const Vec3> points_W, std::int64_t server_t_ns) const {
  for (const Vec3& p : points_W) {
    if ((p - center_W).norm() > radius) return false;
  }
  for (const Body& body : bodies) {
    const Pose X_WB = PatchBodyPoseAt(body.meta, server_t_ns);
    for (const Vec3& p : points_W) {
      const Vec3 p_B = X_WB.R.transpose() * (p - X_WB.t);
      if ((p_B - body.meta.cover_center_B).norm() > body.meta.cover_radius) return false;
    }
  }
  return true;
}

bool PatchStore::Covers(std::span<const Vec3> points_W, std::int64_t server_t_ns) {
  const auto view = View();
  return view && view->Covers(points_W, server_t_ns);
}

// --- the IR of a contact model

void IrFromContactModel(const pd::ContactModel& m, const ProxySample& x, const Pose& X_AP,
                        bool torque, IntermediateRep* ir) {
  ir->sequence = x.sequence;
  ir->sample_time_ns = x.time_ns;
  ir->X_WP_ref = x.X_WP;
  ir->use_target = false;
  ir->num_rows = 0;
  ir->target_stiffness = 0;
  ir->target_rotational_stiffness = 0;
  ir->X_WP_target = x.X_WP;
  const Vec3 c = x.X_WP.t;
  for (const pd::ContactRow& r : m.rows) {
    if (r.depth <= 0 || r.material.stiffness <= 0) continue;
    const double n_norm = r.n_W.norm();
    if (n_norm < 1e-9) continue;
    const Vec3 n = r.n_W / n_norm;
    IrRow row{r.p_W, n, torque ? Vec3((r.p_W - c).cross(n)) : Vec3::Zero(), r.depth,
              r.material.stiffness};
    row.static_friction = r.material.static_friction;
    row.dynamic_friction = r.material.dynamic_friction;
    row.damping = r.material.damping;
    AddIrRow(row, ir);
  }
  if (m.generalized && m.deepest >= 0 && m.sigma > 0 && m.target_stiffness > 0 &&
      m.outcome != pd::ContactOutcome::kSeparated) {
    ir->use_target = true;
    ir->X_WP_target = m.X_WA_target * X_AP;
    ir->target_stiffness = m.target_stiffness;
    ir->target_rotational_stiffness = torque ? m.target_rotational_stiffness : 0;
  }
  ir->validity_radius = m.validity_radius;
  ir->validity_angle = m.validity_angle;
}

// --- LocalContactModel

LocalContactModel::LocalContactModel(pd::ModelPtr probe, const Pose& X_PA,
                                     const LocalModelOptions& options)
    : probe_(std::move(probe)),
      X_PA_(X_PA),
      X_AP_(X_PA.Inverse()),
      options_(options),
      store_(options.limits) {
  const pd::Aabb& box = probe_->mesh().bounds();
  for (int i = 0; i < 8; ++i) {
    corners_A_[static_cast<std::size_t>(i)] =
        Vec3(i & 1 ? box.hi.x() : box.lo.x(), i & 2 ? box.hi.y() : box.lo.y(),
             i & 4 ? box.hi.z() : box.lo.z());
  }
  thinnest_ = box.Size().minCoeff();
}

LocalContactModel::~LocalContactModel() { Stop(); }

void LocalContactModel::OfferPatch(PatchDelta delta, std::int64_t now_ns) {
  last_message_ns_.store(now_ns, std::memory_order_relaxed);
  {
    std::lock_guard lock(queue_mu_);
    offered_bytes_ += delta.wire_bytes;
    queue_.push_back(std::move(delta));
  }
  queue_cv_.notify_all();
}

void LocalContactModel::RejectPatch(const std::string& problem) {
  {
    std::lock_guard lock(queue_mu_);
    undecodable_ = problem.empty() ? std::string("undecodable patch") : problem;
  }
  queue_cv_.notify_all();
}

void LocalContactModel::OfferServerIr(const IntermediateRep& ir) {
  last_message_ns_.store(ir.receive_time_ns, std::memory_order_relaxed);
  server_.Write(ir);
  Wake();
}

void LocalContactModel::OfferSample(const ProxySample& sample) {
  samples_.Write(sample);
  Wake();
}

void LocalContactModel::Wake() {
  bool waiting = false;
  {
    std::lock_guard lock(wake_mu_);
    wake_ = true;
    waiting = waiting_;
  }
  if (waiting) wake_cv_.notify_one();
}

void LocalContactModel::Reset() {
  {
    std::lock_guard lock(queue_mu_);
    queue_.clear();
    undecodable_.clear();
    reset_.store(true, std::memory_order_release);
    reset_worker_.store(true, std::memory_order_release);
  }
  queue_cv_.notify_all();
}

bool LocalContactModel::Covered(const Pose& X_WP, std::int64_t server_t) {
  if (!view_now_) return false;
  const Pose X_WA = X_WP * X_PA_;
  for (std::size_t i = 0; i < 8; ++i) corners_W_[i] = X_WA * corners_A_[i];
  return view_now_->Covers(corners_W_, server_t);
}

bool LocalContactModel::Seed(const Pose& X_WB, pd::PdQueryData* data) const {
  // The server's deepest row: its answer moved the probe about depth x
  // normal from the pose it answered. A contact there, in the body's frame,
  // is where a fresh query looks first (PDt's motion coherence).
  if (!have_server_ || server_ir_.num_rows == 0) return false;
  const IrRow* deepest = &server_ir_.rows[0];
  for (int i = 1; i < server_ir_.num_rows; ++i) {
    const IrRow& r = server_ir_.rows[static_cast<std::size_t>(i)];
    if (r.depth > deepest->depth) deepest = &r;
  }
  const Pose X_WA = server_ir_.X_WP_ref * X_PA_;
  const Pose X_BW = X_WB.Inverse();
  pd::PdQueryData::CoherenceEntry e;
  e.p_BAo = X_BW * (X_WA.t + deepest->depth * deepest->n_W);
  e.R_BA = X_BW.R * X_WA.R;
  e.dir_B = X_BW.R * deepest->n_W;
  data->Remember(e);
  return true;
}

void LocalContactModel::AnswerLocal(const ProxySample& x, std::int64_t now_ns,
                                    std::int64_t server_t, IntermediateRep* ir) {
  view_now_->Bodies(server_t, &bodies_, &keys_);
  // A body whose model was rebuilt starts its coherence cache afresh.
  data_.Resize(bodies_.size());
  data_.per_body_pdg.resize(bodies_.size());
  data_keys_.resize(bodies_.size(), 0);
  for (std::size_t i = 0; i < bodies_.size(); ++i) {
    if (data_keys_[i] != keys_[i]) {
      data_.per_body[i] = pd::PdQueryData();
      data_.per_body_pdg[i] = pd::PdgQueryData();
      data_keys_[i] = keys_[i];
      if (Seed(bodies_[i].X_WB, &data_.per_body[i])) {
        (void)Seed(bodies_[i].X_WB, &data_.per_body_pdg[i].pdt);
        std::lock_guard lock(stats_mu_);
        ++stats_.seeded;
      }
    }
  }
  const Pose X_WA = x.X_WP * X_PA_;
  pd::ComputeScenePd(
      options_.mode, *probe_, X_WA, bodies_, options_.request, &data_, &result_,
      options_.torque ? pd::WrenchTerms::kForceAndTorque : pd::WrenchTerms::kForceOnly);
  pd::ContactModelOptions mo;
  mo.validity_fraction = options_.validity_fraction;
  pd::BuildContactModel(*probe_, X_WA, bodies_, result_, mo, &model_);
  IrFromContactModel(model_, x, X_AP_, options_.torque, ir);
  answered_[x.sequence % kAnswered] = {x.sequence, MaxRowDepth(*ir)};
  ir->receive_time_ns = now_ns;
  ir->compute_time_us = result_.time_us;
  ir->source = kIrSourceLocal;
}

void LocalContactModel::ApplyQueued(std::int64_t now_ns) {
  std::deque<PatchDelta> queue;
  std::string undecodable;
  std::uint64_t bytes = 0;
  bool reset;
  {
    std::lock_guard lock(queue_mu_);
    queue.swap(queue_);
    undecodable.swap(undecodable_);
    bytes = offered_bytes_;
    reset = reset_.exchange(false, std::memory_order_acq_rel);
  }
  bool changed = false;
  std::uint64_t drops = 0;
  if (reset) {
    if (!store_.empty()) ++drops;
    store_.Clear();
    disabled_ = false;
    changed = true;
  }
  std::string problem = undecodable;
  std::uint64_t applied = 0;
  for (const PatchDelta& d : queue) {
    if (disabled_ || !problem.empty()) break;
    problem = store_.Apply(d);
    if (problem.empty()) ++applied;
  }
  changed = changed || applied > 0;
  const bool rejected = !problem.empty() && !disabled_;
  if (rejected) {
    // What the server believes we hold is no longer what we hold: the
    // patch is no use until the stream starts afresh.
    store_.Clear();
    disabled_ = true;
    changed = true;
  }
  // A quiet stream: the scene may have changed unseen.
  if (!store_.empty() && now_ns - last_message_ns_.load(std::memory_order_relaxed) >
                             static_cast<std::int64_t>(options_.patch_quiet_s * 1e9)) {
    store_.Clear();
    ++drops;
    changed = true;
  }
  if (changed) {
    std::shared_ptr<const PatchView> view = disabled_ ? nullptr : store_.View();
    std::lock_guard lock(view_mu_);
    view_ = std::move(view);
  }
  std::lock_guard lock(stats_mu_);
  stats_.patch_bytes = bytes;
  stats_.patches += applied;
  stats_.drops += drops;
  if (rejected) {
    ++stats_.bad_patches;
    stats_.last_problem = problem;
  }
  stats_.triangles_held = store_.triangles_held();
  stats_.max_triangles_held = std::max(stats_.max_triangles_held, stats_.triangles_held);
}

bool LocalContactModel::Step(std::int64_t now_ns, IrMailbox* out) {
  // Patches first: they describe the scene the newest answers came from.
  if (!background_) ApplyQueued(now_ns);
  {
    std::lock_guard lock(view_mu_);
    view_now_ = view_;
  }
  if (reset_worker_.exchange(false, std::memory_order_acq_rel)) have_server_ = false;
  bool new_server = false;
  if (server_.Fetch()) {
    server_ir_ = server_.front();
    have_server_ = true;
    server_ir_published_ = false;
    new_server = true;
    // The reference check: the local answer to the same sample, if any.
    const Answered& a = answered_[server_ir_.sequence % kAnswered];
    if (a.sequence == server_ir_.sequence && a.sequence != 0) {
      const double ds = MaxRowDepth(server_ir_);
      const double diff = std::abs(a.depth - ds);
      std::lock_guard lock(stats_mu_);
      ++stats_.reference_checks;
      if (diff > 1e-4 + 0.05 * std::max(a.depth, ds)) ++stats_.reference_disagreements;
      reference_diff_um_.Add(std::max(1.0, 1e6 * diff));
    }
  }
  const bool new_sample = samples_.Fetch();
  if (new_sample) {
    sample_ = samples_.front();
    have_sample_ = true;
  }
  if (!new_sample && !new_server) return false;

  const std::int64_t server_t = now_ns + offset_ns_.load(std::memory_order_relaxed);
  const bool covered = have_sample_ && Covered(sample_.X_WP, server_t);
  // Where the patch covers the probe, a server answer alone changes nothing:
  // it is only kept for rule 2 at the next sample.
  if (covered && !new_sample) return false;
  bool published = false;
  if (covered) {
    const auto t0 = std::chrono::steady_clock::now();
    IntermediateRep& ir = out->back();
    AnswerLocal(sample_, now_ns, server_t, &ir);
    const double us =
        1e-3 * static_cast<double>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                       std::chrono::steady_clock::now() - t0)
                                       .count());
    // Rule 2: the patch sees no contact, the server's fresh answer does.
    const double server_depth = MaxRowDepth(server_ir_);
    const bool server_deeper = model_.outcome == pd::ContactOutcome::kSeparated && have_server_ &&
                               server_depth >= thinnest_ &&
                               now_ns - server_ir_.receive_time_ns <=
                                   static_cast<std::int64_t>(options_.server_fresh_s * 1e9) &&
                               InsideValidity(server_ir_, sample_.X_WP);
    if (server_deeper) {
      if (!server_ir_published_) {
        out->Write(server_ir_);
        server_ir_published_ = true;
        published = true;
      }
    } else {
      out->Publish();
      server_ir_published_ = false;
      published = true;
    }
    std::lock_guard lock(stats_mu_);
    if (first_step_ns_ < 0) first_step_ns_ = now_ns;
    last_step_ns_ = now_ns;
    ++stats_.steps;
    compute_us_.Add(us);
    if (server_deeper) {
      ++stats_.server_deeper;
    } else {
      ++stats_.local_answers;
    }
  } else {
    // Rule 3. Under a patch the probe has outrun, a late answer for a pose
    // the probe has left would replace the last local IR (still good near
    // where the patch ended) with rows linearised far away: it waits until
    // the probe is inside its validity region, or a newer answer comes.
    const bool usable =
        view_now_ == nullptr || !have_sample_ || InsideValidity(server_ir_, sample_.X_WP);
    if (have_server_ && !server_ir_published_ && usable) {
      out->Write(server_ir_);
      server_ir_published_ = true;
      published = true;
    }
    if (new_sample) {
      std::lock_guard lock(stats_mu_);
      ++stats_.steps;
      ++stats_.uncovered;
    }
  }
  return published;
}

void LocalContactModel::Start(IrMailbox* out, const Clock* clock) {
  if (thread_.joinable()) return;
  background_ = true;
  builder_ = std::jthread([this, clock](std::stop_token st) {
    while (!st.stop_requested()) {
      ApplyQueued(clock->NowNs());
      std::unique_lock lock(queue_mu_);
      // Woken by a patch, a reset or Stop; at least every 10 ms for the
      // quiet-stream drop.
      queue_cv_.wait_for(lock, st, std::chrono::milliseconds(10),
                         [&] { return !queue_.empty() || !undecodable_.empty() || reset_.load(); });
    }
  });
  thread_ = std::jthread([this, out, clock](std::stop_token st) {
    const std::stop_callback on_stop(st, [this] { Wake(); });
    while (!st.stop_requested()) {
      if (Step(clock->NowNs(), out)) continue;
      // Nothing new: sleep until an Offer (a sample or an answer) or Stop
      // wakes us. The flag is set after the mailbox write, so an offer that
      // came after Step looked is never slept through.
      std::unique_lock lock(wake_mu_);
      waiting_ = true;
      wake_cv_.wait_for(lock, std::chrono::milliseconds(10), [&] { return wake_; });
      waiting_ = false;
      wake_ = false;
    }
  });
}

void LocalContactModel::Stop() {
  if (!thread_.joinable()) return;
  thread_.request_stop();
  thread_.join();
  thread_ = std::jthread();
  builder_.request_stop();
  builder_.join();
  builder_ = std::jthread();
  background_ = false;
}

LocalModelStats LocalContactModel::stats() const {
  std::lock_guard lock(stats_mu_);
  LocalModelStats s = stats_;
  s.compute_p50_us = compute_us_.Quantile(0.5);
  s.compute_p99_us = compute_us_.Quantile(0.99);
  s.compute_max_us = compute_us_.max();
  s.reference_diff_p99_mm = 1e-3 * reference_diff_um_.Quantile(0.99);
  s.reference_diff_max_mm = 1e-3 * reference_diff_um_.max();
  const double span = 1e-9 * static_cast<double>(last_step_ns_ - first_step_ns_);
  s.rate_hz = span > 0 ? static_cast<double>(s.local_answers + s.server_deeper) / span : 0;
  return s;
}

}  // namespace hapticpd::device
