// The network Session end to end: a hapticpd server in-process on
// 127.0.0.1 (TCP, ephemeral port), a simulated device and a ServoLoop ticked
// by the test thread at 1 kHz in real time, and the Session between them.
// Assertions are on what the loop rendered, counted in servo ticks (never on
// wall-clock performance); every wait is bounded.
#include "client/session.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <functional>
#include <memory>
#include <thread>
#include <vector>

#include "device/servo_loop.h"
#include "device/simulated_device.h"
#include "tests/server/server_harness.h"
#include "tests/test_util.h"

namespace hapticpd {
namespace {

using client::IrFromContactUpdate;
using client::Session;
using client::SessionOptions;
using device::IntermediateRep;
using device::Pose;
using device::ServoConfig;
using device::ServoLoop;
using device::SimulatedDevice;
using device::TickRecord;
using device::Vec3;
using testing::MakePose;
using testing::WaitUntil;

constexpr double kBoxTop = 0.05;       // box:0.1,0.1,0.05 at the origin
constexpr double kProbeRadius = 0.01;  // sphere:0.01,2 (its CoM at its centre)

SessionOptions Options(int port, v1::PdMode mode = v1::PD_MODE_PDT) {
  SessionOptions o;
  o.server = "127.0.0.1:" + std::to_string(port);
  o.hello.set_scene_id("default");
  o.hello.set_mode(mode);
  o.hello.set_probe_shape("sphere:0.01,2");
  o.connect_timeout_s = 10;
  return o;
}

void AddBox(server::HapticServer& server) {
  auto ch = grpc::CreateChannel("127.0.0.1:" + std::to_string(server.port()),
                                grpc::InsecureChannelCredentials());
  auto stub = v1::SceneService::NewStub(ch);
  const grpc::Status s =
      testing::AddShape(*stub, "default", "box:0.1,0.1,0.05", "box", MakePose(0, 0, 0));
  ASSERT_TRUE(s.ok()) << s.error_message();
}

std::unique_ptr<server::HapticServer> StartServer(const std::string& listen) {
  server::ServerOptions o;
  o.listen = listen;
  o.status_interval_s = 0;
  o.shutdown_grace_s = 0.2;
  auto s = std::make_unique<server::HapticServer>(o);
  s->Start();
  return s;
}

/// Sphere centre `height` above the box's top face (negative: inside).
device::ScriptParams Script(device::HandScript script, double height, double duration,
                            double travel = 0.02) {
  device::ScriptParams p;
  p.script = script;
  p.X_DS = Pose::FromTranslation(Vec3(0, 0, kBoxTop + height));
  p.duration_s = duration;
  p.travel = travel;
  return p;
}

/// Ticks `loop` at 1 kHz on the steady clock for `ticks` ticks (or until
/// `each` returns false).
void RunTicks(ServoLoop& loop, int ticks, const std::function<bool(const TickRecord&)>& each) {
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

TEST(IrFromContactUpdate, MapsRowsTargetAndFrames) {
  v1::ContactUpdate u;
  u.set_sequence(7);
  u.set_client_time_ns(123);
  *u.mutable_pose_ref() = MakePose(1, 2, 3);
  u.set_status(v1::CONTACT_STATUS_PENETRATING);
  auto* r = u.add_rows();
  r->mutable_point()->set_x(1);
  r->mutable_point()->set_y(2);
  r->mutable_normal()->set_z(1);
  r->set_depth(0.002);
  r->set_stiffness(500);
  auto* r0 = u.add_rows();  // separated: dropped
  r0->mutable_normal()->set_z(1);
  r0->set_depth(0);
  r0->set_stiffness(500);
  u.set_validity_radius(0.004);
  const Pose X_AP = Pose::FromTranslation(Vec3(0, 0, 0.5));  // CoM 0.5 above the mesh origin
  IntermediateRep ir;
  ASSERT_TRUE(IrFromContactUpdate(u, X_AP, 999, &ir));
  EXPECT_EQ(ir.sequence, 7u);
  EXPECT_EQ(ir.sample_time_ns, 123);
  EXPECT_EQ(ir.receive_time_ns, 999);
  EXPECT_TRUE(ir.X_WP_ref.t.isApprox(Vec3(1, 2, 3.5)));
  ASSERT_EQ(ir.num_rows, 1);
  EXPECT_DOUBLE_EQ(ir.rows[0].depth, 0.002);
  // m = (p - c) x n with c the proxy origin (the CoM).
  EXPECT_TRUE(
      ir.rows[0].m_W.isApprox((Vec3(1, 2, 0) - Vec3(1, 2, 3.5)).cross(Vec3::UnitZ()), 1e-12));
  EXPECT_FALSE(ir.use_target);
  EXPECT_DOUBLE_EQ(ir.validity_radius, 0.004);

  // PDg in contact: the spring towards the target, in the proxy frame.
  u.set_sigma(4e-6);
  *u.mutable_target_pose() = MakePose(1, 2, 3.01);
  u.set_target_stiffness(800);
  u.set_target_rotational_stiffness(0.1);
  ASSERT_TRUE(IrFromContactUpdate(u, X_AP, 999, &ir));
  EXPECT_TRUE(ir.use_target);
  EXPECT_TRUE(ir.X_WP_target.t.isApprox(Vec3(1, 2, 3.51)));
  EXPECT_DOUBLE_EQ(ir.target_stiffness, 800);

  // Normals are normalised; garbage is refused.
  u.mutable_rows(0)->mutable_normal()->set_z(2);
  ASSERT_TRUE(IrFromContactUpdate(u, X_AP, 999, &ir));
  ASSERT_EQ(ir.num_rows, 1);
  EXPECT_DOUBLE_EQ(ir.rows[0].n_W.z(), 1);
  u.mutable_rows(0)->mutable_normal()->set_z(1);
  u.mutable_rows(0)->set_stiffness(INFINITY);
  EXPECT_FALSE(IrFromContactUpdate(u, X_AP, 999, &ir));
  u.mutable_rows(0)->set_stiffness(500);
  u.mutable_pose_ref()->mutable_position()->set_x(NAN);
  EXPECT_FALSE(IrFromContactUpdate(u, X_AP, 999, &ir));
}

TEST(Session, ConnectFailsWithTheServersReason) {
  auto server = StartServer("127.0.0.1:0");
  SessionOptions o = Options(server->port());
  o.hello.set_scene_id("no-such-scene");
  Session session(o);
  try {
    session.Connect();
    FAIL() << "connected to a missing scene";
  } catch (const client::SessionError& e) {
    EXPECT_NE(std::string(e.what()).find("NOT_FOUND"), std::string::npos) << e.what();
  }
  server->Shutdown();
}

TEST(Session, PressingIntoABodyPushesOutMoreWithDepth) {
  auto server = StartServer("127.0.0.1:0");
  AddBox(*server);
  Session session(Options(server->port()));
  session.Connect();
  // The sphere's centre of mass is its mesh origin.
  EXPECT_TRUE(session.X_PA().t.norm() < 1e-9);

  SimulatedDevice dev(Script(device::HandScript::kPress, kProbeRadius + 0.005, 2.0),
                      &device::SteadyClock::Instance());
  dev.Open();
  ServoConfig config;
  config.X_PA = session.X_PA();
  ServoLoop loop(&dev, config);
  session.Start(&loop);

  struct Sample {
    double depth;  // of the handle's sphere into the box (m)
    Vec3 F;        // commanded on the handle (W)
  };
  std::vector<Sample> samples;
  samples.reserve(3000);
  RunTicks(loop, 2300, [&](const TickRecord& r) {
    samples.push_back({kBoxTop - (r.X_WH.t.z() - kProbeRadius), r.F_cmd_W.force});
    return true;
  });
  session.Stop();
  const client::SessionStats st = session.stats();
  EXPECT_GT(st.updates, 200u);
  EXPECT_GT(st.contact_updates, 20u);
  EXPECT_GT(st.rtt_samples, 100u);
  EXPECT_GT(st.rtt_p50_us, 0);
  EXPECT_LE(st.rtt_p50_us, st.rtt_p99_us);
  EXPECT_EQ(st.connects, 1u);
  EXPECT_EQ(st.disconnects, 0u);

  double dmax = 0, fmax = 0;
  for (const Sample& s : samples) {
    dmax = std::max(dmax, s.depth);
    fmax = std::max(fmax, s.F.z());
    // Whenever there is a real force, it pushes out (+z, the face normal).
    if (s.F.norm() > 0.3) {
      EXPECT_GT(s.F.z(), 0.9 * s.F.norm()) << "at depth " << s.depth;
    }
    // Above the surface there is nothing to push on.
    if (s.depth < -0.002) {
      EXPECT_LT(s.F.norm(), 0.3) << "at depth " << s.depth;
    }
  }
  ASSERT_GT(dmax, 0.004) << "the hand never pressed in";
  EXPECT_GT(fmax, 1.0);
  // Grows with depth: mean push over the deepest third beats the shallowest third.
  double shallow = 0, deep = 0;
  int ns = 0, nd = 0;
  for (const Sample& s : samples) {
    if (s.depth > 0.05 * dmax && s.depth < dmax / 3) shallow += s.F.z(), ++ns;
    if (s.depth > 2 * dmax / 3) deep += s.F.z(), ++nd;
  }
  ASSERT_GT(ns, 5);
  ASSERT_GT(nd, 5);
  EXPECT_GT(deep / nd, 1.5 * (shallow / ns) + 0.2)
      << "shallow " << shallow / ns << " deep " << deep / nd;
  server->Shutdown();
}

TEST(Session, ServerLossFadesTheForceAndTheSessionReconnects) {
  auto server = StartServer("127.0.0.1:0");
  const int port = server->port();
  AddBox(*server);
  Session session(Options(port));
  session.Connect();
  // The hand holds the sphere 6 mm into the box: a steady push out.
  SimulatedDevice dev(Script(device::HandScript::kHold, kProbeRadius - 0.006, 100),
                      &device::SteadyClock::Instance());
  dev.Open();
  ServoConfig config;
  config.X_PA = session.X_PA();
  // Engage at once although the hand starts in contact (this test is about
  // losing the server, not the start-up safety).
  config.startup.quiet_force = 1e3;
  config.startup.quiet_torque = 1e3;
  ServoLoop loop(&dev, config);
  session.Start(&loop);
  testing::ScopedExpectLogs expect_logs;  // the disconnect warning

  double f_before = 0;
  RunTicks(loop, 1500, [&](const TickRecord& r) {
    f_before = r.F_cmd_W.force.z();
    return true;
  });
  ASSERT_GT(f_before, 0.5) << "no steady contact force before the server went away";
  ASSERT_TRUE(session.connected());

  // The server goes away while the loop keeps ticking.
  std::thread stopper([&] { server->Shutdown(); });
  struct Seen {
    bool new_ir;
    double contact;  // |contact wrench on the proxy|
    double force;    // |force commanded on the handle|
  };
  std::vector<Seen> seen;
  seen.reserve(1000);
  RunTicks(loop, 1000, [&](const TickRecord& r) {
    seen.push_back({r.new_ir, r.W_ir.norm(), r.F_cmd_W.force.norm()});
    return true;
  });
  stopper.join();
  server.reset();
  std::size_t last_ir = 0;
  for (std::size_t i = 0; i < seen.size(); ++i) {
    if (seen[i].new_ir) last_ir = i;
  }
  ASSERT_LT(last_ir + 300, seen.size()) << "IRs kept coming after the server stopped";
  // The contact wrench fades to exactly zero within 50 ticks of the last IR
  // (stale after 20 ms, then a 20 ms fade) and stays there.
  std::size_t contact_zero = seen.size();
  for (std::size_t i = last_ir; i < seen.size(); ++i) {
    if (seen[i].contact == 0) {
      contact_zero = i;
      break;
    }
  }
  EXPECT_LE(contact_zero - last_ir, 50u) << "ticks from the last IR to zero contact wrench";
  double max_contact_after = 0, max_force_after = 0;
  for (std::size_t i = contact_zero; i < seen.size(); ++i) {
    max_contact_after = std::max(max_contact_after, seen[i].contact);
    max_force_after = std::max(max_force_after, seen[i].force);
  }
  EXPECT_EQ(max_contact_after, 0) << "contact came back while disconnected";
  // The handle's force is then only the coupling's transient while the hand
  // sinks into the now free space: small, and gone by the end.
  EXPECT_LT(seen[last_ir + 50].force, 0.2 * f_before + 0.02);
  EXPECT_LT(max_force_after, 0.3 * f_before + 0.02);
  EXPECT_LT(seen.back().force, 0.05 * f_before + 0.01);
  EXPECT_FALSE(session.connected());
  EXPECT_GE(session.stats().disconnects, 1u);

  // A server returns on the same port; the session finds it by itself.
  auto again = StartServer("127.0.0.1:" + std::to_string(port));
  AddBox(*again);
  const std::uint64_t updates_before = session.stats().updates;
  bool reconnected = false;
  bool contact_again = false;
  RunTicks(loop, 10000, [&](const TickRecord& r) {
    reconnected = session.stats().connects >= 2;
    // Rendering the new server's IR: contact rows pushing the proxy out.
    contact_again = reconnected && r.ir.have_ir && !r.ir.stale && r.ir.active_rows > 0 &&
                    r.W_ir(2) > 0.1 && r.F_cmd_W.force.z() > 0.5 * f_before;
    return !contact_again;
  });
  EXPECT_TRUE(reconnected) << session.stats().last_error;
  EXPECT_TRUE(contact_again);
  EXPECT_GT(session.stats().updates, updates_before);
  EXPECT_TRUE(WaitUntil([&] { return session.connected(); }, std::chrono::seconds(5)));
  session.Stop();
  again->Shutdown();
}

TEST(Session, StopIsPromptWhileTheServerIsAway) {
  auto server = StartServer("127.0.0.1:0");
  Session session(Options(server->port()));
  session.Connect();
  SimulatedDevice dev(Script(device::HandScript::kHold, 0.05, 1), &device::SteadyClock::Instance());
  dev.Open();
  ServoConfig config;
  ServoLoop loop(&dev, config);
  session.Start(&loop);
  RunTicks(loop, 100, nullptr);
  testing::ScopedExpectLogs expect_logs;  // the disconnect warning
  server->Shutdown();
  server.reset();
  RunTicks(loop, 200, nullptr);
  const auto t0 = std::chrono::steady_clock::now();
  session.Stop();
  EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(5));
  EXPECT_FALSE(session.connected());
}

}  // namespace
}  // namespace hapticpd
