// `hapticpd demo`: the whole pipeline on one machine with no downloads. A
// server in-process on 127.0.0.1, a built-in procedural scene (a torus knot
// and a cup), an observer, and a simulated hand pressing a stick probe into
// the cup's floor through the network Session and the 1 kHz servo loop, first in
// PDt then in PDg. Prints a short report and writes trace.csv and force.svg.
// `--scene FILE.json` runs a scene file instead (proto/wire/scene_file.h): its
// bodies, probe, PD mode (PDt then PDg when it names none) and effects.
#include <signal.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <optional>
#include <stdexcept>
#include <thread>
#include <vector>

#include "client/bench/svg.h"
#include "client/commands.h"
#include "client/session.h"
#include "client/view_options.h"
#include "device/replay_device.h"
#include "device/servo_loop.h"
#include "device/simulated_device.h"
#include "hapticpd/v1/scene.grpc.pb.h"
#include "pd/mesh.h"
#include "proto/wire/convert.h"
#include "proto/wire/routing.h"
#include "proto/wire/scene_file.h"
#include "server/server.h"

namespace hapticpd::cli {
namespace {

using device::Pose;
using device::Vec3;

struct DemoOptions {
  double duration = 3;  // per mode
  std::string out = "hapticpd-demo";
  std::string scene_file;        // empty: the built-in scene
  std::string script = "slide";  // with --scene
  double travel = 0.01;          // with --scene: m the hand goes down from the start
  client::LinkOptions link;      // --delay, --jitter, --loss
  std::string local_model = "on";
  bool view = false;   // --view: the scene in a browser, served until interrupted
  ViewerFlags viewer;  // --listen, --viewer-token, --tls-cert, --tls-key, --rate
};

v1::Body AddShape(v1::SceneService::Stub& stub, const std::string& shape, const std::string& id,
                  const Vec3& at) {
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
  wire::AddSceneHeader(&ctx, "default");
  v1::Body body;
  auto w = stub.AddBody(&ctx, &body);
  v1::AddBodyRequest r;
  auto* h = r.mutable_header();
  h->set_scene_id("default");
  h->set_shape(shape);
  h->mutable_spec()->set_body_id(id);
  wire::ToProto(Pose::FromTranslation(at), h->mutable_spec()->mutable_pose());
  w->Write(r);
  w->WritesDone();
  const grpc::Status s = w->Finish();
  if (!s.ok()) throw CommandError("demo: adding " + shape + ": " + s.error_message());
  return body;
}

struct Run {
  std::string mode;
  std::string effects;  // the servo loop's effect stages
  device::ServoStats stats;
  client::SessionStats net;
  std::vector<device::TrajectorySample> samples;
  bool realtime = false;
};

/// What one run uses: scene, probe, mode, effects, hand script.
struct RunSpec {
  std::string mode;  // "none", "pdt" or "pdg"
  int port = 0;
  std::string scene_id = "default";
  std::string probe_shape = "stick";
  std::optional<v1::InlineMesh> probe_mesh;  // instead of probe_shape
  device::EffectSet effects = device::EffectSet::ContactAndTorque();
  device::EffectParams effect_params;
  device::ScriptParams script;  // duration_s is set per run
  /// The probe's lowest point starts 5 mm above this point.
  Vec3 above = Vec3::Zero();
  std::optional<client::LinkOptions> link;  // an emulated wide-area link
  bool local_model = true;                  // client::SessionOptions::local_model
};

const char* ModeLabel(const std::string& mode) {
  return mode == "pdg" ? "PDg" : mode == "pdt" ? "PDt" : "none";
}

v1::PdMode ModeOf(const std::string& mode) {
  return mode == "pdg" ? v1::PD_MODE_PDG : mode == "pdt" ? v1::PD_MODE_PDT : v1::PD_MODE_NONE;
}

Run RunMode(const RunSpec& spec, double duration) {
  const std::string& mode = spec.mode;
  client::SessionOptions so;
  so.server = "127.0.0.1:" + std::to_string(spec.port);
  so.hello.set_scene_id(spec.scene_id);
  so.hello.set_mode(ModeOf(mode));
  if (spec.probe_mesh) {
    *so.hello.mutable_probe_mesh() = *spec.probe_mesh;
  } else {
    so.hello.set_probe_shape(spec.probe_shape);
  }
  so.hello.set_client_name("hapticpd demo (" + mode + ")");
  so.link = spec.link;
  so.local_model = spec.local_model;
  client::Session session(so);
  try {
    session.Connect();
  } catch (const client::SessionError& e) {
    throw CommandError(std::string("demo: ") + e.what());
  }
  const v1::Welcome& w = session.welcome();
  const double below_com = w.probe_body_frame().position().z() - w.probe_mesh_info().aabb_min().z();
  const Vec3 start = spec.above + Vec3(0, 0, std::max(0.0, below_com) + 0.005);
  device::ScriptParams sp = spec.script;
  sp.duration_s = duration;
  const auto& clock = device::SteadyClock::Instance();
  device::SimulatedDevice sim(sp, &clock);
  device::RecordingDevice rec(&sim, static_cast<std::size_t>(duration * 1100) + 2000);
  rec.Open();
  device::ServoConfig config;
  config.X_PA = session.X_PA();
  config.X_WD = Pose::FromTranslation(start);
  config.effects = spec.effects;
  config.effect_params = spec.effect_params;
  device::ServoLoop loop(&rec, config, &clock);
  session.Start(&loop);
  loop.Start();
  std::this_thread::sleep_for(std::chrono::duration<double>(duration + 0.2));
  loop.Stop();
  session.Stop();
  rec.Close();
  Run r;
  r.mode = mode;
  r.effects = loop.effects().description();
  r.stats = loop.stats();
  r.net = session.stats();
  r.samples = rec.samples();
  r.realtime = loop.got_realtime_priority();
  return r;
}

void WriteCsv(const std::filesystem::path& path, const std::vector<Run>& runs) {
  std::ofstream f(path);
  if (!f) throw CommandError("demo: cannot write " + path.string());
  f << "mode,t_s,px,py,pz,fx,fy,fz,tx,ty,tz\n";
  char line[512];
  for (const Run& r : runs) {
    for (const auto& s : r.samples) {
      const Vec3& p = s.state.X_DH.t;
      const Vec3& F = s.F_cmd_D.force;
      const Vec3& T = s.F_cmd_D.torque;
      std::snprintf(line, sizeof(line), "%s,%.4f,%.6f,%.6f,%.6f,%.5f,%.5f,%.5f,%.6f,%.6f,%.6f\n",
                    r.mode.c_str(), s.t_s, p.x(), p.y(), p.z(), F.x(), F.y(), F.z(), T.x(), T.y(),
                    T.z());
      f << line;
    }
  }
  if (!f) throw CommandError("demo: error writing " + path.string());
}

/// The time intervals (s) in which the commanded force exceeds 2 % of the
/// run's peak (and 0.01 N): where the probe is in contact. Gaps shorter
/// than 20 ms are bridged, so a bounce reads as one contact.
std::vector<std::pair<double, double>> ContactBands(const Run& r) {
  double peak = 0;
  for (const auto& s : r.samples) peak = std::max(peak, s.F_cmd_D.force.norm());
  const double threshold = std::max(0.02 * peak, 0.01);
  std::vector<std::pair<double, double>> bands;
  for (const auto& s : r.samples) {
    if (!(s.F_cmd_D.force.norm() > threshold)) continue;
    if (!bands.empty() && s.t_s - bands.back().second < 0.02) {
      bands.back().second = s.t_s;
    } else {
      bands.emplace_back(s.t_s, s.t_s);
    }
  }
  return bands;
}

/// Force magnitude (N) and torque magnitude (x100, N cm) versus time, one
/// panel per mode, plain SVG (client/bench/svg.h).
void WriteSvg(const std::filesystem::path& path, const std::vector<Run>& runs) {
  double tmax = 0.1, fmax = 0.5;
  for (const Run& r : runs) {
    for (const auto& s : r.samples) {
      tmax = std::max(tmax, s.t_s);
      fmax = std::max({fmax, s.F_cmd_D.force.norm(), 100 * s.F_cmd_D.torque.norm()});
    }
  }
  svg::Figure fig;
  for (const Run& r : runs) {
    svg::Panel& p = fig.panels.emplace_back();
    p.title = std::string(ModeLabel(r.mode)) + ": commanded force and torque vs time (s)";
    p.x_min = 0;
    p.x_max = tmax;
    p.y_min = 0;
    p.y_max = 1.1 * fmax;
    p.series.resize(2);  // both first: a reference into the vector survives no growth
    svg::Series& force = p.series[0];
    svg::Series& torque = p.series[1];
    force.label = "|F| (N)";
    torque.label = "|tau| (N cm)";
    torque.color = "#c0392b";
    for (const auto& s : r.samples) {
      force.x.push_back(s.t_s);
      force.y.push_back(s.F_cmd_D.force.norm());
      torque.x.push_back(s.t_s);
      torque.y.push_back(100 * s.F_cmd_D.torque.norm());
    }
    p.bands = ContactBands(r);
    p.band_label = "in contact (|F| > 2 % of peak)";
  }
  try {
    svg::Write(path, fig);
  } catch (const std::runtime_error& e) {
    throw CommandError(std::string("demo: ") + e.what());
  }
}

/// Every option checked, and the scene file read, before the server starts:
/// the run's common spec (link, local model, the file's probe and script).
RunSpec CheckedDemoSpec(const DemoOptions& o, std::optional<wire::SceneFile>* file) {
  if (!(o.duration >= 0.5) || !std::isfinite(o.duration) || o.duration > 600) {
    throw CommandError("demo: --duration: expected 0.5 to 600 seconds per mode");
  }
  std::error_code ec;
  std::filesystem::create_directories(o.out, ec);
  if (ec) throw CommandError("demo: --out: cannot create " + o.out + ": " + ec.message());

  if (!(o.travel >= 0) || o.travel > 0.2) {
    throw CommandError("demo: --travel: expected 0 to 0.2 m");
  }
  if (const std::string problem = client::LinkOptionsProblem(o.link); !problem.empty()) {
    throw CommandError("demo: " + problem);
  }
  RunSpec base;
  if (o.local_model != "on" && o.local_model != "off") {
    throw CommandError("demo: --local-model: expected on or off, got '" + o.local_model + "'");
  }
  base.local_model = o.local_model == "on";
  // No delay, jitter or loss: no emulator at all (the session's direct path).
  if (o.link.delay_ms > 0 || o.link.jitter_ms > 0 || o.link.loss > 0) base.link = o.link;
  if (!o.scene_file.empty()) {
    try {
      *file = wire::ParseSceneFile(o.scene_file);
      base.script.script = device::ParseHandScript(o.script);
    } catch (const wire::SceneFileError& e) {
      throw CommandError(std::string("demo: --scene: ") + e.what());
    } catch (const std::invalid_argument& e) {
      throw CommandError(std::string("demo: --script: ") + e.what());
    }
    if (!(*file)->probe.mesh_path.empty()) {
      try {
        wire::ToProto(pd::LoadMesh((*file)->probe.mesh_path), &base.probe_mesh.emplace());
      } catch (const pd::MeshError& e) {
        throw CommandError("demo: --scene: " + o.scene_file + ": probe.mesh: " + e.what());
      }
    } else if (!(*file)->probe.shape.empty()) {
      base.probe_shape = (*file)->probe.shape;
    }
  }

  return base;
}

/// The demo's scene: the default knot and cup added here, or the scene file
/// the server loaded. Sets where the hand starts and how far it travels, the
/// scene's effects and modes; returns the scene's line for the header.
std::string SetUpScene(v1::SceneService::Stub& scenes, const DemoOptions& o,
                       const std::optional<wire::SceneFile>& file, RunSpec* base,
                       std::vector<std::string>* modes) {
  char scene_line[512];
  if (!file) {
    const v1::Body knot = AddShape(scenes, "torusknot", "knot", Vec3::Zero());
    const Vec3 kmin = wire::FromProtoUnchecked(knot.mesh_info().aabb_min());
    const Vec3 cup_at(kmin.x() - 0.09, 0, kmin.z());  // clear of the knot
    const v1::Body cup = AddShape(scenes, "cup", "cup", cup_at);
    const Vec3 cup_max = cup_at + wire::FromProtoUnchecked(cup.mesh_info().aabb_max());
    // Above the cup's axis, the stick's tip 5 mm above the rim; the hand
    // pushes the tip down to 5 mm below the cup's base, i.e. into its floor.
    base->above = Vec3(cup_at.x(), cup_at.y(), cup_max.z());
    base->script.script = device::HandScript::kPress;
    base->script.travel = (cup_max.z() - cup_at.z()) + 0.01;
    std::snprintf(scene_line, sizeof(scene_line),
                  "scene 'default': torus knot (%u triangles) and cup (%u triangles), probe: stick",
                  knot.mesh_info().triangles(), cup.mesh_info().triangles());
  } else {
    base->scene_id = file->scene_id;
    grpc::ClientContext ctx;
    wire::AddSceneHeader(&ctx, base->scene_id);
    v1::GetSceneRequest req;
    req.set_scene_id(base->scene_id);
    v1::Scene scene;
    if (const grpc::Status s = scenes.GetScene(&ctx, req, &scene); !s.ok()) {
      throw CommandError("demo: GetScene: " + s.error_message());
    }
    // Centred above the scene's bounding box; the hand goes down by --travel.
    const auto [lo, hi] = SceneBox(scene);
    base->above = Vec3(0.5 * (lo.x() + hi.x()), 0.5 * (lo.y() + hi.y()), hi.z());
    base->script.travel = o.travel + 0.005;  // from 5 mm above the top
    base->effects = client::EffectsFromSceneConfig(scene.config());
    base->effect_params = client::EffectParamsFromSceneConfig(scene.config());
    if (scene.config().pd_mode() != v1::PD_MODE_UNSPECIFIED) {
      *modes = {wire::PdModeName(scene.config().pd_mode())};
    }
    std::snprintf(scene_line, sizeof(scene_line),
                  "scene '%s' from %s: %d bodies, probe: %s, effects: %s, script: %s",
                  base->scene_id.c_str(), o.scene_file.c_str(), scene.bodies_size(),
                  base->probe_mesh ? file->probe.mesh_path.c_str() : base->probe_shape.c_str(),
                  base->effects.ToString().c_str(), device::ToString(base->script.script));
  }

  return scene_line;
}

/// The runs' table, energy and the observer's view.
void PrintSummary(const std::vector<Run>& runs, std::uint64_t frames, double observed_depth) {
  std::printf("\n%-5s %10s %9s %9s %6s %9s %9s %9s %9s %9s %9s %9s\n", "mode", "loop Hz", "p99 us",
              "jitter", "late", "updates", "contact", "rtt p50", "rtt p99", "PD p50", "peak F",
              "peak dF");
  for (const Run& r : runs) {
    const double mean = r.stats.period_us.mean();
    std::printf("%-5s %10.1f %9.0f %9.1f %6llu %9llu %9llu %9.0f %9.0f %9.0f %9.2f %9.3f\n",
                ModeLabel(r.mode), mean > 0 ? 1e6 / mean : 0.0, r.stats.period_us.Quantile(0.99),
                r.stats.period_us.stddev(), static_cast<unsigned long long>(r.stats.late_ticks),
                static_cast<unsigned long long>(r.net.updates),
                static_cast<unsigned long long>(r.net.contact_updates), r.net.rtt_p50_us,
                r.net.rtt_p99_us, r.net.server_compute_p50_us, r.stats.max_force,
                r.stats.max_dforce);
  }
  std::printf(
      "(period p99 and jitter = std of the period in us; rtt = pose sent -> its "
      "ContactUpdate, us; PD = server PD time, us; peak F in N, peak dF in N per tick)\n");
  std::printf("energy into the hand:");
  for (const Run& r : runs)
    std::printf(" %s %.4f J", ModeLabel(r.mode), r.stats.energy_into_hand_j);
  std::printf("; observer: %llu frames, deepest probe %.2f mm%s\n",
              static_cast<unsigned long long>(frames), 1e3 * observed_depth,
              runs[0].realtime ? "; servo thread SCHED_FIFO" : "");
  std::printf("servo effects: %s\n", runs[0].effects.c_str());
}

void RunDemo(const DemoOptions& o) {
  std::optional<wire::SceneFile> file;
  RunSpec base = CheckedDemoSpec(o, &file);

  // With --view, SIGINT and SIGTERM end the demo after the run: blocked in
  // every thread started from here on, taken by sigwait below.
  sigset_t stop_signals;
  sigemptyset(&stop_signals);
  sigaddset(&stop_signals, SIGINT);
  sigaddset(&stop_signals, SIGTERM);
  if (o.view) pthread_sigmask(SIG_BLOCK, &stop_signals, nullptr);

  const auto level = spdlog::get_level();
  spdlog::set_level(spdlog::level::warn);  // the in-process server's info lines
  server::ServerOptions so = server::ServerOptions::InProcess();
  if (file) so.scene_files = {o.scene_file};  // loaded as `serve --scene` loads it
  server::HapticServer server(so);
  try {
    server.Start();
  } catch (const std::runtime_error& e) {
    spdlog::set_level(level);
    throw CommandError(std::string("demo: ") + e.what());
  }
  const int port = server.port();
  base.port = port;
  auto channel =
      grpc::CreateChannel("127.0.0.1:" + std::to_string(port), grpc::InsecureChannelCredentials());
  auto scenes = v1::SceneService::NewStub(channel);
  std::vector<std::string> modes = {"pdt", "pdg"};
  const std::string scene_line = SetUpScene(*scenes, o, file, &base, &modes);
  // An observer, as a viewer would attach one.
  grpc::ClientContext watch_ctx;
  std::atomic<std::uint64_t> frames{0};
  std::atomic<double> observed_depth{0};
  std::thread watcher([&] {
    v1::WatchRequest req;
    req.set_scene_id(base.scene_id);
    req.set_rate_hz(60);
    wire::AddSceneHeader(&watch_ctx, base.scene_id);
    auto reader = scenes->Watch(&watch_ctx, req);
    v1::SceneEvent ev;
    while (reader->Read(&ev)) {
      frames.fetch_add(1);
      if (ev.has_poses()) {
        for (const auto& p : ev.poses().probes()) {
          if (p.depth() > observed_depth.load()) observed_depth = p.depth();
        }
      }
    }
    reader->Finish();
  });

  std::printf("hapticpd demo: server on 127.0.0.1:%d, %s\n", port, scene_line.c_str());
  std::unique_ptr<viewer::Viewer> view;
  if (o.view) {
    ConnectionOptions conn;
    conn.server = "127.0.0.1:" + std::to_string(port);
    try {
      view = std::make_unique<viewer::Viewer>(ViewerOptionsFor(conn, base.scene_id, o.viewer));
      view->Start();
    } catch (const viewer::ViewerError& e) {
      server.Shutdown();
      spdlog::set_level(level);
      throw CommandError(std::string("demo: --view: ") + e.what());
    }
    std::printf("  viewer: %s\n", view->url().c_str());
  }
  if (base.link) {
    std::printf("  emulated link: %s\n", client::LinkDescription(*base.link).c_str());
  }
  std::vector<Run> runs;
  for (const std::string& mode : modes) {
    std::printf("  running %s for %.1f s ...\n", mode.c_str(), o.duration);
    std::fflush(stdout);
    RunSpec spec = base;
    spec.mode = mode;
    runs.push_back(RunMode(spec, o.duration));
  }
  watch_ctx.TryCancel();
  watcher.join();
  if (!view) {
    server.Shutdown();
    spdlog::set_level(level);
  }

  PrintSummary(runs, frames.load(), observed_depth.load());
  const std::filesystem::path out(o.out);
  WriteCsv(out / "trace.csv", runs);
  WriteSvg(out / "force.svg", runs);
  std::printf("wrote %s and %s\n", (out / "trace.csv").c_str(), (out / "force.svg").c_str());
  if (view) {
    std::printf("the run is over; the viewer keeps serving %s until Ctrl-C\n", view->url().c_str());
    std::fflush(stdout);
    int sig = 0;
    sigwait(&stop_signals, &sig);
    view->Stop();
    server.Shutdown();
    spdlog::set_level(level);
  }
  for (const Run& r : runs) {
    if (r.mode != "none" && r.net.contact_updates == 0) {
      throw CommandError("demo: the " + r.mode + " run never touched the " +
                         (file ? "scene" : "cup"));
    }
  }
}

}  // namespace

void RegisterDemo(CLI::App& app) {
  auto o = std::make_shared<DemoOptions>();
  auto* cmd = app.add_subcommand(
      "demo",
      "Everything in one process: server, procedural scene, simulated device (PDt then PDg)");
  cmd->add_option("--scene", o->scene_file,
                  "Scene file (JSON; README \"Scene files\"): bodies, probe, PD mode, effects");
  cmd->add_option("--script", o->script,
                  "With --scene: hand script (hold, press, slide, twist, circle, loop, plate)")
      ->capture_default_str();
  cmd->add_option("--travel", o->travel,
                  "With --scene: how far (m) the hand goes below the scene's top")
      ->capture_default_str();
  cmd->add_option("--duration", o->duration, "Seconds per mode")->capture_default_str();
  cmd->add_option("--out", o->out, "Folder for trace.csv and force.svg")->capture_default_str();
  AddLinkOptions(cmd, &o->link);
  cmd->add_option("--local-model", o->local_model,
                  "on: PD on geometry patches on the device side at the proxy's newest pose; "
                  "off: the server's answers only")
      ->capture_default_str();
  cmd->add_flag("--view", o->view,
                "Serve the scene to a browser (hapticpd view) during the run and after it, "
                "until Ctrl-C");
  AddViewerFlags(cmd, &o->viewer);
  cmd->callback([o] { RunDemo(*o); });
}

}  // namespace hapticpd::cli
