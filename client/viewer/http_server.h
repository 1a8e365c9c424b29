// The viewer's one port: the page, three.js, meshes by hash, /healthz and
// the WebSocket (/ws), over HTTP or HTTPS (Boost.Beast, one network thread).
// Per browser: the scene first, then reliable messages in order, a
// latest-only pose slot and a bounded queue of telemetry batches; a slow
// browser loses pose frames and whole batches (counted), never the viewer's
// pace or another browser's.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>

namespace hapticpd::viewer {

struct HttpOptions {
  /// HOST:PORT with HOST an IP address or "localhost"; port 0 picks a free one.
  std::string listen = "127.0.0.1:8080";
  /// When set, every HTTP and WebSocket request must present it (query
  /// `token=`, or `Authorization: Bearer`), else 401. Required off loopback.
  std::string viewer_token;
  /// PEM files, both or neither: HTTPS and WSS.
  std::string tls_cert, tls_key;
  std::size_t max_request_bytes = 16 * 1024;     ///< request line + headers + body
  std::size_t max_ws_message_bytes = 64 * 1024;  ///< one browser message
  double telemetry_queue_s = 2;                  ///< a browser further behind loses whole batches
  /// Reliable messages (structure changes) one browser may have queued
  /// before they are replaced by one whole scene when it catches up.
  std::size_t max_reliable_bytes = 32u << 20;
};

/// Thrown by HttpServer's constructor and Start for unusable options.
struct ViewerError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

/// Whether `listen`'s host is a loopback address; throws ViewerError when
/// it is not HOST:PORT.
bool IsLoopbackListen(const std::string& listen);

class HttpServer {
 public:
  /// What the server asks of its owner, always on the network thread
  /// (except `mesh`, called there too but thread-safe by contract).
  struct Hooks {
    std::function<std::string()> full_scene;  ///< the whole scene, a "scene" message
    std::function<nlohmann::json()> health;   ///< GET /healthz's fields
    std::function<std::shared_ptr<const std::string>(std::string_view hash)> mesh;
  };

  /// Checks the options (ViewerError: a non-loopback listen without a
  /// viewer token, one TLS file without the other, unreadable PEM files).
  HttpServer(HttpOptions options, Hooks hooks);
  ~HttpServer();
  HttpServer(const HttpServer&) = delete;
  HttpServer& operator=(const HttpServer&) = delete;

  /// Binds and starts the network thread (ViewerError when it cannot bind).
  void Start();
  /// Closes every connection and joins the thread. Idempotent.
  void Stop();
  int port() const;
  bool tls() const;

  /// Runs `fn` on the network thread, after everything posted before it.
  void Post(std::function<void()> fn);

  // Network thread only (inside Post):
  /// A message every browser gets, in order (structure, link state).
  void BroadcastReliable(std::shared_ptr<const std::string> msg);
  /// Every browser gets the whole scene (Hooks::full_scene) next, in place
  /// of anything reliable still queued (after a reconnect to the server).
  void ResendScene();
  /// A pose frame: a JSON object's members after its `{` (the server adds
  /// the browser's own counters in front). Latest-only per browser.
  void BroadcastPoses(std::shared_ptr<const std::string> members);
  /// A telemetry batch, in the same form; queued per browser up to
  /// telemetry_queue_s, older batches dropped whole.
  void BroadcastTelemetry(std::shared_ptr<const std::string> members);
  int browsers() const;

  /// Counters, readable from any thread.
  struct Counts {
    std::uint64_t ws_connects = 0;        ///< WebSocket handshakes accepted
    std::uint64_t poses_dropped = 0;      ///< pose frames replaced before sent
    std::uint64_t telemetry_dropped = 0;  ///< telemetry batches dropped
    std::uint64_t scene_resends = 0;      ///< reliable queues replaced by a scene
    std::uint64_t requests = 0;           ///< HTTP requests answered
    std::uint64_t rejected = 0;           ///< answered 4xx (bad input, token)
    std::uint64_t ws_messages_bad = 0;    ///< browser messages answered with an error
    int browsers = 0;
  };
  Counts counts() const;

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace hapticpd::viewer
