// The state directory (server/store.h), in process with a temporary folder:
// what a restart serves, the schema version, start-up refusals (a corrupt
// file, a foreign SQLite database, an unknown schema version, a directory
// locked by another server) that leave the file untouched, and SQLite errors
// (an injected commit failure, a full database) that fail the mutation with
// nothing changed while the server keeps serving. The "State directory"
// table of tests/README.md is printed from the cases here.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>

#include "server/store.h"
#include "tests/readme_table.h"
#include "tests/server/server_harness.h"
#include "tests/test_util.h"

namespace hapticpd::testing::store_tests {
namespace {

namespace fs = std::filesystem;

class TempDir : public ScopedTempDir {
 public:
  TempDir() : ScopedTempDir("store") {}
  fs::path db() const { return path() / "scenes.db"; }
};

std::string Slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

server::ServerOptions StateOptions(const fs::path& dir) {
  server::ServerOptions o;
  o.listen = "";  // in-process only: no port shared with tests running beside this one
  o.state_dir = dir.string();
  return o;
}

/// Start()'s error for a server on `dir`, or "" when it started.
std::string StartError(const server::ServerOptions& o) {
  server::HapticServer srv(o);
  try {
    srv.Start();
  } catch (const std::exception& e) {
    return e.what();
  }
  srv.Shutdown();
  return "";
}

/// Runs SQL on a database file with the SQLite C API.
void Sql(const fs::path& db, const std::string& sql) {
  sqlite3* h = nullptr;
  ASSERT_EQ(sqlite3_open(db.c_str(), &h), SQLITE_OK);
  char* err = nullptr;
  const int rc = sqlite3_exec(h, sql.c_str(), nullptr, nullptr, &err);
  EXPECT_EQ(rc, SQLITE_OK) << (err ? err : "");
  sqlite3_free(err);
  sqlite3_close(h);
}

std::int64_t SqlInt(const fs::path& db, const std::string& sql) {
  sqlite3* h = nullptr;
  EXPECT_EQ(sqlite3_open_v2(db.c_str(), &h, SQLITE_OPEN_READONLY, nullptr), SQLITE_OK);
  sqlite3_stmt* st = nullptr;
  std::int64_t v = -1;
  if (sqlite3_prepare_v2(h, sql.c_str(), -1, &st, nullptr) == SQLITE_OK &&
      sqlite3_step(st) == SQLITE_ROW) {
    v = sqlite3_column_int64(st, 0);
  }
  sqlite3_finalize(st);
  sqlite3_close(h);
  return v;
}

grpc::Status CreateScene(v1::SceneService::Stub& stub, const std::string& id,
                         v1::SceneConfig config = {}) {
  v1::CreateSceneRequest req;
  req.set_scene_id(id);
  req.set_description("about " + id);
  *req.mutable_config() = config;
  v1::SceneSummary resp;
  return stub.CreateScene(Ctx().get(), req, &resp);
}

grpc::Status AddShape(v1::SceneService::Stub& stub, const std::string& scene,
                      const std::string& shape, const std::string& id, bool movable = false,
                      v1::Body* out = nullptr) {
  v1::Body body;
  return AddBodyRaw(stub, {ShapeHeader(scene, shape, id, MakePose(0.1, 0.2, 0.3), movable)},
                    out ? out : &body);
}

grpc::Status Move(v1::SceneService::Stub& stub, const std::string& scene, const std::string& id,
                  const v1::Pose& pose) {
  v1::MoveBodyRequest req;
  req.set_scene_id(scene);
  req.set_body_id(id);
  *req.mutable_pose() = pose;
  req.mutable_velocity()->mutable_linear()->set_x(0.25);
  req.mutable_velocity()->mutable_angular()->set_z(-1.5);
  v1::MoveBodyResponse resp;
  return stub.MoveBody(Ctx().get(), req, &resp);
}

grpc::Status Remove(v1::SceneService::Stub& stub, const std::string& scene, const std::string& id) {
  v1::RemoveBodyRequest req;
  req.set_scene_id(scene);
  req.set_body_id(id);
  v1::RemoveBodyResponse resp;
  return stub.RemoveBody(Ctx().get(), req, &resp);
}

grpc::Status DeleteScene(v1::SceneService::Stub& stub, const std::string& id) {
  v1::DeleteSceneRequest req;
  req.set_scene_id(id);
  v1::DeleteSceneResponse resp;
  return stub.DeleteScene(Ctx().get(), req, &resp);
}

/// Every scene with its bodies and meshes, revisions cleared: what a
/// restart must reproduce.
std::string Everything(v1::SceneService::Stub& stub) {
  v1::ListScenesResponse list;
  EXPECT_TRUE(stub.ListScenes(Ctx().get(), {}, &list).ok());
  std::string out;
  for (const auto& sum : list.scenes()) {
    v1::GetSceneRequest req;
    req.set_scene_id(sum.scene_id());
    req.set_include_meshes(true);
    v1::Scene sc;
    EXPECT_TRUE(stub.GetScene(Ctx().get(), req, &sc).ok());
    sc.clear_revision();
    out += sc.DebugString();
  }
  return out;
}

/// Everything a server started afresh on the store in `dir` serves.
std::string EverythingAfterRestart(const fs::path& dir) {
  ServerHarness h(Transport::kInProcess, StateOptions(dir));
  return Everything(*h.Scenes());
}

TEST(Store, RestartServesEverythingAcknowledged) {
  TempDir dir;
  std::string before;
  {
    ServerHarness h(Transport::kInProcess, StateOptions(dir.path()));
    auto stub = h.Scenes();
    v1::SceneConfig cfg;
    cfg.set_declared(true);
    cfg.add_effects(v1::EFFECT_CONTACT);
    cfg.add_effects(v1::EFFECT_FRICTION);
    cfg.set_pd_mode(v1::PD_MODE_PDG);
    cfg.mutable_gravity()->set_z(-3);
    cfg.set_probe_shape("sphere:0.01");
    ASSERT_TRUE(CreateScene(*stub, "lab", cfg).ok());
    ASSERT_TRUE(AddShape(*stub, "lab", "box:0.1,0.2,0.3", "crate").ok());
    ASSERT_TRUE(AddShape(*stub, "lab", "sphere", "", true).ok());  // body-1
    ASSERT_TRUE(AddShape(*stub, "lab", "stick", "", true).ok());   // body-2
    // An inline mesh with full double coordinates and a material.
    v1::AddBodyRequest inl;
    auto* hd = inl.mutable_header();
    hd->set_scene_id("default");
    hd->mutable_spec()->set_body_id("tet");
    hd->mutable_spec()->set_label("a tetrahedron");
    *hd->mutable_spec()->mutable_pose() =
        MakePose(1.0 / 3, 0, 0, std::sqrt(0.5), 0, std::sqrt(0.5), 0);
    auto* m = hd->mutable_spec()->mutable_material();
    m->set_stiffness(1234.5);
    m->set_rotational_stiffness(0.7);
    m->set_damping(3.25);
    m->set_static_friction(0.6);
    m->set_dynamic_friction(0.4);
    for (double v : {0.0, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0, 0.1 / 3, 0.0, 0.0, 0.0, 0.1})
      hd->mutable_inline_mesh()->add_vertices(v);
    for (unsigned t : {0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3})
      hd->mutable_inline_mesh()->add_triangles(t);
    v1::Body tet;
    ASSERT_TRUE(AddBodyRaw(*stub, {inl}, &tet).ok());
    ASSERT_TRUE(Move(*stub, "lab", "body-2", MakePose(0.5, -0.25, 0.125, 0, 1, 0, 0)).ok());
    ASSERT_TRUE(Remove(*stub, "lab", "body-1").ok());
    before = Everything(*stub);
  }  // a clean shutdown writes the queued poses
  ServerHarness h(Transport::kInProcess, StateOptions(dir.path()));
  auto stub = h.Scenes();
  EXPECT_EQ(Everything(*stub), before);
  // Assigned ids go on from where they were, never handing out body-1 again.
  v1::Body next;
  ASSERT_TRUE(AddShape(*stub, "lab", "box", "", false, &next).ok());
  EXPECT_EQ(next.body_id(), "body-3");
}

TEST(Store, SchemaVersionAndApplicationIdAreStored) {
  TempDir dir;
  { ServerHarness h(Transport::kInProcess, StateOptions(dir.path())); }
  EXPECT_EQ(SqlInt(dir.db(), "PRAGMA user_version"), server::SceneStore::kSchemaVersion);
  EXPECT_EQ(SqlInt(dir.db(), "PRAGMA application_id"), server::SceneStore::kApplicationId);
  EXPECT_EQ(SqlInt(dir.db(), "SELECT count(*) FROM scenes WHERE id = 'default'"), 1);
}

TEST(Store, CorruptFileStopsTheStartAndIsLeftAsItWas) {
  TempDir dir;
  fs::create_directories(dir.path());
  std::string garbage(8192, '\0');
  for (std::size_t i = 0; i < garbage.size(); ++i) garbage[i] = static_cast<char>(i * 7919 % 251);
  std::ofstream(dir.db(), std::ios::binary) << garbage;
  const std::string err = StartError(StateOptions(dir.path()));
  EXPECT_EQ(err, dir.db().string() +
                     ": not a hapticpd state database (file is not a database); move the file "
                     "away or give another --state DIR");
  EXPECT_EQ(Slurp(dir.db()), garbage);
}

TEST(Store, DamagedPageStopsTheStart) {
  TempDir dir;
  {
    ServerHarness h(Transport::kInProcess, StateOptions(dir.path()));
    auto stub = h.Scenes();
    for (int i = 0; i < 4; ++i) ASSERT_TRUE(AddShape(*stub, "default", "sphere:0.05,4", "").ok());
  }
  Sql(dir.db(), "PRAGMA wal_checkpoint(TRUNCATE)");
  std::string bytes = Slurp(dir.db());
  ASSERT_GT(bytes.size(), 5u * 4096);
  // Overwrite the middle of the file (b-tree pages) with garbage.
  for (std::size_t i = 2 * 4096; i < 4 * 4096; ++i) bytes[i] = static_cast<char>(0xA5);
  std::ofstream(dir.db(), std::ios::binary | std::ios::trunc) << bytes;
  const std::string err = StartError(StateOptions(dir.path()));
  EXPECT_NE(err.find(dir.db().string() + ": the database is corrupt ("), std::string::npos) << err;
  EXPECT_EQ(Slurp(dir.db()), bytes);
}

TEST(Store, ForeignSqliteDatabaseStopsTheStartAndIsLeftAsItWas) {
  TempDir dir;
  fs::create_directories(dir.path());
  Sql(dir.db(), "CREATE TABLE users(name TEXT); INSERT INTO users VALUES('ada');");
  const std::string bytes = Slurp(dir.db());
  const std::string err = StartError(StateOptions(dir.path()));
  EXPECT_EQ(err, dir.db().string() +
                     ": not a hapticpd state database (an SQLite database of another "
                     "application, tables: users); move the file away or give another --state "
                     "DIR");
  EXPECT_EQ(Slurp(dir.db()), bytes);
}

TEST(Store, UnknownSchemaVersionStopsTheStart) {
  TempDir dir;
  { ServerHarness h(Transport::kInProcess, StateOptions(dir.path())); }
  Sql(dir.db(), "PRAGMA user_version = 99");
  const std::string err = StartError(StateOptions(dir.path()));
  EXPECT_EQ(err, dir.db().string() +
                     ": schema version 99, this hapticpd reads version 1 only; run the hapticpd "
                     "that wrote it, or give another --state DIR");
  EXPECT_EQ(SqlInt(dir.db(), "PRAGMA user_version"), 99);
}

TEST(Store, LockedStateDirectoryStopsASecondServer) {
  TempDir dir;
  auto first = std::make_unique<ServerHarness>(Transport::kInProcess, StateOptions(dir.path()));
  EXPECT_EQ(StartError(StateOptions(dir.path())),
            dir.path().string() +
                ": the state directory is in use by another hapticpd server (its lock file is "
                "held); give each server its own --state DIR");
  first.reset();  // shut down: the lock is released
  EXPECT_EQ(StartError(StateOptions(dir.path())), "");
}

/// A server whose commits fail with `code` while `*fail` is set.
server::ServerOptions FailingOptions(const fs::path& dir, std::shared_ptr<std::atomic<int>> fail) {
  server::ServerOptions o = StateOptions(dir);
  o.store_before_commit = [fail] { return fail->load(); };
  return o;
}

TEST(Store, FailedCommitChangesNothingAndTheServerKeepsServing) {
  TempDir dir;
  auto fail = std::make_shared<std::atomic<int>>(SQLITE_OK);
  std::string acknowledged;
  {
    ServerHarness h(Transport::kInProcess, FailingOptions(dir.path(), fail));
    auto stub = h.Scenes();
    ASSERT_TRUE(AddShape(*stub, "default", "box", "keep", true).ok());
    const std::string before = Everything(*stub);
    fail->store(SQLITE_IOERR);
    const std::string msg =
        "state store: disk I/O error (" + dir.db().string() + "); nothing was changed";
    for (const grpc::Status& s :
         {CreateScene(*stub, "lab"), AddShape(*stub, "default", "sphere", "new"),
          AddShape(*stub, "default", "sphere", ""), Remove(*stub, "default", "keep"),
          DeleteScene(*stub, "default")}) {
      EXPECT_EQ(s.error_code(), grpc::StatusCode::UNAVAILABLE);
      EXPECT_EQ(s.error_message(), msg);
    }
    EXPECT_EQ(Everything(*stub), before) << "a failed commit changed the scenes in memory";
    // Reads keep working; once the store writes again, so do mutations.
    fail->store(SQLITE_OK);
    ASSERT_TRUE(AddShape(*stub, "default", "sphere", "").ok());
    v1::Body b;
    ASSERT_TRUE(AddShape(*stub, "default", "stick", "", false, &b).ok());
    EXPECT_EQ(b.body_id(), "body-2") << "a failed AddBody used up an assigned id";
    ASSERT_TRUE(CreateScene(*stub, "lab").ok());
    acknowledged = Everything(*stub);
  }
  EXPECT_EQ(EverythingAfterRestart(dir.path()), acknowledged);
}

TEST(Store, FailedPoseBatchIsWrittenLater) {
  TempDir dir;
  auto fail = std::make_shared<std::atomic<int>>(SQLITE_OK);
  std::string acknowledged;
  {
    ServerHarness h(Transport::kInProcess, FailingOptions(dir.path(), fail));
    auto stub = h.Scenes();
    ASSERT_TRUE(AddShape(*stub, "default", "box", "m", true).ok());
    {
      const ScopedExpectLogs expect;  // "cannot write 1 body poses"
      fail->store(SQLITE_FULL);
      ASSERT_TRUE(Move(*stub, "default", "m", MakePose(2, 3, 4)).ok());
      std::this_thread::sleep_for(server::SceneStore::kPoseFlushInterval * 3);
      fail->store(SQLITE_OK);
    }
    acknowledged = Everything(*stub);
  }
  EXPECT_EQ(EverythingAfterRestart(dir.path()), acknowledged);
}

TEST(Store, FullDatabaseFailsTheMutationAndKeepsServing) {
  TempDir dir;
  server::ServerOptions o = StateOptions(dir.path());
  o.state_max_bytes = 160 * 1024;
  ServerHarness h(Transport::kInProcess, o);
  auto stub = h.Scenes();
  ASSERT_TRUE(AddShape(*stub, "default", "box", "small").ok());
  const std::string before = Everything(*stub);
  // About 250 KB of vertices and 250 KB of triangles: over the cap.
  const grpc::Status s = AddShape(*stub, "default", "sphere:0.05,5", "big");
  EXPECT_EQ(s.error_code(), grpc::StatusCode::UNAVAILABLE);
  EXPECT_EQ(s.error_message(),
            "state store: body 'big' of scene 'default': database or disk is "
            "full (" +
                dir.db().string() + "); nothing was changed");
  EXPECT_EQ(Everything(*stub), before);
  EXPECT_TRUE(AddShape(*stub, "default", "box", "another").ok());
}

TEST(Store, TheStoreWinsOverSceneFilesAndDefaultComesOnlyIntoAnEmptyStore) {
  TempDir dir;
  fs::create_directories(dir.path());
  const fs::path file = dir.path() / "lab.json";
  std::ofstream(file) << R"({"scene": "lab", "bodies": [{"id": "from-file", "shape": "box"}]})";
  server::ServerOptions o = StateOptions(dir.path() / "state");
  o.scene_files = {file.string()};
  {
    ServerHarness h(Transport::kInProcess, o);
    auto stub = h.Scenes();
    ASSERT_TRUE(Remove(*stub, "lab", "from-file").ok());
    ASSERT_TRUE(AddShape(*stub, "lab", "sphere", "added").ok());
  }
  {
    // The file is not loaded again; the store's "lab" is served.
    ServerHarness h(Transport::kInProcess, o);
    auto stub = h.Scenes();
    v1::GetSceneRequest req;
    req.set_scene_id("lab");
    v1::Scene sc;
    ASSERT_TRUE(stub->GetScene(Ctx().get(), req, &sc).ok());
    ASSERT_EQ(sc.bodies_size(), 1);
    EXPECT_EQ(sc.bodies(0).body_id(), "added");
    v1::ListScenesResponse list;
    ASSERT_TRUE(stub->ListScenes(Ctx().get(), {}, &list).ok());
    EXPECT_EQ(list.scenes_size(), 1) << "no 'default' next to a scene file";
  }
  o.scene_files.clear();
  {
    // Without files, "default" only comes into an empty store.
    ServerHarness h(Transport::kInProcess, o);
    auto stub = h.Scenes();
    v1::ListScenesResponse list;
    ASSERT_TRUE(stub->ListScenes(Ctx().get(), {}, &list).ok());
    ASSERT_EQ(list.scenes_size(), 1);
    EXPECT_EQ(list.scenes(0).scene_id(), "lab");
    ASSERT_TRUE(DeleteScene(*stub, "lab").ok());
  }
  ServerHarness h(Transport::kInProcess, o);
  auto stub = h.Scenes();
  v1::ListScenesResponse list;
  ASSERT_TRUE(stub->ListScenes(Ctx().get(), {}, &list).ok());
  ASSERT_EQ(list.scenes_size(), 1);
  EXPECT_EQ(list.scenes(0).scene_id(), "default");
}

// tests/README.md "Bad input", "State directory": every row is a case
// here, the message a start-up gets with DIR for the state directory ("…"
// stands for what the damage decides). HAPTICPD_PRINT_TABLE=1 prints the
// rows (tests/update_tables.py).
TEST(Store, StateDirectoryTable) {
  struct Case {
    std::string what;  // the bad input (README markdown)
    std::string message;
  };
  const std::vector<Case> cases = {
      {"a corrupt file (garbage bytes) in place of the database",
       "DIR/scenes.db: not a hapticpd state database (file is not a database); move the file "
       "away or give another --state DIR"},
      {"a foreign SQLite database (another application's tables)",
       "DIR/scenes.db: not a hapticpd state database (an SQLite database of another "
       "application, tables: users); move the file away or give another --state DIR"},
      {"a store of an unknown schema version",
       "DIR/scenes.db: schema version 2, this hapticpd reads version 1 only; run the hapticpd "
       "that wrote it, or give another --state DIR"},
      {"a state directory another server holds (its `flock`)",
       "DIR: the state directory is in use by another hapticpd server (its lock file is held); "
       "give each server its own --state DIR"},
      {"a store with damaged pages (`PRAGMA quick_check` fails)",
       "DIR/scenes.db: the database is corrupt (…); move the file away or give another --state "
       "DIR"},
  };

  TempDir corrupt, foreign, version, locked, damaged;
  auto with_dir = [](const std::string& msg, const fs::path& d) {
    std::string m = msg;
    for (auto p = m.find("DIR/"); p != std::string::npos; p = m.find("DIR/", p)) {
      m.replace(p, 3, d.string());
    }
    if (m.rfind("DIR:", 0) == 0) m.replace(0, 3, d.string());
    return m;
  };
  fs::create_directories(corrupt.path());
  std::ofstream(corrupt.db(), std::ios::binary) << std::string(4096, 'x');
  fs::create_directories(foreign.path());
  Sql(foreign.db(), "CREATE TABLE users(name TEXT)");
  { ServerHarness h(Transport::kInProcess, StateOptions(version.path())); }
  Sql(version.db(), "PRAGMA user_version = 2");
  ServerHarness holder(Transport::kInProcess, StateOptions(locked.path()));
  {
    ServerHarness h(Transport::kInProcess, StateOptions(damaged.path()));
    auto stub = h.Scenes();
    for (int i = 0; i < 4; ++i) ASSERT_TRUE(AddShape(*stub, "default", "sphere:0.05,4", "").ok());
  }
  Sql(damaged.db(), "PRAGMA wal_checkpoint(TRUNCATE)");
  {
    std::string bytes = Slurp(damaged.db());
    for (std::size_t i = 2 * 4096; i < 4 * 4096; ++i) bytes[i] = static_cast<char>(0xA5);
    std::ofstream(damaged.db(), std::ios::binary | std::ios::trunc) << bytes;
  }
  const std::vector<const TempDir*> dirs = {&corrupt, &foreign, &version, &locked, &damaged};
  ASSERT_EQ(dirs.size(), cases.size());
  for (std::size_t i = 0; i < cases.size(); ++i) {
    SCOPED_TRACE(cases[i].what);
    const std::string got = StartError(StateOptions(dirs[i]->path()));
    EXPECT_TRUE(MessageMatches(got, with_dir(cases[i].message, dirs[i]->path()))) << got;
    PrintTableRow({cases[i].what}, cases[i].message);
  }
}

}  // namespace
}  // namespace hapticpd::testing::store_tests
