// Routing metadata: every scene-scoped call names its scene in a header, so a
// balancer in front of several `hapticpd serve` processes can send it to the
// process that owns the scene without reading the request body (docker/README.md
// "Scaling out"). Clients add it through SceneContext/AddSceneHeader, servers
// check it against the body through CheckSceneHeader: one rule, one place.
#pragma once

#include <grpcpp/client_context.h>
#include <grpcpp/server_context.h>

#include <string_view>

namespace hapticpd::wire {

/// The metadata key (lower case, as HTTP/2 sends it).
inline constexpr char kSceneHeader[] = "x-hapticpd-scene";

/// Adds `x-hapticpd-scene: scene_id` to a call's metadata. Called once per
/// context, before the call starts; an empty id adds nothing.
void AddSceneHeader(grpc::ClientContext* ctx, std::string_view scene_id);

/// OK when the call carries no scene header, or one that equals
/// `body_scene_id` (the scene the request body names). Otherwise
/// INVALID_ARGUMENT naming both ids: a call routed for one scene never
/// acts on another. Two headers are refused the same way.
grpc::Status CheckSceneHeader(const grpc::ServerContextBase& ctx, std::string_view body_scene_id);

}  // namespace hapticpd::wire
