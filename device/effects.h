// Haptic effects: small units the servo loop composes into one pipeline at
// scene load (README "Scene files"), so a tick runs exactly the effects the
// scene declares and nothing else (no per-tick test of disabled effects).
//
// Each effect adds a wrench W = [force; torque about P's origin] on the proxy
// and its stiffness K = -dW/dx (for the implicit proxy step):
//   contact   the IR wrench (PDt rows or the PDg spring); without `torque`
//             its force part only
//   damping   -b v_P inside contact (b from the contact rows' material,
//             capped at proxy mass / period so the explicit term stays stable)
//   friction  Coulomb stick-slip at the contact regions, proxy based (the
//             god-object/CHAI3D way): the proxy is held to an anchor by a
//             tangential spring; when the spring force would exceed mu_s N
//             the contact slips and the anchor is dragged so the force stays
//             mu_d N; it sticks again once the spring force falls below mu_d N
//   weight    m g on the proxy (client only; no server data)
//   texture   A sin(2 pi f t) along the contact normal while in contact (on
//             the proxy: the hand feels the coupling's share of it against
//             the contact stiffness, k_c / (k_c + k_contact) at low frequency)
//   torque    not a stage: it selects the contact stage with torque, and
//             without it the loop commands no torque (3-DoF rendering)
// Effects that need contact regions read the IR; weight needs none.
// Apply() allocates nothing, locks nothing and logs nothing.
#pragma once

#include <array>
#include <cstdint>
#include <string>

#include "device/ir.h"

namespace hapticpd::device {

enum class Effect : std::uint8_t { kContact, kDamping, kFriction, kWeight, kTexture, kTorque };
inline constexpr int kNumEffects = 6;

const char* ToString(Effect e);

/// A set of declared effects.
class EffectSet {
 public:
  constexpr EffectSet() = default;
  /// What a scene that declares nothing gets: contact and torque.
  static constexpr EffectSet ContactAndTorque() {
    return EffectSet().With(Effect::kContact).With(Effect::kTorque);
  }
  static constexpr EffectSet All() { return EffectSet((1u << kNumEffects) - 1); }
  constexpr EffectSet With(Effect e) const { return EffectSet(bits_ | Bit(e)); }
  constexpr EffectSet Without(Effect e) const { return EffectSet(bits_ & ~Bit(e)); }
  constexpr bool Has(Effect e) const { return (bits_ & Bit(e)) != 0; }
  constexpr bool empty() const { return bits_ == 0; }
  constexpr bool operator==(const EffectSet&) const = default;
  /// "contact,torque" (or "none").
  std::string ToString() const;

 private:
  constexpr explicit EffectSet(std::uint32_t bits) : bits_(bits) {}
  static constexpr std::uint32_t Bit(Effect e) { return 1u << static_cast<unsigned>(e); }
  std::uint32_t bits_ = 0;
};

struct EffectParams {
  Vec3 gravity = Vec3(0, 0, -9.81);  ///< m/s^2, W
  double probe_mass = 0.05;          ///< kg: the weight the user feels (not the proxy's mass)
  double texture_amplitude = 0.2;    ///< N
  double texture_frequency = 150;    ///< Hz
  /// N/m: the tangential spring that holds the proxy while friction sticks.
  double friction_stiffness = 2000;
  /// Below this normal force (N) there is no contact for friction, damping, texture.
  double contact_force_eps = 1e-6;
  /// Proxy mass (kg) and period (s): damping is capped at mass / period.
  double proxy_mass = 0.01;
  double period_s = 0.001;
};

/// What a tick hands the effects.
struct EffectInput {
  const IntermediateRep* ir = nullptr;  ///< the evaluator's current IR (rows, material)
  Vec6 wrench_ir = Vec6::Zero();        ///< IR contact wrench at the proxy (blended, faded)
  Mat6 K_ir = Mat6::Zero();
  Pose X_WP;
  Vec3 v_W = Vec3::Zero();
  Vec3 w_W = Vec3::Zero();
  double t_s = 0;  ///< loop time
};

/// State the effects keep between ticks, and how often each one ran.
struct EffectState {
  bool anchored = false;  ///< friction: the proxy has an anchor
  bool slipping = false;
  Vec3 anchor = Vec3::Zero();
  std::array<std::uint64_t, kNumEffects> runs{};  ///< incremented inside each effect's code
};

/// One stage: adds its wrench and stiffness to *W, *K.
using EffectFn = void (*)(const EffectParams&, const EffectInput&, EffectState*, Vec6* W, Mat6* K);

/// The declared effects as a fixed array of function pointers, built once.
class EffectPipeline {
 public:
  explicit EffectPipeline(EffectSet set = EffectSet::ContactAndTorque(),
                          const EffectParams& params = {});

  /// The wrench and stiffness of all stages on the proxy. No allocation.
  void Apply(const EffectInput& in, Vec6* W, Mat6* K) {
    W->setZero();
    K->setZero();
    for (int i = 0; i < num_stages_; ++i)
      stages_[static_cast<std::size_t>(i)](params_, in, &state_, W, K);
  }

  EffectSet effects() const { return set_; }
  const EffectParams& params() const { return params_; }
  int num_stages() const { return num_stages_; }
  /// The stages in order, e.g. "contact(force+torque) > friction > weight".
  const std::string& description() const { return description_; }
  const EffectState& state() const { return state_; }
  /// Forgets friction anchors (e.g. after a reconnect).
  void Reset();

 private:
  EffectSet set_;
  EffectParams params_;
  std::array<EffectFn, kNumEffects> stages_{};
  int num_stages_ = 0;
  std::string description_;
  EffectState state_;
};

/// The contact material at the IR: each row's friction and damping weighted
/// by its penalty force k * depth (zero without rows).
struct ContactMaterial {
  double static_friction = 0;
  double dynamic_friction = 0;
  double damping = 0;
};
ContactMaterial ContactMaterialOf(const IntermediateRep& ir);

}  // namespace hapticpd::device
