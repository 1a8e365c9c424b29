// `hapticpd observe`: a scene's Watch stream summarised once per second
// (bodies, the device sessions' probes: pose, contacts, force), and with
// --json one object at the end (frames received, their rate, the last
// summary). `hapticpd watch` prints every event instead.
#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <string>
#include <string_view>

#include "client/rpc_util.h"
#include "hapticpd/v1/scene.grpc.pb.h"

namespace hapticpd::cli {
namespace {

struct ObserveOptions {
  ConnectionOptions conn;
  std::string scene = "default";
  double duration = 0;  // 0: until the stream ends
  double rate = 60;
  bool json = false;
  bool telemetry = false;  // Watch include_telemetry: a line per device session
};

/// "FAIL_SAFE_STATE_OK" -> "ok" (an enum value's name without its prefix).
std::string Short(const std::string& name, std::string_view prefix) {
  std::string s = name.rfind(prefix, 0) == 0 ? name.substr(prefix.size()) : name;
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

/// A device session's relayed telemetry since the previous line.
struct SessionLine {
  v1::DeviceTelemetry device;  // the latest
  bool have_device = false;
  bool fresh = false;           // telemetry came since the previous line
  double max_force = 0;         // N, commanded on the hand
  double max_server_force = 0;  // N, the server's penalty force
  double update_rate_hz = 0;    // as the server counts them
  std::uint64_t samples = 0;    // commanded samples received
};

double Norm(const v1::Vec3& v) { return std::sqrt(v.x() * v.x() + v.y() * v.y() + v.z() * v.z()); }

/// What the observer knows after the events so far.
struct Summary {
  std::set<std::string> bodies;
  std::uint64_t revision = 0;
  std::uint64_t events = 0;
  std::uint64_t frames = 0;  // pose frames
  std::uint64_t frames_dropped = 0;
  int probes = 0;
  int contacts = 0;                             // probes in contact (depth > 0)
  v1::ProbeState probe;                         // the probe pushed hardest in the last frame
  double max_force = 0;                         // N, over the whole run
  double max_depth = 0;                         // m, over the whole run
  std::map<std::string, SessionLine> sessions;  // with --telemetry
  std::uint64_t batches_dropped = 0;

  void Add(const v1::SceneEvent& ev) {
    ++events;
    revision = ev.revision();
    frames_dropped = ev.frames_dropped();
    if (ev.has_snapshot()) {
      bodies.clear();
      for (const auto& b : ev.snapshot().bodies()) bodies.insert(b.body_id());
    } else if (ev.has_changes()) {
      for (const auto& id : ev.changes().removed()) bodies.erase(id);
      for (const auto& b : ev.changes().added()) bodies.insert(b.body_id());
    } else if (ev.has_telemetry()) {
      batches_dropped = ev.telemetry().batches_dropped();
      for (const v1::SessionTelemetry& st : ev.telemetry().sessions()) {
        SessionLine& l = sessions[st.session_id()];
        l.fresh = true;
        l.update_rate_hz = st.update_rate_hz();
        for (float f : st.server().force())
          l.max_server_force = std::max<double>(l.max_server_force, f);
        if (!st.has_device()) continue;
        l.device = st.device();
        l.have_device = true;
        l.samples += static_cast<std::uint64_t>(st.device().commanded().force_size());
        for (float f : st.device().commanded().force())
          l.max_force = std::max<double>(l.max_force, f);
      }
    } else if (ev.has_poses()) {
      ++frames;
      probes = ev.poses().probes_size();
      contacts = 0;
      probe.Clear();
      double strongest = -1;
      for (const auto& p : ev.poses().probes()) {
        contacts += p.depth() > 0;
        const double f = Norm(p.force());
        max_force = std::max(max_force, f);
        max_depth = std::max(max_depth, p.depth());
        if (f > strongest) strongest = f, probe = p;
      }
    }
  }

  /// One line: t, frames/s over the last interval, bodies, probes.
  std::string Line(double t_s, double rate_hz) const {
    char buf[320];
    int n = std::snprintf(buf, sizeof buf, "t %5.1f s  %5.1f frames/s  bodies %zu  probes %d", t_s,
                          rate_hz, bodies.size(), probes);
    if (probes > 0 && n > 0) {
      const auto& x = probe.pose().position();
      std::snprintf(buf + n, sizeof buf - static_cast<std::size_t>(n),
                    "  contacts %d  probe %s at (%.4f, %.4f, %.4f) depth %.2f mm force %.3f N",
                    contacts, probe.session_id().c_str(), x.x(), x.y(), x.z(), 1e3 * probe.depth(),
                    Norm(probe.force()));
    }
    return buf;
  }

  /// One line per device session that sent telemetry since the previous
  /// call (servo rate, source, fail-safe state, the largest commanded and
  /// server forces); resets the maxima.
  std::string TelemetryLines() {
    std::string out;
    for (auto& [id, l] : sessions) {
      if (!l.fresh) continue;
      const v1::DeviceTelemetry& d = l.device;
      out += l.have_device
                 ? fmt::format(
                       "  session {}: servo {:.0f} Hz  updates {:.0f} Hz  rtt {:.2f} ms  ir age "
                       "{:.1f} ms  source {}  fail-safe {}  force {:.3f} N (server {:.3f} N)  "
                       "lost {}\n",
                       id, d.servo_rate_hz(), l.update_rate_hz, d.round_trip_ms(), d.ir_age_ms(),
                       Short(v1::ContactSource_Name(d.source()), "CONTACT_SOURCE_"),
                       Short(v1::FailSafeState_Name(d.fail_safe()), "FAIL_SAFE_STATE_"),
                       l.max_force, l.max_server_force, d.commanded().samples_lost())
                 : fmt::format(
                       "  session {}: updates {:.0f} Hz  server force {:.3f} N (no device "
                       "telemetry)\n",
                       id, l.update_rate_hz, l.max_server_force);
      l.fresh = false;
      l.max_force = 0;
      l.max_server_force = 0;
    }
    return out;
  }
};

void RunObserve(const ObserveOptions& o) {
  if (!(o.duration >= 0)) throw CommandError("observe: --duration: expected seconds >= 0");
  if (!(o.rate > 0 && o.rate <= 1000)) throw CommandError("observe: --rate: expected (0, 1000]");
  auto stub = v1::SceneService::NewStub(MakeChannel(o.conn));
  auto ctx = MakeSceneContext(o.conn, o.scene, true);
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  if (o.duration > 0) {
    ctx->set_deadline(std::chrono::system_clock::now() +
                      std::chrono::duration_cast<std::chrono::system_clock::duration>(
                          std::chrono::duration<double>(o.duration)));
  }
  v1::WatchRequest req;
  req.set_scene_id(o.scene);
  req.set_rate_hz(o.rate);
  req.set_include_telemetry(o.telemetry);
  auto reader = stub->Watch(ctx.get(), req);
  Summary s;
  v1::SceneEvent ev;
  auto next_line = t0 + std::chrono::seconds(1);
  std::uint64_t frames_at_line = 0;
  auto last_line = t0;
  const auto seconds = [](Clock::duration d) { return std::chrono::duration<double>(d).count(); };
  while (reader->Read(&ev)) {
    s.Add(ev);
    const auto now = Clock::now();
    if (!o.json && now >= next_line) {
      const double rate =
          static_cast<double>(s.frames - frames_at_line) / std::max(1e-9, seconds(now - last_line));
      std::cout << s.Line(seconds(now - t0), rate) << std::endl;
      if (o.telemetry) std::cout << s.TelemetryLines() << std::flush;
      frames_at_line = s.frames;
      last_line = now;
      next_line += std::chrono::seconds(1);
    }
  }
  const grpc::Status status = reader->Finish();
  const double elapsed = seconds(Clock::now() - t0);
  // The deadline is how --duration ends the stream.
  if (!(o.duration > 0 && status.error_code() == grpc::StatusCode::DEADLINE_EXCEEDED && s.events)) {
    Check(status, "observe");
  }
  if (!o.json) return;
  nlohmann::json j;
  j["scene"] = o.scene;
  j["duration_s"] = elapsed;
  j["events"] = s.events;
  j["frames"] = s.frames;
  j["frame_rate_hz"] = elapsed > 0 ? static_cast<double>(s.frames) / elapsed : 0.0;
  j["frames_dropped"] = s.frames_dropped;
  j["revision"] = s.revision;
  j["bodies"] = s.bodies.size();
  j["probes"] = s.probes;
  j["contacts"] = s.contacts;
  j["max_force"] = s.max_force;
  j["max_depth"] = s.max_depth;
  if (s.probes > 0) {
    const auto& x = s.probe.pose().position();
    const auto& q = s.probe.pose().orientation();
    j["probe"] = {{"session_id", s.probe.session_id()},
                  {"position", {x.x(), x.y(), x.z()}},
                  {"orientation", {q.w(), q.x(), q.y(), q.z()}},
                  {"depth", s.probe.depth()},
                  {"force", {s.probe.force().x(), s.probe.force().y(), s.probe.force().z()}},
                  {"sequence", s.probe.sequence()}};
  }
  if (o.telemetry) {
    j["batches_dropped"] = s.batches_dropped;
    nlohmann::json t = nlohmann::json::object();
    for (const auto& [id, l] : s.sessions) {
      const v1::DeviceTelemetry& d = l.device;
      t[id] = {{"servo_rate_hz", d.servo_rate_hz()},
               {"update_rate_hz", l.update_rate_hz},
               {"round_trip_ms", d.round_trip_ms()},
               {"ir_age_ms", d.ir_age_ms()},
               {"source", Short(v1::ContactSource_Name(d.source()), "CONTACT_SOURCE_")},
               {"fail_safe", Short(v1::FailSafeState_Name(d.fail_safe()), "FAIL_SAFE_STATE_")},
               {"samples", l.samples},
               {"samples_lost", d.commanded().samples_lost()}};
    }
    j["telemetry"] = t;
  }
  std::cout << j.dump() << std::endl;
}

}  // namespace

void RegisterObserve(CLI::App& app) {
  auto o = std::make_shared<ObserveOptions>();
  auto* cmd = app.add_subcommand(
      "observe", "Observe a scene: one summary line per second (bodies, probes, contacts, force)");
  AddConnectionOptions(cmd, &o->conn);
  cmd->add_option("--scene", o->scene, "Scene id")->required();
  cmd->add_option("--duration", o->duration, "Seconds (0: until the stream ends)")
      ->capture_default_str();
  cmd->add_option("--rate", o->rate, "Pose frames per second asked of the server")
      ->capture_default_str();
  cmd->add_flag("--json", o->json, "Print one JSON object at the end instead of the lines");
  cmd->add_flag("--telemetry", o->telemetry,
                "Also each device session's relayed telemetry: a line per session (servo rate, "
                "source, fail-safe state, force); with --json a \"telemetry\" object");
  cmd->callback([o] { RunObserve(*o); });
}

}  // namespace hapticpd::cli
