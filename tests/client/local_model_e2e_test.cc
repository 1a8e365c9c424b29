// The local contact model (device/local_model.h) end to end: a hapticpd
// server in-process on 127.0.0.1 streaming geometry patches, a Session with
// SessionOptions::local_model, a simulated hand and a ServoLoop ticked at
// 1 kHz in real time by the test thread. Bodies are added, moved (also with
// a velocity) and removed through the SceneService while the hand is
// coupled; what the loop rendered is checked per tick: which model answered
// (IrEvalInfo::source), whether rows were active, the forces. Every wait is
// bounded and counted in ticks or on the loop's clock; nothing asserts on
// wall-clock performance. The thin plate through a 100 ms link with the
// local model is a timing test (tests/client/delay_proxy_test.cc).
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>
#include <thread>

#include "client/link_emulator.h"
#include "client/session.h"
#include "device/local_model.h"
#include "device/servo_loop.h"
#include "device/simulated_device.h"
#include "tests/client/session_rig.h"
#include "tests/test_util.h"

namespace hapticpd {
namespace {

using device::HandScript;
using device::Pose;
using device::ServoConfig;
using device::TickRecord;
using device::Vec3;
using testing::kBoxTop;
using testing::kProbeRadius;
using testing::MakePose;
using testing::Rig;
using testing::RunTicks;

constexpr std::uint8_t kLocal = device::kIrSourceLocal;

std::unique_ptr<v1::SceneService::Stub> Scenes(int port) {
  return v1::SceneService::NewStub(
      grpc::CreateChannel("127.0.0.1:" + std::to_string(port), grpc::InsecureChannelCredentials()));
}

/// Adds a movable built-in shape to the default scene.
grpc::Status AddMovable(v1::SceneService::Stub& stub, const std::string& shape,
                        const std::string& id, const v1::Pose& pose) {
  v1::Body body;
  return testing::AddBodyRaw(stub, {testing::ShapeHeader("default", shape, id, pose, true)}, &body);
}

/// MoveBody of `id` to `pose` with linear velocity `v_W` (m/s).
grpc::Status MoveWithVelocity(v1::SceneService::Stub& stub, const std::string& id,
                              const v1::Pose& pose, const Vec3& v_W) {
  v1::MoveBodyRequest req;
  req.set_scene_id("default");
  req.set_body_id(id);
  *req.mutable_pose() = pose;
  auto* lin = req.mutable_velocity()->mutable_linear();
  lin->set_x(v_W.x());
  lin->set_y(v_W.y());
  lin->set_z(v_W.z());
  v1::MoveBodyResponse resp;
  auto ctx = testing::Ctx();
  return stub.MoveBody(ctx.get(), req, &resp);
}

/// Engage at once although the hand may start in contact (these tests are
/// about which model answers, not the start-up safety).
ServoConfig EngageAtOnce() {
  ServoConfig c;
  c.startup.quiet_force = 1e3;
  c.startup.quiet_torque = 1e3;
  return c;
}

/// Connects a Session with the local model (unless `local` is false) to
/// the rig's server, through `link` when given, and starts the servo loop
/// under it with a simulated hand on `script`.
void ConnectLocal(Rig& rig, const device::ScriptParams& script, ServoConfig config,
                  std::optional<client::LinkOptions> link = std::nullopt, bool local = true) {
  client::SessionOptions o = testing::Options(rig.server->port());
  o.local_model = local;
  o.link = link;
  rig.session = std::make_unique<client::Session>(o);
  rig.session->Connect();
  rig.device = std::make_unique<device::SimulatedDevice>(script, &device::SteadyClock::Instance());
  rig.device->Open();
  config.X_PA = rig.session->X_PA();
  rig.loop = std::make_unique<device::ServoLoop>(rig.device.get(), config);
  rig.session->Start(rig.loop.get());
}

/// A local-model IR with active rows pushing the proxy up (+z).
bool LocalPush(const TickRecord& r) {
  return r.ir.have_ir && !r.ir.stale && r.ir.source == kLocal && r.ir.active_rows > 0 &&
         r.wrench_ir(2) > 0;
}

/// Ticks until `n` ticks have satisfied `pred` (at most `max_ticks`);
/// returns whether they did.
bool TickUntilCount(device::ServoLoop& loop, int max_ticks, int n,
                    const std::function<bool(const TickRecord&)>& pred) {
  int seen = 0;
  RunTicks(loop, max_ticks, [&](const TickRecord& r) {
    if (pred(r)) ++seen;
    return seen < n;
  });
  return seen >= n;
}

/// Watches the ticks after a change is known to have reached the local
/// model (at tick `seen`): the IR in the mailbox then may still be one
/// answered before it, and is taken at most once, so from the second new
/// IR on everything rendered was answered after the change.
struct AfterChange {
  bool seen = false;
  int new_irs = 0;
  void Tick(const TickRecord& r) {
    if (seen && r.new_ir) ++new_irs;
  }
  bool settled() const { return new_irs >= 2; }
};

TEST(LocalModelE2e, RemovedAddedAndMovedBodiesWhileCoupled) {
  Rig rig;
  auto scenes = Scenes(rig.server->port());
  ASSERT_TRUE(AddMovable(*scenes, "box:0.1,0.1,0.05", "box", MakePose(0, 0, 0)).ok());
  // The hand holds the sphere 6 mm into the box: a steady push out.
  ConnectLocal(rig, testing::Script(HandScript::kHold, kProbeRadius - 0.006, 100), EngageAtOnce());
  client::Session& session = *rig.session;
  device::ServoLoop& loop = *rig.loop;
  ASSERT_TRUE(session.stats().local_model) << session.stats().local_model_note;

  // The local model answers with rows.
  ASSERT_TRUE(TickUntilCount(loop, 5000, 200, LocalPush))
      << "the local model never pushed; local answers " << session.stats().local.local_answers
      << ", patches " << session.stats().local.patches;
  ASSERT_GT(session.stats().local.triangles_held, 0u);
  const std::uint64_t local_ticks_0 = loop.stats().ticks_local;

  // (a) The box is removed: once the local model has dropped its triangles,
  // nothing with rows is rendered again and the force goes to zero.
  {
    std::thread remover([&] { EXPECT_TRUE(testing::RemoveBody(*scenes, "default", "box").ok()); });
    AfterChange after;
    int checked = 0, with_rows = 0, ticks_after = 0;
    double max_force_late = 0, max_contact_late = 0;
    RunTicks(loop, 5000, [&](const TickRecord& r) {
      after.Tick(r);
      if (!after.seen && session.stats().local.triangles_held == 0) after.seen = true;
      if (!after.settled()) return true;
      ++checked;
      // No row, ever; the contact wrench is what the blend from the last IR
      // with rows has left (it decays by a tenth per new IR).
      if (r.ir.active_rows != 0) ++with_rows;
      if (ticks_after >= 100) max_contact_late = std::max(max_contact_late, r.wrench_ir.norm());
      // The proxy and the handle settle on the hand within a few hundred ms
      // once free.
      if (++ticks_after > 400) max_force_late = std::max(max_force_late, r.F_cmd_W.force.norm());
      return ticks_after < 800;
    });
    remover.join();
    ASSERT_TRUE(after.seen) << "the patch never dropped the removed box";
    EXPECT_GE(checked, 500);
    EXPECT_EQ(with_rows, 0) << "a removed body was felt after the patch dropped it";
    EXPECT_LT(max_contact_late, 1e-3) << "contact without a body";
    EXPECT_LT(max_force_late, 1e-2) << "force without a body";
    std::printf("after the removal: contact %g N, force %g N\n", max_contact_late, max_force_late);
  }

  // (b) Another body under the probe (a smaller, thinner box, its top where
  // the box's was) is felt again, from the local patch.
  ASSERT_TRUE(
      AddMovable(*scenes, "box:0.04,0.03,0.02", "block", MakePose(0, 0, kBoxTop - 0.02)).ok());
  const std::uint64_t local_ticks_1 = loop.stats().ticks_local;
  EXPECT_TRUE(TickUntilCount(loop, 5000, 200, [](const TickRecord& r) {
    return LocalPush(r) && r.F_cmd_W.force.z() > 0.3;
  })) << "the added body was not felt from the patch";
  EXPECT_GT(loop.stats().ticks_local, local_ticks_1);

  // (c) The block is moved 3 cm down (away from the probe): the contact
  // follows it, and comes back when it is moved up again (2 mm higher than
  // before: deeper).
  double depth_before = -1;
  RunTicks(loop, 100, [&](const TickRecord& r) {
    depth_before = std::max(depth_before, r.ir.max_depth);
    return true;
  });
  ASSERT_TRUE(testing::MoveBody(*scenes, "default", "block", MakePose(0, 0, kBoxTop - 0.05)).ok());
  {
    // Free for 300 ticks in a row (bounded), then never pushed again.
    int free_run = 0, pushed_after = 0, ticks_after = 0;
    RunTicks(loop, 5000, [&](const TickRecord& r) {
      const bool free = r.ir.active_rows == 0 && r.wrench_ir.norm() < 1e-3;
      if (free_run < 300) {
        free_run = free ? free_run + 1 : 0;
        return true;
      }
      if (!free) ++pushed_after;
      return ++ticks_after < 300;
    });
    EXPECT_GE(free_run, 300) << "the contact did not follow the moved body";
    EXPECT_EQ(pushed_after, 0) << "contact came back with the body 3 cm away";
  }
  ASSERT_TRUE(
      testing::MoveBody(*scenes, "default", "block", MakePose(0, 0, kBoxTop - 0.02 + 0.002)).ok());
  double depth_after = -1;
  EXPECT_TRUE(TickUntilCount(loop, 5000, 200, [&](const TickRecord& r) {
    if (!LocalPush(r)) return false;
    depth_after = std::max(depth_after, r.ir.max_depth);
    return true;
  })) << "the body moved back was not felt";
  EXPECT_GT(depth_after, depth_before) << "2 mm higher is deeper";
  const client::SessionStats st = session.stats();
  std::printf(
      "local model: %llu patches (%llu bytes), %llu local answers, %llu uncovered, %llu drops; "
      "ticks local %llu (before the changes %llu)\n",
      static_cast<unsigned long long>(st.local.patches),
      static_cast<unsigned long long>(st.local.patch_bytes),
      static_cast<unsigned long long>(st.local.local_answers),
      static_cast<unsigned long long>(st.local.uncovered),
      static_cast<unsigned long long>(st.local.drops),
      static_cast<unsigned long long>(loop.stats().ticks_local),
      static_cast<unsigned long long>(local_ticks_0));
  EXPECT_EQ(st.local.bad_patches, 0u) << st.local.last_problem;
  EXPECT_EQ(st.bad_updates, 0u);
}

TEST(LocalModelE2e, AMovingBodyIsFeltWhereItIs) {
  // The hand holds the sphere still 10 cm up; a block whose top is 3 cm
  // under the sphere rises towards it at 0.1 m/s (MoveBody with a velocity:
  // the server carries it along, PoseAt, and so must the patch).
  Rig rig;
  auto scenes = Scenes(rig.server->port());
  constexpr double kHandZ = 0.10;
  constexpr double kGap = 0.03;
  constexpr double kSpeed = 0.1;  // m/s
  const double block_z0 = kHandZ - kProbeRadius - kGap - 0.02;
  ASSERT_TRUE(AddMovable(*scenes, "box:0.05,0.05,0.02", "lift", MakePose(0, 0, block_z0)).ok());
  device::ScriptParams sp;
  sp.script = HandScript::kHold;
  sp.X_DS = Pose::FromTranslation(Vec3(0, 0, kHandZ));
  sp.duration_s = 100;
  ConnectLocal(rig, sp, EngageAtOnce());
  client::Session& session = *rig.session;
  device::ServoLoop& loop = *rig.loop;
  // Settle, and wait for a patch holding the block.
  double proxy_z = 0;
  ASSERT_TRUE(TickUntilCount(loop, 5000, 300,
                             [&](const TickRecord& r) {
                               proxy_z = r.proxy.X_WP.t.z();
                               return r.ir.have_ir && r.ir.source == kLocal &&
                                      session.stats().local.patches > 0;
                             }))
      << "no local answers; patches " << session.stats().local.patches;
  ASSERT_NEAR(proxy_z, kHandZ, 0.002);

  // The loop's clock is the steady clock, and so is the in-process
  // server's: the body's pose time lies between these two.
  const auto& clock = device::SteadyClock::Instance();
  // Written by the mover thread while the loop runs: atomics.
  std::atomic<std::int64_t> t_call0_atomic{0};
  std::int64_t t_call1 = 0;
  grpc::Status moved;
  std::thread mover([&] {
    t_call0_atomic.store(clock.NowNs());
    moved = MoveWithVelocity(*scenes, "lift", MakePose(0, 0, block_z0), Vec3(0, 0, kSpeed));
    t_call1 = clock.NowNs();
  });
  // The sphere's lowest point is its radius under the proxy (its centre).
  const double gap = proxy_z - kProbeRadius - (block_z0 + 0.02);
  const auto arrival_s = gap / kSpeed;
  std::int64_t first_ns = -1;  // the first tick rendering local rows
  double first_depth = 0, max_depth = 0, force_at_first = 0, max_force = 0;
  int before_rows = 0;  // ticks with rows before the body could have arrived
  std::int64_t t_call0 = 0;
  RunTicks(loop, 2000, [&](const TickRecord& r) {
    if (t_call0 == 0) t_call0 = t_call0_atomic.load();
    if (t_call0 == 0) return true;  // the call has not started yet
    const double since_call_s = 1e-9 * static_cast<double>(r.time_ns - t_call0);
    const bool rows = r.ir.have_ir && !r.ir.stale && r.ir.active_rows > 0;
    // 3 ms before the earliest arrival: 0.3 mm of the block's travel.
    if (rows && since_call_s < arrival_s - 0.003) ++before_rows;
    if (first_ns < 0 && rows && r.ir.source == kLocal) {
      first_ns = r.time_ns;
      first_depth = r.ir.max_depth;
      force_at_first = r.wrench_ir(2);
    }
    if (first_ns >= 0) {
      max_depth = std::max(max_depth, r.ir.max_depth);
      max_force = std::max(max_force, r.wrench_ir(2));
      return r.time_ns - first_ns < 100'000'000;  // 100 ms of contact
    }
    return true;
  });
  mover.join();
  t_call0 = t_call0_atomic.load();
  ASSERT_TRUE(moved.ok()) << moved.error_message();
  // Stop the block before the rig goes down.
  EXPECT_TRUE(MoveWithVelocity(*scenes, "lift", MakePose(0, 0, block_z0), Vec3::Zero()).ok());
  ASSERT_GE(first_ns, 0) << "the moving body was never felt from the patch";
  const double earliest_s = 1e-9 * static_cast<double>(t_call0) + arrival_s;
  const double latest_s = 1e-9 * static_cast<double>(t_call1) + arrival_s;
  const double first_s = 1e-9 * static_cast<double>(first_ns);
  std::printf(
      "moving body: arrival predicted %.1f-%.1f ms after the call, first local row at %.1f ms; "
      "depth %.2f mm at first, %.2f mm max over 100 ms (contact force %.2f -> %.2f N)\n",
      1e3 * (earliest_s - 1e-9 * static_cast<double>(t_call0)),
      1e3 * (latest_s - 1e-9 * static_cast<double>(t_call0)),
      1e3 * (first_s - 1e-9 * static_cast<double>(t_call0)), 1e3 * first_depth, 1e3 * max_depth,
      force_at_first, max_force);
  EXPECT_EQ(before_rows, 0) << "contact rendered before the body could have arrived";
  // Not before it arrives (3 ms: the clock offset estimate and the sphere's
  // tessellation, 0.3 mm of travel), and not long after: 60 ms is 6 mm of
  // travel, far beyond a tick or a patch's re-send, yet far under the 200 ms
  // (2 cm) at which a static copy of the block would start to be rendered
  // from the server's answers (rule 2).
  EXPECT_GE(first_s, earliest_s - 0.003);
  EXPECT_LE(first_s, latest_s + 0.060);
  // And it keeps coming: deeper and pushing harder.
  EXPECT_GT(max_depth, first_depth + 0.001);
  EXPECT_GT(max_force, force_at_first + 0.5);
  EXPECT_EQ(session.stats().local.bad_patches, 0u) << session.stats().local.last_problem;
}

TEST(LocalModelE2e, ServerLossDropsThePatchAndReconnectBringsItBack) {
  Rig rig;
  const int port = rig.server->port();
  testing::AddBox(*rig.server);
  ConnectLocal(rig, testing::Script(HandScript::kHold, kProbeRadius - 0.006, 100), EngageAtOnce());
  client::Session& session = *rig.session;
  device::ServoLoop& loop = *rig.loop;
  testing::ScopedExpectLogs expect_logs;  // the disconnect warnings
  ASSERT_TRUE(TickUntilCount(loop, 5000, 200, LocalPush)) << "the local model never pushed";
  const std::uint64_t drops_before = session.stats().local.drops;

  // The server goes away while the loop keeps ticking: the patch is
  // dropped, no new IR comes, and the force fades out.
  std::thread stopper([&] { rig.server->Shutdown(); });
  bool dropped = false;
  // The loop rendered IRs up to the stop (TickUntilCount above); once the
  // session sees the stream end, the loop takes none (RequestLinkLost).
  int last_ir = 0, tick = 0;
  double max_force_late = 0;  // from 100 ticks after the last IR
  RunTicks(loop, 3000, [&](const TickRecord& r) {
    if (r.new_ir) last_ir = tick;
    if (tick - last_ir > 100) {
      max_force_late = std::max(max_force_late, r.F_cmd_D.force.norm());
    }
    ++tick;
    dropped = dropped || session.stats().local.drops > drops_before;
    return !(dropped && tick - last_ir > 400);
  });
  stopper.join();
  rig.server.reset();
  EXPECT_TRUE(dropped) << "the local model kept its patch with the server gone";
  EXPECT_GT(tick - last_ir, 400) << "IRs kept coming after the server stopped";
  EXPECT_LT(max_force_late, 1e-3) << "the force did not fade";
  EXPECT_FALSE(session.connected());

  // A server returns on the same port with the box: the session finds it,
  // and the local model answers again from a new patch.
  rig.server = testing::StartServer("127.0.0.1:" + std::to_string(port));
  testing::AddBox(*rig.server);
  const std::uint64_t patches_before = session.stats().local.patches;
  const std::uint64_t local_ticks_before = loop.stats().ticks_local;
  EXPECT_TRUE(TickUntilCount(
      loop, 10000, 200,
      [&](const TickRecord& r) { return session.stats().connects >= 2 && LocalPush(r); }))
      << "the local model did not answer after the reconnect: " << session.stats().last_error;
  EXPECT_GT(session.stats().local.patches, patches_before);
  EXPECT_GT(loop.stats().ticks_local, local_ticks_before);
  EXPECT_TRUE(testing::WaitUntil([&] { return session.connected(); }, std::chrono::seconds(5)));
  session.Stop();  // while the disconnect warnings are still expected
}

}  // namespace
}  // namespace hapticpd
