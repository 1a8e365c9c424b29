#include "client/viewer/http_server.h"

#include <fmt/format.h>
#include <openssl/crypto.h>
#include <spdlog/spdlog.h>

#include <array>
#include <boost/asio.hpp>
#include <boost/asio/ssl.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/ssl.hpp>
#include <boost/beast/websocket.hpp>
#include <boost/beast/websocket/ssl.hpp>
#include <chrono>
#include <deque>
#include <fstream>
#include <optional>
#include <set>
#include <thread>
#include <type_traits>
#include <vector>

#include "client/viewer/assets.h"
#include "client/viewer/mesh_store.h"

namespace hapticpd::viewer {

namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
namespace net = boost::asio;
namespace ssl = net::ssl;
using tcp = net::ip::tcp;
using Request = http::request<http::string_body>;
using Response = http::response<http::string_body>;
using Clock = std::chrono::steady_clock;

namespace {

constexpr int kMaxBrowsers = 64;
constexpr auto kHttpTimeout = std::chrono::seconds(30);

tcp::endpoint ParseListen(const std::string& listen) {
  const auto colon = listen.rfind(':');
  if (colon == std::string::npos || colon == 0 || colon + 1 == listen.size()) {
    throw ViewerError(fmt::format("--listen: expected HOST:PORT, got '{}'", listen));
  }
  std::string host = listen.substr(0, colon);
  const std::string port_text = listen.substr(colon + 1);
  if (host.size() > 2 && host.front() == '[' && host.back() == ']') {
    host = host.substr(1, host.size() - 2);
  }
  if (host == "localhost") host = "127.0.0.1";
  unsigned long port = 0;
  if (port_text.find_first_not_of("0123456789") != std::string::npos || port_text.size() > 5 ||
      (port = std::stoul(port_text)) > 65535) {
    throw ViewerError(fmt::format("--listen: '{}' is not a port (0-65535)", port_text));
  }
  boost::system::error_code ec;
  const auto addr = net::ip::make_address(host, ec);
  if (ec) {
    throw ViewerError(
        fmt::format("--listen: '{}' is not an IP address (or localhost): {}", host, ec.message()));
  }
  return tcp::endpoint(addr, static_cast<unsigned short>(port));
}

std::string ReadFile(const std::string& path, const char* option) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ViewerError(fmt::format("{}: cannot read {}", option, path));
  return std::string(std::istreambuf_iterator<char>(in), {});
}

/// %XX-decoding of a query value ('+' is a space); nullopt when malformed.
std::optional<std::string> UrlDecode(std::string_view s) {
  std::string out;
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '+') {
      out += ' ';
    } else if (s[i] == '%') {
      if (i + 2 >= s.size()) return std::nullopt;
      const auto hex = [](char c) -> int {
        if (c >= '0' && c <= '9') return c - '0';
        if (c >= 'a' && c <= 'f') return c - 'a' + 10;
        if (c >= 'A' && c <= 'F') return c - 'A' + 10;
        return -1;
      };
      const int hi = hex(s[i + 1]), lo = hex(s[i + 2]);
      if (hi < 0 || lo < 0) return std::nullopt;
      out += static_cast<char>(hi * 16 + lo);
      i += 2;
    } else {
      out += s[i];
    }
  }
  return out;
}

std::string UrlEncode(std::string_view s) {
  std::string out;
  for (unsigned char c : s) {
    if (std::isalnum(c) || c == '-' || c == '_' || c == '.' || c == '~') {
      out += static_cast<char>(c);
    } else {
      out += fmt::format("%{:02X}", c);
    }
  }
  return out;
}

bool SameSecret(std::string_view a, std::string_view b) {
  return a.size() == b.size() && CRYPTO_memcmp(a.data(), b.data(), a.size()) == 0;
}

std::string_view Std(beast::string_view s) { return {s.data(), s.size()}; }
beast::string_view Beast(std::string_view s) { return {s.data(), s.size()}; }

/// A request target split into path and query.
struct Target {
  std::string_view path, query;
};

Target Split(std::string_view target) {
  const auto q = target.find('?');
  if (q == std::string_view::npos) return {target, {}};
  return {target.substr(0, q), target.substr(q + 1)};
}

/// The value of `name` in a query string, decoded; nullopt when absent or malformed.
std::optional<std::string> QueryValue(std::string_view query, std::string_view name) {
  while (!query.empty()) {
    const auto amp = query.find('&');
    const std::string_view item = query.substr(0, amp);
    const auto eq = item.find('=');
    if (item.substr(0, eq) == name && eq != std::string_view::npos) {
      return UrlDecode(item.substr(eq + 1));
    }
    if (amp == std::string_view::npos) break;
    query.remove_prefix(amp + 1);
  }
  return std::nullopt;
}

}  // namespace

bool IsLoopbackListen(const std::string& listen) {
  return ParseListen(listen).address().is_loopback();
}

/// One WebSocket browser's queues (the network thread only).
struct Browser {
  virtual ~Browser() = default;
  virtual void Kick() = 0;

  bool need_scene = true;  // the whole scene goes first, and after a reset
  std::deque<std::shared_ptr<const std::string>> reliable;
  std::size_t reliable_bytes = 0;
  std::shared_ptr<const std::string> pose;  // latest only
  std::deque<std::pair<Clock::time_point, std::shared_ptr<const std::string>>> telemetry;
  std::uint64_t poses_dropped = 0;
  std::uint64_t telemetry_dropped = 0;
};

struct HttpServer::Impl {
  HttpOptions opts;
  Hooks hooks;
  std::optional<ssl::context> ssl_ctx;
  net::io_context ioc{1};
  net::executor_work_guard<net::io_context::executor_type> work{ioc.get_executor()};
  tcp::acceptor acceptor{ioc};
  std::thread thread;
  std::atomic<int> bound_port{0};
  std::atomic<bool> started{false}, stopped{false};
  std::set<std::shared_ptr<Browser>> browsers;  // network thread

  std::atomic<std::uint64_t> ws_connects{0}, poses_dropped{0}, telemetry_dropped{0},
      scene_resends{0}, requests{0}, rejected{0}, ws_bad{0};
  std::atomic<int> browser_count{0};

  Impl(HttpOptions o, Hooks h) : opts(std::move(o)), hooks(std::move(h)) {}

  bool Authorized(const Request& req) const {
    if (opts.viewer_token.empty()) return true;
    const std::string_view auth = Std(req[http::field::authorization]);
    if (auth.size() > 7 && auth.substr(0, 7) == "Bearer " &&
        SameSecret(std::string_view(auth.data() + 7, auth.size() - 7), opts.viewer_token)) {
      return true;
    }
    const auto token = QueryValue(Split(Std(req.target())).query, "token");
    return token && SameSecret(*token, opts.viewer_token);
  }

  Response Error(const Request& req, http::status status, const std::string& text) {
    rejected.fetch_add(1, std::memory_order_relaxed);
    Response res{status, req.version()};
    res.set(http::field::content_type, "text/plain; charset=utf-8");
    res.set(http::field::cache_control, "no-store");
    if (status == http::status::unauthorized) res.set(http::field::www_authenticate, "Bearer");
    res.body() = text + "\n";
    res.keep_alive(false);
    return res;
  }

  /// A bare error for a request that could not be parsed.
  Response Error(http::status status, const std::string& text) {
    Request req;
    req.version(11);
    return Error(req, status, text);
  }

  Response Ok(const Request& req, std::string_view type, std::string body, const char* cache) {
    Response res{http::status::ok, req.version()};
    res.set(http::field::content_type, Beast(type));
    res.set(http::field::cache_control, cache);
    res.body() = std::move(body);
    res.keep_alive(req.keep_alive());
    return res;
  }

  Response Handle(const Request& req) {
    requests.fetch_add(1, std::memory_order_relaxed);
    const std::string_view target = Std(req.target());
    if (target.empty() || target.front() != '/' || target.size() > 1024) {
      return Error(req, http::status::bad_request, "bad request target (expected /PATH, 1 KiB)");
    }
    for (char c : target) {
      if (static_cast<unsigned char>(c) < 0x21 || c == 0x7f) {
        return Error(req, http::status::bad_request, "bad request target (control character)");
      }
    }
    if (req.method() != http::verb::get && req.method() != http::verb::head) {
      return Error(req, http::status::method_not_allowed, "only GET and HEAD");
    }
    if (!Authorized(req)) {
      return Error(req, http::status::unauthorized,
                   "this viewer needs its viewer token: ?token=... or Authorization: Bearer ...");
    }
    const std::string_view path = Split(target).path;
    Response res = Route(req, path);
    res.set(http::field::server, "hapticpd-view");
    res.set("X-Content-Type-Options", "nosniff");
    res.set("Referrer-Policy", "no-referrer");  // the token may be in the URL
    res.prepare_payload();
    if (req.method() == http::verb::head) res.body().clear();  // Content-Length stays
    return res;
  }

  Response Route(const Request& req, std::string_view path) {
    if (path == "/healthz") {
      nlohmann::json j = hooks.health();
      j["browsers"] = browser_count.load();
      return Ok(req, "application/json", j.dump(), "no-store");
    }
    if (path == "/ws") {
      return Error(req, http::status::upgrade_required, "/ws takes a WebSocket upgrade");
    }
    if (path.substr(0, 6) == "/mesh/") {
      const std::string_view hash = path.substr(6);
      if (!IsContentHash(hash)) {
        return Error(req, http::status::bad_request, "mesh hash: expected 32 hex digits");
      }
      auto blob = hooks.mesh(hash);
      if (!blob) {
        return Error(req, http::status::not_found, "no mesh with that hash in the scene now");
      }
      Response res =
          Ok(req, "application/octet-stream", *blob, "public, max-age=31536000, immutable");
      res.set(http::field::etag, fmt::format("\"{}\"", hash));
      return res;
    }
    const std::string_view asset_path = path == "/" ? std::string_view("/index.html") : path;
    for (const internal::Asset& a : internal::Assets()) {
      if (a.path != asset_path) continue;
      std::string body(a.body);
      if (a.path == "/index.html") {
        // The page's own requests (modules, style) carry the token it was
        // opened with; the page forwards it to /ws and /mesh itself.
        const std::string q =
            opts.viewer_token.empty() ? "" : "?token=" + UrlEncode(opts.viewer_token);
        for (auto at = body.find("{{q}}"); at != std::string::npos; at = body.find("{{q}}", at)) {
          body.replace(at, 5, q);
          at += q.size();
        }
        return Ok(req, internal::ContentType(a.path), std::move(body), "no-store");
      }
      return Ok(req, internal::ContentType(a.path), std::move(body), "no-cache");
    }
    return Error(req, http::status::not_found, "not found");
  }

  /// The next message for `b`, or false when it has nothing to send.
  bool Next(Browser& b, std::string* out) {
    if (b.need_scene) {
      b.need_scene = false;
      b.reliable.clear();
      b.reliable_bytes = 0;
      *out = hooks.full_scene();
      return true;
    }
    if (!b.reliable.empty()) {
      *out = *b.reliable.front();
      b.reliable_bytes -= b.reliable.front()->size();
      b.reliable.pop_front();
      return true;
    }
    const auto counters = [&] {
      return fmt::format("{{\"poses_dropped\":{},\"batches_dropped\":{},", b.poses_dropped,
                         b.telemetry_dropped);
    };
    if (!b.telemetry.empty()) {
      *out = counters() + *b.telemetry.front().second;
      b.telemetry.pop_front();
      return true;
    }
    if (b.pose) {
      *out = counters() + *b.pose;
      b.pose.reset();
      return true;
    }
    return false;
  }

  void Accept();
  void Launch(tcp::socket socket);
};

namespace {

/// A WebSocket browser on a plain or TLS stream.
template <class Stream>
class WsSession final : public Browser, public std::enable_shared_from_this<WsSession<Stream>> {
 public:
  WsSession(Stream&& stream, HttpServer::Impl* impl) : ws_(std::move(stream)), impl_(impl) {}

  void Run(Request req) {
    req_ = std::move(req);
    beast::get_lowest_layer(ws_).expires_never();
    auto timeout = websocket::stream_base::timeout::suggested(beast::role_type::server);
    timeout.idle_timeout = std::chrono::seconds(60);
    timeout.keep_alive_pings = true;  // a browser's pong is activity: only a dead peer times out
    ws_.set_option(timeout);
    ws_.set_option(websocket::stream_base::decorator(
        [](websocket::response_type& res) { res.set(http::field::server, "hapticpd-view"); }));
    ws_.read_message_max(impl_->opts.max_ws_message_bytes);
    ws_.async_accept(req_,
                     beast::bind_front_handler(&WsSession::OnAccept, this->shared_from_this()));
  }

  void Kick() override {
    if (writing_ || closed_ || !open_) return;
    if (!impl_->Next(*this, &out_)) return;
    writing_ = true;
    ws_.text(true);
    ws_.async_write(net::buffer(out_),
                    beast::bind_front_handler(&WsSession::OnWrite, this->shared_from_this()));
  }

 private:
  void OnAccept(beast::error_code ec) {
    if (ec) {
      spdlog::debug("viewer: WebSocket handshake failed: {}", ec.message());
      return;
    }
    open_ = true;
    impl_->ws_connects.fetch_add(1, std::memory_order_relaxed);
    impl_->browsers.insert(this->shared_from_this());
    impl_->browser_count.store(static_cast<int>(impl_->browsers.size()));
    Kick();
    Read();
  }

  void Read() {
    ws_.async_read(in_, beast::bind_front_handler(&WsSession::OnRead, this->shared_from_this()));
  }

  void OnRead(beast::error_code ec, std::size_t) {
    if (ec) {
      if (ec == websocket::error::message_too_big) {
        impl_->ws_bad.fetch_add(1, std::memory_order_relaxed);
        spdlog::info("viewer: a browser sent a message over {} bytes: closed",
                     impl_->opts.max_ws_message_bytes);
      }
      return Close();
    }
    const std::string text = beast::buffers_to_string(in_.data());
    in_.consume(in_.size());
    Answer(ws_.got_text(), text);
    Read();
  }

  /// Browser messages: {"type":"ping","t":T} is answered {"type":"pong","t":T};
  /// anything else with an "error" message (the connection stays).
  void Answer(bool is_text, const std::string& text) {
    nlohmann::json reply;
    const nlohmann::json msg = is_text ? nlohmann::json::parse(text, nullptr, false)
                                       : nlohmann::json(nlohmann::json::value_t::discarded);
    if (!is_text) {
      reply = {{"type", "error"}, {"message", "binary messages are not understood"}};
    } else if (msg.is_discarded() || !msg.is_object()) {
      reply = {{"type", "error"}, {"message", "messages are JSON objects"}};
    } else if (msg.value("type", "") == "ping") {
      reply = {{"type", "pong"}, {"t", msg.contains("t") ? msg["t"] : nlohmann::json(nullptr)}};
    } else {
      reply = {{"type", "error"}, {"message", "unknown message type (expected ping)"}};
    }
    if (reply["type"] == "error") impl_->ws_bad.fetch_add(1, std::memory_order_relaxed);
    auto s = std::make_shared<const std::string>(
        reply.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace));
    reliable_bytes += s->size();
    reliable.push_back(std::move(s));
    Kick();
  }

  void OnWrite(beast::error_code ec, std::size_t) {
    writing_ = false;
    if (ec) return Close();
    Kick();
  }

  void Close() {
    if (closed_) return;
    closed_ = true;
    if (open_) {
      impl_->browsers.erase(this->shared_from_this());
      impl_->browser_count.store(static_cast<int>(impl_->browsers.size()));
    }
    beast::error_code ignored;
    beast::get_lowest_layer(ws_).socket().close(ignored);
  }

  websocket::stream<Stream> ws_;
  HttpServer::Impl* impl_;
  Request req_;
  beast::flat_buffer in_;
  std::string out_;
  bool open_ = false, writing_ = false, closed_ = false;
};

/// One HTTP connection (keep-alive), handing a WebSocket upgrade on.
template <class Stream>
class HttpSession final : public std::enable_shared_from_this<HttpSession<Stream>> {
  static constexpr bool kTls = !std::is_same_v<Stream, beast::tcp_stream>;

 public:
  template <class... Args>
  HttpSession(HttpServer::Impl* impl, Args&&... args)
      : stream_(std::forward<Args>(args)...),
        buffer_(2 * impl->opts.max_request_bytes + 1024),
        impl_(impl) {}

  void Run() {
    if constexpr (kTls) {
      beast::get_lowest_layer(stream_).expires_after(kHttpTimeout);
      stream_.async_handshake(
          ssl::stream_base::server,
          beast::bind_front_handler(&HttpSession::OnHandshake, this->shared_from_this()));
    } else {
      DoRead();
    }
  }

 private:
  void OnHandshake(beast::error_code ec) {
    if (ec) {
      spdlog::debug("viewer: TLS handshake failed: {}", ec.message());
      return;
    }
    DoRead();
  }

  void DoRead() {
    parser_.emplace();
    parser_->header_limit(static_cast<std::uint32_t>(impl_->opts.max_request_bytes));
    parser_->body_limit(impl_->opts.max_request_bytes);
    beast::get_lowest_layer(stream_).expires_after(kHttpTimeout);
    http::async_read(stream_, buffer_, *parser_,
                     beast::bind_front_handler(&HttpSession::OnRead, this->shared_from_this()));
  }

  void OnRead(beast::error_code ec, std::size_t) {
    if (ec == http::error::end_of_stream) return Shutdown();
    if (ec == http::error::header_limit || ec == http::error::buffer_overflow) {
      return Send(
          impl_->Error(http::status::request_header_fields_too_large,
                       fmt::format("request header over {} bytes", impl_->opts.max_request_bytes)));
    }
    if (ec == http::error::body_limit) {
      return Send(
          impl_->Error(http::status::payload_too_large,
                       fmt::format("request body over {} bytes", impl_->opts.max_request_bytes)));
    }
    if (ec && ec.category() == http::make_error_code(http::error::bad_target).category()) {
      return Send(
          impl_->Error(http::status::bad_request, "malformed HTTP request: " + ec.message()));
    }
    if (ec) return;  // the peer went away, or timed out
    Request req = parser_->release();
    if (websocket::is_upgrade(req)) {
      const std::string_view path = Split(Std(req.target())).path;
      if (path != "/ws") return Send(impl_->Error(req, http::status::not_found, "WebSocket: /ws"));
      if (!impl_->Authorized(req)) {
        return Send(impl_->Error(req, http::status::unauthorized,
                                 "this viewer needs its viewer token: ?token=..."));
      }
      if (impl_->browser_count.load() >= kMaxBrowsers) {
        return Send(impl_->Error(req, http::status::service_unavailable,
                                 fmt::format("at most {} browsers", kMaxBrowsers)));
      }
      impl_->requests.fetch_add(1, std::memory_order_relaxed);
      std::make_shared<WsSession<Stream>>(std::move(stream_), impl_)->Run(std::move(req));
      return;
    }
    Send(impl_->Handle(req));
  }

  void Send(Response res) {
    res_ = std::move(res);
    if (res_.find(http::field::content_length) == res_.end()) res_.prepare_payload();
    http::async_write(stream_, res_,
                      beast::bind_front_handler(&HttpSession::OnWrite, this->shared_from_this()));
  }

  void OnWrite(beast::error_code ec, std::size_t) {
    if (ec) return;
    if (!res_.keep_alive()) return Shutdown();
    DoRead();
  }

  /// After the answer to a request it stopped reading (an error): what the
  /// client still sends is read and dropped, up to a bound, so that closing
  /// with unread bytes (a TCP reset) does not destroy the answer in flight.
  void Drain() {
    beast::get_lowest_layer(stream_).expires_after(std::chrono::seconds(5));
    stream_.async_read_some(net::buffer(scratch_), [self = this->shared_from_this()](
                                                       beast::error_code ec, std::size_t n) {
      self->drained_ += n;
      if (!ec && self->drained_ < 4 * self->impl_->opts.max_request_bytes + (1 << 20)) {
        self->Drain();
      }
    });
  }

  void Shutdown() {
    if constexpr (kTls) {
      beast::get_lowest_layer(stream_).expires_after(std::chrono::seconds(5));
      stream_.async_shutdown([self = this->shared_from_this()](beast::error_code) {});
    } else {
      beast::error_code ignored;
      stream_.socket().shutdown(tcp::socket::shutdown_send, ignored);
      Drain();
    }
  }

  Stream stream_;
  beast::flat_buffer buffer_;
  HttpServer::Impl* impl_;
  std::optional<http::request_parser<http::string_body>> parser_;
  Response res_;
  std::array<char, 4096> scratch_;
  std::size_t drained_ = 0;
};

}  // namespace

void HttpServer::Impl::Accept() {
  acceptor.async_accept([this](beast::error_code ec, tcp::socket socket) {
    if (ec) {
      if (ec != net::error::operation_aborted) {
        spdlog::info("viewer: accept: {}", ec.message());
      }
    } else {
      Launch(std::move(socket));
    }
    if (acceptor.is_open()) Accept();
  });
}

void HttpServer::Impl::Launch(tcp::socket socket) {
  if (ssl_ctx) {
    std::make_shared<HttpSession<beast::ssl_stream<beast::tcp_stream>>>(this, std::move(socket),
                                                                        *ssl_ctx)
        ->Run();
  } else {
    std::make_shared<HttpSession<beast::tcp_stream>>(this, std::move(socket))->Run();
  }
}

HttpServer::HttpServer(HttpOptions options, Hooks hooks)
    : impl_(std::make_unique<Impl>(std::move(options), std::move(hooks))) {
  const HttpOptions& o = impl_->opts;
  if (!IsLoopbackListen(o.listen) && o.viewer_token.empty()) {
    throw ViewerError(fmt::format(
        "--listen {} is not a loopback address: browsers elsewhere could watch the scene. "
        "Give --viewer-token TOKEN (browsers then open the page with ?token=TOKEN), ideally "
        "with --tls-cert/--tls-key, or listen on 127.0.0.1",
        o.listen));
  }
  if (o.tls_cert.empty() != o.tls_key.empty()) {
    throw ViewerError("--tls-cert and --tls-key go together");
  }
  if (!o.tls_cert.empty()) {
    const std::string cert = ReadFile(o.tls_cert, "--tls-cert");
    const std::string key = ReadFile(o.tls_key, "--tls-key");
    auto& ctx = impl_->ssl_ctx.emplace(ssl::context::tls_server);
    ctx.set_options(ssl::context::default_workarounds | ssl::context::no_sslv2 |
                    ssl::context::no_sslv3 | ssl::context::no_tlsv1 | ssl::context::no_tlsv1_1);
    boost::system::error_code ec;
    ctx.use_certificate_chain(net::buffer(cert), ec);
    if (ec) throw ViewerError(fmt::format("--tls-cert {}: {}", o.tls_cert, ec.message()));
    ctx.use_private_key(net::buffer(key), ssl::context::pem, ec);
    if (ec) throw ViewerError(fmt::format("--tls-key {}: {}", o.tls_key, ec.message()));
  }
}

HttpServer::~HttpServer() { Stop(); }

void HttpServer::Start() {
  Impl& m = *impl_;
  if (m.started.exchange(true)) return;
  const tcp::endpoint ep = ParseListen(m.opts.listen);
  boost::system::error_code ec;
  m.acceptor.open(ep.protocol(), ec);
  if (!ec) m.acceptor.set_option(net::socket_base::reuse_address(true), ec);
  if (!ec) m.acceptor.bind(ep, ec);
  if (!ec) m.acceptor.listen(net::socket_base::max_listen_connections, ec);
  if (ec) throw ViewerError(fmt::format("cannot listen on {}: {}", m.opts.listen, ec.message()));
  m.bound_port = m.acceptor.local_endpoint().port();
  m.Accept();
  m.thread = std::thread([&m] {
    for (;;) {
      try {
        m.ioc.run();
        return;
      } catch (const std::exception& e) {
        spdlog::error("viewer: network thread: {}", e.what());
      }
    }
  });
}

void HttpServer::Stop() {
  Impl& m = *impl_;
  if (!m.started.load() || m.stopped.exchange(true)) return;
  net::post(m.ioc, [&m] {
    boost::system::error_code ignored;
    m.acceptor.close(ignored);
    m.ioc.stop();
  });
  if (m.thread.joinable()) m.thread.join();
  m.browsers.clear();
  m.browser_count = 0;
}

int HttpServer::port() const { return impl_->bound_port.load(); }
bool HttpServer::tls() const { return impl_->ssl_ctx.has_value(); }

void HttpServer::Post(std::function<void()> fn) { net::post(impl_->ioc, std::move(fn)); }

void HttpServer::BroadcastReliable(std::shared_ptr<const std::string> msg) {
  const std::vector<std::shared_ptr<Browser>> all(impl_->browsers.begin(), impl_->browsers.end());
  for (const auto& b : all) {
    if (b->need_scene) continue;  // the scene it will get already holds this
    if (b->reliable_bytes + msg->size() > impl_->opts.max_reliable_bytes) {
      // Far behind: the whole scene, once it catches up, replaces the backlog.
      b->need_scene = true;
      b->reliable.clear();
      b->reliable_bytes = 0;
      impl_->scene_resends.fetch_add(1, std::memory_order_relaxed);
    } else {
      b->reliable_bytes += msg->size();
      b->reliable.push_back(msg);
    }
    b->Kick();
  }
}

void HttpServer::ResendScene() {
  const std::vector<std::shared_ptr<Browser>> all(impl_->browsers.begin(), impl_->browsers.end());
  for (const auto& b : all) {
    b->need_scene = true;
    b->reliable.clear();
    b->reliable_bytes = 0;
    b->Kick();
  }
}

void HttpServer::BroadcastPoses(std::shared_ptr<const std::string> members) {
  const std::vector<std::shared_ptr<Browser>> all(impl_->browsers.begin(), impl_->browsers.end());
  for (const auto& b : all) {
    if (b->pose) {
      ++b->poses_dropped;
      impl_->poses_dropped.fetch_add(1, std::memory_order_relaxed);
    }
    b->pose = members;
    b->Kick();
  }
}

void HttpServer::BroadcastTelemetry(std::shared_ptr<const std::string> members) {
  const auto now = Clock::now();
  const auto horizon = now - std::chrono::duration_cast<Clock::duration>(
                                 std::chrono::duration<double>(impl_->opts.telemetry_queue_s));
  const std::vector<std::shared_ptr<Browser>> all(impl_->browsers.begin(), impl_->browsers.end());
  for (const auto& b : all) {
    while (!b->telemetry.empty() && b->telemetry.front().first < horizon) {
      b->telemetry.pop_front();
      ++b->telemetry_dropped;
      impl_->telemetry_dropped.fetch_add(1, std::memory_order_relaxed);
    }
    b->telemetry.emplace_back(now, members);
    b->Kick();
  }
}

int HttpServer::browsers() const { return static_cast<int>(impl_->browsers.size()); }

HttpServer::Counts HttpServer::counts() const {
  const Impl& m = *impl_;
  Counts c;
  c.ws_connects = m.ws_connects.load();
  c.poses_dropped = m.poses_dropped.load();
  c.telemetry_dropped = m.telemetry_dropped.load();
  c.scene_resends = m.scene_resends.load();
  c.requests = m.requests.load();
  c.rejected = m.rejected.load();
  c.ws_messages_bad = m.ws_bad.load();
  c.browsers = m.browser_count.load();
  return c;
}

}  // namespace hapticpd::viewer
