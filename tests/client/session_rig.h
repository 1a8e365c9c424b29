// Shared pieces of the device-session tests (tests/client): a hapticpd
// server in-process on 127.0.0.1 (TCP), Session options for it, hand
// scripts relative to a 0.1 x 0.1 x 0.05 (half extents) box at the origin,
// the server, Session, simulated hand and ServoLoop wired together (Rig),
// and a real-time 1 kHz ticker for a ServoLoop driven by the test thread.
#pragma once

#include <algorithm>
#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <thread>

#include "client/session.h"
#include "device/servo_loop.h"
#include "device/simulated_device.h"
#include "tests/server/server_harness.h"

namespace hapticpd::testing {

inline constexpr double kBoxTop = 0.05;       // box:0.1,0.1,0.05 at the origin
inline constexpr double kProbeRadius = 0.01;  // sphere:0.01,2 (its CoM at its centre)

inline client::SessionOptions Options(int port, v1::PdMode mode = v1::PD_MODE_PDT) {
  client::SessionOptions o;
  o.server = "127.0.0.1:" + std::to_string(port);
  o.hello.set_scene_id("default");
  o.hello.set_mode(mode);
  o.hello.set_probe_shape("sphere:0.01,2");
  o.connect_timeout_s = 10;
  return o;
}

/// Adds `shape` as body `id` at `pose` to the server's default scene, with
/// the material's stiffness (N/m) when `stiffness` > 0 (else the default).
inline void AddBody(server::HapticServer& server, const std::string& shape, const std::string& id,
                    const v1::Pose& pose, double stiffness = 0) {
  auto ch = grpc::CreateChannel("127.0.0.1:" + std::to_string(server.port()),
                                grpc::InsecureChannelCredentials());
  auto stub = v1::SceneService::NewStub(ch);
  v1::AddBodyRequest req = ShapeHeader("default", shape, id, pose);
  if (stiffness > 0) {
    req.mutable_header()->mutable_spec()->mutable_material()->set_stiffness(stiffness);
  }
  v1::Body body;
  const grpc::Status s = AddBodyRaw(*stub, {req}, &body);
  ASSERT_TRUE(s.ok()) << s.error_message();
}

inline void AddBox(server::HapticServer& server) {
  AddBody(server, "box:0.1,0.1,0.05", "box", MakePose(0, 0, 0));
}

inline std::unique_ptr<server::HapticServer> StartServer(const std::string& listen) {
  server::ServerOptions o;
  o.listen = listen;
  o.status_interval_s = 0;
  o.shutdown_grace_s = 0.2;
  auto s = std::make_unique<server::HapticServer>(o);
  s->Start();
  return s;
}

/// Sphere centre `height` above the box's top face (negative: inside).
inline device::ScriptParams Script(device::HandScript script, double height, double duration,
                                   double travel = 0.02) {
  device::ScriptParams p;
  p.script = script;
  p.X_DS = device::Pose::FromTranslation(device::Vec3(0, 0, kBoxTop + height));
  p.duration_s = duration;
  p.travel = travel;
  return p;
}

/// A server on 127.0.0.1 (ephemeral port) and, once connected, a Session to
/// it, a simulated hand on a script and the servo loop between them. Ends
/// by stopping the session and shutting the server down (if still there).
struct Rig {
  std::unique_ptr<server::HapticServer> server = StartServer("127.0.0.1:0");
  std::unique_ptr<client::Session> session;
  std::unique_ptr<device::SimulatedDevice> device;
  std::unique_ptr<device::ServoLoop> loop;

  /// Connects a Session to `port` (0: the server's own), opens a simulated
  /// hand on `script` on the steady clock and starts the servo loop with
  /// `config` (its X_PA taken from the session) under the session.
  void Connect(const device::ScriptParams& script, device::ServoConfig config = {}, int port = 0) {
    session = std::make_unique<client::Session>(Options(port != 0 ? port : server->port()));
    session->Connect();
    device = std::make_unique<device::SimulatedDevice>(script, &device::SteadyClock::Instance());
    device->Open();
    config.X_PA = session->X_PA();
    loop = std::make_unique<device::ServoLoop>(device.get(), config);
    session->Start(loop.get());
  }
  ~Rig() {
    if (session) session->Stop();
    if (server) server->Shutdown();
  }
};

/// Largest per-tick change of a fading force allowed in a real-time test,
/// as a fraction of the force before the fade: `on_time` for a tick that
/// came on time; the fade runs in real time, so a tick the machine delayed
/// (a loaded CI runner) may fade in proportion to its lateness, and is
/// allowed that much more (`per_ms` per millisecond of its period).
inline double FadeStepAllowance(double dt_s, double on_time, double per_ms) {
  return std::max(on_time, per_ms * dt_s / 1e-3);
}

/// Time (s) from the previous tick record fed to it to this one; 0 for the
/// first. For tests that allow for ticks the machine delayed.
class TickGap {
 public:
  double operator()(const device::TickRecord& r) {
    const double dt = prev_ns_ != 0 ? 1e-9 * static_cast<double>(r.time_ns - prev_ns_) : 0.0;
    prev_ns_ = r.time_ns;
    return dt;
  }

 private:
  std::int64_t prev_ns_ = 0;
};

/// Whether a tick lies within `settle` ticks of one the machine delayed by
/// more than `late_s` (that one included): there the simulated hand has moved
/// on in real time while the proxy took one step, and the coupling stretches
/// and tugs for a few tens of ms. Fed every tick record in order; counts the
/// delayed ticks.
class LateTickWindow {
 public:
  explicit LateTickWindow(int settle = 30, double late_s = 3e-3)
      : settle_(settle), late_s_(late_s), since_late_(settle) {}
  bool operator()(const device::TickRecord& r) {
    if (gap_(r) > late_s_) {
      since_late_ = 0;
      ++late_ticks_;
    }
    return since_late_++ < settle_;
  }
  int late_ticks() const { return late_ticks_; }

 private:
  TickGap gap_;
  int settle_;
  double late_s_;
  int since_late_;
  int late_ticks_ = 0;
};

/// Ticks `loop` at 1 kHz on the steady clock for `ticks` ticks (or until
/// `each` returns false).
inline void RunTicks(device::ServoLoop& loop, int ticks,
                     const std::function<bool(const device::TickRecord&)>& each) {
  const auto& clock = device::SteadyClock::Instance();
  auto next = std::chrono::steady_clock::now();
  for (int i = 0; i < ticks; ++i) {
    next += std::chrono::milliseconds(1);
    std::this_thread::sleep_until(next);
    // If the machine stalled us, do not try to catch up in a burst.
    if (std::chrono::steady_clock::now() - next > std::chrono::milliseconds(5)) {
      next = std::chrono::steady_clock::now();
    }
    loop.Tick(clock.NowNs());
    if (each && !each(loop.last_tick())) return;
  }
}

}  // namespace hapticpd::testing
