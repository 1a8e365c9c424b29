// Health checking and reflection, client cancellation and server shutdown
// with sessions and observers open (no reactor, thread or session left; run
// under the asan preset for leaks), and scene files.
#include <grpcpp/generic/generic_stub.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "tests/server/server_harness.h"
#include "tests/test_util.h"

namespace hapticpd::testing {
namespace {

class LifecycleTest : public ::testing::TestWithParam<Transport> {};

/// grpc.health.v1.Health/Check for the whole server (`service` empty) or one
/// service, through the generic stub (request: field 1 = service name;
/// response: field 1 = ServingStatus; NOT_FOUND gives -1). On a
/// completion queue drained by this thread: a callback on one of gRPC's
/// threads would hand its result over through gRPC's own locks, which
/// ThreadSanitizer cannot see (the tsan preset).
int HealthStatus(const std::shared_ptr<grpc::Channel>& channel, const std::string& service = "") {
  grpc::GenericStub stub(channel);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + kCallDeadline);
  grpc::ByteBuffer req, resp;
  std::string request;
  if (!service.empty()) {
    request = std::string(1, '\x0a') + static_cast<char>(service.size()) + service;
  }
  grpc::Slice body(request);
  req = grpc::ByteBuffer(&body, 1);
  grpc::CompletionQueue cq;
  auto call = stub.PrepareUnaryCall(&ctx, "/grpc.health.v1.Health/Check", req, &cq);
  call->StartCall();
  grpc::Status s;
  call->Finish(&resp, &s, reinterpret_cast<void*>(1));
  void* tag = nullptr;
  bool ok = false;
  const bool got = cq.Next(&tag, &ok);
  cq.Shutdown();
  while (cq.Next(&tag, &ok)) {
  }
  if (!got) return -1;
  if (!s.ok()) return -1;
  std::vector<grpc::Slice> slices;
  if (!resp.Dump(&slices).ok()) return -1;
  std::string bytes;
  for (const auto& sl : slices) bytes.append(reinterpret_cast<const char*>(sl.begin()), sl.size());
  if (bytes.empty()) return 0;  // UNKNOWN (default value, not serialised)
  if (bytes.size() != 2 || bytes[0] != 0x08) return -2;
  return bytes[1];  // 1 SERVING, 2 NOT_SERVING
}

/// Service names listed by grpc.reflection.v1alpha (raw bytes of the reply).
std::string ReflectionListing(const std::shared_ptr<grpc::Channel>& channel) {
  grpc::GenericStub stub(channel);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + kCallDeadline);
  grpc::CompletionQueue cq;
  auto call =
      stub.PrepareCall(&ctx, "/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo", &cq);
  void* tag = nullptr;
  bool ok = false;
  auto step = [&] { return cq.Next(&tag, &ok) && ok; };
  call->StartCall(reinterpret_cast<void*>(1));
  if (!step()) return "";
  const char list_services[] = {0x3a, 0x00};  // field 7 (list_services) = ""
  grpc::Slice s(list_services, 2);
  grpc::ByteBuffer req(&s, 1);
  call->Write(req, reinterpret_cast<void*>(2));
  if (!step()) return "";
  grpc::ByteBuffer resp;
  call->Read(&resp, reinterpret_cast<void*>(3));
  std::string bytes;
  if (step()) {
    std::vector<grpc::Slice> slices;
    (void)resp.Dump(&slices);
    for (const auto& sl : slices)
      bytes.append(reinterpret_cast<const char*>(sl.begin()), sl.size());
  }
  call->WritesDone(reinterpret_cast<void*>(4));
  step();
  grpc::Status st;
  call->Finish(&st, reinterpret_cast<void*>(5));
  step();
  cq.Shutdown();
  while (cq.Next(&tag, &ok)) {
  }
  return bytes;
}

TEST_P(LifecycleTest, HealthAndReflection) {
  ServerHarness h(GetParam());
  EXPECT_EQ(HealthStatus(h.Channel()), 1);
  // Per-service names, as health clients and balancers ask for them.
  EXPECT_EQ(HealthStatus(h.Channel(), "hapticpd.v1.SceneService"), 1);
  EXPECT_EQ(HealthStatus(h.Channel(), "hapticpd.v1.HapticService"), 1);
  EXPECT_EQ(HealthStatus(h.Channel(), "hapticpd.v1.NoSuchService"), -1);
  const std::string listing = ReflectionListing(h.Channel());
  EXPECT_NE(listing.find("hapticpd.v1.SceneService"), std::string::npos);
  EXPECT_NE(listing.find("hapticpd.v1.HapticService"), std::string::npos);
}

TEST(Lifecycle, HealthIsNotServingAndCallsAreRefusedUntilTheStateIsLoaded) {
  int health_while_loading = -5;
  grpc::Status list_while_loading;
  int checked_port = 0;
  server::ServerOptions opt;
  opt.listen = "127.0.0.1:0";
  opt.status_interval_s = 0;
  opt.while_loading = [&](int port) {
    checked_port = port;
    auto channel = grpc::CreateChannel("127.0.0.1:" + std::to_string(port),
                                       grpc::InsecureChannelCredentials());
    health_while_loading = HealthStatus(channel);
    auto stub = v1::SceneService::NewStub(channel);
    v1::ListScenesResponse list;
    auto ctx = Ctx();
    list_while_loading = stub->ListScenes(ctx.get(), {}, &list);
  };
  server::HapticServer srv(opt);
  srv.Start();
  ASSERT_GT(checked_port, 0);
  EXPECT_EQ(health_while_loading, 2) << "health while loading (2: NOT_SERVING)";
  EXPECT_EQ(list_while_loading.error_code(), grpc::StatusCode::UNAVAILABLE);
  EXPECT_EQ(list_while_loading.error_message(),
            "server is loading its state (health: NOT_SERVING); retry shortly");
  auto channel = grpc::CreateChannel("127.0.0.1:" + std::to_string(srv.port()),
                                     grpc::InsecureChannelCredentials());
  EXPECT_EQ(HealthStatus(channel), 1);
  srv.Shutdown();
}

// gRPC takes a port above 65535 modulo 65536 and would listen on another.
TEST(Lifecycle, APortOutOfRangeIsRefused) {
  for (const std::string port : {"70000", "65536", "99999999999999999999999"}) {
    server::ServerOptions opt = server::ServerOptions::InProcess();
    opt.listen = "127.0.0.1:" + port;
    server::HapticServer srv(opt);
    try {
      srv.Start();
      ADD_FAILURE() << "a server started on " << opt.listen << " (port " << srv.port() << ")";
      srv.Shutdown();
    } catch (const std::runtime_error& e) {
      EXPECT_EQ(std::string(e.what()), "cannot listen on " + opt.listen + ": port " + port +
                                           " is out of range (1-65535, or 0 for any free port)");
    }
  }
}

TEST(Lifecycle, ASecondServerOnAPortInUseDoesNotStart) {
  server::ServerOptions opt = server::ServerOptions::InProcess();
  server::HapticServer first(opt);
  first.Start();
  ASSERT_GT(first.port(), 0);
  opt.listen = "127.0.0.1:" + std::to_string(first.port());
  server::HapticServer second(opt);
  try {
    second.Start();
    ADD_FAILURE() << "a second server started on port " << first.port();
  } catch (const std::runtime_error& e) {
    EXPECT_EQ(std::string(e.what()),
              "cannot listen on " + opt.listen +
                  ": address already in use (is another server running on that port?)");
  }
  auto channel = grpc::CreateChannel("127.0.0.1:" + std::to_string(first.port()),
                                     grpc::InsecureChannelCredentials());
  EXPECT_EQ(HealthStatus(channel), 1) << "the first server still serves";
  first.Shutdown();
}

TEST_P(LifecycleTest, ClientCancellationLeavesNothingBehind) {
  ServerHarness h(GetParam());
  auto scenes = h.Scenes();
  ASSERT_TRUE(AddShape(*scenes, "default", "box", "floor", MakePose(0, 0, 0)).ok());
  auto haptics = h.Haptics();
  for (int round = 0; round < 3; ++round) {
    Session a(*haptics), b(*haptics);
    ASSERT_TRUE(a.Open(Session::DefaultHello()).ok());
    ASSERT_TRUE(b.Open(Session::DefaultHello()).ok());
    for (std::uint64_t k = 1; k <= 50; ++k) a.Send(k, MakePose(0, 0, 0.055));  // unread answers
    ASSERT_TRUE(b.Send(1, MakePose(0, 0, 0.055)));
    ASSERT_TRUE(b.Next());
    auto ctx = Ctx();
    v1::WatchRequest wr;
    wr.set_scene_id("default");
    auto watch = scenes->Watch(ctx.get(), wr);
    v1::SceneEvent ev;
    ASSERT_TRUE(watch->Read(&ev));
    ASSERT_TRUE(WaitUntil([&] { return h.server().counts().sessions == 2; }));
    a.Cancel();
    b.Cancel();
    ctx->TryCancel();
    EXPECT_EQ(a.Finish().error_code(), grpc::StatusCode::CANCELLED);
    EXPECT_EQ(b.Finish().error_code(), grpc::StatusCode::CANCELLED);
    watch->Finish();
    ASSERT_TRUE(WaitUntil([&] { return h.server().counts().active_calls == 0; }))
        << "calls left: " << h.server().counts().active_calls;
    EXPECT_EQ(h.server().counts().sessions, 0);
    EXPECT_EQ(h.server().counts().observers, 0);
  }
  // An upload abandoned half-way is not added.
  {
    auto ctx = Ctx();
    v1::Body body;
    auto writer = scenes->AddBody(ctx.get(), &body);
    v1::AddBodyRequest head;
    head.mutable_header()->set_scene_id("default");
    head.mutable_header()->set_format(v1::MESH_FORMAT_OBJ);
    ASSERT_TRUE(writer->Write(head));
    v1::AddBodyRequest chunk;
    chunk.set_chunk("v 0 0 0\n");
    writer->Write(chunk);
    ctx->TryCancel();
    EXPECT_FALSE(writer->Finish().ok());
  }
  ASSERT_TRUE(WaitUntil([&] { return h.server().counts().active_calls == 0; }));
  EXPECT_EQ(GetScene(*scenes, "default").bodies_size(), 1);
}

TEST_P(LifecycleTest, ShutdownWithSessionsAndObserversOpenEndsThemAll) {
  auto h = std::make_unique<ServerHarness>(GetParam());
  auto scenes = h->Scenes();
  ASSERT_TRUE(AddShape(*scenes, "default", "box", "floor", MakePose(0, 0, 0)).ok());
  auto haptics = h->Haptics();
  Session reading(*haptics), stalled(*haptics);
  ASSERT_TRUE(reading.Open(Session::DefaultHello()).ok());
  ASSERT_TRUE(stalled.Open(Session::DefaultHello()).ok());
  ASSERT_TRUE(reading.Send(1, MakePose(0, 0, 0.055)));
  ASSERT_TRUE(reading.Next());
  for (std::uint64_t k = 1; k <= 20; ++k) stalled.Send(k, MakePose(0, 0, 0.055));
  auto wctx = Ctx();
  v1::WatchRequest wr;
  wr.set_scene_id("default");
  wr.set_rate_hz(500);
  auto watch = scenes->Watch(wctx.get(), wr);
  v1::SceneEvent ev;
  ASSERT_TRUE(watch->Read(&ev));
  ASSERT_TRUE(WaitUntil([&] { return h->server().counts().sessions == 2; }));

  std::thread stopper([&] { h->server().Shutdown(); });
  // A client that keeps reading sees its stream end with UNAVAILABLE.
  while (reading.Next()) {
  }
  const auto st = reading.Finish();
  EXPECT_EQ(st.error_code(), grpc::StatusCode::UNAVAILABLE) << st.error_message();
  while (watch->Read(&ev)) {
  }
  const auto ws = watch->Finish();
  EXPECT_TRUE(ws.error_code() == grpc::StatusCode::UNAVAILABLE ||
              ws.error_code() == grpc::StatusCode::CANCELLED)
      << ws.error_message();
  stopper.join();
  EXPECT_EQ(h->server().counts().active_calls, 0);
  EXPECT_EQ(h->server().counts().sessions, 0);
  EXPECT_EQ(h->server().counts().observers, 0);
  // After shutdown, new calls fail instead of hanging. (Over TCP only: gRPC's
  // in-process channel must not be used once its server is shut down.)
  if (GetParam() == Transport::kTcp) {
    auto ctx = std::make_unique<grpc::ClientContext>();
    ctx->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
    v1::ListScenesResponse list;
    EXPECT_FALSE(scenes->ListScenes(ctx.get(), {}, &list).ok());
  }
  stalled.Cancel();
  h.reset();
}

INSTANTIATE_TEST_SUITE_P(Transports, LifecycleTest,
                         ::testing::Values(Transport::kInProcess, Transport::kTcp), TransportName);

TEST(SceneFileTest, PreloadsBodiesAndRejectsBadFiles) {
  const auto dir = std::filesystem::temp_directory_path() /
                   ("hapticpd_scene_test_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "tet.obj")
      << "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
  std::ofstream(dir / "lab.json") << R"({"scene": "lab", "bodies": [
    {"id": "tet", "mesh": "tet.obj", "pose": {"position": [0, 0, 1], "orientation": [0, 0, 0, 1]},
     "material": {"stiffness": 2500}, "movable": true},
    {"id": "floor", "shape": "plate:1,1,0.01"}]})";
  std::ofstream(dir / "bad.json") << R"({"bodies": [{"id": "x", "shape": "box",
    "pose": {"position": [0, 0, 0], "orientation": [2, 0, 0, 0]}}]})";
  std::ofstream(dir / "missing.json") << R"({"bodies": [{"mesh": "nope.obj"}]})";
  {
    server::ServerOptions opt;
    opt.listen = "";
    opt.status_interval_s = 0;
    opt.scene_files = {(dir / "lab.json").string()};
    server::HapticServer srv(opt);
    srv.Start();
    auto stub = v1::SceneService::NewStub(srv.InProcessChannel());
    const v1::Scene scene = GetScene(*stub, "lab");
    ASSERT_EQ(scene.bodies_size(), 2);
    EXPECT_EQ(scene.bodies(0).body_id(), "tet");
    EXPECT_TRUE(scene.bodies(0).movable());
    EXPECT_DOUBLE_EQ(scene.bodies(0).material().stiffness(), 2500);
    EXPECT_DOUBLE_EQ(scene.bodies(0).pose().position().z(), 1);
    EXPECT_EQ(srv.counts().scenes, 1);  // no "default" when scene files are given
  }
  for (const char* f : {"bad.json", "missing.json"}) {
    server::ServerOptions opt;
    opt.listen = "";
    opt.status_interval_s = 0;
    opt.scene_files = {(dir / f).string()};
    server::HapticServer srv(opt);
    try {
      srv.Start();
      ADD_FAILURE() << f << " was accepted";
    } catch (const std::runtime_error& e) {
      const std::string what = e.what();
      EXPECT_EQ(what.rfind((dir / f).string(), 0), 0u) << what;
      EXPECT_NE(what.find("bodies[0]"), std::string::npos) << what;
    }
  }
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace hapticpd::testing
