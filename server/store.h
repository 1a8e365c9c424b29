// The state directory: scenes, bodies (meshes included), poses, materials,
// configs and the outcomes of mutations that carried a request id, kept in an
// embedded SQLite database (WAL mode) so that a restart serves what was
// acknowledged (server/README.md "State directory").
//
//   DIR/lock        flock'ed by the server that owns DIR (one process at a time)
//   DIR/scenes.db   the database (+ scenes.db-wal, scenes.db-shm while open)
//
// Structural mutations are written by Write(), one transaction each,
// committed with synchronous=FULL before the RPC answers. Poses from
// MoveBody are queued (QueuePose) and written by a background thread every
// kPoseFlushInterval: only a moving body's latest pose matters.
#pragma once

#include <grpcpp/support/status.h>

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "hapticpd/v1/haptic.pb.h"
#include "pd/material.h"
#include "pd/mesh.h"
#include "pd/types.h"
#include "server/scene.h"

struct sqlite3;
struct sqlite3_stmt;

namespace hapticpd::server {

/// A state directory that cannot be used (corrupt or foreign database, an
/// unknown schema version, locked by another process, not writable). The
/// message names the file and the problem.
class StoreError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// The first outcome of a mutation that carried a request id.
struct RequestOutcome {
  std::string method;             ///< "CreateScene", "AddBody", ...
  int code = 0;                   ///< grpc::StatusCode
  std::string message;            ///< the status message (errors)
  std::string response;           ///< the serialized response message (OK)
  std::int64_t created_at_s = 0;  ///< Unix time
};

struct StoredBody {
  std::string id, label;
  Pose X_WB;
  Vec3 v_W = Vec3::Zero(), w_W = Vec3::Zero();
  pd::Material material;
  bool movable = false;
  std::vector<Vec3> vertices;
  std::vector<pd::Triangle> triangles;
};

struct StoredScene {
  std::string id, description;
  v1::SceneConfig config;
  std::uint64_t next_body_number = 1;
  std::vector<StoredBody> bodies;  ///< in the order they were added
};

struct StoredRequest {
  std::string client;  ///< RequestLog::ClientHash of the client key
  std::string request_id;
  RequestOutcome outcome;
};

struct StoredState {
  std::vector<StoredScene> scenes;
  std::vector<StoredRequest> requests;
};

class SceneStore {
 public:
  /// PRAGMA user_version of the database; a file with another is refused.
  static constexpr int kSchemaVersion = 1;
  /// PRAGMA application_id: "HPDS". A database without it is not ours.
  static constexpr int kApplicationId = 0x48504453;
  /// Queued poses are written at least this often (the documented bound is
  /// 100 ms; half of it leaves room for the commit itself).
  static constexpr std::chrono::milliseconds kPoseFlushInterval{50};

  /// Opens DIR (created when absent, mode 0700), takes DIR/lock and opens or
  /// creates DIR/scenes.db. Throws StoreError; an existing file that is not a
  /// hapticpd store of this schema version is left untouched. `max_bytes`
  /// (> 0) caps the database: beyond it a write fails as on a full disk.
  static std::unique_ptr<SceneStore> Open(const std::filesystem::path& dir,
                                          std::int64_t max_bytes = 0);
  /// Writes the queued poses and closes the database, then the lock.
  ~SceneStore();
  SceneStore(const SceneStore&) = delete;
  SceneStore& operator=(const SceneStore&) = delete;

  /// Deletes request outcomes created before `expired_before_s`, then reads
  /// everything. Throws StoreError.
  StoredState Load(std::int64_t expired_before_s);

  /// The statements of one transaction; each throws on an SQLite error
  /// (Write rolls the transaction back).
  class Txn {
   public:
    void PutScene(const std::string& id, const std::string& description,
                  const v1::SceneConfig& config, std::uint64_t next_body_number);
    void SetNextBodyNumber(const std::string& scene, std::uint64_t next_body_number);
    void DeleteScene(const std::string& id);
    void PutBody(const std::string& scene, const BodyState& body);
    void DeleteBody(const std::string& scene, const std::string& id);
    void PutRequest(const std::string& client, const std::string& request_id,
                    const RequestOutcome& outcome);

   private:
    friend class SceneStore;
    explicit Txn(SceneStore* store) : store_(store) {}
    SceneStore* store_;
  };

  /// Runs `fill` and commits, durably (synchronous=FULL), in one
  /// transaction. On any error nothing of it is kept, and the result is
  /// UNAVAILABLE "state store: PROBLEM (DB)".
  grpc::Status Write(const std::function<void(Txn&)>& fill);

  /// Queues a body's latest pose for the next batch (never blocks on disk).
  void QueuePose(const std::string& scene, const std::string& body, const Pose& X_WB,
                 const Vec3& v_W, const Vec3& w_W);
  /// Writes the queued poses now (the flush thread calls it every
  /// kPoseFlushInterval); false (logged) when the write failed, and the
  /// poses stay queued.
  bool FlushPoses();
  /// Deletes request outcomes created before `before_s`.
  void PurgeRequests(std::int64_t before_s);

  const std::filesystem::path& db_path() const { return db_path_; }

  /// Tests only: called before each COMMIT; a non-zero SQLite result code
  /// fails the transaction as that error from SQLite would.
  std::function<int()> before_commit;

 private:
  SceneStore() = default;
  struct PendingPose {
    Pose X_WB;
    Vec3 v_W, w_W;
  };
  void Exec(const char* sql);
  sqlite3_stmt* Prepare(const char* sql);
  [[noreturn]] void Fail(const std::string& what);
  void CheckOrCreateSchema();
  void FlushLoop();

  std::filesystem::path dir_, db_path_;
  int lock_fd_ = -1;
  sqlite3* db_ = nullptr;
  std::mutex db_mu_;  // one connection: every statement and transaction
  std::mutex pending_mu_;
  std::map<std::pair<std::string, std::string>, PendingPose> pending_;
  // What the transaction being written deletes (under db_mu_): their queued
  // poses are dropped once it commits.
  std::vector<std::pair<std::string, std::string>> dropped_bodies_;
  std::vector<std::string> dropped_scenes_;
  std::mutex flush_mu_;
  std::condition_variable flush_cv_;
  bool stopping_ = false;
  bool flush_failing_ = false;
  std::thread flusher_;
};

/// The outcomes of mutations sent with a request id, per client, for
/// RequestLog::kTtl; in memory and, for every method but MoveBody (which
/// sets an absolute pose), in the store.
class RequestLog {
 public:
  static constexpr std::chrono::hours kTtl{24};
  /// At most this many outcomes are remembered; beyond it the oldest go.
  static constexpr std::size_t kMaxEntries = 1'000'000;

  explicit RequestLog(SceneStore* store) : store_(store) {}

  /// A short, stable digest of a client key (its token): what the store
  /// keeps, so the database never holds a token.
  static std::string ClientHash(const std::string& client_key);
  /// The map key of a request: client hash and request id.
  static std::string Key(const std::string& client_hash, const std::string& request_id);

  /// Remembers outcomes read from the store.
  void Load(const std::vector<StoredRequest>& requests);

  enum class Claim { kRun, kDone };
  /// kRun: the caller runs the request and must call Finish or Drop. kDone:
  /// `*out` is the first outcome (after waiting while another call with the
  /// same key runs), or an INVALID_ARGUMENT when the id was used for another
  /// method.
  Claim Begin(const std::string& client_hash, const std::string& request_id,
              std::string_view method, RequestOutcome* out);
  /// Without waiting: the finished outcome for the key, if any.
  bool Lookup(const std::string& client_hash, const std::string& request_id,
              std::string_view method, RequestOutcome* out);
  /// Records the outcome of a claimed request. `durable`: it was written in
  /// the mutation's own transaction; otherwise an outcome worth repeating is
  /// written here (not for MoveBody). A transient error (Repeatable() false)
  /// is not recorded: the retry runs again.
  void Finish(const std::string& client_hash, const std::string& request_id, RequestOutcome o,
              bool durable);
  /// Records an error found before the request was claimed, unless the key
  /// already has an outcome.
  void RecordError(const std::string& client_hash, const std::string& request_id, RequestOutcome o);
  /// Whether an error is part of a request's outcome (invalid input, not
  /// found, exists, precondition, limit) rather than transient (shutdown,
  /// store failure, cancelled, auth).
  static bool Repeatable(int code);

 private:
  struct Entry {
    bool done = false;
    RequestOutcome outcome;
  };
  void Persist(const std::string& client_hash, const std::string& request_id,
               const RequestOutcome& o);
  void ExpireLocked(std::int64_t now_s);

  SceneStore* store_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::map<std::string, Entry> entries_;
  std::deque<std::pair<std::int64_t, std::string>> order_;  // (created_at, key), oldest first
};

/// Unix time in seconds.
std::int64_t UnixNow();

}  // namespace hapticpd::server
