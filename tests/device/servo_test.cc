// The servo loop closed through the simulated hand and an in-process PDt
// source, in simulated time: press, slide, plate, closed-loop energy, a
// stalled IR stream, stalls of the whole process, an ended stream, the
// start-up ramp, no allocation in the tick, and the recorder / replay round
// trip (device_tests: every preset).
#include "device/servo_loop.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include "device/replay_device.h"
#include "tests/alloc_counter.h"
#include "tests/device/rig.h"

namespace hapticpd::device {
namespace {

using testing::BoxScene;
using testing::CubeProbe;
using testing::kBoxTop;
using testing::kProbeHalf;
using testing::Rig;
using testing::StartAbove;

ScriptParams Script(HandScript s, double duration = 3) {
  ScriptParams p;
  p.script = s;
  p.X_DS = StartAbove(kBoxTop, 0.005);
  p.duration_s = duration;
  return p;
}

// The whole process stalls before tick `tick`: it comes `stall_ns` after the
// one before (the PD source, pumped after each tick, stalls with it); every
// other tick is one period on.
void StallProcessAt(Rig* rig, std::int64_t tick, std::int64_t stall_ns) {
  rig->tick_time_ns = [tick, stall_ns](std::int64_t n, std::int64_t previous_ns) {
    return previous_ns + (n == tick ? stall_ns : 1'000'000);
  };
}

TEST(Servo, PressPushesOutAndGrowsWithDepth) {
  Rig rig(Script(HandScript::kPress), CubeProbe(), BoxScene());
  double max_fz = 0, min_fz = 0;
  std::vector<std::pair<double, double>> down;  // (handle depth, force) on the way down
  rig.Run(3.2, [&](const TickRecord& r) {
    const double fz = r.F_cmd_W.force.z();  // on the hand: +z pushes out of the box
    max_fz = std::max(max_fz, fz);
    min_fz = std::min(min_fz, fz);
    const double depth = kBoxTop - (r.X_WH.t.z() - kProbeHalf);
    if (rig.time_s() < 1.3 && depth > 0.0005) down.emplace_back(depth, fz);
    // Never pulls the hand into the surface, never sideways.
    EXPECT_LT(std::hypot(r.F_cmd_W.force.x(), r.F_cmd_W.force.y()), 0.05);
  });
  EXPECT_GT(max_fz, 2.0);
  // The coupling damper may tug lightly while the hand lifts off quickly.
  EXPECT_GT(min_fz, -0.2);
  ASSERT_GT(down.size(), 100u);
  // Force grows with depth (mean force per 0.5 mm bin of handle depth; the
  // hand bounces a little on impact, so tick-to-tick it is not monotone)
  // and is about the series stiffness of coupling and contact.
  std::vector<double> sum(64, 0), n(64, 0);
  for (const auto& [d, f] : down) {
    const auto b = static_cast<std::size_t>(d / 0.0005);
    if (b < sum.size()) sum[b] += f, n[b] += 1;
  }
  int bins = 0;
  double prev = -1;
  for (std::size_t b = 0; b < sum.size(); ++b) {
    if (n[b] < 5) continue;
    EXPECT_GT(sum[b] / n[b], prev) << "depth bin " << b;
    prev = sum[b] / n[b];
    ++bins;
  }
  EXPECT_GE(bins, 5);
  const double k_l = rig.loop->coupling().gains.k_lin, k_c = 5000;
  const auto& [d, f] = down.back();
  EXPECT_NEAR(f / d, k_l * k_c / (k_l + k_c), 0.2 * k_l);
  EXPECT_EQ(rig.loop->stats().device_errors, 0u);
}

TEST(Servo, SlideKeepsContactWithoutPopThrough) {
  Rig rig(Script(HandScript::kSlide, 4), CubeProbe(), BoxScene());
  int contact_ticks = 0, lost = 0;
  const double k_c = 5000, fmax = rig.device->info().max_force;
  rig.Run(4, [&](const TickRecord& r) {
    const double t = rig.time_s();
    // The proxy never sinks deeper than the largest force the coupling can
    // apply allows (F_max / k_c), plus a millimetre for blending lag.
    EXPECT_GT(r.proxy.X_WP.t.z() - kProbeHalf, kBoxTop - fmax / k_c - 0.001);
    if (t > 1.2 && t < 3.0) {  // pressed and sliding sideways
      if (r.F_cmd_W.force.z() > 0.5)
        ++contact_ticks;
      else
        ++lost;
    }
  });
  EXPECT_GT(contact_ticks, 1700);
  EXPECT_EQ(lost, 0);
  EXPECT_GT(rig.loop->last_tick().X_WH.t.x(), 0.03);  // it did slide
}

TEST(Servo, PlateForceNeverFlipsInside) {
  // A 4 mm plate (thinner than F_max / k_l = 12 mm) with a stiff surface;
  // the hand goes 4 cm down, far through it.
  pd::Material m;
  m.stiffness = 20000;
  std::vector<pd::SceneBody> plate = {
      {pd::MakeModel(pd::shapes::ThinPlate(0.2, 0.2, 0.004)), Pose::Identity(), m}};
  ScriptParams sp = Script(HandScript::kPlate);
  sp.X_DS = StartAbove(0.002, 0.005);
  sp.travel = 0.04;
  Rig rig(sp, CubeProbe(), plate);
  double max_fz = 0;
  int below = 0;
  rig.Run(3.2, [&](const TickRecord& r) {
    const double fz = r.F_cmd_W.force.z();
    max_fz = std::max(max_fz, fz);
    if (r.X_WH.t.z() - kProbeHalf < -0.002) {  // handle bottom under the plate's bottom face
      ++below;
      EXPECT_GT(fz, -1e-6) << "force flipped at t=" << rig.time_s();
    }
    EXPECT_GT(r.proxy.X_WP.t.z(), 0.0);  // the proxy's centre stays above the mid-plane
  });
  EXPECT_GT(below, 300);  // the handle went through the plate
  EXPECT_GT(max_fz, 5.0);
}

TEST(Servo, ClosedLoopInStaticScenePutsAtMostEpsilonIntoTheHand) {
  for (HandScript s : {HandScript::kLoop, HandScript::kPress, HandScript::kCircle}) {
    SCOPED_TRACE(ToString(s));
    ScriptParams sp = Script(s);
    sp.radius = 0.01;
    Rig rig(sp, CubeProbe(), BoxScene());
    rig.Run(3.5);
    EXPECT_GT(rig.loop->stats().max_force, 1.0);        // it touched
    EXPECT_LT(rig.device->energy_into_hand_j(), 1e-3);  // J
    EXPECT_GT(rig.loop->stats().passivity_min_j, -1e-3);
  }
}

TEST(Servo, StalledIrStreamFadesAndRecovers) {
  // Hold the probe pressed (press script frozen at its deepest), stall the
  // PD source for 200 ms.
  // (4 s press: deepest and still from 1.8 s to 2.2 s.)
  ScriptParams sp = Script(HandScript::kPress, 4);
  Rig rig(sp, CubeProbe(), BoxScene());
  auto stalled = [](double t) { return t > 1.85 && t <= 2.05; };
  double before = 0, max_df = 0, prev = 0;
  double at_50ms = 1e9, gain_at_50ms = 1e9, stretch_at_50ms = 1e9, at_100ms = 1e9, after = 0;
  rig.Run(
      2.2,
      [&](const TickRecord& r) {
        const double t = rig.time_s(), fz = r.F_cmd_W.force.z();
        if (std::abs(t - 1.85) < 5e-4) before = fz;
        if (std::abs(t - 1.901) < 5e-4) {
          at_50ms = fz;
          gain_at_50ms = r.link_gain;
          stretch_at_50ms = (r.X_WH.t - r.proxy.X_WP.t).norm();
        }
        if (std::abs(t - 1.951) < 5e-4) at_100ms = fz;
        if (std::abs(t - 2.19) < 5e-4) after = fz;
        if (t > 1.5) max_df = std::max(max_df, std::abs(fz - prev));
        prev = fz;
      },
      stalled);
  EXPECT_GT(before, 2.0);
  // 50 ms after the last answer the commanded force is gone (stale at 20 ms,
  // the output faded over the next 20 ms, the proxy then held on the
  // handle: no coupling stretch left while the hand sinks).
  EXPECT_EQ(gain_at_50ms, 0.0);
  EXPECT_EQ(stretch_at_50ms, 0.0);
  EXPECT_LT(std::abs(at_50ms), 1e-3);
  EXPECT_LT(std::abs(at_100ms), 1e-3);
  // Recovered: contact is back (stronger: the hand sank deeper meanwhile),
  // ramped in over 100 ms rather than as a step of several newtons.
  EXPECT_GT(after, 0.75 * before);
  EXPECT_LE(after, rig.device->info().max_force + 1e-9);
  EXPECT_LT(max_df, 1.0);
  EXPECT_GT(rig.loop->stats().stale_ticks, 100u);
}

TEST(Servo, AStallOfTheWholeProcessIsNotALinkLoss) {
  // The machine stalls the process for 30 ms with the probe pressed: the
  // servo's tick and the PD source's answers stop together, so the late
  // tick finds the IR 30 ms old, past its 20 ms staleness. That says
  // nothing about the link: the next answer is one tick away. The output
  // must not fade to zero and the proxy must not be put on the handle (it
  // would land inside the box, and the returning answers would push it
  // and the hand out with energy nobody put in). A real link loss still
  // fades: StalledIrStreamFadesAndRecovers.
  ScriptParams sp = Script(HandScript::kPress, 4);
  Rig rig(sp, CubeProbe(), BoxScene());
  constexpr std::int64_t kStallTick = 1900;
  StallProcessAt(&rig, kStallTick, 30'000'000);
  double before = 0, min_gain = 1, min_stretch = 1, min_force = 1e9;
  int stale_late_ticks = 0;
  rig.Run(2.2, [&](const TickRecord& r) {
    const std::int64_t n = rig.tick;
    const double fz = r.F_cmd_W.force.z();
    if (n == kStallTick - 1) before = fz;
    if (n == kStallTick && r.ir.stale) ++stale_late_ticks;
    if (n >= kStallTick && n < kStallTick + 20) {
      min_gain = std::min(min_gain, r.link_gain);
      min_stretch = std::min(min_stretch, (r.X_WH.t - r.proxy.X_WP.t).norm());
      min_force = std::min(min_force, fz);
    }
  });
  EXPECT_GT(before, 2.0);
  EXPECT_EQ(stale_late_ticks, 1)
      << "the late tick must find the IR stale for this test to mean anything";
  EXPECT_EQ(min_gain, 1.0);
  EXPECT_GT(min_stretch, 1e-3);
  EXPECT_GT(min_force, 0.75 * before);
  EXPECT_GE(rig.loop->stats().passivity_min_j, -1e-4);
}

TEST(Servo, AStallDuringTheRampAfterALossHoldsTheGain) {
  // A real loss (the PD source stalled for 200 ms) fades the output; once
  // answers return it ramps back over 100 ms. A stall of the whole process
  // in the middle of that ramp neither fades nor ramps on its late tick:
  // the gain holds, and the ramp goes on from the next tick.
  ScriptParams sp = Script(HandScript::kPress, 4);
  Rig rig(sp, CubeProbe(), BoxScene());
  constexpr std::int64_t kStallTick = 2100;
  StallProcessAt(&rig, kStallTick, 30'000'000);
  auto lost = [](double t) { return t > 1.85 && t <= 2.05; };
  double gain_before = -1, gain_late = -1, gain_after = -1, min_gain = 1;
  bool stale_late = false;
  rig.Run(
      2.2,
      [&](const TickRecord& r) {
        min_gain = std::min(min_gain, r.link_gain);
        if (rig.tick == kStallTick - 1) gain_before = r.link_gain;
        if (rig.tick == kStallTick) {
          gain_late = r.link_gain;
          stale_late = r.ir.stale;
        }
        if (rig.tick == kStallTick + 1) gain_after = r.link_gain;
      },
      lost);
  EXPECT_EQ(min_gain, 0.0) << "the loss must fade the output to zero";
  EXPECT_GT(gain_before, 0.0);
  EXPECT_LT(gain_before, 1.0) << "the stall must fall inside the ramp";
  EXPECT_TRUE(stale_late);
  EXPECT_EQ(gain_late, gain_before);
  EXPECT_GT(gain_after, gain_late);
}

TEST(Servo, EndedStreamFadesAtOnceAndDropsLateIrs) {
  // The session says its stream ended (RequestLinkLost) while the PD source
  // still delivers fresh IRs, as a last answer or a local model's might: the
  // output fades over link_fade_time_s from the next tick, without waiting
  // for the IR to age, and nothing arriving later is rendered until a reset
  // (a new stream).
  ScriptParams sp = Script(HandScript::kPress, 4);
  Rig rig(sp, CubeProbe(), BoxScene());
  double before = 0, at_21ms = 1e9, max_after = 0;
  int late_irs = 0, fresh_after_reset = 0;
  rig.Run(2.2, [&](const TickRecord& r) {
    const double t = rig.time_s(), f = r.F_cmd_W.force.norm();
    if (std::abs(t - 1.85) < 5e-4) {
      before = f;
      rig.loop->RequestLinkLost();
    }
    if (std::abs(t - 1.872) < 5e-4) at_21ms = f;
    if (t > 1.872 && t < 2.0) {
      max_after = std::max(max_after, f);
      if (r.new_ir) ++late_irs;
      EXPECT_TRUE(r.ir.stale) << "t=" << t;
    }
    if (std::abs(t - 2.0) < 5e-4) rig.loop->RequestResetContact();
    if (t > 2.01 && r.new_ir && !r.ir.stale) ++fresh_after_reset;
  });
  EXPECT_GT(before, 2.0);
  EXPECT_LT(at_21ms, 1e-3);
  EXPECT_LT(max_after, 1e-3);
  EXPECT_EQ(late_irs, 0);
  EXPECT_GT(fresh_after_reset, 50);
}

TEST(Servo, StartupWaitsForQuietThenRamps) {
  // Start with the handle 5 mm inside the box: the proxy is put at the
  // handle and pushed out, and nothing is sent until things are quiet.
  ScriptParams sp = Script(HandScript::kHold);
  sp.X_DS = StartAbove(kBoxTop, -0.005);
  Rig rig(sp, CubeProbe(), BoxScene());
  double max_df = 0, prev = 0;
  rig.Run(1.0, [&](const TickRecord& r) {
    max_df = std::max(max_df, (r.F_cmd_W.force.norm() - prev));
    prev = r.F_cmd_W.force.norm();
    if (rig.time_s() < 0.015) {
      EXPECT_EQ(r.startup_gain, 0.0);
      EXPECT_EQ(r.F_cmd_W.force.norm(), 0.0);
    }
  });
  EXPECT_LT(max_df, 0.2);
}

TEST(Servo, TickDoesNotAllocate) {
  if (!hapticpd::testing::CountAllocations::Available()) GTEST_SKIP() << "sanitizer build";
  Rig rig(Script(HandScript::kSlide, 2), CubeProbe(), BoxScene());
  rig.Run(0.9);  // warm up, into contact
  std::size_t allocations = 0;
  for (int i = 0; i < 500; ++i) {
    rig.clock.Set((++rig.tick) * 1'000'000);
    {
      hapticpd::testing::CountAllocations count;
      rig.loop->Tick(rig.clock.NowNs());
      allocations += count.count();
    }
    rig.source->Pump(rig.loop.get(), rig.clock.NowNs());
  }
  EXPECT_GT(rig.loop->stats().ir_updates, 800u);
  EXPECT_EQ(allocations, 0u);
}

TEST(Recorder, RecordThenReplayReproducesTheTrajectory) {
  ManualClock clock;
  ScriptParams sp = Script(HandScript::kTwist, 1);
  SimulatedDevice sim(sp, &clock);
  RecordingDevice rec(&sim, 2000);
  rec.Open();
  ServoLoop loop(&rec, ServoConfig{}, &clock);
  for (int i = 1; i <= 1000; ++i) {
    clock.Set(i * 1'000'000LL);
    loop.Tick(clock.NowNs());
  }
  const auto path = std::filesystem::temp_directory_path() / "hapticpd_recorder_test.csv";
  rec.Save(path);
  ManualClock clock2;
  ReplayDevice replay(path, &clock2);
  replay.Open();
  ASSERT_EQ(rec.samples().size(), 1000u);
  for (std::size_t i = 0; i < 1000; i += 37) {
    clock2.Set(std::llround(rec.samples()[i].t_s * 1e9));
    DeviceState s;
    ASSERT_NE(replay.Read(&s), DeviceStatus::kError);
    EXPECT_LT((s.X_DH.t - rec.samples()[i].state.X_DH.t).norm(), 1e-8);
    EXPECT_LT(Quat(s.X_DH.R).angularDistance(Quat(rec.samples()[i].state.X_DH.R)), 1e-6);
  }
  clock2.Set(5'000'000'000LL);
  DeviceState s;
  EXPECT_EQ(replay.Read(&s), DeviceStatus::kEndOfData);
  std::filesystem::remove(path);
}

// Version 2: with the recorder set on the loop, each tick keeps the proxy
// pose and the IR's rows touching at the proxy, and the header; all of it
// loads back, and a v2 file still replays as a trajectory.
TEST(Recorder, VersionTwoKeepsTheProxyAndItsContactRows) {
  ManualClock clock;
  SimulatedDevice sim(Script(HandScript::kHold, 1), &clock);
  RecordingDevice rec(&sim, 200);
  rec.SetHeader({{"scene", "default"}, {"probe", "shape:stick"}, {"X_WD", PoseValue(Pose{})}});
  rec.Open();
  ServoConfig cfg;
  cfg.recorder = &rec;
  ServoLoop loop(&rec, cfg, &clock);
  for (int i = 1; i <= 100; ++i) {
    clock.Set(i * 1'000'000LL);
    if (i == 50) {
      // A floor 2 mm above the proxy: one row, 2 mm deep where it is.
      IntermediateRep ir;
      ir.X_WP_ref = loop.last_tick().proxy.X_WP;
      ir.receive_time_ns = clock.NowNs();
      ir.num_rows = 1;
      ir.rows[0].p_W = ir.X_WP_ref.t + Vec3(0, 0, -0.01);
      ir.rows[0].n_W = Vec3::UnitZ();
      ir.rows[0].depth = 0.002;
      ir.rows[0].stiffness = 100;
      loop.ir_mailbox().Write(ir);
    }
    loop.Tick(clock.NowNs());
  }
  ASSERT_EQ(rec.ticks().size(), 100u);
  const auto path = std::filesystem::temp_directory_path() / "hapticpd_recorder_v2_test.csv";
  rec.Save(path);
  const Recording r = LoadRecording(path);
  EXPECT_EQ(r.version, 2);
  EXPECT_EQ(r.Header("scene"), "default");
  EXPECT_EQ(r.Header("probe"), "shape:stick");
  EXPECT_LT(ParsePoseValue(r.Header("X_WD")).t.norm(), 1e-12);
  EXPECT_EQ(r.Header("start_ns"), "1000000");  // the clock at the first tick (t_s = 0)
  ASSERT_EQ(r.samples.size(), 100u);
  ASSERT_EQ(r.ticks.size(), 100u);
  EXPECT_EQ(r.ticks[10].num_rows, 0);
  ASSERT_EQ(r.ticks[60].num_rows, 1);
  EXPECT_NEAR(r.ticks[60].rows[0].n_W.z(), 1.0, 1e-6);
  EXPECT_GT(r.ticks[60].rows[0].depth, 0.0015);
  EXPECT_EQ(r.ticks[60].source, static_cast<std::uint8_t>(TickSource::kServer));
  EXPECT_LT((r.ticks[99].X_WA.t - rec.ticks()[99].X_WA.t).norm(), 1e-8);
  EXPECT_EQ(LoadTrajectoryCsv(path).size(), 100u);
  std::filesystem::remove(path);
}

TEST(Recorder, MalformedVersionTwoRowsNameTheProblem) {
  const auto path = std::filesystem::temp_directory_path() / "hapticpd_bad_traj_v2.csv";
  const std::string head =
      "# hapticpd device trajectory v2\n# scene: s\n"
      "t_s,px,py,pz,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz,buttons,fx,fy,fz,tx,ty,tz,"
      "ax,ay,az,aqw,aqx,aqy,aqz,source,rows\n"
      "0,0,0,0,1,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,1,0,0,0,1,\n";
  const std::pair<std::string, std::string> cases[] = {
      {"0.001,0,0,0,1,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,1,0,0,0,1,0 0 0 0 0 1\n",
       ":5: row 1 is not 7 finite numbers"},
      {"0.001,0,0,0,1,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,1,0,0,0,1,0 0 0 0 0 1 nan\n",
       ":5: row 1 is not 7 finite numbers"},
      {"0.001,0,0,0,1,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,2,0,0,0,1,\n",
       ":5: the proxy pose (columns 22-28): quaternion is not unit"},
      {"0.001,0,0,0,1,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,1,0,0,0,7,\n",
       ":5: source is not 1, 2 or 3"},
      {"0.001,0,0,0,1,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,1,0,0,0,1\n",
       ":5: expected 30 columns, got 29"},
  };
  for (const auto& [line, want] : cases) {
    {
      std::ofstream f(path);
      f << head << line;
    }
    try {
      LoadRecording(path);
      ADD_FAILURE() << "no error for " << line;
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(want), std::string::npos) << e.what();
    }
  }
  std::filesystem::remove(path);
}

TEST(Recorder, MalformedCsvNamesFileAndLine) {
  const auto path = std::filesystem::temp_directory_path() / "hapticpd_bad_traj.csv";
  {
    std::ofstream f(path);
    f << "# hapticpd device trajectory v1\n"
         "t_s,px,py,pz,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz,buttons,fx,fy,fz,tx,ty,tz\n"
         "0,0,0,0,1,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0\n"
         "0.001,0,0,nan,1,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0\n";
  }
  try {
    LoadTrajectoryCsv(path);
    ADD_FAILURE() << "no error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(":4: column 4"), std::string::npos) << e.what();
  }
  std::filesystem::remove(path);
}

}  // namespace
}  // namespace hapticpd::device
