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
  std::string scene = "default";
  ViewerFlags viewer;
};

void RunView(const ViewOptions& o) {
  // Blocked in every thread started from here on (gRPC's and the viewer's
  // inherit the mask): sigwait takes them.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  viewer::Viewer v(ViewerOptionsFor(o.conn, o.scene, o.viewer));
  v.Start();
  std::cout << "hapticpd view: scene '" << o.scene << "' on " << o.conn.server << " at " << v.url()
            << std::endl;
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
  vo.make_channel = [conn] { return MakeChannel(conn); };
  return vo;
}

void RegisterView(CLI::App& app) {
  auto o = std::make_shared<ViewOptions>();
  auto* cmd = app.add_subcommand(
      "view", "Watch a scene in a browser: serves a 3D page and a WebSocket (until Ctrl-C)");
  AddConnectionOptions(cmd, &o->conn);
  cmd->add_option("--scene", o->scene, "Scene id")->required();
  AddViewerFlags(cmd, &o->viewer);
  cmd->callback([o] {
    try {
      RunView(*o);
    } catch (const viewer::ViewerError& e) {
      throw CommandError(std::string("view: ") + e.what());
    }
  });
}

}  // namespace hapticpd::cli
