// The servo loop in real time: a simulated hand pressing a stick probe into
// a torus knot, the 1 kHz loop on its own thread (absolute deadlines), and
// its contact answers computed on the same machine. By default they come
// through the real server: a hapticpd server in-process on 127.0.0.1
// (ephemeral port), the knot added with SceneService.AddBody, and a
// client::Session in PDt mode with the stick probe feeding the loop's
// mailboxes, exactly as `hapticpd device` and `hapticpd demo` do. With
// --local a LocalPdIrSource worker thread computes PDt in-process instead
// (no gRPC, no network), for comparison. With --patches the session runs
// the local contact model (device/local_model.h), as `hapticpd device` does
// by default: the server streams geometry patches and the model's worker
// thread answers on them; --delay MS puts an emulated one-way delay (+-20 %
// jitter) between the loop and the server. Reports tick compute time (goal
// p99 <= 20 us) and period jitter (goal p99 period error <= 100 us, < 0.1%
// late ticks), and the IR path's round trip, PD time, rate and IR age.
// --csv FILE also writes those figures as one CSV row under a header
// (tests/bench/update_readme.py renders the README's table from it).
//
//   bench_servo [--seconds S] [--script hold|press|slide|twist|circle|loop|plate]
//               [--local | --patches [--delay MS]] [--csv FILE]
#include <grpcpp/grpcpp.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "client/session.h"
#include "device/local_pd_source.h"
#include "device/servo_loop.h"
#include "device/simulated_device.h"
#include "hapticpd/v1/scene.grpc.pb.h"
#include "pd/shapes.h"
#include "server/server.h"

using namespace hapticpd;
using namespace hapticpd::device;

namespace {

constexpr double kStiffness = 3000;   // N/m, the knot's material in both modes
constexpr double kClearance = 0.005;  // m between the stick's tip and the knot's top at start
constexpr double kKnotX = 0.075;      // m: the start is over a strand of the knot (at y = 0)

struct Args {
  double seconds = 10;
  std::string script = "loop";
  bool local = false;
  bool patches = false;
  double delay_ms = 0;
  std::string csv;  ///< write the figures here too (empty: no CSV)
};

/// One line on stderr naming the problem; exit status 2.
[[noreturn]] void Usage(const std::string& problem) {
  std::fprintf(stderr,
               "bench_servo: %s (usage: bench_servo [--seconds S] [--script "
               "hold|press|slide|twist|circle|loop|plate] [--local | --patches [--delay MS]] "
               "[--csv FILE])\n",
               problem.c_str());
  std::exit(2);
}

Args ParseArgs(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--local") {
      a.local = true;
    } else if (arg == "--patches") {
      a.patches = true;
    } else if (arg == "--seconds" || arg == "--script" || arg == "--delay" || arg == "--csv") {
      if (i + 1 >= argc) Usage(arg + ": missing value");
      const std::string v = argv[++i];
      if (arg == "--script") {
        a.script = v;
        continue;
      }
      if (arg == "--csv") {
        a.csv = v;
        continue;
      }
      char* end = nullptr;
      const double x = std::strtod(v.c_str(), &end);
      if (arg == "--delay") {
        if (v.empty() || *end != '\0' || !std::isfinite(x) || x < 0 || x > 10000) {
          Usage("--delay: expected a one-way delay of 0 to 10000 ms, got '" + v + "'");
        }
        a.delay_ms = x;
        continue;
      }
      a.seconds = x;
      if (v.empty() || *end != '\0' || !std::isfinite(a.seconds) || !(a.seconds > 0)) {
        Usage("--seconds: expected a number of seconds > 0, got '" + v + "'");
      }
    } else {
      Usage("unknown argument '" + arg + "'");
    }
  }
  return a;
}

/// The top (z, m) of the knot's strand under the start point: its highest
/// vertex within 1 cm of (kKnotX, 0) in xy. (The knot's overall top is
/// elsewhere and 25 mm higher; a hand starting above that would never
/// reach the strand with the scripts' 2 cm travel.)
double StrandTop(const pd::Mesh& knot) {
  double top = -1e9;
  for (const Vec3& v : knot.vertices()) {
    if (std::hypot(v.x() - kKnotX, v.y()) < 0.01) top = std::max(top, v.z());
  }
  return top;
}

/// The hand: upright stick, its tip kClearance above the strand's top
/// (`strand_top_z`, world), `below_com` (m) from its centre of mass down to
/// its tip; the device frame is the world frame.
ScriptParams Hand(HandScript script, double strand_top_z, double below_com) {
  ScriptParams sp;
  sp.script = script;
  sp.X_DS = Pose::FromTranslation(Vec3(kKnotX, 0, strand_top_z + below_com + kClearance));
  sp.travel = 0.02;
  sp.duration_s = 4;  // afterwards the hand holds the script's end pose
  return sp;
}

double Quantile(std::vector<double> v, double f) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[static_cast<std::size_t>(f * static_cast<double>(v.size() - 1))];
}

/// The loop's lines, shared by both modes.
void PrintLoop(const ServoStats& s) {
  std::printf("tick compute us: p50 %.2f p99 %.2f p99.9 %.2f max %.1f (goal p99 <= 20)\n",
              s.compute_us.Quantile(0.5), s.compute_us.Quantile(0.99), s.compute_us.Quantile(0.999),
              s.compute_us.max());
  std::printf("period us: mean %.2f std %.2f p50 %.1f p99 %.1f p99.9 %.1f max %.1f\n",
              s.period_us.mean(), s.period_us.stddev(), s.period_us.Quantile(0.5),
              s.period_us.Quantile(0.99), s.period_us.Quantile(0.999), s.period_us.max());
}

/// The period error p99 (us) of the goal: the larger deviation of the
/// period's 1st and 99th percentiles from 1 ms.
double PeriodErrorP99(const ServoStats& s) {
  return std::max(std::abs(s.period_us.Quantile(0.99) - 1000.0),
                  std::abs(1000.0 - s.period_us.Quantile(0.01)));
}

/// The goal lines and a one-line verdict.
void PrintGoals(const ServoStats& s) {
  const double err99 = PeriodErrorP99(s);
  const double late_pct =
      s.ticks ? 100.0 * static_cast<double>(s.late_ticks) / static_cast<double>(s.ticks) : 0;
  std::printf(
      "period error p99 %.1f us (goal <= 100), late ticks %llu of %llu (%.4f%%, goal < 0.1%%)\n",
      err99, static_cast<unsigned long long>(s.late_ticks),
      static_cast<unsigned long long>(s.ticks), late_pct);
  std::printf("%s\n", s.Summary().c_str());
  const bool compute_ok = s.compute_us.Quantile(0.99) <= 20;
  const bool period_ok = err99 <= 100;
  const bool late_ok = s.ticks > 0 && late_pct < 0.1;
  std::printf(
      "goals: tick compute p99 <= 20 us %s; period error p99 <= 100 us %s; "
      "late ticks < 0.1%% %s\n",
      compute_ok ? "met" : "MISSED", period_ok ? "met" : "MISSED", late_ok ? "met" : "MISSED");
}

/// What the IR path measured besides the loop: answers per second, round
/// trip and PD time (us), the worker's or the server's.
struct IrPath {
  double answers_per_s = 0;
  double rtt_p50_us = 0, rtt_p99_us = 0;  ///< 0 without a server
  double pd_p50_us = 0, pd_p99_us = 0;
};

/// With --csv: one header line and one row of the run's figures.
void WriteCsv(const Args& a, const std::string& mode, bool realtime, const ServoStats& s,
              const IrPath& ir) {
  if (a.csv.empty()) return;
  std::ofstream out(a.csv);
  out << "mode,script,seconds,delay_ms,sched_fifo,ticks,late_ticks,compute_p50_us,"
         "compute_p99_us,compute_max_us,period_mean_us,period_std_us,period_p50_us,"
         "period_p99_us,period_max_us,period_error_p99_us,ir_updates,ir_age_p99_ms,stale_ticks,"
         "ticks_server,ticks_local,ticks_faded,max_force_n,energy_into_hand_j,passivity_min_j,"
         "answers_per_s,rtt_p50_us,rtt_p99_us,pd_p50_us,pd_p99_us\n";
  out << mode << "," << a.script << "," << a.seconds << "," << a.delay_ms << ","
      << (realtime ? 1 : 0) << "," << s.ticks << "," << s.late_ticks << ","
      << s.compute_us.Quantile(0.5) << "," << s.compute_us.Quantile(0.99) << ","
      << s.compute_us.max() << "," << s.period_us.mean() << "," << s.period_us.stddev() << ","
      << s.period_us.Quantile(0.5) << "," << s.period_us.Quantile(0.99) << "," << s.period_us.max()
      << "," << PeriodErrorP99(s) << "," << s.ir_updates << "," << s.ir_age_ms.Quantile(0.99) << ","
      << s.stale_ticks << "," << s.ticks_server << "," << s.ticks_local << "," << s.ticks_faded
      << "," << s.max_force << "," << s.energy_into_hand_j << "," << s.passivity_min_j << ","
      << ir.answers_per_s << "," << ir.rtt_p50_us << "," << ir.rtt_p99_us << "," << ir.pd_p50_us
      << "," << ir.pd_p99_us << "\n";
  if (!out) std::fprintf(stderr, "bench_servo: cannot write %s\n", a.csv.c_str());
}

int RunLocal(const Args& a, HandScript script) {
  pd::Material m;
  m.stiffness = kStiffness;
  const pd::ModelPtr knot = pd::MakeModel(pd::shapes::TorusKnot());
  const pd::ModelPtr stick = pd::MakeModel(pd::shapes::Stick());
  std::vector<pd::SceneBody> scene = {{knot, Pose::Identity(), m}};

  const SteadyClock& clock = SteadyClock::Instance();
  LocalPdIrSource source(stick, scene);
  // P sits at the stick's centre of mass, A at its mesh frame (the stick's
  // centre): the tip is half its 15 cm length below P.
  SimulatedDevice dev(Hand(script, StrandTop(knot->mesh()), 0.075), &clock);
  dev.Open();
  ServoConfig cfg;
  cfg.X_PA = source.X_PA();
  ServoLoop loop(&dev, cfg, &clock);

  const std::int64_t t0 = clock.NowNs();
  loop.Start();
  source.Start(&loop, &clock);
  const auto t_end = t0 + static_cast<std::int64_t>(a.seconds * 1e9);
  while (clock.NowNs() < t_end) std::this_thread::sleep_for(std::chrono::milliseconds(100));
  source.Stop();
  loop.Stop();
  const double elapsed = 1e-9 * static_cast<double>(clock.NowNs() - t0);
  dev.Close();

  const ServoStats& s = loop.stats();
  const std::vector<double>& pd = source.compute_times_us();
  std::printf(
      "bench_servo: %.1f s, mode local (LocalPdIrSource worker thread, PDt in-process, no "
      "server), script %s, SCHED_FIFO %s\n",
      a.seconds, a.script.c_str(), loop.got_realtime_priority() ? "yes" : "no (not permitted)");
  PrintLoop(s);
  std::printf(
      "PD worker: %zu answers (%.0f/s), PDt us p50 %.1f p99 %.1f; IR age ms p50 %.2f p99 %.2f\n",
      pd.size(), static_cast<double>(pd.size()) / elapsed, Quantile(pd, 0.5), Quantile(pd, 0.99),
      s.ir_age_ms.Quantile(0.5), s.ir_age_ms.Quantile(0.99));
  PrintGoals(s);
  WriteCsv(a, "local", loop.got_realtime_priority(), s,
           {static_cast<double>(pd.size()) / elapsed, 0, 0, Quantile(pd, 0.5), Quantile(pd, 0.99)});
  return 0;
}

/// The knot, added to the server's "default" scene at the origin with the
/// bench's stiffness; returns the body (its mesh_info has the bounding box).
v1::Body AddKnot(int port) {
  auto stub = v1::SceneService::NewStub(
      grpc::CreateChannel("127.0.0.1:" + std::to_string(port), grpc::InsecureChannelCredentials()));
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
  v1::Body body;
  auto w = stub->AddBody(&ctx, &body);
  v1::AddBodyRequest r;
  auto* h = r.mutable_header();
  h->set_scene_id("default");
  h->set_shape("torusknot");
  h->mutable_spec()->set_body_id("knot");
  h->mutable_spec()->mutable_pose()->mutable_orientation()->set_w(1);
  h->mutable_spec()->mutable_material()->set_stiffness(kStiffness);
  w->Write(r);
  w->WritesDone();
  const grpc::Status st = w->Finish();
  if (!st.ok()) throw std::runtime_error("adding the torus knot: " + st.error_message());
  return body;
}

int RunServer(const Args& a, HandScript script) {
  const auto level = spdlog::get_level();
  spdlog::set_level(spdlog::level::warn);  // the in-process server's info lines
  server::HapticServer server(server::ServerOptions::InProcess());
  server.Start();
  const int port = server.port();
  const v1::Body knot = AddKnot(port);

  client::SessionOptions opt;
  opt.server = "127.0.0.1:" + std::to_string(port);
  opt.hello.set_scene_id("default");
  opt.hello.set_mode(v1::PD_MODE_PDT);
  opt.hello.set_probe_shape("stick");
  opt.hello.set_client_name("bench_servo");
  opt.connect_timeout_s = 10;
  opt.local_model = a.patches;
  if (a.delay_ms > 0) {
    client::LinkOptions link;
    link.delay_ms = a.delay_ms;
    link.jitter_ms = 0.2 * a.delay_ms;
    opt.link = link;
  }
  client::Session session(opt);
  session.Connect();
  const v1::Welcome& welcome = session.welcome();
  const double below_com =
      welcome.probe_body_frame().position().z() - welcome.probe_mesh_info().aabb_min().z();

  const SteadyClock& clock = SteadyClock::Instance();
  SimulatedDevice dev(
      Hand(script, StrandTop(pd::shapes::TorusKnot()) /* the server's "torusknot" */,
           std::max(0.0, below_com)),
      &clock);
  dev.Open();
  ServoConfig cfg;
  cfg.X_PA = session.X_PA();
  cfg.effects = client::EffectsFromSceneConfig(welcome.scene_config());
  cfg.effect_params = client::EffectParamsFromSceneConfig(welcome.scene_config());
  ServoLoop loop(&dev, cfg, &clock);

  const std::int64_t t0 = clock.NowNs();
  session.Start(&loop);
  loop.Start();
  std::this_thread::sleep_for(std::chrono::duration<double>(a.seconds));
  loop.Stop();
  const double elapsed = 1e-9 * static_cast<double>(clock.NowNs() - t0);
  session.Stop();
  dev.Close();
  const client::SessionStats net = session.stats();
  const std::uint64_t pd_calls = server.counts().pd_calls;
  server.Shutdown();
  spdlog::set_level(level);

  const ServoStats& s = loop.stats();
  std::printf(
      "bench_servo: %.1f s, mode server%s (hapticpd server in-process on 127.0.0.1:%d, "
      "client::Session PDt, probe stick, knot %u triangles, one-way delay %.0f ms), script %s, "
      "SCHED_FIFO %s\n",
      a.seconds, a.patches ? " + local contact model" : "", port, knot.mesh_info().triangles(),
      a.delay_ms, a.script.c_str(), loop.got_realtime_priority() ? "yes" : "no (not permitted)");
  PrintLoop(s);
  std::printf(
      "session: %llu poses sent, %llu updates (%.0f/s, %llu in contact, %llu rejected), "
      "deepest %.2f mm, %llu server PD calls, %llu disconnects\n",
      static_cast<unsigned long long>(net.poses_sent), static_cast<unsigned long long>(net.updates),
      static_cast<double>(net.updates) / elapsed,
      static_cast<unsigned long long>(net.contact_updates),
      static_cast<unsigned long long>(net.bad_updates), 1e3 * net.max_depth,
      static_cast<unsigned long long>(pd_calls), static_cast<unsigned long long>(net.disconnects));
  std::printf(
      "round trip us (pose sent -> its ContactUpdate, %llu answered poses): p50 %.0f p99 %.0f "
      "max %.0f; server PD us p50 %.1f p99 %.1f; IR age ms p50 %.2f p99 %.2f\n",
      static_cast<unsigned long long>(net.rtt_samples), net.rtt_p50_us, net.rtt_p99_us,
      net.rtt_max_us, net.server_compute_p50_us, net.server_compute_p99_us,
      s.ir_age_ms.Quantile(0.5), s.ir_age_ms.Quantile(0.99));
  PrintGoals(s);
  WriteCsv(a, a.patches ? "patches" : "server", loop.got_realtime_priority(), s,
           {static_cast<double>(net.updates) / elapsed, net.rtt_p50_us, net.rtt_p99_us,
            net.server_compute_p50_us, net.server_compute_p99_us});
  if (net.updates == 0) {
    std::fprintf(stderr, "bench_servo: the server never answered (%s)\n",
                 net.last_error.empty() ? "no error reported" : net.last_error.c_str());
    return 1;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const Args a = ParseArgs(argc, argv);
  HandScript script;
  try {
    script = ParseHandScript(a.script);
  } catch (const std::invalid_argument& e) {
    Usage(std::string("--script: ") + e.what());
  }
  if (a.local && (a.patches || a.delay_ms > 0)) {
    Usage("--local runs without a server: --patches and --delay need the server mode");
  }
  if (a.local) return RunLocal(a, script);
  try {
    return RunServer(a, script);
  } catch (const std::exception& e) {  // server start, AddBody, Session::Connect
    std::fprintf(stderr, "bench_servo: %s\n", e.what());
    return 1;
  }
}
