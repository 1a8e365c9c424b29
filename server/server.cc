#include "server/server.h"

#include <fmt/format.h>
#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>
#include <grpcpp/security/server_credentials.h>

#include <netdb.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>

#include "proto/wire/text.h"
#include "server/convert.h"
#include "server/core.h"
#include "server/observers.h"
#include "server/scene_file.h"
#include "server/services.h"
#include "server/store.h"

namespace hapticpd::server {

using internal::Log;

std::string DefaultStateDir() {
  if (const char* x = std::getenv("XDG_STATE_HOME"); x != nullptr && x[0] == '/') {
    return (std::filesystem::path(x) / "hapticpd").string();
  }
  if (const char* h = std::getenv("HOME"); h != nullptr && h[0] != 0) {
    return (std::filesystem::path(h) / ".local" / "state" / "hapticpd").string();
  }
  return "";
}

namespace {

std::string ReadFile(const std::string& path, const char* what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot open " + what);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// A --listen address split at its last colon: HOST (an [IPv6] host without
// its brackets) and PORT (empty when there is no colon).
struct ListenAddress {
  std::string host, port;
  bool bracketed = false;
};

ListenAddress SplitListen(const std::string& listen) {
  const std::size_t colon = listen.rfind(':');
  ListenAddress a{listen.substr(0, colon),
                  colon == std::string::npos ? "" : listen.substr(colon + 1)};
  a.bracketed = a.host.size() >= 2 && a.host.front() == '[' && a.host.back() == ']';
  if (a.bracketed) a.host = a.host.substr(1, a.host.size() - 2);
  return a;
}

bool IsLoopback(const std::string& listen) {
  const std::string host = SplitListen(listen).host;
  return host == "localhost" || host.rfind("127.", 0) == 0 || host == "::1";
}

/// Health: the whole server ("") and each service by its full name, as
/// gRPC health clients and load balancers ask.
void SetServing(grpc::Server* server, bool serving) {
  grpc::HealthCheckServiceInterface* health = server->GetHealthCheckService();
  health->SetServingStatus(serving);
  for (const char* name : {"hapticpd.v1.SceneService", "hapticpd.v1.HapticService"}) {
    health->SetServingStatus(name, serving);
  }
}

// Throws when `listen` (HOST:PORT) names a port out of range, or when a
// plain socket cannot bind it because the port is in use or needs
// privileges. gRPC reports that only as a multi-line log record before
// BuildAndStart fails; this check names the problem first. The socket is
// closed at once (a race with another process is left to gRPC's own
// failure). Addresses gRPC resolves itself (unix:, dns:, ...) and hosts
// that do not resolve here are left to gRPC.
void CheckListenAddress(const std::string& listen) {
  const auto [host, port, bracketed] = SplitListen(listen);
  if (port.empty() || port.find_first_not_of("0123456789") != std::string::npos) return;
  // gRPC would take a larger number modulo 65536 and listen on another port.
  const unsigned long long number = port.size() > 18 ? ~0ULL : std::stoull(port);
  if (number > 65535) {
    throw std::runtime_error("cannot listen on " + listen + ": port " + port +
                             " is out of range (1-65535, or 0 for any free port)");
  }
  if (number == 0) return;
  if (host.find(':') != std::string::npos && !bracketed) return;  // IPv6 needs [ ]
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_PASSIVE | AI_NUMERICSERV;
  addrinfo* found = nullptr;
  if (getaddrinfo(host.empty() ? nullptr : host.c_str(), port.c_str(), &hints, &found) != 0) return;
  int error = 0;
  for (const addrinfo* a = found; a != nullptr && error == 0; a = a->ai_next) {
    const int fd = socket(a->ai_family, a->ai_socktype, a->ai_protocol);
    if (fd < 0) continue;
    const int one = 1;
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (bind(fd, a->ai_addr, a->ai_addrlen) != 0 && (errno == EADDRINUSE || errno == EACCES)) {
      error = errno;
    }
    close(fd);
  }
  freeaddrinfo(found);
  if (error == EADDRINUSE) {
    throw std::runtime_error("cannot listen on " + listen +
                             ": address already in use (is another server running on that port?)");
  }
  if (error == EACCES) {
    throw std::runtime_error("cannot listen on " + listen +
                             ": permission denied (ports below 1024 need privileges)");
  }
}

}  // namespace

struct HapticServer::Impl {
  explicit Impl(ServerOptions o) : options(std::move(o)), core(options.limits) {}

  ServerOptions options;
  internal::Core core;
  std::unique_ptr<internal::ObserverPublishers> publishers;
  std::unique_ptr<internal::SceneServiceImpl> scene_service;
  std::unique_ptr<internal::HapticServiceImpl> haptic_service;
  std::unique_ptr<grpc::Server> server;
  int port = 0;
  std::mutex mu;
  std::condition_variable cv;
  bool started = false;
  bool shut_down = false;
  bool shutting = false;
  std::thread status_thread;

  void LoadSceneFile(const std::string& path, const std::set<std::string>& restored);
  std::set<std::string> RestoreState();
  void CommitScenes(const std::set<std::string>& restored);
  void StatusLoop();
};

std::set<std::string> HapticServer::Impl::RestoreState() {
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  core.store = SceneStore::Open(options.state_dir, options.state_max_bytes);
  core.store->before_commit = options.store_before_commit;
  StoredState st = core.store->Load(UnixNow() - std::chrono::seconds(RequestLog::kTtl).count());
  std::set<std::string> restored;
  std::size_t bodies = 0;
  const std::string file = core.store->db_path().string();
  std::size_t skipped = 0;
  for (StoredScene& sc : st.scenes) {
    if (auto s = core.CheckOwner(sc.id); !s.ok()) {
      // Kept in the file, not served: the map gives it to another process.
      Log()->warn("state directory {}: scene '{}' not served: {}", options.state_dir, sc.id,
                  s.error_message());
      ++skipped;
      continue;
    }
    ScenePtr scene;
    // The store wins over today's limits: what was acknowledged is served.
    auto s = core.scenes.Create(sc.id, sc.description, sc.config,
                                std::numeric_limits<std::size_t>::max(), &scene, {});
    if (!s.ok()) throw StoreError(file + ": scene '" + sc.id + "': " + s.error_message());
    for (StoredBody& b : sc.bodies) {
      BodyState body;
      body.uid = core.scenes.NextBodyUid();
      body.id = b.id;
      body.label = b.label;
      body.X_WB = b.X_WB;
      body.v_W = b.v_W;
      body.w_W = b.w_W;
      body.material = b.material;
      body.movable = b.movable;
      try {
        body.model = pd::MakeModel(
            pd::Mesh::FromArrays(std::move(b.vertices), std::move(b.triangles), b.id));
      } catch (const pd::MeshError& e) {
        throw StoreError(file + ": the database is corrupt (body '" + b.id + "' of scene '" +
                         sc.id + "': " + e.what() + ")");
      }
      s = scene->AddBody(std::move(body), std::numeric_limits<std::size_t>::max(), nullptr, "id");
      if (!s.ok()) throw StoreError(file + ": scene '" + sc.id + "': " + s.error_message());
      ++bodies;
    }
    scene->set_next_body_number(sc.next_body_number);
    restored.insert(sc.id);
  }
  core.requests = std::make_unique<RequestLog>(core.store.get());
  core.requests->Load(st.requests);
  Log()->info("state directory {}: {} scenes, {} bodies, {} request ids loaded in {:.0f} ms",
              options.state_dir, st.scenes.size() - skipped, bodies, st.requests.size(),
              std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
  return restored;
}

void HapticServer::Impl::CommitScenes(const std::set<std::string>& restored) {
  if (!core.store) return;
  // The scenes of scene files and "default", in one transaction: a crash
  // during start-up leaves none of them half-written.
  // What to write is read first: the store's lock is never held while the
  // registry's or a scene's is taken (the mutations take them the other way
  // round).
  struct Pending {
    ScenePtr scene;
    v1::SceneConfig config;
    std::uint64_t next_body_number;
    SnapshotPtr snapshot;
  };
  std::vector<Pending> pending;
  for (const ScenePtr& scene : core.scenes.List()) {
    if (restored.count(scene->id())) continue;
    pending.push_back({scene, scene->config(), scene->next_body_number(), scene->snapshot()});
  }
  const grpc::Status s = core.store->Write([&](SceneStore::Txn& t) {
    for (const Pending& p : pending) {
      t.PutScene(p.scene->id(), p.scene->description(), p.config, p.next_body_number);
      for (const BodyState& b : p.snapshot->bodies) t.PutBody(p.scene->id(), b);
    }
  });
  if (!s.ok()) throw StoreError(s.error_message());
}

void HapticServer::Impl::LoadSceneFile(const std::string& path,
                                       const std::set<std::string>& restored) {
  // Throws "FILE: KEY: problem".
  const SceneFile f = ParseSceneFile(path, core.limits.max_mesh_triangles);
  if (restored.count(f.scene_id)) {
    Log()->info("scene '{}' of {} not loaded: the state directory holds that scene", f.scene_id,
                path);
    return;
  }
  if (core.shards && core.shards->Owner(f.scene_id) != core.shard) {
    Log()->info("scene '{}' of {} not loaded: shard '{}' does not own it", f.scene_id, path,
                core.shard);
    return;
  }
  try {
    const std::string& id = f.scene_id;
    if (auto s = ValidateId(id, "scene"); !s.ok()) throw std::runtime_error(s.error_message());
    ScenePtr scene = core.scenes.Get(id);
    if (!scene) {
      auto s = core.scenes.Create(id, f.description, core.limits.max_scenes, &scene);
      if (!s.ok()) throw std::runtime_error(s.error_message());
    }
    scene->set_config(f.config);
    int i = 0;
    for (const SceneFileBody& b : f.bodies) {
      const std::string where = "bodies[" + std::to_string(i++) + "]";
      std::optional<pd::Mesh> mesh;
      grpc::Status s;
      if (!b.mesh_path.empty()) {
        try {
          mesh = pd::LoadMesh(b.mesh_path);
        } catch (const pd::MeshError& e) {
          throw std::runtime_error(where + ".mesh: " + e.what());
        }
        s = wire::CheckMeshRanges(*mesh, where + ".mesh");
      } else {
        s = MeshFromShape(b.shape, where + ".shape", core.limits.max_mesh_triangles, &mesh);
      }
      BodyState body;
      if (s.ok()) s = internal::MakeBody(&core, b.spec, where, std::move(*mesh), &body);
      if (s.ok())
        s = scene->AddBody(std::move(body), core.limits.max_bodies_per_scene, nullptr,
                           where + ".id");
      if (!s.ok()) throw std::runtime_error(s.error_message());
    }
    Log()->info("scene '{}' loaded from {} ({} bodies)", id, path,
                scene->snapshot()->bodies.size());
  } catch (const std::runtime_error& e) {
    throw std::runtime_error(path + ": " + e.what());
  }
}

void HapticServer::Impl::StatusLoop() {
  using namespace std::chrono;
  const auto interval = duration<double>(options.status_interval_s);
  std::uint64_t last_updates = core.stats.updates_sent.load();
  std::uint64_t last_dropped = core.stats.observer_frames_dropped.load();
  auto last = steady_clock::now();
  std::unique_lock lock(mu);
  for (;;) {
    if (cv.wait_for(lock, interval, [&] { return shutting; })) return;
    const auto now = steady_clock::now();
    const double dt = duration<double>(now - last).count();
    const std::uint64_t updates = core.stats.updates_sent.load();
    const std::uint64_t dropped = core.stats.observer_frames_dropped.load();
    const auto hist = core.stats.compute_us.Drain();
    Log()->info(
        "status: {} sessions, {:.0f} updates/s, PD p50 {:.0f} us p99 {:.0f} us, {} observers "
        "({} frames dropped), {} scenes",
        core.sessions.load(), static_cast<double>(updates - last_updates) / dt,
        internal::LatencyHistogram::Quantile(hist, 0.5),
        internal::LatencyHistogram::Quantile(hist, 0.99), core.observers.load(),
        dropped - last_dropped, core.scenes.List().size());
    last_updates = updates;
    last_dropped = dropped;
    last = now;
  }
}

HapticServer::HapticServer(ServerOptions options)
    : impl_(std::make_unique<Impl>(std::move(options))) {}

HapticServer::~HapticServer() { Shutdown(); }

void HapticServer::Start() {
  Impl& m = *impl_;
  const ServerOptions& o = m.options;
  if (!o.tokens_file.empty()) {
    m.core.tokens = TokenStore::FromFile(o.tokens_file);
  } else if (!o.listen.empty() && !IsLoopback(o.listen)) {
    throw std::runtime_error("refusing to listen on " + o.listen +
                             " without --tokens: an open server (no authentication) listens on "
                             "loopback only (127.0.0.1, ::1, localhost)");
  }
  if (o.tls_cert.empty() != o.tls_key.empty()) {
    throw std::runtime_error("TLS needs both --tls-cert and --tls-key");
  }
  if (o.shard_map_file.empty() != o.shard.empty()) {
    throw std::runtime_error("sharding needs both --shard-map FILE and --shard NAME");
  }
  if (!o.shard_map_file.empty()) {
    auto map = std::make_unique<ShardMap>(ShardMap::Load(o.shard_map_file));
    if (!map->HasShard(o.shard)) {
      throw ShardMapError(fmt::format("{}: no line names shard '{}' (--shard); it names: {}",
                                      o.shard_map_file, wire::Printable(o.shard),
                                      fmt::join(map->shards(), ", ")));
    }
    m.core.shards = std::move(map);
    m.core.shard = o.shard;
  }
  if (!o.listen.empty()) CheckListenAddress(o.listen);
  // Bound before the state is loaded, so that health checks see
  // NOT_SERVING (and every call UNAVAILABLE) until it is.
  m.core.loading.store(true);
  m.core.before_build = o.before_build;
  m.publishers = std::make_unique<internal::ObserverPublishers>();
  m.core.publishers = m.publishers.get();
  m.scene_service = std::make_unique<internal::SceneServiceImpl>(&m.core);
  m.haptic_service = std::make_unique<internal::HapticServiceImpl>(&m.core);

  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  builder.SetMaxReceiveMessageSize(o.limits.max_message_bytes);
  // Keepalive: a frozen client or a half-open connection stops answering
  // pings, and the connection and its calls (and their slots) go. Clients
  // may ping every 5 s without data; more often is a strike (2 allowed).
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIME_MS,
                             static_cast<int>(o.limits.keepalive_time_s * 1000));
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIMEOUT_MS,
                             static_cast<int>(o.limits.keepalive_timeout_s * 1000));
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_PERMIT_WITHOUT_CALLS, 1);
  builder.AddChannelArgument(GRPC_ARG_HTTP2_MAX_PINGS_WITHOUT_DATA, 0);
  builder.AddChannelArgument(GRPC_ARG_HTTP2_MIN_RECV_PING_INTERVAL_WITHOUT_DATA_MS, 5000);
  builder.AddChannelArgument(GRPC_ARG_HTTP2_MAX_PING_STRIKES, 2);
  builder.SetMaxSendMessageSize(std::max(o.limits.max_message_bytes, 64 << 20));
  // gRPC binds with SO_REUSEPORT by default: a second server on a port in
  // use would start and share the connections with the first. Refuse it.
  builder.AddChannelArgument(GRPC_ARG_ALLOW_REUSEPORT, 0);
  std::string mode = "in-process only";
  if (!o.listen.empty()) {
    std::shared_ptr<grpc::ServerCredentials> creds;
    if (!o.tls_cert.empty()) {
      grpc::SslServerCredentialsOptions ssl;
      ssl.pem_key_cert_pairs.push_back(
          {ReadFile(o.tls_key, "TLS key"), ReadFile(o.tls_cert, "TLS certificate")});
      creds = grpc::SslServerCredentials(ssl);
      mode = "TLS";
    } else {
      creds = grpc::InsecureServerCredentials();
      mode = "plaintext";
    }
    builder.AddListeningPort(o.listen, creds, &m.port);
  }
  builder.RegisterService(m.scene_service.get());
  builder.RegisterService(m.haptic_service.get());
  // gRPC's threads may predate this server (they serve every server in the
  // process): the handlers take the services over (ServiceCall in core.h).
  internal::GrpcHandOff(m.scene_service.get());
  internal::GrpcHandOff(m.haptic_service.get());
  m.server = builder.BuildAndStart();
  if (!m.server || (!o.listen.empty() && m.port == 0)) {
    m.core.builds.Stop();
    m.publishers->Stop();
    throw std::runtime_error("cannot listen on " + o.listen +
                             " (address in use or invalid HOST:PORT?)");
  }
  SetServing(m.server.get(), false);
  try {
    if (o.while_loading) o.while_loading(m.port);
    // The store first: it wins over scene files, and "default" is created
    // only when it holds no scene.
    std::set<std::string> restored;
    if (!o.state_dir.empty()) {
      restored = m.RestoreState();
    } else {
      m.core.requests = std::make_unique<RequestLog>(nullptr);
    }
    for (const auto& f : o.scene_files) m.LoadSceneFile(f, restored);
    if (o.scene_files.empty() && restored.empty() && !m.core.shards) {
      auto s =
          m.core.scenes.Create("default", "the default scene", m.core.limits.max_scenes, nullptr);
      if (!s.ok()) throw std::runtime_error(s.error_message());
    }
    m.CommitScenes(restored);
  } catch (...) {
    // Nothing was served: end the calls refused meanwhile and stop.
    m.server->Shutdown(std::chrono::system_clock::now());
    m.server->Wait();
    internal::GrpcTakeOver(internal::ServiceDoneKey(m.scene_service.get()));
    internal::GrpcTakeOver(internal::ServiceDoneKey(m.haptic_service.get()));
    m.core.builds.Stop();
    m.publishers->Stop();
    throw;
  }
  m.core.loading.store(false);
  SetServing(m.server.get(), true);
  {
    std::lock_guard lock(m.mu);
    m.started = true;
  }
  if (o.listen.empty()) {
    Log()->info("serving in-process");
  } else {
    const std::string host = o.listen.substr(0, o.listen.rfind(':'));
    Log()->info("listening on {}:{} ({})", host, m.port, mode);
  }
  if (m.core.tokens.open()) {
    Log()->info("no token file: running open (no authentication), loopback only");
  } else {
    Log()->info("{} tokens loaded from {}", m.core.tokens.size(), o.tokens_file);
  }
  if (o.status_interval_s > 0) m.status_thread = std::thread([&m] { m.StatusLoop(); });
}

int HapticServer::port() const { return impl_->port; }

std::shared_ptr<grpc::Channel> HapticServer::InProcessChannel() {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);
  return impl_->server->InProcessChannel(args);
}

void HapticServer::Shutdown() {
  Impl& m = *impl_;
  {
    std::unique_lock lock(m.mu);
    if (!m.started) {
      m.shut_down = true;
      m.cv.notify_all();
      return;
    }
    if (m.shutting) {
      m.cv.wait(lock, [&] { return m.shut_down; });
      return;
    }
    m.shutting = true;
  }
  m.cv.notify_all();
  Log()->info("shutting down: {} sessions, {} observers", m.core.sessions.load(),
              m.core.observers.load());
  m.core.shutting_down.store(true);
  SetServing(m.server.get(), false);
  m.core.StopCalls(nullptr, m.core.Unavailable());
  const auto grace = std::chrono::milliseconds(
      static_cast<std::int64_t>(std::max(0.0, m.options.shutdown_grace_s) * 1000));
  // Streams that finish within the grace period end cleanly; the rest are cancelled.
  m.server->Shutdown(std::chrono::system_clock::now() + grace);
  m.core.builds.Stop();
  if (!m.core.WaitNoCalls(std::chrono::seconds(10))) {
    Log()->error("shutdown: {} calls still active after 10 s", m.core.active_calls());
  }
  m.server->Wait();
  // Every handler has returned (see ServiceCall).
  internal::GrpcTakeOver(internal::ServiceDoneKey(m.scene_service.get()));
  internal::GrpcTakeOver(internal::ServiceDoneKey(m.haptic_service.get()));
  m.publishers->Stop();
  if (m.status_thread.joinable()) m.status_thread.join();
  // Writes the queued poses and lets go of the state directory.
  m.core.requests.reset();
  m.core.store.reset();
  {
    std::lock_guard lock(m.mu);
    m.shut_down = true;
  }
  m.cv.notify_all();
  Log()->info("server stopped");
}

void HapticServer::Wait() {
  std::unique_lock lock(impl_->mu);
  impl_->cv.wait(lock, [&] { return impl_->shut_down; });
}

HapticServer::Counts HapticServer::counts() const {
  const Impl& m = *impl_;
  Counts c;
  c.scenes = static_cast<int>(m.core.scenes.List().size());
  c.sessions = m.core.sessions.load();
  c.observers = m.core.observers.load();
  c.publishers = m.publishers ? m.publishers->running() : 0;
  c.active_calls = m.core.active_calls();
  c.updates_sent = m.core.stats.updates_sent.load();
  c.patches_sent = m.core.stats.patches_sent.load();
  c.patch_bytes = m.core.stats.patch_bytes.load();
  c.observer_frames_sent = m.core.stats.observer_frames_sent.load();
  c.observer_frames_dropped = m.core.stats.observer_frames_dropped.load();
  c.pd_calls = m.core.stats.pd_calls.load();
  c.torque_skipped = m.core.stats.torque_skipped.load();
  c.updates_withheld = m.core.stats.updates_withheld.load();
  c.sessions_idle_ended = m.core.stats.sessions_idle_ended.load();
  c.observers_stalled = m.core.stats.observers_stalled.load();
  return c;
}

}  // namespace hapticpd::server
