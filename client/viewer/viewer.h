// `hapticpd view`: a Watch observer of one scene that serves it to browsers
// (client/viewer/README.md). The Watch stream is read on its own thread and
// reconnected with backoff when the server goes away; browsers are served
// from one port by HttpServer, each at its own pace.
#pragma once

#include <grpcpp/grpcpp.h>

#include <atomic>
#include <functional>
#include <memory>
#include <string>

#include "client/viewer/http_server.h"
#include "client/viewer/mesh_store.h"
#include "client/viewer/replay.h"

namespace hapticpd::viewer {

struct ViewerOptions {
  HttpOptions http;
  /// A new channel to the server for each (re)connection attempt.
  std::function<std::shared_ptr<grpc::Channel>()> make_channel;
  std::string server;        ///< HOST:PORT, for messages and /healthz
  std::string server_token;  ///< the viewer's own token to the server (observe role)
  std::string scene_id = "default";
  double rate_hz = 60;  ///< pose frames per second asked of the server
  /// Meshes over this many triangles are drawn simplified to it
  /// (SimplifyForDisplay); 0 draws every mesh in full.
  std::size_t display_triangles = kDefaultDisplayTriangles;
  /// Reconnection backoff: the first wait, doubled per failure up to the last.
  double reconnect_min_s = 0.25;
  double reconnect_max_s = 5;
  /// Set: play this recording instead of watching a server (`view
  /// --replay`); `make_channel` is then not used.
  std::shared_ptr<ReplayPlayer> replay;
  double replay_speed = 1;  ///< recorded seconds per second
};

class Viewer {
 public:
  /// Checks the options (ViewerError, see HttpServer).
  explicit Viewer(ViewerOptions options);
  ~Viewer();
  Viewer(const Viewer&) = delete;
  Viewer& operator=(const Viewer&) = delete;

  /// Binds the port (ViewerError) and starts watching the scene.
  void Start();
  /// Stops watching and serving. Idempotent.
  void Stop();

  int port() const;
  /// The page's URL, e.g. "http://127.0.0.1:8080/" (with ?token= when set).
  std::string url() const;

  struct Counts {
    bool server_connected = false;
    std::uint64_t events = 0;      ///< Watch events read
    std::uint64_t reconnects = 0;  ///< Watch streams started after the first
    bool replay_finished = false;  ///< a replay without loop played to its end
    HttpServer::Counts http;
  };
  Counts counts() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace hapticpd::viewer
