// `hapticpd view --replay`'s player (client/viewer/replay.h), stepped by
// hand on its play clock: the events a recording becomes, that every
// recorded tick reaches the plot exactly once, the contacts and wrench of a
// pose frame, the end and the loop; and LoadReplay's sources and errors.
// Runs in every preset (label services, with the other viewer tests).
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "client/viewer/http_server.h"
#include "client/viewer/replay.h"

namespace hapticpd {
namespace {

using viewer::ReplayInput;
using viewer::ReplayPlayer;

constexpr int kTicks = 100;        // 1 ms apart: 0.099 s
constexpr int kFirstContact = 40;  // ticks 40..69 touch
constexpr int kLastContact = 69;

/// A version 2 recording of a probe going down 1 mm per 10 ticks, touching
/// in ticks 40..69 with two rows, the device frame turned a quarter turn
/// about z (so that W and D differ).
ReplayInput MakeInput() {
  ReplayInput in;
  in.file = "hand-made.csv";
  in.X_WD = Pose::FromQuaternion(Quat(Eigen::AngleAxisd(M_PI / 2, Vec3::UnitZ())), Vec3(0, 0, 0.1));
  device::Recording& rec = in.recording;
  rec.version = 2;
  rec.header = {{"scene", "s"}, {"mode", "pdt"}};
  for (int i = 0; i < kTicks; ++i) {
    device::TrajectorySample s;
    s.t_s = 0.5 + 1e-3 * i;  // a recording need not start at 0
    s.state.X_DH = Pose::FromTranslation(Vec3(0, 0, -1e-4 * i));
    device::RecordedTick t;
    t.X_WA = in.X_WD * s.state.X_DH;
    t.source = i % 2 == 0 ? 1 : 2;
    if (i >= kFirstContact && i <= kLastContact) {
      s.F_cmd_D.force = Vec3(1, 0, 0.5 * i);
      t.num_rows = 2;
      t.rows[0] = {Vec3(0.01, 0, 0), Vec3::UnitZ(), 1e-4};
      t.rows[1] = {Vec3(-0.01, 0, 0), Vec3::UnitZ(), 3e-4};
    }
    rec.samples.push_back(s);
    rec.ticks.push_back(t);
  }
  in.scene.set_scene_id("s");
  in.scene.set_revision(7);
  in.scene.add_bodies()->set_body_id("block");
  in.session.set_session_id(ReplayPlayer::kSessionId);
  in.session.set_mode(v1::PD_MODE_PDT);
  return in;
}

struct Played {
  std::vector<v1::SceneEvent> events;
  std::vector<std::int64_t> sample_times_ns;  // every commanded sample, in order
  std::vector<std::uint64_t> frame_sequences;
};

/// Steps the play clock by `step_s` until the player finishes (or `until_s`).
void Play(ReplayPlayer* p, double step_s, double until_s, Played* out) {
  for (double t = 0; t <= until_s && !p->finished(); t += step_s) {
    const std::size_t first = out->events.size();
    p->AdvanceTo(t, &out->events);
    for (std::size_t i = first; i < out->events.size(); ++i) {
      const v1::SceneEvent& ev = out->events[i];
      if (ev.has_telemetry()) {
        const v1::WrenchSamples& w = ev.telemetry().sessions(0).device().commanded();
        ASSERT_EQ(w.offset_us_size(), w.force_size());
        for (std::uint32_t o : w.offset_us()) {
          out->sample_times_ns.push_back(w.start_time_ns() + 1000 * std::int64_t{o});
        }
      } else if (ev.has_poses()) {
        out->frame_sequences.push_back(ev.poses().probes(0).sequence());
      }
    }
  }
}

TEST(ReplayPlayer, BeginsWithTheSceneThenTheSession) {
  ReplayPlayer p(MakeInput(), false);
  std::vector<v1::SceneEvent> evs;
  p.Begin(&evs);
  ASSERT_EQ(evs.size(), 2u);
  ASSERT_TRUE(evs[0].has_snapshot());
  EXPECT_EQ(evs[0].snapshot().bodies(0).body_id(), "block");
  EXPECT_EQ(evs[0].revision(), 7u);
  ASSERT_TRUE(evs[1].has_sessions());
  EXPECT_EQ(evs[1].sessions().added(0).session_id(), "replay");
  EXPECT_NEAR(p.duration_s(), 0.099, 1e-9);
}

TEST(ReplayPlayer, EveryTickReachesThePlotOnceAndFramesFollowTheRecording) {
  for (const double step : {1.0 / 60, 0.0004, 0.2}) {
    SCOPED_TRACE(fmt::format("play step {} s", step));
    ReplayPlayer p(MakeInput(), false);
    Played played;
    Play(&p, step, 10, &played);
    ASSERT_TRUE(p.finished());
    // Every commanded sample once, in order, 1 ms apart on the replay clock.
    ASSERT_EQ(played.sample_times_ns.size(), static_cast<std::size_t>(kTicks));
    for (int i = 0; i < kTicks; ++i) {
      EXPECT_NEAR(static_cast<double>(played.sample_times_ns[static_cast<std::size_t>(i)]), 1e6 * i,
                  1e3)
          << "sample " << i;
    }
    // Frames move forward and the last one is the last tick.
    ASSERT_FALSE(played.frame_sequences.empty());
    for (std::size_t i = 1; i < played.frame_sequences.size(); ++i) {
      EXPECT_GT(played.frame_sequences[i], played.frame_sequences[i - 1]);
    }
    EXPECT_EQ(played.frame_sequences.back(), static_cast<std::uint64_t>(kTicks));
    // Nothing more once finished.
    std::vector<v1::SceneEvent> after;
    p.AdvanceTo(20, &after);
    EXPECT_TRUE(after.empty());
  }
}

TEST(ReplayPlayer, AFrameShowsTheProxyItsRowsAndTheWrenchInTheWorld) {
  ReplayInput in = MakeInput();
  const ReplayInput copy = in;
  ReplayPlayer p(std::move(in), false);
  std::vector<v1::SceneEvent> evs;
  p.AdvanceTo(0.050, &evs);  // tick 50: in contact
  const v1::ProbeState* probe = nullptr;
  int telemetry = 0;
  for (const auto& ev : evs) {
    if (ev.has_poses()) probe = &ev.poses().probes(0);
    if (ev.has_telemetry()) {
      ++telemetry;
      const v1::DeviceTelemetry& d = ev.telemetry().sessions(0).device();
      EXPECT_EQ(d.ticks_server() + d.ticks_local(), 51u);  // ticks 0..50 alternate 1, 2
      EXPECT_EQ(d.ticks_server(), 26u);
      EXPECT_EQ(d.source(), v1::CONTACT_SOURCE_SERVER);  // tick 50 is even
      EXPECT_NEAR(d.servo_rate_hz(), 1000, 1e-6);
      EXPECT_NEAR(d.commanded().force(50), std::hypot(1.0, 25.0), 1e-4);
    }
  }
  EXPECT_EQ(telemetry, 1);
  ASSERT_NE(probe, nullptr);
  EXPECT_EQ(probe->session_id(), "replay");
  EXPECT_EQ(probe->sequence(), 51u);
  EXPECT_EQ(probe->status(), v1::CONTACT_STATUS_PENETRATING);
  ASSERT_EQ(probe->rows_size(), 2);
  EXPECT_DOUBLE_EQ(probe->rows(1).depth(), 3e-4);
  EXPECT_DOUBLE_EQ(probe->depth(), 3e-4);  // the deepest row
  EXPECT_DOUBLE_EQ(probe->rows(0).point().x(), 0.01);
  EXPECT_DOUBLE_EQ(probe->pose().position().z(), copy.recording.ticks[50].X_WA.t.z());
  // F_cmd_D = (1, 0, 25) turned a quarter about z: (0, 1, 25) in W.
  EXPECT_NEAR(probe->force().x(), 0, 1e-12);
  EXPECT_NEAR(probe->force().y(), 1, 1e-12);
  EXPECT_NEAR(probe->force().z(), 25, 1e-12);

  evs.clear();
  p.AdvanceTo(0.080, &evs);  // tick 80: out of contact again
  ASSERT_FALSE(evs.empty());
  ASSERT_TRUE(evs.back().has_poses());
  EXPECT_EQ(evs.back().poses().probes(0).rows_size(), 0);
  EXPECT_EQ(evs.back().poses().probes(0).status(), v1::CONTACT_STATUS_SEPARATED);
}

TEST(ReplayPlayer, ALoopStartsAgainLaterOnTheSameClock) {
  ReplayPlayer p(MakeInput(), true);
  Played first;
  Play(&p, 0.01, 0.2, &first);  // the whole recording, then 0.1 s of its end
  EXPECT_FALSE(p.finished());
  EXPECT_EQ(first.sample_times_ns.size(), static_cast<std::size_t>(kTicks));
  // Paused for kLoopPauseS after the end: nothing.
  Played second;
  const double restart = 0.099 + ReplayPlayer::kLoopPauseS;
  for (double t = 0.21; t < restart - 0.005; t += 0.01) p.AdvanceTo(t, &second.events);
  EXPECT_TRUE(second.events.empty());
  EXPECT_EQ(p.loops(), 0u);
  for (double t = restart; t <= restart + 0.2; t += 0.01) p.AdvanceTo(t, &second.events);
  EXPECT_EQ(p.loops(), 1u);
  std::int64_t last_first = 0, first_second = -1;
  for (const auto& ev : first.events) last_first = std::max(last_first, ev.server_time_ns());
  for (const auto& ev : second.events) {
    if (ev.has_poses() && first_second < 0) first_second = ev.server_time_ns();
  }
  // The plot's clock never runs backwards across passes.
  EXPECT_GT(first_second, last_first);
}

class LoadReplayTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ =
        std::filesystem::temp_directory_path() /
        fmt::format("hapticpd-replay-test-{}", ::testing::UnitTest::GetInstance()->random_seed());
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::filesystem::path Write(const std::string& name, const std::string& text) {
    const auto p = dir_ / name;
    std::ofstream(p) << text;
    return p;
  }
  /// A two-tick version 2 recording with the given header lines.
  std::filesystem::path Recording(const std::string& header) {
    return Write("rec.csv",
                 "# hapticpd device trajectory v2\n" + header +
                     "t_s,px,py,pz,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz,buttons,fx,fy,fz,tx,ty,tz,"
                     "ax,ay,az,aqw,aqx,aqy,aqz,source,rows\n"
                     "0,0,0,0,1,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0.1,1,0,0,0,3,\n"
                     "0.001,0,0,0,1,0,0,0,0,0,0,0,0,0,0,0,0,1,0,0,0,0,0,0.1,1,0,0,0,1,"
                     "0 0 0 0 0 1 0.001\n");
  }
  std::filesystem::path dir_;
};

TEST_F(LoadReplayTest, TheSceneFromAFileAndTheProbeFromTheHeader) {
  const auto scene = Write("scene.json", R"({"scene": "desk", "bodies": [
      {"id": "desk", "shape": "plate:0.4,0.4,0.02", "pose": {"position": [0, 0, -0.01]}}]})");
  viewer::ReplaySources src;
  src.scene_file = scene.string();
  const ReplayInput in = viewer::LoadReplay(
      Recording(
          "# scene: desk\n# probe: shape:sphere:0.005\n# mode: pdg\n# X_WD: 0 0 0.12 1 0 0 0\n"),
      src);
  EXPECT_EQ(in.scene.scene_id(), "desk");
  ASSERT_EQ(in.scene.bodies_size(), 1);
  EXPECT_GT(in.scene.bodies(0).mesh().triangles_size(), 0);
  EXPECT_GT(in.scene.bodies(0).mesh_info().triangles(), 0u);
  EXPECT_GT(in.session.probe_mesh().vertices_size(), 0);
  EXPECT_EQ(in.session.mode(), v1::PD_MODE_PDG);
  EXPECT_DOUBLE_EQ(in.X_WD.t.z(), 0.12);
  ASSERT_EQ(in.recording.ticks.size(), 2u);
  EXPECT_EQ(in.recording.ticks[1].num_rows, 1);
}

TEST_F(LoadReplayTest, AProbeThatIsABodyOfTheScene) {
  const auto scene = Write("scene.json", R"({"scene": "s", "bodies": [
      {"id": "pen", "shape": "sphere:0.005"}]})");
  viewer::ReplaySources src;
  src.scene_file = scene.string();
  const ReplayInput in = viewer::LoadReplay(Recording("# probe: body:pen\n"), src);
  EXPECT_EQ(in.session.probe_body_id(), "pen");
  src.probe = "body:nope";
  try {
    viewer::LoadReplay(Recording("# probe: body:pen\n"), src);
    FAIL() << "a probe body the scene has not was accepted";
  } catch (const viewer::ViewerError& e) {
    EXPECT_NE(std::string(e.what()).find("'nope'"), std::string::npos) << e.what();
  }
}

TEST_F(LoadReplayTest, BadInputIsNamed) {
  const auto scene = Write("scene.json", R"({"scene": "s", "bodies": [
      {"id": "b", "shape": "sphere:0.005"}]})");
  viewer::ReplaySources src;
  src.scene_file = scene.string();
  const auto expect_error = [&](const std::filesystem::path& file, const std::string& what) {
    try {
      viewer::LoadReplay(file, src);
      ADD_FAILURE() << "accepted; expected an error with '" << what << "'";
    } catch (const viewer::ViewerError& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    }
  };
  expect_error(Write("v1.csv",
                     "# hapticpd device trajectory v1\n"
                     "t_s,px,py,pz,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz,buttons,fx,fy,fz,tx,ty,tz\n"
                     "0,0,0,0,1,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0\n"),
               "version 1 recording");
  expect_error(dir_ / "missing.csv", "missing.csv");
  expect_error(Recording("# scene: s\n"), "names no probe");
  expect_error(Recording("# probe: " + (dir_ / "nothing.obj").string() + "\n"), "nothing.obj");
  expect_error(Recording("# probe: shape:sphere:-1\n"), "sphere:-1");
  expect_error(Recording("# probe: shape:sphere:0.01\n# X_WD: 0 0 0 2 0 0 0\n"), "X_WD");
  src.scene_file = (dir_ / "no-scene.json").string();
  expect_error(Recording("# probe: shape:sphere:0.01\n"), "--scene-file");
  // Without a scene file, the scene comes from a server: none is named here.
  src.scene_file.clear();
  expect_error(Recording("# probe: shape:sphere:0.01\n"), "pass --scene-file");
}

}  // namespace
}  // namespace hapticpd
