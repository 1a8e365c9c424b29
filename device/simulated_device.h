// A simulated haptic device: the handle plus the hand holding it, integrated
// at a fine step between servo ticks (../shared/docs/HAPTICS.md "How we
// measure it"). The handle is a rigid body (mass, isotropic inertia, viscous
// damping to the ground: the device's own friction) pulled by the hand, a
// spring-damper towards a scripted trajectory, and pushed by the commanded
// wrench, held constant between Command calls (zero-order hold) like a real
// amplifier. It integrates lazily up to the clock's time on every Read, so
// it runs in real time on SteadyClock and deterministically on ManualClock.
// It also accounts exactly for the work the commanded wrench did on the
// handle (energy into the hand).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "device/haptic_device.h"

namespace hapticpd::device {

/// The scripted hand trajectories. All are relative to the start pose S
/// (its axes: "down" is -z_S, "sideways" +x_S, the probe axis z_S) and are
/// smooth (C1) with zero velocity at both ends.
enum class HandScript : std::uint8_t {
  kHold,    ///< stay at the start pose
  kPress,   ///< down by `travel` and back up
  kSlide,   ///< down by `travel`, sideways by `lateral` along +x_S, up
  kTwist,   ///< down by `travel`, rotate by `angle` about z_S and back, up
  kCircle,  ///< a vertical circle in the x_S-z_S plane through S, radius `radius`, lowest 2r below
            ///< S
  kLoop,    ///< a closed 3-D path with some rotation that returns to S
  kPlate,   ///< down by `travel` (through a thin plate), hold, back up
};

const char* ToString(HandScript s);
/// Parses "hold", "press", "slide", "twist", "circle", "loop", "plate";
/// throws std::invalid_argument naming the valid ones otherwise.
HandScript ParseHandScript(const std::string& name);

struct ScriptParams {
  HandScript script = HandScript::kPress;
  Pose X_DS;              ///< start pose S in the device frame
  double duration_s = 3;  ///< the script's length; afterwards the hand holds its end pose
  double travel = 0.02;   ///< m
  double lateral = 0.04;  ///< m
  double angle = 0.6;     ///< rad
  double radius = 0.01;   ///< m
  /// s the hand holds the start pose before the script begins (a user
  /// waiting for the link to come up before reaching for the scene).
  double hold_s = 0;
};

/// The hand's target pose X_DS(t) (t in seconds from the start).
Pose ScriptPose(const ScriptParams& p, double t_s);

struct HandModel {
  double handle_mass = 0.3;          ///< kg
  double handle_inertia = 2e-4;      ///< kg m^2
  double handle_damping = 3.0;       ///< N s/m to the ground
  double handle_ang_damping = 0.01;  ///< N m s/rad
  double hand_stiffness = 300;       ///< N/m towards the script
  double hand_damping = 2.0;         ///< N s/m relative to the script's velocity
  double hand_ang_stiffness = 0.5;   ///< N m/rad
  double hand_ang_damping = 0.005;   ///< N m s/rad
  double substep_s = 2.5e-4;         ///< integration step
};

/// A 6-DoF device with limits between a Phantom Premium 6DOF and a sigma.7:
/// F 12 N, tau 0.2 N m, K 2000 N/m, 1 N m/rad, B 1.5 N s/m, 0.005 N m s/rad.
/// Its physical damping (HandModel) satisfies Colgate's condition at 1 kHz
/// for any gains inside these limits.
DeviceInfo SimulatedDeviceInfo();

/// A start pose centred above an axis-aligned box (a scene's bounds):
/// identity orientation, `clearance` above its top face.
Pose StartPoseAbove(const Vec3& aabb_min, const Vec3& aabb_max, double clearance);

class SimulatedDevice final : public HapticDevice {
 public:
  SimulatedDevice(const ScriptParams& script, const Clock* clock, const HandModel& hand = {},
                  const DeviceInfo& info = SimulatedDeviceInfo());

  void Open() override;
  void Close() override { open_ = false; }
  bool is_open() const override { return open_; }
  const DeviceInfo& info() const override { return info_; }
  DeviceStatus Read(DeviceState* state) override;
  DeviceStatus Command(const Wrench& F_H_D) override;

  /// Work (J) done on the handle by the commanded wrench since Open: the
  /// energy the device put into the hand.
  double energy_into_hand_j() const { return energy_j_; }
  /// Seconds of script time elapsed since Open.
  double script_time_s() const;
  bool script_done() const { return script_time_s() >= script_.duration_s; }
  const ScriptParams& script() const { return script_; }
  /// The hand's current target (for traces).
  Pose hand_target() const { return ScriptPose(script_, script_time_s()); }

 private:
  void AdvanceTo(std::int64_t t_ns);

  ScriptParams script_;
  const Clock* clock_;
  HandModel hand_;
  DeviceInfo info_;
  bool open_ = false;
  std::int64_t t0_ns_ = 0;
  std::int64_t t_ns_ = 0;
  Pose X_DH_;
  Vec3 v_ = Vec3::Zero();
  Vec3 w_ = Vec3::Zero();
  Wrench cmd_;
  double energy_j_ = 0;
};

}  // namespace hapticpd::device
