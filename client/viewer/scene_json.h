// The viewer's WebSocket messages (client/viewer/README.md "Protocol"):
// Watch events turned into JSON, and the scene as the viewer knows it, from
// which a browser that connects (or falls behind) gets the whole scene.
#pragma once

#include <cstdint>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <string>

#include "client/viewer/mesh_store.h"
#include "hapticpd/v1/scene.pb.h"

namespace hapticpd::viewer {

/// One Watch event as a WebSocket message ("scene", "bodies", "sessions",
/// "poses" or "telemetry"; see the README for the fields). Meshes go into
/// `meshes` and the message names them by hash. A "scene" message made from
/// a snapshot has no sessions or probes yet: they follow in their own events.
nlohmann::json EventToJson(const v1::SceneEvent& ev, MeshStore* meshes);

/// Which meshes the current scene uses (bodies and probes), followed from
/// the events in order, so that the store can drop the others.
class MeshRefs {
 public:
  /// Updates the references from an EventToJson message.
  void Apply(const nlohmann::json& msg);
  std::set<std::string> hashes() const;

 private:
  std::map<std::string, std::string> bodies_, sessions_;  // id -> hash
};

/// The scene as the browsers should see it now: applied message by message
/// in the order they are broadcast. Not thread-safe (the viewer keeps it on
/// its network thread).
class SceneModel {
 public:
  /// `source`: what the scene comes from, for the page ("server HOST:PORT",
  /// "replay of FILE").
  explicit SceneModel(std::string scene_id, std::string source = "")
      : scene_id_(std::move(scene_id)), source_(std::move(source)) {}

  /// Applies an EventToJson message or a "link" message.
  void Apply(const nlohmann::json& msg);
  /// The whole current scene as a "scene" message (bodies at their latest
  /// poses, sessions, latest probes and device status, link state).
  nlohmann::json FullScene() const;

  bool server_connected() const { return server_connected_; }
  std::uint64_t revision() const { return revision_; }
  std::size_t bodies() const { return bodies_.size(); }
  const std::string& scene_id() const { return scene_id_; }
  const std::string& source() const { return source_; }

 private:
  std::string scene_id_;
  std::string source_;
  std::map<std::string, nlohmann::json> bodies_;    // id -> body
  std::map<std::string, nlohmann::json> sessions_;  // id -> session
  std::map<std::string, nlohmann::json> status_;    // id -> latest device status
  nlohmann::json probes_ = nlohmann::json::array();
  std::uint64_t revision_ = 0;
  std::uint32_t observers_ = 0;
  std::int64_t server_time_ns_ = 0;
  bool server_connected_ = false;
  // The server announces sessions: telemetry then counts only for those
  // announced. A batch sent before a session's removal may arrive after it
  // (the bridge sends announcements first) and must not bring it back.
  bool sessions_announced_ = false;
  std::string link_error_;
};

/// A "link" message: whether the viewer is linked to the server, and why not.
nlohmann::json LinkJson(bool server_connected, const std::string& error);

}  // namespace hapticpd::viewer
