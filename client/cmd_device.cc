// `hapticpd device`: the device side of a haptic session. A simulated hand
// (or a replayed trajectory) drives a device whose 1 kHz servo loop renders
// contact from the server's ContactUpdates through the network Session
// (client/session.h); at the end it prints the loop's and the session's
// statistics (one JSON object with --json).
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <iostream>
#include <limits>
#include <memory>
#include <thread>

#include "client/rpc_util.h"
#include "client/session.h"
#include "device/replay_device.h"
#include "device/servo_loop.h"
#include "device/simulated_device.h"
#include "hapticpd/v1/scene.grpc.pb.h"
#include "pd/mesh.h"
#include "proto/wire/convert.h"

namespace hapticpd::cli {
namespace {

using device::Pose;
using device::Vec3;

struct DeviceOptions {
  ConnectionOptions conn;
  std::string scene;
  std::string probe;
  std::string probe_body;
  std::string mode = "pdt";
  std::string simulated;
  std::string replay;
  std::string start;
  double duration = 5;
  double travel = 0.02;
  double max_rate = 0;
  std::string record;
  bool json = false;
  client::LinkOptions link;  // --delay, --jitter, --loss
  std::string local_model = "on";
  std::uint32_t patch_triangles = 8192;
};

/// Default start: centred above the scene's bounding box (bodies other than
/// the probe body), the probe's lowest point 5 mm above its top.
Pose DefaultStart(const DeviceOptions& o, const v1::Welcome& welcome) {
  auto stub = v1::SceneService::NewStub(MakeChannel(o.conn));
  auto ctx = MakeSceneContext(o.conn, o.scene);
  v1::GetSceneRequest req;
  req.set_scene_id(o.scene);
  v1::Scene scene;
  Check(stub->GetScene(ctx.get(), req, &scene), "device");
  const auto [lo, hi] = SceneBox(scene, o.probe_body);  // empty scene: at the origin
  const double below_com =
      welcome.probe_body_frame().position().z() - welcome.probe_mesh_info().aabb_min().z();
  return device::StartPoseAbove(lo, hi, std::max(0.0, below_com) + 0.005);
}

/// Every option checked before anything connects: the session's options
/// (hello, link, local model), the hand script and the start pose if given.
client::SessionOptions CheckedSessionOptions(const DeviceOptions& o, device::HandScript* script,
                                             std::optional<Pose>* start) {
  client::SessionOptions so;
  so.server = o.conn.server;
  so.token = o.conn.token;
  so.credentials = MakeCredentials(o.conn);
  so.connect_timeout_s = o.conn.timeout_s > 0 ? std::min(o.conn.timeout_s, 10.0) : 10.0;
  v1::Hello& h = so.hello;
  h.set_scene_id(o.scene);
  if (o.mode == "pdt")
    h.set_mode(v1::PD_MODE_PDT);
  else if (o.mode == "pdg")
    h.set_mode(v1::PD_MODE_PDG);
  else if (o.mode == "none")
    h.set_mode(v1::PD_MODE_NONE);
  else
    throw CommandError("device: --mode: expected pdt, pdg or none, got '" + o.mode + "'");
  if (o.probe.empty() == o.probe_body.empty()) {
    throw CommandError("device: give exactly one of --probe MESH|shape:SPEC and --probe-body ID");
  }
  if (!o.probe_body.empty()) {
    h.set_probe_body_id(o.probe_body);
  } else if (o.probe.rfind("shape:", 0) == 0) {
    h.set_probe_shape(o.probe.substr(6));
  } else {
    wire::ToProto(pd::LoadMesh(o.probe), h.mutable_probe_mesh());
  }
  if (o.simulated.empty() == o.replay.empty()) {
    throw CommandError("device: give exactly one of --simulated SCRIPT and --replay FILE");
  }
  if (!(o.duration > 0) || !std::isfinite(o.duration) || o.duration > 24 * 3600) {
    throw CommandError("device: --duration: expected seconds > 0");
  }
  if (!(o.travel > 0) || !std::isfinite(o.travel)) {
    throw CommandError("device: --travel: expected metres > 0");
  }
  if (!(o.max_rate >= 0) || !std::isfinite(o.max_rate)) {
    throw CommandError("device: --max-rate: expected >= 0");
  }
  h.set_max_rate_hz(o.max_rate);
  if (const std::string problem = client::LinkOptionsProblem(o.link); !problem.empty()) {
    throw CommandError("device: " + problem);
  }
  if (o.local_model != "on" && o.local_model != "off") {
    throw CommandError("device: --local-model: expected on or off, got '" + o.local_model + "'");
  }
  so.local_model = o.local_model == "on";
  if (o.patch_triangles < 1 || o.patch_triangles > 1'000'000) {
    throw CommandError("device: --patch-triangles: expected 1 to 1000000, got " +
                       std::to_string(o.patch_triangles));
  }
  so.patch_max_triangles = o.patch_triangles;
  // No delay, jitter or loss: no emulator at all (the session's direct path).
  if (o.link.delay_ms > 0 || o.link.jitter_ms > 0 || o.link.loss > 0) so.link = o.link;
  *script = device::HandScript::kHold;
  if (!o.simulated.empty()) {
    try {
      *script = device::ParseHandScript(o.simulated);
    } catch (const std::invalid_argument& e) {
      throw CommandError(std::string("device: --simulated: ") + e.what());
    }
  }
  if (!o.start.empty()) *start = wire::FromProtoUnchecked(ParsePose(o.start, "--start"));
  return so;
}

/// The hand: a simulated script from `start` (its workspace centred there),
/// or a replayed trajectory.
std::unique_ptr<device::HapticDevice> MakeHand(const DeviceOptions& o, device::HandScript script,
                                               const Pose& start, const device::Clock& clock) {
  if (!o.simulated.empty()) {
    device::ScriptParams sp;
    sp.script = script;
    sp.X_DS = Pose{start.R, Vec3::Zero()};
    sp.duration_s = std::max(0.5, 0.9 * o.duration);
    sp.travel = o.travel;
    return std::make_unique<device::SimulatedDevice>(sp, &clock);
  }
  return std::make_unique<device::ReplayDevice>(o.replay, &clock);
}

/// The run's statistics, as `--json` prints them.
nlohmann::json DeviceJson(const DeviceOptions& o, const device::ServoLoop& loop,
                          const client::SessionStats& ss, double elapsed) {
  const device::ServoStats& s = loop.stats();
  const double period_mean = s.period_us.mean();
  nlohmann::json j;
  j["loop_hz"] = period_mean > 0 ? 1e6 / period_mean : 0.0;
  j["ticks"] = s.ticks;
  j["elapsed_s"] = elapsed;
  j["period_mean_us"] = period_mean;
  j["period_std_us"] = s.period_us.stddev();
  j["period_p50_us"] = s.period_us.Quantile(0.5);
  j["period_p99_us"] = s.period_us.Quantile(0.99);
  j["period_p999_us"] = s.period_us.Quantile(0.999);
  j["period_max_us"] = s.period_us.max();
  j["late_ticks"] = s.late_ticks;
  j["tick_compute_p99_us"] = s.compute_us.Quantile(0.99);
  j["tick_compute_max_us"] = s.compute_us.max();
  j["realtime_priority"] = loop.got_realtime_priority();
  j["updates"] = ss.updates;
  j["contact_updates"] = ss.contact_updates;
  j["bad_updates"] = ss.bad_updates;
  j["poses_sent"] = ss.poses_sent;
  j["ir_updates"] = s.ir_updates;
  j["rtt_p50_us"] = ss.rtt_p50_us;
  j["rtt_p99_us"] = ss.rtt_p99_us;
  j["rtt_max_us"] = ss.rtt_max_us;
  j["server_pd_p50_us"] = ss.server_compute_p50_us;
  j["server_pd_p99_us"] = ss.server_compute_p99_us;
  j["ir_age_p50_ms"] = s.ir_age_ms.Quantile(0.5);
  j["ir_age_p99_ms"] = s.ir_age_ms.Quantile(0.99);
  j["stale_ticks"] = s.stale_ticks;
  j["outside_ticks"] = s.outside_ticks;
  j["clamped_ticks"] = s.clamped_ticks;
  j["device_errors"] = s.device_errors;
  j["max_depth"] = ss.max_depth;
  j["max_force"] = s.max_force;
  j["max_torque"] = s.max_torque;
  j["max_dforce"] = s.max_dforce;
  j["max_dtorque"] = s.max_dtorque;
  j["energy_j"] = s.energy_into_hand_j;
  j["passivity_min_j"] = s.passivity_min_j;
  j["connects"] = ss.connects;
  j["disconnects"] = ss.disconnects;
  j["contact_from"] = {
      {"server", s.ticks_server}, {"local_patch", s.ticks_local}, {"none_or_faded", s.ticks_faded}};
  j["local_model"] = {{"state", ss.local_model_note},
                      {"patches", ss.local.patches},
                      {"bad_patches", ss.local.bad_patches},
                      {"patch_bytes", ss.local.patch_bytes},
                      {"max_triangles_held", ss.local.max_triangles_held},
                      {"answers", ss.local.local_answers},
                      {"server_deeper", ss.local.server_deeper},
                      {"uncovered", ss.local.uncovered},
                      {"rate_hz", ss.local.rate_hz},
                      {"pd_p50_us", ss.local.compute_p50_us},
                      {"pd_p99_us", ss.local.compute_p99_us},
                      {"reference_checks", ss.local.reference_checks},
                      {"reference_disagreements", ss.local.reference_disagreements},
                      {"reference_diff_p99_mm", ss.local.reference_diff_p99_mm}};
  if (!ss.local.last_problem.empty()) j["local_model"]["last_problem"] = ss.local.last_problem;
  if (ss.link.active) {
    j["link"] = {{"delay_ms", o.link.delay_ms},
                 {"jitter_ms", o.link.jitter_ms},
                 {"loss", o.link.loss},
                 {"poses_sent", ss.link.poses.sent},
                 {"poses_lost", ss.link.poses.lost + ss.link.poses.overflow},
                 {"updates_sent", ss.link.updates.sent},
                 {"updates_lost", ss.link.updates.lost + ss.link.updates.overflow}};
  }
  return j;
}

/// The run's statistics as text.
void PrintDevice(const DeviceOptions& o, const nlohmann::json& j, const device::ServoLoop& loop,
                 const client::Session& session, const client::SessionStats& ss,
                 const device::RecordingDevice* rec) {
  const device::ServoStats& s = loop.stats();
  const double elapsed = j["elapsed_s"].get<double>();
  std::printf(
      "device: %.1f s on scene '%s' (%s), session %s\n"
      "  loop   %.1f Hz, period p50 %.0f us p99 %.0f us max %.0f us, %llu late ticks%s\n"
      "  net    %llu updates (%llu in contact), round trip p50 %.0f us p99 %.0f us, "
      "server PD p50 %.0f us\n"
      "  force  max %.2f N (step %.3f N/tick), torque max %.3f N m, depth max %.2f mm\n"
      "  energy into the hand %.4f J, passivity observer min %.4f J\n",
      elapsed, o.scene.c_str(), o.mode.c_str(), session.welcome().session_id().c_str(),
      j["loop_hz"].get<double>(), s.period_us.Quantile(0.5), s.period_us.Quantile(0.99),
      s.period_us.max(), static_cast<unsigned long long>(s.late_ticks),
      loop.got_realtime_priority() ? " (SCHED_FIFO)" : "",
      static_cast<unsigned long long>(ss.updates),
      static_cast<unsigned long long>(ss.contact_updates), ss.rtt_p50_us, ss.rtt_p99_us,
      ss.server_compute_p50_us, s.max_force, s.max_dforce, s.max_torque, 1e3 * ss.max_depth,
      s.energy_into_hand_j, s.passivity_min_j);
  if (ss.link.active) {
    std::printf("  link   emulated %s: %llu of %llu poses and %llu of %llu updates lost\n",
                client::LinkDescription(o.link).c_str(),
                static_cast<unsigned long long>(ss.link.poses.lost + ss.link.poses.overflow),
                static_cast<unsigned long long>(ss.link.poses.sent),
                static_cast<unsigned long long>(ss.link.updates.lost + ss.link.updates.overflow),
                static_cast<unsigned long long>(ss.link.updates.sent));
  }
  std::printf(
      "  model  contact from the server %llu ticks, local patch %llu, none %llu; local "
      "model %s",
      static_cast<unsigned long long>(s.ticks_server),
      static_cast<unsigned long long>(s.ticks_local),
      static_cast<unsigned long long>(s.ticks_faded), ss.local_model_note.c_str());
  if (ss.local_model) {
    std::printf(
        ": %llu patches (%.0f kB, %zu triangles held at most), %.0f answers/s, PD p50 %.0f us "
        "p99 %.0f us",
        static_cast<unsigned long long>(ss.local.patches), 1e-3 * ss.local.patch_bytes,
        ss.local.max_triangles_held, ss.local.rate_hz, ss.local.compute_p50_us,
        ss.local.compute_p99_us);
    std::printf(", %llu of %llu server answers disagree with it",
                static_cast<unsigned long long>(ss.local.reference_disagreements),
                static_cast<unsigned long long>(ss.local.reference_checks));
    if (ss.local.bad_patches > 0) {
      std::printf(", %llu bad patches (last: %s)",
                  static_cast<unsigned long long>(ss.local.bad_patches),
                  ss.local.last_problem.c_str());
    }
  }
  std::printf("\n");
  if (ss.disconnects > 0) {
    std::printf("  %llu disconnects, last: %s\n", static_cast<unsigned long long>(ss.disconnects),
                ss.last_error.c_str());
  }
  if (rec) std::printf("  recorded %zu samples to %s\n", rec->samples().size(), o.record.c_str());
}

void RunDevice(const DeviceOptions& o) {
  device::HandScript script;
  std::optional<Pose> start;
  const client::SessionOptions so = CheckedSessionOptions(o, &script, &start);
  // --- connect, then build the device and the loop around the welcome
  client::Session session(so);
  try {
    session.Connect();
  } catch (const client::SessionError& e) {
    throw CommandError(std::string("device: ") + e.what() + " (server " + o.conn.server + ")");
  }
  if (!start) start = DefaultStart(o, session.welcome());
  const auto& clock = device::SteadyClock::Instance();
  // The device's workspace is centred on the start pose.
  const Pose X_WD = Pose::FromTranslation(start->t);
  std::unique_ptr<device::HapticDevice> dev = MakeHand(o, script, *start, clock);
  std::unique_ptr<device::RecordingDevice> rec;
  device::HapticDevice* used = dev.get();
  if (!o.record.empty()) {
    rec = std::make_unique<device::RecordingDevice>(
        dev.get(), static_cast<std::size_t>(o.duration * 1000 * 1.1) + 1000);
    used = rec.get();
  }
  used->Open();
  device::ServoConfig config;
  config.X_PA = session.X_PA();
  config.X_WD = X_WD;
  // The scene's declared effects (Welcome.scene_config).
  config.effects = client::EffectsFromSceneConfig(session.welcome().scene_config());
  config.effect_params = client::EffectParamsFromSceneConfig(session.welcome().scene_config());
  if (rec) {
    // Version 2: what `hapticpd view --replay` needs to show the session.
    rec->SetHeader({{"scene", o.scene},
                    {"server", o.conn.server},
                    {"probe", o.probe_body.empty() ? o.probe : "body:" + o.probe_body},
                    {"mode", o.mode},
                    {"X_WD", device::PoseValue(X_WD)},
                    {"X_PA", device::PoseValue(session.X_PA())}});
    config.recorder = rec.get();
  }
  device::ServoLoop loop(used, config, &clock);
  session.Start(&loop);
  loop.Start();
  const auto t0 = std::chrono::steady_clock::now();
  std::this_thread::sleep_for(std::chrono::duration<double>(o.duration));
  loop.Stop();
  const double elapsed =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  session.Stop();
  used->Close();
  if (rec) rec->Save(o.record);

  const client::SessionStats ss = session.stats();
  const nlohmann::json j = DeviceJson(o, loop, ss, elapsed);
  if (o.json) {
    std::cout << j.dump() << std::endl;
    return;
  }
  PrintDevice(o, j, loop, session, ss, rec.get());
}

}  // namespace

void RegisterDevice(CLI::App& app) {
  auto o = std::make_shared<DeviceOptions>();
  auto* cmd = app.add_subcommand(
      "device", "Run a (simulated or replayed) haptic device against a server at 1 kHz");
  AddConnectionOptions(cmd, &o->conn);
  cmd->add_option("--scene", o->scene, "Scene id")->required();
  cmd->add_option("--probe", o->probe, "Probe: a mesh file, or shape:SPEC (e.g. shape:stick)");
  cmd->add_option("--probe-body", o->probe_body, "Use this scene body as the probe instead");
  cmd->add_option("--mode", o->mode, "pdt, pdg or none")->capture_default_str();
  cmd->add_option("--simulated", o->simulated,
                  "Simulated hand script: hold, press, slide, twist, circle, loop, plate");
  cmd->add_option("--replay", o->replay, "Replay a trajectory CSV (as written by --record)");
  cmd->add_option(
      "--start", o->start,
      "Start pose \"x y z [qw qx qy qz]\", commas or spaces (default: above the scene, centred)");
  cmd->add_option("--duration", o->duration, "Seconds to run")->capture_default_str();
  cmd->add_option("--travel", o->travel, "Script travel (m)")->capture_default_str();
  cmd->add_option("--max-rate", o->max_rate, "Ask the server for at most this many updates/s")
      ->capture_default_str();
  cmd->add_option("--record", o->record,
                  "Write the session to this CSV (the device trajectory, and per tick the proxy "
                  "pose and contact rows; hapticpd view --replay shows it)");
  cmd->add_flag("--json", o->json, "Print the statistics as one JSON object");
  AddLinkOptions(cmd, &o->link);
  cmd->add_option("--local-model", o->local_model,
                  "on: ask for geometry patches and run PD on them on the device side at the "
                  "proxy's newest pose (model-mediated rendering; needs --probe); off: render "
                  "the server's answers only")
      ->capture_default_str();
  cmd->add_option("--patch-triangles", o->patch_triangles,
                  "Most patch triangles held per body (the server may cut it lower)")
      ->capture_default_str();
  cmd->callback([o] { RunDevice(*o); });
}

void AddLinkOptions(CLI::App* cmd, client::LinkOptions* link) {
  cmd->add_option("--delay", link->delay_ms,
                  "Emulate a wide-area link: one-way delay (ms, each direction, 0 to 10000)")
      ->capture_default_str();
  cmd->add_option("--jitter", link->jitter_ms,
                  "Emulated link: uniform +-jitter on the delay (ms, at most --delay)")
      ->capture_default_str();
  cmd->add_option("--loss", link->loss,
                  "Emulated link: fraction of pose and update messages lost, in [0, 1)")
      ->capture_default_str();
}

}  // namespace hapticpd::cli
