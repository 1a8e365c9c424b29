#include "server/scene.h"

#include <algorithm>
#include <cmath>

#include "server/convert.h"

namespace hapticpd::server {

bool Moving(const BodyState& b) { return !b.v_W.isZero(0.0) || !b.w_W.isZero(0.0); }

Pose PoseAt(const BodyState& b, std::int64_t t_ns) {
  if (!Moving(b)) return b.X_WB;
  return MovedPose(b.X_WB, b.v_W, b.w_W, static_cast<double>(t_ns - b.pose_time_ns) * 1e-9);
}

const BodyState* SceneSnapshot::Find(const std::string& id) const {
  for (const BodyState& b : bodies) {
    if (b.id == id) return &b;
  }
  return nullptr;
}

void ChangeSignal::Notify() {
  {
    std::lock_guard lock(mu_);
    count_.fetch_add(1);
  }
  cv_.notify_all();
}

std::uint64_t ChangeSignal::WaitFor(std::uint64_t seen,
                                    std::chrono::steady_clock::time_point deadline) {
  std::unique_lock lock(mu_);
  cv_.wait_until(lock, deadline, [&] { return count_.load() != seen; });
  return count_.load();
}

Scene::Scene(std::string id, std::string description, ChangeSignal* signal)
    : id_(std::move(id)), description_(std::move(description)), signal_(signal) {
  snapshot_.store(std::make_shared<const SceneSnapshot>());
}

void Scene::Publish(std::shared_ptr<SceneSnapshot> next) {
  snapshot_.store(std::move(next), std::memory_order_release);
  signal_->Notify();
  changes_.Notify();
}

grpc::Status Scene::AddBody(BodyState body, std::size_t max_bodies, BodyState* added,
                            const std::string& id_field, const WriteHook& hook) {
  std::lock_guard lock(write_mu_);
  if (deleted())
    return grpc::Status(grpc::StatusCode::NOT_FOUND, "scene '" + id_ + "' was deleted");
  const SnapshotPtr cur = snapshot();
  if (cur->bodies.size() >= max_bodies) {
    return grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                        "scene '" + id_ + "' already holds " + std::to_string(cur->bodies.size()) +
                            " bodies (server limit " + std::to_string(max_bodies) + ")");
  }
  const std::uint64_t first_number = next_body_number_;
  if (body.id.empty()) {
    do {
      body.id = "body-" + std::to_string(next_body_number_++);
    } while (cur->Find(body.id) != nullptr);
  } else if (cur->Find(body.id) != nullptr) {
    return grpc::Status(grpc::StatusCode::ALREADY_EXISTS,
                        id_field + ": scene '" + id_ + "' already has a body '" + body.id + "'");
  }
  if (hook) {
    if (auto s = hook({&body, cur->revision + 1, next_body_number_}); !s.ok()) {
      next_body_number_ = first_number;
      return s;
    }
  }
  if (body.pose_time_ns == 0) body.pose_time_ns = NowNs();
  auto next = std::make_shared<SceneSnapshot>(*cur);
  next->revision = cur->revision + 1;
  next->structure_revision = cur->structure_revision + 1;
  next->bodies.push_back(std::move(body));
  if (added) *added = next->bodies.back();
  Publish(std::move(next));
  return grpc::Status::OK;
}

grpc::Status Scene::MoveBody(const std::string& id, const Pose& X_WB, const Vec3* v_W,
                             const Vec3* w_W, std::uint64_t* revision, const WriteHook& hook) {
  std::lock_guard lock(write_mu_);
  if (deleted())
    return grpc::Status(grpc::StatusCode::NOT_FOUND, "scene '" + id_ + "' was deleted");
  const SnapshotPtr cur = snapshot();
  const BodyState* b = cur->Find(id);
  if (b == nullptr) {
    return grpc::Status(grpc::StatusCode::NOT_FOUND,
                        "body_id: scene '" + id_ + "' has no body '" + id + "'");
  }
  if (!b->movable) {
    return grpc::Status(grpc::StatusCode::FAILED_PRECONDITION,
                        "body_id: body '" + id + "' is static (add it with movable = true)");
  }
  auto next = std::make_shared<SceneSnapshot>(*cur);
  next->revision = cur->revision + 1;
  for (BodyState& nb : next->bodies) {
    if (nb.id != id) continue;
    nb.X_WB = X_WB;
    nb.v_W = v_W ? *v_W : Vec3::Zero();
    nb.w_W = w_W ? *w_W : Vec3::Zero();
    nb.pose_time_ns = NowNs();
    if (hook) {
      if (auto s = hook({&nb, next->revision, next_body_number_}); !s.ok()) return s;
    }
  }
  if (revision) *revision = next->revision;
  Publish(std::move(next));
  return grpc::Status::OK;
}

grpc::Status Scene::RemoveBody(const std::string& id, std::uint64_t* revision,
                               const WriteHook& hook) {
  std::lock_guard lock(write_mu_);
  if (deleted())
    return grpc::Status(grpc::StatusCode::NOT_FOUND, "scene '" + id_ + "' was deleted");
  const SnapshotPtr cur = snapshot();
  if (cur->Find(id) == nullptr) {
    return grpc::Status(grpc::StatusCode::NOT_FOUND,
                        "body_id: scene '" + id_ + "' has no body '" + id + "'");
  }
  if (hook) {
    if (auto s = hook({nullptr, cur->revision + 1, next_body_number_}); !s.ok()) return s;
  }
  auto next = std::make_shared<SceneSnapshot>();
  next->revision = cur->revision + 1;
  next->structure_revision = cur->structure_revision + 1;
  next->bodies.reserve(cur->bodies.size() - 1);
  for (const BodyState& b : cur->bodies) {
    if (b.id != id) next->bodies.push_back(b);
  }
  if (revision) *revision = next->revision;
  Publish(std::move(next));
  return grpc::Status::OK;
}

void Scene::MarkDeleted() {
  {
    std::lock_guard lock(write_mu_);
    deleted_.store(true, std::memory_order_release);
  }
  signal_->Notify();
  changes_.Notify();
}

grpc::Status Scene::MarkDeleted(const std::function<grpc::Status()>& hook) {
  {
    std::lock_guard lock(write_mu_);
    if (deleted())
      return grpc::Status(grpc::StatusCode::NOT_FOUND, "scene_id: no scene '" + id_ + "'");
    if (hook) {
      if (auto s = hook(); !s.ok()) return s;
    }
    deleted_.store(true, std::memory_order_release);
  }
  signal_->Notify();
  changes_.Notify();
  return grpc::Status::OK;
}

std::uint64_t Scene::next_body_number() const {
  std::lock_guard lock(write_mu_);
  return next_body_number_;
}

void Scene::set_next_body_number(std::uint64_t n) {
  std::lock_guard lock(write_mu_);
  next_body_number_ = std::max<std::uint64_t>(1, n);
}

void Scene::AddProbe(std::shared_ptr<ProbeSlot> slot) {
  {
    std::lock_guard lock(probes_mu_);
    probes_.push_back(std::move(slot));
    ++probes_revision_;
  }
  changes_.Notify();
}

void Scene::RemoveProbe(const ProbeSlot* slot) {
  {
    std::lock_guard lock(probes_mu_);
    std::erase_if(probes_, [&](const auto& p) { return p.get() == slot; });
    ++probes_revision_;
  }
  changes_.Notify();
}

void Scene::CopySessions(std::vector<std::shared_ptr<ProbeSlot>>* out) const {
  out->clear();
  std::lock_guard lock(probes_mu_);
  *out = probes_;
}

void Scene::CopyProbes(std::vector<ProbeCopy>* out) const {
  out->clear();
  std::lock_guard lock(probes_mu_);
  for (const auto& p : probes_) {
    std::lock_guard plock(p->mu);
    if (!p->valid) continue;
    out->push_back({p->session_id, p->X_WA, p->force_W, p->depth, p->sequence, p->full});
  }
}

grpc::Status SceneRegistry::Create(const std::string& id, const std::string& description,
                                   std::size_t max_scenes, ScenePtr* out) {
  return Create(id, description, v1::SceneConfig(), max_scenes, out, nullptr);
}

grpc::Status SceneRegistry::Create(const std::string& id, const std::string& description,
                                   const v1::SceneConfig& config, std::size_t max_scenes,
                                   ScenePtr* out, const std::function<grpc::Status()>& hook) {
  std::lock_guard lock(mu_);
  if (scenes_.count(id)) {
    return grpc::Status(grpc::StatusCode::ALREADY_EXISTS, "scene_id: scene '" + id + "' exists");
  }
  if (scenes_.size() >= max_scenes) {
    return grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                        "scene_id: the server already hosts " + std::to_string(scenes_.size()) +
                            " scenes (limit " + std::to_string(max_scenes) + ")");
  }
  if (hook) {
    if (auto s = hook(); !s.ok()) return s;
  }
  auto scene = std::make_shared<Scene>(id, description, signal_);
  scene->set_config(config);
  scenes_.emplace(id, scene);
  if (out) *out = std::move(scene);
  return grpc::Status::OK;
}

grpc::Status SceneRegistry::Remove(const std::string& id, const std::function<grpc::Status()>& hook,
                                   ScenePtr* out) {
  std::lock_guard lock(mu_);
  auto it = scenes_.find(id);
  if (it == scenes_.end())
    return grpc::Status(grpc::StatusCode::NOT_FOUND, "scene_id: no scene '" + id + "'");
  // Under the scene's writer lock: no body is added to the store after the
  // scene's rows are gone.
  if (auto s = it->second->MarkDeleted(hook); !s.ok()) return s;
  if (out) *out = it->second;
  scenes_.erase(it);
  return grpc::Status::OK;
}

ScenePtr SceneRegistry::Get(const std::string& id) const {
  std::lock_guard lock(mu_);
  auto it = scenes_.find(id);
  return it == scenes_.end() ? nullptr : it->second;
}

ScenePtr SceneRegistry::Remove(const std::string& id) {
  ScenePtr s;
  {
    std::lock_guard lock(mu_);
    auto it = scenes_.find(id);
    if (it == scenes_.end()) return nullptr;
    s = it->second;
    scenes_.erase(it);
  }
  s->MarkDeleted();
  return s;
}

std::vector<ScenePtr> SceneRegistry::List() const {
  std::lock_guard lock(mu_);
  std::vector<ScenePtr> out;
  for (const auto& [id, s] : scenes_) out.push_back(s);
  return out;
}

}  // namespace hapticpd::server
