// Every scene-scoped call our clients make carries `x-hapticpd-scene: ID`
// (proto/wire/routing.h), the header a balancer routes on: the CLI's
// commands (through popen, `view` included) and the device Session, against a server that
// records each call's method and header and answers UNIMPLEMENTED.
// ListScenes names no scene and carries none.
#include <grpcpp/generic/async_generic_service.h>
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <mutex>
#include <string>
#include <vector>

#include "client/session.h"
#include "server/core.h"
#include "tests/cli_runner.h"
#include "tests/client/session_rig.h"
#include "tests/test_util.h"

namespace hapticpd::testing::routing_header_tests {
namespace {

namespace fs = std::filesystem;

struct Call {
  std::string method;
  std::vector<std::string> scenes;  ///< every x-hapticpd-scene value sent
};

/// A gRPC server that records every call and refuses it.
class Recorder final : public grpc::CallbackGenericService {
 public:
  Recorder() {
    grpc::ServerBuilder b;
    b.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port_);
    b.RegisterCallbackGenericService(this);
    server_ = b.BuildAndStart();
  }
  ~Recorder() override { server_->Shutdown(std::chrono::system_clock::now()); }
  int port() const { return port_; }
  std::string Address() const { return "127.0.0.1:" + std::to_string(port_); }
  std::vector<Call> Take() {
    std::lock_guard lock(mu_);
    return std::exchange(calls_, {});
  }

 private:
  grpc::ServerGenericBidiReactor* CreateReactor(grpc::GenericCallbackServerContext* ctx) override {
    Call c{ctx->method(), {}};
    const auto [first, last] = ctx->client_metadata().equal_range("x-hapticpd-scene");
    for (auto it = first; it != last; ++it)
      c.scenes.emplace_back(it->second.data(), it->second.size());
    {
      std::lock_guard lock(mu_);
      calls_.push_back(std::move(c));
    }
    // Finish before the reactor is bound goes into gRPC's backlog, which the
    // reactor's destructor frees on another gRPC thread; the hand-over tells
    // TSan about the order gRPC's uninstrumented locks give it.
    struct Refuse final : grpc::ServerGenericBidiReactor {
      Refuse() {
        Finish(grpc::Status(grpc::StatusCode::UNIMPLEMENTED, "recording only"));
        server::internal::GrpcHandOff(this);
      }
      void OnDone() override {
        server::internal::GrpcTakeOver(this);
        delete this;
      }
    };
    return new Refuse;
  }

  int port_ = 0;
  std::unique_ptr<grpc::Server> server_;
  std::mutex mu_;
  std::vector<Call> calls_;
};

class RoutingHeader : public ::testing::Test {
 protected:
  /// Runs `hapticpd ARGS --server ...` and returns the calls it made.
  std::vector<Call> Cli(const std::string& args) {
    const RunResult r = RunCli(args + " --server " + rec_.Address() + " --timeout 5");
    EXPECT_NE(r.exit_code, 0) << "the recorder refuses every call; output: " << r.out;
    return rec_.Take();
  }
  /// Every call of `calls` is `method` with exactly one header `scene`.
  void ExpectRouted(const std::vector<Call>& calls, const std::string& method,
                    const std::string& scene) {
    ASSERT_FALSE(calls.empty()) << method << ": no call reached the server";
    for (const Call& c : calls) {
      EXPECT_EQ(c.method, "/hapticpd.v1." + method);
      EXPECT_EQ(c.scenes, std::vector<std::string>{scene}) << c.method;
    }
  }
  Recorder rec_;
};

TEST_F(RoutingHeader, CliSceneCallsNameTheirScene) {
  ExpectRouted(Cli("inject --scene lab-3 --shape box:0.1,0.1,0.1"), "SceneService/AddBody",
               "lab-3");
  ExpectRouted(Cli("move --scene lab-3 --body b --pose 0,0,0"), "SceneService/MoveBody", "lab-3");
  ExpectRouted(Cli("remove --scene lab-3 --body b"), "SceneService/RemoveBody", "lab-3");
  ExpectRouted(Cli("scene create lab-3"), "SceneService/CreateScene", "lab-3");
  ExpectRouted(Cli("scene delete lab-3"), "SceneService/DeleteScene", "lab-3");
  ExpectRouted(Cli("scene get lab-3"), "SceneService/GetScene", "lab-3");
  const fs::path dir = fs::temp_directory_path() / ("hapticpd_route_" + std::to_string(::getpid()));
  ExpectRouted(Cli("scene export lab-3 " + dir.string()), "SceneService/GetScene", "lab-3");
  fs::create_directories(dir);
  std::ofstream(dir / "scene.json") << R"({"scene": "from-file", "bodies": []})";
  ExpectRouted(Cli("scene load " + (dir / "scene.json").string() + " --scene lab-3"),
               "SceneService/CreateScene", "lab-3");
  ExpectRouted(Cli("scene load " + (dir / "scene.json").string()), "SceneService/CreateScene",
               "from-file");
  fs::remove_all(dir);
  ExpectRouted(Cli("watch --scene lab-3"), "SceneService/Watch", "lab-3");
  ExpectRouted(Cli("observe --scene lab-3 --duration 1"), "SceneService/Watch", "lab-3");
  ExpectRouted(Cli("couple --scene lab-3 --duration 1"), "HapticService/Couple", "lab-3");
  {
    // The viewer retries its Watch until stopped (timeout sends SIGTERM).
    const RunResult r = RunCli("view --scene lab-3 --listen 127.0.0.1:0 --server " +
                               rec_.Address() + " & sleep 1.5; kill $!; wait");
    (void)r;
    ExpectRouted(rec_.Take(), "SceneService/Watch", "lab-3");
  }
  const std::vector<Call> list = Cli("scene list");
  ASSERT_EQ(list.size(), 1u);
  EXPECT_EQ(list[0].method, "/hapticpd.v1.SceneService/ListScenes");
  EXPECT_TRUE(list[0].scenes.empty());
}

TEST_F(RoutingHeader, DeviceSessionNamesItsScene) {
  client::SessionOptions o = Options(rec_.port());
  o.hello.set_scene_id("lab-7");
  o.connect_timeout_s = 5;
  {
    const ScopedExpectLogs refused;  // the session may log the refusal
    client::Session session(o);
    EXPECT_THROW(session.Connect(), client::SessionError);
  }
  ExpectRouted(rec_.Take(), "HapticService/Couple", "lab-7");
}

// `scene list --servers`: each process asked directly, each scene prefixed
// by its server; a scene two servers hold and a server that cannot answer
// fail the command after the listing.
TEST(SceneListServers, ListsEachServerAndFindsCopies) {
  auto a = StartServer("127.0.0.1:0");
  auto b = StartServer("127.0.0.1:0");
  const std::string A = "127.0.0.1:" + std::to_string(a->port());
  const std::string B = "127.0.0.1:" + std::to_string(b->port());
  // Both hold "default" (unsharded servers): a copy.
  RunResult r = RunCli("scene list --servers " + A + "," + B);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.out.find(A + "  default  bodies 0"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find(B + "  default  bodies 0"), std::string::npos) << r.out;
  EXPECT_NE(r.err.find("scene 'default' is held by 2 servers: " + A + ", " + B), std::string::npos)
      << r.err;
  r = RunCli("scene list --servers " + A);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.out,
            A + "  default  bodies 0  sessions 0  observers 0  revision 0  the default scene\n");
  b->Shutdown();
  r = RunCli("scene list --timeout 2 --servers " + A + "," + B);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.out.find(A + "  default"), std::string::npos) << r.out;
  EXPECT_NE(r.err.find(B + ": UNAVAILABLE"), std::string::npos) << r.err;
  a->Shutdown();
}

}  // namespace
}  // namespace hapticpd::testing::routing_header_tests
