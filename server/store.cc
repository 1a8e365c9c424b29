#include "server/store.h"

#include <fcntl.h>
#include <openssl/sha.h>
#include <sqlite3.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

#include "server/core.h"

namespace hapticpd::server {

using internal::Log;

namespace {

namespace fs = std::filesystem;

constexpr const char* kSchema = R"sql(
CREATE TABLE scenes(
  id TEXT PRIMARY KEY,
  description TEXT NOT NULL,
  config BLOB NOT NULL,            -- hapticpd.v1.SceneConfig
  next_body_number INTEGER NOT NULL
);
CREATE TABLE bodies(
  seq INTEGER PRIMARY KEY AUTOINCREMENT,   -- the order bodies were added
  scene_id TEXT NOT NULL,
  id TEXT NOT NULL,
  label TEXT NOT NULL,
  movable INTEGER NOT NULL,
  pose BLOB NOT NULL,              -- 12 doubles: R row-major, then t
  velocity BLOB NOT NULL,          -- 6 doubles: linear, angular
  stiffness REAL NOT NULL,
  rotational_stiffness REAL NOT NULL,
  damping REAL NOT NULL,
  static_friction REAL NOT NULL,
  dynamic_friction REAL NOT NULL,
  vertices BLOB NOT NULL,          -- 3 doubles per vertex
  triangles BLOB NOT NULL,         -- 3 int32 per triangle
  UNIQUE(scene_id, id)
);
CREATE TABLE requests(
  client TEXT NOT NULL,            -- digest of the client's token (RequestLog::ClientHash)
  request_id TEXT NOT NULL,
  method TEXT NOT NULL,
  code INTEGER NOT NULL,
  message TEXT NOT NULL,
  response BLOB NOT NULL,
  created_at INTEGER NOT NULL,     -- Unix seconds
  PRIMARY KEY(client, request_id)
);
CREATE INDEX requests_by_age ON requests(created_at);
)sql";

/// A prepared statement, finalized when it goes out of scope.
class Stmt {
 public:
  explicit Stmt(sqlite3_stmt* s) : s_(s) {}
  ~Stmt() { sqlite3_finalize(s_); }
  Stmt(const Stmt&) = delete;
  Stmt& operator=(const Stmt&) = delete;
  sqlite3_stmt* get() const { return s_; }
  void Text(int i, const std::string& v) {
    sqlite3_bind_text(s_, i, v.data(), static_cast<int>(v.size()), SQLITE_TRANSIENT);
  }
  void Blob(int i, const void* p, std::size_t n) {
    // A zero-length blob still binds as a blob (not NULL): NOT NULL columns.
    static const char kEmpty = 0;
    sqlite3_bind_blob64(s_, i, n ? p : &kEmpty, n, SQLITE_TRANSIENT);
  }
  void Blob(int i, const std::string& v) { Blob(i, v.data(), v.size()); }
  void Int(int i, std::int64_t v) { sqlite3_bind_int64(s_, i, v); }
  void Real(int i, double v) { sqlite3_bind_double(s_, i, v); }
  std::string ColText(int i) const {
    const auto* p = reinterpret_cast<const char*>(sqlite3_column_text(s_, i));
    return p ? std::string(p, static_cast<std::size_t>(sqlite3_column_bytes(s_, i))) : "";
  }
  std::string ColBlob(int i) const {
    const auto* p = static_cast<const char*>(sqlite3_column_blob(s_, i));
    return p ? std::string(p, static_cast<std::size_t>(sqlite3_column_bytes(s_, i))) : "";
  }

 private:
  sqlite3_stmt* s_;
};

std::string PoseBlob(const Pose& X) {
  double d[12];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) d[r * 3 + c] = X.R(r, c);
  for (int i = 0; i < 3; ++i) d[9 + i] = X.t[i];
  return std::string(reinterpret_cast<const char*>(d), sizeof d);
}

std::string TwistBlob(const Vec3& v, const Vec3& w) {
  const double d[6] = {v.x(), v.y(), v.z(), w.x(), w.y(), w.z()};
  return std::string(reinterpret_cast<const char*>(d), sizeof d);
}

}  // namespace

std::int64_t UnixNow() {
  return std::chrono::duration_cast<std::chrono::seconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

// ---------------------------------------------------------------- SceneStore

std::unique_ptr<SceneStore> SceneStore::Open(const fs::path& dir, std::int64_t max_bytes) {
  std::unique_ptr<SceneStore> s(new SceneStore());
  s->dir_ = dir;
  s->db_path_ = dir / "scenes.db";
  std::error_code ec;
  if (!fs::exists(dir, ec)) {
    fs::create_directories(dir, ec);
    if (ec) {
      throw StoreError(dir.string() + ": cannot create the state directory (" + ec.message() + ")");
    }
    fs::permissions(dir, fs::perms::owner_all, fs::perm_options::replace, ec);
  } else if (!fs::is_directory(dir, ec)) {
    throw StoreError(dir.string() + ": the state directory is not a directory");
  }
  const fs::path lock = dir / "lock";
  s->lock_fd_ = ::open(lock.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0600);
  if (s->lock_fd_ < 0) {
    throw StoreError(lock.string() + ": cannot open the lock file (" + std::strerror(errno) + ")");
  }
  if (::flock(s->lock_fd_, LOCK_EX | LOCK_NB) != 0) {
    const int e = errno;
    if (e == EWOULDBLOCK) {
      throw StoreError(dir.string() +
                       ": the state directory is in use by another hapticpd server (its lock "
                       "file is held); give each server its own --state DIR");
    }
    throw StoreError(lock.string() + ": cannot lock (" + std::strerror(e) + ")");
  }
  const bool existed = fs::exists(s->db_path_, ec);
  // SQLITE_OPEN_CREATE only for a new file: an existing one is never replaced.
  const int flags = SQLITE_OPEN_READWRITE | (existed ? 0 : SQLITE_OPEN_CREATE) |
                    SQLITE_OPEN_NOMUTEX | SQLITE_OPEN_EXRESCODE;
  if (sqlite3_open_v2(s->db_path_.c_str(), &s->db_, flags, nullptr) != SQLITE_OK) {
    const std::string msg = s->db_ ? sqlite3_errmsg(s->db_) : "out of memory";
    throw StoreError(s->db_path_.string() + ": cannot open (" + msg + ")");
  }
  s->CheckOrCreateSchema();
  if (max_bytes > 0) {
    const std::string sql =
        "PRAGMA max_page_count = " + std::to_string(std::max<std::int64_t>(1, max_bytes / 4096));
    s->Exec(sql.c_str());
  }
  s->flusher_ = std::thread([p = s.get()] { p->FlushLoop(); });
  return s;
}

SceneStore::~SceneStore() {
  {
    std::lock_guard lock(flush_mu_);
    stopping_ = true;
  }
  flush_cv_.notify_all();
  if (flusher_.joinable()) flusher_.join();
  if (db_) {
    FlushPoses();
    sqlite3_close_v2(db_);
  }
  if (lock_fd_ >= 0) ::close(lock_fd_);  // releases the flock
}

void SceneStore::Fail(const std::string& what) {
  throw StoreError(what + ": " + sqlite3_errmsg(db_));
}

void SceneStore::Exec(const char* sql) {
  char* err = nullptr;
  if (sqlite3_exec(db_, sql, nullptr, nullptr, &err) != SQLITE_OK) {
    const std::string msg = err ? err : sqlite3_errmsg(db_);
    sqlite3_free(err);
    throw StoreError(msg);
  }
}

sqlite3_stmt* SceneStore::Prepare(const char* sql) {
  sqlite3_stmt* st = nullptr;
  if (sqlite3_prepare_v2(db_, sql, -1, &st, nullptr) != SQLITE_OK) {
    throw StoreError(sqlite3_errmsg(db_));
  }
  return st;
}

void SceneStore::CheckOrCreateSchema() {
  const std::string file = db_path_.string();
  const std::string fix = "; move the file away or give another --state DIR";
  auto scalar = [&](const char* sql, std::int64_t* out) {
    sqlite3_stmt* raw = nullptr;
    if (sqlite3_prepare_v2(db_, sql, -1, &raw, nullptr) != SQLITE_OK) return false;
    Stmt owned(raw);
    if (sqlite3_step(raw) != SQLITE_ROW) return false;
    *out = sqlite3_column_int64(raw, 0);
    return true;
  };
  std::int64_t app = 0, version = 0, objects = 0;
  if (!scalar("PRAGMA application_id", &app) || !scalar("PRAGMA user_version", &version) ||
      !scalar("SELECT count(*) FROM sqlite_schema", &objects)) {
    throw StoreError(file + ": not a hapticpd state database (" + sqlite3_errmsg(db_) + ")" + fix);
  }
  if (app == 0 && objects == 0 && version == 0) {
    // A new (empty) database: ours from here on.
    try {
      Exec("PRAGMA journal_mode = WAL");
      Exec("BEGIN IMMEDIATE");
      Exec(kSchema);
      Exec(("PRAGMA application_id = " + std::to_string(kApplicationId)).c_str());
      Exec(("PRAGMA user_version = " + std::to_string(kSchemaVersion)).c_str());
      Exec("COMMIT");
    } catch (const StoreError& e) {
      throw StoreError(file + ": cannot create the database (" + e.what() + ")");
    }
  } else if (app != kApplicationId) {
    std::string tables;
    {
      Stmt st(Prepare("SELECT name FROM sqlite_schema WHERE type = 'table' ORDER BY name LIMIT 4"));
      while (sqlite3_step(st.get()) == SQLITE_ROW) {
        tables += (tables.empty() ? "" : ", ") + st.ColText(0);
      }
    }
    throw StoreError(file + ": not a hapticpd state database (an SQLite database of another " +
                     "application" + (tables.empty() ? "" : ", tables: " + tables) + ")" + fix);
  } else if (version != kSchemaVersion) {
    throw StoreError(file + ": schema version " + std::to_string(version) +
                     ", this hapticpd reads version " + std::to_string(kSchemaVersion) +
                     " only; run the hapticpd that wrote it, or give another --state DIR");
  } else {
    // An existing store of ours: a damaged page stops the start, never a
    // later mutation.
    Stmt st(Prepare("PRAGMA quick_check"));
    std::string result;
    while (sqlite3_step(st.get()) == SQLITE_ROW) {
      if (!result.empty()) result += "; ";
      result += st.ColText(0);
      if (result.size() > 200) break;
    }
    if (result != "ok") {
      throw StoreError(file + ": the database is corrupt (" +
                       (result.empty() ? std::string(sqlite3_errmsg(db_)) : result) + ")" + fix);
    }
    Exec("PRAGMA journal_mode = WAL");
  }
  Exec("PRAGMA synchronous = FULL");
  sqlite3_busy_timeout(db_, 5000);
}

StoredState SceneStore::Load(std::int64_t expired_before_s) {
  PurgeRequests(expired_before_s);
  std::lock_guard lock(db_mu_);
  StoredState out;
  const std::string file = db_path_.string();
  std::map<std::string, std::size_t> index;
  {
    Stmt st(Prepare("SELECT id, description, config, next_body_number FROM scenes ORDER BY id"));
    int rc;
    while ((rc = sqlite3_step(st.get())) == SQLITE_ROW) {
      StoredScene sc;
      sc.id = st.ColText(0);
      sc.description = st.ColText(1);
      if (!sc.config.ParseFromString(st.ColBlob(2))) {
        throw StoreError(file + ": the database is corrupt (scene '" + sc.id +
                         "': unreadable config)");
      }
      sc.next_body_number = static_cast<std::uint64_t>(sqlite3_column_int64(st.get(), 3));
      index[sc.id] = out.scenes.size();
      out.scenes.push_back(std::move(sc));
    }
    if (rc != SQLITE_DONE) Fail(file + ": reading scenes");
  }
  {
    Stmt st(Prepare(
        "SELECT scene_id, id, label, movable, pose, velocity, stiffness, rotational_stiffness, "
        "damping, static_friction, dynamic_friction, vertices, triangles FROM bodies ORDER BY "
        "seq"));
    int rc;
    while ((rc = sqlite3_step(st.get())) == SQLITE_ROW) {
      const std::string scene = st.ColText(0);
      StoredBody b;
      b.id = st.ColText(1);
      auto corrupt = [&](const char* what) {
        return StoreError(file + ": the database is corrupt (body '" + b.id + "' of scene '" +
                          scene + "': " + what + ")");
      };
      const auto it = index.find(scene);
      if (it == index.end()) throw corrupt("no such scene");
      b.label = st.ColText(2);
      b.movable = sqlite3_column_int64(st.get(), 3) != 0;
      const std::string pose = st.ColBlob(4), vel = st.ColBlob(5);
      if (pose.size() != 12 * sizeof(double) || vel.size() != 6 * sizeof(double)) {
        throw corrupt("pose or velocity of the wrong size");
      }
      double p[12], v[6];
      std::memcpy(p, pose.data(), sizeof p);
      std::memcpy(v, vel.data(), sizeof v);
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) b.X_WB.R(r, c) = p[r * 3 + c];
      b.X_WB.t = Vec3(p[9], p[10], p[11]);
      b.v_W = Vec3(v[0], v[1], v[2]);
      b.w_W = Vec3(v[3], v[4], v[5]);
      b.material.stiffness = sqlite3_column_double(st.get(), 6);
      b.material.rotational_stiffness = sqlite3_column_double(st.get(), 7);
      b.material.damping = sqlite3_column_double(st.get(), 8);
      b.material.static_friction = sqlite3_column_double(st.get(), 9);
      b.material.dynamic_friction = sqlite3_column_double(st.get(), 10);
      const std::string verts = st.ColBlob(11), tris = st.ColBlob(12);
      if (verts.size() % (3 * sizeof(double)) != 0 || tris.size() % sizeof(pd::Triangle) != 0) {
        throw corrupt("mesh arrays of the wrong size");
      }
      b.vertices.resize(verts.size() / (3 * sizeof(double)));
      for (std::size_t i = 0; i < b.vertices.size(); ++i) {
        double x[3];
        std::memcpy(x, verts.data() + i * sizeof x, sizeof x);
        b.vertices[i] = Vec3(x[0], x[1], x[2]);
      }
      b.triangles.resize(tris.size() / sizeof(pd::Triangle));
      if (!tris.empty()) std::memcpy(b.triangles.data(), tris.data(), tris.size());
      out.scenes[it->second].bodies.push_back(std::move(b));
    }
    if (rc != SQLITE_DONE) Fail(file + ": reading bodies");
  }
  {
    Stmt st(Prepare(
        "SELECT client, request_id, method, code, message, response, created_at FROM requests"));
    int rc;
    while ((rc = sqlite3_step(st.get())) == SQLITE_ROW) {
      StoredRequest r;
      r.client = st.ColText(0);
      r.request_id = st.ColText(1);
      r.outcome.method = st.ColText(2);
      r.outcome.code = static_cast<int>(sqlite3_column_int64(st.get(), 3));
      r.outcome.message = st.ColText(4);
      r.outcome.response = st.ColBlob(5);
      r.outcome.created_at_s = sqlite3_column_int64(st.get(), 6);
      out.requests.push_back(std::move(r));
    }
    if (rc != SQLITE_DONE) Fail(file + ": reading request ids");
  }
  return out;
}

// One statement with bound values, run to completion (throws on error).
#define HAPTICPD_STORE_RUN(st, what) \
  if (sqlite3_step((st).get()) != SQLITE_DONE) store_->Fail(what)

void SceneStore::Txn::PutScene(const std::string& id, const std::string& description,
                               const v1::SceneConfig& config, std::uint64_t next_body_number) {
  Stmt st(store_->Prepare(
      "INSERT INTO scenes(id, description, config, next_body_number) VALUES(?, ?, ?, ?)"));
  st.Text(1, id);
  st.Text(2, description);
  st.Blob(3, config.SerializeAsString());
  st.Int(4, static_cast<std::int64_t>(next_body_number));
  HAPTICPD_STORE_RUN(st, "scene '" + id + "'");
}

void SceneStore::Txn::SetNextBodyNumber(const std::string& scene, std::uint64_t n) {
  Stmt st(store_->Prepare("UPDATE scenes SET next_body_number = ? WHERE id = ?"));
  st.Int(1, static_cast<std::int64_t>(n));
  st.Text(2, scene);
  HAPTICPD_STORE_RUN(st, "scene '" + scene + "'");
}

void SceneStore::Txn::DeleteScene(const std::string& id) {
  for (const char* sql :
       {"DELETE FROM bodies WHERE scene_id = ?", "DELETE FROM scenes WHERE id = ?"}) {
    Stmt st(store_->Prepare(sql));
    st.Text(1, id);
    HAPTICPD_STORE_RUN(st, "deleting scene '" + id + "'");
  }
  store_->dropped_scenes_.push_back(id);
}

void SceneStore::Txn::PutBody(const std::string& scene, const BodyState& b) {
  Stmt st(store_->Prepare(
      "INSERT INTO bodies(scene_id, id, label, movable, pose, velocity, stiffness, "
      "rotational_stiffness, damping, static_friction, dynamic_friction, vertices, triangles) "
      "VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)"));
  st.Text(1, scene);
  st.Text(2, b.id);
  st.Text(3, b.label);
  st.Int(4, b.movable ? 1 : 0);
  st.Blob(5, PoseBlob(b.X_WB));
  st.Blob(6, TwistBlob(b.v_W, b.w_W));
  st.Real(7, b.material.stiffness);
  st.Real(8, b.material.rotational_stiffness);
  st.Real(9, b.material.damping);
  st.Real(10, b.material.static_friction);
  st.Real(11, b.material.dynamic_friction);
  const pd::Mesh& m = b.model->mesh();
  std::vector<double> v(3 * m.num_vertices());
  for (std::size_t i = 0; i < m.num_vertices(); ++i) {
    for (int k = 0; k < 3; ++k) v[3 * i + k] = m.vertices()[i][k];
  }
  st.Blob(12, v.data(), v.size() * sizeof(double));
  st.Blob(13, m.triangles().data(), m.triangles().size() * sizeof(pd::Triangle));
  HAPTICPD_STORE_RUN(st, "body '" + b.id + "' of scene '" + scene + "'");
}

void SceneStore::Txn::DeleteBody(const std::string& scene, const std::string& id) {
  Stmt st(store_->Prepare("DELETE FROM bodies WHERE scene_id = ? AND id = ?"));
  st.Text(1, scene);
  st.Text(2, id);
  HAPTICPD_STORE_RUN(st, "deleting body '" + id + "' of scene '" + scene + "'");
  store_->dropped_bodies_.emplace_back(scene, id);
}

void SceneStore::Txn::PutRequest(const std::string& client, const std::string& request_id,
                                 const RequestOutcome& o) {
  Stmt st(store_->Prepare(
      "INSERT OR REPLACE INTO requests(client, request_id, method, code, message, response, "
      "created_at) VALUES(?, ?, ?, ?, ?, ?, ?)"));
  st.Text(1, client);
  st.Text(2, request_id);
  st.Text(3, o.method);
  st.Int(4, o.code);
  st.Text(5, o.message);
  st.Blob(6, o.response);
  st.Int(7, o.created_at_s);
  HAPTICPD_STORE_RUN(st, "request id '" + request_id + "'");
}

#undef HAPTICPD_STORE_RUN

grpc::Status SceneStore::Write(const std::function<void(Txn&)>& fill) {
  std::lock_guard lock(db_mu_);
  dropped_bodies_.clear();
  dropped_scenes_.clear();
  try {
    Exec("BEGIN IMMEDIATE");
    Txn t(this);
    fill(t);
    if (before_commit) {
      if (const int rc = before_commit(); rc != SQLITE_OK) throw StoreError(sqlite3_errstr(rc));
    }
    Exec("COMMIT");
  } catch (const StoreError& e) {
    if (!sqlite3_get_autocommit(db_)) sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr);
    return grpc::Status(grpc::StatusCode::UNAVAILABLE, std::string("state store: ") + e.what() +
                                                           " (" + db_path_.string() +
                                                           "); nothing was changed");
  }
  // Committed: a queued pose of a body or scene that is gone must not be
  // written over a later body of the same id.
  if (!dropped_bodies_.empty() || !dropped_scenes_.empty()) {
    std::lock_guard plock(pending_mu_);
    for (const auto& key : dropped_bodies_) pending_.erase(key);
    for (const std::string& scene : dropped_scenes_) {
      std::erase_if(pending_, [&](const auto& kv) { return kv.first.first == scene; });
    }
  }
  return grpc::Status::OK;
}

void SceneStore::QueuePose(const std::string& scene, const std::string& body, const Pose& X_WB,
                           const Vec3& v_W, const Vec3& w_W) {
  std::lock_guard lock(pending_mu_);
  pending_[{scene, body}] = PendingPose{X_WB, v_W, w_W};
}

bool SceneStore::FlushPoses() {
  std::lock_guard lock(db_mu_);
  std::map<std::pair<std::string, std::string>, PendingPose> batch;
  {
    std::lock_guard plock(pending_mu_);
    batch.swap(pending_);
  }
  if (batch.empty()) return true;
  try {
    Exec("BEGIN IMMEDIATE");
    Stmt st(Prepare("UPDATE bodies SET pose = ?, velocity = ? WHERE scene_id = ? AND id = ?"));
    for (const auto& [key, p] : batch) {
      sqlite3_reset(st.get());
      st.Blob(1, PoseBlob(p.X_WB));
      st.Blob(2, TwistBlob(p.v_W, p.w_W));
      st.Text(3, key.first);
      st.Text(4, key.second);
      if (sqlite3_step(st.get()) != SQLITE_DONE) Fail("pose of body '" + key.second + "'");
    }
    if (before_commit) {
      if (const int rc = before_commit(); rc != SQLITE_OK) throw StoreError(sqlite3_errstr(rc));
    }
    Exec("COMMIT");
  } catch (const StoreError& e) {
    if (!sqlite3_get_autocommit(db_)) sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr);
    {
      // Back in the queue unless a newer pose came meanwhile.
      std::lock_guard plock(pending_mu_);
      for (auto& [key, p] : batch) pending_.try_emplace(key, p);
    }
    if (!flush_failing_) {
      Log()->warn("state store: cannot write {} body poses ({}; {}); retrying", batch.size(),
                  e.what(), db_path_.string());
      flush_failing_ = true;
    }
    return false;
  }
  if (flush_failing_) {
    Log()->info("state store: body poses are written again");
    flush_failing_ = false;
  }
  return true;
}

void SceneStore::PurgeRequests(std::int64_t before_s) {
  std::lock_guard lock(db_mu_);
  try {
    Stmt st(Prepare("DELETE FROM requests WHERE created_at < ?"));
    st.Int(1, before_s);
    if (sqlite3_step(st.get()) != SQLITE_DONE) Fail("purging request ids");
  } catch (const StoreError& e) {
    Log()->warn("state store: {} ({})", e.what(), db_path_.string());
  }
}

void SceneStore::FlushLoop() {
  using Clock = std::chrono::steady_clock;
  auto next_purge = Clock::now() + std::chrono::minutes(10);
  std::unique_lock lock(flush_mu_);
  while (!stopping_) {
    flush_cv_.wait_for(lock, kPoseFlushInterval, [&] { return stopping_; });
    if (stopping_) break;
    lock.unlock();
    FlushPoses();
    if (Clock::now() >= next_purge) {
      PurgeRequests(UnixNow() - std::chrono::seconds(RequestLog::kTtl).count());
      next_purge = Clock::now() + std::chrono::minutes(10);
    }
    lock.lock();
  }
}

// ---------------------------------------------------------------- RequestLog

std::string RequestLog::ClientHash(const std::string& client_key) {
  unsigned char d[SHA256_DIGEST_LENGTH];
  SHA256(reinterpret_cast<const unsigned char*>(client_key.data()), client_key.size(), d);
  static const char* hex = "0123456789abcdef";
  std::string out;
  for (int i = 0; i < 16; ++i) {
    out += hex[d[i] >> 4];
    out += hex[d[i] & 15];
  }
  return out;
}

std::string RequestLog::Key(const std::string& client_hash, const std::string& request_id) {
  return client_hash + "/" + request_id;
}

bool RequestLog::Repeatable(int code) {
  switch (static_cast<grpc::StatusCode>(code)) {
    case grpc::StatusCode::OK:
    case grpc::StatusCode::INVALID_ARGUMENT:
    case grpc::StatusCode::NOT_FOUND:
    case grpc::StatusCode::ALREADY_EXISTS:
    case grpc::StatusCode::FAILED_PRECONDITION:
    case grpc::StatusCode::RESOURCE_EXHAUSTED:
    case grpc::StatusCode::OUT_OF_RANGE:
      return true;
    default:
      return false;
  }
}

void RequestLog::Load(const std::vector<StoredRequest>& requests) {
  std::vector<const StoredRequest*> sorted;
  for (const auto& r : requests) sorted.push_back(&r);
  std::sort(sorted.begin(), sorted.end(), [](const auto* a, const auto* b) {
    return a->outcome.created_at_s < b->outcome.created_at_s;
  });
  std::lock_guard lock(mu_);
  for (const StoredRequest* r : sorted) {
    const std::string key = Key(r->client, r->request_id);
    entries_[key] = Entry{true, r->outcome};
    order_.emplace_back(r->outcome.created_at_s, key);
  }
}

void RequestLog::ExpireLocked(std::int64_t now_s) {
  const std::int64_t oldest = now_s - std::chrono::seconds(kTtl).count();
  while (!order_.empty() && (order_.front().first < oldest || order_.size() > kMaxEntries)) {
    const auto& [t, key] = order_.front();
    if (auto it = entries_.find(key);
        it != entries_.end() && it->second.done && it->second.outcome.created_at_s == t) {
      entries_.erase(it);
    }
    order_.pop_front();
  }
}

namespace {
bool SameMethod(const RequestOutcome& o, std::string_view method, const std::string& request_id,
                RequestOutcome* out) {
  if (o.method == method) return true;
  *out = RequestOutcome{std::string(method), static_cast<int>(grpc::StatusCode::INVALID_ARGUMENT),
                        "request_id: '" + request_id + "' was already used for " + o.method +
                            " (a request id names one mutation)",
                        "", 0};
  return false;
}
}  // namespace

RequestLog::Claim RequestLog::Begin(const std::string& client_hash, const std::string& request_id,
                                    std::string_view method, RequestOutcome* out) {
  const std::string key = Key(client_hash, request_id);
  const std::int64_t now = UnixNow();
  std::unique_lock lock(mu_);
  ExpireLocked(now);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  for (;;) {
    auto it = entries_.find(key);
    if (it == entries_.end()) {
      Entry e;
      e.outcome.method = std::string(method);
      e.outcome.created_at_s = now;
      entries_.emplace(key, std::move(e));
      order_.emplace_back(now, key);
      return Claim::kRun;
    }
    if (it->second.done) {
      if (SameMethod(it->second.outcome, method, request_id, out)) *out = it->second.outcome;
      return Claim::kDone;
    }
    // The same id is running on another call (a retry sent before the first
    // answer came): its outcome is this one's.
    if (cv_.wait_until(lock, deadline) == std::cv_status::timeout) {
      *out =
          RequestOutcome{std::string(method), static_cast<int>(grpc::StatusCode::UNAVAILABLE),
                         "request_id: a call with this id is still running; retry later", "", now};
      return Claim::kDone;
    }
  }
}

bool RequestLog::Lookup(const std::string& client_hash, const std::string& request_id,
                        std::string_view method, RequestOutcome* out) {
  std::lock_guard lock(mu_);
  const auto it = entries_.find(Key(client_hash, request_id));
  if (it == entries_.end() || !it->second.done) return false;
  if (SameMethod(it->second.outcome, method, request_id, out)) *out = it->second.outcome;
  return true;
}

void RequestLog::Finish(const std::string& client_hash, const std::string& request_id,
                        RequestOutcome o, bool durable) {
  const std::string key = Key(client_hash, request_id);
  {
    std::lock_guard lock(mu_);
    auto it = entries_.find(key);
    if (it == entries_.end()) return;
    if (!Repeatable(o.code)) {
      entries_.erase(it);
    } else {
      o.created_at_s = it->second.outcome.created_at_s;
      it->second = Entry{true, o};
    }
  }
  cv_.notify_all();
  if (!durable && Repeatable(o.code)) Persist(client_hash, request_id, o);
}

void RequestLog::RecordError(const std::string& client_hash, const std::string& request_id,
                             RequestOutcome o) {
  if (!Repeatable(o.code) || o.code == 0) return;
  const std::string key = Key(client_hash, request_id);
  o.created_at_s = UnixNow();
  {
    std::lock_guard lock(mu_);
    if (entries_.count(key)) return;
    entries_.emplace(key, Entry{true, o});
    order_.emplace_back(o.created_at_s, key);
  }
  Persist(client_hash, request_id, o);
}

void RequestLog::Persist(const std::string& client_hash, const std::string& request_id,
                         const RequestOutcome& o) {
  // MoveBody sets an absolute pose: repeating it after a crash is harmless,
  // so its outcomes are not worth a synchronous write.
  if (store_ == nullptr || o.method == "MoveBody") return;
  const grpc::Status s =
      store_->Write([&](SceneStore::Txn& t) { t.PutRequest(client_hash, request_id, o); });
  if (!s.ok()) {
    Log()->warn("request id '{}': outcome kept in memory only: {}", request_id, s.error_message());
  }
}

}  // namespace hapticpd::server
