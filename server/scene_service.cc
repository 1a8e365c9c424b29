#include <grpcpp/grpcpp.h>

#include "proto/wire/ranges.h"
#include "proto/wire/routing.h"
#include "proto/wire/text.h"
#include "server/convert.h"
#include "server/observers.h"
#include "server/scene_file.h"
#include "server/services.h"

namespace hapticpd::server::internal {
namespace {

grpc::ServerUnaryReactor* Done(grpc::CallbackServerContext* ctx, const grpc::Status& s) {
  auto* r = ctx->DefaultReactor();
  r->Finish(Bounded(s));
  return r;
}

/// A mutation's request id (server/README.md "Idempotent mutations"):
/// Start claims it (or answers with the first outcome), Put writes the
/// outcome in the mutation's own transaction, End records it.
class RequestIdCall {
 public:
  RequestIdCall(Core* core, const char* method) : core_(core), method_(method) {}

  /// True: run the request. False: `*result` (and `*resp` when OK) is the
  /// answer, the first outcome of this id or a malformed id.
  bool Start(const std::string& client_key, const std::string& request_id,
             google::protobuf::Message* resp, grpc::Status* result) {
    if (request_id.empty()) return true;
    if (auto s = ValidateId(request_id, "request_id"); !s.ok()) {
      *result = s;
      return false;
    }
    client_ = RequestLog::ClientHash(client_key);
    id_ = request_id;
    RequestOutcome first;
    if (core_->requests->Begin(client_, id_, method_, &first) == RequestLog::Claim::kDone) {
      *result = Replay(first, resp);
      return false;
    }
    claimed_ = true;
    return true;
  }

  /// In a store transaction: the successful outcome, committed with the change.
  void Put(SceneStore::Txn& t, const google::protobuf::Message& resp) {
    if (!claimed_) return;
    t.PutRequest(client_, id_, Outcome(grpc::Status::OK, &resp));
    durable_ = true;
  }

  grpc::Status End(const grpc::Status& s, const google::protobuf::Message& resp) {
    if (claimed_) {
      core_->requests->Finish(client_, id_, Outcome(s, &resp), durable_ && s.ok());
      claimed_ = false;
    }
    return s;
  }

  static grpc::Status Replay(const RequestOutcome& o, google::protobuf::Message* resp) {
    if (o.code != 0) return grpc::Status(static_cast<grpc::StatusCode>(o.code), o.message);
    if (resp != nullptr) resp->ParseFromString(o.response);
    return grpc::Status::OK;
  }

 private:
  RequestOutcome Outcome(const grpc::Status& s, const google::protobuf::Message* resp) const {
    RequestOutcome o;
    o.method = method_;
    o.code = static_cast<int>(s.error_code());
    o.message = s.error_message();
    if (s.ok() && resp != nullptr) o.response = resp->SerializeAsString();
    o.created_at_s = UnixNow();
    return o;
  }

  Core* core_;
  const char* method_;
  std::string client_, id_;
  bool claimed_ = false;
  bool durable_ = false;
};

/// A mutation's common part: the gate and the token, then the request id
/// (RequestIdCall), then `run(request)`, whose outcome End records.
template <class Run>
grpc::ServerUnaryReactor* RunMutation(Core* core, grpc::CallbackServerContext* ctx,
                                      const char* method, const std::string& request_id,
                                      google::protobuf::Message* resp, const Run& run) {
  if (auto s = core->Gate(); !s.ok()) return Done(ctx, s);
  if (auto s = core->tokens.CheckAnyToken(*ctx); !s.ok()) return Done(ctx, s);
  RequestIdCall request(core, method);
  grpc::Status replay;
  if (!request.Start(ClientKey(core->tokens, *ctx), request_id, resp, &replay))
    return Done(ctx, replay);
  return Done(ctx, request.End(run(request), *resp));
}

/// Receives a body upload, then builds it on the build queue.
class AddBodyReactor final : public grpc::ServerReadReactor<v1::AddBodyRequest>,
                             public StoppableCall {
 public:
  AddBodyReactor(Core* core, grpc::CallbackServerContext* ctx, v1::Body* resp)
      : core_(core), ctx_(ctx), resp_(resp), client_(ClientKey(core->tokens, *ctx)) {
    core_->Register(this);
    if (auto s = core_->Gate(); !s.ok()) {
      FinishOnce(s);
      return;
    }
    GrpcStart(this, [&] { StartRead(&req_); });
  }

  void Stop(const grpc::Status& status) override {
    std::lock_guard lock(mu_);
    if (!submitted_) FinishOnceLocked(status);
  }
  const Scene* scene() const override { return nullptr; }

 private:
  void OnReadDone(bool ok) override {
    const Reaction reaction(this);
    std::lock_guard lock(mu_);
    if (finished_) return;
    if (!ok) {
      OnComplete();
      return;
    }
    grpc::Status s = Take();
    if (replayed_) {
      FinishOnceLocked(s);
      return;
    }
    if (!s.ok()) {
      RecordError(s);
      FinishOnceLocked(s);
      return;
    }
    GrpcStart(this, [&] { StartRead(&req_); });
  }

  /// Handles one message (under mu_).
  grpc::Status Take() {
    if (req_.has_header()) {
      if (have_header_) return InvalidArgument("header", "sent twice (send it first, once)");
      have_header_ = true;
      header_.Swap(req_.mutable_header());
      if (auto s = core_->tokens.CheckAnyToken(*ctx_); !s.ok()) return s;
      if (!header_.request_id().empty()) {
        if (auto s = ValidateId(header_.request_id(), "header.request_id"); !s.ok()) return s;
        request_id_ok_ = true;
        // A retry of a finished upload is answered at once, without its bytes.
        RequestOutcome first;
        if (core_->requests->Lookup(RequestLog::ClientHash(client_), header_.request_id(),
                                    "AddBody", &first)) {
          replayed_ = true;
          return RequestIdCall::Replay(first, resp_);
        }
      }
      ScenePtr scene;
      if (auto s = ResolveScene(core_, *ctx_, header_.scene_id(), Role::kInject, &scene); !s.ok())
        return s;
      scene_ = scene;
      if (auto s = ValidateSpec(header_.spec(), "header.spec"); !s.ok()) return s;
      if (scene_->snapshot()->bodies.size() >= core_->limits.max_bodies_per_scene) {
        return grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                            "scene '" + scene_->id() + "' already holds the server limit of " +
                                std::to_string(core_->limits.max_bodies_per_scene) + " bodies");
      }
      if (header_.mesh_case() == v1::AddBodyHeader::MESH_NOT_SET) {
        return InvalidArgument("header.mesh", "give a format (then chunks), inline_mesh or shape");
      }
      if (header_.mesh_case() == v1::AddBodyHeader::kFormat &&
          (header_.format() == v1::MESH_FORMAT_UNSPECIFIED ||
           !v1::MeshFormat_IsValid(header_.format()))) {
        return InvalidArgument("header.format", "unspecified or unknown mesh format");
      }
      if (header_.total_bytes() > core_->limits.max_mesh_bytes) {
        return grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                            "header.total_bytes: " + std::to_string(header_.total_bytes()) +
                                " bytes exceed the server limit of " +
                                std::to_string(core_->limits.max_mesh_bytes));
      }
      return grpc::Status::OK;
    }
    if (req_.has_chunk()) {
      if (!have_header_) return InvalidArgument("header", "must be the first message");
      if (header_.mesh_case() != v1::AddBodyHeader::kFormat) {
        return InvalidArgument("chunk", "file bytes sent for a body given inline or as a shape");
      }
      const std::size_t total = bytes_.size() + req_.chunk().size();
      if (header_.total_bytes() > 0 && total > header_.total_bytes()) {
        return InvalidArgument("chunk", std::to_string(total) +
                                            " bytes received, more than header.total_bytes " +
                                            std::to_string(header_.total_bytes()));
      }
      if (total > core_->limits.max_mesh_bytes) {
        return grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                            "chunk: the mesh exceeds the server limit of " +
                                std::to_string(core_->limits.max_mesh_bytes) + " bytes");
      }
      bytes_ += req_.chunk();
      return grpc::Status::OK;
    }
    return InvalidArgument("part", "empty AddBodyRequest (neither header nor chunk)");
  }

  /// An upload with a valid request id that fails before it is built: a
  /// retry gets the same error (RequestLog::RecordError keeps only errors of
  /// the request itself, never transient ones).
  void RecordError(const grpc::Status& s) {
    if (!request_id_ok_ || s.ok()) return;
    RequestOutcome o;
    o.method = "AddBody";
    o.code = static_cast<int>(s.error_code());
    o.message = s.error_message();
    core_->requests->RecordError(RequestLog::ClientHash(client_), header_.request_id(), o);
  }

  /// The client half-closed: build the body off this thread (under mu_).
  void OnComplete() {
    if (!have_header_) {
      FinishOnceLocked(InvalidArgument("header", "missing (the stream was empty)"));
      return;
    }
    if (ctx_->IsCancelled()) {
      FinishOnceLocked(grpc::Status::CANCELLED);
      return;
    }
    if (header_.mesh_case() == v1::AddBodyHeader::kFormat && header_.total_bytes() > 0 &&
        bytes_.size() != header_.total_bytes()) {
      const grpc::Status s = InvalidArgument(
          "chunk", std::to_string(bytes_.size()) + " bytes received, header.total_bytes said " +
                       std::to_string(header_.total_bytes()));
      RecordError(s);
      FinishOnceLocked(s);
      return;
    }
    submitted_ = true;
    const bool queued = core_->builds.Submit(client_, [this] { Build(); });
    if (!queued) {
      submitted_ = false;
      FinishOnceLocked(core_->Unavailable());
    }
  }

  void Build() {
    if (core_->before_build) core_->before_build(header_.spec().label());
    RequestIdCall request(core_, "AddBody");
    grpc::Status replay;
    if (!request.Start(client_, header_.request_id(), resp_, &replay)) {
      FinishBuilt(replay);
      return;
    }
    FinishBuilt(request.End(BuildAndAdd(request), *resp_));
  }

  grpc::Status BuildAndAdd(RequestIdCall& request) {
    grpc::Status s;
    std::optional<pd::Mesh> mesh;
    const std::size_t max_tris = core_->limits.max_mesh_triangles;
    switch (header_.mesh_case()) {
      case v1::AddBodyHeader::kFormat:
        s = MeshFromBytes(bytes_, header_.format(), "chunk", max_tris, &mesh);
        break;
      case v1::AddBodyHeader::kInlineMesh:
        s = MeshFromInline(header_.inline_mesh(), "header.inline_mesh", max_tris, &mesh);
        break;
      case v1::AddBodyHeader::kShape:
        s = MeshFromShape(header_.shape(), "header.shape", max_tris, &mesh);
        break;
      default:
        s = InvalidArgument("header.mesh", "missing");
    }
    std::string().swap(bytes_);
    BodyState body;
    if (s.ok()) s = MakeBody(core_, header_.spec(), "header.spec", std::move(*mesh), &body);
    if (s.ok() && core_->shutting_down.load()) s = core_->Unavailable();
    BodyState added;
    if (s.ok()) {
      const std::string& scene_id = scene_->id();
      s = scene_->AddBody(std::move(body), core_->limits.max_bodies_per_scene, &added,
                          "header.spec.body_id", [&](const Scene::WriteInfo& w) {
                            return core_->Commit([&](SceneStore::Txn& t) {
                              t.PutBody(scene_id, *w.body);
                              t.SetNextBodyNumber(scene_id, w.next_body_number);
                              v1::Body answer;
                              FillBody(*w.body, false, &answer);
                              request.Put(t, answer);
                            });
                          });
    }
    if (s.ok()) {
      FillBody(added, false, resp_);
      Log()->info("scene '{}': added body '{}' ({} triangles)", scene_->id(), added.id,
                  added.model->mesh().num_triangles());
    } else {
      Log()->info("scene '{}': AddBody rejected: {}", wire::Printable(header_.scene_id()),
                  wire::Printable(s.error_message(), wire::kMaxStatusMessage));
    }
    return s;
  }

  void FinishBuilt(const grpc::Status& s) {
    {
      std::lock_guard lock(mu_);
      if (finished_) return;
      finished_ = true;
    }
    // Outside the lock and the last touch of `this`: OnDone may run (and
    // delete this reactor) on another thread as soon as Finish is called.
    GrpcStart(this, [&] { Finish(Bounded(s)); });
  }

  /// Only from reactions (OnReadDone) or under Core::StopCalls' lock, where
  /// OnDone cannot run before the caller has let go of mu_.
  void FinishOnceLocked(const grpc::Status& s) {
    if (finished_) return;
    finished_ = true;
    GrpcStart(this, [&] { Finish(Bounded(s)); });
  }
  void FinishOnce(const grpc::Status& s) {
    {
      std::lock_guard lock(mu_);
      if (finished_) return;
      finished_ = true;
    }
    // Outside the lock and the last touch of `this`: OnDone may run (and
    // delete this reactor) on another thread as soon as Finish is called.
    GrpcStart(this, [&] { Finish(Bounded(s)); });
  }

  void OnDone() override {
    GrpcTakeOver(this);
    core_->Unregister(this);
    delete this;
  }

  Core* core_;
  grpc::CallbackServerContext* ctx_;
  v1::Body* resp_;
  std::mutex mu_;
  bool finished_ = false;
  bool submitted_ = false;
  bool have_header_ = false;
  bool request_id_ok_ = false;  ///< the header carries a well-formed request id
  bool replayed_ = false;       ///< answered with the first outcome of its request id
  v1::AddBodyRequest req_;
  v1::AddBodyHeader header_;
  std::string bytes_;
  const std::string client_;  ///< ClientKey: the build pool's per-client bound
  ScenePtr scene_;
};

}  // namespace

grpc::Status ResolveScene(Core* core, const grpc::ServerContextBase& ctx, const std::string& id,
                          Role role, ScenePtr* out) {
  if (auto s = core->tokens.CheckAnyToken(ctx); !s.ok()) return s;
  // The id's syntax first: nothing longer than an id is echoed or looked up.
  if (auto s = ValidateId(id, "scene_id"); !s.ok()) return s;
  // A call routed for one scene (its header) never acts on another.
  if (auto s = wire::CheckSceneHeader(ctx, id); !s.ok()) return s;
  // Permission first: a caller without rights learns nothing about which scenes exist.
  if (auto s = core->tokens.Check(ctx, id, role); !s.ok()) return s;
  ScenePtr scene = core->scenes.Get(id);
  if (!scene) return grpc::Status(grpc::StatusCode::NOT_FOUND, "scene_id: no scene '" + id + "'");
  *out = std::move(scene);
  return grpc::Status::OK;
}

grpc::Status ValidateSpec(const v1::BodySpec& spec, std::string_view field) {
  const std::string f(field);
  if (!spec.body_id().empty()) {
    if (auto s = ValidateId(spec.body_id(), f + ".body_id"); !s.ok()) return s;
  }
  Pose X;
  if (auto s = FromProto(spec.pose(), f + ".pose", &X); !s.ok()) return s;
  if (spec.has_material()) {
    pd::Material m;
    if (auto s = FromProto(spec.material(), f + ".material", &m); !s.ok()) return s;
  }
  if (spec.has_velocity()) {
    if (auto s = ValidateTwist(spec.velocity(), f + ".velocity"); !s.ok()) return s;
  }
  if (spec.label().size() > 256) return InvalidArgument(f + ".label", "is longer than 256 bytes");
  return grpc::Status::OK;
}

grpc::Status MakeBody(Core* core, const v1::BodySpec& spec, std::string_view field, pd::Mesh mesh,
                      BodyState* out) {
  const std::string f(field);
  if (auto s = ValidateSpec(spec, field); !s.ok()) return s;
  BodyState b;
  b.uid = core->scenes.NextBodyUid();
  b.id = spec.body_id();
  b.label = spec.label();
  (void)FromProto(spec.pose(), f + ".pose", &b.X_WB);
  if (spec.has_material()) (void)FromProto(spec.material(), f + ".material", &b.material);
  if (spec.has_velocity()) {
    (void)FromProto(spec.velocity().linear(), "v", &b.v_W);
    (void)FromProto(spec.velocity().angular(), "w", &b.w_W);
  }
  b.movable = spec.movable();
  b.model = pd::MakeModel(std::move(mesh));  // BVH and mass properties: off the haptic path
  *out = std::move(b);
  return grpc::Status::OK;
}

grpc::ServerUnaryReactor* SceneServiceImpl::CreateScene(grpc::CallbackServerContext* ctx,
                                                        const v1::CreateSceneRequest* req,
                                                        v1::SceneSummary* resp) {
  const ServiceCall call(this);
  auto run = [&](RequestIdCall& request) -> grpc::Status {
    if (auto s = ValidateId(req->scene_id(), "scene_id"); !s.ok()) return s;
    if (auto s = wire::CheckSceneHeader(*ctx, req->scene_id()); !s.ok()) return s;
    if (req->description().size() > 1024) {
      return InvalidArgument("description", "is longer than 1024 bytes");
    }
    if (const std::string e =
            CheckSceneConfig(req->config(), "config", core_->limits.max_mesh_triangles);
        !e.empty()) {
      return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, e);
    }
    if (auto s = core_->tokens.Check(*ctx, req->scene_id(), Role::kAdmin); !s.ok()) return s;
    if (auto s = core_->CheckOwner(req->scene_id()); !s.ok()) return s;
    v1::SceneSummary answer;
    answer.set_scene_id(req->scene_id());
    answer.set_description(req->description());
    *answer.mutable_config() = req->config();
    ScenePtr scene;
    auto s = core_->scenes.Create(
        req->scene_id(), req->description(), req->config(), core_->limits.max_scenes, &scene, [&] {
          return core_->Commit([&](SceneStore::Txn& t) {
            t.PutScene(req->scene_id(), req->description(), req->config(), 1);
            request.Put(t, answer);
          });
        });
    if (!s.ok()) return s;
    *resp = answer;
    Log()->info("created scene '{}'", scene->id());
    return grpc::Status::OK;
  };
  return RunMutation(core_, ctx, "CreateScene", req->request_id(), resp, run);
}

grpc::ServerUnaryReactor* SceneServiceImpl::ListScenes(grpc::CallbackServerContext* ctx,
                                                       const v1::ListScenesRequest*,
                                                       v1::ListScenesResponse* resp) {
  const ServiceCall call(this);
  if (auto s = core_->Gate(); !s.ok()) return Done(ctx, s);
  if (auto s = core_->tokens.CheckAnyToken(*ctx); !s.ok()) return Done(ctx, s);
  for (const ScenePtr& s : core_->scenes.List()) {
    if (!core_->tokens.CanSee(*ctx, s->id())) continue;
    auto* sum = resp->add_scenes();
    const SnapshotPtr snap = s->snapshot();
    sum->set_scene_id(s->id());
    sum->set_description(s->description());
    sum->set_bodies(static_cast<std::uint32_t>(snap->bodies.size()));
    sum->set_sessions(static_cast<std::uint32_t>(std::max(0, s->sessions.load())));
    sum->set_observers(static_cast<std::uint32_t>(std::max(0, s->observers.load())));
    sum->set_revision(snap->revision);
    *sum->mutable_config() = s->config();
  }
  return Done(ctx, grpc::Status::OK);
}

grpc::ServerUnaryReactor* SceneServiceImpl::GetScene(grpc::CallbackServerContext* ctx,
                                                     const v1::GetSceneRequest* req,
                                                     v1::Scene* resp) {
  const ServiceCall call(this);
  if (auto s = core_->Gate(); !s.ok()) return Done(ctx, s);
  ScenePtr scene;
  if (auto s = ResolveScene(core_, *ctx, req->scene_id(), Role::kObserve, &scene); !s.ok())
    return Done(ctx, s);
  FillScene(*scene, *scene->snapshot(), req->include_meshes(), resp);
  return Done(ctx, grpc::Status::OK);
}

grpc::ServerUnaryReactor* SceneServiceImpl::DeleteScene(grpc::CallbackServerContext* ctx,
                                                        const v1::DeleteSceneRequest* req,
                                                        v1::DeleteSceneResponse* resp) {
  const ServiceCall call(this);
  auto run = [&](RequestIdCall& request) -> grpc::Status {
    ScenePtr scene;
    if (auto s = ResolveScene(core_, *ctx, req->scene_id(), Role::kAdmin, &scene); !s.ok())
      return s;
    ScenePtr removed;
    auto s = core_->scenes.Remove(
        req->scene_id(),
        [&] {
          return core_->Commit([&](SceneStore::Txn& t) {
            t.DeleteScene(req->scene_id());
            request.Put(t, v1::DeleteSceneResponse());
          });
        },
        &removed);
    if (!s.ok()) return s;
    core_->StopCalls(removed.get(), grpc::Status(grpc::StatusCode::NOT_FOUND,
                                                 "scene '" + removed->id() + "' was deleted"));
    Log()->info("deleted scene '{}'", removed->id());
    return grpc::Status::OK;
  };
  return RunMutation(core_, ctx, "DeleteScene", req->request_id(), resp, run);
}

grpc::ServerReadReactor<v1::AddBodyRequest>* SceneServiceImpl::AddBody(
    grpc::CallbackServerContext* ctx, v1::Body* resp) {
  const ServiceCall call(this);
  return new AddBodyReactor(core_, ctx, resp);
}

grpc::ServerUnaryReactor* SceneServiceImpl::MoveBody(grpc::CallbackServerContext* ctx,
                                                     const v1::MoveBodyRequest* req,
                                                     v1::MoveBodyResponse* resp) {
  const ServiceCall call(this);
  auto run = [&](RequestIdCall&) -> grpc::Status {
    ScenePtr scene;
    if (auto s = ResolveScene(core_, *ctx, req->scene_id(), Role::kInject, &scene); !s.ok())
      return s;
    if (auto s = ValidateId(req->body_id(), "body_id"); !s.ok()) return s;
    Pose X_WB;
    if (auto s = FromProto(req->pose(), "pose", &X_WB); !s.ok()) return s;
    Vec3 v = Vec3::Zero(), w = Vec3::Zero();
    if (req->has_velocity()) {
      // The velocity ranges first (FromProto alone checks finiteness and the
      // coordinate range).
      if (auto s = ValidateTwist(req->velocity(), "velocity"); !s.ok()) return s;
      (void)FromProto(req->velocity().linear(), "velocity.linear", &v, wire::kLinearVelocity);
      (void)FromProto(req->velocity().angular(), "velocity.angular", &w, wire::kAngularVelocity);
    }
    std::uint64_t rev = 0;
    // The pose goes into the next batch of the store (at most 100 ms later):
    // only a moving body's latest pose matters.
    SceneStore* store = core_->store.get();
    auto s = scene->MoveBody(req->body_id(), X_WB, &v, &w, &rev, [&](const Scene::WriteInfo& info) {
      if (store) {
        store->QueuePose(scene->id(), info.body->id, info.body->X_WB, info.body->v_W,
                         info.body->w_W);
      }
      return grpc::Status::OK;
    });
    if (!s.ok()) return s;
    resp->set_revision(rev);
    return grpc::Status::OK;
  };
  return RunMutation(core_, ctx, "MoveBody", req->request_id(), resp, run);
}

grpc::ServerUnaryReactor* SceneServiceImpl::RemoveBody(grpc::CallbackServerContext* ctx,
                                                       const v1::RemoveBodyRequest* req,
                                                       v1::RemoveBodyResponse* resp) {
  const ServiceCall call(this);
  auto run = [&](RequestIdCall& request) -> grpc::Status {
    ScenePtr scene;
    if (auto s = ResolveScene(core_, *ctx, req->scene_id(), Role::kInject, &scene); !s.ok())
      return s;
    if (auto s = ValidateId(req->body_id(), "body_id"); !s.ok()) return s;
    std::uint64_t rev = 0;
    auto s = scene->RemoveBody(req->body_id(), &rev, [&](const Scene::WriteInfo& info) {
      return core_->Commit([&](SceneStore::Txn& t) {
        t.DeleteBody(scene->id(), req->body_id());
        v1::RemoveBodyResponse answer;
        answer.set_revision(info.revision);
        request.Put(t, answer);
      });
    });
    if (!s.ok()) return s;
    resp->set_revision(rev);
    Log()->info("scene '{}': removed body '{}'", scene->id(), req->body_id());
    return grpc::Status::OK;
  };
  return RunMutation(core_, ctx, "RemoveBody", req->request_id(), resp, run);
}

grpc::ServerWriteReactor<v1::SceneEvent>* SceneServiceImpl::Watch(grpc::CallbackServerContext* ctx,
                                                                  const v1::WatchRequest* req) {
  const ServiceCall call(this);
  struct Reject final : grpc::ServerWriteReactor<v1::SceneEvent> {
    explicit Reject(const grpc::Status& s) {
      GrpcStart(this, [&] { Finish(Bounded(s)); });
    }
    void OnDone() override {
      GrpcTakeOver(this);
      delete this;
    }
  };
  if (auto s = core_->Gate(); !s.ok()) return new Reject(s);
  ScenePtr scene;
  if (auto s = ResolveScene(core_, *ctx, req->scene_id(), Role::kObserve, &scene); !s.ok())
    return new Reject(s);
  if (auto s = wire::CheckRange(req->rate_hz(), wire::kWatchRateHz, "rate_hz"); !s.ok()) {
    return new Reject(s);
  }
  // Counted here (released in WatchReactor::OnDone) so concurrent Watch calls cannot overshoot.
  if (core_->observers.fetch_add(1) >= core_->limits.max_observers) {
    --core_->observers;
    return new Reject(grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                                   "the server already has its limit of " +
                                       std::to_string(core_->limits.max_observers) + " observers"));
  }
  return new WatchReactor(core_, ctx, std::move(scene), *req);
}

}  // namespace hapticpd::server::internal
