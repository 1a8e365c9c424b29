// Token-file roles per scene, enforced on every RPC; token-file parsing;
// TLS; an open server refuses a non-loopback address.
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "server/auth.h"
#include "tests/server/server_harness.h"
#include "tests/test_util.h"

namespace hapticpd::testing {
namespace {

std::filesystem::path WriteTemp(const std::string& name, const std::string& text) {
  const auto path = std::filesystem::temp_directory_path() /
                    ("hapticpd_auth_test_" + std::to_string(::getpid()) + "_" + name);
  std::ofstream(path) << text;
  return path;
}

constexpr char kTokens[] = R"({"tokens": [
  {"token": "obs", "name": "watcher", "roles": {"default": ["observe"]}},
  {"token": "inj", "name": "injector", "roles": {"default": ["inject"]}},
  {"token": "dev", "name": "arm", "roles": {"default": ["device"]}},
  {"token": "adm", "name": "ops", "roles": {"*": ["admin"]}},
  {"token": "lab", "name": "lab-only", "roles": {"lab": ["inject", "device"]}}
]})";

class AuthTest : public ::testing::TestWithParam<Transport> {
 protected:
  void SetUp() override { tokens_ = WriteTemp("tokens.json", kTokens); }
  void TearDown() override { std::filesystem::remove(tokens_); }
  std::filesystem::path tokens_;
};

grpc::StatusCode CreateScene(v1::SceneService::Stub& stub, const std::string& id,
                             const std::string& token) {
  v1::CreateSceneRequest req;
  req.set_scene_id(id);
  v1::SceneSummary resp;
  auto ctx = Ctx(token);
  return stub.CreateScene(ctx.get(), req, &resp).error_code();
}

grpc::StatusCode GetSceneCode(v1::SceneService::Stub& stub, const std::string& id,
                              const std::string& token) {
  v1::GetSceneRequest req;
  req.set_scene_id(id);
  v1::Scene resp;
  auto ctx = Ctx(token);
  return stub.GetScene(ctx.get(), req, &resp).error_code();
}

grpc::StatusCode CoupleCode(v1::HapticService::Stub& stub, const std::string& scene,
                            const std::string& token) {
  Session s(stub, token);
  return s.Open(Session::DefaultHello(scene)).error_code();
}

TEST_P(AuthTest, RolesAreEnforcedPerSceneAndRpc) {
  server::ServerOptions opt;
  opt.tokens_file = tokens_.string();
  ServerHarness h(GetParam(), opt);
  auto scenes = h.Scenes();
  auto haptics = h.Haptics();
  using grpc::StatusCode;
  // No token or an unknown one: UNAUTHENTICATED everywhere.
  EXPECT_EQ(GetSceneCode(*scenes, "default", ""), StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(GetSceneCode(*scenes, "default", "wrong"), StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(AddShape(*scenes, "default", "box", "", MakePose(0, 0, 0), false, "").error_code(),
            StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(CoupleCode(*haptics, "default", ""), StatusCode::UNAUTHENTICATED);
  {
    v1::ListScenesResponse list;
    auto ctx = Ctx();
    EXPECT_EQ(scenes->ListScenes(ctx.get(), {}, &list).error_code(), StatusCode::UNAUTHENTICATED);
  }
  // observe: read only.
  EXPECT_EQ(GetSceneCode(*scenes, "default", "obs"), StatusCode::OK);
  EXPECT_EQ(AddShape(*scenes, "default", "box", "", MakePose(0, 0, 0), false, "obs").error_code(),
            StatusCode::PERMISSION_DENIED);
  EXPECT_EQ(CoupleCode(*haptics, "default", "obs"), StatusCode::PERMISSION_DENIED);
  EXPECT_EQ(CreateScene(*scenes, "x", "obs"), StatusCode::PERMISSION_DENIED);
  // inject: bodies, not sessions or scenes.
  EXPECT_EQ(AddShape(*scenes, "default", "box", "b", MakePose(0, 0, 0), true, "inj").error_code(),
            StatusCode::OK);
  EXPECT_EQ(GetSceneCode(*scenes, "default", "inj"), StatusCode::OK);
  EXPECT_EQ(CoupleCode(*haptics, "default", "inj"), StatusCode::PERMISSION_DENIED);
  EXPECT_EQ(CreateScene(*scenes, "x", "inj"), StatusCode::PERMISSION_DENIED);
  {
    v1::RemoveBodyRequest rm;
    rm.set_scene_id("default");
    rm.set_body_id("b");
    v1::RemoveBodyResponse rr;
    auto ctx = Ctx("dev");
    EXPECT_EQ(scenes->RemoveBody(ctx.get(), rm, &rr).error_code(), StatusCode::PERMISSION_DENIED);
  }
  // device: sessions.
  EXPECT_EQ(CoupleCode(*haptics, "default", "dev"), StatusCode::OK);
  EXPECT_EQ(AddShape(*scenes, "default", "box", "", MakePose(0, 0, 0), false, "dev").error_code(),
            StatusCode::PERMISSION_DENIED);
  // Roles are per scene: "lab" rights do not reach "default".
  EXPECT_EQ(AddShape(*scenes, "default", "box", "", MakePose(0, 0, 0), false, "lab").error_code(),
            StatusCode::PERMISSION_DENIED);
  EXPECT_EQ(CreateScene(*scenes, "lab", "lab"), StatusCode::PERMISSION_DENIED);
  // admin: everything, on every scene.
  EXPECT_EQ(CreateScene(*scenes, "lab", "adm"), StatusCode::OK);
  EXPECT_EQ(AddShape(*scenes, "lab", "box", "", MakePose(0, 0, 0), false, "lab").error_code(),
            StatusCode::OK);
  EXPECT_EQ(CoupleCode(*haptics, "lab", "lab"), StatusCode::OK);
  EXPECT_EQ(CoupleCode(*haptics, "default", "lab"), StatusCode::PERMISSION_DENIED);
  // Listing shows only the scenes a token has a role on.
  {
    v1::ListScenesResponse list;
    auto ctx = Ctx("lab");
    ASSERT_TRUE(scenes->ListScenes(ctx.get(), {}, &list).ok());
    ASSERT_EQ(list.scenes_size(), 1);
    EXPECT_EQ(list.scenes(0).scene_id(), "lab");
  }
  {
    v1::DeleteSceneRequest del;
    del.set_scene_id("lab");
    v1::DeleteSceneResponse dr;
    auto ctx = Ctx("lab");
    EXPECT_EQ(scenes->DeleteScene(ctx.get(), del, &dr).error_code(), StatusCode::PERMISSION_DENIED);
    auto ctx2 = Ctx("adm");
    EXPECT_EQ(scenes->DeleteScene(ctx2.get(), del, &dr).error_code(), StatusCode::OK);
  }
  // The failed attempts changed nothing.
  auto ctx = Ctx("adm");
  v1::GetSceneRequest get;
  get.set_scene_id("default");
  v1::Scene scene;
  ASSERT_TRUE(scenes->GetScene(ctx.get(), get, &scene).ok());
  EXPECT_EQ(scene.bodies_size(), 1);
}

INSTANTIATE_TEST_SUITE_P(Transports, AuthTest,
                         ::testing::Values(Transport::kInProcess, Transport::kTcp), TransportName);

TEST(TokenStoreTest, RejectsMalformedFilesNamingTheProblem) {
  using server::TokenStore;
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"{", "not valid JSON"},
      {"[]", "\"tokens\" array"},
      {R"({"tokens": [{"roles": {}}]})", "tokens[0]: needs a non-empty string \"token\""},
      {R"({"tokens": [{"token": "a"}]})", "tokens[0]: needs an object \"roles\""},
      {R"({"tokens": [{"token": "a", "roles": {"s": ["fly"]}}]})", "unknown role \"fly\""},
      {R"({"tokens": [{"token": "a", "roles": {"s": "observe"}}]})", "roles.s: not an array"},
      {R"({"tokens": [{"token": "a", "roles": {}}, {"token": "a", "roles": {}}]})",
       "tokens[1]: duplicate token"},
  };
  for (const auto& [text, what] : bad) {
    try {
      TokenStore::FromJson(text, "t.json");
      ADD_FAILURE() << "accepted: " << text;
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
      EXPECT_EQ(std::string(e.what()).rfind("t.json", 0), 0u) << e.what();
    }
  }
  EXPECT_THROW(TokenStore::FromFile("/nonexistent/tokens.json"), std::runtime_error);
}

TEST(ServerStartTest, OpenServerRefusesNonLoopbackAddresses) {
  server::ServerOptions opt;
  opt.listen = "0.0.0.0:0";
  opt.status_interval_s = 0;
  server::HapticServer s(opt);
  try {
    s.Start();
    ADD_FAILURE() << "an open server started on 0.0.0.0";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("loopback"), std::string::npos) << e.what();
  }
}

TEST(ServerStartTest, TlsServesOnlyTlsClients) {
  const std::string dir = HAPTICPD_TESTDATA_DIR "/tls";
  server::ServerOptions opt;
  opt.listen = "127.0.0.1:0";
  opt.status_interval_s = 0;
  opt.tls_cert = dir + "/server.crt";
  opt.tls_key = dir + "/server.key";
  server::HapticServer srv(opt);
  srv.Start();
  const std::string target = "127.0.0.1:" + std::to_string(srv.port());
  std::ifstream in(opt.tls_cert);
  grpc::SslCredentialsOptions ssl;
  ssl.pem_root_certs.assign(std::istreambuf_iterator<char>(in), {});
  auto tls = v1::SceneService::NewStub(grpc::CreateChannel(target, grpc::SslCredentials(ssl)));
  v1::ListScenesResponse list;
  {
    auto ctx = Ctx();
    const auto s = tls->ListScenes(ctx.get(), {}, &list);
    EXPECT_TRUE(s.ok()) << s.error_message();
  }
  EXPECT_EQ(list.scenes_size(), 1);
  auto plain =
      v1::SceneService::NewStub(grpc::CreateChannel(target, grpc::InsecureChannelCredentials()));
  auto ctx = std::make_unique<grpc::ClientContext>();
  ctx->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
  EXPECT_FALSE(plain->ListScenes(ctx.get(), {}, &list).ok());
  srv.Shutdown();
}

}  // namespace
}  // namespace hapticpd::testing
