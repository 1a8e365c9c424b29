#include "device/effects.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <utility>

#include "pd/enum_names.h"

namespace hapticpd::device {

namespace {
constexpr std::pair<Effect, const char*> kEffectNames[] = {
    {Effect::kContact, "contact"}, {Effect::kDamping, "damping"}, {Effect::kFriction, "friction"},
    {Effect::kWeight, "weight"},   {Effect::kTexture, "texture"}, {Effect::kTorque, "torque"}};
}  // namespace

const char* ToString(Effect e) { return EnumName<kEffectNames>(e, "?"); }

std::string EffectSet::ToString() const {
  std::string s;
  for (int i = 0; i < kNumEffects; ++i) {
    const auto e = static_cast<Effect>(i);
    if (!Has(e)) continue;
    if (!s.empty()) s += ",";
    s += device::ToString(e);
  }
  return s.empty() ? "none" : s;
}

ContactMaterial ContactMaterialOf(const IntermediateRep& ir) {
  ContactMaterial m;
  double total = 0;
  for (int i = 0; i < ir.num_rows; ++i) {
    const IrRow& r = ir.rows[static_cast<std::size_t>(i)];
    const double w = r.stiffness * std::max(0.0, r.depth);
    m.static_friction += w * r.static_friction;
    m.dynamic_friction += w * r.dynamic_friction;
    m.damping += w * r.damping;
    total += w;
  }
  if (total > 0) {
    m.static_friction /= total;
    m.dynamic_friction /= total;
    m.damping /= total;
  }
  return m;
}

namespace {

constexpr std::size_t Idx(Effect e) { return static_cast<std::size_t>(e); }

/// The contact normal (unit, towards the probe) and normal force N of the IR
/// wrench; N = 0 outside contact.
double NormalForce(const EffectParams& p, const EffectInput& in, Vec3* n) {
  const Vec3 F = in.wrench_ir.head<3>();
  const double N = F.norm();
  if (N <= p.contact_force_eps) return 0;
  *n = F / N;
  return N;
}

void ContactForceTorque(const EffectParams&, const EffectInput& in, EffectState* s, Vec6* W,
                        Mat6* K) {
  ++s->runs[Idx(Effect::kContact)];
  *W += in.wrench_ir;
  *K += in.K_ir;
}

/// 3-DoF contact: the force and its translational stiffness only.
void ContactForce(const EffectParams&, const EffectInput& in, EffectState* s, Vec6* W, Mat6* K) {
  ++s->runs[Idx(Effect::kContact)];
  W->head<3>() += in.wrench_ir.head<3>();
  K->topLeftCorner<3, 3>() += in.K_ir.topLeftCorner<3, 3>();
}

void Damping(const EffectParams& p, const EffectInput& in, EffectState* s, Vec6* W, Mat6*) {
  ++s->runs[Idx(Effect::kDamping)];
  Vec3 n;
  if (NormalForce(p, in, &n) <= 0 || in.ir == nullptr) return;
  const double b = std::min(ContactMaterialOf(*in.ir).damping, p.proxy_mass / p.period_s);
  W->head<3>() -= b * in.v_W;
}

void Friction(const EffectParams& p, const EffectInput& in, EffectState* s, Vec6* W, Mat6* K) {
  ++s->runs[Idx(Effect::kFriction)];
  Vec3 n;
  const double N = NormalForce(p, in, &n);
  if (N <= 0 || in.ir == nullptr || p.friction_stiffness <= 0) {
    s->anchored = false;
    s->slipping = false;
    return;
  }
  const Vec3& x = in.X_WP.t;
  if (!s->anchored) {
    s->anchor = x;
    s->anchored = true;
    s->slipping = false;
  }
  const ContactMaterial m = ContactMaterialOf(*in.ir);
  const double k = p.friction_stiffness;
  Vec3 d = x - s->anchor;
  d -= n * n.dot(d);  // tangential part
  const double stretch = d.norm();
  const double limit_static = m.static_friction * N;
  const double limit_dynamic = m.dynamic_friction * N;
  if (!s->slipping && k * stretch > limit_static) s->slipping = true;
  if (s->slipping && k * stretch < limit_dynamic) s->slipping = false;
  if (s->slipping) {
    // Drag the anchor along so the spring force is mu_d N (the friction cone's edge).
    const double keep = limit_dynamic / k;
    const Vec3 d_keep = stretch > 0 ? Vec3(d * (keep / stretch)) : Vec3::Zero();
    s->anchor += d - d_keep;
    d = d_keep;
    // A force of constant magnitude: no stiffness along the tangent.
    W->head<3>() -= k * d;
    return;
  }
  W->head<3>() -= k * d;
  K->topLeftCorner<3, 3>() += k * (Mat3::Identity() - n * n.transpose());
}

void Weight(const EffectParams& p, const EffectInput&, EffectState* s, Vec6* W, Mat6*) {
  ++s->runs[Idx(Effect::kWeight)];
  W->head<3>() += p.probe_mass * p.gravity;
}

void Texture(const EffectParams& p, const EffectInput& in, EffectState* s, Vec6* W, Mat6*) {
  ++s->runs[Idx(Effect::kTexture)];
  Vec3 n;
  if (NormalForce(p, in, &n) <= 0) return;
  W->head<3>() +=
      p.texture_amplitude * std::sin(2 * std::numbers::pi * p.texture_frequency * in.t_s) * n;
}

}  // namespace

EffectPipeline::EffectPipeline(EffectSet set, const EffectParams& params)
    : set_(set), params_(params) {
  auto add = [&](EffectFn fn, const char* name) {
    stages_[static_cast<std::size_t>(num_stages_++)] = fn;
    if (!description_.empty()) description_ += " > ";
    description_ += name;
  };
  if (set.Has(Effect::kContact)) {
    if (set.Has(Effect::kTorque)) {
      add(&ContactForceTorque, "contact(force+torque)");
    } else {
      add(&ContactForce, "contact(force)");
    }
  }
  if (set.Has(Effect::kFriction)) add(&Friction, "friction");
  if (set.Has(Effect::kDamping)) add(&Damping, "damping");
  if (set.Has(Effect::kTexture)) add(&Texture, "texture");
  if (set.Has(Effect::kWeight)) add(&Weight, "weight");
  if (description_.empty()) description_ = "none";
}

void EffectPipeline::Reset() {
  state_.anchored = false;
  state_.slipping = false;
}

}  // namespace hapticpd::device
