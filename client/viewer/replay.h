// `hapticpd view --replay FILE`: a recorded device session (`hapticpd
// device --record`, version 2) played in the viewer's page. The recording
// becomes the Watch events a live session would have produced (the scene's
// snapshot, the session, pose frames with the proxy and its contact rows,
// telemetry with every tick's commanded wrench), so the page and its
// protocol are the same for both.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <grpcpp/grpcpp.h>

#include "device/replay_device.h"
#include "hapticpd/v1/scene.pb.h"

namespace hapticpd::viewer {

/// What a replay shows: the recording, the scene it was recorded against
/// (bodies with meshes) and the session's probe.
struct ReplayInput {
  std::string file;  ///< the recording, for messages and the session's name
  device::Recording recording;
  v1::Scene scene;
  v1::SessionInfo session;
  Pose X_WD;  ///< the device frame in the world (the header's X_WD)
};

/// Where the scene and the probe of a replay come from. Empty fields fall
/// back to the recording's header (`scene`, `server`, `probe`).
struct ReplaySources {
  std::string scene_file;  ///< a scene file (serve --scene): no server needed
  std::string scene_id;    ///< else this scene, fetched from `server` (GetScene)
  std::string server;      ///< HOST:PORT
  std::string probe;       ///< a mesh file, shape:SPEC or body:ID
  /// A channel to `server` (the CLI's connection options: token, TLS).
  std::function<std::shared_ptr<grpc::Channel>(const std::string& server)> make_channel;
  std::string server_token;
  double timeout_s = 10;  ///< for GetScene
};

/// Loads the recording and what it shows. Throws ViewerError naming the
/// file and the problem: a version 1 recording (no proxy or contacts), no
/// ticks, a scene that cannot be found (the server named, unreachable, or
/// without that scene: pass --scene-file), a probe mesh that cannot be read.
ReplayInput LoadReplay(const std::filesystem::path& file, const ReplaySources& sources);

/// Plays a ReplayInput as Watch events against a play clock the caller
/// drives (seconds since Begin, any speed applied by the caller), so that
/// tests step it by hand.
class ReplayPlayer {
 public:
  /// Telemetry batches per second (a live session sends 20).
  static constexpr double kTelemetryPeriodS = 0.05;
  /// With `loop`, the recording starts again this long after its end.
  static constexpr double kLoopPauseS = 1.0;

  ReplayPlayer(ReplayInput input, bool loop);

  /// The first events: the scene's snapshot, then the session.
  void Begin(std::vector<v1::SceneEvent>* out);
  /// Plays up to `play_s` (non-decreasing): a telemetry batch holding every
  /// tick passed since the previous batch (at most one per
  /// kTelemetryPeriodS, and one at the end), then one pose frame at the
  /// newest tick reached. Nothing once finished.
  void AdvanceTo(double play_s, std::vector<v1::SceneEvent>* out);

  /// The recording's length (s, from the first tick to the last).
  double duration_s() const { return duration_s_; }
  /// The whole recording was played and `loop` is off.
  bool finished() const { return finished_; }
  /// Times the recording started again (loop).
  std::uint64_t loops() const { return loops_; }
  const ReplayInput& input() const { return in_; }
  /// The session id the replay's probe has in the page.
  static constexpr const char* kSessionId = "replay";

 private:
  v1::SceneEvent Event() const;
  void AddPoseFrame(std::size_t tick, std::vector<v1::SceneEvent>* out) const;
  void FlushTelemetry(std::vector<v1::SceneEvent>* out);
  std::int64_t TimeNs(double t_rec_s) const;

  ReplayInput in_;
  bool loop_;
  double duration_s_ = 0;
  double t_first_ = 0;           // the first sample's recorded time
  std::size_t next_ = 0;         // the first tick not yet played
  std::size_t batch_begin_ = 0;  // the first tick of the pending batch
  double last_batch_play_s_ = 0;
  double epoch_s_ = 0;  // play time at which the current pass started
  std::uint64_t loops_ = 0;
  std::uint64_t telemetry_seq_ = 0;
  bool finished_ = false;
};

}  // namespace hapticpd::viewer
