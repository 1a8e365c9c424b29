// A device session's PD side without a network (server/session_worker.h):
// hello to welcome, pose to ContactUpdate, the scene's declared effects, the
// last check before a motor, and one rule from PD answer to what the device
// renders: the server's update, decoded by the client, gives the device the
// same rows and validity as the device side's own PD source on the same
// pose. Depths are checked against FCL. Runs in every preset (label
// `services`).
#include <gtest/gtest.h>

#include "client/session.h"
#include "device/local_pd_source.h"
#include "pd/shapes.h"
#include "server/session_worker.h"
#include "tests/oracles/fcl_oracle.h"
#include "tests/server/server_harness.h"

namespace hapticpd::testing {
namespace {

using server::internal::AnswerInfo;
using server::internal::MailPose;
using server::internal::SessionWorker;

/// A scene "s" holding one static box (half extents 5 cm) at the origin.
struct BoxScene {
  server::ChangeSignal signal;
  server::ScenePtr scene = std::make_shared<server::Scene>("s", "", &signal);
  pd::ModelPtr box = pd::MakeModel(pd::shapes::Box(Vec3::Constant(0.05)));

  explicit BoxScene(const v1::SceneConfig& config = {}) {
    scene->set_config(config);
    server::BodyState b;
    b.uid = 1;
    b.id = "box";
    b.model = box;
    b.material.static_friction = 0.6;
    b.material.dynamic_friction = 0.4;
    b.material.damping = 2;
    EXPECT_TRUE(scene->AddBody(std::move(b), 8, nullptr, "id").ok());
  }
};

v1::Hello SphereHello(v1::PdMode mode = v1::PD_MODE_PDT) {
  v1::Hello h = Session::DefaultHello("s", mode, "sphere:0.01,2");
  return h;
}

MailPose At(double z, std::uint64_t seq = 1) {
  MailPose p;
  p.sequence = seq;
  p.X_WA = Pose::FromTranslation(Vec3(0.01, -0.005, z));
  return p;
}

TEST(SessionWorker, HelloGivesTheWelcomeOfItsProbe) {
  BoxScene s;
  SessionWorker w(server::Limits{}, "s1");
  v1::Welcome welcome;
  ASSERT_TRUE(w.Start(SphereHello(), s.scene, &welcome).ok());
  EXPECT_EQ(welcome.session_id(), "s1");
  EXPECT_EQ(welcome.mode(), v1::PD_MODE_PDT);
  EXPECT_EQ(welcome.probe_mesh_info().triangles(), 320u);
  EXPECT_EQ(welcome.protocol_version(), server::internal::kProtocolVersion);
  v1::Hello bad = SphereHello();
  bad.set_probe_shape("sphere:-1");
  SessionWorker w2(server::Limits{}, "s2");
  const grpc::Status st = w2.Start(bad, s.scene, &welcome);
  EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(st.error_message().rfind("hello.probe_shape: ", 0), 0u) << st.error_message();
}

TEST(SessionWorker, PressAnswersWithRowsMaterialAndAnFclVerifiedDepth) {
  BoxScene s;
  SessionWorker w(server::Limits{}, "s1");
  v1::Welcome welcome;
  ASSERT_TRUE(w.Start(SphereHello(), s.scene, &welcome).ok());
  v1::ContactUpdate u;
  // Free above the box.
  AnswerInfo info = w.Answer(At(0.2), 0, &u);
  EXPECT_TRUE(info.pd_ran);
  EXPECT_EQ(u.status(), v1::CONTACT_STATUS_SEPARATED);
  EXPECT_EQ(u.rows_size(), 0);
  // 4 mm into the top face.
  const MailPose p = At(0.05 + 0.01 - 0.004, 2);
  info = w.Answer(p, 3, &u);
  ASSERT_EQ(u.status(), v1::CONTACT_STATUS_PENETRATING);
  EXPECT_EQ(u.sequence(), 2u);
  EXPECT_EQ(u.poses_superseded(), 3u);
  ASSERT_GE(u.rows_size(), 1);
  ASSERT_EQ(u.body_ids_size(), 1);
  EXPECT_EQ(u.body_ids(0), "box");
  for (const v1::ContactRow& r : u.rows()) {
    EXPECT_NEAR(r.normal().z(), 1.0, 1e-6);
    EXPECT_EQ(r.static_friction(), 0.6);
    EXPECT_EQ(r.dynamic_friction(), 0.4);
    EXPECT_EQ(r.damping(), 2);
    EXPECT_EQ(r.body_index(), 0u);
  }
  EXPECT_GT(u.force().z(), 0);
  EXPECT_EQ(info.force_W.z(), u.force().z());
  // The PD vector moves the probe out: free after a 1e-6 push, colliding
  // after a pull back (FCL, independent of pd/).
  const Vec3 d(u.pd_translation().x(), u.pd_translation().y(), u.pd_translation().z());
  EXPECT_NEAR(d.norm(), u.depth(), 1e-12);
  const pd::ModelPtr probe = w.probe();
  const Pose out = Pose::FromTranslation(p.X_WA.t + d * (1 + 1e-6));
  const Pose back = Pose::FromTranslation(p.X_WA.t + d * (1 - 1e-3));
  const FclModel fcl_probe(probe->mesh()), fcl_box(s.box->mesh());
  EXPECT_FALSE(FclCollide(fcl_probe, out, fcl_box, Pose::Identity()));
  EXPECT_TRUE(FclCollide(fcl_probe, back, fcl_box, Pose::Identity()));
  // Validity: a tenth of the probe's bounding radius beyond the depth.
  EXPECT_DOUBLE_EQ(u.validity_radius(), 0.1 * probe->mesh().bounding_radius() + u.depth());
}

TEST(SessionWorker, SceneWithoutTorqueGetsNoMomentsAndModeNoneNoPd) {
  v1::SceneConfig contact_only;
  contact_only.set_declared(true);
  contact_only.add_effects(v1::EFFECT_CONTACT);
  BoxScene s(contact_only);
  SessionWorker w(server::Limits{}, "s1");
  v1::Welcome welcome;
  ASSERT_TRUE(w.Start(SphereHello(), s.scene, &welcome).ok());
  v1::ContactUpdate u;
  const AnswerInfo info = w.Answer(At(0.055), 0, &u);
  EXPECT_FALSE(info.torque);
  ASSERT_GE(u.rows_size(), 1);
  for (const v1::ContactRow& r : u.rows()) EXPECT_FALSE(r.has_moment());
  EXPECT_FALSE(u.has_torque());

  SessionWorker none(server::Limits{}, "s2");
  ASSERT_TRUE(none.Start(SphereHello(v1::PD_MODE_NONE), s.scene, &welcome).ok());
  const AnswerInfo ni = none.Answer(At(0.055), 0, &u);
  EXPECT_FALSE(ni.pd_ran);
  EXPECT_EQ(u.status(), v1::CONTACT_STATUS_NONE);
  EXPECT_EQ(u.rows_size(), 0);
  EXPECT_GT(u.validity_radius(), 0);
}

TEST(SessionWorker, AnswerOverTheForceLimitIsWithheld) {
  BoxScene s;
  server::Limits limits;
  limits.max_update_force = 0.5;
  SessionWorker w(limits, "s1");
  v1::Welcome welcome;
  ASSERT_TRUE(w.Start(SphereHello(), s.scene, &welcome).ok());
  v1::ContactUpdate u;
  const AnswerInfo info = w.Answer(At(0.05), 7, &u);  // 1 cm deep: 10 N
  ASSERT_NE(info.withheld, nullptr);
  EXPECT_STREQ(info.withheld, "force over the server's --max-update-force");
  EXPECT_EQ(u.status(), v1::CONTACT_STATUS_WITHHELD);
  EXPECT_EQ(u.rows_size(), 0);
  EXPECT_FALSE(u.has_force());
  EXPECT_EQ(u.sequence(), 1u);
  EXPECT_EQ(info.force_W, Vec3::Zero());
}

TEST(SessionWorker, ServerUpdateAndTheDeviceSourceGiveTheSameRowsAndValidity) {
  // A sphere, and a hammer whose centre of mass is far from its bounding
  // box's centre (the two radii of the validity rule differ).
  for (const char* shape : {"sphere:0.01,2", "hammer"}) {
    SCOPED_TRACE(shape);
    BoxScene s;
    SessionWorker w(server::Limits{}, "s1");
    v1::Welcome welcome;
    ASSERT_TRUE(
        w.Start(Session::DefaultHello("s", v1::PD_MODE_PDT, shape), s.scene, &welcome).ok());
    pd::SceneBody body{s.box, Pose::Identity(), pd::Material{}};
    body.material.static_friction = 0.6;
    body.material.dynamic_friction = 0.4;
    body.material.damping = 2;
    device::LocalPdIrSource local(w.probe(), {body});
    const double bottom = w.probe()->mesh().bounds().lo.z();
    int with_rows = 0;
    for (double depth : {0.001, 0.004, 0.008}) {
      SCOPED_TRACE(depth);
      const MailPose p = At(0.05 - bottom - depth);
      v1::ContactUpdate u;
      w.Answer(p, 0, &u);
      device::IntermediateRep from_wire;
      ASSERT_TRUE(client::IrFromContactUpdate(u, local.X_PA().Inverse(), 0, &from_wire));
      device::ProxySample sample;
      sample.X_WP = p.X_WA * local.X_PA().Inverse();
      device::IntermediateRep from_local;
      local.Compute(sample, &from_local);
      ASSERT_EQ(from_wire.num_rows, from_local.num_rows);
      with_rows += from_local.num_rows > 0;
      for (int i = 0; i < from_local.num_rows; ++i) {
        const device::IrRow& a = from_wire.rows[static_cast<std::size_t>(i)];
        const device::IrRow& b = from_local.rows[static_cast<std::size_t>(i)];
        EXPECT_LT((a.p_W - b.p_W).norm(), 1e-12);
        EXPECT_LT((a.n_W - b.n_W).norm(), 1e-12);
        EXPECT_NEAR(a.depth, b.depth, 1e-12);
        EXPECT_EQ(a.stiffness, b.stiffness);
        EXPECT_EQ(a.static_friction, b.static_friction);
        EXPECT_EQ(a.damping, b.damping);
      }
      EXPECT_NEAR(from_wire.validity_radius, from_local.validity_radius, 1e-12);
      EXPECT_NEAR(from_wire.validity_angle, from_local.validity_angle, 1e-12);
    }
    EXPECT_EQ(with_rows, 3);
  }
}

}  // namespace
}  // namespace hapticpd::testing
