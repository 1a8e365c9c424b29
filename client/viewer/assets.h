// The viewer's web files and three.js, embedded in the binary at build time
// (client/viewer/CMakeLists.txt runs embed_assets.cmake).
#pragma once

#include <string_view>
#include <vector>

namespace hapticpd::viewer::internal {

struct Asset {
  std::string_view path;  ///< URL path, e.g. "/viewer.js"
  std::string_view body;
};

/// Every embedded file.
const std::vector<Asset>& Assets();

/// The Content-Type of an asset, from its extension.
inline std::string_view ContentType(std::string_view path) {
  const auto ends = [&](std::string_view ext) {
    return path.size() >= ext.size() && path.substr(path.size() - ext.size()) == ext;
  };
  if (ends(".html")) return "text/html; charset=utf-8";
  if (ends(".js")) return "text/javascript; charset=utf-8";
  if (ends(".css")) return "text/css; charset=utf-8";
  return "application/octet-stream";
}

}  // namespace hapticpd::viewer::internal
