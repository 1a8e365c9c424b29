#include "client/rpc_util.h"

#include <chrono>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <random>
#include <sstream>
#include <vector>

#include "proto/wire/convert.h"
#include "proto/wire/routing.h"
#include "proto/wire/status.h"

namespace hapticpd::cli {

std::vector<double> ParseNumbers(const std::string& text, const std::string& option) {
  std::vector<double> out;
  std::stringstream fields(text);
  std::string field;
  while (std::getline(fields, field, ',')) {
    std::istringstream words(field);
    std::string item;
    bool any = false;
    while (words >> item) {
      any = true;
      char* end = nullptr;
      const double v = std::strtod(item.c_str(), &end);
      if (end != item.c_str() + item.size()) {
        throw CommandError(option + ": '" + item + "' is not a number (in '" + text + "')");
      }
      out.push_back(v);
    }
    if (!any) throw CommandError(option + ": an empty field (in '" + text + "')");
  }
  return out;
}

void AddConnectionOptions(CLI::App* cmd, ConnectionOptions* o) {
  if (const char* s = std::getenv("HAPTICPD_SERVER")) o->server = s;
  if (const char* t = std::getenv("HAPTICPD_TOKEN")) o->token = t;
  cmd->add_option("--server", o->server, "Server HOST:PORT (or $HAPTICPD_SERVER)")
      ->capture_default_str();
  cmd->add_option("--token", o->token, "Access token (or $HAPTICPD_TOKEN)");
  cmd->add_flag("--tls", o->tls, "Connect with TLS, trusting the system's root CAs");
  cmd->add_option("--tls-ca", o->tls_ca, "Connect with TLS, trusting this PEM CA certificate");
  cmd->add_option("--timeout", o->timeout_s, "Seconds before a call gives up")
      ->capture_default_str();
}

std::shared_ptr<grpc::ChannelCredentials> MakeCredentials(const ConnectionOptions& o) {
  if (o.tls_ca.empty() && !o.tls) return grpc::InsecureChannelCredentials();
  grpc::SslCredentialsOptions ssl;
  if (!o.tls_ca.empty()) {
    std::ifstream in(o.tls_ca);
    if (!in) throw CommandError("--tls-ca: cannot open " + o.tls_ca);
    std::ostringstream ss;
    ss << in.rdbuf();
    ssl.pem_root_certs = ss.str();
  }
  return grpc::SslCredentials(ssl);
}

std::shared_ptr<grpc::Channel> MakeChannel(const ConnectionOptions& o) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(256 << 20);
  return grpc::CreateCustomChannel(o.server, MakeCredentials(o), args);
}

std::unique_ptr<grpc::ClientContext> MakeContext(const ConnectionOptions& o, bool streaming) {
  auto ctx = std::make_unique<grpc::ClientContext>();
  if (!o.token.empty()) ctx->AddMetadata("authorization", "Bearer " + o.token);
  if (!streaming && o.timeout_s > 0) {
    ctx->set_deadline(std::chrono::system_clock::now() +
                      std::chrono::milliseconds(static_cast<std::int64_t>(o.timeout_s * 1000)));
  }
  return ctx;
}

std::unique_ptr<grpc::ClientContext> MakeSceneContext(const ConnectionOptions& o,
                                                      const std::string& scene_id, bool streaming) {
  auto ctx = MakeContext(o, streaming);
  wire::AddSceneHeader(ctx.get(), scene_id);
  return ctx;
}

std::string NewRequestId() {
  static thread_local std::mt19937_64 rng = [] {
    std::random_device rd;
    std::seed_seq seq{rd(), rd(), rd(), rd()};
    return std::mt19937_64(seq);
  }();
  static const char* hex = "0123456789abcdef";
  std::string id = "cli-";
  for (int i = 0; i < 24; ++i) id += hex[rng() & 15];
  return id;
}

std::string StatusText(const grpc::Status& s) {
  return std::string(wire::StatusCodeName(s.error_code())) + ": " + s.error_message();
}

void Check(const grpc::Status& s, const std::string& cmd) {
  if (s.ok()) return;
  throw CommandError(cmd + ": " + StatusText(s));
}

namespace {

/// `text`'s numbers, `count` or `long_count` of them (else a CommandError
/// that shows `usage`).
std::vector<double> ParseCounted(const std::string& text, const std::string& option,
                                 std::size_t count, std::size_t long_count, const char* usage) {
  auto v = ParseNumbers(text, option);
  if (v.size() != count && v.size() != long_count) {
    throw CommandError(option + ": expected " + usage + " (commas or spaces), got '" + text + "'");
  }
  return v;
}

/// v[at], v[at + 1], v[at + 2] into `out`.
void SetXyz(const std::vector<double>& v, std::size_t at, v1::Vec3* out) {
  out->set_x(v[at]);
  out->set_y(v[at + 1]);
  out->set_z(v[at + 2]);
}

}  // namespace

v1::Pose ParsePose(const std::string& text, const std::string& option) {
  const auto v = ParseCounted(text, option, 3, 7, "'x y z' or 'x y z qw qx qy qz'");
  v1::Pose p;
  SetXyz(v, 0, p.mutable_position());
  if (v.size() == 7) {
    auto* q = p.mutable_orientation();
    q->set_w(v[3]);
    q->set_x(v[4]);
    q->set_y(v[5]);
    q->set_z(v[6]);
  }
  return p;
}

v1::Twist ParseTwist(const std::string& text, const std::string& option) {
  const auto v = ParseCounted(text, option, 3, 6, "'vx vy vz' or 'vx vy vz wx wy wz'");
  v1::Twist t;
  SetXyz(v, 0, t.mutable_linear());
  if (v.size() == 6) SetXyz(v, 3, t.mutable_angular());
  return t;
}

std::pair<Vec3, Vec3> SceneBox(const v1::Scene& scene, const std::string& skip_body_id) {
  Vec3 lo = Vec3::Constant(std::numeric_limits<double>::infinity());
  Vec3 hi = -lo;
  for (const v1::Body& b : scene.bodies()) {
    if (!skip_body_id.empty() && b.body_id() == skip_body_id) continue;
    const Pose X = wire::FromProtoUnchecked(b.pose());
    const Vec3 a = wire::FromProtoUnchecked(b.mesh_info().aabb_min()),
               c = wire::FromProtoUnchecked(b.mesh_info().aabb_max());
    for (int i = 0; i < 8; ++i) {
      const Vec3 p((i & 1) ? c.x() : a.x(), (i & 2) ? c.y() : a.y(), (i & 4) ? c.z() : a.z());
      lo = lo.cwiseMin(X * p);
      hi = hi.cwiseMax(X * p);
    }
  }
  if (!lo.allFinite()) lo = hi = Vec3::Zero();
  return {lo, hi};
}

}  // namespace hapticpd::cli
