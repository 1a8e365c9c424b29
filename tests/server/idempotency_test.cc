// Request ids (server/README.md "Idempotent mutations"): for every mutation,
// the same id sent twice gives the first outcome and one change; the same id
// from another token is another request; a retry of a failed request gets
// the same error, except for transient errors, which a retry runs again;
// the ids of structural mutations survive a restart.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include "tests/server/server_harness.h"

namespace hapticpd::testing::idempotency_tests {
namespace {

namespace fs = std::filesystem;

class Folder : public ScopedTempDir {
 public:
  Folder() : ScopedTempDir("idem") {
    fs::create_directories(path());
    std::ofstream(path() / "tokens.json") << R"({"tokens": [
      {"token": "alice", "roles": {"*": ["admin"]}},
      {"token": "bob", "roles": {"*": ["admin"]}}]})";
  }
  server::ServerOptions Options(bool durable) const {
    server::ServerOptions o;
    o.tokens_file = (path() / "tokens.json").string();
    if (durable) o.state_dir = (path() / "state").string();
    return o;
  }
};

struct Client {
  std::unique_ptr<v1::SceneService::Stub> stub;
  std::string token;

  grpc::Status Create(const std::string& id, const std::string& rid, v1::SceneSummary* out) {
    v1::CreateSceneRequest req;
    req.set_scene_id(id);
    req.set_description("d");
    req.set_request_id(rid);
    return stub->CreateScene(Ctx(token).get(), req, out);
  }
  grpc::Status Delete(const std::string& id, const std::string& rid) {
    v1::DeleteSceneRequest req;
    req.set_scene_id(id);
    req.set_request_id(rid);
    v1::DeleteSceneResponse resp;
    return stub->DeleteScene(Ctx(token).get(), req, &resp);
  }
  grpc::Status Add(const std::string& scene, const std::string& body_id, const std::string& rid,
                   v1::Body* out) {
    v1::AddBodyRequest r = ShapeHeader(scene, "box", body_id, MakePose(0, 0, 0), true);
    r.mutable_header()->set_request_id(rid);
    return AddBodyRaw(*stub, {r}, out, token);
  }
  grpc::Status Move(const std::string& scene, const std::string& body, double x,
                    const std::string& rid, v1::MoveBodyResponse* out) {
    v1::MoveBodyRequest req;
    req.set_scene_id(scene);
    req.set_body_id(body);
    *req.mutable_pose() = MakePose(x, 0, 0);
    req.set_request_id(rid);
    return stub->MoveBody(Ctx(token).get(), req, out);
  }
  grpc::Status Remove(const std::string& scene, const std::string& body, const std::string& rid,
                      v1::RemoveBodyResponse* out) {
    v1::RemoveBodyRequest req;
    req.set_scene_id(scene);
    req.set_body_id(body);
    req.set_request_id(rid);
    return stub->RemoveBody(Ctx(token).get(), req, out);
  }
  v1::Scene Get(const std::string& scene) {
    v1::GetSceneRequest req;
    req.set_scene_id(scene);
    v1::Scene sc;
    EXPECT_TRUE(stub->GetScene(Ctx(token).get(), req, &sc).ok());
    return sc;
  }
  int Scenes() {
    v1::ListScenesResponse list;
    EXPECT_TRUE(stub->ListScenes(Ctx(token).get(), {}, &list).ok());
    return list.scenes_size();
  }
};

void ExpectSame(const grpc::Status& a, const grpc::Status& b) {
  EXPECT_EQ(a.error_code(), b.error_code());
  EXPECT_EQ(a.error_message(), b.error_message());
}

class Idempotency : public ::testing::TestWithParam<bool> {};  // durable store or memory

TEST_P(Idempotency, EveryMutationRetriedGivesTheFirstOutcomeAndOneChange) {
  Folder f;
  ServerHarness h(Transport::kInProcess, f.Options(GetParam()));
  Client c{h.Scenes(), "alice"};

  v1::SceneSummary s1, s2;
  ASSERT_TRUE(c.Create("lab", "create-1", &s1).ok());
  ASSERT_TRUE(c.Create("lab", "create-1", &s2).ok()) << "the retry ran again";
  EXPECT_EQ(s1.SerializeAsString(), s2.SerializeAsString());
  EXPECT_EQ(c.Scenes(), 2);  // default and lab

  v1::Body b1, b2;
  ASSERT_TRUE(c.Add("lab", "", "add-1", &b1).ok());
  ASSERT_TRUE(c.Add("lab", "", "add-1", &b2).ok());
  EXPECT_EQ(b1.body_id(), "body-1");
  EXPECT_EQ(b1.SerializeAsString(), b2.SerializeAsString());
  EXPECT_EQ(c.Get("lab").bodies_size(), 1) << "the retried upload added a second body";

  v1::MoveBodyResponse m1, m2, m3;
  ASSERT_TRUE(c.Move("lab", "body-1", 0.5, "move-1", &m1).ok());
  ASSERT_TRUE(c.Move("lab", "body-1", 0.75, "move-2", &m2).ok());
  ASSERT_TRUE(c.Move("lab", "body-1", 0.5, "move-1", &m3).ok());
  EXPECT_EQ(m3.revision(), m1.revision());
  EXPECT_EQ(c.Get("lab").bodies(0).pose().position().x(), 0.75)
      << "the retried move was applied again";

  v1::RemoveBodyResponse r1, r2;
  ASSERT_TRUE(c.Remove("lab", "body-1", "remove-1", &r1).ok());
  ASSERT_TRUE(c.Remove("lab", "body-1", "remove-1", &r2).ok());
  EXPECT_EQ(r1.revision(), r2.revision());

  ASSERT_TRUE(c.Delete("lab", "delete-1").ok());
  ASSERT_TRUE(c.Delete("lab", "delete-1").ok());
  EXPECT_EQ(c.Scenes(), 1);
  // Without the id, the same requests are new ones.
  EXPECT_EQ(c.Delete("lab", "").error_code(), grpc::StatusCode::NOT_FOUND);
}

TEST_P(Idempotency, IdsAreScopedPerToken) {
  Folder f;
  ServerHarness h(Transport::kInProcess, f.Options(GetParam()));
  Client alice{h.Scenes(), "alice"}, bob{h.Scenes(), "bob"};
  v1::Body a, b;
  ASSERT_TRUE(alice.Add("default", "", "same", &a).ok());
  ASSERT_TRUE(bob.Add("default", "", "same", &b).ok());
  EXPECT_EQ(a.body_id(), "body-1");
  EXPECT_EQ(b.body_id(), "body-2");
  EXPECT_EQ(alice.Get("default").bodies_size(), 2);
  v1::SceneSummary s;
  ASSERT_TRUE(alice.Create("x", "c", &s).ok());
  EXPECT_EQ(bob.Create("x", "c", &s).error_code(), grpc::StatusCode::ALREADY_EXISTS);
}

TEST_P(Idempotency, RetryOfAFailedRequestGetsTheSameError) {
  Folder f;
  ServerHarness h(Transport::kInProcess, f.Options(GetParam()));
  Client c{h.Scenes(), "alice"};
  v1::RemoveBodyResponse rr;
  const grpc::Status first = c.Remove("default", "ghost", "rm-ghost", &rr);
  ASSERT_EQ(first.error_code(), grpc::StatusCode::NOT_FOUND);
  v1::Body b;
  ASSERT_TRUE(c.Add("default", "ghost", "", &b).ok());
  ExpectSame(c.Remove("default", "ghost", "rm-ghost", &rr), first);
  EXPECT_EQ(c.Get("default").bodies_size(), 1) << "the retry removed the body";

  // A rejected upload (duplicate id): the same error after the duplicate is gone.
  const grpc::Status dup = c.Add("default", "ghost", "add-ghost", &b);
  ASSERT_EQ(dup.error_code(), grpc::StatusCode::ALREADY_EXISTS);
  ASSERT_TRUE(c.Remove("default", "ghost", "", &rr).ok());
  ExpectSame(c.Add("default", "ghost", "add-ghost", &b), dup);
  EXPECT_EQ(c.Get("default").bodies_size(), 0);

  // Rejected before the upload was built (unknown scene).
  const grpc::Status nosuch = c.Add("later", "", "add-later", &b);
  ASSERT_EQ(nosuch.error_code(), grpc::StatusCode::NOT_FOUND);
  v1::SceneSummary s;
  ASSERT_TRUE(c.Create("later", "", &s).ok());
  ExpectSame(c.Add("later", "", "add-later", &b), nosuch);

  v1::MoveBodyResponse mr;
  const grpc::Status mv = c.Move("default", "nobody", 1, "mv", &mr);
  ASSERT_EQ(mv.error_code(), grpc::StatusCode::NOT_FOUND);
  ExpectSame(c.Move("default", "nobody", 1, "mv", &mr), mv);
}

TEST_P(Idempotency, ConcurrentRetriesMakeOneChange) {
  Folder f;
  ServerHarness h(Transport::kInProcess, f.Options(GetParam()));
  std::vector<std::thread> threads;
  std::atomic<int> ok{0};
  std::vector<std::string> ids(6);
  for (int i = 0; i < 6; ++i) {
    threads.emplace_back([&, i] {
      Client c{h.Scenes(), "alice"};
      v1::Body b;
      if (c.Add("default", "", "together", &b).ok()) ++ok;
      ids[i] = b.body_id();
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(ok.load(), 6);
  for (const auto& id : ids) EXPECT_EQ(id, ids[0]);
  Client c{h.Scenes(), "alice"};
  EXPECT_EQ(c.Get("default").bodies_size(), 1);
}

TEST_P(Idempotency, MalformedOrReusedIdsAreRejected) {
  Folder f;
  ServerHarness h(Transport::kInProcess, f.Options(GetParam()));
  Client c{h.Scenes(), "alice"};
  v1::SceneSummary s;
  grpc::Status st = c.Create("a", "has space", &s);
  EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(st.error_message(), "request_id: may only contain A-Z a-z 0-9 _ . - (got 'has space')");
  st = c.Create("a", std::string(65, 'r'), &s);
  EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(st.error_message().rfind("request_id: ", 0), 0u) << st.error_message();
  v1::Body b;
  st = c.Add("default", "", "bad/id", &b);
  EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(st.error_message().rfind("header.request_id: ", 0), 0u) << st.error_message();
  EXPECT_EQ(c.Scenes(), 1);

  ASSERT_TRUE(c.Create("a", "one", &s).ok());
  st = c.Delete("a", "one");
  EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(st.error_message(),
            "request_id: 'one' was already used for CreateScene (a request id names one "
            "mutation)");
  EXPECT_EQ(c.Scenes(), 2);
}

INSTANTIATE_TEST_SUITE_P(Stores, Idempotency, ::testing::Values(false, true),
                         [](const auto& info) { return info.param ? "Durable" : "InMemory"; });

TEST(IdempotencyDurable, IdsSurviveARestartAndTransientErrorsAreNotKept) {
  Folder f;
  auto fail = std::make_shared<std::atomic<int>>(SQLITE_OK);
  server::ServerOptions o = f.Options(true);
  o.store_before_commit = [fail] { return fail->load(); };
  v1::SceneSummary s1;
  v1::Body b1;
  grpc::Status missing;
  {
    ServerHarness h(Transport::kInProcess, o);
    Client c{h.Scenes(), "alice"};
    ASSERT_TRUE(c.Create("lab", "c1", &s1).ok());
    ASSERT_TRUE(c.Add("lab", "", "a1", &b1).ok());
    v1::RemoveBodyResponse rr;
    missing = c.Remove("lab", "nope", "r1", &rr);
    ASSERT_EQ(missing.error_code(), grpc::StatusCode::NOT_FOUND);
    // A store failure is transient: the retry runs again, and succeeds.
    fail->store(SQLITE_IOERR);
    v1::Body b;
    EXPECT_EQ(c.Add("lab", "later", "a2", &b).error_code(), grpc::StatusCode::UNAVAILABLE);
    fail->store(SQLITE_OK);
    EXPECT_TRUE(c.Add("lab", "later", "a2", &b).ok());
  }
  ServerHarness h(Transport::kInProcess, o);
  Client c{h.Scenes(), "alice"};
  v1::SceneSummary s2;
  v1::Body b2;
  ASSERT_TRUE(c.Create("lab", "c1", &s2).ok());
  EXPECT_EQ(s1.SerializeAsString(), s2.SerializeAsString());
  ASSERT_TRUE(c.Add("lab", "", "a1", &b2).ok());
  EXPECT_EQ(b1.SerializeAsString(), b2.SerializeAsString());
  EXPECT_EQ(c.Get("lab").bodies_size(), 2);  // body-1 and later
  v1::Body nope;
  ASSERT_TRUE(c.Add("lab", "nope", "", &nope).ok());
  v1::RemoveBodyResponse rr;
  ExpectSame(c.Remove("lab", "nope", "r1", &rr), missing);
  EXPECT_EQ(c.Get("lab").bodies_size(), 3);
}

}  // namespace
}  // namespace hapticpd::testing::idempotency_tests
