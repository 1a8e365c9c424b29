// `hapticpd view`'s library (client/viewer): the HTTP side through a Beast
// client in the test (page, three.js, meshes by hash, tokens, TLS, bad
// input), and the WebSocket side against a real in-process server (the
// scene on connect, live changes, recovery after the server restarts), and
// the per-browser queues of HttpServer (a browser that never reads loses
// pose frames and telemetry batches, never another browser's). Every wait
// is bounded and about the order of events, never about wall-clock speed.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <boost/asio.hpp>
#include <boost/asio/ssl.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/ssl.hpp>
#include <boost/beast/websocket.hpp>
#include <chrono>
#include <cstring>
#include <future>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "client/viewer/http_server.h"
#include "client/viewer/mesh_store.h"
#include "client/viewer/scene_json.h"
#include "client/viewer/viewer.h"
#include "tests/server/server_harness.h"
#include "tests/test_util.h"

namespace hapticpd {
namespace {

namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
namespace net = boost::asio;
using tcp = net::ip::tcp;
using nlohmann::json;
using testing::MakePose;
using testing::WaitUntil;

constexpr auto kWait = std::chrono::seconds(30);

struct Reply {
  int status = 0;
  std::map<std::string, std::string> headers;
  std::string body;
  std::string header(const std::string& name) const {
    const auto it = headers.find(name);
    return it == headers.end() ? "" : it->second;
  }
};

Reply FromBeast(const http::response<http::string_body>& res) {
  Reply r;
  r.status = static_cast<int>(res.result_int());
  for (const auto& f : res) r.headers[std::string(f.name_string())] = std::string(f.value());
  r.body = res.body();
  return r;
}

template <class Stream>
Reply GetOn(Stream& stream, const std::string& target, const std::string& bearer) {
  http::request<http::empty_body> req{http::verb::get, target, 11};
  req.set(http::field::host, "127.0.0.1");
  if (!bearer.empty()) req.set(http::field::authorization, "Bearer " + bearer);
  http::write(stream, req);
  beast::flat_buffer buf;
  http::response_parser<http::string_body> parser;
  parser.body_limit(64 << 20);
  http::read(stream, buf, parser);
  return FromBeast(parser.get());
}

tcp::endpoint Loopback(int port) {
  return tcp::endpoint(net::ip::make_address("127.0.0.1"), static_cast<unsigned short>(port));
}

/// One GET over a fresh connection; HTTPS (any certificate) when `tls`.
Reply Get(int port, const std::string& target, const std::string& bearer = "", bool tls = false) {
  net::io_context ioc;
  if (!tls) {
    beast::tcp_stream stream(ioc);
    stream.connect(Loopback(port));
    return GetOn(stream, target, bearer);
  }
  net::ssl::context ctx(net::ssl::context::tls_client);
  ctx.set_verify_mode(net::ssl::verify_none);
  beast::ssl_stream<beast::tcp_stream> stream(ioc, ctx);
  beast::get_lowest_layer(stream).connect(Loopback(port));
  stream.handshake(net::ssl::stream_base::client);
  return GetOn(stream, target, bearer);
}

/// Raw bytes in, the response (status line, headers, body) out.
Reply Raw(int port, const std::string& bytes) {
  net::io_context ioc;
  beast::tcp_stream stream(ioc);
  stream.connect(Loopback(port));
  beast::error_code ec;
  // The viewer may answer and stop reading before all of an oversized request is sent.
  net::write(stream, net::buffer(bytes), ec);
  beast::flat_buffer buf;
  http::response<http::string_body> res;
  http::read(stream, buf, res, ec);
  if (ec) return Reply{};  // status 0: no HTTP answer
  return FromBeast(res);
}

/// A WebSocket browser stand-in: every read has a deadline (a test fails,
/// never hangs). `receive_buffer` > 0 shrinks the socket's receive buffer
/// (a browser that stops reading stalls the viewer's writes sooner).
class WsClient {
 public:
  explicit WsClient(int port, const std::string& target = "/ws", int receive_buffer = 0)
      : ws_(ioc_) {
    auto& sock = beast::get_lowest_layer(ws_).socket();
    sock.open(tcp::v4());
    if (receive_buffer > 0) sock.set_option(net::socket_base::receive_buffer_size(receive_buffer));
    beast::get_lowest_layer(ws_).connect(Loopback(port));
    ws_.handshake("127.0.0.1", target, ec_);
  }
  bool open() const { return !ec_; }
  const beast::error_code& error() const { return ec_; }

  /// The next message, or nullopt when none comes within `timeout` or the
  /// connection ends.
  std::optional<json> Next(std::chrono::milliseconds timeout = kWait) {
    buf_.consume(buf_.size());
    bool done = false;
    beast::error_code ec;
    ws_.async_read(buf_, [&](beast::error_code e, std::size_t) {
      ec = e;
      done = true;
    });
    ioc_.restart();
    ioc_.run_for(timeout);
    if (!done) {
      beast::get_lowest_layer(ws_).socket().close();
      ioc_.restart();
      ioc_.run();
      return std::nullopt;
    }
    if (ec) return std::nullopt;
    last_text_ = beast::buffers_to_string(buf_.data());
    return json::parse(last_text_);
  }

  /// Messages until one of `type` for which `pred` holds; nullopt if none.
  template <class Pred>
  std::optional<json> Until(const std::string& type, Pred pred) {
    const auto end = std::chrono::steady_clock::now() + kWait;
    while (std::chrono::steady_clock::now() < end) {
      auto m = Next(std::chrono::duration_cast<std::chrono::milliseconds>(
          end - std::chrono::steady_clock::now()));
      if (!m) return std::nullopt;
      if ((*m)["type"] == type && pred(*m)) return m;
    }
    return std::nullopt;
  }
  std::optional<json> Until(const std::string& type) {
    return Until(type, [](const json&) { return true; });
  }

  /// False when the viewer closed the connection before all was sent.
  bool Send(const std::string& text, bool binary = false) {
    ws_.binary(binary);
    beast::error_code ec;
    ws_.write(net::buffer(text), ec);
    return !ec;
  }

 private:
  net::io_context ioc_;
  websocket::stream<beast::tcp_stream> ws_;
  beast::flat_buffer buf_;
  beast::error_code ec_;
  std::string last_text_;
};

bool HasBody(const json& bodies, const std::string& id) {
  for (const json& b : bodies) {
    if (b["id"] == id) return true;
  }
  return false;
}

/// A server in-process on 127.0.0.1 with a box in its default scene, and a
/// viewer of that scene on a free loopback port.
class ViewerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    server_ = StartServer(0);
    auto stub = Scenes();
    v1::Body body;
    ASSERT_TRUE(testing::AddBodyRaw(*stub,
                                    {testing::ShapeHeader("default", "box:0.1,0.1,0.05", "box",
                                                          MakePose(0, 0, 0), true)},
                                    &body)
                    .ok());
    box_triangles_ = body.mesh_info().triangles();
  }
  void TearDown() override {
    if (viewer_) viewer_->Stop();
    if (server_) server_->Shutdown();
  }

  static std::unique_ptr<server::HapticServer> StartServer(int port) {
    server::ServerOptions o = server::ServerOptions::InProcess();
    o.listen = "127.0.0.1:" + std::to_string(port);
    o.shutdown_grace_s = 0.2;
    auto s = std::make_unique<server::HapticServer>(o);
    s->Start();
    return s;
  }

  std::unique_ptr<v1::SceneService::Stub> Scenes() {
    return v1::SceneService::NewStub(grpc::CreateChannel(
        "127.0.0.1:" + std::to_string(server_port_ ? server_port_ : server_->port()),
        grpc::InsecureChannelCredentials()));
  }

  viewer::ViewerOptions Options(const std::string& listen = "127.0.0.1:0") {
    viewer::ViewerOptions o;
    o.http.listen = listen;
    server_port_ = server_->port();
    const std::string address = "127.0.0.1:" + std::to_string(server_port_);
    o.server = address;
    o.make_channel = [address] {
      return grpc::CreateChannel(address, grpc::InsecureChannelCredentials());
    };
    o.reconnect_min_s = 0.05;
    o.reconnect_max_s = 0.2;
    return o;
  }

  /// Starts the viewer and waits until it has the server's scene.
  void StartViewer(viewer::ViewerOptions o) {
    const std::string token = o.http.viewer_token;
    const bool tls = !o.http.tls_cert.empty();
    viewer_ = std::make_unique<viewer::Viewer>(std::move(o));
    viewer_->Start();
    ASSERT_TRUE(WaitUntil(
        [&] {
          return json::parse(
                     Get(viewer_->port(), "/healthz", token, tls).body)["server_connected"] == true;
        },
        kWait));
  }

  std::unique_ptr<server::HapticServer> server_;
  int server_port_ = 0;
  std::unique_ptr<viewer::Viewer> viewer_;
  std::uint32_t box_triangles_ = 0;
};

TEST_F(ViewerTest, ServesThePageAndThreeJs) {
  StartViewer(Options());
  const int port = viewer_->port();
  const Reply page = Get(port, "/");
  EXPECT_EQ(page.status, 200);
  EXPECT_EQ(page.header("Content-Type"), "text/html; charset=utf-8");
  EXPECT_NE(page.body.find("<canvas id=\"scene\">"), std::string::npos);
  EXPECT_NE(page.body.find("\"three\": \"/three/build/three.module.js\""), std::string::npos)
      << "without a viewer token the import map carries no token";
  EXPECT_EQ(page.body.find("{{q}}"), std::string::npos);
  const Reply three = Get(port, "/three/build/three.module.js");
  EXPECT_EQ(three.status, 200);
  EXPECT_EQ(three.header("Content-Type"), "text/javascript; charset=utf-8");
  EXPECT_NE(three.body.find("var REVISION = '111';"), std::string::npos);
  const Reply orbit = Get(port, "/three/examples/jsm/controls/OrbitControls.js");
  EXPECT_EQ(orbit.status, 200);
  EXPECT_NE(orbit.body.find("OrbitControls"), std::string::npos);
  for (const char* path : {"/viewer.js", "/plot.js", "/style.css"}) {
    EXPECT_EQ(Get(port, path).status, 200) << path;
  }
  EXPECT_NE(Get(port, "/viewer.js").body.find("window.hapticpdView"), std::string::npos);
  EXPECT_EQ(Get(port, "/nothing-here").status, 404);
  const json health = json::parse(Get(port, "/healthz").body);
  EXPECT_EQ(health["server_connected"], true);
  EXPECT_EQ(health["scene_id"], "default");
  EXPECT_EQ(health["browsers"], 0);
  EXPECT_TRUE(health["revision"].is_number());
}

TEST_F(ViewerTest, ABrowserGetsTheWholeSceneOnConnectAndMeshesByHash) {
  StartViewer(Options());
  WsClient ws(viewer_->port());
  ASSERT_TRUE(ws.open()) << ws.error().message();
  const auto scene = ws.Next();
  ASSERT_TRUE(scene);
  EXPECT_EQ((*scene)["type"], "scene");
  EXPECT_EQ((*scene)["scene_id"], "default");
  EXPECT_EQ((*scene)["server_connected"], true);
  ASSERT_EQ((*scene)["bodies"].size(), 1u);
  const json& box = (*scene)["bodies"][0];
  EXPECT_EQ(box["id"], "box");
  EXPECT_EQ(box["info"]["triangles"], box_triangles_);
  const std::string hash = box["mesh"];
  ASSERT_TRUE(viewer::IsContentHash(hash)) << hash;

  const Reply mesh = Get(viewer_->port(), "/mesh/" + hash);
  ASSERT_EQ(mesh.status, 200);
  EXPECT_EQ(mesh.header("Content-Type"), "application/octet-stream");
  EXPECT_EQ(mesh.header("Cache-Control"), "public, max-age=31536000, immutable");
  EXPECT_EQ(mesh.header("ETag"), "\"" + hash + "\"");
  ASSERT_GE(mesh.body.size(), 16u);
  EXPECT_EQ(mesh.body.substr(0, 4), "HPDM");
  std::uint32_t head[3];
  std::memcpy(head, mesh.body.data() + 4, sizeof head);
  EXPECT_EQ(head[0], 1u);
  EXPECT_EQ(head[2], box_triangles_);
  EXPECT_EQ(mesh.body.size(), 16u + 12u * head[1] + 12u * head[2]);
  EXPECT_EQ(viewer::ContentHash(mesh.body), hash) << "the name is the content's hash";

  EXPECT_EQ(Get(viewer_->port(), "/mesh/" + std::string(32, '0')).status, 404);
  EXPECT_EQ(Get(viewer_->port(), "/mesh/xyz").status, 400);
  EXPECT_EQ(Get(viewer_->port(), "/mesh/" + hash + "0").status, 400);
  // Pose frames follow, each with this browser's own drop counters.
  const auto poses = ws.Until("poses");
  ASSERT_TRUE(poses);
  EXPECT_TRUE((*poses)["poses_dropped"].is_number());
  EXPECT_TRUE((*poses)["batches_dropped"].is_number());
  EXPECT_TRUE(HasBody((*poses)["bodies"], "box"));
  EXPECT_EQ(json::parse(Get(viewer_->port(), "/healthz").body)["browsers"], 1);
}

TEST_F(ViewerTest, BodiesInjectedMovedAndRemovedReachTheBrowserLive) {
  StartViewer(Options());
  WsClient ws(viewer_->port());
  ASSERT_TRUE(ws.Until("scene"));
  auto stub = Scenes();
  ASSERT_TRUE(
      testing::AddShape(*stub, "default", "sphere:0.02,1", "ball", MakePose(0.3, 0, 0), true).ok());
  const auto added = ws.Until("bodies", [](const json& m) { return HasBody(m["added"], "ball"); });
  ASSERT_TRUE(added);
  EXPECT_TRUE(viewer::IsContentHash((*added)["added"][0]["mesh"].get<std::string>()));

  ASSERT_TRUE(testing::MoveBody(*stub, "default", "ball", MakePose(0.3, 0.1, 0)).ok());
  ASSERT_TRUE(ws.Until("poses", [](const json& m) {
    for (const json& b : m["bodies"]) {
      if (b["id"] == "ball" && b["pose"]["p"][1] == 0.1) return true;
    }
    return false;
  }));

  ASSERT_TRUE(testing::RemoveBody(*stub, "default", "ball").ok());
  ASSERT_TRUE(ws.Until("bodies", [](const json& m) {
    for (const json& id : m["removed"]) {
      if (id == "ball") return true;
    }
    return false;
  }));
  // A browser connecting now gets the scene as it is: the box, no ball.
  WsClient late(viewer_->port());
  const auto scene = late.Until("scene");
  ASSERT_TRUE(scene);
  EXPECT_TRUE(HasBody((*scene)["bodies"], "box"));
  EXPECT_FALSE(HasBody((*scene)["bodies"], "ball"));
}

TEST_F(ViewerTest, TheServerGoingAwayIsShownAndTheSceneResentOnReconnect) {
  testing::ScopedExpectLogs expect;  // the server's shutdown
  StartViewer(Options());
  WsClient ws(viewer_->port());
  ASSERT_TRUE(ws.Until("scene"));
  const int port = server_->port();
  server_->Shutdown();
  ASSERT_TRUE(ws.Until("link", [](const json& m) { return m["server_connected"] == false; }));
  EXPECT_EQ(json::parse(Get(viewer_->port(), "/healthz").body)["server_connected"], false);
  // A new server on the same port, with other bodies: the browser gets the
  // whole new scene.
  server_ = StartServer(port);
  auto stub = Scenes();
  ASSERT_TRUE(
      testing::AddShape(*stub, "default", "sphere:0.02,1", "fresh", MakePose(0, 0, 0), true).ok());
  // The viewer may reconnect before or after the body is added (under TSan
  // it did before): the browser gets it in the new scene, or as an addition
  // right after it.
  const auto scene = ws.Until("scene", [](const json& m) { return m["server_connected"] == true; });
  ASSERT_TRUE(scene);
  EXPECT_FALSE(HasBody((*scene)["bodies"], "box"));
  if (!HasBody((*scene)["bodies"], "fresh")) {
    EXPECT_TRUE(ws.Until("bodies", [](const json& m) { return HasBody(m["added"], "fresh"); }));
  }
  EXPECT_GE(viewer_->counts().reconnects, 1u);
}

TEST_F(ViewerTest, OffLoopbackAViewerTokenIsRequiredAndChecked) {
  try {
    viewer::Viewer v(Options("0.0.0.0:0"));
    FAIL() << "a non-loopback listen without a viewer token was accepted";
  } catch (const viewer::ViewerError& e) {
    EXPECT_NE(std::string(e.what()).find("--viewer-token"), std::string::npos) << e.what();
  }
  auto o = Options("0.0.0.0:0");
  o.http.viewer_token = "s3cret/+";
  StartViewer(std::move(o));
  const int port = viewer_->port();
  for (const char* target : {"/", "/healthz", "/viewer.js", "/three/build/three.module.js",
                             "/?token=wrong", "/?token=s3cret", "/?tok=s3cret%2F%2B"}) {
    const Reply r = Get(port, target);
    EXPECT_EQ(r.status, 401) << target;
    EXPECT_EQ(r.header("WWW-Authenticate"), "Bearer") << target;
  }
  EXPECT_EQ(Get(port, "/", "wrong").status, 401);
  const Reply page = Get(port, "/?token=s3cret%2F%2B");
  EXPECT_EQ(page.status, 200);
  // The page's module and style requests carry the token it was opened with.
  EXPECT_NE(page.body.find("/three/build/three.module.js?token=s3cret%2F%2B"), std::string::npos);
  EXPECT_EQ(Get(port, "/healthz", "s3cret/+").status, 200);
  EXPECT_EQ(Get(port, "/three/build/three.module.js?token=s3cret%2F%2B").status, 200);

  WsClient refused(port, "/ws");
  EXPECT_FALSE(refused.open());
  WsClient wrong(port, "/ws?token=s3cret");
  EXPECT_FALSE(wrong.open());
  WsClient ok(port, "/ws?token=s3cret%2F%2B");
  ASSERT_TRUE(ok.open()) << ok.error().message();
  EXPECT_TRUE(ok.Until("scene"));
  EXPECT_EQ(viewer_->counts().http.ws_connects, 1u);
}

TEST_F(ViewerTest, ServesHttpsWithACertificate) {
  auto o = Options();
  o.http.tls_cert = std::string(HAPTICPD_TESTDATA_DIR) + "/tls/server.crt";
  o.http.tls_key = std::string(HAPTICPD_TESTDATA_DIR) + "/tls/server.key";
  StartViewer(std::move(o));
  EXPECT_EQ(viewer_->url().substr(0, 8), "https://");
  const Reply health = Get(viewer_->port(), "/healthz", "", true);
  EXPECT_EQ(health.status, 200);
  EXPECT_EQ(json::parse(health.body)["server_connected"], true);
  EXPECT_NE(Get(viewer_->port(), "/", "", true).body.find("hapticpd view"), std::string::npos);
  // Plain HTTP to the TLS port gets no page.
  EXPECT_NE(Raw(viewer_->port(), "GET / HTTP/1.1\r\nHost: x\r\n\r\n").status, 200);

  auto bad = Options();
  bad.http.tls_cert = std::string(HAPTICPD_TESTDATA_DIR) + "/tls/missing.crt";
  bad.http.tls_key = bad.http.tls_cert;
  EXPECT_THROW(viewer::Viewer{bad}, viewer::ViewerError);
  auto half = Options();
  half.http.tls_cert = std::string(HAPTICPD_TESTDATA_DIR) + "/tls/server.crt";
  EXPECT_THROW(viewer::Viewer{half}, viewer::ViewerError);
}

TEST_F(ViewerTest, BadHttpRequestsGetClearErrors) {
  StartViewer(Options());
  const int port = viewer_->port();
  const std::string before = Get(port, "/healthz").body;
  struct Case {
    std::string bytes;
    int status;
  };
  const std::string huge_header(64 * 1024, 'a');
  const Case cases[] = {
      {"GET ../etc/passwd HTTP/1.1\r\nHost: x\r\n\r\n", 400},
      {"GET /mesh/../../etc/passwd HTTP/1.1\r\nHost: x\r\n\r\n", 400},
      {"GET /%2e%2e/secret HTTP/1.1\r\nHost: x\r\n\r\n", 404},
      {"GET /ws HTTP/1.1\r\nHost: x\r\n\r\n", 426},
      {"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 2\r\n\r\nhi", 405},
      {"HELLO\r\n\r\n", 400},
      {"GET / HTTP/1.1\r\nHost: x\r\nX-Big: " + huge_header + "\r\n\r\n", 431},
      {"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 1000000\r\n\r\n" + std::string(1000, 'b'),
       413},
  };
  for (const Case& c : cases) {
    const Reply r = Raw(port, c.bytes);
    EXPECT_EQ(r.status, c.status) << c.bytes.substr(0, 60);
    EXPECT_FALSE(r.body.empty()) << "an error says why: " << c.bytes.substr(0, 60);
  }
  // Still serving, unchanged.
  EXPECT_EQ(Get(port, "/healthz").body, before);
  EXPECT_EQ(Get(port, "/").status, 200);
}

TEST_F(ViewerTest, BadWebSocketMessagesGetErrorsAndNeverCrash) {
  StartViewer(Options());
  WsClient ws(viewer_->port());
  ASSERT_TRUE(ws.Until("scene"));
  ASSERT_TRUE(ws.Send(R"({"type":"ping","t":12.5})"));
  const auto pong = ws.Until("pong");
  ASSERT_TRUE(pong);
  EXPECT_EQ((*pong)["t"], 12.5);
  for (const std::string& bad : {std::string("not json"), std::string("[1,2]"),
                                 std::string(R"({"type":"delete-all"})"), std::string("{}")}) {
    ASSERT_TRUE(ws.Send(bad));
    const auto err = ws.Until("error");
    ASSERT_TRUE(err) << bad;
    EXPECT_FALSE((*err)["message"].get<std::string>().empty());
  }
  ASSERT_TRUE(ws.Send("\x01\x02", true));
  ASSERT_TRUE(ws.Until("error"));
  EXPECT_GE(viewer_->counts().http.ws_messages_bad, 5u);
  // Over the size limit, or text that is not UTF-8 (RFC 6455 fails the
  // connection): that browser is closed, the viewer serves on.
  ws.Send(std::string(256 * 1024, ' '));
  while (ws.Next()) {
  }
  WsClient again(viewer_->port());
  ASSERT_TRUE(again.Until("scene"));
  again.Send("\xff\xfe");
  while (again.Next()) {
  }
  WsClient third(viewer_->port());
  EXPECT_TRUE(third.Until("scene"));
}

/// HttpServer alone, fed by the test as the viewer feeds it.
class BrowserQueues : public ::testing::Test {
 protected:
  void SetUp() override {
    viewer::HttpOptions o;
    o.listen = "127.0.0.1:0";
    o.telemetry_queue_s = 0;  // every batch a browser has not taken when the next comes is dropped
    http_ = std::make_unique<viewer::HttpServer>(
        o, viewer::HttpServer::Hooks{[] { return std::string(R"({"type":"scene"})"); },
                                     [] { return json::object(); },
                                     [](std::string_view) { return nullptr; }});
    http_->Start();
  }
  void TearDown() override { http_->Stop(); }

  /// Runs `fn` on the network thread and waits for it.
  template <class Fn>
  void OnNetwork(Fn fn) {
    std::promise<void> done;
    http_->Post([&] {
      fn();
      done.set_value();
    });
    ASSERT_EQ(done.get_future().wait_for(kWait), std::future_status::ready)
        << "the network thread is stuck";
  }

  std::unique_ptr<viewer::HttpServer> http_;
};

TEST_F(BrowserQueues, ABrowserThatNeverReadsDoesNotHoldUpAnother) {
  WsClient stalled(http_->port(), "/ws", 4096);  // reads nothing after the handshake
  WsClient reader(http_->port());
  ASSERT_TRUE(stalled.open() && reader.open());
  ASSERT_TRUE(reader.Until("scene"));
  ASSERT_TRUE(WaitUntil([&] { return http_->counts().browsers == 2; }, kWait));
  // Frames of 64 KiB until the stalled browser's socket is full and its
  // frames are replaced unsent; the reader takes each frame as it comes.
  const std::string pad(64 * 1024, 'x');
  int frame = 0;
  const auto send = [&] {
    ++frame;
    OnNetwork([&] {
      http_->BroadcastPoses(std::make_shared<const std::string>(
          fmt::format(R"("type":"poses","frame":{},"pad":"{}"}})", frame, pad)));
    });
  };
  while (http_->counts().poses_dropped == 0 && frame < 2000) {
    send();
    ASSERT_TRUE(reader.Until("poses", [&](const json& m) { return m["frame"] == frame; }))
        << "frame " << frame;
  }
  ASSERT_GT(http_->counts().poses_dropped, 0u) << "the stalled browser never filled up";
  // The stalled one keeps losing frames; the reader keeps getting each newest one.
  const auto dropped = http_->counts().poses_dropped;
  for (int i = 0; i < 20; ++i) {
    send();
    const auto m = reader.Until("poses", [&](const json& m) { return m["frame"] == frame; });
    ASSERT_TRUE(m);
    EXPECT_EQ((*m)["poses_dropped"], 0) << "the reader lost none";
  }
  EXPECT_GE(http_->counts().poses_dropped, dropped + 19);

  // Telemetry: the stalled browser loses whole batches; the reader gets every one.
  for (int i = 1; i <= 10; ++i) {
    OnNetwork([&] {
      http_->BroadcastTelemetry(std::make_shared<const std::string>(
          fmt::format(R"("type":"telemetry","batch":{}}})", i)));
    });
    const auto m = reader.Until("telemetry", [&](const json& m) { return m["batch"] == i; });
    ASSERT_TRUE(m) << "batch " << i;
    EXPECT_EQ((*m)["batches_dropped"], 0);
  }
  EXPECT_GE(http_->counts().telemetry_dropped, 9u);
}

TEST_F(BrowserQueues, ABrowserFarBehindGetsTheWholeSceneInsteadOfTheBacklog) {
  viewer::HttpOptions o;
  o.listen = "127.0.0.1:0";
  o.max_reliable_bytes = 1 << 20;
  int scenes = 0;
  viewer::HttpServer http(
      o, viewer::HttpServer::Hooks{
             [&] { return fmt::format(R"({{"type":"scene","n":{}}})", ++scenes); },
             [] { return json::object(); }, [](std::string_view) { return nullptr; }});
  http.Start();
  WsClient stalled(http.port(), "/ws", 4096);
  ASSERT_TRUE(WaitUntil([&] { return http.counts().browsers == 1; }, kWait));
  const std::string pad(64 * 1024, 'y');
  for (int i = 0; i < 2000 && http.counts().scene_resends == 0; ++i) {
    std::promise<void> done;
    http.Post([&] {
      http.BroadcastReliable(std::make_shared<const std::string>(
          fmt::format(R"({{"type":"bodies","i":{},"pad":"{}"}})", i, pad)));
      done.set_value();
    });
    ASSERT_EQ(done.get_future().wait_for(kWait), std::future_status::ready);
  }
  EXPECT_GT(http.counts().scene_resends, 0u);
  // Once it reads, the stalled browser gets a whole scene after what was in flight.
  EXPECT_TRUE(stalled.Until("scene", [](const json& m) { return m["n"] == 2; }));
  http.Stop();
}

// The bridge sends announcements before queued telemetry, so the last batch
// of a session that ended can reach the model after the removal. It must not
// bring the session back: a page that connects later would show it forever.
TEST(SceneModelSessions, TelemetryAfterTheRemovalDoesNotBringTheSessionBack) {
  viewer::SceneModel model("live");
  model.Apply({{"type", "scene"}, {"bodies", json::array()}});
  model.Apply({{"type", "sessions"},
               {"added", json::array({json{{"id", "s1"}}})},
               {"removed", json::array()}});
  const json batch = {{"type", "telemetry"},
                      {"sessions", json::array({json{{"id", "s1"}, {"device", "ok"}}})}};
  model.Apply(batch);
  EXPECT_EQ(model.FullScene()["status"].count("s1"), 1u);
  model.Apply({{"type", "sessions"}, {"added", json::array()}, {"removed", {"s1"}}});
  model.Apply(batch);  // sent before the removal, arrived after it
  const json scene = model.FullScene();
  EXPECT_TRUE(scene["sessions"].empty()) << scene.dump();
  EXPECT_EQ(scene["status"].count("s1"), 0u) << scene.dump();
  // A page that connects now learns that the server announces sessions.
  EXPECT_EQ(scene["sessions_announced"], true) << scene.dump();
}

}  // namespace
}  // namespace hapticpd
