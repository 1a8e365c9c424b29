// `hapticpd serve`: run the haptic rendering server until SIGINT/SIGTERM.
#include <pthread.h>
#include <signal.h>
#include <spdlog/spdlog.h>

#include <cstdlib>
#include <iostream>
#include <thread>

#include "client/commands.h"
#include "server/server.h"

namespace hapticpd::cli {
namespace {

struct ServeOptions {
  server::ServerOptions server;
  std::string log_level = "info";
  std::string state;
  bool ephemeral = false;
};

void RunServe(const ServeOptions& o) {
  const auto level = spdlog::level::from_str(o.log_level);
  if (level == spdlog::level::off && o.log_level != "off") {
    throw CommandError("serve: --log-level: unknown level '" + o.log_level + "'");
  }
  spdlog::set_level(level);
  ServeOptions opts = o;
  if (o.ephemeral) {
    if (!o.state.empty()) throw CommandError("serve: give --state DIR or --ephemeral, not both");
    opts.server.state_dir.clear();
  } else {
    opts.server.state_dir = o.state.empty() ? server::DefaultStateDir() : o.state;
    if (opts.server.state_dir.empty()) {
      throw CommandError(
          "serve: no state directory: neither XDG_STATE_HOME nor HOME is set; give --state DIR "
          "or --ephemeral");
    }
  }
  // Block the signals in every thread (gRPC's inherit the mask) and take
  // them synchronously below.
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGINT);
  sigaddset(&set, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &set, nullptr);
  server::HapticServer srv(opts.server);
  try {
    srv.Start();
  } catch (const std::exception& e) {
    throw CommandError(std::string("serve: ") + e.what());
  }
  int sig = 0;
  sigwait(&set, &sig);
  spdlog::info("received {}, shutting down", sig == SIGINT ? "SIGINT" : "SIGTERM");
  // A second signal during shutdown exits at once.
  std::thread second([&set] {
    int s2 = 0;
    sigwait(&set, &s2);
    std::_Exit(130);
  });
  second.detach();
  srv.Shutdown();
}

}  // namespace

void RegisterServe(CLI::App& app) {
  auto o = std::make_shared<ServeOptions>();
  auto* cmd = app.add_subcommand("serve", "Run the haptic rendering server (gRPC)");
  auto& s = o->server;
  cmd->add_option("--listen", s.listen, "HOST:PORT to listen on (port 0: any free port)")
      ->capture_default_str();
  cmd->add_option("--tokens", s.tokens_file,
                  "Token file (JSON) mapping tokens to roles per scene; without one the server "
                  "runs open and only on loopback");
  cmd->add_option("--tls-cert", s.tls_cert, "PEM certificate chain: serve over TLS")
      ->check(CLI::ExistingFile);
  cmd->add_option("--tls-key", s.tls_key, "PEM private key for --tls-cert")
      ->check(CLI::ExistingFile);
  cmd->add_option("--scene", s.scene_files,
                  "Scene file (JSON: bodies, probe, PD mode, effects; README \"Scene files "
                  "and effects\") to preload; repeatable. A scene the state directory holds is "
                  "not loaded again. Without one (and an empty state directory): an empty scene "
                  "'default'")
      ->check(CLI::ExistingFile);
  cmd->add_option("--shard-map", s.shard_map_file,
                  "Shard map (lines 'PREFIX SHARD', the file HAProxy routes by; docker/README.md "
                  "\"Scaling out\"): with --shard, this process creates, restores and preloads "
                  "only the scenes whose longest matching prefix names it, and has no 'default' "
                  "scene")
      ->check(CLI::ExistingFile);
  cmd->add_option("--shard", s.shard, "This process's name in --shard-map");
  cmd->add_option("--state", o->state,
                  "State directory: scenes, bodies (meshes included), poses, materials, configs "
                  "and request ids are kept there (SQLite, DIR/scenes.db) and served again after "
                  "a restart; structural changes are on disk before they are acknowledged, "
                  "poses within 100 ms. One server per directory. Default: "
                  "$XDG_STATE_HOME/hapticpd, else ~/.local/state/hapticpd");
  cmd->add_flag("--ephemeral", o->ephemeral,
                "Keep everything in memory only (nothing survives the process)");
  cmd->add_option("--status-interval", s.status_interval_s,
                  "Seconds between status lines (0: none)")
      ->capture_default_str();
  cmd->add_option("--max-sessions", s.limits.max_sessions, "Device sessions at most")
      ->capture_default_str();
  cmd->add_option("--max-observers", s.limits.max_observers, "Observers at most")
      ->capture_default_str();
  cmd->add_option("--max-bodies", s.limits.max_bodies_per_scene, "Bodies per scene at most")
      ->capture_default_str();
  cmd->add_option("--max-scenes", s.limits.max_scenes, "Scenes at most")->capture_default_str();
  cmd->add_option("--max-triangles", s.limits.max_mesh_triangles, "Triangles per mesh at most")
      ->capture_default_str();
  cmd->add_option("--max-mesh-bytes", s.limits.max_mesh_bytes, "Bytes per uploaded mesh file")
      ->capture_default_str();
  cmd->add_option("--max-message-bytes", s.limits.max_message_bytes,
                  "Bytes per received gRPC message")
      ->capture_default_str();
  cmd->add_option("--max-update-force", s.limits.max_update_force,
                  "N: an answer with a larger force (or a non-finite number) is withheld: sent "
                  "as zero force and no rows (CONTACT_STATUS_WITHHELD)")
      ->check(CLI::Range(1e-3, 1e9))
      ->capture_default_str();
  cmd->add_option("--max-update-torque", s.limits.max_update_torque, "N m: likewise for the torque")
      ->check(CLI::Range(1e-3, 1e9))
      ->capture_default_str();
  cmd->add_option("--max-patch-triangles", s.limits.max_patch_triangles,
                  "Triangles of one body a device session's geometry patches hold at most "
                  "(a client asking for more gets this many)")
      ->check(CLI::Range(std::size_t{1}, std::size_t{1} << 22))
      ->capture_default_str();
  cmd->add_option("--idle-timeout", s.limits.idle_timeout_s,
                  "Seconds: a device session that sends nothing for this long after its last "
                  "message or the server's last answer, or an observer whose write has not "
                  "completed for this long, is ended (0: never)")
      ->check(CLI::Range(0.0, 86400.0))
      ->capture_default_str();
  cmd->add_option("--keepalive", s.limits.keepalive_time_s,
                  "Seconds between the server's HTTP/2 keepalive pings; a connection that does "
                  "not answer within --keepalive-timeout is dropped")
      ->check(CLI::Range(0.1, 86400.0))
      ->capture_default_str();
  cmd->add_option("--keepalive-timeout", s.limits.keepalive_timeout_s,
                  "Seconds a keepalive ping may go unanswered")
      ->check(CLI::Range(0.1, 3600.0))
      ->capture_default_str();
  cmd->add_option("--build-threads", s.limits.build_threads,
                  "Threads that parse uploaded meshes and build their BVHs")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  cmd->add_option("--max-builds-per-client", s.limits.max_builds_per_client,
                  "Builds one client (token, or peer address when open) may run at once")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  cmd->add_option("--log-level", o->log_level, "trace, debug, info, warn, error, off")
      ->capture_default_str();
  cmd->callback([o] { RunServe(*o); });
}

}  // namespace hapticpd::cli
