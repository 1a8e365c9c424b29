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
#include "tests/client/session_rig.h"
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
using device::TickRecord;
using device::Vec3;
using testing::MakePose;
using testing::WaitUntil;

using testing::AddBox;
using testing::kBoxTop;
using testing::kProbeRadius;
using testing::Options;
using testing::Rig;
using testing::RunTicks;
using testing::Script;
using testing::StartServer;

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

TEST(IrFromContactUpdate, TakesAQuaternionByTheOneUnitRule) {
  // pd/types.h IsUnitQuaternion: a norm within 1e-3 of 1 is normalised, any
  // other refused, as on the server.
  for (const auto& [w, taken] :
       {std::pair{1.0005, true}, std::pair{0.9995, true}, std::pair{1.002, false},
        std::pair{0.6, false}, std::pair{std::nan(""), false}}) {
    v1::ContactUpdate u;
    *u.mutable_pose_ref() = MakePose(1, 2, 3);
    u.mutable_pose_ref()->mutable_orientation()->set_w(w);
    IntermediateRep ir;
    EXPECT_EQ(IrFromContactUpdate(u, Pose::Identity(), 0, &ir), taken) << w;
    if (taken) {
      EXPECT_NEAR(ir.X_WP_ref.R.determinant(), 1.0, 1e-12) << w;
    }
  }
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
  Rig rig;
  AddBox(*rig.server);
  rig.Connect(Script(device::HandScript::kPress, kProbeRadius + 0.005, 2.0));
  Session& session = *rig.session;
  ServoLoop& loop = *rig.loop;
  // The sphere's centre of mass is its mesh origin.
  EXPECT_TRUE(session.X_PA().t.norm() < 1e-9);

  struct Sample {
    double depth;     // of the handle's sphere into the box (m)
    Vec3 F;           // commanded on the handle (W)
    Vec3 F_contact;   // the IR's contact force on the proxy (W)
    bool after_late;  // within 30 ticks of a tick the machine delayed
    bool link_fresh;  // the loop's output not faded for a stale link
  };
  // A tick the machine delays by over 3 ms (here under a sanitizer on 2
  // busy cores: one CI run pulled 0.32 N down 2.3 mm above the surface) lets
  // the simulated hand move on in real time while the proxy takes one step:
  // the coupling stretches and pulls for a few tens of ms. The
  // commanded-force checks below skip the ticks of that window
  // (testing::LateTickWindow); the contact force is checked on every tick.
  std::vector<Sample> samples;
  samples.reserve(3000);
  testing::LateTickWindow after_late;
  RunTicks(loop, 2300, [&](const TickRecord& r) {
    samples.push_back({kBoxTop - (r.X_WH.t.z() - kProbeRadius), r.F_cmd_W.force,
                       r.wrench_ir.head<3>(), after_late(r), r.link_gain >= 1});
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
  std::size_t settling = 0;
  for (const Sample& s : samples) {
    dmax = std::max(dmax, s.depth);
    fmax = std::max(fmax, s.F.z());
    // The contact pushes out along the face normal (+z) or not at all.
    EXPECT_GE(s.F_contact.z(), 0.0) << "at depth " << s.depth;
    EXPECT_LE(std::hypot(s.F_contact.x(), s.F_contact.y()), 1e-9 + 1e-6 * s.F_contact.z())
        << "at depth " << s.depth;
    if (s.after_late) {
      ++settling;
      continue;
    }
    // Whenever there is a real force, it pushes out (+z, the face normal).
    if (s.F.norm() > 0.3) {
      EXPECT_GT(s.F.z(), 0.9 * s.F.norm()) << "at depth " << s.depth;
    }
    // Above the surface there is nothing to push on.
    if (s.depth < -0.002) {
      EXPECT_LT(s.F.norm(), 0.3) << "at depth " << s.depth;
    }
  }
  // Under a sanitizer on 2 busy cores most ticks can fall in a window; the
  // commanded-force checks must still have covered a real part of the press.
  EXPECT_GT(samples.size() - settling, samples.size() / 10)
      << "too many delayed ticks for the checks to mean much";
  ASSERT_GT(dmax, 0.004) << "the hand never pressed in";
  EXPECT_GT(fmax, 1.0);
  // Grows with depth: mean push over the deepest third beats the shallowest
  // third. A commanded-force check too, so ticks in a late window are left
  // out, and so are ticks the loop faded because the server's answers went
  // stale (a starved server under a sanitizer; that fade is right, and is
  // tested in Servo.StalledIrStreamFadesAndRecovers).
  double shallow = 0, deep = 0;
  int ns = 0, nd = 0;
  for (const Sample& s : samples) {
    if (s.after_late || !s.link_fresh) continue;
    if (s.depth > 0.05 * dmax && s.depth < dmax / 3) shallow += s.F.z(), ++ns;
    if (s.depth > 2 * dmax / 3) deep += s.F.z(), ++nd;
  }
  ASSERT_GT(ns, 5) << "too few on-time ticks with a fresh link in the shallowest third";
  ASSERT_GT(nd, 5) << "too few on-time ticks with a fresh link in the deepest third";
  EXPECT_GT(deep / nd, 1.5 * (shallow / ns) + 0.2)
      << "shallow " << shallow / ns << " deep " << deep / nd;
}

TEST(Session, ServerLossFadesTheForceAndTheSessionReconnects) {
  Rig rig;
  const int port = rig.server->port();
  AddBox(*rig.server);
  ServoConfig config;
  // Engage at once although the hand starts in contact (this test is about
  // losing the server, not the start-up safety).
  config.startup.quiet_force = 1e3;
  config.startup.quiet_torque = 1e3;
  // The hand holds the sphere 6 mm into the box: a steady push out.
  rig.Connect(Script(device::HandScript::kHold, kProbeRadius - 0.006, 100), config);
  Session& session = *rig.session;
  ServoLoop& loop = *rig.loop;
  testing::ScopedExpectLogs expect_logs;  // the disconnect warning

  double f_before = 0;
  RunTicks(loop, 1500, [&](const TickRecord& r) {
    f_before = r.F_cmd_W.force.z();
    return true;
  });
  ASSERT_GT(f_before, 0.5) << "no steady contact force before the server went away";
  ASSERT_TRUE(session.connected());

  // The server goes away while the loop keeps ticking.
  std::thread stopper([&] { rig.server->Shutdown(); });
  struct Seen {
    bool new_ir;
    double stretch;  // m, handle to proxy (the coupling's stretch)
    double force;    // |force commanded on the device (what it receives)|
    double link;     // the loop's link-loss gain
    std::int64_t time_ns;
  };
  std::vector<Seen> seen;
  seen.reserve(1000);
  RunTicks(loop, 1000, [&](const TickRecord& r) {
    seen.push_back({r.new_ir, (r.X_WH.t - r.proxy.X_WP.t).norm(), r.F_cmd_D.force.norm(),
                    r.link_gain, r.time_ns});
    return true;
  });
  stopper.join();
  rig.server.reset();
  std::size_t last_ir = 0;
  for (std::size_t i = 0; i < seen.size(); ++i) {
    if (seen[i].new_ir) last_ir = i;
  }
  ASSERT_LT(last_ir + 300, seen.size()) << "IRs kept coming after the server stopped";
  // From the last answer (the moment the server was gone for the loop): the
  // IR is stale after 20 ms and the output fades over the next 20 ms, so
  // within 50 ticks (50 ms at 1 kHz) the commanded force is below 1 mN and
  // stays there. (The gate makes it exactly zero; 1 mN is three orders of
  // magnitude under the contact force before and far under what a hand can
  // feel, so the bound does not depend on rounding.) Before this gate the
  // coupling still pulled 0.1-0.2 N at 100 ms: the proxy dragging behind the
  // sinking handle.
  constexpr double kZeroForce = 1e-3;  // N
  std::size_t force_zero = seen.size();
  for (std::size_t i = last_ir; i < seen.size(); ++i) {
    if (seen[i].force < kZeroForce) {
      force_zero = i;
      break;
    }
  }
  EXPECT_LE(force_zero - last_ir, 50u) << "ticks from the last IR to zero commanded force";
  // Link loss has one fade, the loop's output gain: once it is zero the
  // proxy is held on the handle, so no coupling stretch is left to be felt
  // when answers return, and it stays so while disconnected.
  std::size_t gain_zero = seen.size();
  for (std::size_t i = last_ir; i < seen.size() && gain_zero == seen.size(); ++i) {
    if (seen[i].link == 0) gain_zero = i;
  }
  double max_stretch_after = 0, max_force_after = 0, max_step = 0;
  for (std::size_t i = last_ir + 1; i < seen.size(); ++i) {
    // A step over its allowance: 10% of the force before per on-time tick
    // (the 20 ms fade is 5% per ms), more for a tick the machine delayed.
    const double dt = 1e-9 * static_cast<double>(seen[i].time_ns - seen[i - 1].time_ns);
    max_step = std::max(max_step, std::abs(seen[i].force - seen[i - 1].force) /
                                      testing::FadeStepAllowance(dt, 1.0, 1.0));
    if (i >= gain_zero) max_stretch_after = std::max(max_stretch_after, seen[i].stretch);
    if (i >= force_zero) max_force_after = std::max(max_force_after, seen[i].force);
  }
  EXPECT_LT(gain_zero, seen.size()) << "the link gain never reached zero";
  EXPECT_EQ(max_stretch_after, 0) << "the proxy left the handle while disconnected";
  EXPECT_LT(max_force_after, kZeroForce) << "force came back while disconnected";
  EXPECT_EQ(seen.back().link, 0.0);
  // A fade, not a cut: no on-time tick drops more than a tenth of the force
  // before (a delayed tick, in proportion to its lateness).
  EXPECT_LT(max_step, 0.1 * f_before) << "force jumped while fading";
  EXPECT_FALSE(session.connected());
  EXPECT_GE(session.stats().disconnects, 1u);

  // A server returns on the same port; the session finds it by itself.
  rig.server = StartServer("127.0.0.1:" + std::to_string(port));
  AddBox(*rig.server);
  const std::uint64_t updates_before = session.stats().updates;
  bool reconnected = false;
  bool contact_again = false;
  bool fresh_ir = false;   // an IR from the new server was taken
  double stale_force = 0;  // max |F| after the return, before fresh_ir
  double min_gain = 1e9;   // startup gain after the return
  double max_gain_step = 0, max_dforce = 0, prev_gain = 1, prev_force = seen.back().force;
  RunTicks(loop, 10000, [&](const TickRecord& r) {
    reconnected = session.stats().connects >= 2;
    const double f = r.F_cmd_D.force.norm();
    if (reconnected && r.new_ir) fresh_ir = true;
    if (!fresh_ir) stale_force = std::max(stale_force, f);
    min_gain = std::min(min_gain, r.startup_gain);
    max_gain_step = std::max(max_gain_step, r.startup_gain - prev_gain);
    max_dforce = std::max(max_dforce, std::abs(f - prev_force));
    prev_gain = r.startup_gain;
    prev_force = f;
    // Rendering the new server's IR: contact rows pushing the proxy out.
    contact_again = reconnected && r.ir.have_ir && !r.ir.stale && r.ir.active_rows > 0 &&
                    r.wrench_ir(2) > 0.1 && r.F_cmd_W.force.z() > 0.5 * f_before;
    return !contact_again;
  });
  EXPECT_TRUE(reconnected) << session.stats().last_error;
  EXPECT_TRUE(contact_again);
  EXPECT_GT(session.stats().updates, updates_before);
  // Nothing from before the loss is felt after the return, and the force
  // comes back through the start-up ramp (re-armed on reconnect: from zero,
  // at most one ramp step per tick), never as a step.
  EXPECT_LT(stale_force, kZeroForce);
  EXPECT_EQ(min_gain, 0.0);
  EXPECT_LE(max_gain_step, config.period_s / config.startup.ramp_time_s + 1e-12);
  EXPECT_LT(max_dforce, 0.1 * f_before);
  EXPECT_TRUE(WaitUntil([&] { return session.connected(); }, std::chrono::seconds(5)));
  session.Stop();  // while the disconnect warnings are still expected
}

TEST(Session, StopIsPromptWhileTheServerIsAway) {
  Rig rig;
  rig.Connect(Script(device::HandScript::kHold, 0.05, 1));
  RunTicks(*rig.loop, 100, nullptr);
  testing::ScopedExpectLogs expect_logs;  // the disconnect warning
  rig.server->Shutdown();
  rig.server.reset();
  RunTicks(*rig.loop, 200, nullptr);
  const auto t0 = std::chrono::steady_clock::now();
  rig.session->Stop();
  EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(5));
  EXPECT_FALSE(rig.session->connected());
}

}  // namespace
}  // namespace hapticpd
