// Several `hapticpd serve` processes behind HAProxy, as docker/README.md
// "Scaling out" describes: three sharded servers on loopback, HAProxy with
// docker/haproxy.cfg (addresses, TLS bind and paths replaced) and the shard
// map docker/shard-map.txt, driven through the real clients (the `hapticpd`
// CLI: scene create, inject, get, couple, device, observe). Label `scale`, release preset
// only: it starts processes and waits on HAProxy's health checks, with
// margins of seconds. Skipped when `haproxy` is not installed.
#include <fcntl.h>
#include <grpcpp/generic/async_generic_service.h>
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "device/replay_device.h"
#include "hapticpd/v1/scene.grpc.pb.h"
#include "tests/cli_runner.h"

extern char** environ;

namespace hapticpd::testing::scale_tests {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

const fs::path kDocker = fs::path(HAPTICPD_SOURCE_DIR) / "docker";

std::string FindHaproxy() {
  std::vector<std::string> dirs;
  if (const char* p = std::getenv("PATH")) {
    std::stringstream ss(p);
    for (std::string d; std::getline(ss, d, ':');) dirs.push_back(d);
  }
  dirs.insert(dirs.end(), {"/usr/sbin", "/usr/local/sbin"});
  for (const auto& d : dirs) {
    const fs::path c = fs::path(d) / "haproxy";
    if (!d.empty() && ::access(c.c_str(), X_OK) == 0) return c.string();
  }
  return "";
}

int FreePort() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof(a);
  if (::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) != 0 ||
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) != 0) {
    ::close(fd);
    return 0;
  }
  ::close(fd);
  return ntohs(a.sin_port);
}

/// A child process, its stdout and stderr in `log`; killed when destroyed.
class Process {
 public:
  Process(const std::vector<std::string>& argv, const fs::path& log) : log_(log) {
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 1, log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
    posix_spawn_file_actions_adddup2(&fa, 1, 2);
    posix_spawn_file_actions_addopen(&fa, 0, "/dev/null", O_RDONLY, 0);
    if (posix_spawn(&pid_, args[0], &fa, nullptr, args.data(), environ) != 0) pid_ = -1;
    posix_spawn_file_actions_destroy(&fa);
    EXPECT_GT(pid_, 0) << "cannot start " << argv[0];
  }
  ~Process() { Kill(SIGKILL); }
  Process(const Process&) = delete;
  Process& operator=(const Process&) = delete;

  /// Sends `sig` and reaps the process; its exit status (-1 when gone).
  int Kill(int sig) {
    if (pid_ <= 0) return -1;
    ::kill(pid_, sig);
    return Wait();
  }
  /// Waits for the process to end by itself; its exit code, or -signal.
  int Wait() {
    if (pid_ <= 0) return -1;
    int status = 0;
    ::waitpid(pid_, &status, 0);
    pid_ = -1;
    return WIFEXITED(status) ? WEXITSTATUS(status) : -WTERMSIG(status);
  }
  bool Running() {
    if (pid_ <= 0) return false;
    int status = 0;
    if (::waitpid(pid_, &status, WNOHANG) == 0) return true;
    pid_ = -1;
    return false;
  }
  std::string Log() const {
    std::ifstream in(log_);
    std::ostringstream ss;
    ss << in.rdbuf();
    return ss.str();
  }

 private:
  fs::path log_;
  pid_t pid_ = -1;
};

/// `show stat` on HAProxy's stats socket: "backend/server" -> status
/// ("UP", "DOWN", "UP 1/2" going down, "DOWN 1/2" coming up, ...).
std::map<std::string, std::string> ShowStat(const fs::path& socket_path) {
  std::map<std::string, std::string> out;
  const int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
  sockaddr_un a{};
  a.sun_family = AF_UNIX;
  std::snprintf(a.sun_path, sizeof(a.sun_path), "%s", socket_path.c_str());
  if (::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) != 0) {
    ::close(fd);
    return out;
  }
  const std::string cmd = "show stat\n";
  if (::write(fd, cmd.data(), cmd.size()) != static_cast<ssize_t>(cmd.size())) {
    ::close(fd);
    return out;
  }
  std::string text;
  char buf[4096];
  for (ssize_t n; (n = ::read(fd, buf, sizeof(buf))) > 0;) text.append(buf, n);
  ::close(fd);
  std::stringstream lines(text);
  std::vector<std::string> header;
  for (std::string line; std::getline(lines, line);) {
    std::vector<std::string> f;
    std::stringstream ss(line.rfind("# ", 0) == 0 ? line.substr(2) : line);
    for (std::string x; std::getline(ss, x, ',');) f.push_back(x);
    if (line.rfind("# ", 0) == 0) {
      header = f;
      continue;
    }
    std::size_t status = header.size();
    for (std::size_t i = 0; i < header.size(); ++i) {
      if (header[i] == "status") status = i;
    }
    if (f.size() > status && f.size() > 1) out[f[0] + "/" + f[1]] = f[status];
  }
  return out;
}

template <typename Pred>
bool WaitFor(Pred pred, std::chrono::milliseconds timeout) {
  const auto end = Clock::now() + timeout;
  while (Clock::now() < end) {
    if (pred()) return true;
    std::this_thread::sleep_for(50ms);
  }
  return pred();
}

/// A device session's line of `hapticpd observe --telemetry`, at the
/// observer's time `t_s` (the preceding "t ... s" line).
struct TelemetryLine {
  double t_s = 0;
  double updates_hz = 0;  // as the server counts them
  double force = 0;       // N, the largest commanded on the hand since the last line
};

/// The telemetry lines of an observer's output (one device session).
std::vector<TelemetryLine> ParseTelemetry(const std::string& log) {
  std::vector<TelemetryLine> out;
  std::stringstream in(log);
  double t = -1;
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("t ", 0) == 0) {
      t = std::strtod(line.c_str() + 2, nullptr);
      continue;
    }
    const std::size_t u = line.find(" updates "), f = line.find(" force ");
    if (t < 0 || line.rfind("  session ", 0) != 0 || u == std::string::npos ||
        f == std::string::npos) {
      continue;
    }
    out.push_back({t, std::strtod(line.c_str() + u + 9, nullptr),
                   std::strtod(line.c_str() + f + 7, nullptr)});
  }
  return out;
}

// The median of per-second rates: a second in which the whole machine
// stalls (seen here: every process of the test, observers included, lost
// most of one second while nothing was started or killed) moves it less
// than a change that lasts.
double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 == 1 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

std::string ReadText(const fs::path& p) {
  std::ifstream in(p);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

/// Replaces every `from` in `text`; fails the test when there is none (the
/// shipped file changed and this test no longer runs it as shipped).
void Replace(std::string* text, const std::string& from, const std::string& to) {
  std::size_t n = 0;
  for (std::size_t at = 0; (at = text->find(from, at)) != std::string::npos; at += to.size(), ++n) {
    text->replace(at, from.size(), to);
  }
  EXPECT_GT(n, 0u) << "docker/haproxy.cfg no longer holds '" << from << "'";
}

std::vector<std::string> ListScenes(const std::string& address) {
  auto stub =
      v1::SceneService::NewStub(grpc::CreateChannel(address, grpc::InsecureChannelCredentials()));
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + 5s);
  v1::ListScenesResponse resp;
  if (!stub->ListScenes(&ctx, {}, &resp).ok()) return {"(unreachable)"};
  std::vector<std::string> ids;
  for (const auto& s : resp.scenes()) ids.push_back(s.scene_id());
  return ids;
}

/// The shard docker/shard-map.txt gives each test scene, written out by hand
/// (longest prefix: `lab-vr-` over `lab-`).
const std::map<std::string, std::vector<std::string>>& ExpectedPlacement() {
  static const auto* m = [] {
    auto* m = new std::map<std::string, std::vector<std::string>>;
    for (int i = 0; i < 10; ++i) {
      (*m)["hapticpd-1"].push_back("lab-" + std::to_string(i));
      (*m)["hapticpd-3"].push_back("train-" + std::to_string(i));
    }
    for (int i = 0; i < 5; ++i) {
      (*m)["hapticpd-2"].push_back("lab-vr-" + std::to_string(i));
      (*m)["hapticpd-2"].push_back("demo-" + std::to_string(i));
    }
    for (auto& [_, ids] : *m) std::sort(ids.begin(), ids.end());
    return m;
  }();
  return *m;
}

class Scale : public ::testing::Test {
 protected:
  void SetUp() override {
    haproxy_ = FindHaproxy();
    if (haproxy_.empty()) {
      GTEST_SKIP() << "haproxy is not installed (Debian package `haproxy`, installed by "
                      "docker/install-deps.sh): the scale tests run HAProxy in front of three "
                      "hapticpd serve processes";
    }
    static int n = 0;
    dir_ = fs::temp_directory_path() /
           ("hapticpd_scale_" + std::to_string(::getpid()) + "_" + std::to_string(n++));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    for (int i = 1; i <= 3; ++i) ports_[Name(i)] = FreePort();
    balancer_port_ = FreePort();
  }
  void TearDown() override {
    devices_.clear();
    observers_.clear();
    haproxy_proc_.reset();
    servers_.clear();
    std::error_code ec;
    if (!HasFailure() && !dir_.empty()) fs::remove_all(dir_, ec);
  }

  static std::string Name(int i) { return "hapticpd-" + std::to_string(i); }
  std::string Address(const std::string& name) {
    return "127.0.0.1:" + std::to_string(ports_[name]);
  }
  std::string Balancer() const { return "127.0.0.1:" + std::to_string(balancer_port_); }
  fs::path Socket() const { return dir_ / "admin.sock"; }

  void StartServer(const std::string& name) {
    servers_[name] = std::make_unique<Process>(
        std::vector<std::string>{HAPTICPD_CLI_PATH, "serve", "--listen", Address(name), "--state",
                                 (dir_ / name).string(), "--shard-map",
                                 (kDocker / "shard-map.txt").string(), "--shard", name,
                                 "--status-interval", "0", "--log-level", "warn"},
        dir_ / (name + ".log"));
    ASSERT_TRUE(WaitFor(
        [&] { return ListScenes(Address(name)) != std::vector<std::string>{"(unreachable)"}; },
        20s))
        << name << " did not start: " << servers_[name]->Log();
  }

  /// docker/haproxy.cfg on loopback; `edit` changes it further.
  void StartBalancer(const std::function<void(std::string*)>& edit = {}) {
    std::string cfg = ReadText(kDocker / "haproxy.cfg");
    Replace(&cfg, "bind :50051 proto h2 ssl crt /etc/haproxy/tls/hapticpd.pem alpn h2",
            "bind " + Balancer() + " proto h2");
    Replace(&cfg, "/var/run/haproxy/admin.sock", Socket().string());
    Replace(&cfg, "/etc/haproxy/shard-map.txt", (kDocker / "shard-map.txt").string());
    for (int i = 1; i <= 3; ++i) Replace(&cfg, Name(i) + ":50051", Address(Name(i)));
    if (edit) edit(&cfg);
    std::ofstream(dir_ / "haproxy.cfg") << cfg;
    haproxy_proc_ = std::make_unique<Process>(
        std::vector<std::string>{haproxy_, "-db", "-f", (dir_ / "haproxy.cfg").string()},
        dir_ / "haproxy.log");
    ASSERT_TRUE(WaitFor([&] { return !ShowStat(Socket()).empty(); }, 10s))
        << "HAProxy did not start: " << haproxy_proc_->Log();
  }

  std::string Status(const std::string& name) {
    return ShowStat(Socket())["shard_" + name + "/" + name];
  }
  bool Up(const std::string& name) { return Status(name) == "UP"; }
  /// What the observer of `name`'s coupled scene has printed so far.
  std::vector<TelemetryLine> TelemetryOf(const std::string& name) {
    return ParseTelemetry(observers_.at(name)->Log());
  }
  bool Down(const std::string& name) { return Status(name).rfind("DOWN", 0) == 0; }

  /// `hapticpd ARGS` through the balancer.
  RunResult Cli(const std::string& args) {
    return RunCli(args + " --server " + Balancer() + " --timeout 10");
  }

  std::string haproxy_;
  fs::path dir_;
  std::map<std::string, int> ports_;
  int balancer_port_ = 0;
  std::map<std::string, std::unique_ptr<Process>> servers_;
  std::unique_ptr<Process> haproxy_proc_;
  std::map<std::string, std::unique_ptr<Process>> devices_;
  std::map<std::string, std::unique_ptr<Process>> observers_;
};

constexpr char kSessionRate[] = "500";  // updates/s (device --max-rate)

TEST_F(Scale, EachSceneLivesOnItsOwnerAndNowhereElseWhenItDies) {
  for (int i = 1; i <= 3; ++i) ASSERT_NO_FATAL_FAILURE(StartServer(Name(i)));
  ASSERT_NO_FATAL_FAILURE(StartBalancer());
  for (int i = 1; i <= 3; ++i) {
    ASSERT_TRUE(WaitFor([&] { return Up(Name(i)); }, 10s)) << Name(i) << ": " << Status(Name(i));
  }

  // 30 scenes through the balancer, each on the process the map names.
  for (const auto& [name, ids] : ExpectedPlacement()) {
    for (const auto& id : ids) {
      const RunResult r = Cli("scene create " + id);
      ASSERT_EQ(r.exit_code, 0) << id << ": " << r.err;
    }
  }
  for (const auto& [name, ids] : ExpectedPlacement()) {
    EXPECT_EQ(ListScenes(Address(name)), ids) << name;
  }
  {
    std::string servers;
    for (int i = 1; i <= 3; ++i) servers += (i > 1 ? "," : "") + Address(Name(i));
    const RunResult all = RunCli("scene list --servers " + servers);
    EXPECT_EQ(all.exit_code, 0) << all.err;
    EXPECT_EQ(std::count(all.out.begin(), all.out.end(), '\n'), 30) << all.out;
  }
  // A scene no prefix maps belongs to no process.
  const RunResult nobody = Cli("scene create nobody-1");
  EXPECT_NE(nobody.exit_code, 0);
  EXPECT_NE(nobody.err.find("FAILED_PRECONDITION"), std::string::npos) << nobody.err;

  // A 1 kHz device session on a scene of each process, through the balancer,
  // pressing a stick into a box (`device --simulated press`), and an
  // observer of each scene's relayed telemetry. hapticpd-2's session runs on
  // past its server's restart. The loops run at 1 kHz; each asks for at
  // most kSessionRate server answers and renders them without the local
  // model: three servers, three loops, three observers and HAProxy
  // saturate this 2-core machine otherwise (a survivor's update rate then
  // swung 750-1000/s from second to second, and lower while the dying pair
  // lived), and the rate would measure the CPU the dead pair frees, not the
  // sessions' independence. (The fade with the local model on is
  // Servo.EndedStreamFadesAtOnceAndDropsLateIrs and
  // LocalModelE2e.ServerLossDropsThePatchAndReconnectBringsItBack.)
  const std::map<std::string, std::string> coupled = {
      {"hapticpd-1", "lab-0"}, {"hapticpd-2", "lab-vr-0"}, {"hapticpd-3", "train-0"}};
  std::map<std::string, Clock::time_point> observed_from;
  for (const auto& [name, scene] : coupled) {
    const RunResult r =
        Cli("inject --scene " + scene + " --shape box:0.1,0.1,0.1 --id box --pose 0,0,0");
    ASSERT_EQ(r.exit_code, 0) << r.err;
    const bool dies = name == "hapticpd-2";
    devices_[name] = std::make_unique<Process>(
        std::vector<std::string>{HAPTICPD_CLI_PATH, "device", "--server", Balancer(), "--scene",
                                 scene, "--probe", "shape:stick", "--local-model", "off",
                                 "--max-rate", kSessionRate, "--simulated", "press", "--duration",
                                 dies ? "28" : "20", "--json", "--record",
                                 (dir_ / ("device-" + name + ".csv")).string()},
        dir_ / ("device-" + name + ".log"));
    observed_from[name] = Clock::now();
    observers_[name] = std::make_unique<Process>(
        std::vector<std::string>{HAPTICPD_CLI_PATH, "observe", "--server", Balancer(), "--scene",
                                 scene, "--telemetry", "--duration", "20"},
        dir_ / ("observe-" + name + ".log"));
  }
  // Kill once every session has run 6 s and hapticpd-2's presses in. The
  // survivors' "before" window (the 4 s before the kill) then starts 2 s
  // after the last process was started: those starts cost the loops more
  // than anything the window is about.
  Clock::time_point last_started = Clock::time_point::min();
  for (const auto& [name, t] : observed_from) last_started = std::max(last_started, t);
  ASSERT_TRUE(WaitFor(
      [&] {
        if (Clock::now() < last_started + 6s) return false;
        for (const auto& [name, _] : coupled) {
          if (TelemetryOf(name).size() < 3) return false;
        }
        const auto t = TelemetryOf("hapticpd-2");
        return t.back().force > 0.5;
      },
      20s))
      << observers_["hapticpd-2"]->Log() << devices_["hapticpd-2"]->Log();

  // hapticpd-2 dies.
  const auto killed = Clock::now();
  servers_["hapticpd-2"]->Kill(SIGKILL);
  ASSERT_TRUE(WaitFor([&] { return Down("hapticpd-2"); }, 10s)) << Status("hapticpd-2");
  const double to_down = std::chrono::duration<double>(Clock::now() - killed).count();
  EXPECT_LT(to_down, 3.0) << "HAProxy marked hapticpd-2 down " << to_down << " s after the kill";
  std::cout << "hapticpd-2 marked down " << to_down << " s after the kill\n";
  EXPECT_TRUE(Up("hapticpd-1") && Up("hapticpd-3"));

  // Its scenes are served nowhere: calls get UNAVAILABLE, creating one fails
  // the same way, and no other process takes it.
  for (const std::string& id : ExpectedPlacement().at("hapticpd-2")) {
    const RunResult r = Cli("scene get " + id);
    EXPECT_NE(r.exit_code, 0) << id;
    EXPECT_NE(r.err.find("UNAVAILABLE"), std::string::npos) << id << ": " << r.err;
  }
  const RunResult create = Cli("scene create lab-vr-new");
  EXPECT_NE(create.err.find("UNAVAILABLE"), std::string::npos) << create.err;
  for (const std::string name : {"hapticpd-1", "hapticpd-3"}) {
    EXPECT_EQ(ListScenes(Address(name)), ExpectedPlacement().at(name)) << name;
  }

  // The survivors' window after the kill: 4 s with nothing else started
  // (the checks above start a CLI process each, which on this machine
  // costs the loops more than the kill could).
  const auto quiet_from = Clock::now();
  std::this_thread::sleep_until(quiet_from + 4s);

  // Back after a restart, from its state directory.
  const auto restarted = Clock::now();
  ASSERT_NO_FATAL_FAILURE(StartServer("hapticpd-2"));
  ASSERT_TRUE(WaitFor([&] { return Up("hapticpd-2"); }, 10s)) << Status("hapticpd-2");
  EXPECT_EQ(ListScenes(Address("hapticpd-2")), ExpectedPlacement().at("hapticpd-2"));
  const RunResult get = Cli("scene get lab-vr-0");
  EXPECT_EQ(get.exit_code, 0) << get.err;
  EXPECT_NE(get.out.find("\"box\""), std::string::npos) << get.out;
  EXPECT_TRUE(Cli("scene create lab-vr-new").exit_code == 0);
  EXPECT_EQ(ListScenes(Address("hapticpd-1")), ExpectedPlacement().at("hapticpd-1"));

  // Every session ran to its end; hapticpd-2's reconnected to the restarted process.
  std::map<std::string, nlohmann::json> stats;
  for (const auto& [name, scene] : coupled) {
    const int code = devices_[name]->Wait();
    const std::string log = devices_[name]->Log();
    ASSERT_EQ(code, 0) << name << ": " << log;
    // The statistics are the last line that opens a JSON object.
    const std::size_t nl = log.rfind("\n{");
    const std::size_t brace = nl != std::string::npos ? nl + 1 : log.rfind('{', 0);
    ASSERT_NE(brace, std::string::npos) << name << ": no statistics: " << log;
    stats[name] = nlohmann::json::parse(log.substr(brace));
  }
  EXPECT_EQ(stats["hapticpd-1"]["disconnects"], 0) << stats["hapticpd-1"].dump();
  EXPECT_EQ(stats["hapticpd-3"]["disconnects"], 0) << stats["hapticpd-3"].dump();
  EXPECT_GE(stats["hapticpd-2"]["disconnects"].get<int>(), 1) << stats["hapticpd-2"].dump();
  EXPECT_GE(stats["hapticpd-2"]["connects"].get<int>(), 2)
      << "hapticpd-2's session did not reconnect after the restart: " << stats["hapticpd-2"].dump();

  // The other processes' sessions went on at their rate: the median of the
  // update rates their observers saw over the 4 s before the kill and over
  // the 3 s from 1 s into the quiet window after it differ by less than
  // 10 % (a stall of a survivor shows as a second at a fraction of the
  // rate; a machine busy with other work moved the medians by up to 5.4 %).
  for (const std::string name : {"hapticpd-1", "hapticpd-3"}) {
    observers_[name]->Wait();
    std::vector<double> before, after;
    for (const TelemetryLine& l : TelemetryOf(name)) {
      const auto at = observed_from[name] + std::chrono::duration_cast<Clock::duration>(
                                                std::chrono::duration<double>(l.t_s));
      if (at > killed - 4s && at <= killed) before.push_back(l.updates_hz);
      if (at > quiet_from + 1s && at <= quiet_from + 4s) after.push_back(l.updates_hz);
    }
    ASSERT_GE(before.size(), 2u) << observers_[name]->Log();
    ASSERT_GE(after.size(), 2u) << observers_[name]->Log();
    const double b = Median(before), a = Median(after);
    std::cout << name << ": median updates/s " << b << " before the kill, " << a << " after\n";
    // Running at all before the kill: three servers, their sessions and
    // observers share two cores with whatever test ctest runs beside this
    // one (448 updates/s of 500 seen once), so the floor is generous; the
    // comparison below is what the test is about.
    EXPECT_GT(b, 0.75 * std::stod(kSessionRate)) << name << ": " << observers_[name]->Log();
    EXPECT_LT(std::abs(a / b - 1), 0.10)
        << name << ": " << b << " updates/s before the kill, " << a << " after\n"
        << observers_[name]->Log();
  }

  // hapticpd-2's session pushed before the kill, and 50 ms after it the force
  // on the hand was zero (under 1 mN) until its server was back: the stream
  // went quiet, the IR went stale and the link gain faded it out.
  const device::Recording rec = device::LoadRecording(dir_ / "device-hapticpd-2.csv");
  const std::int64_t start_ns = std::stoll(rec.Header("start_ns"));
  const auto ns = [](Clock::time_point t) {
    return std::chrono::duration_cast<std::chrono::nanoseconds>(t.time_since_epoch()).count();
  };
  double pushed = 0, after_fade = 0, worst_at_ms = 0, last_force_ms = 0;
  std::size_t faded_ticks = 0;
  std::string profile;  // |F| every 10 ms from the kill, for the failure message
  for (const device::TrajectorySample& s : rec.samples) {
    const std::int64_t t = start_ns + std::llround(s.t_s * 1e9);
    const double f = s.F_cmd_D.force.norm();
    if (t > ns(killed - 200ms) && t <= ns(killed)) pushed = std::max(pushed, f);
    const double since_kill_ms = (t - ns(killed)) * 1e-6;
    if (since_kill_ms >= 0 && since_kill_ms < 200 && std::fmod(s.t_s * 1e3, 10.0) < 1.0) {
      profile += " " + std::to_string(static_cast<int>(since_kill_ms)) + ":" + std::to_string(f);
    }
    if (t >= ns(killed) && t < ns(restarted) && f >= 1e-3) last_force_ms = since_kill_ms;
    if (t >= ns(killed + 50ms) && t < ns(restarted)) {
      if (f > after_fade) worst_at_ms = since_kill_ms;
      after_fade = std::max(after_fade, f);
      ++faded_ticks;
    }
  }
  EXPECT_GT(pushed, 0.3) << "no contact force in the 200 ms before the kill";
  std::cout << "hapticpd-2's session: " << pushed << " N before the kill, under 1 mN from "
            << last_force_ms << " ms after it\n";
  EXPECT_GT(faded_ticks, 1000u);
  EXPECT_LT(after_fade, 1e-3) << "N on the hand from 50 ms after its server died (at "
                              << worst_at_ms << " ms); ms:|F| from the kill:" << profile;
}

/// A gRPC server that answers grpc.health.v1.Health/Check, SERVING or
/// NOT_SERVING (the HealthCheckResponse `status` field: 08 01 or 08 02),
/// and refuses every other method.
class HealthOnly final : public grpc::CallbackGenericService {
 public:
  HealthOnly(int port, bool serving) : serving_(serving) {
    grpc::ServerBuilder b;
    b.AddListeningPort("127.0.0.1:" + std::to_string(port), grpc::InsecureServerCredentials());
    b.RegisterCallbackGenericService(this);
    server_ = b.BuildAndStart();
  }
  ~HealthOnly() override { server_->Shutdown(std::chrono::system_clock::now()); }

 private:
  class Answer final : public grpc::ServerGenericBidiReactor {
   public:
    Answer(bool check, bool serving) : check_(check) {
      const char bytes[2] = {0x08, static_cast<char>(serving ? 0x01 : 0x02)};
      grpc::Slice slice(bytes, sizeof(bytes));
      response_ = grpc::ByteBuffer(&slice, 1);
      if (!check_) {
        Finish(grpc::Status(grpc::StatusCode::UNIMPLEMENTED, "only Health/Check"));
        return;
      }
      StartRead(&request_);
    }
    void OnReadDone(bool) override { StartWriteAndFinish(&response_, {}, grpc::Status::OK); }
    void OnDone() override { delete this; }

   private:
    bool check_;
    grpc::ByteBuffer request_, response_;
  };
  grpc::ServerGenericBidiReactor* CreateReactor(grpc::GenericCallbackServerContext* ctx) override {
    return new Answer(ctx->method() == "/grpc.health.v1.Health/Check", serving_);
  }

  bool serving_;
  std::unique_ptr<grpc::Server> server_;
};

TEST_F(Scale, HealthCheckReadsTheAnswerNotTheHttpStatus) {
  // hapticpd-1 a real server, -2 health NOT_SERVING, -3 health SERVING.
  ASSERT_NO_FATAL_FAILURE(StartServer("hapticpd-1"));
  HealthOnly not_serving(ports_["hapticpd-2"], false);
  HealthOnly serving(ports_["hapticpd-3"], true);
  ASSERT_NO_FATAL_FAILURE(StartBalancer());
  EXPECT_TRUE(WaitFor([&] { return Down("hapticpd-2"); }, 5s)) << Status("hapticpd-2");
  std::this_thread::sleep_for(2s);  // several checks later
  EXPECT_EQ(Status("hapticpd-1"), "UP");
  EXPECT_EQ(Status("hapticpd-3"), "UP");
  EXPECT_TRUE(Down("hapticpd-2")) << Status("hapticpd-2");
  // A scene of the NOT_SERVING process: UNAVAILABLE, not another process.
  const RunResult r = Cli("scene get demo-1");
  EXPECT_NE(r.err.find("UNAVAILABLE"), std::string::npos) << r.err;

  // The same file asking for a wrong method (":path .../Nope!", as long as
  // "/Check" in the HPACK bytes): gRPC still answers HTTP 200 (UNIMPLEMENTED
  // in the trailers), and every process goes down.
  haproxy_proc_.reset();
  fs::remove(Socket());
  ASSERT_NO_FATAL_FAILURE(StartBalancer([](std::string* cfg) {
    Replace(cfg, "4865616c74682f436865636b01", "4865616c74682f4e6f70652101");
  }));
  for (int i = 1; i <= 3; ++i) {
    EXPECT_TRUE(WaitFor([&] { return Down(Name(i)); }, 5s)) << Name(i) << ": " << Status(Name(i));
  }
}

}  // namespace
}  // namespace hapticpd::testing::scale_tests
