// The server's boundary against a client that means harm or has a bug:
// answers unfit for a motor are withheld, untrusted strings come back and
// go to the log bounded and escaped, "Bearer " is required, total_bytes is
// held in both directions, and one client's large upload does not hold up
// another's small one. No wall-clock assertions: uploads are ordered by the
// server's build hook. Runs in every preset (label `services`).
#include <spdlog/sinks/base_sink.h>
#include <unistd.h>

#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <future>
#include <map>
#include <mutex>
#include <thread>

#include "server/core.h"
#include "tests/server/server_harness.h"
#include "tests/test_util.h"

namespace hapticpd::testing {
namespace {

namespace fs = std::filesystem;

/// A token file with tokens "alice" and "bob" (admin everywhere), removed
/// when done.
class TwoTokens {
 public:
  TwoTokens() {
    path_ = fs::temp_directory_path() / ("hapticpd_boundary_" + std::to_string(::getpid()) + "_" +
                                         std::to_string(counter_++) + ".json");
    std::ofstream(path_) << R"({"tokens": [
      {"token": "alice", "name": "alice", "roles": {"*": ["admin"]}},
      {"token": "bob", "name": "bob", "roles": {"*": ["admin"]}}]})";
  }
  ~TwoTokens() { fs::remove(path_); }
  std::string path() const { return path_.string(); }

 private:
  static inline int counter_ = 0;
  fs::path path_;
};

TEST(Boundary, AnswerOverTheForceLimitIsWithheldAsZeroForceWithoutRows) {
  server::ServerOptions opt;
  opt.limits.max_update_force = 1.0;  // N; the box below pushes far harder
  ServerHarness h(Transport::kInProcess, opt);
  auto scenes = h.Scenes();
  auto haptics = h.Haptics();
  ASSERT_TRUE(AddShape(*scenes, "default", "box", "floor", MakePose(0, 0, 0)).ok());
  Session s(*haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello()).ok());
  const ScopedExpectLogs expect_warning;  // logged once per session
  // Free space first: nothing to withhold.
  ASSERT_TRUE(s.Send(1, MakePose(0, 0, 0.2)));
  auto free = s.Next();
  ASSERT_TRUE(free);
  EXPECT_EQ(free->status(), v1::CONTACT_STATUS_SEPARATED);
  // 2 cm deep into a 1000 N/m box: 20 N > 1 N.
  for (std::uint64_t k = 2; k <= 4; ++k) {
    ASSERT_TRUE(s.Send(k, MakePose(0, 0, 0.05 + 0.01 - 0.02)));
    auto u = s.Next();
    ASSERT_TRUE(u);
    EXPECT_EQ(u->status(), v1::CONTACT_STATUS_WITHHELD);
    EXPECT_EQ(u->rows_size(), 0);
    EXPECT_EQ(u->body_ids_size(), 0);
    EXPECT_EQ(u->force().x(), 0);
    EXPECT_EQ(u->force().y(), 0);
    EXPECT_EQ(u->force().z(), 0);
    EXPECT_EQ(u->depth(), 0);
    EXPECT_EQ(u->sequence(), k);
    EXPECT_EQ(u->target_pose().position().z(), u->pose_ref().position().z());
    EXPECT_GT(u->validity_radius(), 0);
  }
  EXPECT_EQ(h.server().counts().updates_withheld, 3u);
  s.ExpectCleanEnd();
}

TEST(Boundary, TheSameContactUnderTheDefaultLimitIsSent) {
  ServerHarness h(Transport::kInProcess);
  auto scenes = h.Scenes();
  auto haptics = h.Haptics();
  ASSERT_TRUE(AddShape(*scenes, "default", "box", "floor", MakePose(0, 0, 0)).ok());
  Session s(*haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello()).ok());
  ASSERT_TRUE(s.Send(1, MakePose(0, 0, 0.04)));
  auto u = s.Next();
  ASSERT_TRUE(u);
  EXPECT_EQ(u->status(), v1::CONTACT_STATUS_PENETRATING);
  EXPECT_GT(u->rows_size(), 0);
  EXPECT_GT(u->force().z(), 1.0);
  EXPECT_EQ(h.server().counts().updates_withheld, 0u);
  s.ExpectCleanEnd();
}

TEST(Boundary, TokenWithoutBearerPrefixIsRefused) {
  TwoTokens tokens;
  server::ServerOptions opt;
  opt.tokens_file = tokens.path();
  ServerHarness h(Transport::kInProcess, opt);
  auto scenes = h.Scenes();
  v1::ListScenesResponse list;
  grpc::ClientContext bare;
  bare.AddMetadata("authorization", "alice");
  const grpc::Status s = scenes->ListScenes(&bare, {}, &list);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(s.error_message(),
            "the authorization metadata must be 'Bearer TOKEN' (the 'Bearer ' prefix is missing)");
  auto good = Ctx("alice");
  EXPECT_TRUE(scenes->ListScenes(good.get(), {}, &list).ok());
}

/// No raw control character, and at most wire::kMaxStatusMessage bytes.
void ExpectBoundedAndEscaped(const grpc::Status& s, const std::string& field) {
  EXPECT_FALSE(s.ok());
  EXPECT_LE(s.error_message().size(), 1024u) << s.error_message().substr(0, 200);
  EXPECT_EQ(s.error_message().rfind(field, 0), 0u) << s.error_message().substr(0, 200);
  for (char c : s.error_message()) {
    EXPECT_FALSE(static_cast<unsigned char>(c) < 0x20) << "raw control character in the status";
  }
}

TEST(Boundary, MegabyteAndControlCharacterIdsComeBackBoundedAndNamed) {
  ServerHarness h(Transport::kTcp);  // over TCP: an 8 KiB trailer limit applies
  auto scenes = h.Scenes();
  const std::string huge(1 << 20, 'x');
  const std::string nasty = "evil\n2026-01-01 [error] forged\x1b[31m";
  for (const std::string& id : {huge, nasty}) {
    v1::GetSceneRequest get;
    get.set_scene_id(id);
    v1::Scene scene;
    auto c1 = Ctx();
    const grpc::Status g = scenes->GetScene(c1.get(), get, &scene);
    EXPECT_EQ(g.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << g.error_message();
    ExpectBoundedAndEscaped(g, "scene_id");

    v1::CreateSceneRequest create;
    create.set_scene_id(id);
    v1::SceneSummary sum;
    auto c2 = Ctx();
    const grpc::Status c = scenes->CreateScene(c2.get(), create, &sum);
    EXPECT_EQ(c.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    ExpectBoundedAndEscaped(c, "scene_id");

    v1::Body body;
    const grpc::Status a =
        AddBodyRaw(*scenes, {ShapeHeader("default", "box", id, MakePose(0, 0, 0))}, &body);
    EXPECT_EQ(a.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    ExpectBoundedAndEscaped(a, "header.spec.body_id");
  }
  // A megabyte shape spec: the error names the field, bounded.
  v1::Body body;
  const grpc::Status a =
      AddBodyRaw(*scenes, {ShapeHeader("default", "box:" + huge, "b", MakePose(0, 0, 0))}, &body);
  EXPECT_EQ(a.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  ExpectBoundedAndEscaped(a, "header.shape");
}

/// Collects what the server logs (its logger shares the default logger's
/// sinks at its creation, so the sink is added to it directly while no
/// server runs).
class CaptureSink final : public spdlog::sinks::base_sink<std::mutex> {
 public:
  std::vector<std::string> lines() {
    std::lock_guard lock(mutex_);
    return lines_;
  }

 protected:
  void sink_it_(const spdlog::details::log_msg& msg) override {
    lines_.emplace_back(msg.payload.data(), msg.payload.size());
  }
  void flush_() override {}

 private:
  std::vector<std::string> lines_;
};

TEST(Boundary, ClientNameAndIdsAreEscapedAndCutInTheLog) {
  auto sink = std::make_shared<CaptureSink>();
  auto& sinks = server::internal::Log()->sinks();
  sinks.push_back(sink);
  const auto old_level = server::internal::Log()->level();
  server::internal::Log()->set_level(spdlog::level::info);
  const std::string name = "mallory\n[info] forged line\x1b[2J" + std::string(100000, 'm');
  {
    ServerHarness h(Transport::kInProcess);
    auto scenes = h.Scenes();
    auto haptics = h.Haptics();
    ASSERT_TRUE(AddShape(*scenes, "default", "box", "floor", MakePose(0, 0, 0)).ok());
    Session s(*haptics);
    v1::Hello hello = Session::DefaultHello();
    hello.set_client_name(name);
    ASSERT_TRUE(s.Open(hello).ok());
    s.ExpectCleanEnd();
    // An AddBody rejected for its scene id (logged with the id).
    v1::Body body;
    (void)AddBodyRaw(*scenes, {ShapeHeader("nope\nforged", "box", "b", MakePose(0, 0, 0))}, &body);
  }
  sinks.pop_back();
  server::internal::Log()->set_level(old_level);
  bool saw_session = false;
  const std::string size = "(" + std::to_string(name.size()) + " bytes)";
  for (const std::string& line : sink->lines()) {
    EXPECT_LE(line.size(), 2048u) << line.substr(0, 200);
    EXPECT_EQ(line.find('\n'), std::string::npos) << line.substr(0, 200);
    EXPECT_EQ(line.find('\x1b'), std::string::npos) << line.substr(0, 200);
    if (line.find("mallory\\n[info] forged line\\x1b[2J") != std::string::npos) {
      saw_session = true;
      EXPECT_NE(line.find(size), std::string::npos) << line;
    }
  }
  EXPECT_TRUE(saw_session) << "the session's log line with the escaped client name";
}

v1::AddBodyRequest FileHeader(const std::string& id, std::uint64_t total_bytes) {
  v1::AddBodyRequest r;
  auto* h = r.mutable_header();
  h->set_scene_id("default");
  h->set_format(v1::MESH_FORMAT_OBJ);
  h->mutable_spec()->set_body_id(id);
  h->set_total_bytes(total_bytes);
  return r;
}

v1::AddBodyRequest Bytes(std::string b) {
  v1::AddBodyRequest r;
  r.set_chunk(std::move(b));
  return r;
}

TEST(Boundary, TotalBytesIsHeldInBothDirections) {
  ServerHarness h(Transport::kInProcess);
  auto scenes = h.Scenes();
  const std::string obj =
      "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
  v1::Body body;
  // Understated: more bytes arrive than announced.
  grpc::Status s = AddBodyRaw(*scenes, {FileHeader("under", 10), Bytes(obj)}, &body);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(s.error_message(), "chunk: " + std::to_string(obj.size()) +
                                   " bytes received, more than header.total_bytes 10");
  // Overstated: fewer bytes than announced.
  s = AddBodyRaw(*scenes, {FileHeader("over", obj.size() + 5), Bytes(obj)}, &body);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(s.error_message(), "chunk: " + std::to_string(obj.size()) +
                                   " bytes received, header.total_bytes said " +
                                   std::to_string(obj.size() + 5));
  // Exact, and absent (0): accepted.
  EXPECT_TRUE(AddBodyRaw(*scenes, {FileHeader("exact", obj.size()), Bytes(obj)}, &body).ok());
  EXPECT_TRUE(AddBodyRaw(*scenes, {FileHeader("unsaid", 0), Bytes(obj)}, &body).ok());
  EXPECT_EQ(GetScene(*scenes, "default").bodies_size(), 2);
}

/// Holds the build of the body labelled "large" until released, and records
/// for every other build whether it started while the large one was held.
struct BuildGate {
  std::mutex mu;
  std::condition_variable cv;
  bool large_started = false;
  bool holding = false;  // the large build is inside the hook
  bool released = false;
  std::map<std::string, bool> started_while_held;

  void BeforeBuild(const std::string& label) {
    std::unique_lock lock(mu);
    if (label != "large") {
      started_while_held[label] = holding;
      return;
    }
    large_started = holding = true;
    cv.notify_all();
    // Bounded: a broken pool must fail the test, not hang it.
    cv.wait_for(lock, std::chrono::seconds(20), [&] { return released; });
    holding = false;
  }
};

grpc::Status AddLabelled(v1::SceneService::Stub& stub, const std::string& id,
                         const std::string& label, const std::string& token) {
  v1::AddBodyRequest r = ShapeHeader("default", "box", id, MakePose(0, 0, 0));
  r.mutable_header()->mutable_spec()->set_label(label);
  v1::Body body;
  return AddBodyRaw(stub, {r}, &body, token);
}

TEST(Boundary, SmallUploadOfAnotherClientCompletesWhileALargeOneBuilds) {
  TwoTokens tokens;
  BuildGate gate;
  server::ServerOptions opt;
  opt.tokens_file = tokens.path();
  opt.before_build = [&](const std::string& label) { gate.BeforeBuild(label); };
  ServerHarness h(Transport::kTcp, opt);
  auto scenes = h.Scenes();
  auto large =
      std::async(std::launch::async, [&] { return AddLabelled(*scenes, "big", "large", "alice"); });
  {
    std::unique_lock lock(gate.mu);
    ASSERT_TRUE(
        gate.cv.wait_for(lock, std::chrono::seconds(30), [&] { return gate.large_started; }));
  }
  // Alice's second upload waits for her first (one build per client at a
  // time); Bob's goes through while hers is held.
  auto alice_small = std::async(std::launch::async, [&] {
    return AddLabelled(*scenes, "alice-small", "alice-small", "alice");
  });
  const grpc::Status bob = AddLabelled(*scenes, "bob-small", "bob-small", "bob");
  EXPECT_TRUE(bob.ok()) << bob.error_message();
  {
    std::lock_guard lock(gate.mu);
    gate.released = true;
  }
  gate.cv.notify_all();
  EXPECT_TRUE(large.get().ok());
  EXPECT_TRUE(alice_small.get().ok());
  std::lock_guard lock(gate.mu);
  ASSERT_EQ(gate.started_while_held.size(), 2u);
  EXPECT_TRUE(gate.started_while_held["bob-small"])
      << "a small upload waited behind another client's large one";
  EXPECT_FALSE(gate.started_while_held["alice-small"]) << "one client ran two builds at once";
}

}  // namespace
}  // namespace hapticpd::testing
