// `hapticpd view`: the scene in a browser. A Watch observer of the server
// that serves a three.js page and a WebSocket on one port
// (client/viewer/README.md); runs until SIGINT or SIGTERM.
#include <signal.h>
#include <spdlog/spdlog.h>

#include <iostream>

#include "client/view_options.h"

namespace hapticpd::cli {
namespace {

struct ViewOptions {
  ConnectionOptions conn;
  std::string scene;
  ViewerFlags viewer;
  // --replay: a `device --record` file played instead of a live scene.
  std::string replay, scene_file, probe;
  double speed = 1;
  bool loop = false;
  bool server_given = false;  // --server on the command line (else the recording's)
};

void RunView(const ViewOptions& o) {
  // Blocked in every thread started from here on (gRPC's and the viewer's
  // inherit the mask): sigwait takes them.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  viewer::ViewerOptions vo = ViewerOptionsFor(o.conn, o.scene, o.viewer);
  if (!o.replay.empty()) {
    viewer::ReplaySources src;
    src.scene_file = o.scene_file;
    src.scene_id = o.scene;
    src.server = o.server_given ? o.conn.server : "";
    src.probe = o.probe;
    src.server_token = o.conn.token;
    src.make_channel = [conn = o.conn](const std::string& server) {
      ConnectionOptions c = conn;
      c.server = server;
      return MakeChannel(c);
    };
    vo.replay = std::make_shared<viewer::ReplayPlayer>(viewer::LoadReplay(o.replay, src), o.loop);
    vo.scene_id = vo.replay->input().scene.scene_id();
    vo.replay_speed = o.speed;
    vo.server.clear();  // /healthz: the source says where the scene came from
  }
  viewer::Viewer v(std::move(vo));
  v.Start();
  if (o.replay.empty()) {
    std::cout << "hapticpd view: scene '" << o.scene << "' on " << o.conn.server << " at "
              << v.url() << std::endl;
  } else {
    std::cout << "hapticpd view: replay of " << o.replay << " at " << v.url() << std::endl;
  }
  int sig = 0;
  sigwait(&signals, &sig);
  spdlog::info("received {}, stopping the viewer", sig == SIGINT ? "SIGINT" : "SIGTERM");
  v.Stop();
}

}  // namespace

void AddViewerFlags(CLI::App* cmd, ViewerFlags* f) {
  cmd->add_option("--listen", f->listen,
                  "HOST:PORT the page is served on (loopback unless --viewer-token)")
      ->capture_default_str();
  cmd->add_option("--viewer-token", f->viewer_token,
                  "Token every browser must present (?token=...); required off loopback");
  cmd->add_option("--tls-cert", f->tls_cert, "PEM certificate: serve https and wss");
  cmd->add_option("--tls-key", f->tls_key, "PEM private key for --tls-cert");
  cmd->add_option("--rate", f->rate, "Pose frames per second asked of the server")
      ->capture_default_str();
  cmd->add_option("--display-triangles", f->display_triangles,
                  "Meshes over this many triangles are drawn simplified to it (0: in full)")
      ->capture_default_str();
}

viewer::ViewerOptions ViewerOptionsFor(const ConnectionOptions& conn, const std::string& scene,
                                       const ViewerFlags& f) {
  viewer::ViewerOptions vo;
  vo.http.listen = f.listen;
  vo.http.viewer_token = f.viewer_token;
  vo.http.tls_cert = f.tls_cert;
  vo.http.tls_key = f.tls_key;
  vo.server = conn.server;
  vo.server_token = conn.token;
  vo.scene_id = scene;
  vo.rate_hz = f.rate;
  vo.display_triangles = f.display_triangles;
  vo.make_channel = [conn] { return MakeChannel(conn); };
  return vo;
}

void RegisterView(CLI::App& app) {
  auto o = std::make_shared<ViewOptions>();
  auto* cmd = app.add_subcommand(
      "view", "Watch a scene in a browser: serves a 3D page and a WebSocket (until Ctrl-C)");
  AddConnectionOptions(cmd, &o->conn);
  cmd->add_option("--scene", o->scene,
                  "Scene id (with --replay: the scene to fetch, else the recording's)");
  AddViewerFlags(cmd, &o->viewer);
  cmd->add_option("--replay", o->replay,
                  "Play a session recorded by `device --record` instead of watching live");
  cmd->add_option("--scene-file", o->scene_file,
                  "With --replay: the scene from this file instead of the server");
  cmd->add_option(
      "--probe", o->probe,
      "With --replay: the probe (mesh file, shape:SPEC, body:ID) if not the recording's");
  cmd->add_option("--speed", o->speed, "With --replay: recorded seconds per second")
      ->capture_default_str();
  cmd->add_flag("--loop", o->loop, "With --replay: start again after the end");
  cmd->callback([o, cmd] {
    o->server_given = cmd->count("--server") > 0;
    if (o->replay.empty()) {
      if (o->scene.empty()) throw CommandError("view: --scene is required (or --replay FILE)");
      for (const char* flag : {"--scene-file", "--probe", "--speed", "--loop"}) {
        if (cmd->count(flag) > 0)
          throw CommandError(std::string("view: ") + flag + " needs --replay");
      }
    }
    try {
      RunView(*o);
    } catch (const viewer::ViewerError& e) {
      throw CommandError(std::string("view: ") + e.what());
    }
  });
}

}  // namespace hapticpd::cli
