#include "proto/wire/routing.h"

#include <fmt/format.h>

#include <iterator>
#include <string>

#include "proto/wire/text.h"

namespace hapticpd::wire {

void AddSceneHeader(grpc::ClientContext* ctx, std::string_view scene_id) {
  if (scene_id.empty()) return;
  ctx->AddMetadata(kSceneHeader, std::string(scene_id));
}

grpc::Status CheckSceneHeader(const grpc::ServerContextBase& ctx, std::string_view body_scene_id) {
  const auto& md = ctx.client_metadata();
  const auto [first, last] = md.equal_range(kSceneHeader);
  if (first == last) return grpc::Status::OK;
  if (std::next(first) != last) {
    return grpc::Status(
        grpc::StatusCode::INVALID_ARGUMENT,
        fmt::format("{}: sent more than once (send one, naming the call's scene)", kSceneHeader));
  }
  const std::string_view header(first->second.data(), first->second.size());
  if (header == body_scene_id) return grpc::Status::OK;
  return grpc::Status(
      grpc::StatusCode::INVALID_ARGUMENT,
      fmt::format("{}: the header names scene '{}' but the request is for scene '{}' (a call "
                  "routed to one scene's server never acts on another's)",
                  kSceneHeader, Printable(header), Printable(body_scene_id)));
}

}  // namespace hapticpd::wire
