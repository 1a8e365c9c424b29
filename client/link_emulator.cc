#include "client/link_emulator.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace hapticpd::client {
namespace {

std::uint64_t SplitMix64(std::uint64_t* state) {
  std::uint64_t z = (*state += 0x9e3779b97f4a7c15ULL);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

std::string Num(double x) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%g", x);
  return buf;
}

}  // namespace

std::string LinkOptionsProblem(const LinkOptions& o) {
  // Written so that NaN fails every check.
  if (!(o.delay_ms >= 0 && o.delay_ms <= 10000)) {
    return "--delay: expected 0 to 10000 ms, got " + Num(o.delay_ms);
  }
  if (!(o.jitter_ms >= 0 && o.jitter_ms <= o.delay_ms)) {
    return "--jitter: expected 0 to --delay (" + Num(o.delay_ms) + " ms), got " + Num(o.jitter_ms);
  }
  if (!(o.loss >= 0 && o.loss < 1)) {
    return "--loss: expected a fraction in [0, 1), got " + Num(o.loss);
  }
  if (o.max_in_flight == 0) return "link: max_in_flight must be at least 1";
  return "";
}

std::string LinkDescription(const LinkOptions& o) {
  char buf[160];
  std::snprintf(buf, sizeof(buf), "%g ms +-%g ms one way, %g%% loss", o.delay_ms, o.jitter_ms,
                100 * o.loss);
  return buf;
}

LinkSchedule::LinkSchedule(const LinkOptions& o, std::uint64_t stream)
    : delay_ns_(std::llround(o.delay_ms * 1e6)),
      jitter_ns_(std::llround(o.jitter_ms * 1e6)),
      loss_(o.loss) {
  // Decorrelate the directions (and nearby seeds) before the first draw.
  std::uint64_t s = o.seed ^ (stream * 0xd1b54a32d192ed03ULL);
  state_ = SplitMix64(&s);
}

double LinkSchedule::Uniform() {
  return static_cast<double>(SplitMix64(&state_) >> 11) * 0x1.0p-53;
}

std::optional<std::int64_t> LinkSchedule::Admit(std::int64_t send_ns, bool may_lose) {
  // Both draws every time, so a message's delay does not depend on whether
  // the ones before it were lost.
  const double u_loss = Uniform();
  const double u_jitter = Uniform();
  if (may_lose && u_loss < loss_) return std::nullopt;
  const std::int64_t jitter = std::llround((2 * u_jitter - 1) * static_cast<double>(jitter_ns_));
  const std::int64_t due = std::max(last_delivery_ns_, send_ns + delay_ns_ + jitter);
  last_delivery_ns_ = due;
  return due;
}

}  // namespace hapticpd::client
