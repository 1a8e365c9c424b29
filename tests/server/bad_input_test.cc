// The "SceneService and Couple" bad-input table of tests/README.md, as a
// test: every class of bad request the SceneService and HapticService
// reject, the exact status and message the user gets, and proof that nothing
// changed (every scene, byte for byte, before and after the rejected
// request). HAPTICPD_PRINT_TABLE=1 prints the rows as README markdown
// (tests/update_tables.py).
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "proto/wire/status.h"
#include "tests/readme_table.h"
#include "tests/server/server_harness.h"

namespace hapticpd::testing {
namespace {

namespace fs = std::filesystem;

constexpr char kTokens[] = R"({"tokens": [
  {"token": "obs", "name": "watcher", "roles": {"default": ["observe"]}},
  {"token": "adm", "name": "ops", "roles": {"*": ["admin"]}}
]})";

struct Row {
  std::string rpc;                        // the RPC
  std::string what;                       // the bad-input class (README markdown)
  std::function<grpc::Status()> request;  // issues it
  grpc::StatusCode code;
  std::string message;  // exact
};

/// Every scene (ListScenes + GetScene with meshes), serialized: equal
/// snapshots mean nothing changed.
std::string Snapshot(v1::SceneService::Stub& stub) {
  v1::ListScenesResponse list;
  auto ctx = Ctx("adm");
  EXPECT_TRUE(stub.ListScenes(ctx.get(), {}, &list).ok());
  std::string out = list.SerializeAsString();
  for (const auto& s : list.scenes()) {
    v1::GetSceneRequest req;
    req.set_scene_id(s.scene_id());
    req.set_include_meshes(true);
    v1::Scene scene;
    auto c = Ctx("adm");
    EXPECT_TRUE(stub.GetScene(c.get(), req, &scene).ok());
    out += scene.SerializeAsString();
  }
  return out;
}

v1::AddBodyRequest Chunk(std::string bytes) {
  v1::AddBodyRequest r;
  r.set_chunk(std::move(bytes));
  return r;
}

std::string ReadFile(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

class BadInputTable : public ::testing::Test {
 protected:
  void SetUp() override {
    tokens_ =
        fs::temp_directory_path() / ("hapticpd_bad_input_" + std::to_string(::getpid()) + ".json");
    std::ofstream(tokens_) << kTokens;
    server::ServerOptions opt;
    opt.tokens_file = tokens_.string();
    opt.limits.max_mesh_triangles = 500;
    opt.limits.max_mesh_bytes = 4096;
    opt.limits.max_scenes = 2;
    h_ = std::make_unique<ServerHarness>(Transport::kInProcess, opt);
    scenes_ = h_->Scenes();
    haptics_ = h_->Haptics();
    ASSERT_TRUE(AddShape(*scenes_, "default", "box", "keep", MakePose(0, 0, 0), true, "adm").ok());
    v1::CreateSceneRequest req;
    req.set_scene_id("lab");
    v1::SceneSummary resp;
    auto ctx = Ctx("adm");
    ASSERT_TRUE(scenes_->CreateScene(ctx.get(), req, &resp).ok());
  }
  void TearDown() override {
    h_.reset();
    fs::remove(tokens_);
  }

  grpc::Status Add(const std::vector<v1::AddBodyRequest>& reqs, const std::string& token = "adm") {
    v1::Body body;
    return AddBodyRaw(*scenes_, reqs, &body, token);
  }
  grpc::Status Move(const std::string& body, const v1::Pose& pose,
                    const std::string& token = "adm") {
    v1::MoveBodyRequest req;
    req.set_scene_id("default");
    req.set_body_id(body);
    *req.mutable_pose() = pose;
    v1::MoveBodyResponse resp;
    auto ctx = Ctx(token);
    return scenes_->MoveBody(ctx.get(), req, &resp);
  }
  grpc::Status Remove(const std::string& scene, const std::string& body,
                      const std::string& token = "adm") {
    v1::RemoveBodyRequest req;
    req.set_scene_id(scene);
    req.set_body_id(body);
    v1::RemoveBodyResponse resp;
    auto ctx = Ctx(token);
    return scenes_->RemoveBody(ctx.get(), req, &resp);
  }
  grpc::Status Create(const v1::CreateSceneRequest& req, const std::string& token = "adm") {
    v1::SceneSummary resp;
    auto ctx = Ctx(token);
    return scenes_->CreateScene(ctx.get(), req, &resp);
  }
  grpc::Status CreateId(const std::string& scene) {
    v1::CreateSceneRequest req;
    req.set_scene_id(scene);
    return Create(req);
  }
  grpc::Status Delete(const std::string& scene, const std::string& token = "adm") {
    v1::DeleteSceneRequest req;
    req.set_scene_id(scene);
    v1::DeleteSceneResponse resp;
    auto ctx = Ctx(token);
    return scenes_->DeleteScene(ctx.get(), req, &resp);
  }
  grpc::Status Hello(const v1::Hello& hello, const std::string& token = "adm") {
    Session s(*haptics_, token);
    return s.Open(hello);
  }
  grpc::Status MeshFile(const fs::path& file, v1::MeshFormat format) {
    v1::AddBodyRequest head;
    head.mutable_header()->set_scene_id("default");
    head.mutable_header()->set_format(format);
    return Add({head, Chunk(ReadFile(file))});
  }

  /// Runs every row: exact code and message, and an unchanged server.
  void Check(const std::vector<Row>& rows) {
    for (const Row& r : rows) {
      SCOPED_TRACE(r.rpc + ": " + r.what);
      const std::string before = Snapshot(*scenes_);
      const grpc::Status s = r.request();
      EXPECT_STREQ(wire::StatusCodeName(s.error_code()), wire::StatusCodeName(r.code))
          << s.error_message();
      EXPECT_EQ(s.error_message(), r.message);
      EXPECT_TRUE(Snapshot(*scenes_) == before) << "the rejected request changed the server";
      PrintTableRow({r.rpc, r.what}, std::string(wire::StatusCodeName(r.code)) + ": " + r.message);
    }
  }

  fs::path tokens_;
  std::unique_ptr<ServerHarness> h_;
  std::unique_ptr<v1::SceneService::Stub> scenes_;
  std::unique_ptr<v1::HapticService::Stub> haptics_;
};

using grpc::StatusCode;

TEST_F(BadInputTable, SceneServiceRequests) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  auto shape = [](const v1::Pose& p, const std::string& id = "") {
    return ShapeHeader("default", "box", id, p);
  };
  auto inline_mesh = [](std::vector<double> v, std::vector<std::uint32_t> t) {
    v1::AddBodyRequest r;
    r.mutable_header()->set_scene_id("default");
    auto* m = r.mutable_header()->mutable_inline_mesh();
    for (double x : v) m->add_vertices(x);
    for (auto i : t) m->add_triangles(i);
    return r;
  };
  v1::AddBodyRequest obj;
  obj.mutable_header()->set_scene_id("default");
  obj.mutable_header()->set_format(v1::MESH_FORMAT_OBJ);
  const std::vector<double> tri = {0, 0, 0, 1, 0, 0, 0, 1, 0};
  std::vector<Row> rows;
  rows.push_back({"AddBody", "NaN position", [&] { return Add({shape(MakePose(nan, 0, 0))}); },
                  StatusCode::INVALID_ARGUMENT,
                  "header.spec.pose.position.x: must be a finite number, got nan"});
  rows.push_back({"AddBody", "quaternion not unit",
                  [&] { return Add({shape(MakePose(0, 0, 0, 2, 0, 0, 0))}); },
                  StatusCode::INVALID_ARGUMENT,
                  "header.spec.pose.orientation: quaternion norm 2.000000 is not 1 (a unit "
                  "quaternion w, x, y, z is required)"});
  rows.push_back({"AddBody", "negative stiffness",
                  [&] {
                    auto r = shape(MakePose(0, 0, 0));
                    r.mutable_header()->mutable_spec()->mutable_material()->set_stiffness(-1);
                    return Add({r});
                  },
                  StatusCode::INVALID_ARGUMENT,
                  "header.spec.material.stiffness: must be in [0, 1e+07] N/m, got -1"});
  rows.push_back({"AddBody", "stiffness over its range",
                  [&] {
                    auto r = shape(MakePose(0, 0, 0));
                    r.mutable_header()->mutable_spec()->mutable_material()->set_stiffness(1e9);
                    return Add({r});
                  },
                  StatusCode::INVALID_ARGUMENT,
                  "header.spec.material.stiffness: must be in [0, 1e+07] N/m, got 1e+09"});
  rows.push_back(
      {"AddBody", "dynamic friction above static",
       [&] {
         auto r = shape(MakePose(0, 0, 0));
         auto* m = r.mutable_header()->mutable_spec()->mutable_material();
         m->set_static_friction(0.5);
         m->set_dynamic_friction(0.8);
         return Add({r});
       },
       StatusCode::INVALID_ARGUMENT,
       "header.spec.material.dynamic_friction: must not exceed static_friction (0.8 > 0.5)"});
  rows.push_back({"AddBody", "position beyond 10 km",
                  [&] { return Add({shape(MakePose(2e4, 0, 0))}); }, StatusCode::INVALID_ARGUMENT,
                  "header.spec.pose.position.x: must be in [-10000, 10000] m, got 20000"});
  rows.push_back(
      {"AddBody", "shape size out of range",
       [&] { return Add({ShapeHeader("default", "sphere:1e-300", "", MakePose(0, 0, 0))}); },
       StatusCode::INVALID_ARGUMENT,
       "header.shape: shape spec 'sphere:1e-300': radius must be in [1e-06, 10000] m, got "
       "1e-300"});
  rows.push_back(
      {"AddBody", "whitespace in a shape spec",
       [&] { return Add({ShapeHeader("default", "stick ", "", MakePose(0, 0, 0))}); },
       StatusCode::INVALID_ARGUMENT,
       "header.shape: shape spec 'stick ': whitespace is not allowed in a shape spec (at byte "
       "5)"});
  rows.push_back(
      {"AddBody", "partial shape parameters",
       [&] { return Add({ShapeHeader("default", "box:0.1", "", MakePose(0, 0, 0))}); },
       StatusCode::INVALID_ARGUMENT,
       "header.shape: shape spec 'box:0.1': 'box' needs all of hx,hy,hz or none (for the "
       "defaults); missing hy,hz"});
  rows.push_back({"AddBody", "bad body id", [&] { return Add({shape(MakePose(0, 0, 0), "a b")}); },
                  StatusCode::INVALID_ARGUMENT,
                  "header.spec.body_id: may only contain A-Z a-z 0-9 _ . - (got 'a b')"});
  rows.push_back({"AddBody", "duplicate body id",
                  [&] { return Add({shape(MakePose(0, 0, 0), "keep")}); },
                  StatusCode::ALREADY_EXISTS,
                  "header.spec.body_id: scene 'default' already has a body 'keep'"});
  rows.push_back({"AddBody", "unknown scene",
                  [&] { return Add({ShapeHeader("nope", "box", "", MakePose(0, 0, 0))}); },
                  StatusCode::NOT_FOUND, "scene_id: no scene 'nope'"});
  rows.push_back({"AddBody", "unknown shape",
                  [&] { return Add({ShapeHeader("default", "blob", "", MakePose(0, 0, 0))}); },
                  StatusCode::INVALID_ARGUMENT,
                  "header.shape: shape spec 'blob': unknown shape 'blob'; known shapes: box, "
                  "sphere, capsule, cylinder, stick, torus, torusknot, plate, spoon, cup, hammer"});
  rows.push_back({"AddBody", "inline index out of range",
                  [&] {
                    return Add({inline_mesh(tri, {0, 1, 3})});
                  },
                  StatusCode::INVALID_ARGUMENT,
                  "header.inline_mesh.triangles[2]: vertex index 3 is out of range (3 vertices)"});
  rows.push_back({"AddBody", "inline NaN vertex",
                  [&] {
                    return Add({inline_mesh({0, 0, 0, nan, 0, 0, 0, 1, 0}, {0, 1, 2})});
                  },
                  StatusCode::INVALID_ARGUMENT,
                  "header.inline_mesh.vertices[3]: must be a finite number, got nan"});
  rows.push_back({"AddBody", "inline vertex beyond 10 km",
                  [&] {
                    return Add({inline_mesh({0, 0, 0, 1e300, 0, 0, 0, 1, 0}, {0, 1, 2})});
                  },
                  StatusCode::INVALID_ARGUMENT,
                  "header.inline_mesh.vertices[3]: must be in [-10000, 10000] m, got 1e+300"});
  rows.push_back({"AddBody", "inline mesh of no size",
                  [&] {
                    return Add({inline_mesh({0, 0, 0, 1e-9, 0, 0, 0, 1e-9, 0}, {0, 1, 2})});
                  },
                  StatusCode::INVALID_ARGUMENT,
                  "header.inline_mesh: bounding-box diagonal 1.41421e-09 m is below the minimum "
                  "of 1e-06 m"});
  rows.push_back(
      {"AddBody", "too many triangles",
       [&] { return Add({ShapeHeader("default", "sphere:0.05,3", "", MakePose(0, 0, 0))}); },
       StatusCode::RESOURCE_EXHAUSTED,
       "header.shape: 1280 triangles exceed the server limit of 500"});
  // Counted before anything is built: 12e12 triangles would take hours.
  rows.push_back({"AddBody", "shape resolution far too high",
                  [&] {
                    return Add(
                        {ShapeHeader("default", "box:0.1,0.1,0.1,1000000", "", MakePose(0, 0, 0))});
                  },
                  StatusCode::RESOURCE_EXHAUSTED,
                  "header.shape: 12000000000000 triangles exceed the server limit of 500"});
  rows.push_back({"AddBody", "mesh bytes over the limit",
                  [&] {
                    return Add({obj, Chunk(std::string(3000, ' ')), Chunk(std::string(3000, ' '))});
                  },
                  StatusCode::RESOURCE_EXHAUSTED,
                  "chunk: the mesh exceeds the server limit of 4096 bytes"});
  rows.push_back({"AddBody", "header but no mesh bytes", [&] { return Add({obj}); },
                  StatusCode::INVALID_ARGUMENT, "chunk: no mesh bytes were sent"});
  rows.push_back({"AddBody", "chunk before header", [&] { return Add({Chunk("v 0 0 0\n")}); },
                  StatusCode::INVALID_ARGUMENT, "header: must be the first message"});
  rows.push_back({"AddBody", "empty stream", [&] { return Add({}); }, StatusCode::INVALID_ARGUMENT,
                  "header: missing (the stream was empty)"});
  rows.push_back({"MoveBody", "NaN position", [&] { return Move("keep", MakePose(nan, 0, 0)); },
                  StatusCode::INVALID_ARGUMENT,
                  "pose.position.x: must be a finite number, got nan"});
  rows.push_back({"MoveBody", "quaternion not unit",
                  [&] { return Move("keep", MakePose(0, 0, 0, 0.5, 0, 0, 0)); },
                  StatusCode::INVALID_ARGUMENT,
                  "pose.orientation: quaternion norm 0.500000 is not 1 (a unit quaternion w, x, y, "
                  "z is required)"});
  rows.push_back({"MoveBody", "unknown body", [&] { return Move("ghost", MakePose(0, 0, 0)); },
                  StatusCode::NOT_FOUND, "body_id: scene 'default' has no body 'ghost'"});
  rows.push_back({"RemoveBody", "unknown body", [&] { return Remove("default", "ghost"); },
                  StatusCode::NOT_FOUND, "body_id: scene 'default' has no body 'ghost'"});
  rows.push_back({"RemoveBody", "unknown scene", [&] { return Remove("nope", "keep"); },
                  StatusCode::NOT_FOUND, "scene_id: no scene 'nope'"});
  rows.push_back({"CreateScene", "bad id", [&] { return CreateId("has space"); },
                  StatusCode::INVALID_ARGUMENT,
                  "scene_id: may only contain A-Z a-z 0-9 _ . - (got 'has space')"});
  rows.push_back({"CreateScene", "gravity out of range",
                  [&] {
                    v1::CreateSceneRequest req;
                    req.set_scene_id("new");
                    req.mutable_config()->mutable_gravity()->set_z(-1000);
                    return Create(req);
                  },
                  StatusCode::INVALID_ARGUMENT,
                  "config.gravity.z: must be in [-100, 100] m/s^2, got -1000"});
  rows.push_back({"CreateScene", "bad probe shape",
                  [&] {
                    v1::CreateSceneRequest req;
                    req.set_scene_id("new");
                    req.mutable_config()->set_probe_shape("stick ");
                    return Create(req);
                  },
                  StatusCode::INVALID_ARGUMENT,
                  "config.probe_shape: shape spec 'stick ': whitespace is not allowed in a shape "
                  "spec (at byte 5)"});
  rows.push_back({"CreateScene", "existing id", [&] { return CreateId("lab"); },
                  StatusCode::ALREADY_EXISTS, "scene_id: scene 'lab' exists"});
  rows.push_back({"CreateScene", "over the scene limit", [&] { return CreateId("third"); },
                  StatusCode::RESOURCE_EXHAUSTED,
                  "scene_id: the server already hosts 2 scenes (limit 2)"});
  rows.push_back({"DeleteScene", "unknown scene", [&] { return Delete("nope"); },
                  StatusCode::NOT_FOUND, "scene_id: no scene 'nope'"});
  rows.push_back({"any RPC", "no token", [&] { return Remove("default", "keep", ""); },
                  StatusCode::UNAUTHENTICATED,
                  "missing or unknown token (send metadata 'authorization: Bearer TOKEN')"});
  rows.push_back({"any RPC", "unknown token", [&] { return Remove("default", "keep", "wrong"); },
                  StatusCode::UNAUTHENTICATED,
                  "missing or unknown token (send metadata 'authorization: Bearer TOKEN')"});
  rows.push_back({"RemoveBody", "observe-only token",
                  [&] { return Remove("default", "keep", "obs"); }, StatusCode::PERMISSION_DENIED,
                  "token 'watcher' lacks role 'inject' on scene 'default'"});
  rows.push_back(
      {"AddBody", "observe-only token", [&] { return Add({shape(MakePose(0, 0, 0))}, "obs"); },
       StatusCode::PERMISSION_DENIED, "token 'watcher' lacks role 'inject' on scene 'default'"});
  rows.push_back({"any RPC", "token without `Bearer `",
                  [&] {
                    grpc::ClientContext ctx;
                    ctx.AddMetadata("authorization", "adm");
                    v1::ListScenesResponse list;
                    return scenes_->ListScenes(&ctx, {}, &list);
                  },
                  StatusCode::UNAUTHENTICATED,
                  "the authorization metadata must be 'Bearer TOKEN' (the 'Bearer ' prefix is "
                  "missing)"});
  rows.push_back({"GetScene",
                  "a 1 MB scene id (any id field: checked before it is looked up or echoed)",
                  [&] {
                    v1::GetSceneRequest req;
                    req.set_scene_id(std::string(1 << 20, 'x'));
                    v1::Scene scene;
                    auto ctx = Ctx("adm");
                    return scenes_->GetScene(ctx.get(), req, &scene);
                  },
                  StatusCode::INVALID_ARGUMENT, "scene_id: is longer than 64 characters"});
  rows.push_back({"CreateScene",
                  "control characters in the id (escaped, cut at 64 bytes with the length)",
                  [&] { return CreateId("a\nb\x1b[2J"); }, StatusCode::INVALID_ARGUMENT,
                  "scene_id: may only contain A-Z a-z 0-9 _ . - (got 'a\\nb\\x1b[2J')"});
  rows.push_back({"MoveBody", "velocity out of range",
                  [&] {
                    v1::MoveBodyRequest req;
                    req.set_scene_id("default");
                    req.set_body_id("keep");
                    req.mutable_velocity()->mutable_linear()->set_x(1000);
                    v1::MoveBodyResponse resp;
                    auto ctx = Ctx("adm");
                    return scenes_->MoveBody(ctx.get(), req, &resp);
                  },
                  StatusCode::INVALID_ARGUMENT,
                  "velocity.linear.x: must be in [-100, 100] m/s, got 1000"});
  const std::string tet =
      "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
  rows.push_back({"AddBody", "more bytes than `total_bytes`",
                  [&] {
                    v1::AddBodyRequest h = obj;
                    h.mutable_header()->set_total_bytes(10);
                    return Add({h, Chunk(tet)});
                  },
                  StatusCode::INVALID_ARGUMENT,
                  "chunk: " + std::to_string(tet.size()) +
                      " bytes received, more than header.total_bytes 10"});
  rows.push_back({"AddBody", "fewer bytes than `total_bytes`",
                  [&] {
                    v1::AddBodyRequest h = obj;
                    h.mutable_header()->set_total_bytes(tet.size() + 5);
                    return Add({h, Chunk(tet)});
                  },
                  StatusCode::INVALID_ARGUMENT,
                  "chunk: " + std::to_string(tet.size()) +
                      " bytes received, header.total_bytes said " +
                      std::to_string(tet.size() + 5)});
  Check(rows);
}

TEST_F(BadInputTable, CoupleHello) {
  std::vector<Row> rows;
  auto with = [](const std::function<void(v1::Hello*)>& f) {
    v1::Hello h = Session::DefaultHello();
    f(&h);
    return h;
  };
  rows.push_back({"Couple hello", "protocol version 2",
                  [&] { return Hello(with([](v1::Hello* h) { h->set_protocol_version(2); })); },
                  StatusCode::FAILED_PRECONDITION,
                  "hello.protocol_version: this server speaks version 1, the client asked for 2"});
  rows.push_back(
      {"Couple hello", "no PD mode",
       [&] { return Hello(with([](v1::Hello* h) { h->set_mode(v1::PD_MODE_UNSPECIFIED); })); },
       StatusCode::INVALID_ARGUMENT,
       "hello.mode: say which PD mode (PD_MODE_NONE, PD_MODE_PDT, PD_MODE_PDG)"});
  rows.push_back({"Couple hello", "unknown scene",
                  [&] { return Hello(with([](v1::Hello* h) { h->set_scene_id("nowhere"); })); },
                  StatusCode::NOT_FOUND, "hello.scene_id: no scene 'nowhere'"});
  rows.push_back({"Couple hello", "no probe",
                  [&] { return Hello(with([](v1::Hello* h) { h->clear_probe_shape(); })); },
                  StatusCode::INVALID_ARGUMENT,
                  "hello.probe: give probe_body_id, probe_mesh or probe_shape"});
  rows.push_back(
      {"Couple hello", "bad probe shape",
       [&] { return Hello(with([](v1::Hello* h) { h->set_probe_shape("sphere:-1"); })); },
       StatusCode::INVALID_ARGUMENT,
       "hello.probe_shape: shape spec 'sphere:-1': radius must be in [1e-06, 10000] m, got -1"});
  rows.push_back({"Couple hello", "unknown probe body",
                  [&] { return Hello(with([](v1::Hello* h) { h->set_probe_body_id("ghost"); })); },
                  StatusCode::NOT_FOUND,
                  "hello.probe_body_id: scene 'default' has no body 'ghost'"});
  rows.push_back(
      {"Couple hello", "NaN probe stiffness",
       [&] {
         return Hello(
             with([](v1::Hello* h) { h->mutable_material()->set_stiffness(std::nan("")); }));
       },
       StatusCode::INVALID_ARGUMENT, "hello.material.stiffness: must be a finite number, got nan"});
  rows.push_back({"Couple hello", "rate out of range",
                  [&] { return Hello(with([](v1::Hello* h) { h->set_max_rate_hz(1e6); })); },
                  StatusCode::INVALID_ARGUMENT,
                  "hello.max_rate_hz: must be in [0, 100000] Hz, got 1e+06"});
  rows.push_back(
      {"Couple hello", "observe-only token", [&] { return Hello(Session::DefaultHello(), "obs"); },
       StatusCode::PERMISSION_DENIED, "token 'watcher' lacks role 'device' on scene 'default'"});
  Check(rows);
  EXPECT_TRUE(WaitUntil([&] { return h_->server().counts().sessions == 0; }));
}

TEST_F(BadInputTable, BadMeshFilesUploaded) {
  // Every file of the bad-input corpus with a wire format (unknown.xyz has
  // none: its row is the CLI's), uploaded as OBJ/STL/PLY/OFF bytes.
  const fs::path dir = fs::path(HAPTICPD_TESTDATA_DIR) / "bad";
  const std::vector<std::pair<std::string, std::string>> files = {
      {"degenerate_only.obj",
       "chunk: no non-degenerate triangles (the reader skipped all 2 face(s): repeated or invalid "
       "vertex indices)"},
      {"empty.obj", "chunk: no mesh bytes were sent"},
      {"garbage.ply", "chunk: not a valid PLY: missing the 'ply' magic line"},
      {"garbage.stl",
       "chunk: not a valid STL: binary header says 1303066130 triangles (65153306584 bytes) but "
       "the file has 600 bytes, and it is not ASCII STL"},
      {"index_out_of_range.obj", "chunk: face 0 refers to vertex 8, out of range [0, 3)"},
      {"infinite_vertex.off", "chunk: line 4: vertex 1 has a non-finite coordinate (1e400)"},
      {"nan_vertex.obj", "chunk: line 3: vertex has a non-finite coordinate (v nan 1 0)"},
      {"no_faces.obj", "chunk: no faces found"},
      {"truncated.off", "chunk: line 5: vertex 2 has 2 numbers, expected 3"},
      {"truncated.ply",
       "chunk: truncated after line 12: the header promises 8 vertex elements, the file holds 3"},
      {"truncated.stl",
       "chunk: not a valid STL: binary header says 1000 triangles (50084 bytes) but the file has "
       "184 bytes, and it is not ASCII STL"},
  };
  const std::map<std::string, v1::MeshFormat> formats = {{".obj", v1::MESH_FORMAT_OBJ},
                                                         {".off", v1::MESH_FORMAT_OFF},
                                                         {".stl", v1::MESH_FORMAT_STL},
                                                         {".ply", v1::MESH_FORMAT_PLY}};
  std::size_t with_format = 0;
  for (const auto& e : fs::directory_iterator(dir)) {
    with_format += formats.count(e.path().extension().string());
  }
  ASSERT_EQ(files.size(), with_format) << "a new file in tests/data/bad needs a row here";
  std::vector<Row> rows;
  for (const auto& [name, message] : files) {
    const fs::path f = dir / name;
    rows.push_back(
        {"AddBody (mesh bytes)", name,
         [this, f, format = formats.at(f.extension().string())] { return MeshFile(f, format); },
         StatusCode::INVALID_ARGUMENT, message});
  }
  Check(rows);
}

TEST_F(BadInputTable, FuzzReproducersUploaded) {
  // Inputs the fuzzers found (tests/fuzz/corpus): before the pre-scans in
  // pd/mesh.cc and our own OFF/PLY readers (pd/mesh_readers.cc) they aborted
  // the server (an OpenMesh assert), hung a worker forever or allocated
  // gigabytes.
  const fs::path dir = fs::path(HAPTICPD_FUZZ_CORPUS_DIR);
  struct Repro {
    std::string what;
    std::string file;
    v1::MeshFormat format;
    std::string message;
  };
  const std::vector<Repro> repros = {
      {"OBJ face corner without an index (fuzzer: aborted the server)",
       "mesh_obj/crash-openmesh-face-assert.obj", v1::MESH_FORMAT_OBJ,
       "chunk: line 1: face corner '/?/' does not start with a vertex index"},
      {"PLY header line OpenMesh does not know (fuzzer: hung a worker forever)",
       "mesh_ply/timeout-no-end-header.ply", v1::MESH_FORMAT_PLY,
       "chunk: not a valid PLY: line 9: unknown header keyword '1nd_header'"},
      {"PLY bad format line (fuzzer: hung a worker forever)",
       "mesh_ply/timeout-bad-format-line.ply", v1::MESH_FORMAT_PLY,
       "chunk: not a valid PLY: line 2: expected 'format "
       "ascii|binary_little_endian|binary_big_endian 1.0'"},
      {"PLY unknown property type (fuzzer: hung a worker forever)",
       "mesh_ply/timeout-bad-property-type.ply", v1::MESH_FORMAT_PLY,
       "chunk: not a valid PLY: line 8: expected 'property TYPE NAME' or 'property list TYPE TYPE "
       "NAME'"},
      {"PLY element count larger than the file (allocated gigabytes)",
       "mesh_ply/oom-huge-count.ply", v1::MESH_FORMAT_PLY,
       "chunk: not a valid PLY: element vertex count 4000000000 is more than a file of 169 bytes "
       "can hold"},
      {"PLY malformed element line (fuzzer: allocated gigabytes)",
       "mesh_ply/oom-bad-element-line.ply", v1::MESH_FORMAT_PLY,
       "chunk: not a valid PLY: line 3: expected 'element NAME COUNT'"},
      {"OFF variant COFF with a huge vertex count (fuzzer: allocated gigabytes)",
       "mesh_off/oom-coff-huge-count.off", v1::MESH_FORMAT_OFF,
       "chunk: line 1: OFF variant 'COFF' is not supported (plain OFF only)"},
      {"OFF variant COFF with a huge face corner count (fuzzer: allocated gigabytes)",
       "mesh_off/oom-coff-face-corner-count.off", v1::MESH_FORMAT_OFF,
       "chunk: line 1: OFF variant 'COFF' is not supported (plain OFF only)"},
      {"OFF vertex line with four numbers (fuzzer: allocated gigabytes)",
       "mesh_off/oom-off-vertex-line-with-4-numbers.off", v1::MESH_FORMAT_OFF,
       "chunk: line 5: vertex 2 has 4 numbers, expected 3"},
      {"ASCII PLY body that does not match its header (fuzzer: allocated gigabytes)",
       "mesh_ply/oom-ply-ascii-body-misaligned.ply", v1::MESH_FORMAT_PLY,
       "chunk: line 14: vertex 4 has 4 values, expected 3"},
      {"unknown OFF variant with a huge count (fuzzer: allocated gigabytes)",
       "mesh_off/oom-unknown-variant-huge-count.off", v1::MESH_FORMAT_OFF,
       "chunk: line 1: OFF variant 'OFF444444444FF?\?\?\?\?' is not supported (plain OFF "
       "only)"},
  };
  std::vector<Row> rows;
  for (const Repro& r : repros) {
    rows.push_back({"AddBody (mesh bytes)", r.what,
                    [this, f = dir / r.file, format = r.format] { return MeshFile(f, format); },
                    StatusCode::INVALID_ARGUMENT, r.message});
  }
  Check(rows);
}

}  // namespace
}  // namespace hapticpd::testing
