// RPC benchmark: pose -> ContactUpdate round trip of one device session over
// loopback TCP, against a `hapticpd` server running in this process.
//
//   1. Lock-step round trips (send pose k, wait for its answer) for the stick
//      pressing into and sliding on the Stanford bunny (69K triangles), PD
//      mode none (the transport floor) and PDt on the same poses in the same
//      run: round trip p50/p99/p99.9, server PD time p50/p99, and the overhead
//      (round trip - PD time) p50/p99 against the goal p50 <= 150 us.
//   2. Sustained rate: poses streamed at 2 kHz without waiting for answers
//      (newest-pose mailbox); answers per second, against >= 1000/s.
//   3. With 32 observers watching the scene at 60 Hz: the change in the
//      session's update rate when streaming poses at the 1 kHz servo rate
//      (goal < 5 %), and (for information) in the CPU-bound lock-step run.
//
// Prints a table and writes a CSV (--csv FILE, default bench_rpc.csv). No
// assertions on time.
//
//   ./build/release/tests/bench/bench_rpc [--models DIR] [--frames N] [--csv FILE]
//
// The balancer hop (tests/bench/README.md "Balancer hop (scale-out)"): with
// --target HOST:PORT no server runs in this process; the bench adds the scene
// body to --scene through the target and measures the lock-step round trips
// of (1) against it, every call naming its scene in x-hapticpd-scene (and
// carrying --token as a bearer token). With --direct HOST:PORT too (the
// process that owns the scene) it runs one session through each address and
// alternates blocks of poses between them (--blocks, the order swapped every
// block, so machine noise hits both alike): round trip p50/p99 through the
// balancer and direct, and what the hop adds. tests/bench/scale_hop.sh starts
// three sharded servers and HAProxy on loopback and runs this.
//
//   bench_rpc --target 127.0.0.1:50051 --direct 127.0.0.1:50052 --scene lab-bench
//            [--token T] [--frames N] [--blocks B] [--mode none|pdt] [--csv FILE]
//
// Without ../shared/models the bunny is replaced by a procedural torus knot.
#include <grpcpp/grpcpp.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <numeric>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "hapticpd/v1/haptic.grpc.pb.h"
#include "hapticpd/v1/scene.grpc.pb.h"
#include "pd/mesh.h"
#include "pd/shapes.h"
#include "proto/wire/routing.h"
#include "server/server.h"

namespace v1 = hapticpd::v1;
namespace pd = hapticpd::pd;
using hapticpd::Vec3;
using Clock = std::chrono::steady_clock;

namespace {

constexpr double kGoalOverheadUs = 150;
constexpr double kGoalRate = 1000;
constexpr double kGoalObserverEffect = 0.05;

double Quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<std::size_t>(q * static_cast<double>(v.size())))];
}

std::int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch())
      .count();
}

v1::Pose MakePose(const Vec3& p, double qw, double qx, double qy, double qz) {
  v1::Pose out;
  out.mutable_position()->set_x(p.x());
  out.mutable_position()->set_y(p.y());
  out.mutable_position()->set_z(p.z());
  out.mutable_orientation()->set_w(qw);
  out.mutable_orientation()->set_x(qx);
  out.mutable_orientation()->set_y(qy);
  out.mutable_orientation()->set_z(qz);
  return out;
}

/// The stick (axis z, 15 cm) turned to point down -y, its tip starting 4 mm
/// above the top of the scene, pressing 3 mm in, sliding on a 4 mm circle and
/// coming back out: one pose per millisecond.
std::vector<v1::Pose> Trajectory(const pd::Mesh& scene, int frames) {
  const Vec3 c = scene.bounds().Center();
  const double reach = 0.2 * scene.bounds().Size().norm();
  Vec3 top = c;
  double best = -1e300;
  for (const Vec3& v : scene.vertices()) {
    const double dx = v.x() - c.x(), dz = v.z() - c.z();
    if (dx * dx + dz * dz < reach * reach && v.y() > best) {
      best = v.y();
      top = v;
    }
  }
  const double s = std::sqrt(0.5);
  std::vector<v1::Pose> out;
  out.reserve(frames);
  for (int k = 0; k < frames; ++k) {
    const double t = static_cast<double>(k) / std::max(1, frames - 1);
    const double press = 0.004 - 0.007 * std::sin(M_PI * t);  // gap: +4 mm .. -3 mm .. +4 mm
    const double a = 6 * M_PI * t;
    const Vec3 tip = top + Vec3(0.004 * std::cos(a) - 0.004, press, 0.004 * std::sin(a));
    out.push_back(MakePose(tip + Vec3(0, 0.075, 0), s, -s, 0, 0));
  }
  return out;
}

/// The scene every call names (body and x-hapticpd-scene header) and the
/// access token it carries, if any.
struct Route {
  std::string scene_id = "default";
  std::string token;

  void Apply(grpc::ClientContext* ctx) const {
    hapticpd::wire::AddSceneHeader(ctx, scene_id);
    if (!token.empty()) ctx->AddMetadata("authorization", "Bearer " + token);
  }
};

struct Session {
  grpc::ClientContext ctx;
  std::unique_ptr<grpc::ClientReaderWriter<v1::CoupleRequest, v1::CoupleResponse>> stream;

  Session(v1::HapticService::Stub& stub, v1::PdMode mode, const Route& route = {}) {
    route.Apply(&ctx);
    stream = stub.Couple(&ctx);
    v1::CoupleRequest hello;
    auto* h = hello.mutable_hello();
    h->set_protocol_version(1);
    h->set_scene_id(route.scene_id);
    h->set_mode(mode);
    h->set_probe_shape("stick");
    h->set_client_name("bench_rpc");
    v1::CoupleResponse resp;
    if (!stream->Write(hello) || !stream->Read(&resp) || !resp.has_welcome()) {
      const auto s = stream->Finish();
      throw std::runtime_error("hello failed: " + s.error_message());
    }
  }
  void Close() {
    stream->WritesDone();
    v1::CoupleResponse resp;
    while (stream->Read(&resp)) {
    }
    const auto s = stream->Finish();
    if (!s.ok()) throw std::runtime_error("session ended with " + s.error_message());
  }
};

struct LockStep {
  std::vector<double> rtt_us, pd_us, overhead_us;
  double seconds = 0;
  int contacts = 0;
  double rate() const { return static_cast<double>(rtt_us.size()) / seconds; }
};

/// Warm-up (connection, coherence caches), not measured: sequences 1..50.
void WarmUp(Session& s, const std::vector<v1::Pose>& poses) {
  v1::CoupleRequest req;
  v1::CoupleResponse resp;
  for (std::size_t k = 0; k < std::min<std::size_t>(50, poses.size()); ++k) {
    req.mutable_pose()->set_sequence(k + 1);
    *req.mutable_pose()->mutable_pose() = poses[k];
    s.stream->Write(req);
    s.stream->Read(&resp);
  }
}

/// Lock-step round trips for poses[begin, end) (sequence 1000 + k), added to
/// `r`; r.seconds grows by the time they took.
void LockStepRange(Session& s, const std::vector<v1::Pose>& poses, std::size_t begin,
                   std::size_t end, LockStep* out) {
  LockStep& r = *out;
  v1::CoupleRequest req;
  v1::CoupleResponse resp;
  const auto t0 = Clock::now();
  for (std::size_t k = begin; k < end; ++k) {
    const std::uint64_t seq = 1000 + k;
    req.mutable_pose()->set_sequence(seq);
    *req.mutable_pose()->mutable_pose() = poses[k];
    const std::int64_t sent = NowNs();
    req.mutable_pose()->set_client_time_ns(sent);
    if (!s.stream->Write(req)) throw std::runtime_error("write failed");
    do {
      if (!s.stream->Read(&resp)) throw std::runtime_error("stream ended");
    } while (!resp.has_update() || resp.update().sequence() != seq);
    const double rtt = static_cast<double>(NowNs() - sent) / 1e3;
    const double pd_us = resp.update().compute_time_us();
    r.rtt_us.push_back(rtt);
    r.pd_us.push_back(pd_us);
    r.overhead_us.push_back(rtt - pd_us);
    if (resp.update().rows_size() > 0) ++r.contacts;
  }
  r.seconds += std::chrono::duration<double>(Clock::now() - t0).count();
}

LockStep RunLockStep(v1::HapticService::Stub& stub, v1::PdMode mode,
                     const std::vector<v1::Pose>& poses) {
  Session s(stub, mode);
  LockStep r;
  WarmUp(s, poses);
  LockStepRange(s, poses, 0, poses.size(), &r);
  s.Close();
  return r;
}

/// The balancer hop: one session through `via` (the balancer) and one to
/// `direct` (the scene's owner), both open for the whole run; the poses in
/// `blocks` blocks, each block run on both sessions back to back, the one
/// going first alternating.
std::pair<LockStep, LockStep> RunHop(v1::HapticService::Stub& via, v1::HapticService::Stub& direct,
                                     v1::PdMode mode, const Route& route,
                                     const std::vector<v1::Pose>& poses, int blocks) {
  Session a(via, mode, route), b(direct, mode, route);
  WarmUp(a, poses);
  WarmUp(b, poses);
  std::pair<LockStep, LockStep> r;
  const std::size_t n = poses.size();
  for (int i = 0; i < blocks; ++i) {
    const std::size_t begin = n * i / blocks, end = n * (i + 1) / blocks;
    if (i % 2 == 0) {
      LockStepRange(a, poses, begin, end, &r.first);
      LockStepRange(b, poses, begin, end, &r.second);
    } else {
      LockStepRange(b, poses, begin, end, &r.second);
      LockStepRange(a, poses, begin, end, &r.first);
    }
  }
  a.Close();
  b.Close();
  return r;
}

struct Streamed {
  double sent_rate = 0, answer_rate = 0;
  std::uint64_t superseded = 0;
};

/// Poses paced at `rate_hz` for `seconds`, answers read concurrently.
Streamed RunStreamed(v1::HapticService::Stub& stub, v1::PdMode mode,
                     const std::vector<v1::Pose>& poses, double rate_hz, double seconds) {
  Session s(stub, mode);
  std::atomic<std::uint64_t> sent{0};
  std::thread writer([&] {
    v1::CoupleRequest req;
    const auto period = std::chrono::nanoseconds(static_cast<std::int64_t>(1e9 / rate_hz));
    const auto t0 = Clock::now();
    auto next = t0;
    for (std::uint64_t k = 0; Clock::now() - t0 < std::chrono::duration<double>(seconds); ++k) {
      req.mutable_pose()->set_sequence(k + 1);
      *req.mutable_pose()->mutable_pose() = poses[k % poses.size()];
      req.mutable_pose()->set_client_time_ns(NowNs());
      if (!s.stream->Write(req)) break;
      ++sent;
      next += period;
      std::this_thread::sleep_until(next);
    }
    s.stream->WritesDone();
  });
  Streamed r;
  v1::CoupleResponse resp;
  std::uint64_t answers = 0;
  const auto t0 = Clock::now();
  while (s.stream->Read(&resp)) {
    if (!resp.has_update()) continue;
    ++answers;
    r.superseded += resp.update().poses_superseded();
  }
  const double dt = std::chrono::duration<double>(Clock::now() - t0).count();
  writer.join();
  const auto st = s.stream->Finish();
  if (!st.ok()) throw std::runtime_error("streamed session: " + st.error_message());
  r.sent_rate = static_cast<double>(sent.load()) / dt;
  r.answer_rate = static_cast<double>(answers) / dt;
  return r;
}

/// `n` observers reading the scene at `rate_hz` on their own threads.
class Observers {
 public:
  Observers(const std::shared_ptr<grpc::Channel>& channel, int n, double rate_hz) {
    for (int i = 0; i < n; ++i) {
      auto& o = all_.emplace_back(std::make_unique<One>());
      o->stub = v1::SceneService::NewStub(channel);
      v1::WatchRequest req;
      req.set_scene_id("default");
      req.set_rate_hz(rate_hz);
      o->reader = o->stub->Watch(&o->ctx, req);
      o->thread = std::thread([p = o.get(), this] {
        v1::SceneEvent ev;
        while (p->reader->Read(&ev)) frames_.fetch_add(1);
      });
    }
  }
  ~Observers() {
    for (auto& o : all_) o->ctx.TryCancel();
    for (auto& o : all_) {
      o->thread.join();
      o->reader->Finish();
    }
  }
  std::uint64_t frames() const { return frames_.load(); }

 private:
  struct One {
    grpc::ClientContext ctx;
    std::unique_ptr<v1::SceneService::Stub> stub;
    std::unique_ptr<grpc::ClientReader<v1::SceneEvent>> reader;
    std::thread thread;
  };
  std::vector<std::unique_ptr<One>> all_;
  std::atomic<std::uint64_t> frames_{0};
};

/// The scene body "scene" in route.scene_id: the bunny uploaded as OBJ bytes,
/// or a torus knot. `mesh` is set whatever the answer (an existing body of
/// that id, ALREADY_EXISTS, is taken to be this one).
grpc::Status AddScene(v1::SceneService::Stub& scenes, const Route& route, const std::string& models,
                      std::string* name, std::optional<pd::Mesh>* mesh) {
  const std::filesystem::path bunny = std::filesystem::path(models) / "stanford-bunny.obj";
  grpc::ClientContext ctx;
  route.Apply(&ctx);
  v1::Body body;
  auto writer = scenes.AddBody(&ctx, &body);
  v1::AddBodyRequest head;
  head.mutable_header()->set_scene_id(route.scene_id);
  head.mutable_header()->mutable_spec()->set_body_id("scene");
  if (std::filesystem::exists(bunny)) {
    *name = "bunny";
    *mesh = pd::LoadMesh(bunny.string());
    head.mutable_header()->set_format(v1::MESH_FORMAT_OBJ);
    writer->Write(head);
    std::ifstream in(bunny, std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), {});
    v1::AddBodyRequest chunk;
    for (std::size_t off = 0; off < bytes.size(); off += 256 * 1024) {
      chunk.set_chunk(bytes.substr(off, 256 * 1024));
      writer->Write(chunk);
    }
  } else {
    *name = "torusknot (no shared models)";
    *mesh = pd::shapes::MakeShape("torusknot");
    head.mutable_header()->set_shape("torusknot");
    writer->Write(head);
  }
  writer->WritesDone();
  return writer->Finish();
}

void PrintHeader(const char* first) {
  std::cout << std::left << std::setw(22) << first << std::right << std::setw(9) << "p50"
            << std::setw(9) << "p99" << std::setw(9) << "p99.9" << std::setw(9) << "PD p50"
            << std::setw(9) << "PD p99" << std::setw(9) << "ovh p50" << std::setw(9) << "ovh p99"
            << std::setw(9) << "rate/s" << std::setw(9) << "contact"
            << "\n";
}

void PrintRow(const std::string& name, const LockStep& r) {
  std::cout << std::left << std::setw(22) << name << std::right << std::fixed
            << std::setprecision(1) << std::setw(9) << Quantile(r.rtt_us, 0.5) << std::setw(9)
            << Quantile(r.rtt_us, 0.99) << std::setw(9) << Quantile(r.rtt_us, 0.999) << std::setw(9)
            << Quantile(r.pd_us, 0.5) << std::setw(9) << Quantile(r.pd_us, 0.99) << std::setw(9)
            << Quantile(r.overhead_us, 0.5) << std::setw(9) << Quantile(r.overhead_us, 0.99)
            << std::setw(9) << std::setprecision(0) << r.rate() << std::setw(9) << r.contacts
            << "\n";
}

void WriteCsvHeader(std::ofstream& out) {
  out << "run,frames,rtt_p50_us,rtt_p99_us,rtt_p999_us,pd_p50_us,pd_p99_us,overhead_p50_us,"
         "overhead_p99_us,rate_per_s,contacts\n";
}

void WriteCsvRow(std::ofstream& out, const std::string& name, const LockStep& r) {
  out << name << "," << r.rtt_us.size() << "," << Quantile(r.rtt_us, 0.5) << ","
      << Quantile(r.rtt_us, 0.99) << "," << Quantile(r.rtt_us, 0.999) << ","
      << Quantile(r.pd_us, 0.5) << "," << Quantile(r.pd_us, 0.99) << ","
      << Quantile(r.overhead_us, 0.5) << "," << Quantile(r.overhead_us, 0.99) << "," << r.rate()
      << "," << r.contacts << "\n";
}

std::shared_ptr<grpc::Channel> Connect(const std::string& address) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);
  return grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args);
}

/// --target [--direct]: round trips against running servers, no server here.
int RunRemote(const std::string& target, const std::string& direct, const Route& route,
              const std::string& models, int frames, int blocks, v1::PdMode mode,
              const std::string& csv) {
  const auto via = Connect(target);
  auto scenes = v1::SceneService::NewStub(via);
  std::string scene_name;
  std::optional<pd::Mesh> scene_mesh;
  if (const grpc::Status st = AddScene(*scenes, route, models, &scene_name, &scene_mesh);
      !st.ok() && st.error_code() != grpc::StatusCode::ALREADY_EXISTS) {
    std::cerr << "bench_rpc: cannot add the body 'scene' to scene '" << route.scene_id
              << "' through " << target << ": " << st.error_message()
              << " (create the scene first: hapticpd scene create " << route.scene_id << ")\n";
    return 1;
  }
  const std::vector<v1::Pose> poses = Trajectory(*scene_mesh, frames);
  auto via_stub = v1::HapticService::NewStub(via);
  const std::string mode_name = mode == v1::PD_MODE_NONE ? "none" : "pdt";
  std::cout << "bench_rpc: stick (92 triangles) vs " << scene_name << " ("
            << scene_mesh->num_triangles() << " triangles) in scene '" << route.scene_id
            << "', PD mode " << mode_name << ", " << frames
            << " poses per path, lock-step (one pose in flight)\n";
  std::ofstream out(csv);
  WriteCsvHeader(out);
  if (direct.empty()) {
    std::cout << "target " << target << "\n\n";
    Session s(*via_stub, mode, route);
    LockStep r;
    WarmUp(s, poses);
    LockStepRange(s, poses, 0, poses.size(), &r);
    s.Close();
    PrintHeader("round trip (us)");
    PrintRow("target " + mode_name, r);
    WriteCsvRow(out, "target_" + mode_name, r);
    std::cout << "wrote " << csv << "\n";
    return 0;
  }
  auto direct_stub = v1::HapticService::NewStub(Connect(direct));
  std::cout << "through the balancer " << target << ", direct to the owner " << direct << ", "
            << blocks << " alternating blocks\n\n";
  const auto [hop, own] = RunHop(*via_stub, *direct_stub, mode, route, poses, blocks);
  PrintHeader("round trip (us)");
  PrintRow("via balancer", hop);
  PrintRow("direct", own);
  const double h50 = Quantile(hop.rtt_us, 0.5), d50 = Quantile(own.rtt_us, 0.5);
  const double h99 = Quantile(hop.rtt_us, 0.99), d99 = Quantile(own.rtt_us, 0.99);
  std::cout << std::fixed << std::setprecision(1) << "\nthe hop adds: p50 " << h50 - d50 << " us (x"
            << std::setprecision(2) << h50 / d50 << "), p99 " << std::setprecision(1) << h99 - d99
            << " us (x" << std::setprecision(2) << h99 / d99 << ")\n";
  WriteCsvRow(out, "via_balancer_" + mode_name, hop);
  WriteCsvRow(out, "direct_" + mode_name, own);
  out << "hop_added_p50_us," << h50 - d50 << "\nhop_added_p99_us," << h99 - d99
      << "\nhop_ratio_p50," << h50 / d50 << "\nhop_ratio_p99," << h99 / d99 << "\n";
  std::cout << "wrote " << csv << "\n";
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  std::string models = HAPTICPD_MODELS_DIR;
  std::string csv = "bench_rpc.csv";
  int frames = 3000;
  int blocks = 20;
  std::string target, direct, mode_arg = "pdt";
  Route route;
  bool scene_given = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::cerr << "bench_rpc: " << a << " needs a value\n";
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--models")
      models = next();
    else if (a == "--frames")
      frames = std::max(10, std::atoi(next().c_str()));
    else if (a == "--csv")
      csv = next();
    else if (a == "--target")
      target = next();
    else if (a == "--direct")
      direct = next();
    else if (a == "--token")
      route.token = next();
    else if (a == "--scene") {
      route.scene_id = next();
      scene_given = true;
    } else if (a == "--blocks")
      blocks = std::max(2, std::atoi(next().c_str()));
    else if (a == "--mode")
      mode_arg = next();
    else {
      std::cerr << "usage: bench_rpc [--models DIR] [--frames N] [--csv FILE]\n"
                   "       bench_rpc --target HOST:PORT [--direct HOST:PORT] --scene ID "
                   "[--token T] [--blocks B] [--mode none|pdt] [--models DIR] [--frames N] "
                   "[--csv FILE]\n";
      return a == "--help" ? 0 : 2;
    }
  }
  spdlog::set_level(spdlog::level::warn);
  if (target.empty() && (!direct.empty() || !route.token.empty() || scene_given)) {
    std::cerr << "bench_rpc: --direct, --token and --scene need --target\n";
    return 2;
  }
  if (mode_arg != "pdt" && mode_arg != "none") {
    std::cerr << "bench_rpc: --mode: expected none or pdt, got '" << mode_arg << "'\n";
    return 2;
  }
  if (!target.empty()) {
    try {
      return RunRemote(target, direct, route, models, frames, blocks,
                       mode_arg == "none" ? v1::PD_MODE_NONE : v1::PD_MODE_PDT, csv);
    } catch (const std::exception& e) {
      std::cerr << "bench_rpc: " << e.what() << "\n";
      return 1;
    }
  }

  hapticpd::server::HapticServer server(hapticpd::server::ServerOptions::InProcess());
  server.Start();
  const auto channel = Connect("127.0.0.1:" + std::to_string(server.port()));
  auto scenes = v1::SceneService::NewStub(channel);
  auto haptics = v1::HapticService::NewStub(channel);

  std::string scene_name;
  std::optional<pd::Mesh> scene_mesh;
  if (const grpc::Status st = AddScene(*scenes, Route{}, models, &scene_name, &scene_mesh);
      !st.ok()) {
    std::cerr << "bench_rpc: cannot add the scene: " << st.error_message() << "\n";
    return 1;
  }
  const std::vector<v1::Pose> poses = Trajectory(*scene_mesh, frames);

  std::cout << "bench_rpc: stick (92 triangles) vs " << scene_name << " ("
            << scene_mesh->num_triangles() << " triangles), " << frames
            << " poses, loopback TCP, lock-step (one pose in flight)\n\n";
  const LockStep none = RunLockStep(*haptics, v1::PD_MODE_NONE, poses);
  const LockStep pdt = RunLockStep(*haptics, v1::PD_MODE_PDT, poses);
  const Streamed s_none = RunStreamed(*haptics, v1::PD_MODE_NONE, poses, 2000, 3);
  const Streamed s_pdt = RunStreamed(*haptics, v1::PD_MODE_PDT, poses, 2000, 3);
  const Streamed s_1k = RunStreamed(*haptics, v1::PD_MODE_PDT, poses, 1000, 3);
  LockStep pdt_obs;
  Streamed s_1k_obs;
  std::uint64_t observer_frames = 0;
  double observer_seconds = 0;
  {
    Observers obs(channel, 32, 60);
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    const std::uint64_t f0 = obs.frames();
    const auto t0 = Clock::now();
    s_1k_obs = RunStreamed(*haptics, v1::PD_MODE_PDT, poses, 1000, 3);
    pdt_obs = RunLockStep(*haptics, v1::PD_MODE_PDT, poses);
    observer_seconds = std::chrono::duration<double>(Clock::now() - t0).count();
    observer_frames = obs.frames() - f0;
  }

  PrintHeader("round trip (us)");
  PrintRow("none (transport)", none);
  PrintRow("pdt", pdt);
  PrintRow("pdt + 32 observers", pdt_obs);
  const double ovh = Quantile(pdt.overhead_us, 0.5);
  std::cout << std::fixed << std::setprecision(1) << "\noverhead p50 (round trip - PD) " << ovh
            << " us, goal <= " << kGoalOverheadUs
            << " us: " << (ovh <= kGoalOverheadUs ? "met" : "NOT met") << " (transport floor p50 "
            << Quantile(none.rtt_us, 0.5) << " us)\n";
  std::cout << "streamed at 2 kHz: none " << std::setprecision(0) << s_none.answer_rate
            << " answers/s, pdt " << s_pdt.answer_rate << " answers/s (" << s_pdt.superseded
            << " poses superseded), goal >= " << kGoalRate
            << "/s: " << (s_pdt.answer_rate >= kGoalRate ? "met" : "NOT met (PD-bound?)") << "\n";
  const double effect = 1.0 - s_1k_obs.answer_rate / s_1k.answer_rate;
  const double effect_ls = 1.0 - pdt_obs.rate() / pdt.rate();
  std::cout << std::setprecision(1) << "32 observers at 60 Hz ("
            << static_cast<double>(observer_frames) / observer_seconds
            << " frames/s received): session streamed at 1 kHz " << s_1k.answer_rate << " -> "
            << s_1k_obs.answer_rate << " answers/s, change " << 100 * effect << " %, goal < "
            << 100 * kGoalObserverEffect
            << " %: " << (std::abs(effect) < kGoalObserverEffect ? "met" : "NOT met") << "\n"
            << "  (lock-step, CPU-bound on 2 cores with the observers' clients in this process: "
            << pdt.rate() << " -> " << pdt_obs.rate() << " round trips/s, change "
            << 100 * effect_ls << " %)\n";

  std::ofstream out(csv);
  WriteCsvHeader(out);
  WriteCsvRow(out, "none", none);
  WriteCsvRow(out, "pdt", pdt);
  WriteCsvRow(out, "pdt_32_observers", pdt_obs);
  out << "streamed_none,,"
      << ",,,,,,," << s_none.answer_rate << ",\n";
  out << "streamed_pdt,,"
      << ",,,,,,," << s_pdt.answer_rate << ",\n";
  out << "streamed_pdt_1khz,,"
      << ",,,,,,," << s_1k.answer_rate << ",\n";
  out << "streamed_pdt_1khz_32_observers,,"
      << ",,,,,,," << s_1k_obs.answer_rate << ",\n";
  std::cout << "wrote " << csv << "\n";
  server.Shutdown();
  return 0;
}
