#include "server/telemetry.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "proto/wire/convert.h"
#include "proto/wire/ranges.h"

namespace hapticpd::server {
namespace {

/// Microseconds from `start_ns` to `t_ns`, held in a uint32 (a sample
/// outside [0, 2^32) us of the batch's first is put at its edge).
std::uint32_t OffsetUs(std::int64_t start_ns, std::int64_t t_ns) {
  const std::int64_t us = (t_ns - start_ns) / 1000;
  return static_cast<std::uint32_t>(
      std::clamp<std::int64_t>(us, 0, std::numeric_limits<std::uint32_t>::max()));
}

}  // namespace

grpc::Status CheckDeviceTelemetry(const v1::DeviceTelemetry& t, std::uint64_t last_sequence) {
  if (t.sequence() <= last_sequence) {
    return wire::InvalidArgument(
        "telemetry.sequence", fmt::format("must increase from message to message, got {} after {}",
                                          t.sequence(), last_sequence));
  }
  const std::pair<double, const char*> rates[] = {{t.servo_rate_hz(), "telemetry.servo_rate_hz"},
                                                  {t.update_rate_hz(), "telemetry.update_rate_hz"},
                                                  {t.local_rate_hz(), "telemetry.local_rate_hz"}};
  for (const auto& [v, field] : rates) {
    if (auto s = wire::CheckRange(v, wire::kTelemetryRateHz, field); !s.ok()) return s;
  }
  const std::pair<double, const char*> times[] = {
      {t.round_trip_ms(), "telemetry.round_trip_ms"},
      {t.ir_age_ms(), "telemetry.ir_age_ms"},
      {t.emulated_delay_ms(), "telemetry.emulated_delay_ms"},
      {t.emulated_jitter_ms(), "telemetry.emulated_jitter_ms"}};
  for (const auto& [v, field] : times) {
    if (auto s = wire::CheckRange(v, wire::kTelemetryMs, field); !s.ok()) return s;
  }
  if (auto s = wire::CheckRange(t.emulated_loss(), wire::kLossFraction, "telemetry.emulated_loss");
      !s.ok()) {
    return s;
  }
  Pose X;
  if (t.has_handle_pose()) {
    if (auto s = wire::FromProto(t.handle_pose(), "telemetry.handle_pose", &X); !s.ok()) return s;
  }
  if (t.has_proxy_pose()) {
    if (auto s = wire::FromProto(t.proxy_pose(), "telemetry.proxy_pose", &X); !s.ok()) return s;
  }
  const v1::WrenchSamples& c = t.commanded();
  if (c.offset_us_size() != c.force_size() || c.force_size() != c.torque_size()) {
    return wire::InvalidArgument(
        "telemetry.commanded",
        fmt::format("offset_us, force and torque must have the same length, got {}, {} and {}",
                    c.offset_us_size(), c.force_size(), c.torque_size()));
  }
  if (c.force_size() > kMaxTelemetrySamples) {
    return wire::InvalidArgument("telemetry.commanded",
                                 fmt::format("at most {} samples per message, got {}",
                                             kMaxTelemetrySamples, c.force_size()));
  }
  for (int i = 0; i < c.force_size(); ++i) {
    if (i > 0 && c.offset_us(i) < c.offset_us(i - 1)) {
      return wire::InvalidArgument(
          fmt::format("telemetry.commanded.offset_us[{}]", i),
          fmt::format("must not decrease, got {} after {}", c.offset_us(i), c.offset_us(i - 1)));
    }
    if (auto s = wire::CheckRange(c.force(i), wire::kTelemetryForce,
                                  fmt::format("telemetry.commanded.force[{}]", i));
        !s.ok()) {
      return s;
    }
    if (auto s = wire::CheckRange(c.torque(i), wire::kTelemetryTorque,
                                  fmt::format("telemetry.commanded.torque[{}]", i));
        !s.ok()) {
      return s;
    }
  }
  return grpc::Status::OK;
}

void TelemetryFeed::AddAnswer(std::int64_t time_ns, double force, double torque) {
  answers_.Push(Answer{time_ns, static_cast<float>(force), static_cast<float>(torque)});
}

void TelemetryFeed::AddDevice(v1::DeviceTelemetry* t) {
  const auto n = static_cast<std::size_t>(t->commanded().force_size());
  std::lock_guard lock(mu_);
  // Bounded: nobody took the older messages (no observer publisher runs).
  while (!pending_.empty() && pending_samples_ + n > kFeedDeviceSamples) {
    const auto old = static_cast<std::size_t>(pending_.front().commanded().force_size());
    dropped_samples_ += old;
    pending_samples_ -= old;
    pending_.erase(pending_.begin());
  }
  pending_samples_ += n;
  pending_.emplace_back();
  pending_.back().Swap(t);
}

void TelemetryFeed::Take(std::int64_t now_ns, v1::SessionTelemetry* out) {
  std::uint64_t dropped = 0;
  taken_.clear();
  {
    std::lock_guard lock(mu_);
    taken_.swap(pending_);
    pending_samples_ = 0;
    dropped = dropped_samples_;
  }
  if (!taken_.empty()) {
    // Every message's samples, on the first sample's time.
    v1::WrenchSamples merged;
    bool have_start = false;
    std::uint64_t ticks[3] = {0, 0, 0};
    for (const v1::DeviceTelemetry& m : taken_) {
      ticks[0] += m.ticks_server();
      ticks[1] += m.ticks_local();
      ticks[2] += m.ticks_faded();
      const v1::WrenchSamples& c = m.commanded();
      if (c.force_size() == 0) continue;
      if (!have_start) {
        merged.set_start_time_ns(c.start_time_ns());
        have_start = true;
      }
      for (int i = 0; i < c.force_size(); ++i) {
        merged.add_offset_us(OffsetUs(merged.start_time_ns(),
                                      c.start_time_ns() + std::int64_t{1000} * c.offset_us(i)));
        merged.add_force(c.force(i));
        merged.add_torque(c.torque(i));
      }
    }
    v1::DeviceTelemetry* d = out->mutable_device();
    d->Swap(&taken_.back());
    merged.set_samples_lost(d->commanded().samples_lost() + dropped);
    d->mutable_commanded()->Swap(&merged);
    d->set_ticks_server(ticks[0]);
    d->set_ticks_local(ticks[1]);
    d->set_ticks_faded(ticks[2]);
  }
  v1::WrenchSamples* server = out->mutable_server();
  Answer a;
  while (answers_.Pop(&a)) {
    if (server->force_size() == 0) server->set_start_time_ns(a.time_ns);
    server->add_offset_us(OffsetUs(server->start_time_ns(), a.time_ns));
    server->add_force(a.force);
    server->add_torque(a.torque);
  }
  server->set_samples_lost(answers_.lost());
  const std::uint64_t answers = answers_.pushed() + answers_.lost();
  out->set_update_rate_hz(last_take_ns_ != 0 && now_ns > last_take_ns_
                              ? 1e9 * static_cast<double>(answers - last_answers_) /
                                    static_cast<double>(now_ns - last_take_ns_)
                              : 0.0);
  last_answers_ = answers;
  last_take_ns_ = now_ns;
}

void TelemetryFeed::Discard(std::int64_t now_ns) {
  taken_.clear();
  {
    std::lock_guard lock(mu_);
    taken_.swap(pending_);
    pending_samples_ = 0;
  }
  taken_.clear();
  Answer a;
  while (answers_.Pop(&a)) {
  }
  last_answers_ = answers_.pushed() + answers_.lost();
  last_take_ns_ = now_ns;
}

}  // namespace hapticpd::server
