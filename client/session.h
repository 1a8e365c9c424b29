// The device-side network Session: one HapticService.Couple stream
// between a ServoLoop and the server, kept alive across server restarts.
//
//   Session session(options);
//   session.Connect();                     // hello -> welcome; throws SessionError
//   config.X_PA = session.X_PA();          // proxy frame P at the probe's CoM
//   ServoLoop loop(&device, config);
//   session.Start(&loop); loop.Start();    // network thread + 1 kHz servo thread
//   ...
//   loop.Stop(); session.Stop();
//
// The network thread only touches the loop's mailboxes: it fetches the
// newest proxy sample and sends it as a ProbePose (latest only: samples the
// servo loop published while a Write was under way are superseded, never
// queued), and a reader thread turns every ContactUpdate into an
// IntermediateRep (IrFromContactUpdate) published to the IR mailbox. When
// the stream breaks it reconnects with exponential backoff; meanwhile no IR
// arrives, so the servo loop fades the contact force to zero by itself (the
// IR goes stale), and on reconnect it asks the loop to ResetContact (the
// start-up ramp re-arms). Round trips (pose written -> its ContactUpdate
// read) and update counts are kept for statistics. SessionOptions::link
// puts an emulated delay, jitter and loss between the loop and the stream
// (client/link_emulator.h), on the session's threads.
#pragma once

#include <grpcpp/grpcpp.h>

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>

#include "client/link_emulator.h"
#include "device/haptic_device.h"
#include "device/ir.h"
#include "device/local_model.h"
#include "device/servo_loop.h"
#include "device/stats.h"
#include "hapticpd/v1/haptic.grpc.pb.h"

namespace hapticpd::client {

/// Converts a ContactUpdate into the IR the servo loop renders. X_AP maps
/// the probe's mesh frame A (the wire's poses) to the proxy frame P (X_AP =
/// X_PA^-1); receive_time_ns is the loop clock's time of arrival. PDt (and
/// PDg without a target) uses the rows (the deepest kMaxIrRows are kept);
/// a PDg answer in contact with a positive target stiffness renders the
/// spring towards target_pose instead. Row normals are normalised (rows
/// with a zero normal, depth or stiffness are skipped); non-finite numbers
/// make it return false (the IR is then not to be published). No
/// allocation.
bool IrFromContactUpdate(const v1::ContactUpdate& update, const device::Pose& X_AP,
                         std::int64_t receive_time_ns, device::IntermediateRep* ir);

/// Decodes a GeometryPatch into the device side's PatchDelta: "" or the
/// problem (one line naming the field: arrays of the wrong length, a
/// non-finite or out-of-range number, a body patch over
/// `max_triangles_per_body`). Index ranges and what is held are checked
/// when the patch is applied (device::PatchStore::Apply).
std::string PatchDeltaFromProto(const v1::GeometryPatch& g, std::size_t max_triangles_per_body,
                                device::PatchDelta* out);

/// The servo loop's effects for a scene's declaration (the Welcome's
/// scene_config; one that declares nothing means contact and torque), and
/// their parameters (gravity, probe mass, texture).
device::EffectSet EffectsFromSceneConfig(const v1::SceneConfig& c);
device::EffectParams EffectParamsFromSceneConfig(const v1::SceneConfig& c);

/// A failed Connect (one line: what and why).
struct SessionError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

struct SessionOptions {
  std::string server = "127.0.0.1:50051";  ///< HOST:PORT
  /// nullptr: insecure (plaintext) channel.
  std::shared_ptr<grpc::ChannelCredentials> credentials;
  std::string token;  ///< sent as "authorization: Bearer TOKEN" when set
  /// The hello: scene, mode, exactly one probe (probe_shape, probe_mesh or
  /// probe_body_id), optional material and max_rate_hz. protocol_version
  /// and client_name are filled in when left empty.
  v1::Hello hello;
  double connect_timeout_s = 5;  ///< per attempt: channel ready + welcome
  double backoff_initial_s = 0.02;
  double backoff_max_s = 1.0;
  /// How often the network thread looks for a new proxy sample when idle.
  double poll_interval_s = 100e-6;
  /// An emulated wide-area link (client/link_emulator.h) between the servo
  /// loop and the stream, both directions: poses enter it when the network
  /// thread takes them from the loop, updates when the reader reads them,
  /// and a delivery thread publishes due updates to the IR mailbox. Unset
  /// (the default): no emulation, today's path exactly. Must be valid
  /// (LinkOptionsProblem); the Session constructor throws SessionError
  /// otherwise.
  std::optional<LinkOptions> link;
  /// The local contact model (device/local_model.h): the hello asks for
  /// geometry patches and PD runs on them on the device side at the
  /// proxy's newest pose. Needs a probe given by shape or mesh (the client
  /// builds the same probe model as the server) and mode PDt or PDg;
  /// otherwise the session runs without it and says why
  /// (SessionStats::local_model_note).
  bool local_model = false;
  /// Most triangles held per body (PatchRequest.max_triangles_per_body).
  std::uint32_t patch_max_triangles = 8192;
  /// m, PatchRequest.min_margin (0: the server's default).
  double patch_min_margin = 0;
  /// Device telemetry (CoupleRequest.telemetry): every telemetry_interval_s
  /// the network thread drains the servo loop's sample ring
  /// (ServoLoop::samples()) and sends one DeviceTelemetry up the stream
  /// with every tick's commanded force and torque, the ticks per contact
  /// source, the fail-safe state, rates, round trip, IR age, the emulated
  /// link and the handle and proxy poses; a last one on Stop (before the
  /// stream ends, so no tick is left out). Through the
  /// emulated link when there is one (its own direction, kLinkTelemetry:
  /// the poses' schedule is unchanged); what the link loses is counted in
  /// the next message's samples_lost. The server relays it to observers.
  bool telemetry = true;
  double telemetry_interval_s = 0.05;
};

/// What the emulated link did (SessionOptions::link), per direction.
struct LinkStats {
  bool active = false;
  LinkCounters poses;      ///< client -> server
  LinkCounters updates;    ///< server -> client
  LinkCounters telemetry;  ///< device telemetry, client -> server
};

/// Statistics any thread may read (a consistent copy under a mutex; the
/// servo thread never calls this).
struct SessionStats {
  std::uint64_t poses_sent = 0;
  std::uint64_t updates = 0;          ///< ContactUpdates received
  std::uint64_t bad_updates = 0;      ///< rejected by IrFromContactUpdate
  std::uint64_t contact_updates = 0;  ///< updates with at least one row
  std::uint64_t connects = 0;         ///< successful hello/welcome exchanges
  std::uint64_t disconnects = 0;      ///< streams that ended other than by Stop
  std::uint64_t failed_attempts = 0;  ///< reconnect attempts that failed
  /// Updates dropped by StallUpdatesFor (fault injection).
  std::uint64_t withheld_updates = 0;
  std::uint64_t rtt_samples = 0;
  double rtt_p50_us = 0, rtt_p99_us = 0, rtt_max_us = 0, rtt_mean_us = 0;
  double server_compute_p50_us = 0, server_compute_p99_us = 0;
  double max_depth = 0;  ///< m, deepest PD reported
  std::string last_error;
  std::string session_id;  ///< of the current (or last) stream
  LinkStats link;
  /// The local contact model: running, or why not; and what it did.
  bool local_model = false;
  std::string local_model_note;
  device::LocalModelStats local;
  std::uint64_t patches_received = 0;
  double server_clock_offset_ms = 0;  ///< server steady clock - loop clock
  /// Device telemetry (SessionOptions::telemetry): messages written to the
  /// stream and the servo samples in them; samples lost on the current
  /// stream (the ring was full, or the emulated link dropped their
  /// message: what the last message reported as samples_lost); samples
  /// taken while no stream was open (discarded: they belong to no session).
  std::uint64_t telemetry_sent = 0;
  std::uint64_t telemetry_samples_sent = 0;
  std::uint64_t telemetry_samples_lost = 0;
  std::uint64_t telemetry_samples_discarded = 0;
};

class Session {
 public:
  explicit Session(SessionOptions options,
                   const device::Clock* clock = &device::SteadyClock::Instance());
  ~Session();
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;

  /// Sends the hello and reads the welcome (the first one: later welcomes
  /// after reconnects do not change it). Throws SessionError with the
  /// server's status (e.g. "NOT_FOUND: scene 'x'") or a timeout.
  void Connect();
  const v1::Welcome& welcome() const { return welcome_; }
  /// The probe's mesh frame A in the proxy frame P (P: A moved to the
  /// probe's centre of mass, same axes). Valid after Connect().
  device::Pose X_PA() const { return X_PA_; }

  /// Starts the network thread against `loop` (which must outlive Stop()).
  /// Requires Connect().
  void Start(device::ServoLoop* loop);
  /// Ends the stream (half-close) and joins the threads. Idempotent.
  void Stop();

  bool connected() const { return connected_.load(); }
  /// Fault injection for tests: every ContactUpdate that arrives during the
  /// next `seconds` is withheld from the servo loop, as if the server had
  /// stopped answering while the stream stays up. Any thread. When unused it
  /// costs the reader thread one relaxed atomic load per update.
  void StallUpdatesFor(double seconds);
  /// A thread-safe snapshot.
  SessionStats stats() const;

 private:
  struct Stream;
  std::unique_ptr<Stream> Open(bool first, std::string* error, grpc::StatusCode* code);
  void Run(std::stop_token st);
  void Serve(Stream& s, std::stop_token st);
  void ReadLoop(Stream* s);
  /// Publishes an update that has arrived (directly, or out of the
  /// emulated link) to the IR mailbox and counts it. One thread at a time:
  /// the reader, or the link's delivery thread.
  void Accept(const v1::ContactUpdate& u, std::int64_t now_ns);
  /// With an emulated link: hands due updates to Accept until `done`.
  void DeliverLoop(const std::atomic<bool>& done);
  /// A patch that has arrived (directly, or out of the emulated link).
  void AcceptPatch(const v1::GeometryPatch& g, std::int64_t now_ns);
  /// Sets up the local contact model after the first welcome.
  void StartLocalModel();
  /// Writes one pose to the stream (false: the stream is broken).
  bool WritePose(Stream& s, const device::ProxySample& x, v1::CoupleRequest* req);
  /// Device telemetry (network thread): a new stream starts from an empty
  /// ring; each step drains it into one message (`latest`: the newest proxy
  /// sample, or null) and writes it, or hands it to the emulated link;
  /// `flush` (Stop) repeats until the ring is empty and writes directly.
  /// False: the stream is broken.
  void StartTelemetry(std::int64_t now_ns);
  bool TelemetryStep(Stream& s, std::int64_t now_ns, const device::ProxySample* latest, bool flush);
  bool WriteTelemetry(Stream& s, const v1::CoupleRequest& req);

  SessionOptions options_;
  const device::Clock* clock_;
  v1::Welcome welcome_;
  device::Pose X_PA_, X_AP_;
  device::ServoLoop* loop_ = nullptr;
  std::unique_ptr<Stream> first_;  // from Connect(), used by the first Serve

  // Cancels whatever blocks the network thread on Stop().
  std::mutex ctx_mu_;
  grpc::ClientContext* live_ctx_ = nullptr;
  std::atomic<bool> stopping_{false};
  // Stop() asks the network thread for a last telemetry message first.
  std::atomic<bool> flush_requested_{false};
  std::atomic<bool> flush_done_{false};
  std::atomic<bool> connected_{false};
  std::atomic<std::int64_t> stall_until_ns_{0};  // StallUpdatesFor (clock_ time)

  // The emulated link (options_.link), or none.
  struct Link {
    explicit Link(const LinkOptions& o)
        : poses(o, kLinkUp), updates(o, kLinkDown), telemetry(o, kLinkTelemetry) {}
    DelayLine<device::ProxySample> poses;
    DelayLine<v1::CoupleResponse> updates;  // updates and patches, in order
    DelayLine<v1::CoupleRequest> telemetry;
  };
  std::unique_ptr<Link> link_;

  // Pose send times, by sequence (written by the network thread, read by
  // the reader thread).
  static constexpr std::size_t kRing = 4096;
  std::array<std::atomic<std::uint64_t>, kRing> sent_seq_{};
  std::array<std::atomic<std::int64_t>, kRing> sent_ns_{};

  // The local contact model (options_.local_model and usable), or none.
  std::unique_ptr<device::LocalContactModel> local_;
  device::IntermediateRep server_ir_;  // decoded server answer (reader/delivery thread)
  // Round trip and server clock offset estimates (reader/delivery thread
  // writes; the network thread reads the round trip for ProbePose).
  std::atomic<double> rtt_estimate_us_{0};
  double best_rtt_us_ = 0;
  std::uint64_t since_best_ = 0;

  // Device telemetry: the network thread's own.
  struct Telemetry {
    std::uint64_t sequence = 0;
    std::int64_t next_ns = 0;
    std::int64_t last_ns = 0;
    std::uint64_t ring_lost_base = 0;  // the ring's lost() when the stream started
    std::uint64_t link_lost = 0;       // samples in messages the emulated link dropped
    std::uint64_t last_ticks = 0, last_updates = 0, last_local_answers = 0;
    device::TickSample latest;
    bool have_latest = false;
    std::optional<device::TickSample> carry;  // did not fit the previous message
    v1::CoupleRequest req, due;
  };
  Telemetry tel_;

  mutable std::mutex stats_mu_;
  SessionStats counters_;
  double last_rtt_us_ = 0;  // under stats_mu_
  // 1 us to 100 s, 32 bins per octave (2.2 % resolution).
  device::Histogram rtt_us_ = device::Histogram::LogScale(1, 1e8, 32);
  device::Histogram compute_us_ = device::Histogram::LogScale(1, 1e8, 32);

  std::jthread thread_;
};

}  // namespace hapticpd::client
