// End to end: runs `hapticpd serve` as a child process on 127.0.0.1 with an
// ephemeral port and drives it with the `hapticpd` CLIs (inject, move,
// remove, scene, watch, couple), then stops it with SIGTERM / SIGINT while a
// session is open. Every wait is bounded.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <thread>

#include <grpcpp/grpcpp.h>

#include "hapticpd/v1/scene.grpc.pb.h"
#include "tests/test_util.h"

namespace hapticpd::testing {
namespace {

namespace fs = std::filesystem;

std::string Slurp(const fs::path& p) {
  std::ifstream in(p);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

struct RunResult {
  int exit_code = -1;
  std::string out, err;
};

class ServeProcess {
 public:
  explicit ServeProcess(const std::vector<std::string>& extra) {
    dir_ = fs::temp_directory_path() /
           ("hapticpd_e2e_" + std::to_string(::getpid()) + "_" + std::to_string(counter_++));
    fs::create_directories(dir_);
    log_ = dir_ / "serve.log";
    std::vector<std::string> args = {HAPTICPD_CLI_PATH,   "serve", "--listen",   "127.0.0.1:0",
                                     "--status-interval", "0.2",   "--ephemeral"};
    args.insert(args.end(), extra.begin(), extra.end());
    pid_ = ::fork();
    if (pid_ == 0) {
      const int fd = ::open(log_.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      ::dup2(fd, 1);
      ::dup2(fd, 2);
      const int devnull = ::open("/dev/null", O_RDONLY);
      ::dup2(devnull, 0);
      std::vector<char*> argv;
      for (auto& a : args) argv.push_back(a.data());
      argv.push_back(nullptr);
      ::execv(argv[0], argv.data());
      ::_exit(127);
    }
  }
  ~ServeProcess() {
    if (pid_ > 0 && !exited_) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }

  /// Waits for "listening on 127.0.0.1:PORT" in the log; returns the address.
  std::string WaitAddress() {
    const std::regex re("listening on (127\\.0\\.0\\.1:[0-9]+)");
    for (int i = 0; i < 3000; ++i) {  // up to 30 s
      std::smatch m;
      const std::string log = Slurp(log_);
      if (std::regex_search(log, m, re)) return m[1];
      if (HasExited()) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    ADD_FAILURE() << "server did not start; log:\n" << Slurp(log_);
    return "";
  }

  bool HasExited() {
    if (exited_) return true;
    int status = 0;
    if (::waitpid(pid_, &status, WNOHANG) == pid_) {
      exited_ = true;
      exit_code_ = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    }
    return exited_;
  }

  /// Sends `sig` and waits (bounded) for the exit code.
  int Stop(int sig) {
    ::kill(pid_, sig);
    for (int i = 0; i < 3000 && !HasExited(); ++i) {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    EXPECT_TRUE(exited_) << "server did not exit within 30 s of signal " << sig;
    return exit_code_;
  }

  std::string log() const { return Slurp(log_); }
  const fs::path& dir() const { return dir_; }

 private:
  static inline int counter_ = 0;
  fs::path dir_, log_;
  pid_t pid_ = -1;
  bool exited_ = false;
  int exit_code_ = -1;
};

/// Runs `hapticpd ARGS` (shell text) with stdin from /dev/null, behind the
/// command `wrapper` (shell text, e.g. "timeout 2") when one is given.
RunResult Cli(const std::string& args, const fs::path& dir, const std::string& wrapper = "") {
  static int n = 0;
  const fs::path err = dir / ("cli_" + std::to_string(n++) + ".err");
  const std::string cmd =
      wrapper + " '" + HAPTICPD_CLI_PATH + "' " + args + " </dev/null 2>'" + err.string() + "'";
  RunResult r;
  FILE* pipe = ::popen(cmd.c_str(), "r");
  if (!pipe) return r;
  char buf[4096];
  std::size_t got = 0;
  while ((got = std::fread(buf, 1, sizeof buf, pipe)) > 0) r.out.append(buf, got);
  const int status = ::pclose(pipe);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.err = Slurp(err);
  return r;
}

TEST(ServeE2eTest, CliDrivesAServerThatStopsCleanlyOnSigterm) {
  ServeProcess srv({});
  const std::string addr = srv.WaitAddress();
  ASSERT_FALSE(addr.empty());
  const std::string s = "--server " + addr + " --timeout 30";
  const fs::path obj = srv.dir() / "tet.obj";
  std::ofstream(obj)
      << "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";

  RunResult r = Cli("inject " + s + " --shape box:0.05,0.05,0.05 --id floor", srv.dir());
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.out, "floor\n");
  r = Cli("inject " + s + " --mesh '" + obj.string() + "' --pose 0.5,0,0 --movable --chunk-kib 1",
          srv.dir());
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.out, "body-1\n");
  r = Cli("move " + s + " --body body-1 --pose 0.6,0,0,1,0,0,0", srv.dir());
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("body-1"), std::string::npos);
  // The same pose syntax as pd's: spaces, commas or both between numbers.
  r = Cli("move " + s + " --body body-1 --pose '0.6 0 0 1, 0, 0, 0'", srv.dir());
  EXPECT_EQ(r.exit_code, 0) << r.err;
  r = Cli("move " + s + " --body body-1 --pose '0.6,,0'", srv.dir());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("--pose: an empty field"), std::string::npos) << r.err;
  r = Cli("scene list " + s, srv.dir());
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("default  bodies 2"), std::string::npos) << r.out;

  // A short scripted device session pressing into the floor, and an observer.
  r = Cli("couple " + s + " --duration 0.5 --rate 500 --from 0,0,0.1 --to 0,0,0.052", srv.dir());
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find(" updates in "), std::string::npos) << r.out;
  r = Cli("watch " + s + " --count 3 --rate 100", srv.dir());
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("snapshot: 2 bodies"), std::string::npos) << r.out;
  // Ended by Ctrl-C while writing into a pipe, watch has written every
  // event line it printed (no line waits in a buffer when the signal comes).
  r = Cli("watch " + s + " --rate 10", srv.dir(), "timeout -s INT 2");
  EXPECT_NE(r.out.find("snapshot: 2 bodies"), std::string::npos) << r.out << r.err;

  // Errors: non-zero exit, one line naming the status and the field.
  r = Cli("remove " + s + " --body nope", srv.dir());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(r.out, "");
  EXPECT_EQ(r.err, "hapticpd: remove: NOT_FOUND: body_id: scene 'default' has no body 'nope'\n");
  r = Cli("move " + s + " --body floor --pose 0,0,0,2,0,0,0", srv.dir());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("INVALID_ARGUMENT: pose.orientation"), std::string::npos) << r.err;
  r = Cli("inject " + s + " --shape box --pose 0,nan,0", srv.dir());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("INVALID_ARGUMENT: header.spec.pose.position.y"), std::string::npos)
      << r.err;
  r = Cli("remove " + s + " --body floor", srv.dir());
  EXPECT_EQ(r.exit_code, 0) << r.err;

  EXPECT_EQ(srv.Stop(SIGTERM), 0) << srv.log();
  const std::string log = srv.log();
  EXPECT_NE(log.find("running open (no authentication), loopback only"), std::string::npos);
  EXPECT_NE(log.find("status: "), std::string::npos) << log;
  EXPECT_NE(log.find("received SIGTERM"), std::string::npos) << log;
  EXPECT_NE(log.find("server stopped"), std::string::npos) << log;
}

TEST(ServeE2eTest, SigintWithASessionOpenTellsTheSession) {
  ServeProcess srv({});
  const std::string addr = srv.WaitAddress();
  ASSERT_FALSE(addr.empty());
  const fs::path out = srv.dir() / "couple.out";
  const std::string cmd = std::string("'") + HAPTICPD_CLI_PATH + "' couple --server " + addr +
                          " --duration 60 --rate 200 </dev/null >'" + out.string() + "' 2>&1";
  std::thread client([&] { (void)std::system(cmd.c_str()); });
  // Wait until the session is up, then interrupt the server.
  bool up = false;
  for (int i = 0; i < 3000 && !up; ++i) {
    up = Slurp(out).find("session ") != std::string::npos;
    if (!up) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_TRUE(up) << Slurp(out);
  EXPECT_EQ(srv.Stop(SIGINT), 0) << srv.log();
  client.join();
  EXPECT_NE(Slurp(out).find("UNAVAILABLE: server is shutting down"), std::string::npos)
      << Slurp(out);
}

TEST(ServeE2eTest, TokensAndBadStartOptions) {
  ServeProcess probe({});  // for a scratch folder
  const fs::path tokens = probe.dir() / "tokens.json";
  std::ofstream(tokens) << R"({"tokens": [{"token": "t1", "roles": {"default": ["inject"]}}]})";
  {
    ServeProcess srv({"--tokens", tokens.string()});
    const std::string addr = srv.WaitAddress();
    ASSERT_FALSE(addr.empty());
    RunResult r = Cli("inject --server " + addr + " --shape box", srv.dir());
    EXPECT_EQ(r.exit_code, 1);
    EXPECT_NE(r.err.find("UNAUTHENTICATED"), std::string::npos) << r.err;
    r = Cli("inject --server " + addr + " --token t1 --shape box", srv.dir());
    EXPECT_EQ(r.exit_code, 0) << r.err;
    r = Cli("scene create lab --server " + addr + " --token t1", srv.dir());
    EXPECT_EQ(r.exit_code, 1);
    EXPECT_NE(r.err.find("PERMISSION_DENIED"), std::string::npos) << r.err;
    // A second server on the same port: one line naming the problem, not
    // gRPC's log record first.
    r = Cli("serve --ephemeral --listen " + addr, probe.dir());
    EXPECT_EQ(r.exit_code, 1);
    EXPECT_EQ(r.err, "hapticpd: serve: cannot listen on " + addr +
                         ": address already in use (is another server running on that port?)\n");
    EXPECT_EQ(srv.Stop(SIGTERM), 0);
  }
  RunResult r = Cli("serve --ephemeral --listen 0.0.0.0:0", probe.dir());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("loopback"), std::string::npos) << r.err;
  probe.Stop(SIGTERM);
}

/// GetScene with meshes, revision cleared and each orientation checked
/// against `other`'s within 1e-12, then copied from it (a quaternion goes
/// through a rotation matrix on the way).
v1::Scene SceneFor(const std::string& addr, const std::string& id) {
  auto stub =
      v1::SceneService::NewStub(grpc::CreateChannel(addr, grpc::InsecureChannelCredentials()));
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
  v1::GetSceneRequest req;
  req.set_scene_id(id);
  req.set_include_meshes(true);
  v1::Scene sc;
  EXPECT_TRUE(stub->GetScene(&ctx, req, &sc).ok());
  sc.clear_revision();
  return sc;
}

// `scene export` then `scene import` into another server: the scene comes
// back with everything (config, ids, labels, poses, velocities, materials,
// movable flags, meshes to the last bit).
TEST(ServeE2eTest, SceneExportThenImportLosesNothing) {
  ServeProcess a({}), b({});
  const std::string addr_a = a.WaitAddress(), addr_b = b.WaitAddress();
  ASSERT_FALSE(addr_a.empty());
  ASSERT_FALSE(addr_b.empty());
  const fs::path file = a.dir() / "lab.json";
  std::ofstream(file) << R"({"scene": "lab", "description": "a lab", "mode": "pdg",
    "effects": ["contact", "friction", "texture"], "gravity": [0, 0.5, -3],
    "texture": {"amplitude": 0.5, "frequency": 100},
    "probe": {"shape": "sphere:0.01", "mass": 0.2, "inertia": 0.001},
    "bodies": [{"id": "cup", "shape": "cup:1", "label": "the cup", "movable": true,
      "pose": {"position": [0.1, 0.2, 0.3], "orientation": [0.6, 0.8, 0, 0]},
      "material": {"stiffness": 1234.5, "rotational_stiffness": 0.25, "damping": 3,
                   "static_friction": 0.7, "dynamic_friction": 0.3},
      "velocity": {"linear": [0.1, 0, 0], "angular": [0, 0, 1]}}]})";
  std::ofstream(a.dir() / "tet.obj") << "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\n"
                                        "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
  const std::string s = " --server " + addr_a + " --timeout 30";
  for (const std::string& cmd :
       {"scene load " + file.string() + s,
        "inject --scene lab --mesh " + (a.dir() / "tet.obj").string() +
            " --id tet --velocity 0.1,0.2,0.3,1,2,3 --stiffness 500 --movable --label mesh" + s,
        "inject --scene lab --shape sphere:0.0123456789,2 --id ball --pose 1e-3,2e-3,3e-3" + s,
        "move --scene lab --body cup --pose 0.5,0.25,0.125,0.28,0.96,0,0 --velocity 1,2,3" + s,
        "scene export lab " + (a.dir() / "out").string() + s,
        "scene import " + (a.dir() / "out").string() + " --server " + addr_b}) {
    const RunResult r = Cli(cmd, a.dir());
    ASSERT_EQ(r.exit_code, 0) << cmd << "\n" << r.err;
  }
  v1::Scene from = SceneFor(addr_a, "lab"), to = SceneFor(addr_b, "lab");
  ASSERT_EQ(from.bodies_size(), 3);
  ASSERT_EQ(to.bodies_size(), 3);
  for (int i = 0; i < 3; ++i) {
    const auto& q = from.bodies(i).pose().orientation();
    auto* r = to.mutable_bodies(i)->mutable_pose()->mutable_orientation();
    EXPECT_NEAR(r->w(), q.w(), 1e-12);
    EXPECT_NEAR(r->x(), q.x(), 1e-12);
    EXPECT_NEAR(r->y(), q.y(), 1e-12);
    EXPECT_NEAR(r->z(), q.z(), 1e-12);
    *r = q;
  }
  EXPECT_EQ(to.DebugString(), from.DebugString());
  EXPECT_EQ(a.Stop(SIGTERM), 0);
  EXPECT_EQ(b.Stop(SIGTERM), 0);
}

}  // namespace
}  // namespace hapticpd::testing
