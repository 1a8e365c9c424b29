// Durability of the state directory against kill -9: a real `hapticpd serve
// --state DIR` process takes a stream of mutations (scenes created and
// deleted, bodies added as shapes and as an uploaded mesh file, moved and
// removed, each with a request id) and is killed with SIGKILL at a random
// moment. After a restart on the same directory every acknowledged
// structural mutation is there (the one in flight at the kill may or may not
// be), every body's pose is one it held within the last 100 ms before the
// kill (server/README.md "State directory": poses are written in batches),
// and the database passes PRAGMA integrity_check. Real time decides where
// the kill lands: label `timing`. Rounds: 3, or 60 with --long
// (HAPTICPD_TEST_COUNT to choose).
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sqlite3.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <optional>
#include <random>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "tests/server/server_harness.h"
#include "tests/test_util.h"

namespace hapticpd::testing::durability_tests {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

std::string ReadAll(const fs::path& p) {
  std::ifstream in(p);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

/// `hapticpd serve --state DIR` as a child process.
class Serve {
 public:
  Serve(const fs::path& state, const fs::path& log) : log_(log) {
    std::vector<std::string> args = {HAPTICPD_CLI_PATH,   "serve",   "--listen",
                                     "127.0.0.1:0",       "--state", state.string(),
                                     "--status-interval", "0"};
    pid_ = ::fork();
    if (pid_ == 0) {
      const int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      ::dup2(fd, 1);
      ::dup2(fd, 2);
      std::vector<char*> argv;
      for (auto& a : args) argv.push_back(a.data());
      argv.push_back(nullptr);
      ::execv(argv[0], argv.data());
      ::_exit(127);
    }
  }
  ~Serve() { Kill(); }

  /// "127.0.0.1:PORT" once the log says it listens, "" when it did not start.
  std::string WaitAddress() {
    const std::regex re("listening on (127\\.0\\.0\\.1:[0-9]+)");
    for (int i = 0; i < 3000; ++i) {
      std::smatch m;
      const std::string log = ReadAll(log_);
      if (std::regex_search(log, m, re)) return m[1];
      int status = 0;
      if (::waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        break;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    ADD_FAILURE() << "server did not start:\n" << ReadAll(log_);
    return "";
  }
  void Kill() {
    if (pid_ <= 0) return;
    ::kill(pid_, SIGKILL);
    ::waitpid(pid_, nullptr, 0);
    pid_ = -1;
  }
  int Term() {
    ::kill(pid_, SIGTERM);
    int status = 0;
    ::waitpid(pid_, &status, 0);
    pid_ = -1;
    return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  }
  pid_t pid() const { return pid_; }

 private:
  fs::path log_;
  pid_t pid_ = -1;
};

struct PoseEvent {
  double x;                 ///< the pose's x (unique per move)
  Clock::time_point sent;   ///< before the request was sent
  Clock::time_point acked;  ///< when the answer came (max() while unknown)
};

struct BodyModel {
  bool movable = false;
  std::string label;
  std::uint32_t triangles = 0;
  std::vector<PoseEvent> poses;  ///< acknowledged moves in order (the first: AddBody)
};

struct SceneModel {
  std::map<std::string, BodyModel> bodies;
};

/// What the client was told, and the one mutation whose answer never came.
struct Model {
  std::map<std::string, SceneModel> scenes;
  enum class Op { kNone, kCreate, kDelete, kAdd, kMove, kRemove } uncertain = Op::kNone;
  std::string u_scene, u_body;
  BodyModel u_added;
  std::optional<PoseEvent> u_move;
};

std::string WriteMeshFile(const fs::path& dir) {
  // A closed octahedron with 8 triangles, as an OBJ file.
  const fs::path p = dir / "octa.obj";
  std::ofstream(p) << "v 0.1 0 0\nv -0.1 0 0\nv 0 0.1 0\nv 0 -0.1 0\nv 0 0 0.1\nv 0 0 -0.1\n"
                      "f 1 3 5\nf 3 2 5\nf 2 4 5\nf 4 1 5\nf 3 1 6\nf 2 3 6\nf 4 2 6\nf 1 4 6\n";
  return p.string();
}

std::unique_ptr<grpc::ClientContext> Deadline() {
  auto ctx = std::make_unique<grpc::ClientContext>();
  ctx->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
  return ctx;
}

/// Sends random mutations until one fails (the server was killed); returns
/// that status.
grpc::Status Drive(v1::SceneService::Stub& stub, std::mt19937_64& rng,
                   const std::string& mesh_bytes, Model* m, int round) {
  int counter = 0;
  const auto start = Clock::now();
  struct Tally {
    int n = 0;
    double ms = 0;
  };
  std::map<std::string, Tally> tally;
  auto report = [&] {
    std::ostringstream line;
    line << "round " << round << ": killed after "
         << std::chrono::duration<double, std::milli>(Clock::now() - start).count() << " ms;";
    for (const auto& [op, t] : tally)
      line << " " << op << " " << t.n << " (mean " << t.ms / std::max(1, t.n) << " ms)";
    std::cout << line.str() << "\n";
  };
  auto rid = [&] { return "r" + std::to_string(round) + "-" + std::to_string(counter++); };
  std::uniform_real_distribution<double> u(0, 1);
  for (;;) {
    // Pick an operation that applies to the model.
    std::vector<std::string> scenes;
    for (const auto& [id, s] : m->scenes) scenes.push_back(id);
    std::vector<std::pair<std::string, std::string>> bodies, movable;
    for (const auto& [sid, s] : m->scenes) {
      for (const auto& [bid, b] : s.bodies) {
        bodies.emplace_back(sid, bid);
        if (b.movable) movable.emplace_back(sid, bid);
      }
    }
    const double r = u(rng);
    const auto t_sent = Clock::now();
    grpc::Status st;
    if (scenes.size() < 2 || (r < 0.05 && scenes.size() < 12)) {
      const std::string id = "s" + std::to_string(round) + "-" + std::to_string(counter);
      v1::CreateSceneRequest req;
      req.set_scene_id(id);
      req.set_request_id(rid());
      v1::SceneSummary resp;
      m->uncertain = Model::Op::kCreate;
      m->u_scene = id;
      st = stub.CreateScene(Deadline().get(), req, &resp);
      if (st.ok()) m->scenes[id];
    } else if (r >= 0.05 && r < 0.08 && scenes.size() > 2) {
      const std::string id = scenes[rng() % scenes.size()];
      v1::DeleteSceneRequest req;
      req.set_scene_id(id);
      req.set_request_id(rid());
      v1::DeleteSceneResponse resp;
      m->uncertain = Model::Op::kDelete;
      m->u_scene = id;
      st = stub.DeleteScene(Deadline().get(), req, &resp);
      if (st.ok()) m->scenes.erase(id);
    } else if (r < 0.35 || movable.empty()) {
      const std::string scene = scenes[rng() % scenes.size()];
      const std::string id = "b" + std::to_string(round) + "-" + std::to_string(counter);
      const bool mesh = u(rng) < 0.3;
      BodyModel b;
      b.movable = u(rng) < 0.7;
      b.label = mesh ? "octa" : "box";
      b.triangles = mesh ? 8 : 12;
      const double x = round + 1e-4 * counter;  // unique in the test
      v1::AddBodyRequest head = ShapeHeader(scene, "box", id, MakePose(x, 0, 0), b.movable);
      head.mutable_header()->mutable_spec()->set_label(b.label);
      head.mutable_header()->set_request_id(rid());
      std::vector<v1::AddBodyRequest> parts;
      if (mesh) {
        head.mutable_header()->set_format(v1::MESH_FORMAT_OBJ);
        head.mutable_header()->set_total_bytes(mesh_bytes.size());
        parts.push_back(head);
        for (std::size_t off = 0; off < mesh_bytes.size(); off += 100) {
          v1::AddBodyRequest c;
          c.set_chunk(mesh_bytes.substr(off, 100));
          parts.push_back(c);
        }
      } else {
        parts.push_back(head);
      }
      b.poses.push_back({x, t_sent, Clock::time_point::max()});
      m->uncertain = Model::Op::kAdd;
      m->u_scene = scene;
      m->u_body = id;
      m->u_added = b;
      v1::Body out;
      auto ctx = Deadline();
      auto w = stub.AddBody(ctx.get(), &out);
      for (const auto& p : parts) {
        if (!w->Write(p)) break;
      }
      w->WritesDone();
      st = w->Finish();
      if (st.ok()) {
        b.poses.back().acked = Clock::now();
        m->scenes[scene].bodies[id] = b;
      }
    } else if (r < 0.92) {
      const auto [scene, id] = movable[rng() % movable.size()];
      const double x = round + 1e-4 * counter;  // unique in the test
      v1::MoveBodyRequest req;
      req.set_scene_id(scene);
      req.set_body_id(id);
      *req.mutable_pose() = MakePose(x, 0.5, 0);
      req.set_request_id(rid());
      v1::MoveBodyResponse resp;
      m->uncertain = Model::Op::kMove;
      m->u_scene = scene;
      m->u_body = id;
      m->u_move = PoseEvent{x, t_sent, Clock::time_point::max()};
      st = stub.MoveBody(Deadline().get(), req, &resp);
      if (st.ok()) m->scenes[scene].bodies[id].poses.push_back({x, t_sent, Clock::now()});
    } else {
      const auto [scene, id] = bodies[rng() % bodies.size()];
      v1::RemoveBodyRequest req;
      req.set_scene_id(scene);
      req.set_body_id(id);
      req.set_request_id(rid());
      v1::RemoveBodyResponse resp;
      m->uncertain = Model::Op::kRemove;
      m->u_scene = scene;
      m->u_body = id;
      st = stub.RemoveBody(Deadline().get(), req, &resp);
      if (st.ok()) m->scenes[scene].bodies.erase(id);
    }
    if (!st.ok()) {  // killed: this one's outcome is unknown
      report();
      return st;
    }
    const char* names[] = {"", "create", "delete", "add", "move", "remove"};
    Tally& t = tally[names[static_cast<int>(m->uncertain)]];
    ++t.n;
    t.ms += std::chrono::duration<double, std::milli>(Clock::now() - t_sent).count();
    m->uncertain = Model::Op::kNone;
    m->u_move.reset();
  }
}

/// The server's scenes: id -> body id -> Body.
std::map<std::string, std::map<std::string, v1::Body>> Fetch(v1::SceneService::Stub& stub) {
  std::map<std::string, std::map<std::string, v1::Body>> out;
  v1::ListScenesResponse list;
  EXPECT_TRUE(stub.ListScenes(Deadline().get(), {}, &list).ok());
  for (const auto& s : list.scenes()) {
    v1::GetSceneRequest req;
    req.set_scene_id(s.scene_id());
    v1::Scene sc;
    EXPECT_TRUE(stub.GetScene(Deadline().get(), req, &sc).ok());
    auto& bodies = out[s.scene_id()];
    for (const auto& b : sc.bodies()) bodies[b.body_id()] = b;
  }
  return out;
}

std::string IntegrityCheck(const fs::path& db) {
  sqlite3* h = nullptr;
  if (sqlite3_open_v2(db.c_str(), &h, SQLITE_OPEN_READWRITE, nullptr) != SQLITE_OK) {
    sqlite3_close(h);
    return "cannot open";
  }
  sqlite3_stmt* st = nullptr;
  std::string out;
  if (sqlite3_prepare_v2(h, "PRAGMA integrity_check", -1, &st, nullptr) == SQLITE_OK) {
    while (sqlite3_step(st) == SQLITE_ROW) {
      out += reinterpret_cast<const char*>(sqlite3_column_text(st, 0));
    }
  } else {
    out = sqlite3_errmsg(h);
  }
  sqlite3_finalize(st);
  sqlite3_close(h);
  return out;
}

/// Every pose x the body may hold after a kill at `killed`: the last
/// acknowledged one, any it held within the 100 ms before the kill, and the
/// one of the move in flight.
std::vector<double> AllowedPoses(const BodyModel& b, const std::optional<PoseEvent>& in_flight,
                                 Clock::time_point killed) {
  std::vector<double> out;
  const auto window = killed - std::chrono::milliseconds(100);
  for (std::size_t i = 0; i < b.poses.size(); ++i) {
    const bool last = i + 1 == b.poses.size();
    // Held until the next move was applied, which is no later than its answer.
    if (last || b.poses[i + 1].acked >= window) out.push_back(b.poses[i].x);
  }
  if (in_flight) out.push_back(in_flight->x);
  return out;
}

TEST(Durability, KillNineAtRandomMomentsLosesNothingAcknowledged) {
  const int rounds = TestCount(3);
  const std::uint64_t seed = TestSeed(20261203);
  std::mt19937_64 rng(seed);
  const fs::path dir =
      fs::temp_directory_path() / ("hapticpd_durability_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const fs::path state = dir / "state";
  std::string mesh_bytes = ReadAll(WriteMeshFile(dir));
  Model model;
  model.scenes["default"];
  for (int round = 0; round < rounds; ++round) {
    SCOPED_TRACE("round " + std::to_string(round) + " of seed " + std::to_string(seed));
    Clock::time_point killed;
    {
      Serve srv(state, dir / ("serve-" + std::to_string(round) + "a.log"));
      const std::string addr = srv.WaitAddress();
      ASSERT_FALSE(addr.empty());
      auto stub =
          v1::SceneService::NewStub(grpc::CreateChannel(addr, grpc::InsecureChannelCredentials()));
      // The kill lands anywhere in 50-600 ms of mutations.
      const auto delay = std::chrono::milliseconds(50 + static_cast<int>(rng() % 550));
      std::atomic<bool> killing{false};
      std::thread killer([&] {
        std::this_thread::sleep_for(delay);
        killed = Clock::now();
        killing = true;
        srv.Kill();
      });
      std::mt19937_64 drive_rng(rng());
      const grpc::Status st = Drive(*stub, drive_rng, mesh_bytes, &model, round);
      const bool early = !killing.load();
      killer.join();
      ASSERT_FALSE(early) << "a mutation failed before the kill: " << st.error_code() << " "
                          << st.error_message();
    }
    Serve srv(state, dir / ("serve-" + std::to_string(round) + "b.log"));
    const std::string addr = srv.WaitAddress();
    ASSERT_FALSE(addr.empty());
    std::map<std::string, std::map<std::string, v1::Body>> got;
    {
      // Closed before the SIGTERM below: an open connection holds shutdown
      // for its grace period.
      auto stub =
          v1::SceneService::NewStub(grpc::CreateChannel(addr, grpc::InsecureChannelCredentials()));
      got = Fetch(*stub);
    }
    const auto u = model.uncertain;
    // Scenes.
    for (const auto& [id, s] : model.scenes) {
      const bool may_be_gone = u == Model::Op::kDelete && model.u_scene == id;
      EXPECT_TRUE(got.count(id) || may_be_gone) << "acknowledged scene '" << id << "' is lost";
    }
    for (const auto& [id, bodies] : got) {
      const bool may_exist = u == Model::Op::kCreate && model.u_scene == id;
      EXPECT_TRUE(model.scenes.count(id) || may_exist)
          << "scene '" << id << "' was never acknowledged";
    }
    // Bodies, their attributes and poses.
    for (const auto& [sid, s] : model.scenes) {
      if (!got.count(sid)) continue;
      const auto& bodies = got[sid];
      for (const auto& [bid, b] : s.bodies) {
        const bool may_be_gone =
            u == Model::Op::kRemove && model.u_scene == sid && model.u_body == bid;
        const auto it = bodies.find(bid);
        if (it == bodies.end()) {
          EXPECT_TRUE(may_be_gone)
              << "acknowledged body '" << bid << "' of '" << sid << "' is lost";
          continue;
        }
        EXPECT_EQ(it->second.movable(), b.movable) << bid;
        EXPECT_EQ(it->second.label(), b.label) << bid;
        EXPECT_EQ(it->second.mesh_info().triangles(), b.triangles) << bid;
        const bool moving = u == Model::Op::kMove && model.u_scene == sid && model.u_body == bid;
        const auto allowed = AllowedPoses(b, moving ? model.u_move : std::nullopt, killed);
        const double x = it->second.pose().position().x();
        bool ok = false;
        for (double a : allowed) ok = ok || a == x;
        EXPECT_TRUE(ok) << "body '" << bid << "' of '" << sid << "' restored at x = " << x
                        << ", not a pose it held within 100 ms of the kill (last acknowledged x = "
                        << b.poses.back().x << ")";
      }
      for (const auto& [bid, b] : bodies) {
        const bool may_exist = u == Model::Op::kAdd && model.u_scene == sid && model.u_body == bid;
        EXPECT_TRUE(s.bodies.count(bid) || may_exist)
            << "body '" << bid << "' was never acknowledged";
      }
    }
    // Take the server's state as the model for the next round (this
    // resolves the uncertain mutation), with each restored pose as held now.
    Model next;
    const auto now = Clock::now();
    for (const auto& [sid, bodies] : got) {
      auto& sm = next.scenes[sid];
      for (const auto& [bid, b] : bodies) {
        BodyModel bm;
        bm.movable = b.movable();
        bm.label = b.label();
        bm.triangles = b.mesh_info().triangles();
        bm.poses.push_back({b.pose().position().x(), now, now});
        sm.bodies[bid] = bm;
      }
    }
    model = next;
    EXPECT_EQ(srv.Term(), 0);
    EXPECT_EQ(IntegrityCheck(state / "scenes.db"), "ok");
    if (::testing::Test::HasFailure()) break;
  }
  std::error_code ec;
  fs::remove_all(dir, ec);
}

}  // namespace
}  // namespace hapticpd::testing::durability_tests
