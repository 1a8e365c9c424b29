// Local geometry patches (server/patch_builder.h) through a device session's
// worker, without a network: what the client holds after each patch is
// compared with brute force over the body's triangles; the per-body limit,
// drops, new geometry under an old id, the hello's request and its
// validation; and moving bodies (PoseAt) as the PD and the patches see them.
#include <gtest/gtest.h>

#include <cmath>
#include <optional>

#include "pd/shapes.h"
#include "server/patch_builder.h"
#include "server/session_worker.h"
#include "tests/server/patch_client.h"
#include "tests/server/server_harness.h"

namespace hapticpd::testing::patches {
namespace {

using server::internal::MailPose;
using server::internal::PatchBuilder;
using server::internal::SessionWorker;

constexpr std::int64_t kT0 = 1'000'000'000'000;  // a server clock time for the tests (ns)

/// A scene "s" holding a finely tessellated ball "ball" (radius 5 cm),
/// turned and shifted so that its mesh frame is not W's.
struct BallScene {
  server::ChangeSignal signal;
  server::ScenePtr scene = std::make_shared<server::Scene>("s", "", &signal);
  pd::ModelPtr ball = pd::MakeModel(pd::shapes::Sphere(0.05, 4));
  Pose X_WB{Eigen::AngleAxisd(0.3, Vec3::UnitX()).toRotationMatrix(), Vec3(0.1, 0, 0)};

  BallScene() { Add("ball", ball, X_WB, 1); }
  void Add(const std::string& id, const pd::ModelPtr& model, const Pose& X, std::uint64_t uid) {
    server::BodyState b;
    b.uid = uid;
    b.id = id;
    b.model = model;
    b.X_WB = X;
    EXPECT_TRUE(scene->AddBody(std::move(b), 8, nullptr, "id").ok());
  }
  /// The probe's centre `height` above the ball's surface (W +z).
  Vec3 Above(double height) const { return X_WB.t + Vec3(0, 0, 0.05 + height); }
};

v1::Hello PatchHello(std::uint32_t max_triangles = 0, double min_margin = 0) {
  v1::Hello h = Session::DefaultHello("s", v1::PD_MODE_PDT, "sphere:0.01,2");
  h.mutable_patches()->set_enabled(true);
  h.mutable_patches()->set_max_triangles_per_body(max_triangles);
  h.mutable_patches()->set_min_margin(min_margin);
  return h;
}

/// A pose of the probe (its centre of mass at p_W), one second after the
/// previous one (so the speed estimate stays near zero for small moves).
MailPose Pose1(const Vec3& p_W, std::uint64_t seq) {
  MailPose p;
  p.sequence = seq;
  p.X_WA = Pose::FromTranslation(p_W);
  p.rx_ns = kT0 + static_cast<std::int64_t>(seq) * 1'000'000'000;
  p.client_time_ns = p.rx_ns;
  return p;
}

/// Answers `p` and returns its patch (asserting that one was cut, or not).
std::optional<v1::GeometryPatch> AnswerAndPatch(SessionWorker& w, const MailPose& p) {
  v1::ContactUpdate u;
  w.Answer(p, 0, &u);
  v1::GeometryPatch patch;
  if (!w.Patch(p, &patch)) return std::nullopt;
  return patch;
}

Vec3 V(const v1::Vec3& v) { return Vec3(v.x(), v.y(), v.z()); }

/// Starts `w` with `hello` on `scene`; these tests do not read the welcome.
grpc::Status StartWorker(SessionWorker& w, const v1::Hello& hello, const server::ScenePtr& scene) {
  v1::Welcome welcome;
  return w.Start(hello, scene, &welcome);
}

TEST(GeometryPatch, FirstPatchHoldsExactlyTheTrianglesWithinTheRegion) {
  BallScene s;
  SessionWorker w(server::Limits{}, "s1");
  ASSERT_TRUE(StartWorker(w, PatchHello(), s.scene).ok());
  // The probe's reach: its bounding box's farthest corner from the centre
  // of mass (the client tests those corners), sqrt(3) radii for a sphere.
  const double r = w.patch_builder()->probe_reach();
  EXPECT_NEAR(r, std::sqrt(3.0) * w.probe()->radius_about_com(), 1e-3);
  const Vec3 c_W = s.Above(0.004);
  const auto patch = AnswerAndPatch(w, Pose1(c_W, 1));
  ASSERT_TRUE(patch);
  EXPECT_EQ(patch->sequence(), 1u);
  EXPECT_EQ(patch->scene_revision(), s.scene->snapshot()->revision);
  EXPECT_EQ(patch->server_time_ns(), kT0 + 1'000'000'000);
  // The region: the probe's reach plus the default margin (5 mm for a
  // probe of 1 cm radius at rest).
  EXPECT_LT((V(patch->center()) - c_W).norm(), 1e-12);
  EXPECT_NEAR(patch->radius(), r + 0.005, 1e-12);
  ASSERT_EQ(patch->bodies_size(), 1);
  const v1::BodyPatch& bp = patch->bodies(0);
  EXPECT_EQ(bp.body_id(), "ball");
  EXPECT_EQ(bp.body_key(), 1u);
  EXPECT_FALSE(bp.truncated());
  EXPECT_EQ(bp.cover_radius(), patch->radius());
  EXPECT_LT((V(bp.cover_center()) - s.X_WB.Inverse() * c_W).norm(), 1e-12);
  EXPECT_EQ(bp.material().stiffness(), pd::Material{}.stiffness);
  PatchClient client;
  client.Apply(*patch);
  const std::set<std::uint32_t> want =
      TrianglesWithin(s.ball->mesh(), V(bp.cover_center()), bp.cover_radius());
  EXPECT_GT(want.size(), 20u);
  EXPECT_EQ(client.Held("ball"), want);
  ExpectVerticesOf(s.ball->mesh(), client.bodies["ball"]);
}

TEST(GeometryPatch, ProbeMovesAQuarterMarginBeforeTheNextPatchWhichSendsOnlyNewTriangles) {
  BallScene s;
  SessionWorker w(server::Limits{}, "s1");
  ASSERT_TRUE(StartWorker(w, PatchHello(), s.scene).ok());
  PatchClient client;
  const auto first = AnswerAndPatch(w, Pose1(s.Above(0.004), 1));
  ASSERT_TRUE(first);
  client.Apply(*first);
  const std::set<std::uint32_t> before = client.Held("ball");
  // Within a quarter of the 5 mm margin: nothing to send.
  EXPECT_FALSE(AnswerAndPatch(w, Pose1(s.Above(0.004) + Vec3(0.001, 0, 0), 2)));
  // 6 mm sideways: a delta (the client checks that nothing it holds is
  // sent again).
  const Vec3 c2 = s.Above(0.004) + Vec3(0.006, 0, 0);
  const auto second = AnswerAndPatch(w, Pose1(c2, 3));
  ASSERT_TRUE(second);
  ASSERT_EQ(second->bodies_size(), 1);
  const v1::BodyPatch& bp = second->bodies(0);
  EXPECT_GT(bp.triangle_indices_size(), 0);
  EXPECT_LT(static_cast<std::size_t>(bp.triangle_indices_size()), before.size());
  client.Apply(*second);
  const Vec3 c_B = s.X_WB.Inverse() * c2;
  EXPECT_LT((V(bp.cover_center()) - c_B).norm(), 1e-12);
  const std::set<std::uint32_t> held = client.Held("ball");
  const std::set<std::uint32_t> within = TrianglesWithin(s.ball->mesh(), c_B, bp.cover_radius());
  const std::set<std::uint32_t> hysteresis =
      TrianglesWithin(s.ball->mesh(), c_B, PatchBuilder::kHysteresis * bp.cover_radius());
  // Held: everything within the region, plus what was held before and is
  // still within the hysteresis radius; nothing else.
  std::set<std::uint32_t> expected = within;
  for (std::uint32_t f : before) {
    if (hysteresis.contains(f)) expected.insert(f);
  }
  EXPECT_EQ(held, expected);
  EXPECT_GT(expected.size(), within.size());  // the hysteresis kept some
  // Far away along the ball: the old triangles go.
  const Vec3 c3 = s.X_WB.t + Vec3(0, 0.05 + 0.004, 0);
  const auto third = AnswerAndPatch(w, Pose1(c3, 4));
  ASSERT_TRUE(third);
  ASSERT_EQ(third->bodies_size(), 1);
  EXPECT_GT(third->bodies(0).dropped_triangles_size(), 0);
  client.Apply(*third);
  const Vec3 c3_B = s.X_WB.Inverse() * c3;
  EXPECT_EQ(client.Held("ball"), TrianglesWithin(s.ball->mesh(), c3_B, third->radius()));
  ExpectVerticesOf(s.ball->mesh(), client.bodies["ball"]);
}

TEST(GeometryPatch, PerBodyLimitKeepsTheNearestAndShrinksTheCover) {
  BallScene s;
  server::Limits limits;
  limits.max_patch_triangles = 40;
  for (const std::uint32_t asked : {0u, 25u, 1000u}) {
    SCOPED_TRACE("max_triangles_per_body " + std::to_string(asked));
    const std::size_t limit = asked == 0 ? 40 : std::min<std::size_t>(asked, 40);
    SessionWorker w(limits, "s1");
    ASSERT_TRUE(StartWorker(w, PatchHello(asked), s.scene).ok());
    ASSERT_EQ(w.patch_builder()->limit(), limit);
    PatchClient client;
    // Touching the ball, then sliding over it: every patch keeps the limit.
    for (std::uint64_t k = 1; k <= 4; ++k) {
      const Vec3 c = s.Above(0.0) + Vec3(0.004 * static_cast<double>(k), 0, 0);
      const auto patch = AnswerAndPatch(w, Pose1(c, k));
      ASSERT_TRUE(patch);
      client.Apply(*patch);
      ASSERT_EQ(patch->bodies_size(), 1);
      const v1::BodyPatch& bp = patch->bodies(0);
      const std::set<std::uint32_t> held = client.Held("ball");
      EXPECT_LE(held.size(), limit);
      EXPECT_TRUE(bp.truncated());
      EXPECT_LT(bp.cover_radius(), patch->radius());
      // Everything within the cover is held, and the cover is as large as
      // the limit allows: the nearest triangle left out is just beyond it.
      const std::set<std::uint32_t> covered =
          TrianglesWithin(s.ball->mesh(), V(bp.cover_center()), bp.cover_radius());
      for (std::uint32_t f : covered) EXPECT_TRUE(held.contains(f)) << "triangle " << f;
      EXPECT_GT(TrianglesWithin(s.ball->mesh(), V(bp.cover_center()),
                                std::nextafter(bp.cover_radius(), 1.0))
                    .size(),
                covered.size());
    }
  }
}

TEST(GeometryPatch, RemovedBodyIsDroppedAndNewGeometryUnderItsIdStartsOver) {
  BallScene s;
  SessionWorker w(server::Limits{}, "s1");
  ASSERT_TRUE(StartWorker(w, PatchHello(), s.scene).ok());
  PatchClient client;
  const Vec3 c = s.Above(0.004);
  auto patch = AnswerAndPatch(w, Pose1(c, 1));
  ASSERT_TRUE(patch);
  client.Apply(*patch);
  ASSERT_FALSE(client.Held("ball").empty());
  // Removed: dropped.
  ASSERT_TRUE(s.scene->RemoveBody("ball", nullptr).ok());
  patch = AnswerAndPatch(w, Pose1(c, 2));
  ASSERT_TRUE(patch);
  EXPECT_EQ(patch->bodies_size(), 0);
  ASSERT_EQ(patch->dropped_bodies_size(), 1);
  EXPECT_EQ(patch->dropped_bodies(0), "ball");
  client.Apply(*patch);
  EXPECT_TRUE(client.bodies.empty());

  // Back, then replaced by a box under the same id: a new key, and every
  // covered triangle of the box is sent (the client starts from nothing).
  s.Add("ball", s.ball, s.X_WB, 2);
  patch = AnswerAndPatch(w, Pose1(c, 3));
  ASSERT_TRUE(patch);
  client.Apply(*patch);
  EXPECT_EQ(client.bodies["ball"].key, 2u);
  ASSERT_TRUE(s.scene->RemoveBody("ball", nullptr).ok());
  const pd::ModelPtr box = pd::MakeModel(pd::shapes::Box(Vec3::Constant(0.05), 8));
  s.Add("ball", box, s.X_WB, 3);
  patch = AnswerAndPatch(w, Pose1(c, 4));
  ASSERT_TRUE(patch);
  EXPECT_EQ(patch->dropped_bodies_size(), 0);
  ASSERT_EQ(patch->bodies_size(), 1);
  const v1::BodyPatch& bp = patch->bodies(0);
  EXPECT_EQ(bp.body_key(), 3u);
  EXPECT_EQ(bp.dropped_triangles_size(), 0);
  const std::set<std::uint32_t> want =
      TrianglesWithin(box->mesh(), V(bp.cover_center()), bp.cover_radius());
  ASSERT_FALSE(want.empty());
  EXPECT_EQ(static_cast<std::size_t>(bp.triangle_indices_size()), want.size());
  client.Apply(*patch);
  EXPECT_EQ(client.Held("ball"), want);
  ExpectVerticesOf(box->mesh(), client.bodies["ball"]);
}

TEST(GeometryPatch, HelloWithoutPatchesNeverGetsOne) {
  BallScene s;
  v1::Hello plain = PatchHello();
  plain.clear_patches();
  v1::Hello disabled = PatchHello();
  disabled.mutable_patches()->set_enabled(false);
  for (const v1::Hello& h : {plain, disabled}) {
    SessionWorker w(server::Limits{}, "s1");
    ASSERT_TRUE(StartWorker(w, h, s.scene).ok());
    EXPECT_FALSE(w.patches_enabled());
    for (std::uint64_t k = 1; k <= 3; ++k) {
      EXPECT_FALSE(AnswerAndPatch(w, Pose1(s.Above(0.01 * static_cast<double>(k)), k)));
    }
  }
}

TEST(GeometryPatch, BadPatchRequestIsRejectedNamingTheField) {
  BallScene s;
  for (const double m : {-0.001, std::nan(""), HUGE_VAL, 1.5}) {
    SessionWorker w(server::Limits{}, "s1");
    const grpc::Status st = StartWorker(w, PatchHello(0, m), s.scene);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << m;
    EXPECT_EQ(st.error_message().rfind("hello.patches.min_margin: ", 0), 0u) << st.error_message();
  }
  // In range: accepted, and the margin never below it.
  SessionWorker w(server::Limits{}, "s1");
  ASSERT_TRUE(StartWorker(w, PatchHello(0, 0.02), s.scene).ok());
  EXPECT_EQ(w.patch_builder()->min_margin(), 0.02);
  const auto patch = AnswerAndPatch(w, Pose1(s.Above(0.004), 1));
  ASSERT_TRUE(patch);
  EXPECT_NEAR(patch->radius(), w.patch_builder()->probe_reach() + 0.02, 1e-12);
}

TEST(GeometryPatch, MarginFollowsSpeedAndRoundTripWithinItsBounds) {
  const pd::ModelPtr probe = pd::MakeModel(pd::shapes::Sphere(0.01, 2));
  PatchBuilder b(probe, 100, 0);
  const double r = probe->radius_about_com();
  EXPECT_EQ(b.Margin(0.0), 0.005);
  // 0.5 m/s for a while (1 ms samples): the margin is twice the distance
  // covered over the round trip plus the patch latency.
  for (int k = 0; k <= 400; ++k) {
    b.Observe(Pose::FromTranslation(Vec3(0.0005 * k, 0, 0)), 1'000'000LL * k, 0);
  }
  EXPECT_NEAR(b.speed(), 0.5, 1e-3);
  EXPECT_NEAR(b.Margin(0.01), 2 * 0.5 * (0.01 + PatchBuilder::kPatchLatencyS), 1e-4);
  // A long round trip hits the cap of a few probe radii.
  EXPECT_EQ(b.Margin(server::internal::kMaxRoundTripUs * 1e-6),
            PatchBuilder::kMaxMarginOverRadius * r);
  // A hostile timestamp (a metre in a nanosecond) is cut to the top speed.
  b.Observe(Pose::FromTranslation(Vec3(1, 0, 0)), 1'000'000LL * 400 + 1, 0);
  EXPECT_LE(b.speed(), PatchBuilder::kMaxSpeed);
  // Round trips as the reactor takes them.
  using server::internal::SanitizeRoundTripUs;
  EXPECT_EQ(SanitizeRoundTripUs(2500), 2500);
  EXPECT_EQ(SanitizeRoundTripUs(-1), 0);
  EXPECT_EQ(SanitizeRoundTripUs(std::nan("")), 0);
  EXPECT_EQ(SanitizeRoundTripUs(1e12), server::internal::kMaxRoundTripUs);
}

TEST(MovingBody, PoseAtCarriesAndTurnsTheBody) {
  server::BodyState b;
  b.X_WB = Pose{Eigen::AngleAxisd(0.2, Vec3::UnitX()).toRotationMatrix(), Vec3(1, 2, 3)};
  b.pose_time_ns = kT0;
  EXPECT_FALSE(server::Moving(b));
  EXPECT_EQ(server::PoseAt(b, kT0 + 5'000'000'000).t, b.X_WB.t);
  b.v_W = Vec3(0.1, 0, -0.2);
  b.w_W = Vec3(0, 0, M_PI / 2);  // a quarter turn a second about W's z
  ASSERT_TRUE(server::Moving(b));
  const Pose X = server::PoseAt(b, kT0 + 1'000'000'000);
  EXPECT_LT((X.t - Vec3(1.1, 2, 2.8)).norm(), 1e-12);
  const Mat3 R = Eigen::AngleAxisd(M_PI / 2, Vec3::UnitZ()).toRotationMatrix() * b.X_WB.R;
  EXPECT_LT((X.R - R).norm(), 1e-12);
  const Pose back = server::PoseAt(b, kT0 - 1'000'000'000);  // before pose_time: extrapolated
  EXPECT_LT((back.t - Vec3(0.9, 2, 3.2)).norm(), 1e-12);
}

/// A box moving up at 10 cm/s towards a probe resting at the origin.
struct RisingBox {
  server::ChangeSignal signal;
  server::ScenePtr scene = std::make_shared<server::Scene>("s", "", &signal);
  pd::ModelPtr box = pd::MakeModel(pd::shapes::Box(Vec3::Constant(0.05)));
  RisingBox() {
    server::BodyState b;
    b.uid = 1;
    b.id = "box";
    b.model = box;
    b.movable = true;
    b.X_WB = Pose::FromTranslation(Vec3(0, 0, -0.2));  // top face at z = -0.15
    b.v_W = Vec3(0, 0, 0.1);
    b.pose_time_ns = kT0;
    EXPECT_TRUE(scene->AddBody(std::move(b), 8, nullptr, "id").ok());
  }
};

TEST(MovingBody, PdSeesTheBodyWhereItIsWhenThePoseArrives) {
  RisingBox s;
  ASSERT_EQ(s.scene->snapshot()->bodies[0].pose_time_ns, kT0);  // kept when given
  SessionWorker w(server::Limits{}, "s1");
  ASSERT_TRUE(StartWorker(w, PatchHello(), s.scene).ok());
  MailPose p;
  p.sequence = 1;
  p.X_WA = Pose::Identity();  // the probe sphere (1 cm) at rest at the origin
  p.rx_ns = kT0;
  v1::ContactUpdate u;
  w.Answer(p, 0, &u);
  EXPECT_EQ(u.status(), v1::CONTACT_STATUS_SEPARATED);
  // 1.55 s later the top face is at z = +0.005: 1.5 cm into the probe.
  p.sequence = 2;
  p.rx_ns = kT0 + 1'550'000'000;
  w.Answer(p, 0, &u);
  ASSERT_EQ(u.status(), v1::CONTACT_STATUS_PENETRATING);
  EXPECT_GT(u.depth(), 0.012);
  EXPECT_LT(u.depth(), 0.0151);
  EXPECT_GT(u.force().z(), 0.0);  // the body pushes the probe up
  // Same pose, earlier again: separated (the pose is a function of time,
  // not of the last answer).
  p.sequence = 3;
  p.rx_ns = kT0 + 1'000'000'000;
  w.Answer(p, 0, &u);
  EXPECT_EQ(u.status(), v1::CONTACT_STATUS_SEPARATED);
}

TEST(MovingBody, PatchCarriesTheMotionAndIsResentWhileTheBodyMoves) {
  RisingBox s;
  SessionWorker w(server::Limits{}, "s1");
  ASSERT_TRUE(StartWorker(w, PatchHello(), s.scene).ok());
  MailPose p;
  p.sequence = 1;
  p.X_WA = Pose::Identity();
  p.rx_ns = kT0 + 1'500'000'000;  // the top face at z = 0
  v1::GeometryPatch patch;
  ASSERT_TRUE(w.Patch(p, &patch));
  ASSERT_EQ(patch.bodies_size(), 1);
  const v1::BodyPatch& bp = patch.bodies(0);
  EXPECT_EQ(V(bp.pose().position()), Vec3(0, 0, -0.2));
  EXPECT_EQ(V(bp.velocity().linear()), Vec3(0, 0, 0.1));
  EXPECT_EQ(V(bp.velocity().angular()), Vec3::Zero());
  EXPECT_EQ(bp.pose_time_ns(), kT0);
  // The cover is centred where the probe is relative to the body then, and
  // widened by the body's motion until the next patch.
  EXPECT_LT((V(bp.cover_center()) - Vec3(0, 0, 0.05)).norm(), 1e-12);
  EXPECT_GT(bp.cover_radius(), patch.radius());
  PatchClient client;
  client.Apply(patch);
  EXPECT_EQ(client.Held("box"),
            TrianglesWithin(s.box->mesh(), V(bp.cover_center()), bp.cover_radius()));
  // The probe rests; the body's motion alone re-sends it every 50 ms.
  p.rx_ns += 10'000'000;
  EXPECT_FALSE(w.Patch(p, &patch));
  p.rx_ns += PatchBuilder::kMovingResendNs;
  ASSERT_TRUE(w.Patch(p, &patch));
  EXPECT_EQ(patch.sequence(), 2u);
  client.Apply(patch);
}

}  // namespace
}  // namespace hapticpd::testing::patches
