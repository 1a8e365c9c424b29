// A device session's telemetry on its way to observers (Watch with
// include_telemetry): the DeviceTelemetry messages the client sends up the
// Couple stream, and the server's own penalty force and torque per answer.
//
//   PD worker  --AddAnswer (wait-free ring)-->  TelemetryFeed
//   gRPC reader --AddDevice (validated; a short lock, bounded)-->  TelemetryFeed
//   the scene's observer publisher --Take, about 20 Hz-->  SessionTelemetry
//
// Nothing here waits on an observer: what no publisher takes in time is
// dropped and counted (samples_lost).
#pragma once

#include <grpcpp/support/status.h>

#include <atomic>
#include <cstdint>
#include <mutex>
#include <vector>

#include "device/spsc_ring.h"
#include "hapticpd/v1/scene.pb.h"
#include "proto/wire/ranges.h"

namespace hapticpd::server {

using wire::kMaxTelemetrySamples;
/// Answers a session's feed holds for the publisher (8 s at 1 kHz).
inline constexpr std::size_t kFeedAnswers = 8192;
/// Commanded samples a session's feed holds for the publisher; beyond it
/// the oldest messages are dropped (their samples counted lost).
inline constexpr std::size_t kFeedDeviceSamples = 16384;

/// OK, or INVALID_ARGUMENT naming the field ("telemetry.FIELD: problem"):
/// every number finite and in range, poses valid, the sample arrays of
/// equal length and at most kMaxTelemetrySamples, offsets not decreasing,
/// and `t.sequence()` greater than `last_sequence` (0: none yet).
grpc::Status CheckDeviceTelemetry(const v1::DeviceTelemetry& t, std::uint64_t last_sequence);

class TelemetryFeed {
 public:
  TelemetryFeed() = default;
  TelemetryFeed(const TelemetryFeed&) = delete;
  TelemetryFeed& operator=(const TelemetryFeed&) = delete;

  /// The PD worker (one thread), per answer: the penalty force and torque
  /// magnitudes sent, at server steady-clock time `time_ns`. Wait-free, no
  /// allocation.
  void AddAnswer(std::int64_t time_ns, double force, double torque);
  /// The stream's reader: a DeviceTelemetry that passed
  /// CheckDeviceTelemetry (moved from). The lock is held for a move.
  void AddDevice(v1::DeviceTelemetry* t);

  /// The publisher (one thread): everything since its previous Take, as
  /// `out`'s device (the latest message, its `commanded` holding every
  /// message's samples with offsets from the first sample and its ticks
  /// per source summed over the messages), server,
  /// update_rate_hz (answers per second since the previous Take; 0 on the
  /// first). Leaves session_id and scene_revision to the caller.
  void Take(std::int64_t now_ns, v1::SessionTelemetry* out);
  /// The same, keeping nothing (no observer asks for telemetry).
  void Discard(std::int64_t now_ns);

 private:
  struct Answer {
    std::int64_t time_ns = 0;
    float force = 0;
    float torque = 0;
  };
  device::SpscRing<Answer> answers_{kFeedAnswers};

  std::mutex mu_;  // held by AddDevice and Take for a swap or a move
  std::vector<v1::DeviceTelemetry> pending_;
  std::size_t pending_samples_ = 0;
  std::uint64_t dropped_samples_ = 0;  // device samples the feed could not keep

  // The publisher's own.
  std::vector<v1::DeviceTelemetry> taken_;
  std::int64_t last_take_ns_ = 0;
  std::uint64_t last_answers_ = 0;
};

}  // namespace hapticpd::server
