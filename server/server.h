// The hapticpd gRPC server: SceneService and HapticService on the callback
// API, gRPC health checking and server reflection. The library's one public
// header: a program that runs a server (`hapticpd serve`, `demo`, `bench
// delay`) needs this and nothing else of server/; what the client shares
// with the server (conversions, the scene-file format) is in proto/wire/.
//
//   HapticServer server(options);
//   server.Start();                 // throws std::runtime_error (bind, TLS, files)
//   ... server.port() ...
//   server.Shutdown();              // bounded; also from the destructor
#pragma once

#include <grpcpp/channel.h>

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace hapticpd::server {

/// Server limits; going over one of the counts gives RESOURCE_EXHAUSTED.
struct Limits {
  std::size_t max_mesh_triangles = 2'000'000;
  std::size_t max_mesh_bytes = 256u << 20;  ///< per uploaded mesh file
  std::size_t max_bodies_per_scene = 256;
  std::size_t max_scenes = 64;
  int max_sessions = 16;
  int max_observers = 64;
  int max_message_bytes = 8 << 20;  ///< per received gRPC message

  /// A ContactUpdate whose force (N) or torque (N m) is larger than these,
  /// or that holds a non-finite number, is replaced before it is sent by
  /// one with zero force and no rows (CONTACT_STATUS_WITHHELD).
  double max_update_force = 1e4;
  double max_update_torque = 1e3;

  /// Most triangles of one body a device session's client holds through
  /// its geometry patches (PatchRequest.max_triangles_per_body is cut to
  /// it): bounds the patches' size and the client's memory.
  std::size_t max_patch_triangles = 8192;

  /// A device session that sends no message for this long (counted from
  /// its last message or the server's last answer, whichever is later, so
  /// a slow answer does not count against the client) ends with
  /// DEADLINE_EXCEEDED, and an observer whose write has not completed for
  /// this long is cancelled: either frees its slot. Behind a load balancer
  /// (where keepalive pings stop at the balancer) this is what frees the
  /// slot of a frozen client. <= 0 disables it.
  double idle_timeout_s = 20;
  /// HTTP/2 keepalive: the server pings each connection after this long
  /// without a ping and drops the connection (cancelling its calls) when
  /// the ping is not answered within keepalive_timeout_s. Clients may ping
  /// at most every 5 s without data.
  double keepalive_time_s = 10;
  double keepalive_timeout_s = 10;

  /// Mesh parsing and BVH builds (AddBody) run on this many threads; one
  /// client (token, or peer address on an open server) has at most
  /// max_builds_per_client of them at a time, so a large upload never
  /// holds up another client's small one.
  int build_threads = 2;
  int max_builds_per_client = 1;
};

struct ServerOptions {
  /// HOST:PORT; port 0 picks a free port (see HapticServer::port()). Empty:
  /// in-process only (InProcessChannel).
  std::string listen = "127.0.0.1:50051";
  /// Token file (server/auth.h). Without one the server runs open and
  /// refuses any non-loopback listen address.
  std::string tokens_file;
  /// PEM files; both or neither.
  std::string tls_cert;
  std::string tls_key;
  /// Scene files (JSON) preloaded at start; without any, one empty scene
  /// named "default" is created (not when sharded).
  std::vector<std::string> scene_files;
  /// Sharded (docker/README.md "Scaling out"): the shard map file
  /// (server/shard_map.h) and this process's name in it; both or neither.
  /// A sharded server creates, restores and preloads only the scenes the map
  /// gives it (CreateScene of another's: FAILED_PRECONDITION naming the
  /// owner) and has no "default" scene.
  std::string shard_map_file;
  std::string shard;
  Limits limits;
  /// State directory (server/README.md "State directory"): scenes, bodies,
  /// poses, materials, configs and request ids are kept in DIR/scenes.db and
  /// served again after a restart. Empty (the default here, so that servers
  /// inside other programs and tests never write to disk): memory only.
  /// `hapticpd serve` defaults to DefaultStateDir().
  std::string state_dir;
  /// > 0: the database may grow to about this many bytes; beyond it a
  /// mutation fails as on a full disk (UNAVAILABLE), nothing changes.
  std::int64_t state_max_bytes = 0;
  /// Tests only: called before each commit to the state store; a non-zero
  /// SQLite result code makes the commit fail as that error would.
  std::function<int()> store_before_commit;
  /// Seconds between one-line status logs; <= 0 disables them.
  double status_interval_s = 10;
  /// Seconds streams get to finish at shutdown before they are cancelled.
  double shutdown_grace_s = 2;
  /// Tests only: called on a build thread before each AddBody build, with
  /// the body's label (lets a test order builds without timing).
  std::function<void(const std::string& label)> before_build;
  /// Tests only: called by Start once the port is bound, before the state
  /// store and scene files are loaded (health NOT_SERVING, calls refused),
  /// with the bound port (0 in-process).
  std::function<void(int port)> while_loading;

  /// A server inside another program (the demo, benchmarks): loopback on a
  /// free port, no periodic status line, a short shutdown grace.
  static ServerOptions InProcess() {
    ServerOptions o;
    o.listen = "127.0.0.1:0";
    o.status_interval_s = 0;
    o.shutdown_grace_s = 0.5;
    return o;
  }
};

class HapticServer {
 public:
  explicit HapticServer(ServerOptions options);
  ~HapticServer();
  HapticServer(const HapticServer&) = delete;
  HapticServer& operator=(const HapticServer&) = delete;

  /// Loads tokens and scenes, binds and starts serving.
  void Start();
  /// The bound TCP port (0 when listening in-process only).
  int port() const;
  /// A channel to this server that bypasses the network stack. It must not
  /// be used once Shutdown() has begun (gRPC's in-process transport crashes).
  std::shared_ptr<grpc::Channel> InProcessChannel();
  /// Health NOT_SERVING, tells every session and observer (UNAVAILABLE),
  /// waits up to shutdown_grace_s for streams to finish, cancels the rest.
  /// Idempotent and thread-safe.
  void Shutdown();
  /// Blocks until Shutdown() has completed.
  void Wait();

  /// Current counts, for tests and the status line.
  struct Counts {
    int scenes = 0;
    int sessions = 0;
    int observers = 0;
    int active_calls = 0;  ///< streaming reactors not yet done
    int publishers = 0;    ///< per-scene observer publisher threads running
    std::uint64_t updates_sent = 0;
    std::uint64_t patches_sent = 0;  ///< geometry patches written to device sessions
    std::uint64_t patch_bytes = 0;   ///< their serialized size
    std::uint64_t observer_frames_sent = 0;
    std::uint64_t observer_frames_dropped = 0;
    std::uint64_t pd_calls = 0;             ///< PD queries run by device sessions
    std::uint64_t torque_skipped = 0;       ///< answers without torque (scene declares none)
    std::uint64_t updates_withheld = 0;     ///< answers sent as CONTACT_STATUS_WITHHELD
    std::uint64_t sessions_idle_ended = 0;  ///< device sessions ended by the idle timeout
    std::uint64_t observers_stalled = 0;    ///< observers cancelled for a write stuck that long
  };
  Counts counts() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// `hapticpd serve`'s state directory when --state is not given:
/// $XDG_STATE_HOME/hapticpd, else $HOME/.local/state/hapticpd (empty when
/// neither variable is set).
std::string DefaultStateDir();

}  // namespace hapticpd::server
