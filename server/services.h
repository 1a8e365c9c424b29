// The gRPC service implementations (internal to server/).
#pragma once

#include "hapticpd/v1/haptic.grpc.pb.h"
#include "hapticpd/v1/scene.grpc.pb.h"
#include "server/core.h"

namespace hapticpd::server::internal {

class SceneServiceImpl final : public v1::SceneService::CallbackService {
 public:
  explicit SceneServiceImpl(Core* core) : core_(core) {}

  grpc::ServerUnaryReactor* CreateScene(grpc::CallbackServerContext* ctx,
                                        const v1::CreateSceneRequest* req,
                                        v1::SceneSummary* resp) override;
  grpc::ServerUnaryReactor* ListScenes(grpc::CallbackServerContext* ctx,
                                       const v1::ListScenesRequest* req,
                                       v1::ListScenesResponse* resp) override;
  grpc::ServerUnaryReactor* GetScene(grpc::CallbackServerContext* ctx,
                                     const v1::GetSceneRequest* req, v1::Scene* resp) override;
  grpc::ServerUnaryReactor* DeleteScene(grpc::CallbackServerContext* ctx,
                                        const v1::DeleteSceneRequest* req,
                                        v1::DeleteSceneResponse* resp) override;
  grpc::ServerReadReactor<v1::AddBodyRequest>* AddBody(grpc::CallbackServerContext* ctx,
                                                       v1::Body* resp) override;
  grpc::ServerUnaryReactor* MoveBody(grpc::CallbackServerContext* ctx,
                                     const v1::MoveBodyRequest* req,
                                     v1::MoveBodyResponse* resp) override;
  grpc::ServerUnaryReactor* RemoveBody(grpc::CallbackServerContext* ctx,
                                       const v1::RemoveBodyRequest* req,
                                       v1::RemoveBodyResponse* resp) override;
  grpc::ServerWriteReactor<v1::SceneEvent>* Watch(grpc::CallbackServerContext* ctx,
                                                  const v1::WatchRequest* req) override;

 private:
  Core* core_;
};

class HapticServiceImpl final : public v1::HapticService::CallbackService {
 public:
  explicit HapticServiceImpl(Core* core) : core_(core) {}
  grpc::ServerBidiReactor<v1::CoupleRequest, v1::CoupleResponse>* Couple(
      grpc::CallbackServerContext* ctx) override;

 private:
  Core* core_;
};

/// Finds a scene the caller may use with `role`: NOT_FOUND or the auth error.
grpc::Status ResolveScene(Core* core, const grpc::ServerContextBase& ctx, const std::string& id,
                          Role role, ScenePtr* out);

/// Builds a validated body (mesh model, BVH, pose, material) from a spec and
/// an already-built mesh. Runs off the gRPC threads.
grpc::Status MakeBody(Core* core, const v1::BodySpec& spec, std::string_view field, pd::Mesh mesh,
                      BodyState* out);

/// Validates a body spec's scalar parts (id, pose, material, velocity).
grpc::Status ValidateSpec(const v1::BodySpec& spec, std::string_view field);

}  // namespace hapticpd::server::internal
