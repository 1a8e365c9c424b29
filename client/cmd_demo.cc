// `hapticpd demo`: the whole pipeline on one machine with no downloads. A
// server in-process on 127.0.0.1, a built-in procedural scene (a torus knot
// and a cup), an observer, and a simulated hand pressing a stick probe into
// the cup's floor through the network Session and the 1 kHz servo loop, first in
// PDt then in PDg. Prints a short report and writes trace.csv and force.svg.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <thread>
#include <vector>

#include "client/commands.h"
#include "client/session.h"
#include "device/replay_device.h"
#include "device/servo_loop.h"
#include "device/simulated_device.h"
#include "hapticpd/v1/scene.grpc.pb.h"
#include "server/server.h"

namespace hapticpd::cli {
namespace {

using device::Pose;
using device::Vec3;

struct DemoOptions {
  double duration = 3;  // per mode
  std::string out = "hapticpd-demo";
};

Vec3 ToVec(const v1::Vec3& v) { return Vec3(v.x(), v.y(), v.z()); }

v1::Body AddShape(v1::SceneService::Stub& stub, const std::string& shape, const std::string& id,
                  const Vec3& at) {
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
  v1::Body body;
  auto w = stub.AddBody(&ctx, &body);
  v1::AddBodyRequest r;
  auto* h = r.mutable_header();
  h->set_scene_id("default");
  h->set_shape(shape);
  h->mutable_spec()->set_body_id(id);
  h->mutable_spec()->mutable_pose()->mutable_position()->set_x(at.x());
  h->mutable_spec()->mutable_pose()->mutable_position()->set_y(at.y());
  h->mutable_spec()->mutable_pose()->mutable_position()->set_z(at.z());
  h->mutable_spec()->mutable_pose()->mutable_orientation()->set_w(1);
  w->Write(r);
  w->WritesDone();
  const grpc::Status s = w->Finish();
  if (!s.ok()) throw CommandError("demo: adding " + shape + ": " + s.error_message());
  return body;
}

struct Run {
  std::string mode;
  device::ServoStats stats;
  client::SessionStats net;
  std::vector<device::TrajectorySample> samples;
  bool realtime = false;
};

Run RunMode(const std::string& mode, int port, const Vec3& cup_at, const Vec3& cup_max,
            double duration) {
  client::SessionOptions so;
  so.server = "127.0.0.1:" + std::to_string(port);
  so.hello.set_scene_id("default");
  so.hello.set_mode(mode == "pdg" ? v1::PD_MODE_PDG : v1::PD_MODE_PDT);
  so.hello.set_probe_shape("stick");
  so.hello.set_client_name("hapticpd demo (" + mode + ")");
  client::Session session(so);
  try {
    session.Connect();
  } catch (const client::SessionError& e) {
    throw CommandError(std::string("demo: ") + e.what());
  }
  const v1::Welcome& w = session.welcome();
  const double below_com = w.probe_body_frame().position().z() - w.probe_mesh_info().aabb_min().z();
  // Above the cup's axis, the stick's tip 5 mm above the rim; the hand
  // pushes the tip down to 5 mm below the cup's base, i.e. into its floor.
  const Vec3 start(cup_at.x(), cup_at.y(), cup_max.z() + below_com + 0.005);
  const double travel = (cup_max.z() - cup_at.z()) + 0.01;
  device::ScriptParams sp;
  sp.script = device::HandScript::kPress;
  sp.duration_s = duration;
  sp.travel = travel;
  const auto& clock = device::SteadyClock::Instance();
  device::SimulatedDevice sim(sp, &clock);
  device::RecordingDevice rec(&sim, static_cast<std::size_t>(duration * 1100) + 2000);
  rec.Open();
  device::ServoConfig config;
  config.X_PA = session.X_PA();
  config.X_WD = Pose::FromTranslation(start);
  device::ServoLoop loop(&rec, config, &clock);
  session.Start(&loop);
  loop.Start();
  std::this_thread::sleep_for(std::chrono::duration<double>(duration + 0.2));
  loop.Stop();
  session.Stop();
  rec.Close();
  Run r;
  r.mode = mode;
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

/// Force magnitude (N) and torque magnitude (x100, N cm) versus time, one
/// panel per mode, plain SVG.
void WriteSvg(const std::filesystem::path& path, const std::vector<Run>& runs) {
  const double W = 760, H = 220, L = 60, R = 20, T = 30, B = 40;
  double tmax = 0.1, fmax = 0.5;
  for (const Run& r : runs) {
    for (const auto& s : r.samples) {
      tmax = std::max(tmax, s.t_s);
      fmax = std::max({fmax, s.F_cmd_D.force.norm(), 100 * s.F_cmd_D.torque.norm()});
    }
  }
  fmax *= 1.1;
  std::ofstream f(path);
  if (!f) throw CommandError("demo: cannot write " + path.string());
  const double total_h = H * static_cast<double>(runs.size());
  f << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << W << "\" height=\"" << total_h
    << "\" font-family=\"sans-serif\" font-size=\"12\">\n<rect width=\"100%\" height=\"100%\" "
       "fill=\"white\"/>\n";
  char buf[256];
  for (std::size_t k = 0; k < runs.size(); ++k) {
    const double y0 = H * static_cast<double>(k);
    const double pw = W - L - R, ph = H - T - B;
    auto X = [&](double t) { return L + pw * t / tmax; };
    auto Y = [&](double v) { return y0 + T + ph * (1 - v / fmax); };
    std::snprintf(buf, sizeof(buf),
                  "<text x=\"%g\" y=\"%g\" font-weight=\"bold\">%s: force |F| (N, blue), torque "
                  "|tau| (N cm, red) vs time (s)</text>\n",
                  L, y0 + 18, runs[k].mode == "pdg" ? "PDg" : "PDt");
    f << buf;
    std::snprintf(buf, sizeof(buf),
                  "<rect x=\"%g\" y=\"%g\" width=\"%g\" height=\"%g\" fill=\"none\" "
                  "stroke=\"#888\"/>\n",
                  L, y0 + T, pw, ph);
    f << buf;
    for (int i = 0; i <= 4; ++i) {
      const double v = fmax * i / 4, t = tmax * i / 4;
      std::snprintf(buf, sizeof(buf),
                    "<text x=\"%g\" y=\"%g\" text-anchor=\"end\">%.2g</text>\n"
                    "<text x=\"%g\" y=\"%g\" text-anchor=\"middle\">%.2g</text>\n",
                    L - 4, Y(v) + 4, v, X(t), y0 + H - B + 16, t);
      f << buf;
    }
    for (int which = 0; which < 2; ++which) {
      f << "<polyline fill=\"none\" stroke=\"" << (which == 0 ? "#1f5fbf" : "#c0392b")
        << "\" stroke-width=\"1.2\" points=\"";
      const auto& ss = runs[k].samples;
      const std::size_t step = std::max<std::size_t>(1, ss.size() / 1500);
      for (std::size_t i = 0; i < ss.size(); i += step) {
        const double v =
            which == 0 ? ss[i].F_cmd_D.force.norm() : 100 * ss[i].F_cmd_D.torque.norm();
        std::snprintf(buf, sizeof(buf), "%.1f,%.1f ", X(ss[i].t_s), Y(v));
        f << buf;
      }
      f << "\"/>\n";
    }
  }
  f << "</svg>\n";
  if (!f) throw CommandError("demo: error writing " + path.string());
}

void RunDemo(const DemoOptions& o) {
  if (!(o.duration >= 0.5) || !std::isfinite(o.duration) || o.duration > 600) {
    throw CommandError("demo: --duration: expected 0.5 to 600 seconds per mode");
  }
  const std::filesystem::path out(o.out);
  std::error_code ec;
  std::filesystem::create_directories(out, ec);
  if (ec) throw CommandError("demo: --out: cannot create " + out.string() + ": " + ec.message());

  const auto level = spdlog::get_level();
  spdlog::set_level(spdlog::level::warn);  // the in-process server's info lines
  server::ServerOptions so;
  so.listen = "127.0.0.1:0";
  so.status_interval_s = 0;
  so.shutdown_grace_s = 0.5;
  server::HapticServer server(so);
  server.Start();
  const int port = server.port();
  auto channel =
      grpc::CreateChannel("127.0.0.1:" + std::to_string(port), grpc::InsecureChannelCredentials());
  auto scenes = v1::SceneService::NewStub(channel);
  const v1::Body knot = AddShape(*scenes, "torusknot", "knot", Vec3::Zero());
  const Vec3 kmin = ToVec(knot.mesh_info().aabb_min());
  const Vec3 cup_at(kmin.x() - 0.09, 0, kmin.z());  // clear of the knot
  const v1::Body cup = AddShape(*scenes, "cup", "cup", cup_at);

  // An observer, as a viewer would attach one.
  grpc::ClientContext watch_ctx;
  std::atomic<std::uint64_t> frames{0};
  std::atomic<double> observed_depth{0};
  std::thread watcher([&] {
    v1::WatchRequest req;
    req.set_scene_id("default");
    req.set_rate_hz(60);
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

  std::printf(
      "hapticpd demo: server on 127.0.0.1:%d, scene 'default': torus knot (%u triangles) "
      "and cup (%u triangles), probe: stick\n",
      port, knot.mesh_info().triangles(), cup.mesh_info().triangles());
  std::vector<Run> runs;
  for (const char* mode : {"pdt", "pdg"}) {
    std::printf("  running %s for %.1f s ...\n", mode, o.duration);
    std::fflush(stdout);
    runs.push_back(
        RunMode(mode, port, cup_at, cup_at + ToVec(cup.mesh_info().aabb_max()), o.duration));
  }
  watch_ctx.TryCancel();
  watcher.join();
  server.Shutdown();
  spdlog::set_level(level);

  std::printf("\n%-5s %10s %9s %9s %6s %9s %9s %9s %9s %9s %9s %9s\n", "mode", "loop Hz", "p99 us",
              "jitter", "late", "updates", "contact", "rtt p50", "rtt p99", "PD p50", "peak F",
              "peak dF");
  for (const Run& r : runs) {
    const double mean = r.stats.period_us.mean();
    std::printf("%-5s %10.1f %9.0f %9.1f %6llu %9llu %9llu %9.0f %9.0f %9.0f %9.2f %9.3f\n",
                r.mode == "pdg" ? "PDg" : "PDt", mean > 0 ? 1e6 / mean : 0.0,
                r.stats.period_us.Quantile(0.99), r.stats.period_us.stddev(),
                static_cast<unsigned long long>(r.stats.late_ticks),
                static_cast<unsigned long long>(r.net.updates),
                static_cast<unsigned long long>(r.net.contact_updates), r.net.rtt_p50_us,
                r.net.rtt_p99_us, r.net.server_compute_p50_us, r.stats.max_force,
                r.stats.max_dforce);
  }
  std::printf(
      "(period p99 and jitter = std of the period in us; rtt = pose sent -> its "
      "ContactUpdate, us; PD = server PD time, us; peak F in N, peak dF in N per tick)\n");
  std::printf(
      "energy into the hand: PDt %.4f J, PDg %.4f J; observer: %llu frames, deepest "
      "probe %.2f mm%s\n",
      runs[0].stats.energy_into_hand_j, runs[1].stats.energy_into_hand_j,
      static_cast<unsigned long long>(frames.load()), 1e3 * observed_depth.load(),
      runs[0].realtime ? "; servo thread SCHED_FIFO" : "");
  WriteCsv(out / "trace.csv", runs);
  WriteSvg(out / "force.svg", runs);
  std::printf("wrote %s and %s\n", (out / "trace.csv").c_str(), (out / "force.svg").c_str());
  for (const Run& r : runs) {
    if (r.net.contact_updates == 0) {
      throw CommandError("demo: the " + r.mode + " run never touched the cup");
    }
  }
}

}  // namespace

void RegisterDemo(CLI::App& app) {
  auto o = std::make_shared<DemoOptions>();
  auto* cmd = app.add_subcommand(
      "demo",
      "Everything in one process: server, procedural scene, simulated device (PDt then PDg)");
  cmd->add_option("--duration", o->duration, "Seconds per mode")->capture_default_str();
  cmd->add_option("--out", o->out, "Folder for trace.csv and force.svg")->capture_default_str();
  cmd->callback([o] { RunDemo(*o); });
}

}  // namespace hapticpd::cli
