#include "client/viewer/viewer.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <condition_variable>
#include <mutex>
#include <optional>
#include <thread>

#include "client/viewer/mesh_store.h"
#include "client/viewer/scene_json.h"
#include "hapticpd/v1/scene.grpc.pb.h"
#include "proto/wire/routing.h"
#include "proto/wire/status.h"

namespace hapticpd::viewer {
namespace {

using nlohmann::json;

std::string Dump(const json& j) { return j.dump(-1, ' ', false, json::error_handler_t::replace); }

/// A JSON object's text after its opening brace (HttpServer prepends the
/// browser's own counters).
std::shared_ptr<const std::string> Members(const json& j) {
  std::string s = Dump(j);
  s.erase(0, 1);
  return std::make_shared<const std::string>(std::move(s));
}

}  // namespace

struct Viewer::Impl {
  ViewerOptions opts;
  MeshStore meshes;
  MeshRefs refs;     // the Watch thread's
  SceneModel model;  // the network thread's
  HttpServer http;

  std::thread watcher;
  std::mutex mu;  // guards ctx, stopping (with cv)
  std::condition_variable cv;
  grpc::ClientContext* ctx = nullptr;
  bool stopping = false;
  std::atomic<bool> connected{false};
  std::atomic<std::uint64_t> events{0}, reconnects{0};
  std::atomic<bool> replay_finished{false};

  std::mutex pose_mu;  // the newest pose frame not yet taken by the network thread
  std::optional<json> pending_pose;
  bool pose_posted = false;

  explicit Impl(ViewerOptions o)
      : opts(std::move(o)),
        meshes(opts.display_triangles),
        model(opts.scene_id,
              opts.replay ? "replay of " + opts.replay->input().file : "server " + opts.server),
        http(opts.http,
             HttpServer::Hooks{[this] { return Dump(model.FullScene()); },
                               [this] {
                                 return json{{"server_connected", model.server_connected()},
                                             {"scene_id", opts.scene_id},
                                             {"server", opts.server},
                                             {"source", model.source()},
                                             {"revision", model.revision()},
                                             {"bodies", model.bodies()}};
                               },
                               [this](std::string_view hash) { return meshes.Find(hash); }}) {}

  void PostLink(bool up, const std::string& error) {
    connected = up;
    json msg = LinkJson(up, error);
    http.Post([this, msg = std::move(msg)] {
      model.Apply(msg);
      http.BroadcastReliable(std::make_shared<const std::string>(Dump(msg)));
    });
  }

  /// `linked_now`: the first event of a stream (the snapshot): the link
  /// state changes with the scene, in one step for browsers and /healthz.
  void Handle(const v1::SceneEvent& ev, bool linked_now) {
    json msg = EventToJson(ev, &meshes);
    const std::string type = msg["type"];
    if (type == "scene" || type == "bodies" || type == "sessions") {
      refs.Apply(msg);
      meshes.Retain(refs.hashes());
    }
    if (type == "poses") {
      // Latest only here too: the network thread takes the newest frame.
      std::lock_guard lock(pose_mu);
      pending_pose = std::move(msg);
      if (!pose_posted) {
        pose_posted = true;
        http.Post([this] { DrainPose(); });
      }
    } else if (type == "telemetry") {
      http.Post([this, msg = std::move(msg)] {
        model.Apply(msg);
        http.BroadcastTelemetry(Members(msg));
      });
    } else if (type == "scene") {
      connected = true;
      http.Post([this, msg = std::move(msg), linked_now] {
        if (linked_now) model.Apply(LinkJson(true, ""));
        model.Apply(msg);
        http.ResendScene();  // the whole scene holds the link state
      });
      return;
    } else if (type == "bodies" || type == "sessions") {
      http.Post([this, msg = std::move(msg)] {
        model.Apply(msg);
        http.BroadcastReliable(std::make_shared<const std::string>(Dump(msg)));
      });
    }
    if (linked_now) PostLink(true, "");  // a stream that did not start with a snapshot
  }

  void DrainPose() {
    json msg;
    {
      std::lock_guard lock(pose_mu);
      msg = std::move(*pending_pose);
      pending_pose.reset();
      pose_posted = false;
    }
    model.Apply(msg);
    http.BroadcastPoses(Members(msg));
  }

  /// The replay's opening events (the scene, the session): handled before
  /// the HTTP server starts, so that its first answer already holds them.
  void BeginReplay() {
    std::vector<v1::SceneEvent> evs;
    opts.replay->Begin(&evs);
    bool first = true;
    for (const v1::SceneEvent& ev : evs) {
      events.fetch_add(1, std::memory_order_relaxed);
      Handle(ev, first);
      first = false;
    }
  }

  /// Plays the recording (begun by BeginReplay) at opts.replay_speed, a
  /// pose frame per 1 / rate_hz, until its end (then holds it) or Stop.
  void RunReplay() {
    ReplayPlayer& player = *opts.replay;
    std::vector<v1::SceneEvent> evs;
    spdlog::info("viewer: replaying {} ({:.1f} s, scene '{}')", player.input().file,
                 player.duration_s(), opts.scene_id);
    const auto t0 = std::chrono::steady_clock::now();
    const auto period = std::chrono::duration<double>(1.0 / opts.rate_hz);
    std::unique_lock lock(mu);
    while (!stopping && !player.finished()) {
      lock.unlock();
      const double play =
          opts.replay_speed *
          std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      evs.clear();
      player.AdvanceTo(play, &evs);
      for (const v1::SceneEvent& ev : evs) {
        events.fetch_add(1, std::memory_order_relaxed);
        Handle(ev, false);
      }
      lock.lock();
      cv.wait_for(lock, period, [this] { return stopping; });
    }
    if (player.finished()) {
      replay_finished = true;
      spdlog::info("viewer: the replay of {} ended; the page holds its last frame",
                   player.input().file);
    }
  }

  /// Watch, read until the stream ends, wait, again; until Stop.
  void Run() {
    if (opts.replay) return RunReplay();
    double backoff = opts.reconnect_min_s;
    bool first = true;
    std::string last_error;
    for (;;) {
      grpc::ClientContext call;
      if (!opts.server_token.empty()) {
        call.AddMetadata("authorization", "Bearer " + opts.server_token);
      }
      wire::AddSceneHeader(&call, opts.scene_id);
      {
        std::lock_guard lock(mu);
        if (stopping) return;
        ctx = &call;
      }
      auto stub = v1::SceneService::NewStub(opts.make_channel());
      v1::WatchRequest req;
      req.set_scene_id(opts.scene_id);
      req.set_rate_hz(opts.rate_hz);
      req.set_include_meshes(true);
      req.set_include_contacts(true);  // older servers ignore what they do not know
      req.set_include_telemetry(true);
      auto reader = stub->Watch(&call, req);
      v1::SceneEvent ev;
      bool linked = false;
      while (reader->Read(&ev)) {
        const bool linked_now = !linked;
        if (linked_now) {
          linked = true;
          backoff = opts.reconnect_min_s;
          if (!first) reconnects.fetch_add(1);
          first = false;
          last_error.clear();
          spdlog::info("viewer: watching scene '{}' on {}", opts.scene_id, opts.server);
        }
        events.fetch_add(1, std::memory_order_relaxed);
        Handle(ev, linked_now);
      }
      const grpc::Status status = reader->Finish();
      std::unique_lock lock(mu);
      ctx = nullptr;
      if (stopping) return;
      const std::string error =
          fmt::format("{}: {}", wire::StatusCodeName(status.error_code()), status.error_message());
      if (error != last_error) {
        const bool operator_must_act = status.error_code() == grpc::StatusCode::UNAUTHENTICATED ||
                                       status.error_code() == grpc::StatusCode::PERMISSION_DENIED ||
                                       status.error_code() == grpc::StatusCode::NOT_FOUND ||
                                       status.error_code() == grpc::StatusCode::INVALID_ARGUMENT;
        const auto level = operator_must_act ? spdlog::level::warn : spdlog::level::info;
        spdlog::log(level, "viewer: Watch of scene '{}' on {} ended ({}); retrying", opts.scene_id,
                    opts.server, error);
        last_error = error;
      }
      PostLink(false, error);
      cv.wait_for(lock, std::chrono::duration<double>(backoff), [this] { return stopping; });
      if (stopping) return;
      backoff = std::min(2 * backoff, opts.reconnect_max_s);
    }
  }
};

Viewer::Viewer(ViewerOptions options) : impl_(std::make_unique<Impl>(std::move(options))) {
  if (!impl_->opts.make_channel && !impl_->opts.replay)
    throw ViewerError("viewer: no channel to the server");
  if (!(impl_->opts.rate_hz > 0 && impl_->opts.rate_hz <= 1000)) {
    throw ViewerError("--rate: expected (0, 1000] frames per second");
  }
  if (!(impl_->opts.replay_speed > 0 && impl_->opts.replay_speed <= 100)) {
    throw ViewerError("--speed: expected (0, 100] recorded seconds per second");
  }
}

Viewer::~Viewer() { Stop(); }

void Viewer::Start() {
  if (impl_->opts.replay) impl_->BeginReplay();  // queued for the network thread
  impl_->http.Start();
  impl_->watcher = std::thread([this] { impl_->Run(); });
}

void Viewer::Stop() {
  {
    std::lock_guard lock(impl_->mu);
    if (impl_->stopping) return;
    impl_->stopping = true;
    if (impl_->ctx) impl_->ctx->TryCancel();
  }
  impl_->cv.notify_all();
  if (impl_->watcher.joinable()) impl_->watcher.join();
  impl_->http.Stop();
}

int Viewer::port() const { return impl_->http.port(); }

std::string Viewer::url() const {
  std::string host = impl_->opts.http.listen.substr(0, impl_->opts.http.listen.rfind(':'));
  if (host == "0.0.0.0") host = "127.0.0.1";
  if (host == "::" || host == "[::]") host = "[::1]";
  std::string url = fmt::format("{}://{}:{}/", impl_->http.tls() ? "https" : "http", host, port());
  if (!impl_->opts.http.viewer_token.empty()) {
    url += "?token=" + impl_->opts.http.viewer_token;
  }
  return url;
}

Viewer::Counts Viewer::counts() const {
  Counts c;
  c.server_connected = impl_->connected.load();
  c.events = impl_->events.load();
  c.reconnects = impl_->reconnects.load();
  c.replay_finished = impl_->replay_finished.load();
  c.http = impl_->http.counts();
  return c;
}

}  // namespace hapticpd::viewer
