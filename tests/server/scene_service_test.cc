// SceneService over both transports: scene lifecycle, body upload (chunks,
// inline, shape), move/remove, and every class of invalid input: the status
// code, a message naming the field, and the scene unchanged afterwards.
#include <fstream>
#include <sstream>

#include "tests/server/server_harness.h"
#include "tests/test_util.h"

namespace hapticpd::testing {
namespace {

class SceneServiceTest : public ::testing::TestWithParam<Transport> {};

TEST_P(SceneServiceTest, StartsWithAnEmptyDefaultScene) {
  ServerHarness h(GetParam());
  auto stub = h.Scenes();
  v1::ListScenesResponse list;
  auto ctx = Ctx();
  ASSERT_TRUE(stub->ListScenes(ctx.get(), {}, &list).ok());
  ASSERT_EQ(list.scenes_size(), 1);
  EXPECT_EQ(list.scenes(0).scene_id(), "default");
  EXPECT_EQ(list.scenes(0).bodies(), 0u);
}

TEST_P(SceneServiceTest, SceneLifecycle) {
  ServerHarness h(GetParam());
  auto stub = h.Scenes();
  v1::CreateSceneRequest create;
  create.set_scene_id("lab");
  create.set_description("bench");
  v1::SceneSummary summary;
  {
    auto ctx = Ctx();
    ASSERT_TRUE(stub->CreateScene(ctx.get(), create, &summary).ok());
  }
  EXPECT_EQ(summary.scene_id(), "lab");
  {
    auto ctx = Ctx();
    const auto s = stub->CreateScene(ctx.get(), create, &summary);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::ALREADY_EXISTS);
  }
  // Bodies: a shape, an inline tetrahedron, and an OBJ uploaded in small chunks.
  ASSERT_TRUE(AddShape(*stub, "lab", "box:0.05,0.05,0.05", "floor", MakePose(0, 0, 0)).ok());
  v1::AddBodyRequest inl;
  auto* ih = inl.mutable_header();
  ih->set_scene_id("lab");
  ih->mutable_spec()->set_movable(true);
  for (double v : {0., 0., 0., 1., 0., 0., 0., 1., 0., 0., 0., 1.}) {
    ih->mutable_inline_mesh()->add_vertices(v * 0.01);
  }
  for (unsigned i : {0u, 2u, 1u, 0u, 1u, 3u, 0u, 3u, 2u, 1u, 2u, 3u}) {
    ih->mutable_inline_mesh()->add_triangles(i);
  }
  v1::Body tet;
  ASSERT_TRUE(AddBodyRaw(*stub, {inl}, &tet).ok());
  EXPECT_EQ(tet.body_id(), "body-1");  // server-assigned
  EXPECT_EQ(tet.mesh_info().triangles(), 4u);
  EXPECT_TRUE(tet.mesh_info().watertight());

  const std::string obj =
      "v 0 0 0\nv 0.02 0 0\nv 0 0.02 0\nv 0 0 0.02\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
  std::vector<v1::AddBodyRequest> parts(1);
  parts[0].mutable_header()->set_scene_id("lab");
  parts[0].mutable_header()->set_format(v1::MESH_FORMAT_OBJ);
  parts[0].mutable_header()->mutable_spec()->set_body_id("obj");
  for (std::size_t off = 0; off < obj.size(); off += 7) {
    parts.emplace_back().set_chunk(obj.substr(off, 7));
  }
  v1::Body ob;
  const auto s = AddBodyRaw(*stub, parts, &ob);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(ob.mesh_info().triangles(), 4u);

  v1::Scene scene = GetScene(*stub, "lab");
  ASSERT_EQ(scene.bodies_size(), 3);
  EXPECT_EQ(scene.revision(), 3u);

  const v1::Pose moved_to = MakePose(0.1, 0.2, 0.3, 0, 1, 0, 0);
  v1::MoveBodyResponse moved;
  ASSERT_TRUE(MoveBody(*stub, "lab", "body-1", moved_to, &moved).ok());
  EXPECT_EQ(moved.revision(), 4u);
  scene = GetScene(*stub, "lab");
  EXPECT_DOUBLE_EQ(scene.bodies(1).pose().position().z(), 0.3);
  EXPECT_DOUBLE_EQ(scene.bodies(1).pose().orientation().x(), 1.0);

  EXPECT_EQ(MoveBody(*stub, "lab", "floor", moved_to).error_code(),  // static
            grpc::StatusCode::FAILED_PRECONDITION);
  ASSERT_TRUE(RemoveBody(*stub, "lab", "obj").ok());
  EXPECT_EQ(GetScene(*stub, "lab").bodies_size(), 2);

  v1::GetSceneRequest with_meshes;
  with_meshes.set_scene_id("lab");
  with_meshes.set_include_meshes(true);
  v1::Scene full;
  {
    auto ctx = Ctx();
    ASSERT_TRUE(stub->GetScene(ctx.get(), with_meshes, &full).ok());
  }
  EXPECT_EQ(full.bodies(0).mesh().triangles_size(), 36);  // the box: 12 triangles

  ASSERT_TRUE(DeleteScene(*stub, "lab").ok());
  EXPECT_EQ(DeleteScene(*stub, "lab").error_code(), grpc::StatusCode::NOT_FOUND);
  v1::GetSceneRequest get;
  get.set_scene_id("lab");
  {
    auto ctx = Ctx();
    EXPECT_EQ(stub->GetScene(ctx.get(), get, &full).error_code(), grpc::StatusCode::NOT_FOUND);
  }
}

TEST_P(SceneServiceTest, UploadsASharedModelInChunks) {
  HAPTICPD_REQUIRE_MODEL(bunny, "stanford-bunny.obj");
  ServerHarness h(GetParam());
  auto stub = h.Scenes();
  std::ifstream in(bunny, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), {});
  std::vector<v1::AddBodyRequest> parts(1);
  parts[0].mutable_header()->set_scene_id("default");
  parts[0].mutable_header()->set_format(v1::MESH_FORMAT_OBJ);
  parts[0].mutable_header()->set_total_bytes(bytes.size());
  for (std::size_t off = 0; off < bytes.size(); off += 64 * 1024) {
    parts.emplace_back().set_chunk(bytes.substr(off, 64 * 1024));
  }
  v1::Body body;
  const auto s = AddBodyRaw(*stub, parts, &body);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_GT(body.mesh_info().triangles(), 60000u);
}

// ---------------------------------------------------------------------------
// Invalid input: status, field named, scene unchanged.

struct BadCase {
  std::string name;
  std::vector<v1::AddBodyRequest> requests;
  grpc::StatusCode code;
  std::string field;  // must appear in the message
};

v1::AddBodyRequest Inline(std::vector<double> v, std::vector<unsigned> t) {
  v1::AddBodyRequest r;
  r.mutable_header()->set_scene_id("default");
  r.mutable_header()->mutable_inline_mesh();  // set even when both arrays are empty
  for (double x : v) r.mutable_header()->mutable_inline_mesh()->add_vertices(x);
  for (unsigned i : t) r.mutable_header()->mutable_inline_mesh()->add_triangles(i);
  return r;
}

v1::AddBodyRequest Chunk(const std::string& s) {
  v1::AddBodyRequest r;
  r.set_chunk(s);
  return r;
}

TEST_P(SceneServiceTest, InvalidAddBodyIsRejectedAndChangesNothing) {
  server::ServerOptions opt;
  opt.limits.max_mesh_triangles = 500;
  opt.limits.max_mesh_bytes = 4096;
  opt.limits.max_bodies_per_scene = 2;
  opt.limits.max_message_bytes = 64 * 1024;
  ServerHarness h(GetParam(), opt);
  auto stub = h.Scenes();
  ASSERT_TRUE(AddShape(*stub, "default", "box", "keep", MakePose(0, 0, 0)).ok());
  const v1::Scene before = GetScene(*stub, "default");

  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  const std::vector<double> tri_v = {0, 0, 0, 1, 0, 0, 0, 1, 0};
  std::vector<BadCase> cases;
  auto shape = [](const v1::Pose& p) { return ShapeHeader("default", "box", "", p); };
  cases.push_back({"nan position",
                   {shape(MakePose(nan, 0, 0))},
                   grpc::StatusCode::INVALID_ARGUMENT,
                   "header.spec.pose.position.x"});
  cases.push_back({"inf position",
                   {shape(MakePose(0, 0, inf))},
                   grpc::StatusCode::INVALID_ARGUMENT,
                   "header.spec.pose.position.z"});
  cases.push_back({"quaternion norm 2",
                   {shape(MakePose(0, 0, 0, 2, 0, 0, 0))},
                   grpc::StatusCode::INVALID_ARGUMENT,
                   "header.spec.pose.orientation"});
  cases.push_back({"zero quaternion",
                   {shape(MakePose(0, 0, 0, 0, 0, 0, 0))},
                   grpc::StatusCode::INVALID_ARGUMENT,
                   "header.spec.pose.orientation"});
  cases.push_back({"nan quaternion",
                   {shape(MakePose(0, 0, 0, nan, 0, 0, 0))},
                   grpc::StatusCode::INVALID_ARGUMENT,
                   "header.spec.pose.orientation.w"});
  {
    auto r = shape(MakePose(0, 0, 0));
    r.mutable_header()->mutable_spec()->mutable_material()->set_stiffness(-1);
    cases.push_back({"negative stiffness",
                     {r},
                     grpc::StatusCode::INVALID_ARGUMENT,
                     "header.spec.material.stiffness"});
  }
  {
    auto r = shape(MakePose(0, 0, 0));
    r.mutable_header()->mutable_spec()->set_body_id("bad id!");
    cases.push_back(
        {"bad body id", {r}, grpc::StatusCode::INVALID_ARGUMENT, "header.spec.body_id"});
  }
  {
    auto r = shape(MakePose(0, 0, 0));
    r.mutable_header()->mutable_spec()->set_body_id("keep");
    cases.push_back({"duplicate id", {r}, grpc::StatusCode::ALREADY_EXISTS, "body_id"});
  }
  cases.push_back({"index out of range",
                   {Inline(tri_v, {0, 1, 3})},
                   grpc::StatusCode::INVALID_ARGUMENT,
                   "header.inline_mesh.triangles[2]"});
  cases.push_back({"vertices not xyz",
                   {Inline({0, 0, 0, 1}, {0, 0, 0})},
                   grpc::StatusCode::INVALID_ARGUMENT,
                   "header.inline_mesh.vertices"});
  cases.push_back({"empty mesh",
                   {Inline({}, {})},
                   grpc::StatusCode::INVALID_ARGUMENT,
                   "header.inline_mesh.vertices"});
  cases.push_back({"no triangles",
                   {Inline(tri_v, {})},
                   grpc::StatusCode::INVALID_ARGUMENT,
                   "header.inline_mesh.triangles"});
  cases.push_back({"nan vertex",
                   {Inline({0, 0, 0, nan, 0, 0, 0, 1, 0}, {0, 1, 2})},
                   grpc::StatusCode::INVALID_ARGUMENT,
                   "header.inline_mesh.vertices[3]"});
  cases.push_back({"unknown scene",
                   {ShapeHeader("nope", "box", "", MakePose(0, 0, 0))},
                   grpc::StatusCode::NOT_FOUND,
                   "scene_id"});
  cases.push_back({"bad shape",
                   {ShapeHeader("default", "blob", "", MakePose(0, 0, 0))},
                   grpc::StatusCode::INVALID_ARGUMENT,
                   "header.shape"});
  cases.push_back({"too many triangles",
                   {ShapeHeader("default", "sphere:0.05,3", "", MakePose(0, 0, 0))},
                   grpc::StatusCode::RESOURCE_EXHAUSTED,
                   "triangles"});
  {
    v1::AddBodyRequest r;
    r.mutable_header()->set_scene_id("default");
    r.mutable_header()->set_format(v1::MESH_FORMAT_OBJ);
    cases.push_back({"garbage obj",
                     {r, Chunk("v 0 0 0\nv 1 0 0\nf 1 2 9\nthis is not obj\n")},
                     grpc::StatusCode::INVALID_ARGUMENT,
                     "chunk"});
    cases.push_back({"no bytes", {r}, grpc::StatusCode::INVALID_ARGUMENT, "chunk"});
    cases.push_back({"too many bytes",
                     {r, Chunk(std::string(3000, ' ')), Chunk(std::string(3000, ' '))},
                     grpc::StatusCode::RESOURCE_EXHAUSTED,
                     "bytes"});
    auto announced = r;
    announced.mutable_header()->set_total_bytes(1 << 20);
    cases.push_back({"announced too many bytes",
                     {announced},
                     grpc::StatusCode::RESOURCE_EXHAUSTED,
                     "header.total_bytes"});
    cases.push_back({"header twice", {r, r}, grpc::StatusCode::INVALID_ARGUMENT, "header"});
    auto unspecified = r;
    unspecified.mutable_header()->set_format(v1::MESH_FORMAT_UNSPECIFIED);
    cases.push_back(
        {"unspecified format", {unspecified}, grpc::StatusCode::INVALID_ARGUMENT, "header.format"});
  }
  cases.push_back(
      {"chunk before header", {Chunk("v 0 0 0\n")}, grpc::StatusCode::INVALID_ARGUMENT, "header"});
  cases.push_back({"chunk after inline",
                   {Inline(tri_v, {0, 1, 2}), Chunk("x")},
                   grpc::StatusCode::INVALID_ARGUMENT,
                   "chunk"});
  cases.push_back({"empty stream", {}, grpc::StatusCode::INVALID_ARGUMENT, "header"});
  {
    std::vector<double> big(3 * 4000, 0.0);  // 96 KB > 64 KiB message limit
    cases.push_back(
        {"message too large", {Inline(big, {0, 1, 2})}, grpc::StatusCode::RESOURCE_EXHAUSTED, ""});
  }
  for (const BadCase& c : cases) {
    SCOPED_TRACE(c.name);
    v1::Body body;
    const grpc::Status s = AddBodyRaw(*stub, c.requests, &body);
    EXPECT_EQ(s.error_code(), c.code) << s.error_message();
    EXPECT_NE(s.error_message().find(c.field), std::string::npos) << s.error_message();
    const v1::Scene after = GetScene(*stub, "default");
    EXPECT_EQ(after.revision(), before.revision());
    EXPECT_EQ(after.bodies_size(), before.bodies_size());
  }
  // The body limit: one more fits, the next does not.
  ASSERT_TRUE(AddShape(*stub, "default", "box", "second", MakePose(1, 0, 0)).ok());
  const v1::Scene full = GetScene(*stub, "default");
  const auto s = AddShape(*stub, "default", "box", "third", MakePose(2, 0, 0));
  EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << s.error_message();
  EXPECT_EQ(GetScene(*stub, "default").revision(), full.revision());
}

TEST_P(SceneServiceTest, InvalidMoveRemoveAndSceneRequests) {
  ServerHarness h(GetParam());
  auto stub = h.Scenes();
  ASSERT_TRUE(AddShape(*stub, "default", "box", "m", MakePose(0, 0, 0), true).ok());
  const v1::Scene before = GetScene(*stub, "default");
  const double nan = std::numeric_limits<double>::quiet_NaN();
  struct MoveCase {
    std::string body;
    v1::Pose pose;
    grpc::StatusCode code;
    std::string field;
  };
  const std::vector<MoveCase> moves = {
      {"m", MakePose(nan, 0, 0), grpc::StatusCode::INVALID_ARGUMENT, "pose.position.x"},
      {"m", MakePose(0, 0, 0, 0.5, 0, 0, 0), grpc::StatusCode::INVALID_ARGUMENT,
       "pose.orientation"},
      {"ghost", MakePose(0, 0, 0), grpc::StatusCode::NOT_FOUND, "body_id"},
      {"", MakePose(0, 0, 0), grpc::StatusCode::INVALID_ARGUMENT, "body_id"},
  };
  for (const auto& c : moves) {
    SCOPED_TRACE(c.field + " " + c.body);
    const auto s = MoveBody(*stub, "default", c.body, c.pose);
    EXPECT_EQ(s.error_code(), c.code) << s.error_message();
    EXPECT_NE(s.error_message().find(c.field), std::string::npos) << s.error_message();
  }
  {
    v1::MoveBodyRequest req;
    req.set_scene_id("default");
    req.set_body_id("m");
    req.mutable_velocity()->mutable_angular()->set_y(nan);
    v1::MoveBodyResponse resp;
    auto ctx = Ctx();
    const auto s = stub->MoveBody(ctx.get(), req, &resp);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(s.error_message().find("velocity.angular.y"), std::string::npos);
  }
  {
    v1::MoveBodyRequest req;
    req.set_scene_id("elsewhere");
    req.set_body_id("m");
    v1::MoveBodyResponse resp;
    auto ctx = Ctx();
    EXPECT_EQ(stub->MoveBody(ctx.get(), req, &resp).error_code(), grpc::StatusCode::NOT_FOUND);
  }
  EXPECT_EQ(RemoveBody(*stub, "default", "ghost").error_code(), grpc::StatusCode::NOT_FOUND);
  for (const std::string& id : std::vector<std::string>{"", "has space", std::string(65, 'a')}) {
    const auto s = CreateScene(*stub, id);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(s.error_message().find("scene_id"), std::string::npos);
  }
  const v1::Scene after = GetScene(*stub, "default");
  EXPECT_EQ(after.revision(), before.revision());
  EXPECT_EQ(after.bodies(0).pose().position().x(), 0.0);
}

TEST_P(SceneServiceTest, QuaternionsNearUnitAreNormalised) {
  ServerHarness h(GetParam());
  auto stub = h.Scenes();
  ASSERT_TRUE(AddShape(*stub, "default", "box", "b", MakePose(0, 0, 0, 1.0005, 0, 0, 0)).ok());
  const auto q = GetScene(*stub, "default").bodies(0).pose().orientation();
  EXPECT_NEAR(q.w() * q.w() + q.x() * q.x() + q.y() * q.y() + q.z() * q.z(), 1.0, 1e-12);
}

TEST_P(SceneServiceTest, SceneLimit) {
  server::ServerOptions opt;
  opt.limits.max_scenes = 2;
  ServerHarness h(GetParam(), opt);
  auto stub = h.Scenes();
  ASSERT_TRUE(CreateScene(*stub, "second").ok());
  EXPECT_EQ(CreateScene(*stub, "third").error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
}

INSTANTIATE_TEST_SUITE_P(Transports, SceneServiceTest,
                         ::testing::Values(Transport::kInProcess, Transport::kTcp), TransportName);

}  // namespace
}  // namespace hapticpd::testing
