// Routing for several processes behind a balancer (docker/README.md "Scaling
// out"): the x-hapticpd-scene header of every scene-scoped call must name the
// scene of its request body (INVALID_ARGUMENT naming both, nothing changed;
// streams checked at their first message); calls without it are served as
// before. The shard map (server/shard_map.h): its format, its errors naming
// the line, the longest prefix; a sharded server creates, restores and
// preloads only its own scenes and has no "default".
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "proto/wire/routing.h"
#include "server/shard_map.h"
#include "tests/server/server_harness.h"
#include "tests/test_util.h"

namespace hapticpd::testing::routing_tests {
namespace {

namespace fs = std::filesystem;

/// The test deadline and `x-hapticpd-scene: scene`.
std::unique_ptr<grpc::ClientContext> Routed(const std::string& scene) {
  auto ctx = Ctx();
  wire::AddSceneHeader(ctx.get(), scene);
  return ctx;
}

void ExpectNamesBoth(const grpc::Status& s, const std::string& header, const std::string& body) {
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_NE(s.error_message().find("x-hapticpd-scene"), std::string::npos) << s.error_message();
  EXPECT_NE(s.error_message().find("'" + header + "'"), std::string::npos) << s.error_message();
  EXPECT_NE(s.error_message().find("'" + body + "'"), std::string::npos) << s.error_message();
}

class SceneHeader : public ::testing::TestWithParam<Transport> {
 protected:
  void SetUp() override {
    ASSERT_TRUE(CreateScene(*scenes, "a").ok());
    ASSERT_TRUE(CreateScene(*scenes, "b").ok());
    ASSERT_TRUE(AddShape(*scenes, "a", "box:0.1,0.1,0.05", "box", MakePose(0, 0, 0), true).ok());
  }
  std::string SceneBytes(const std::string& id) {
    v1::GetSceneRequest req;
    req.set_scene_id(id);
    req.set_include_meshes(true);
    v1::Scene out;
    auto ctx = Ctx();
    EXPECT_TRUE(scenes->GetScene(ctx.get(), req, &out).ok());
    return out.SerializeAsString();
  }
  ServerHarness h{GetParam()};
  std::unique_ptr<v1::SceneService::Stub> scenes = h.Scenes();
};

TEST_P(SceneHeader, UnaryCallsForAnotherSceneAreRefusedAndChangeNothing) {
  const std::string a = SceneBytes("a"), b = SceneBytes("b");
  {
    v1::CreateSceneRequest req;
    req.set_scene_id("c");
    v1::SceneSummary out;
    ExpectNamesBoth(scenes->CreateScene(Routed("a").get(), req, &out), "a", "c");
  }
  {
    v1::GetSceneRequest req;
    req.set_scene_id("a");
    v1::Scene out;
    ExpectNamesBoth(scenes->GetScene(Routed("b").get(), req, &out), "b", "a");
  }
  {
    v1::MoveBodyRequest req;
    req.set_scene_id("a");
    req.set_body_id("box");
    *req.mutable_pose() = MakePose(0.01, 0, 0);
    v1::MoveBodyResponse out;
    ExpectNamesBoth(scenes->MoveBody(Routed("b").get(), req, &out), "b", "a");
  }
  {
    v1::RemoveBodyRequest req;
    req.set_scene_id("a");
    req.set_body_id("box");
    v1::RemoveBodyResponse out;
    ExpectNamesBoth(scenes->RemoveBody(Routed("b").get(), req, &out), "b", "a");
  }
  {
    v1::DeleteSceneRequest req;
    req.set_scene_id("a");
    v1::DeleteSceneResponse out;
    ExpectNamesBoth(scenes->DeleteScene(Routed("b").get(), req, &out), "b", "a");
  }
  {
    v1::Body out;
    auto ctx = Routed("b");
    auto w = scenes->AddBody(ctx.get(), &out);
    w->Write(ShapeHeader("a", "sphere:0.01,1", "ball", MakePose(0, 0, 0.2)));
    w->WritesDone();
    ExpectNamesBoth(w->Finish(), "b", "a");
  }
  EXPECT_EQ(SceneBytes("a"), a);
  EXPECT_EQ(SceneBytes("b"), b);
  v1::GetSceneRequest req;
  req.set_scene_id("c");
  v1::Scene out;
  EXPECT_EQ(scenes->GetScene(Ctx().get(), req, &out).error_code(), grpc::StatusCode::NOT_FOUND);
}

TEST_P(SceneHeader, StreamsCheckTheirFirstMessage) {
  {
    v1::WatchRequest req;
    req.set_scene_id("a");
    auto ctx = Routed("b");
    auto reader = scenes->Watch(ctx.get(), req);
    v1::SceneEvent ev;
    if (reader->Read(&ev)) {
      ADD_FAILURE() << "Watch of 'a' routed for 'b' sent an event";
      ctx->TryCancel();
    }
    ExpectNamesBoth(reader->Finish(), "b", "a");
  }
  auto haptics = h.Haptics();
  auto ctx = Routed("b");
  auto stream = haptics->Couple(ctx.get());
  v1::CoupleRequest hello;
  *hello.mutable_hello() = Session::DefaultHello("a");
  stream->Write(hello);
  v1::CoupleResponse resp;
  if (stream->Read(&resp)) {
    ADD_FAILURE() << "Couple on 'a' routed for 'b' was welcomed";
    ctx->TryCancel();
  }
  const grpc::Status s = stream->Finish();
  ExpectNamesBoth(s, "b", "a");
  EXPECT_EQ(s.error_message().rfind("x-hapticpd-scene", 0), 0u)
      << "the header is not a field of the hello: " << s.error_message();
}

TEST_P(SceneHeader, MatchingOrAbsentHeadersAreServed) {
  for (const bool routed : {true, false}) {
    SCOPED_TRACE(routed ? "header" : "no header");
    const std::string id = routed ? "routed" : "plain";
    auto ctx = [&] { return routed ? Routed(id) : Ctx(); };
    v1::CreateSceneRequest create;
    create.set_scene_id(id);
    v1::SceneSummary summary;
    ASSERT_TRUE(scenes->CreateScene(ctx().get(), create, &summary).ok());
    v1::Body body;
    auto upload = ctx();
    auto w = scenes->AddBody(upload.get(), &body);
    w->Write(ShapeHeader(id, "box:0.1,0.1,0.05", "box", MakePose(0, 0, 0), true));
    w->WritesDone();
    ASSERT_TRUE(w->Finish().ok());
    v1::MoveBodyRequest move;
    move.set_scene_id(id);
    move.set_body_id("box");
    *move.mutable_pose() = MakePose(0.01, 0, 0);
    v1::MoveBodyResponse moved;
    EXPECT_TRUE(scenes->MoveBody(ctx().get(), move, &moved).ok());
    v1::GetSceneRequest get;
    get.set_scene_id(id);
    v1::Scene scene;
    ASSERT_TRUE(scenes->GetScene(ctx().get(), get, &scene).ok());
    EXPECT_EQ(scene.bodies_size(), 1);
    {
      v1::WatchRequest req;
      req.set_scene_id(id);
      auto wctx = ctx();
      auto reader = scenes->Watch(wctx.get(), req);
      v1::SceneEvent ev;
      EXPECT_TRUE(reader->Read(&ev));
      wctx->TryCancel();
      reader->Finish();
    }
    {
      auto haptics = h.Haptics();
      auto cctx = ctx();
      auto stream = haptics->Couple(cctx.get());
      v1::CoupleRequest hello;
      *hello.mutable_hello() = Session::DefaultHello(id);
      stream->Write(hello);
      v1::CoupleResponse resp;
      ASSERT_TRUE(stream->Read(&resp));
      EXPECT_TRUE(resp.has_welcome());
      stream->WritesDone();
      while (stream->Read(&resp)) {
      }
      EXPECT_TRUE(stream->Finish().ok());
    }
    v1::DeleteSceneRequest del;
    del.set_scene_id(id);
    v1::DeleteSceneResponse deleted;
    EXPECT_TRUE(scenes->DeleteScene(ctx().get(), del, &deleted).ok());
  }
}

TEST_P(SceneHeader, TwoHeadersAreRefused) {
  auto ctx = Routed("a");
  wire::AddSceneHeader(ctx.get(), "a");
  v1::GetSceneRequest req;
  req.set_scene_id("a");
  v1::Scene out;
  const grpc::Status s = scenes->GetScene(ctx.get(), req, &out);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_NE(s.error_message().find("more than once"), std::string::npos) << s.error_message();
}

INSTANTIATE_TEST_SUITE_P(Transports, SceneHeader,
                         ::testing::Values(Transport::kInProcess, Transport::kTcp), TransportName);

// --- the shard map

TEST(ShardMapFile, LongestPrefixWinsWhateverTheOrder) {
  const server::ShardMap m = server::ShardMap::Parse(
      "# comment\n\nlab- s1\nlab-big-x\ts3\r\n  lab-big   s2  \ndemo s2\n", "m.txt");
  EXPECT_EQ(m.Owner("lab-1"), "s1");
  EXPECT_EQ(m.Owner("lab-big1"), "s2");
  EXPECT_EQ(m.Owner("lab-big-x1"), "s3");
  EXPECT_EQ(m.Owner("demo"), "s2");
  EXPECT_EQ(m.Owner("demo2"), "s2");
  EXPECT_EQ(m.Owner("lab"), "");
  EXPECT_EQ(m.Owner("other"), "");
  EXPECT_EQ(m.shards(), (std::vector<std::string>{"s1", "s3", "s2"}));
  EXPECT_TRUE(m.HasShard("s3"));
  EXPECT_FALSE(m.HasShard("s4"));
}

TEST(ShardMapFile, BadLinesAreNamed) {
  struct Case {
    const char* text;
    const char* expect;
  };
  for (const Case& c : {
           Case{"a s1\nb\n", "m.txt:2: expected 'PREFIX SHARD' (two fields), got 1"},
           Case{"a s1 # owner\n", "m.txt:1: expected 'PREFIX SHARD' (two fields), got 4"},
           Case{"a s1\n\nl*b s2\n", "m.txt:3: prefix 'l*b' holds '*'"},
           Case{"a s/1\n", "m.txt:1: shard 's/1' holds '/'"},
           Case{"a s1\n# x\na s2\n", "m.txt:3: prefix 'a' is already mapped on line 1"},
           Case{"# nothing\n\n", "m.txt: maps no prefix to a shard"},
       }) {
    SCOPED_TRACE(c.text);
    try {
      server::ShardMap::Parse(c.text, "m.txt");
      ADD_FAILURE() << "accepted";
    } catch (const server::ShardMapError& e) {
      EXPECT_EQ(std::string(e.what()).rfind(c.expect, 0), 0u) << e.what();
    }
  }
  try {
    server::ShardMap::Load("/nonexistent/shard-map.txt");
    ADD_FAILURE() << "accepted";
  } catch (const server::ShardMapError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/shard-map.txt"), std::string::npos);
  }
}

class Folder : public ScopedTempDir {
 public:
  Folder() : ScopedTempDir("routing") {
    fs::create_directories(path());
    std::ofstream(path() / "shard-map.txt") << "# test map\nlab- s1\nlab-b s2\nkeep s1\n";
  }
  std::string Map() const { return (path() / "shard-map.txt").string(); }
};

server::ServerOptions Sharded(const Folder& f, const std::string& shard) {
  server::ServerOptions o;
  o.shard_map_file = f.Map();
  o.shard = shard;
  return o;
}

TEST(Sharded, CreatesOnlyItsOwnScenesAndHasNoDefault) {
  Folder f;
  ServerHarness h(Transport::kInProcess, Sharded(f, "s1"));
  auto scenes = h.Scenes();
  EXPECT_TRUE(SceneIds(*scenes).empty());
  EXPECT_TRUE(CreateScene(*scenes, "lab-1").ok());
  EXPECT_TRUE(CreateScene(*scenes, "keep").ok());
  const grpc::Status other = CreateScene(*scenes, "lab-b7");
  EXPECT_EQ(other.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << other.error_message();
  EXPECT_NE(other.error_message().find("belongs to shard 's2'"), std::string::npos)
      << other.error_message();
  EXPECT_NE(other.error_message().find(f.Map()), std::string::npos) << other.error_message();
  const grpc::Status nobody = CreateScene(*scenes, "zzz");
  EXPECT_EQ(nobody.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << nobody.error_message();
  EXPECT_NE(nobody.error_message().find("no shard owns scene 'zzz'"), std::string::npos)
      << nobody.error_message();
  EXPECT_EQ(SceneIds(*scenes), (std::vector<std::string>{"keep", "lab-1"}));
}

TEST(Sharded, RestoresAndPreloadsOnlyItsOwnScenes) {
  Folder f;
  const std::string state = (f.path() / "state").string();
  {
    // Unsharded first: the store holds scenes of both shards.
    server::ServerOptions o;
    o.state_dir = state;
    ServerHarness h(Transport::kInProcess, o);
    auto scenes = h.Scenes();
    ASSERT_TRUE(CreateScene(*scenes, "lab-1").ok());
    ASSERT_TRUE(CreateScene(*scenes, "lab-b1").ok());
  }
  std::ofstream(f.path() / "scene.json") << R"({"scene": "lab-b2", "bodies": []})";
  std::ofstream(f.path() / "mine.json") << R"({"scene": "lab-2", "bodies": []})";
  server::ServerOptions o = Sharded(f, "s1");
  o.state_dir = state;
  o.scene_files = {(f.path() / "scene.json").string(), (f.path() / "mine.json").string()};
  const ScopedExpectLogs expect_logs;  // "scene 'lab-b1' not served" (warn)
  ServerHarness h(Transport::kInProcess, o);
  auto scenes = h.Scenes();
  EXPECT_EQ(SceneIds(*scenes), (std::vector<std::string>{"lab-1", "lab-2"}));
}

TEST(Sharded, StartRefusesAMapWithoutItsShardOrHalfTheOptions) {
  Folder f;
  for (const auto& [map, shard, expect] :
       std::vector<std::tuple<std::string, std::string, std::string>>{
           {f.Map(), "s9", "no line names shard 's9' (--shard); it names: s1, s2"},
           {f.Map(), "", "sharding needs both --shard-map FILE and --shard NAME"},
           {"", "s1", "sharding needs both --shard-map FILE and --shard NAME"}}) {
    server::ServerOptions o;
    o.shard_map_file = map;
    o.shard = shard;
    o.listen = "";
    server::HapticServer srv(o);
    try {
      srv.Start();
      ADD_FAILURE() << "started with map '" << map << "', shard '" << shard << "'";
    } catch (const std::exception& e) {
      EXPECT_NE(std::string(e.what()).find(expect), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace hapticpd::testing::routing_tests
