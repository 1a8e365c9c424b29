#include "device/local_pd_source.h"

#include "device/local_model.h"

#include <algorithm>
#include <chrono>

namespace hapticpd::device {

LocalPdIrSource::LocalPdIrSource(pd::ModelPtr probe, std::vector<pd::SceneBody> bodies,
                                 const LocalPdOptions& options)
    : probe_(std::move(probe)), bodies_(std::move(bodies)), options_(options) {
  data_.Resize(bodies_.size());
  compute_us_.reserve(1 << 20);
}

LocalPdIrSource::~LocalPdIrSource() { Stop(); }

Pose LocalPdIrSource::X_PA() const { return Pose::FromTranslation(-probe_->mass().p_MC); }

void LocalPdIrSource::Compute(const ProxySample& sample, IntermediateRep* ir) {
  const Pose X_WA = sample.X_WP * X_PA();
  pd::ComputeScenePdt(*probe_, X_WA, bodies_, options_.request, &data_, &result_);
  pd::ContactModelOptions model_options;
  model_options.validity_fraction = options_.validity_fraction;
  pd::BuildContactModel(*probe_, X_WA, bodies_, result_, model_options, &model_);
  IrFromContactModel(model_, sample, X_PA().Inverse(), /*torque=*/true, ir);
  ir->compute_time_us = result_.time_us;
}

void LocalPdIrSource::Pump(ServoLoop* loop, std::int64_t now_ns, bool stalled) {
  ++tick_;
  if (stalled) {
    pending_.clear();
    return;
  }
  ProxyMailbox& in = loop->proxy_mailbox();
  const int every = std::max(1, options_.compute_every_ticks);
  if (tick_ % static_cast<std::uint64_t>(every) == 0 && in.Fetch()) {
    Pending p{tick_ + static_cast<std::uint64_t>(std::max(0, options_.latency_ticks)), {}};
    Compute(in.front(), &p.ir);
    pending_.push_back(p);
    computed_.fetch_add(1);
  }
  // Deliver the newest due IR (older due ones are superseded, like the
  // server's newest-answer mailbox).
  bool deliver = false;
  IntermediateRep* out = &loop->ir_mailbox().back();
  while (!pending_.empty() && pending_.front().due_tick <= tick_) {
    *out = pending_.front().ir;
    pending_.pop_front();
    deliver = true;
  }
  if (deliver) {
    out->receive_time_ns = now_ns;
    loop->ir_mailbox().Publish();
  }
}

void LocalPdIrSource::Start(ServoLoop* loop, const Clock* clock) {
  if (thread_.joinable()) return;
  thread_ = std::jthread([this, loop, clock](std::stop_token st) {
    ProxyMailbox& in = loop->proxy_mailbox();
    IrMailbox& out = loop->ir_mailbox();
    while (!st.stop_requested()) {
      if (!in.Fetch()) {
        std::this_thread::sleep_for(std::chrono::microseconds(100));
        continue;
      }
      const std::int64_t t0 = SteadyClock::Instance().NowNs();
      Compute(in.front(), &out.back());
      const std::int64_t t1 = SteadyClock::Instance().NowNs();
      if (compute_us_.size() < compute_us_.capacity()) {
        compute_us_.push_back(1e-3 * static_cast<double>(t1 - t0));
      }
      out.back().receive_time_ns = clock->NowNs();
      out.Publish();
      computed_.fetch_add(1);
    }
  });
}

void LocalPdIrSource::Stop() {
  if (!thread_.joinable()) return;
  thread_.request_stop();
  thread_.join();
  thread_ = std::jthread();
}

}  // namespace hapticpd::device
