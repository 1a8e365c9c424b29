// A hapticpd server for tests, reached either through gRPC's in-process
// channel or over TCP on 127.0.0.1 with an ephemeral port, plus small client
// helpers. Every client call carries a generous deadline so that a bug shows
// up as a failed test, never as a hung one.
#pragma once

#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <system_error>
#include <thread>
#include <vector>

#include "hapticpd/v1/haptic.grpc.pb.h"
#include "hapticpd/v1/scene.grpc.pb.h"
#include "server/server.h"

namespace hapticpd::testing {

/// The folder hapticpd_<tag>_<pid>_<n> in the system's temp folder: absent at
/// the start (the test or the code under test makes it), removed with all in
/// it at the end.
class ScopedTempDir {
 public:
  explicit ScopedTempDir(const std::string& tag) {
    static int n = 0;
    path_ = std::filesystem::temp_directory_path() /
            ("hapticpd_" + tag + "_" + std::to_string(::getpid()) + "_" + std::to_string(n++));
    std::filesystem::remove_all(path_);
  }
  ~ScopedTempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  ScopedTempDir(const ScopedTempDir&) = delete;
  ScopedTempDir& operator=(const ScopedTempDir&) = delete;
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

enum class Transport { kInProcess, kTcp };

inline std::string TransportName(const ::testing::TestParamInfo<Transport>& info) {
  return info.param == Transport::kInProcess ? "InProcess" : "Tcp";
}

/// Deadline for any single client call or stream in the tests.
inline constexpr std::chrono::seconds kCallDeadline{60};

/// Polls `pred` every 2 ms until it holds or `timeout` passes.
template <typename Pred>
bool WaitUntil(Pred pred, std::chrono::milliseconds timeout = std::chrono::seconds(30)) {
  const auto end = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < end) {
    if (pred()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  return pred();
}

class ServerHarness {
 public:
  explicit ServerHarness(Transport t, server::ServerOptions options = {}) : transport_(t) {
    options.listen = t == Transport::kTcp ? "127.0.0.1:0" : "";
    options.status_interval_s = 0;
    server_ = std::make_unique<server::HapticServer>(options);
    server_->Start();
  }
  ~ServerHarness() { server_->Shutdown(); }

  server::HapticServer& server() { return *server_; }

  /// A new channel (each call: separate connections over TCP).
  std::shared_ptr<grpc::Channel> Channel() {
    if (transport_ == Transport::kInProcess) return server_->InProcessChannel();
    grpc::ChannelArguments args;
    args.SetMaxReceiveMessageSize(64 << 20);
    return grpc::CreateCustomChannel("127.0.0.1:" + std::to_string(server_->port()),
                                     grpc::InsecureChannelCredentials(), args);
  }
  std::unique_ptr<v1::SceneService::Stub> Scenes() { return v1::SceneService::NewStub(Channel()); }
  std::unique_ptr<v1::HapticService::Stub> Haptics() {
    return v1::HapticService::NewStub(Channel());
  }

 private:
  Transport transport_;
  std::unique_ptr<server::HapticServer> server_;
};

/// A harness whose default scene holds a static body "floor" of
/// `floor_shape` at the origin, with a scene and a haptic stub.
class FloorHarness : public ServerHarness {
 public:
  FloorHarness(Transport t, const std::string& floor_shape);

  std::unique_ptr<v1::SceneService::Stub> scenes = Scenes();
  std::unique_ptr<v1::HapticService::Stub> haptics = Haptics();
};

/// A client context with the test deadline and, if given, a token.
inline std::unique_ptr<grpc::ClientContext> Ctx(const std::string& token = "") {
  auto ctx = std::make_unique<grpc::ClientContext>();
  ctx->set_deadline(std::chrono::system_clock::now() + kCallDeadline);
  if (!token.empty()) ctx->AddMetadata("authorization", "Bearer " + token);
  return ctx;
}

inline v1::Pose MakePose(double x, double y, double z, double qw = 1, double qx = 0, double qy = 0,
                         double qz = 0) {
  v1::Pose p;
  p.mutable_position()->set_x(x);
  p.mutable_position()->set_y(y);
  p.mutable_position()->set_z(z);
  p.mutable_orientation()->set_w(qw);
  p.mutable_orientation()->set_x(qx);
  p.mutable_orientation()->set_y(qy);
  p.mutable_orientation()->set_z(qz);
  return p;
}

/// Uploads one AddBody stream made of `requests`.
inline grpc::Status AddBodyRaw(v1::SceneService::Stub& stub,
                               const std::vector<v1::AddBodyRequest>& requests, v1::Body* out,
                               const std::string& token = "") {
  auto ctx = Ctx(token);
  auto writer = stub.AddBody(ctx.get(), out);
  for (const auto& r : requests) {
    if (!writer->Write(r)) break;
  }
  writer->WritesDone();
  return writer->Finish();
}

inline v1::AddBodyRequest ShapeHeader(const std::string& scene, const std::string& shape,
                                      const std::string& id, const v1::Pose& pose,
                                      bool movable = false) {
  v1::AddBodyRequest r;
  auto* h = r.mutable_header();
  h->set_scene_id(scene);
  h->set_shape(shape);
  h->mutable_spec()->set_body_id(id);
  *h->mutable_spec()->mutable_pose() = pose;
  h->mutable_spec()->set_movable(movable);
  return r;
}

/// Adds a built-in shape; returns the status.
inline grpc::Status AddShape(v1::SceneService::Stub& stub, const std::string& scene,
                             const std::string& shape, const std::string& id, const v1::Pose& pose,
                             bool movable = false, const std::string& token = "") {
  v1::Body body;
  return AddBodyRaw(stub, {ShapeHeader(scene, shape, id, pose, movable)}, &body, token);
}

inline v1::Scene GetScene(v1::SceneService::Stub& stub, const std::string& scene) {
  v1::GetSceneRequest req;
  req.set_scene_id(scene);
  v1::Scene out;
  auto ctx = Ctx();
  const grpc::Status s = stub.GetScene(ctx.get(), req, &out);
  EXPECT_TRUE(s.ok()) << s.error_message();
  return out;
}

/// The ids of the scenes `stub`'s server holds, sorted.
inline std::vector<std::string> SceneIds(v1::SceneService::Stub& stub) {
  v1::ListScenesResponse resp;
  auto ctx = Ctx();
  EXPECT_TRUE(stub.ListScenes(ctx.get(), {}, &resp).ok());
  std::vector<std::string> ids;
  for (const auto& s : resp.scenes()) ids.push_back(s.scene_id());
  std::sort(ids.begin(), ids.end());
  return ids;
}

/// CreateScene for `scene`; the summary into `out` when given.
inline grpc::Status CreateScene(v1::SceneService::Stub& stub, const std::string& scene,
                                v1::SceneSummary* out = nullptr) {
  v1::CreateSceneRequest req;
  req.set_scene_id(scene);
  v1::SceneSummary summary;
  auto ctx = Ctx();
  return stub.CreateScene(ctx.get(), req, out ? out : &summary);
}

/// DeleteScene for `scene`.
inline grpc::Status DeleteScene(v1::SceneService::Stub& stub, const std::string& scene) {
  v1::DeleteSceneRequest req;
  req.set_scene_id(scene);
  v1::DeleteSceneResponse resp;
  auto ctx = Ctx();
  return stub.DeleteScene(ctx.get(), req, &resp);
}

/// MoveBody of `body` in `scene` to `pose`; the response into `out` when given.
inline grpc::Status MoveBody(v1::SceneService::Stub& stub, const std::string& scene,
                             const std::string& body, const v1::Pose& pose,
                             v1::MoveBodyResponse* out = nullptr) {
  v1::MoveBodyRequest req;
  req.set_scene_id(scene);
  req.set_body_id(body);
  *req.mutable_pose() = pose;
  v1::MoveBodyResponse resp;
  auto ctx = Ctx();
  return stub.MoveBody(ctx.get(), req, out ? out : &resp);
}

/// RemoveBody of `body` from `scene`.
inline grpc::Status RemoveBody(v1::SceneService::Stub& stub, const std::string& scene,
                               const std::string& body) {
  v1::RemoveBodyRequest req;
  req.set_scene_id(scene);
  req.set_body_id(body);
  v1::RemoveBodyResponse resp;
  auto ctx = Ctx();
  return stub.RemoveBody(ctx.get(), req, &resp);
}

inline FloorHarness::FloorHarness(Transport t, const std::string& floor_shape) : ServerHarness(t) {
  const grpc::Status s = AddShape(*scenes, "default", floor_shape, "floor", MakePose(0, 0, 0));
  EXPECT_TRUE(s.ok()) << "adding the floor: " << s.error_message();
}

/// One device session over the synchronous streaming API.
class Session {
 public:
  Session(v1::HapticService::Stub& stub, const std::string& token = "") : ctx_(Ctx(token)) {
    stream_ = stub.Couple(ctx_.get());
  }
  ~Session() {
    if (!finished_) {
      ctx_->TryCancel();
      stream_->Finish();
    }
  }

  static v1::Hello DefaultHello(const std::string& scene = "default",
                                v1::PdMode mode = v1::PD_MODE_PDT,
                                const std::string& probe_shape = "sphere:0.01,2") {
    v1::Hello h;
    h.set_protocol_version(1);
    h.set_scene_id(scene);
    h.set_mode(mode);
    h.set_probe_shape(probe_shape);
    h.set_client_name("test");
    return h;
  }

  /// Sends the hello and reads the welcome; on failure returns the status.
  grpc::Status Open(const v1::Hello& hello) {
    v1::CoupleRequest req;
    *req.mutable_hello() = hello;
    stream_->Write(req);
    v1::CoupleResponse resp;
    if (!stream_->Read(&resp)) return Finish();
    if (!resp.has_welcome()) return grpc::Status(grpc::StatusCode::INTERNAL, "no welcome");
    welcome_ = resp.welcome();
    return grpc::Status::OK;
  }

  bool Send(std::uint64_t seq, const v1::Pose& pose, std::int64_t client_time_ns = 0) {
    v1::CoupleRequest req;
    req.mutable_pose()->set_sequence(seq);
    *req.mutable_pose()->mutable_pose() = pose;
    req.mutable_pose()->set_client_time_ns(client_time_ns);
    return stream_->Write(req);
  }

  /// The next ContactUpdate, or nothing when the stream ended.
  std::optional<v1::ContactUpdate> Next() {
    v1::CoupleResponse resp;
    while (stream_->Read(&resp)) {
      if (resp.has_update()) return resp.update();
    }
    return std::nullopt;
  }

  bool Write(const v1::CoupleRequest& req) { return stream_->Write(req); }
  /// The next message of any kind (updates, geometry patches); false when
  /// the stream ended.
  bool Read(v1::CoupleResponse* resp) { return stream_->Read(resp); }
  void CloseWrites() { stream_->WritesDone(); }
  grpc::Status Finish() {
    finished_ = true;
    return stream_->Finish();
  }
  void Cancel() { ctx_->TryCancel(); }

  const v1::Welcome& welcome() const { return welcome_; }

  /// Closes the writes and expects the server to end the stream cleanly:
  /// no update left, status OK.
  void ExpectCleanEnd() {
    CloseWrites();
    EXPECT_FALSE(Next().has_value()) << "an update after the writes were closed";
    const grpc::Status st = Finish();
    EXPECT_TRUE(st.ok()) << st.error_message();
  }

 private:
  std::unique_ptr<grpc::ClientContext> ctx_;
  std::unique_ptr<grpc::ClientReaderWriter<v1::CoupleRequest, v1::CoupleResponse>> stream_;
  v1::Welcome welcome_;
  bool finished_ = false;
};

}  // namespace hapticpd::testing
