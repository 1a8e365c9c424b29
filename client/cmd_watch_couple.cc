// `hapticpd watch`: an observer printing one line per scene event.
// `hapticpd couple`: a scripted device session (a probe swept back and forth
// along a segment) printing the answer rate and pose -> ContactUpdate round
// trips. A test and demo client, not the 1 kHz haptic servo loop.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <iostream>
#include <thread>
#include <vector>

#include "client/rpc_util.h"
#include "hapticpd/v1/haptic.grpc.pb.h"
#include "hapticpd/v1/scene.grpc.pb.h"

namespace hapticpd::cli {
namespace {

std::int64_t SteadyNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

struct WatchOptions {
  ConnectionOptions conn;
  std::string scene = "default";
  double rate = 60;
  int count = 0;
};

void RunWatch(const WatchOptions& o) {
  auto stub = v1::SceneService::NewStub(MakeChannel(o.conn));
  auto ctx = MakeSceneContext(o.conn, o.scene, true);
  v1::WatchRequest req;
  req.set_scene_id(o.scene);
  req.set_rate_hz(o.rate);
  auto reader = stub->Watch(ctx.get(), req);
  v1::SceneEvent ev;
  int n = 0;
  while (reader->Read(&ev)) {
    std::cout << "revision " << ev.revision() << " ";
    if (ev.has_snapshot()) {
      std::cout << "snapshot: " << ev.snapshot().bodies_size() << " bodies";
      for (const auto& b : ev.snapshot().bodies()) std::cout << " " << b.body_id();
    } else if (ev.has_changes()) {
      std::cout << "changes:";
      for (const auto& b : ev.changes().added()) std::cout << " +" << b.body_id();
      for (const auto& id : ev.changes().removed()) std::cout << " -" << id;
    } else if (ev.has_poses()) {
      std::cout << "poses: " << ev.poses().bodies_size() << " bodies, " << ev.poses().probes_size()
                << " probes";
      for (const auto& p : ev.poses().probes()) {
        std::cout << " [" << p.session_id() << " depth " << p.depth() << "]";
      }
    }
    // Flushed per line: a pipe or file would otherwise hold the lines until
    // exit, and Ctrl-C (the usual end of a watch) would lose them.
    std::cout << " (dropped " << ev.frames_dropped() << ")" << std::endl;
    if (o.count > 0 && ++n >= o.count) {
      ctx->TryCancel();
      break;
    }
  }
  const grpc::Status s = reader->Finish();
  if (o.count > 0 && n >= o.count) return;
  Check(s, "watch");
}

struct CoupleOptions {
  ConnectionOptions conn;
  std::string scene = "default";
  std::string probe_shape = "sphere:0.01,2";
  std::string probe_body;
  std::string mode = "pdt";
  std::string from = "0,0,0.1", to = "0,0,-0.1";
  double rate = 1000;
  double duration = 5;
  double period = 2;
};

void RunCouple(const CoupleOptions& o) {
  v1::PdMode mode;
  if (o.mode == "pdt")
    mode = v1::PD_MODE_PDT;
  else if (o.mode == "pdg")
    mode = v1::PD_MODE_PDG;
  else if (o.mode == "none")
    mode = v1::PD_MODE_NONE;
  else
    throw CommandError("couple: --mode: expected pdt, pdg or none, got '" + o.mode + "'");
  const v1::Pose a = ParsePose(o.from, "--from"), b = ParsePose(o.to, "--to");
  auto stub = v1::HapticService::NewStub(MakeChannel(o.conn));
  auto ctx = MakeSceneContext(o.conn, o.scene, true);
  auto stream = stub->Couple(ctx.get());
  v1::CoupleRequest hello;
  auto* h = hello.mutable_hello();
  h->set_protocol_version(1);
  h->set_scene_id(o.scene);
  h->set_mode(mode);
  h->set_client_name("hapticpd couple");
  if (!o.probe_body.empty())
    h->set_probe_body_id(o.probe_body);
  else
    h->set_probe_shape(o.probe_shape);
  if (!stream->Write(hello)) Check(stream->Finish(), "couple");
  v1::CoupleResponse resp;
  if (!stream->Read(&resp) || !resp.has_welcome()) Check(stream->Finish(), "couple");
  std::cout << "session " << resp.welcome().session_id() << " on scene '" << o.scene << "'"
            << std::endl;

  constexpr std::size_t kRing = 1 << 16;
  std::vector<std::int64_t> sent_ns(kRing, 0);
  std::atomic<bool> done{false};
  std::thread writer([&] {
    const auto period = std::chrono::nanoseconds(static_cast<std::int64_t>(1e9 / o.rate));
    const auto t0 = std::chrono::steady_clock::now();
    auto next = t0;
    v1::CoupleRequest req;
    for (std::uint64_t seq = 1; !done.load(); ++seq) {
      const double t = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      if (t >= o.duration) break;
      const double s = 0.5 - 0.5 * std::cos(2 * M_PI * t / o.period);  // 0 -> 1 -> 0
      auto* p = req.mutable_pose();
      p->set_sequence(seq);
      auto* pos = p->mutable_pose()->mutable_position();
      pos->set_x(a.position().x() + s * (b.position().x() - a.position().x()));
      pos->set_y(a.position().y() + s * (b.position().y() - a.position().y()));
      pos->set_z(a.position().z() + s * (b.position().z() - a.position().z()));
      const std::int64_t now = SteadyNs();
      sent_ns[seq % kRing] = now;
      p->set_client_time_ns(now);
      if (!stream->Write(req)) break;
      next += period;
      std::this_thread::sleep_until(next);
    }
    stream->WritesDone();
  });
  std::vector<double> rtt_us;
  std::uint64_t updates = 0, contacts = 0;
  const auto t0 = std::chrono::steady_clock::now();
  while (stream->Read(&resp)) {
    if (!resp.has_update()) continue;
    const auto& u = resp.update();
    ++updates;
    if (!u.rows().empty()) ++contacts;
    rtt_us.push_back(static_cast<double>(SteadyNs() - u.client_time_ns()) / 1e3);
  }
  done = true;
  writer.join();
  Check(stream->Finish(), "couple");
  const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::sort(rtt_us.begin(), rtt_us.end());
  auto q = [&](double f) {
    return rtt_us.empty() ? 0.0
                          : rtt_us[std::min(rtt_us.size() - 1, std::size_t(f * rtt_us.size()))];
  };
  std::cout << std::fixed << std::setprecision(1) << updates << " updates in " << secs << " s ("
            << updates / secs << "/s), " << contacts << " in contact, round trip p50 " << q(0.5)
            << " us p99 " << q(0.99) << " us\n";
}

}  // namespace

void RegisterWatchCouple(CLI::App& app) {
  {
    auto o = std::make_shared<WatchOptions>();
    auto* cmd = app.add_subcommand("watch", "Observe a scene: one line per event");
    AddConnectionOptions(cmd, &o->conn);
    cmd->add_option("--scene", o->scene, "Scene id")->capture_default_str();
    cmd->add_option("--rate", o->rate, "Pose frames per second")->capture_default_str();
    cmd->add_option("--count", o->count, "Stop after this many events (0: never)");
    cmd->callback([o] { RunWatch(*o); });
  }
  {
    auto o = std::make_shared<CoupleOptions>();
    auto* cmd = app.add_subcommand(
        "couple", "Scripted device session: sweep a probe between two poses, report round trips");
    AddConnectionOptions(cmd, &o->conn);
    cmd->add_option("--scene", o->scene, "Scene id")->capture_default_str();
    cmd->add_option("--probe-shape", o->probe_shape, "Probe shape")->capture_default_str();
    cmd->add_option("--probe-body", o->probe_body, "Use this scene body as the probe instead");
    cmd->add_option("--mode", o->mode, "pdt, pdg or none")->capture_default_str();
    cmd->add_option("--from", o->from, "Start position \"x y z\" (commas or spaces)")
        ->capture_default_str();
    cmd->add_option("--to", o->to, "Turning position \"x y z\" (commas or spaces)")
        ->capture_default_str();
    cmd->add_option("--rate", o->rate, "Poses per second")->capture_default_str();
    cmd->add_option("--duration", o->duration, "Seconds (0 < d)")->capture_default_str();
    cmd->add_option("--period", o->period, "Seconds per sweep there and back")
        ->capture_default_str();
    cmd->callback([o] { RunCouple(*o); });
  }
}

}  // namespace hapticpd::cli
