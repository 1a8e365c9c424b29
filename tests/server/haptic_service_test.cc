// HapticService.Couple over both transports: scripted poses into a body, the
// newest-pose mailbox, the probe taken from a scene body, hello and pose
// validation, the session limit, and scene deletion.
#include <cmath>

#include "pd/shapes.h"
#include "tests/server/patch_client.h"
#include "tests/server/server_harness.h"
#include "tests/test_util.h"

namespace hapticpd::testing {
namespace {

class HapticServiceTest : public ::testing::TestWithParam<Transport> {};

constexpr double kBoxTop = 0.05;       // box:0.05 -> top face at z = 0.05
constexpr double kProbeRadius = 0.01;  // sphere:0.01,2

TEST_P(HapticServiceTest, ScriptedPosesIntoABodyGetOneAnswerEachPushingOut) {
  FloorHarness h(GetParam(), "box:0.05,0.05,0.05");
  Session s(*h.haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello()).ok());
  EXPECT_EQ(s.welcome().protocol_version(), 1u);
  EXPECT_FALSE(s.welcome().session_id().empty());
  EXPECT_EQ(s.welcome().probe_mesh_info().triangles(), 320u);

  // Down from 3 cm above contact to 1.5 cm into the box, then back up.
  std::vector<double> zs;
  for (int i = 0; i <= 30; ++i) zs.push_back(0.09 - 0.0015 * i);
  for (int i = 29; i >= 0; --i) zs.push_back(zs[i]);
  int penetrating = 0;
  for (std::size_t k = 0; k < zs.size(); ++k) {
    const std::uint64_t seq = 100 + k;
    const double x = 0.003 * std::sin(static_cast<double>(k));  // a little sideways wobble
    ASSERT_TRUE(s.Send(seq, MakePose(x, 0.002, zs[k]), 5000 + static_cast<std::int64_t>(k)));
    const auto u = s.Next();
    ASSERT_TRUE(u.has_value()) << "no answer for pose " << seq;
    SCOPED_TRACE("z = " + std::to_string(zs[k]));
    EXPECT_EQ(u->sequence(), seq);
    EXPECT_EQ(u->client_time_ns(), 5000 + static_cast<std::int64_t>(k));
    EXPECT_DOUBLE_EQ(u->pose_ref().position().z(), zs[k]);
    EXPECT_DOUBLE_EQ(u->pose_ref().position().x(), x);
    EXPECT_GT(u->server_send_time_ns(), 0);
    EXPECT_GE(u->server_send_time_ns(), u->server_receive_time_ns());
    EXPECT_GT(u->validity_radius(), 0);
    const double overlap = kBoxTop + kProbeRadius - zs[k];  // upper bound (inscribed sphere)
    if (overlap < -1e-3) {
      EXPECT_EQ(u->status(), v1::CONTACT_STATUS_SEPARATED);
      EXPECT_EQ(u->rows_size(), 0);
      EXPECT_EQ(u->force().z(), 0.0);
      continue;
    }
    if (overlap < 2e-3) continue;  // near the surface: facet-dependent, either answer is right
    ++penetrating;
    EXPECT_EQ(u->status(), v1::CONTACT_STATUS_PENETRATING);
    ASSERT_GE(u->rows_size(), 1);
    EXPECT_EQ(u->body_ids(0), "floor");
    // Pushes out of the top face: up, with the depth of the overlap.
    EXPECT_GT(u->depth(), 0.5 * overlap);
    EXPECT_LE(u->depth(), overlap + 1e-9);
    EXPECT_GT(u->force().z(), 0.0);
    EXPECT_NEAR(u->force().z(), 1000.0 * u->depth(), 0.05 * 1000.0 * u->depth());
    EXPECT_NEAR(u->force().x(), 0.0, 1e-6);
    EXPECT_NEAR(u->pd_translation().z(), u->depth(), 1e-9);
    EXPECT_NEAR(u->target_pose().position().z(), zs[k] + u->depth(), 1e-9);
    for (const auto& row : u->rows()) {
      EXPECT_NEAR(row.normal().z(), 1.0, 1e-9);
      EXPECT_GT(row.depth(), 0.0);
      EXPECT_DOUBLE_EQ(row.stiffness(), 1000.0);
      EXPECT_EQ(row.body_index(), 0u);
    }
    EXPECT_GT(u->compute_time_us(), 0.0);
  }
  EXPECT_GE(penetrating, 10);
  s.ExpectCleanEnd();
}

TEST_P(HapticServiceTest, PdgSessionPushesOutWithTheFullAnswerPose) {
  // A sphere probe pressed into a box, tilted: PDg answers with a target
  // pose (translation and rotation) whose translation pushes out of the top
  // face, never deeper than PDt's straight push, and a force pushing up.
  FloorHarness h(GetParam(), "box:0.05,0.05,0.05");
  Session s(*h.haptics);
  auto hello = Session::DefaultHello();
  hello.set_mode(v1::PD_MODE_PDG);
  ASSERT_TRUE(s.Open(hello).ok());
  int penetrating = 0;
  for (int k = 0; k <= 20; ++k) {
    const double z = 0.07 - 0.0008 * k;
    ASSERT_TRUE(s.Send(10 + k, MakePose(0.001, 0.002, z), k));
    const auto u = s.Next();
    ASSERT_TRUE(u.has_value());
    EXPECT_EQ(u->sequence(), static_cast<std::uint64_t>(10 + k));
    const double overlap = kBoxTop + kProbeRadius - z;
    if (overlap < 2e-3) continue;
    ++penetrating;
    SCOPED_TRACE("z = " + std::to_string(z));
    EXPECT_EQ(u->status(), v1::CONTACT_STATUS_PENETRATING);
    EXPECT_GT(u->depth(), 0.0);
    EXPECT_LE(u->depth(), overlap + 1e-9);  // sqrt(sigma) <= the straight push out
    EXPECT_GT(u->target_pose().position().z(), z);
    EXPECT_GT(u->force().z(), 0.0);
    EXPECT_NEAR(std::sqrt(u->sigma()), u->depth(), 1e-12) << "not a PDg answer";
    for (const auto& row : u->rows()) {
      const double n =
          std::sqrt(row.normal().x() * row.normal().x() + row.normal().y() * row.normal().y() +
                    row.normal().z() * row.normal().z());
      EXPECT_NEAR(n, 1.0, 1e-12) << "row normals are unit";
    }
    EXPECT_TRUE(std::isfinite(u->rotation_angle()));
    EXPECT_TRUE(std::isfinite(u->torque().x()) && std::isfinite(u->torque().y()) &&
                std::isfinite(u->torque().z()));
  }
  EXPECT_GE(penetrating, 5);
  s.ExpectCleanEnd();
}

TEST_P(HapticServiceTest, ModeNoneEchoesWithoutPd) {
  FloorHarness h(GetParam(), "box");
  Session s(*h.haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello("default", v1::PD_MODE_NONE)).ok());
  for (std::uint64_t seq = 1; seq <= 20; ++seq) {
    ASSERT_TRUE(s.Send(seq, MakePose(0, 0, 0)));  // deep inside the box: no PD anyway
    const auto u = s.Next();
    ASSERT_TRUE(u);
    EXPECT_EQ(u->sequence(), seq);
    EXPECT_EQ(u->status(), v1::CONTACT_STATUS_NONE);
    EXPECT_EQ(u->rows_size(), 0);
  }
  s.ExpectCleanEnd();
}

TEST_P(HapticServiceTest, BurstOfPosesIsAnsweredNewestFirstNeverQueued) {
  FloorHarness h(GetParam(), "box");
  Session s(*h.haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello()).ok());
  constexpr int kPoses = 300;
  for (int k = 1; k <= kPoses; ++k) {
    ASSERT_TRUE(s.Send(k, MakePose(0, 0, 0.055 - 1e-5 * k)));
  }
  s.CloseWrites();
  std::uint64_t last = 0;
  int answers = 0;
  std::uint64_t superseded = 0;
  while (auto u = s.Next()) {
    EXPECT_GT(u->sequence(), last);  // never an older pose after a newer one
    last = u->sequence();
    superseded += u->poses_superseded();
    ++answers;
  }
  EXPECT_TRUE(s.Finish().ok());
  EXPECT_EQ(last, static_cast<std::uint64_t>(kPoses));  // the newest pose is always answered
  EXPECT_GE(answers, 1);
  EXPECT_LE(answers + superseded, static_cast<std::uint64_t>(kPoses));
}

TEST_P(HapticServiceTest, StaleSequenceNumbersAreIgnored) {
  ServerHarness h(GetParam());
  auto haptics = h.Haptics();
  Session s(*haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello("default", v1::PD_MODE_NONE)).ok());
  ASSERT_TRUE(s.Send(10, MakePose(0, 0, 0)));
  ASSERT_EQ(s.Next()->sequence(), 10u);
  ASSERT_TRUE(s.Send(5, MakePose(0, 0, 0)));  // older: ignored
  ASSERT_TRUE(s.Send(11, MakePose(0, 0, 0)));
  EXPECT_EQ(s.Next()->sequence(), 11u);
  s.ExpectCleanEnd();
}

TEST_P(HapticServiceTest, ProbeFromASceneBodyIgnoresItself) {
  FloorHarness h(GetParam(), "box:0.05,0.05,0.05");
  ASSERT_TRUE(AddShape(*h.scenes, "default", "sphere:0.01,2", "tool", MakePose(0, 0, 0.055)).ok());
  Session s(*h.haptics);
  v1::Hello hello = Session::DefaultHello();
  hello.set_probe_body_id("tool");
  ASSERT_TRUE(s.Open(hello).ok());
  ASSERT_TRUE(s.Send(1, MakePose(0, 0, 0.055)));
  const auto u = s.Next();
  ASSERT_TRUE(u);
  EXPECT_EQ(u->status(), v1::CONTACT_STATUS_PENETRATING);
  ASSERT_EQ(u->body_ids_size(), 1);
  EXPECT_EQ(u->body_ids(0), "floor");
  EXPECT_LT(u->depth(), 0.0051);
}

TEST_P(HapticServiceTest, ProbeMaterialCombinesInSeries) {
  FloorHarness h(GetParam(), "box:0.05,0.05,0.05");
  Session s(*h.haptics);
  v1::Hello hello = Session::DefaultHello();
  hello.mutable_material()->set_stiffness(1000);  // with the floor's 1000: 500 N/m
  ASSERT_TRUE(s.Open(hello).ok());
  ASSERT_TRUE(s.Send(1, MakePose(0, 0, 0.055)));
  const auto u = s.Next();
  ASSERT_TRUE(u && u->rows_size() > 0);
  EXPECT_DOUBLE_EQ(u->rows(0).stiffness(), 500.0);
  EXPECT_NEAR(u->force().z(), 500.0 * u->depth(), 0.05 * 500.0 * u->depth());
}

struct HelloCase {
  std::string name;
  v1::Hello hello;
  grpc::StatusCode code;
  std::string field;
};

TEST_P(HapticServiceTest, InvalidHellosAreRejectedNamingTheField) {
  FloorHarness h(GetParam(), "box");
  const auto before = GetScene(*h.scenes, "default");
  std::vector<HelloCase> cases;
  auto base = Session::DefaultHello();
  {
    auto x = base;
    x.set_protocol_version(2);
    cases.push_back(
        {"version", x, grpc::StatusCode::FAILED_PRECONDITION, "hello.protocol_version"});
  }
  {
    auto x = base;
    x.set_mode(static_cast<v1::PdMode>(77));
    cases.push_back({"unknown mode", x, grpc::StatusCode::INVALID_ARGUMENT, "hello.mode"});
  }
  {
    auto x = base;
    x.set_mode(v1::PD_MODE_UNSPECIFIED);
    cases.push_back({"no mode", x, grpc::StatusCode::INVALID_ARGUMENT, "hello.mode"});
  }
  {
    auto x = base;
    x.set_scene_id("nowhere");
    cases.push_back({"scene", x, grpc::StatusCode::NOT_FOUND, "hello.scene_id"});
  }
  {
    auto x = base;
    x.clear_probe_shape();
    cases.push_back({"no probe", x, grpc::StatusCode::INVALID_ARGUMENT, "hello.probe"});
  }
  {
    auto x = base;
    x.set_probe_shape("sphere:-1");
    cases.push_back({"bad shape", x, grpc::StatusCode::INVALID_ARGUMENT, "hello.probe_shape"});
  }
  {
    auto x = base;
    x.set_probe_body_id("ghost");
    cases.push_back({"ghost body", x, grpc::StatusCode::NOT_FOUND, "hello.probe_body_id"});
  }
  {
    auto x = base;
    x.mutable_probe_mesh()->add_vertices(0);
    cases.push_back(
        {"bad inline probe", x, grpc::StatusCode::INVALID_ARGUMENT, "hello.probe_mesh.vertices"});
  }
  {
    auto x = base;
    x.mutable_material()->set_stiffness(std::nan(""));
    cases.push_back(
        {"material", x, grpc::StatusCode::INVALID_ARGUMENT, "hello.material.stiffness"});
  }
  {
    auto x = base;
    x.set_max_rate_hz(-5);
    cases.push_back({"rate", x, grpc::StatusCode::INVALID_ARGUMENT, "hello.max_rate_hz"});
  }
  for (const auto& c : cases) {
    SCOPED_TRACE(c.name);
    Session s(*h.haptics);
    const grpc::Status st = s.Open(c.hello);
    EXPECT_EQ(st.error_code(), c.code) << st.error_message();
    EXPECT_NE(st.error_message().find(c.field), std::string::npos) << st.error_message();
  }
  EXPECT_EQ(GetScene(*h.scenes, "default").revision(), before.revision());
  ASSERT_TRUE(WaitUntil([&] { return h.server().counts().sessions == 0; }));
}

/// `s` answers nothing more and ends with `code`, its message naming `field`.
::testing::AssertionResult EndsNaming(Session& s, grpc::StatusCode code, const std::string& field) {
  const bool answered = s.Next().has_value();
  const grpc::Status st = s.Finish();
  if (!answered && st.error_code() == code && st.error_message().find(field) != std::string::npos) {
    return ::testing::AssertionSuccess();
  }
  return ::testing::AssertionFailure()
         << (answered ? "answered again, then " : "") << "ended with code " << st.error_code()
         << " '" << st.error_message() << "' (want code " << code << " naming '" << field << "')";
}

TEST_P(HapticServiceTest, InvalidStreamsEndTheSessionNamingTheField) {
  ServerHarness h(GetParam());
  auto haptics = h.Haptics();
  {
    Session s(*haptics);  // a pose before the hello
    ASSERT_TRUE(s.Send(1, MakePose(0, 0, 0)));
    EXPECT_TRUE(EndsNaming(s, grpc::StatusCode::FAILED_PRECONDITION, "pose"));
  }
  for (const v1::Pose& bad : {MakePose(0, 0, 0, 0.3, 0, 0, 0), MakePose(0, std::nan(""), 0)}) {
    Session s(*haptics);
    ASSERT_TRUE(s.Open(Session::DefaultHello()).ok());
    ASSERT_TRUE(s.Send(1, MakePose(0, 0, 1)));
    ASSERT_TRUE(s.Next());
    s.Send(2, bad);
    EXPECT_TRUE(EndsNaming(s, grpc::StatusCode::INVALID_ARGUMENT, "pose.pose."));
  }
  {
    Session s(*haptics);  // a second hello
    ASSERT_TRUE(s.Open(Session::DefaultHello()).ok());
    v1::CoupleRequest again;
    *again.mutable_hello() = Session::DefaultHello();
    s.Write(again);
    EXPECT_TRUE(EndsNaming(s, grpc::StatusCode::INVALID_ARGUMENT, "hello"));
  }
  {
    Session s(*haptics);  // an empty message
    ASSERT_TRUE(s.Open(Session::DefaultHello()).ok());
    s.Write(v1::CoupleRequest());
    EXPECT_FALSE(s.Next());
    EXPECT_EQ(s.Finish().error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  }
}

TEST_P(HapticServiceTest, SessionLimit) {
  server::ServerOptions opt;
  opt.limits.max_sessions = 2;
  ServerHarness h(GetParam(), opt);
  auto haptics = h.Haptics();
  auto a = std::make_unique<Session>(*haptics);
  Session b(*haptics);
  ASSERT_TRUE(a->Open(Session::DefaultHello()).ok());
  ASSERT_TRUE(b.Open(Session::DefaultHello()).ok());
  {
    Session c(*haptics);
    const auto st = c.Open(Session::DefaultHello());
    EXPECT_EQ(st.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << st.error_message();
  }
  a->CloseWrites();
  EXPECT_TRUE(a->Finish().ok());
  a.reset();
  ASSERT_TRUE(WaitUntil([&] { return h.server().counts().sessions <= 1; }));
  Session d(*haptics);
  EXPECT_TRUE(d.Open(Session::DefaultHello()).ok());
}

TEST_P(HapticServiceTest, DeletingTheSceneEndsItsSessions) {
  ServerHarness h(GetParam());
  auto scenes = h.Scenes();
  ASSERT_TRUE(CreateScene(*scenes, "temp").ok());
  auto haptics = h.Haptics();
  Session s(*haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello("temp")).ok());
  ASSERT_TRUE(s.Send(1, MakePose(0, 0, 0)));
  ASSERT_TRUE(s.Next());
  ASSERT_TRUE(DeleteScene(*scenes, "temp").ok());
  while (s.Next()) {
  }
  const auto st = s.Finish();
  EXPECT_EQ(st.error_code(), grpc::StatusCode::NOT_FOUND) << st.error_message();
}

TEST_P(HapticServiceTest, PatchesArriveInOrderAmongTheUpdatesAndHoldTheRegion) {
  FloorHarness h(GetParam(), "sphere:0.05,4");
  Session s(*h.haptics);
  v1::Hello hello = Session::DefaultHello();
  hello.mutable_patches()->set_enabled(true);
  ASSERT_TRUE(s.Open(hello).ok());
  PatchClient client;
  v1::CoupleResponse resp;
  auto take = [&] {
    if (resp.has_patch()) client.Apply(resp.patch());
  };
  // Sliding over the ball's top, 2 mm a pose: every few poses the probe
  // leaves a quarter of the margin behind and a patch is due.
  const int n = 30;
  for (int k = 0; k < n; ++k) {
    v1::CoupleRequest req;
    auto* pose = req.mutable_pose();
    pose->set_sequence(static_cast<std::uint64_t>(k + 1));
    *pose->mutable_pose() = MakePose(-0.03 + 0.002 * k, 0, 0.058);
    pose->set_client_time_ns(1'000'000'000LL + 10'000'000LL * k);
    pose->set_round_trip_us(k == 3 ? std::nan("") : 2000);  // a bad report is ignored
    ASSERT_TRUE(s.Write(req));
    for (;;) {
      ASSERT_TRUE(s.Read(&resp)) << "the stream ended before the answer to pose " << k + 1;
      take();
      if (resp.has_update() && resp.update().sequence() == static_cast<std::uint64_t>(k + 1)) break;
    }
  }
  s.CloseWrites();
  while (s.Read(&resp)) {
    EXPECT_FALSE(resp.has_update()) << "an update after the writes were closed";
    take();
  }
  const grpc::Status st = s.Finish();
  EXPECT_TRUE(st.ok()) << st.error_message();
  ASSERT_GE(client.sequence, 3u);
  ASSERT_TRUE(client.bodies.contains("floor"));
  const PatchClient::Body& b = client.bodies.at("floor");
  const pd::Mesh ball = pd::shapes::MakeShape("sphere:0.05,4");
  ExpectVerticesOf(ball, b);
  // The last patch's cover, about one of the last poses (a pose answered
  // while the previous patch is still being written cuts none), is held.
  const Vec3 c(b.last.cover_center().x(), b.last.cover_center().y(), b.last.cover_center().z());
  EXPECT_LT((c - Vec3(-0.03 + 0.002 * (n - 1), 0, 0.058)).norm(), 0.01);
  const std::set<std::uint32_t> held = client.Held("floor");
  const std::set<std::uint32_t> covered = TrianglesWithin(ball, c, b.last.cover_radius());
  EXPECT_FALSE(covered.empty());
  for (std::uint32_t f : covered) EXPECT_TRUE(held.contains(f)) << "triangle " << f;
  EXPECT_TRUE(WaitUntil([&] { return h.server().counts().patches_sent >= client.sequence; }));
  EXPECT_GT(h.server().counts().patch_bytes, 0u);
}

INSTANTIATE_TEST_SUITE_P(Transports, HapticServiceTest,
                         ::testing::Values(Transport::kInProcess, Transport::kTcp), TransportName);

}  // namespace
}  // namespace hapticpd::testing
