// Geometry patches from the wire (client::PatchDeltaFromProto): a malformed
// patch from a server is refused with a problem naming the field, before
// anything reaches the device side's store. Runs in every preset
// (client_tests; no network).
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <string>

#include "client/session.h"

namespace hapticpd {
namespace {

/// One body with a single triangle (vertices 0, 1, 2 of a mesh of 4).
v1::GeometryPatch GoodPatch() {
  v1::GeometryPatch g;
  g.set_sequence(3);
  g.set_scene_revision(2);
  g.mutable_center()->set_z(0.1);
  g.set_radius(0.2);
  v1::BodyPatch* b = g.add_bodies();
  b->set_body_id("floor");
  b->set_body_key(11);
  b->set_triangle_count(2);
  b->set_vertex_count(4);
  b->mutable_pose()->mutable_orientation()->set_w(1);
  b->mutable_material()->set_stiffness(800);
  b->set_cover_radius(0.2);
  for (std::uint32_t v : {0u, 1u, 2u}) b->add_vertex_indices(v);
  for (double x : {0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0}) b->add_vertices(x);
  b->add_triangle_indices(1);
  for (std::uint32_t v : {0u, 1u, 2u}) b->add_triangles(v);
  return g;
}

TEST(PatchWire, DecodesEveryField) {
  device::PatchDelta d;
  ASSERT_EQ(client::PatchDeltaFromProto(GoodPatch(), 8192, &d), "");
  EXPECT_EQ(d.sequence, 3u);
  EXPECT_EQ(d.scene_revision, 2u);
  EXPECT_DOUBLE_EQ(d.radius, 0.2);
  EXPECT_GT(d.wire_bytes, 0u);
  ASSERT_EQ(d.bodies.size(), 1u);
  const device::PatchBodyDelta& b = d.bodies[0];
  EXPECT_EQ(b.id, "floor");
  EXPECT_EQ(b.key, 11u);
  EXPECT_EQ(b.material.stiffness, 800);
  ASSERT_EQ(b.vertices.size(), 3u);
  EXPECT_EQ(b.vertices[1], device::Vec3(1, 0, 0));
  ASSERT_EQ(b.triangles.size(), 1u);
  EXPECT_EQ(b.triangle_indices[0], 1u);
  // And the store takes it.
  device::PatchStore store;
  EXPECT_EQ(store.Apply(d), "");
  EXPECT_EQ(store.triangles_held(), 1u);
}

TEST(PatchWire, MalformedPatchesAreRefusedNamingTheField) {
  struct Case {
    const char* what;
    std::function<void(v1::GeometryPatch*)> spoil;
    const char* expect;  // in the problem
  };
  const std::vector<Case> cases = {
      {"vertices not 3 per index",
       [](v1::GeometryPatch* g) { g->mutable_bodies(0)->add_vertices(1); }, ".vertices"},
      {"triangles not 3 per index",
       [](v1::GeometryPatch* g) { g->mutable_bodies(0)->add_triangle_indices(0); }, ".triangles"},
      {"non-finite vertex",
       [](v1::GeometryPatch* g) { g->mutable_bodies(0)->set_vertices(4, std::nan("")); },
       "not finite"},
      {"vertex beyond 1e6 m",
       [](v1::GeometryPatch* g) { g->mutable_bodies(0)->set_vertices(0, 1e300); }, "not finite"},
      {"non-finite pose",
       [](v1::GeometryPatch* g) {
         g->mutable_bodies(0)->mutable_pose()->mutable_position()->set_x(INFINITY);
       },
       ".pose"},
      {"zero quaternion",
       [](v1::GeometryPatch* g) {
         g->mutable_bodies(0)->mutable_pose()->mutable_orientation()->set_w(0);
       },
       ".pose"},
      {"non-finite region", [](v1::GeometryPatch* g) { g->set_radius(std::nan("")); }, "radius"},
      {"non-finite velocity",
       [](v1::GeometryPatch* g) {
         g->mutable_bodies(0)->mutable_velocity()->mutable_linear()->set_x(std::nan(""));
       },
       "velocity"},
  };
  for (const Case& c : cases) {
    v1::GeometryPatch g = GoodPatch();
    c.spoil(&g);
    device::PatchDelta d;
    const std::string problem = client::PatchDeltaFromProto(g, 8192, &d);
    EXPECT_NE(problem.find(c.expect), std::string::npos) << c.what << ": '" << problem << "'";
    EXPECT_NE(problem.find("patch 3"), std::string::npos) << c.what << ": '" << problem << "'";
  }
  // Over the client's size limit in one message.
  device::PatchDelta d;
  const std::string over = client::PatchDeltaFromProto(GoodPatch(), 0, &d);
  EXPECT_NE(over.find("over the limit"), std::string::npos) << over;
  // Index ranges are the store's: decoded, then refused whole when applied.
  v1::GeometryPatch g = GoodPatch();
  g.mutable_bodies(0)->set_triangle_indices(0, 7);
  ASSERT_EQ(client::PatchDeltaFromProto(g, 8192, &d), "");
  device::PatchStore store;
  EXPECT_NE(store.Apply(d).find("triangle index 7 out of range"), std::string::npos);
  EXPECT_EQ(store.triangles_held(), 0u);
}

}  // namespace
}  // namespace hapticpd
