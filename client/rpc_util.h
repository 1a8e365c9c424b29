// Shared plumbing of the network subcommands (inject, move, remove, scene,
// watch, couple): connection options, channel, per-call context, parsing of
// poses, and turning a gRPC status into a CommandError.
#pragma once

#include <grpcpp/grpcpp.h>

#include <CLI/CLI.hpp>
#include <memory>
#include <string>
#include <utility>

#include "client/commands.h"
#include "hapticpd/v1/scene.pb.h"
#include "hapticpd/v1/types.pb.h"
#include "pd/types.h"

namespace hapticpd::cli {

struct ConnectionOptions {
  std::string server = "127.0.0.1:50051";
  std::string token;   ///< also from $HAPTICPD_TOKEN
  std::string tls_ca;  ///< PEM CA file: use TLS and trust this CA
  bool tls = false;    ///< use TLS with the system's roots
  double timeout_s = 30;
};

/// Adds --server, --token, --tls, --tls-ca, --timeout to `cmd`.
void AddConnectionOptions(CLI::App* cmd, ConnectionOptions* o);

/// Plaintext, or TLS (--tls: the system's roots; --tls-ca: that PEM CA)
/// when either is given. Throws CommandError when --tls-ca cannot be read.
std::shared_ptr<grpc::ChannelCredentials> MakeCredentials(const ConnectionOptions& o);
/// A channel to --server with MakeCredentials' credentials.
std::shared_ptr<grpc::Channel> MakeChannel(const ConnectionOptions& o);
/// A context carrying the token and (unless `streaming`) the deadline.
/// For calls that name no scene (ListScenes).
std::unique_ptr<grpc::ClientContext> MakeContext(const ConnectionOptions& o,
                                                 bool streaming = false);
/// The same for a scene-scoped call: it also carries the routing header
/// `x-hapticpd-scene: scene_id` (proto/wire/routing.h), so that a balancer
/// sends it to the process owning the scene (docker/README.md "Scaling out").
std::unique_ptr<grpc::ClientContext> MakeSceneContext(const ConnectionOptions& o,
                                                      const std::string& scene_id,
                                                      bool streaming = false);

/// "CODE: message", e.g. "NOT_FOUND: scene_id: no scene 'x'".
std::string StatusText(const grpc::Status& s);
/// Throws CommandError "CMD: CODE: message" for a non-OK status.
void Check(const grpc::Status& s, const std::string& cmd);

/// A fresh request id for one mutation (server/README.md "Idempotent
/// mutations"): "cli-" and 24 random hex digits. A retry of that mutation
/// sends the same id.
std::string NewRequestId();

/// "x,y,z" or "x,y,z,qw,qx,qy,qz" (metres; unit quaternion w, x, y, z).
v1::Pose ParsePose(const std::string& text, const std::string& option);
/// "vx,vy,vz" or "vx,vy,vz,wx,wy,wz".
v1::Twist ParseTwist(const std::string& text, const std::string& option);

/// The world bounding box (lo, hi) of a scene's bodies, leaving out the body
/// `skip_body_id` (a device's probe body); both zero for an empty scene.
std::pair<Vec3, Vec3> SceneBox(const v1::Scene& scene, const std::string& skip_body_id = "");

}  // namespace hapticpd::cli
