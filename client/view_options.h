// What `view` and `demo --view` share: the viewer's command-line options and
// the viewer's configuration from them.
#pragma once

#include <CLI/CLI.hpp>
#include <string>

#include "client/rpc_util.h"
#include "client/viewer/viewer.h"

namespace hapticpd::cli {

struct ViewerFlags {
  std::string listen = "127.0.0.1:8080";
  std::string viewer_token;
  std::string tls_cert, tls_key;
  double rate = 60;  ///< pose frames per second asked of the server
  std::size_t display_triangles = viewer::kDefaultDisplayTriangles;
};

/// Adds --listen, --viewer-token, --tls-cert, --tls-key, --rate,
/// --display-triangles to `cmd`.
void AddViewerFlags(CLI::App* cmd, ViewerFlags* f);

/// The viewer of `scene` on the server `conn` names, serving as `f` says.
viewer::ViewerOptions ViewerOptionsFor(const ConnectionOptions& conn, const std::string& scene,
                                       const ViewerFlags& f);

}  // namespace hapticpd::cli
