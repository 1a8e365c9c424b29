// The device side's local contact model (device/local_model.h): the patch
// store's bookkeeping and its refusals, PD on a patch against PD on the whole
// body (checked with FCL), and the rule that picks which model answers.
// Runs in every preset (device_tests; no real time, no network).
#include "device/local_model.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <thread>

#include "pd/primitives.h"
#include "pd/shapes.h"
#include "tests/oracles/fcl_oracle.h"

namespace hapticpd::device {
namespace {

/// A patch of `model` at X_WB holding every triangle within `radius` of the
/// world point `c_W` (the server's rule, by brute force).
PatchBodyDelta CutBody(const std::string& id, const pd::GeometryModel& model, const Pose& X_WB,
                       const Vec3& c_W, double radius, std::uint64_t key = 7) {
  PatchBodyDelta b;
  b.id = id;
  b.key = key;
  const pd::Mesh& m = model.mesh();
  b.triangle_count = static_cast<std::uint32_t>(m.num_triangles());
  b.vertex_count = static_cast<std::uint32_t>(m.num_vertices());
  b.X_WB = X_WB;
  b.material.stiffness = 1000;
  const Vec3 c_B = X_WB.R.transpose() * (c_W - X_WB.t);
  b.cover_center_B = c_B;
  b.cover_radius = radius;
  std::vector<bool> sent(m.num_vertices(), false);
  for (std::size_t f = 0; f < m.num_triangles(); ++f) {
    const auto& t = m.triangles()[f];
    Vec3 bary;
    const Vec3 q = pd::internal::ClosestPointOnTriangle(c_B, m.vertices()[t[0]], m.vertices()[t[1]],
                                                        m.vertices()[t[2]], &bary);
    if ((q - c_B).norm() > radius) continue;
    b.triangle_indices.push_back(static_cast<std::uint32_t>(f));
    b.triangles.push_back({static_cast<std::uint32_t>(t[0]), static_cast<std::uint32_t>(t[1]),
                           static_cast<std::uint32_t>(t[2])});
    for (int k = 0; k < 3; ++k) {
      if (sent[t[k]]) continue;
      sent[t[k]] = true;
      b.vertex_indices.push_back(static_cast<std::uint32_t>(t[k]));
      b.vertices.push_back(m.vertices()[t[k]]);
    }
  }
  return b;
}

struct Scene {
  pd::ModelPtr probe = pd::MakeModel(pd::shapes::Stick());
  pd::ModelPtr box = pd::MakeModel(pd::shapes::Box(Vec3(0.1, 0.1, 0.05), 12));
  Pose X_WB;  // identity: top face at z = 0.05
  /// The stick upright, its lowest point `depth` below the box's top, at x.
  Pose ProbeAt(double depth, double x = 0.01) const {
    const double lo = probe->mesh().bounds().lo.z();
    return Pose::FromTranslation(Vec3(x, 0.0, 0.05 - depth - lo));
  }
  Pose X_PA() const { return Pose::FromTranslation(-probe->mass().p_MC); }
  Vec3 Com(const Pose& X_WA) const { return X_WA * probe->mass().p_MC; }
  double Reach() const { return probe->radius_about_com(); }
  PatchDelta Patch(const Pose& X_WA, double margin, std::uint64_t seq = 1) const {
    PatchDelta d;
    d.sequence = seq;
    d.center_W = Com(X_WA);
    d.radius = Reach() + margin;
    d.bodies.push_back(CutBody("box", *box, X_WB, d.center_W, d.radius));
    return d;
  }
  ProxySample Sample(const Pose& X_WA, std::uint64_t seq, std::int64_t t_ns) const {
    ProxySample s;
    s.sequence = seq;
    s.time_ns = t_ns;
    s.X_WP = X_WA * X_PA().Inverse();
    return s;
  }
  /// A server answer for the probe at X_WA: one upward row, arrived at t.
  IntermediateRep ServerAnswer(const Pose& X_WA, double depth, double stiffness,
                               std::int64_t t_ns) const {
    IntermediateRep ir;
    ir.receive_time_ns = t_ns;
    ir.num_rows = 1;
    ir.rows[0].n_W = Vec3::UnitZ();
    ir.rows[0].depth = depth;
    ir.rows[0].stiffness = stiffness;
    ir.X_WP_ref = Sample(X_WA, 1, t_ns).X_WP;
    return ir;
  }
};

/// Offers the sample and steps the model at t: false when it published nothing.
bool OfferAndStep(LocalContactModel* lm, const ProxySample& sample, std::int64_t t,
                  IrMailbox* out) {
  lm->OfferSample(sample);
  return lm->Step(t, out);
}

/// OfferAndStep, then takes what the model published.
bool StepFetch(LocalContactModel* lm, const ProxySample& sample, std::int64_t t, IrMailbox* out) {
  return OfferAndStep(lm, sample, t, out) && out->Fetch();
}

TEST(PatchStore, HoldsWhatWasSentAndCoversTheProbe) {
  Scene sc;
  const Pose X_WA = sc.ProbeAt(0.003);
  PatchStore store;
  const PatchDelta d = sc.Patch(X_WA, 0.01);
  ASSERT_EQ(store.Apply(d), "");
  EXPECT_EQ(store.triangles_held(), d.bodies[0].triangle_indices.size());
  EXPECT_GT(store.triangles_held(), 0u);
  EXPECT_LT(store.triangles_held(), sc.box->mesh().num_triangles());
  // The probe's bounding-box corners: inside; 2 cm along the stick (the
  // direction that moves its farthest corners most), outside the 1 cm margin.
  const pd::Aabb& box = sc.probe->mesh().bounds();
  auto corners = [&](const Pose& X) {
    std::vector<Vec3> c;
    for (int i = 0; i < 8; ++i) {
      c.push_back(X * Vec3(i & 1 ? box.hi.x() : box.lo.x(), i & 2 ? box.hi.y() : box.lo.y(),
                           i & 4 ? box.hi.z() : box.lo.z()));
    }
    return c;
  };
  EXPECT_TRUE(store.Covers(corners(X_WA), 0));
  EXPECT_FALSE(store.Covers(corners(Pose::FromTranslation(Vec3(0, 0, 0.02)) * X_WA), 0));
  // Dropping triangles forgets them, and the vertices only they used.
  PatchDelta drop;
  drop.sequence = 2;
  drop.center_W = d.center_W;
  drop.radius = d.radius;
  PatchBodyDelta b = d.bodies[0];
  b.vertex_indices.clear();
  b.vertices.clear();
  b.triangle_indices.clear();
  b.triangles.clear();
  b.dropped_triangles = {d.bodies[0].triangle_indices[0], d.bodies[0].triangle_indices[1]};
  drop.bodies.push_back(b);
  ASSERT_EQ(store.Apply(drop), "");
  EXPECT_EQ(store.triangles_held(), d.bodies[0].triangle_indices.size() - 2);
  // A dropped body is gone.
  PatchDelta gone;
  gone.sequence = 3;
  gone.center_W = d.center_W;
  gone.radius = d.radius;
  gone.dropped_bodies = {"box"};
  ASSERT_EQ(store.Apply(gone), "");
  EXPECT_EQ(store.triangles_held(), 0u);
  EXPECT_EQ(store.bodies_held(), 0u);
}

TEST(PatchStore, RefusesMalformedPatchesWholeAndNamesTheProblem) {
  Scene sc;
  const Pose X_WA = sc.ProbeAt(0.003);
  const PatchDelta good = sc.Patch(X_WA, 0.01);
  struct Case {
    const char* what;
    std::function<void(PatchDelta*)> spoil;
    const char* expect;
  };
  const std::vector<Case> cases = {
      {"triangle index", [](PatchDelta* d) { d->bodies[0].triangle_indices[0] = 1u << 30; },
       "triangle index"},
      {"vertex index", [](PatchDelta* d) { d->bodies[0].vertex_indices[0] = 1u << 30; },
       "vertex index"},
      {"triangle vertex", [](PatchDelta* d) { d->bodies[0].triangles[0][1] = 1u << 30; },
       "out of range"},
      {"vertex not held",
       [](PatchDelta* d) {
         d->bodies[0].vertex_indices.pop_back();
         d->bodies[0].vertices.pop_back();
       },
       "not held"},
      {"non-finite vertex", [](PatchDelta* d) { d->bodies[0].vertices[0].x() = std::nan(""); },
       "not finite"},
      {"huge vertex", [](PatchDelta* d) { d->bodies[0].vertices[0].x() = 1e200; }, "not finite"},
      {"non-finite pose", [](PatchDelta* d) { d->bodies[0].X_WB.t.z() = INFINITY; }, "pose"},
      {"non-finite region", [](PatchDelta* d) { d->radius = std::nan(""); }, "region"},
      {"material", [](PatchDelta* d) { d->bodies[0].material.stiffness = -1; }, "material"},
      {"lengths", [](PatchDelta* d) { d->bodies[0].vertices.pop_back(); }, "lengths"},
  };
  for (const Case& c : cases) {
    PatchStore store;
    PatchDelta d = good;
    c.spoil(&d);
    const std::string problem = store.Apply(d);
    EXPECT_NE(problem.find(c.expect), std::string::npos) << c.what << ": " << problem;
    EXPECT_TRUE(store.empty()) << c.what;
    EXPECT_EQ(store.triangles_held(), 0u) << c.what;
  }
  // Over the size limit.
  PatchLimits small;
  small.max_triangles_per_body = good.bodies[0].triangle_indices.size() - 1;
  PatchStore limited(small);
  EXPECT_NE(limited.Apply(good).find("over the limit"), std::string::npos);
  EXPECT_EQ(limited.triangles_held(), 0u);
  // Not newer than the last applied: refused, and what is held stays.
  PatchStore store;
  ASSERT_EQ(store.Apply(good), "");
  const std::size_t held = store.triangles_held();
  PatchDelta again = good;
  again.bodies[0].dropped_triangles = again.bodies[0].triangle_indices;
  EXPECT_NE(store.Apply(again).find("not newer"), std::string::npos);
  EXPECT_EQ(store.triangles_held(), held);
}

TEST(PatchStore, MovingBodyIsWhereItsVelocitySaysOnTheServersClock) {
  PatchBodyDelta b;
  b.X_WB = Pose::FromTranslation(Vec3(1, 0, 0));
  b.v_W = Vec3(0, 0.1, 0);
  b.w_W = Vec3(0, 0, 0.5);
  b.pose_time_ns = 1'000'000'000;
  const Pose X = PatchBodyPoseAt(b, 3'000'000'000);  // 2 s later
  EXPECT_NEAR(X.t.y(), 0.2, 1e-12);
  EXPECT_NEAR(X.t.x(), 1.0, 1e-12);
  const Mat3 R = Eigen::AngleAxisd(1.0, Vec3::UnitZ()).toRotationMatrix();
  EXPECT_LT((X.R - R).norm(), 1e-12);
}

/// PD on a patch holding every triangle the full query touches gives the
/// full body's answer (same depth within the contact tolerance, same
/// regions), and it is a real contact by FCL.
TEST(LocalModel, PatchAnswerMatchesTheWholeBodyAndIsARealContact) {
  Scene sc;
  const hapticpd::testing::FclModel fcl_probe(sc.probe->mesh());
  for (double depth : {0.001, 0.003, 0.008}) {
    for (double x : {0.0, 0.02, -0.04}) {
      const Pose X_WA = sc.ProbeAt(depth, x);
      PatchStore store;
      ASSERT_EQ(store.Apply(sc.Patch(X_WA, 0.01)), "");
      std::vector<pd::SceneBody> patch;
      std::vector<std::uint64_t> keys;
      store.Bodies(0, &patch, &keys);
      ASSERT_EQ(patch.size(), 1u);
      const std::vector<pd::SceneBody> whole = {{sc.box, sc.X_WB, patch[0].material}};
      pd::PenetrationRequest req;
      pd::ScenePdData d1, d2;
      pd::ScenePdResult r_whole, r_patch;
      pd::ComputeScenePdt(*sc.probe, X_WA, whole, req, &d1, &r_whole);
      pd::ComputeScenePdt(*sc.probe, X_WA, patch, req, &d2, &r_patch);
      ASSERT_TRUE(r_whole.colliding);
      ASSERT_TRUE(r_patch.colliding) << "depth " << depth << " x " << x;
      const pd::PenetrationResult& a = r_whole.bodies[0];
      const pd::PenetrationResult& b = r_patch.bodies[0];
      // The contact tolerance: contact_epsilon of the smaller size (the probe's).
      const double tol = req.contact_epsilon * sc.probe->mesh().bounds().Size().norm();
      EXPECT_NEAR(b.depth, a.depth, tol) << "depth " << depth << " x " << x;
      EXPECT_LT((b.translation_W - a.translation_W).norm(), tol);
      ASSERT_EQ(b.regions.size(), a.regions.size());
      for (std::size_t i = 0; i < a.regions.size(); ++i) {
        EXPECT_GT(a.regions[i].n_W.dot(b.regions[i].n_W), 1 - 1e-9);
      }
      // FCL, on the whole body: the patch's answer separates the probe from
      // the body, not just from the patch.
      const hapticpd::testing::FclModel fcl_box(sc.box->mesh());
      const Vec3 u = b.translation_W / b.depth;
      const double step = 1e-6 * b.depth;
      EXPECT_FALSE(hapticpd::testing::FclCollide(
          fcl_probe, Pose{b.X_WA_result.R, b.X_WA_result.t + u * step}, fcl_box, sc.X_WB))
          << "an over-push: not free when pushed out";
      EXPECT_TRUE(hapticpd::testing::FclCollide(
          fcl_probe, Pose{b.X_WA_result.R, b.X_WA_result.t - u * step}, fcl_box, sc.X_WB))
          << "not a contact: free when pulled in";
    }
  }
}

TEST(LocalModel, AnswersLocallyWhereThePatchCoversAndFallsBackWhereItDoesNot) {
  Scene sc;
  LocalModelOptions o;
  LocalContactModel lm(sc.probe, sc.X_PA(), o);
  IrMailbox out;
  const Pose X_WA = sc.ProbeAt(0.003);
  std::int64_t t = 1'000'000'000;
  // No patch yet: a server answer is passed through, the sample is
  // uncovered.
  IntermediateRep server = sc.ServerAnswer(X_WA, 0.002, 500, t);
  lm.OfferServerIr(server);
  ASSERT_TRUE(StepFetch(&lm, sc.Sample(X_WA, 1, t), t, &out));
  EXPECT_EQ(out.front().source, kIrSourceServer);
  EXPECT_EQ(lm.stats().uncovered, 1u);
  // A patch: the local model answers at the sample's pose, from the box.
  lm.OfferPatch(sc.Patch(X_WA, 0.01), t);
  t += 1'000'000;
  ASSERT_TRUE(StepFetch(&lm, sc.Sample(X_WA, 2, t), t, &out));
  const IntermediateRep& ir = out.front();
  EXPECT_EQ(ir.source, kIrSourceLocal);
  ASSERT_GE(ir.num_rows, 1);
  EXPECT_NEAR(ir.rows[0].depth, 0.003, 1e-5);
  EXPECT_GT(ir.rows[0].n_W.z(), 0.999);
  EXPECT_EQ(ir.rows[0].stiffness, 1000);
  EXPECT_EQ(lm.stats().local_answers, 1u);
  // The probe outruns the patch (6 cm sideways, margin 1 cm): the server's
  // answer, never rows from geometry the patch does not hold.
  const Pose far = sc.ProbeAt(0.003, 0.06);
  t += 1'000'000;
  server.receive_time_ns = t;
  server.rows[0].depth = 0.0025;
  lm.OfferServerIr(server);
  ASSERT_TRUE(StepFetch(&lm, sc.Sample(far, 3, t), t, &out));
  EXPECT_EQ(out.front().source, kIrSourceServer);
  EXPECT_EQ(out.front().rows[0].depth, 0.0025);
  EXPECT_EQ(lm.stats().uncovered, 2u);
  // Back in the patch: local again.
  t += 1'000'000;
  ASSERT_TRUE(StepFetch(&lm, sc.Sample(X_WA, 4, t), t, &out));
  EXPECT_EQ(out.front().source, kIrSourceLocal);
}

// Under a patch the probe has outrun, a late server answer for a pose the
// probe has left (outside that answer's validity region) is held back: the
// last local IR stays, and the servo loop fades it as the probe leaves its
// validity. An answer valid where the probe is now is rendered.
TEST(LocalModel, ALateServerAnswerForAPoseTheProbeHasLeftIsHeldBack) {
  Scene sc;
  LocalContactModel lm(sc.probe, sc.X_PA(), LocalModelOptions{});
  IrMailbox out;
  const Pose X_WA = sc.ProbeAt(0.003);
  std::int64_t t = 1'000'000'000;
  lm.OfferPatch(sc.Patch(X_WA, 0.01), t);
  ASSERT_TRUE(StepFetch(&lm, sc.Sample(X_WA, 1, t), t, &out));
  ASSERT_EQ(out.front().source, kIrSourceLocal);
  // The probe is 6 cm away, out of the patch; the answer is for X_WA.
  const Pose far = sc.ProbeAt(0.003, 0.06);
  IntermediateRep late = sc.ServerAnswer(X_WA, 0.002, 500, t);
  late.validity_radius = 0.01;
  t += 1'000'000;
  late.receive_time_ns = t;
  lm.OfferServerIr(late);
  EXPECT_FALSE(OfferAndStep(&lm, sc.Sample(far, 2, t), t, &out));
  EXPECT_FALSE(out.Fetch());
  EXPECT_EQ(lm.stats().uncovered, 1u);
  // An answer for where the probe is now is rendered.
  IntermediateRep now = sc.ServerAnswer(far, 0.0025, 500, t);
  now.validity_radius = 0.01;
  t += 1'000'000;
  now.receive_time_ns = t;
  lm.OfferServerIr(now);
  ASSERT_TRUE(StepFetch(&lm, sc.Sample(far, 3, t), t, &out));
  EXPECT_EQ(out.front().source, kIrSourceServer);
  EXPECT_EQ(out.front().rows[0].depth, 0.0025);
}

TEST(LocalModel, ARemovedBodyIsNeverFeltAgain) {
  Scene sc;
  LocalContactModel lm(sc.probe, sc.X_PA(), LocalModelOptions{});
  IrMailbox out;
  const Pose X_WA = sc.ProbeAt(0.003);
  std::int64_t t = 1'000'000'000;
  lm.OfferPatch(sc.Patch(X_WA, 0.01), t);
  ASSERT_TRUE(StepFetch(&lm, sc.Sample(X_WA, 1, t), t, &out));
  ASSERT_GE(out.front().num_rows, 1);
  // The body is removed (a later scene revision): the next patch drops it.
  PatchDelta gone;
  gone.sequence = 2;
  gone.scene_revision = 2;
  gone.center_W = sc.Com(X_WA);
  gone.radius = sc.Reach() + 0.01;
  gone.dropped_bodies = {"box"};
  lm.OfferPatch(gone, t);
  for (int i = 2; i < 20; ++i) {
    t += 1'000'000;
    ASSERT_TRUE(StepFetch(&lm, sc.Sample(X_WA, static_cast<std::uint64_t>(i), t), t, &out));
    EXPECT_EQ(out.front().source, kIrSourceLocal);
    EXPECT_EQ(out.front().num_rows, 0) << "tick " << i;
  }
}

TEST(LocalModel, AMovingBodyIsFeltWhereItIsNow) {
  Scene sc;
  LocalContactModel lm(sc.probe, sc.X_PA(), LocalModelOptions{});
  IrMailbox out;
  // The probe rests 2 mm above the box; the box rises at 10 mm/s from
  // server time 0.
  const Pose X_WA = sc.ProbeAt(-0.002);
  PatchDelta d = sc.Patch(X_WA, 0.01);
  d.bodies[0].v_W = Vec3(0, 0, 0.01);
  d.bodies[0].cover_radius = 1.0;  // the whole box is sent
  d.bodies[0] = CutBody("box", *sc.box, sc.X_WB, d.center_W, 1.0);
  d.bodies[0].v_W = Vec3(0, 0, 0.01);
  d.radius = 1.0;
  lm.SetServerClockOffset(-1'000'000'000);       // loop clock 1 s = server clock 0
  std::int64_t t = 1'000'000'000 + 100'000'000;  // server 0.1 s: box 1 mm up, still free
  lm.OfferPatch(d, t);
  ASSERT_TRUE(StepFetch(&lm, sc.Sample(X_WA, 1, t), t, &out));
  EXPECT_EQ(out.front().num_rows, 0);
  t = 1'000'000'000 + 500'000'000;  // server 0.5 s: 5 mm up, 3 mm into the probe
  ASSERT_TRUE(StepFetch(&lm, sc.Sample(X_WA, 2, t), t, &out));
  ASSERT_GE(out.front().num_rows, 1);
  EXPECT_NEAR(out.front().rows[0].depth, 0.003, 1e-4);
}

TEST(LocalModel, ProbeDeeperThanThePatchCanTellGetsTheServersAnswer) {
  Scene sc;
  LocalContactModel lm(sc.probe, sc.X_PA(), LocalModelOptions{});
  IrMailbox out;
  // A big box holding the whole stick inside: no triangle of the patch
  // crosses the probe.
  const pd::ModelPtr big = pd::MakeModel(pd::shapes::Box(Vec3(0.5, 0.5, 0.5), 4));
  const Pose X_WA = Pose::FromTranslation(Vec3(0, 0, -0.1));
  PatchDelta d;
  d.sequence = 1;
  d.center_W = sc.Com(X_WA);
  d.radius = sc.Reach() + 0.01;
  d.bodies.push_back(CutBody("big", *big, Pose(), d.center_W, d.radius));
  ASSERT_TRUE(d.bodies[0].triangle_indices.empty());
  std::int64_t t = 1'000'000'000;
  lm.OfferPatch(d, t);
  IntermediateRep server = sc.ServerAnswer(X_WA, 0.3, 1000, t);
  lm.OfferServerIr(server);
  ASSERT_TRUE(StepFetch(&lm, sc.Sample(X_WA, 1, t), t, &out));
  EXPECT_EQ(out.front().source, kIrSourceServer);
  EXPECT_EQ(out.front().rows[0].depth, 0.3);
  EXPECT_EQ(lm.stats().server_deeper, 1u);
}

TEST(LocalModel, ABadPatchIsCountedAndTurnsTheModelOffUntilReset) {
  Scene sc;
  LocalContactModel lm(sc.probe, sc.X_PA(), LocalModelOptions{});
  IrMailbox out;
  const Pose X_WA = sc.ProbeAt(0.003);
  std::int64_t t = 1'000'000'000;
  PatchDelta bad = sc.Patch(X_WA, 0.01);
  bad.bodies[0].triangle_indices[0] = 1u << 30;
  lm.OfferPatch(bad, t);
  (void)OfferAndStep(&lm, sc.Sample(X_WA, 1, t), t, &out);
  LocalModelStats s = lm.stats();
  EXPECT_EQ(s.bad_patches, 1u);
  EXPECT_NE(s.last_problem.find("out of range"), std::string::npos);
  EXPECT_EQ(s.local_answers, 0u);
  // Even a good patch after it is not used: what the server believes is
  // held is no longer what is held.
  lm.OfferPatch(sc.Patch(X_WA, 0.01, 2), t);
  t += 1'000'000;
  (void)OfferAndStep(&lm, sc.Sample(X_WA, 2, t), t, &out);
  EXPECT_EQ(lm.stats().local_answers, 0u);
  // A new stream starts afresh.
  lm.Reset();
  lm.OfferPatch(sc.Patch(X_WA, 0.01, 1), t);
  t += 1'000'000;
  ASSERT_TRUE(OfferAndStep(&lm, sc.Sample(X_WA, 3, t), t, &out));
  EXPECT_EQ(lm.stats().local_answers, 1u);
  // An undecodable patch counts the same way.
  lm.RejectPatch("patch 2 bodies[0] ('box').vertices: 5 numbers for 2 vertex indices");
  t += 1'000'000;
  (void)OfferAndStep(&lm, sc.Sample(X_WA, 4, t), t, &out);
  EXPECT_EQ(lm.stats().bad_patches, 2u);
}

TEST(LocalModel, AQuietStreamDropsThePatch) {
  Scene sc;
  LocalModelOptions o;
  o.patch_quiet_s = 0.5;
  LocalContactModel lm(sc.probe, sc.X_PA(), o);
  IrMailbox out;
  const Pose X_WA = sc.ProbeAt(0.003);
  std::int64_t t = 1'000'000'000;
  lm.OfferPatch(sc.Patch(X_WA, 0.01), t);
  ASSERT_TRUE(OfferAndStep(&lm, sc.Sample(X_WA, 1, t), t, &out));
  EXPECT_EQ(lm.stats().local_answers, 1u);
  t += 400'000'000;  // quiet, but not for long
  ASSERT_TRUE(OfferAndStep(&lm, sc.Sample(X_WA, 2, t), t, &out));
  EXPECT_EQ(lm.stats().local_answers, 2u);
  t += 200'000'000;  // 0.6 s without a message
  (void)OfferAndStep(&lm, sc.Sample(X_WA, 3, t), t, &out);
  EXPECT_EQ(lm.stats().local_answers, 2u);
  EXPECT_EQ(lm.stats().drops, 1u);
}

TEST(LocalModel, TheServersAnswerIsCheckedAgainstTheLocalAnswerToTheSameSample) {
  Scene sc;
  LocalContactModel lm(sc.probe, sc.X_PA(), LocalModelOptions{});
  IrMailbox out;
  const Pose X_WA = sc.ProbeAt(0.003);
  std::int64_t t = 1'000'000'000;
  lm.OfferPatch(sc.Patch(X_WA, 0.01), t);
  for (std::uint64_t seq = 1; seq <= 3; ++seq) {
    t += 1'000'000;
    ASSERT_TRUE(OfferAndStep(&lm, sc.Sample(X_WA, seq, t), t, &out));
  }
  // The server answers sample 2 as the patch did (3 mm), then sample 3 a
  // millimetre deeper, then a sample the local model never answered.
  IntermediateRep server;
  server.num_rows = 1;
  server.rows[0].n_W = Vec3::UnitZ();
  server.rows[0].stiffness = 1000;
  for (auto [seq, depth] : {std::pair<std::uint64_t, double>{2, 0.003}, {3, 0.004}, {99, 0.003}}) {
    t += 1'000'000;
    server.sequence = seq;
    server.rows[0].depth = depth;
    server.receive_time_ns = t;
    lm.OfferServerIr(server);
    (void)lm.Step(t, &out);
  }
  const LocalModelStats s = lm.stats();
  EXPECT_EQ(s.reference_checks, 2u);
  EXPECT_EQ(s.reference_disagreements, 1u);
  EXPECT_NEAR(s.reference_diff_max_mm, 1.0, 0.05);
}

// With Start(), patches are applied and built on their own thread while the
// worker keeps answering from the previous view.
TEST(LocalModel, ThreadedWorkerAnswersFromPatchesBuiltInTheBackground) {
  Scene sc;
  LocalContactModel lm(sc.probe, sc.X_PA(), LocalModelOptions{});
  IrMailbox out;
  const Clock& clock = SteadyClock::Instance();
  lm.Start(&out, &clock);
  const Pose X_WA = sc.ProbeAt(0.003);
  lm.OfferPatch(sc.Patch(X_WA, 0.01), clock.NowNs());
  bool local = false;
  for (std::uint64_t seq = 1; seq < 5000 && !local; ++seq) {
    lm.OfferSample(sc.Sample(X_WA, seq, clock.NowNs()));
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
    while (out.Fetch()) {
      if (out.front().source == kIrSourceLocal && out.front().num_rows > 0) local = true;
    }
  }
  lm.Stop();
  EXPECT_TRUE(local) << "no local answer within 5000 samples";
  EXPECT_EQ(lm.stats().patches, 1u);
  EXPECT_GT(lm.stats().local_answers, 0u);
}

// A body's query state starts from the server's answer when its patch model
// is new, and the seeded query answers as the cold one does.
TEST(LocalModel, AFreshPatchQueryIsSeededWithTheServersAnswer) {
  Scene sc;
  const Pose X_WA = sc.ProbeAt(0.004);
  auto run = [&](bool with_server) {
    LocalContactModel lm(sc.probe, sc.X_PA(), LocalModelOptions{});
    IrMailbox out;
    std::int64_t t = 1'000'000'000;
    if (with_server) {
      IntermediateRep server = sc.ServerAnswer(X_WA, 0.004, 1000, t);
      lm.OfferServerIr(server);
    }
    lm.OfferPatch(sc.Patch(X_WA, 0.01), t);
    EXPECT_TRUE(OfferAndStep(&lm, sc.Sample(X_WA, 2, t), t, &out));
    EXPECT_TRUE(out.Fetch());
    EXPECT_EQ(out.front().source, kIrSourceLocal);
    EXPECT_GE(out.front().num_rows, 1);
    return std::pair{lm.stats().seeded, out.front().rows[0].depth};
  };
  const auto [seeded_cold, depth_cold] = run(false);
  const auto [seeded, depth] = run(true);
  EXPECT_EQ(seeded_cold, 0u);
  EXPECT_EQ(seeded, 1u);
  EXPECT_NEAR(depth, 0.004, 1e-6);
  EXPECT_NEAR(depth, depth_cold, 1e-9);
}

}  // namespace
}  // namespace hapticpd::device
