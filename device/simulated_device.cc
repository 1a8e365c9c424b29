#include "device/simulated_device.h"

#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>
#include <utility>

#include "device/math.h"

namespace hapticpd::device {

using internal::SmoothStep;

namespace {
/// Each script's name (--script), in the order the error message lists them.
constexpr std::pair<HandScript, const char*> kHandScriptNames[] = {
    {HandScript::kHold, "hold"},   {HandScript::kPress, "press"},   {HandScript::kSlide, "slide"},
    {HandScript::kTwist, "twist"}, {HandScript::kCircle, "circle"}, {HandScript::kLoop, "loop"},
    {HandScript::kPlate, "plate"}};
}  // namespace

const char* ToString(HandScript s) {
  for (const auto& [script, name] : kHandScriptNames) {
    if (s == script) return name;
  }
  return "?";
}

HandScript ParseHandScript(const std::string& name) {
  std::string names;
  for (const auto& [script, script_name] : kHandScriptNames) {
    if (name == script_name) return script;
    names += (names.empty() ? "" : ", ") + std::string(script_name);
  }
  throw std::invalid_argument("unknown hand script '" + name + "' (" + names + ")");
}

namespace {
// Smoothstep from 0 to 1 as s goes from a to b.
double Ramp(double s, double a, double b) { return SmoothStep((s - a) / (b - a)); }
}  // namespace

Pose ScriptPose(const ScriptParams& p, double t_s) {
  t_s -= p.hold_s;
  const double s = p.duration_s > 0 ? std::clamp(t_s / p.duration_s, 0.0, 1.0) : 1.0;
  Vec3 d = Vec3::Zero();    // displacement in S
  Vec3 rot = Vec3::Zero();  // rotation vector in S
  constexpr double kTwoPi = 2 * std::numbers::pi;
  switch (p.script) {
    case HandScript::kHold:
      break;
    case HandScript::kPress:
      d.z() = -p.travel * (Ramp(s, 0, 0.45) - Ramp(s, 0.55, 1));
      break;
    case HandScript::kSlide:
      d.z() = -p.travel * (Ramp(s, 0, 0.2) - Ramp(s, 0.8, 1));
      d.x() = p.lateral * Ramp(s, 0.2, 0.8);
      break;
    case HandScript::kTwist:
      d.z() = -p.travel * (Ramp(s, 0, 0.2) - Ramp(s, 0.8, 1));
      rot.z() = p.angle * (Ramp(s, 0.2, 0.5) - Ramp(s, 0.5, 0.8));
      break;
    case HandScript::kCircle: {
      const double th = kTwoPi * Ramp(s, 0, 1);
      d.x() = p.radius * std::sin(th);
      d.z() = -p.radius * (1 - std::cos(th));
      break;
    }
    case HandScript::kLoop: {
      const double th = kTwoPi * Ramp(s, 0, 1);
      d.x() = p.lateral * 0.5 * std::sin(th);
      d.y() = p.lateral * 0.25 * std::sin(2 * th);
      d.z() = -p.travel * 0.5 * (1 - std::cos(th));
      rot.z() = 0.5 * p.angle * std::sin(th);
      rot.x() = 0.2 * p.angle * std::sin(2 * th);
      break;
    }
    case HandScript::kPlate:
      d.z() = -p.travel * (Ramp(s, 0, 0.6) - Ramp(s, 0.7, 1));
      break;
  }
  return p.X_DS * Pose{internal::ExpRotation(rot), d};
}

DeviceInfo SimulatedDeviceInfo() {
  DeviceInfo i;
  i.name = "simulated hand + handle";
  i.dof_sensed = 6;
  i.dof_actuated = 6;
  i.max_force = 12;
  i.max_torque = 0.2;
  i.max_linear_stiffness = 2000;
  i.max_angular_stiffness = 1.0;
  i.max_linear_damping = 1.5;
  i.max_angular_damping = 0.005;
  i.workspace_min_D = Vec3::Constant(-1);
  i.workspace_max_D = Vec3::Constant(1);
  i.buttons = 1;
  return i;
}

Pose StartPoseAbove(const Vec3& aabb_min, const Vec3& aabb_max, double clearance) {
  const Vec3 c = 0.5 * (aabb_min + aabb_max);
  return Pose::FromTranslation(Vec3(c.x(), c.y(), aabb_max.z() + clearance));
}

SimulatedDevice::SimulatedDevice(const ScriptParams& script, const Clock* clock,
                                 const HandModel& hand, const DeviceInfo& info)
    : script_(script), clock_(clock), hand_(hand), info_(info) {}

void SimulatedDevice::Open() {
  open_ = true;
  t0_ns_ = t_ns_ = clock_->NowNs();
  X_DH_ = ScriptPose(script_, 0);
  v_.setZero();
  w_.setZero();
  cmd_ = Wrench{};
  energy_j_ = 0;
}

double SimulatedDevice::script_time_s() const { return 1e-9 * static_cast<double>(t_ns_ - t0_ns_); }

void SimulatedDevice::AdvanceTo(std::int64_t t_ns) {
  const double hs = hand_.substep_s;
  const double m = hand_.handle_mass, I = hand_.handle_inertia;
  while (t_ns_ < t_ns) {
    const double h = std::min(hs, 1e-9 * static_cast<double>(t_ns - t_ns_));
    const double t = script_time_s();
    // Script pose and velocity (central difference of the smooth script).
    const double e = 1e-4;
    const Pose Xs = ScriptPose(script_, t + h);
    const Pose Xa = ScriptPose(script_, t + h - e), Xb = ScriptPose(script_, t + h + e);
    const Vec3 vs = (Xb.t - Xa.t) / (2 * e);
    const Vec3 ws = internal::LogRotation(Xb.R * Xa.R.transpose()) / (2 * e);
    // Translation: semi-implicit in the springs and dampers (stable at any
    // substep), explicit in the held command.
    const double kh = hand_.hand_stiffness, bh = hand_.hand_damping, b = hand_.handle_damping;
    const Vec3 f = kh * (Xs.t - X_DH_.t) + bh * vs + cmd_.force;
    const Vec3 v_new = (m * v_ + h * f) / (m + h * (b + bh) + h * h * kh);
    const Vec3 dp = h * v_new;
    // Rotation about the handle origin, same scheme.
    const double kr = hand_.hand_ang_stiffness, br = hand_.hand_ang_damping;
    const double bra = hand_.handle_ang_damping;
    const Vec3 tau = kr * internal::LogRotation(Xs.R * X_DH_.R.transpose()) + br * ws + cmd_.torque;
    const Vec3 w_new = (I * w_ + h * tau) / (I + h * (bra + br) + h * h * kr);
    energy_j_ += cmd_.force.dot(dp) + cmd_.torque.dot(h * w_new);
    v_ = v_new;
    w_ = w_new;
    X_DH_.t += dp;
    X_DH_.R = internal::Orthonormalize(internal::ExpRotation(h * w_) * X_DH_.R);
    t_ns_ += static_cast<std::int64_t>(std::llround(h * 1e9));
  }
}

DeviceStatus SimulatedDevice::Read(DeviceState* state) {
  if (!open_) return DeviceStatus::kNotOpen;
  AdvanceTo(clock_->NowNs());
  state->X_DH = X_DH_;
  state->v_DH_D = v_;
  state->w_DH_D = w_;
  state->buttons = 0;
  state->time_ns = t_ns_;
  return DeviceStatus::kOk;
}

DeviceStatus SimulatedDevice::Command(const Wrench& F_H_D) {
  if (!open_) return DeviceStatus::kNotOpen;
  cmd_.force = internal::ClampNorm(F_H_D.force, info_.max_force);
  cmd_.torque = internal::ClampNorm(F_H_D.torque, info_.max_torque);
  return DeviceStatus::kOk;
}

}  // namespace hapticpd::device
