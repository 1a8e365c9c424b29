// The haptic device abstraction (CHAI3D's cGenericHapticDevice, reduced to
// what the servo loop needs) and the monotonic clock every device and the
// servo loop share.
//
// Frames: D is the device's base frame (its workspace), H the handle frame.
// A device reports X_DH and the handle's spatial velocity in D, and takes a
// wrench on the handle expressed in D with the torque about the handle
// origin. Units are SI (m, kg, s, N, N m). The servo loop maps D into the
// scene's world W with a fixed X_WD (ServoConfig).
#pragma once

#include <cstdint>
#include <string>

#include "pd/types.h"

namespace hapticpd::device {

using hapticpd::Mat3;
using hapticpd::Mat6;
using hapticpd::Pose;
using hapticpd::Quat;
using hapticpd::Vec3;
using hapticpd::Vec6;
using hapticpd::Wrench;

/// A monotonic clock in integer nanoseconds. Real-time runs use SteadyClock
/// (CLOCK_MONOTONIC); tests use ManualClock so nothing depends on wall time.
class Clock {
 public:
  virtual ~Clock() = default;
  virtual std::int64_t NowNs() const = 0;
};

/// std::chrono::steady_clock (CLOCK_MONOTONIC on Linux).
class SteadyClock final : public Clock {
 public:
  std::int64_t NowNs() const override;
  static const SteadyClock& Instance();
};

/// A clock a test advances by hand.
class ManualClock final : public Clock {
 public:
  explicit ManualClock(std::int64_t start_ns = 0) : now_ns_(start_ns) {}
  std::int64_t NowNs() const override { return now_ns_; }
  void Set(std::int64_t ns) { now_ns_ = ns; }
  void Advance(std::int64_t ns) { now_ns_ += ns; }

 private:
  std::int64_t now_ns_;
};

/// Static description of a device (CHAI3D's cHapticDeviceInfo). Limits are
/// the closed-loop values at 1 kHz the manufacturer (or CHAI3D) certifies;
/// the servo loop picks its coupling gains inside them.
struct DeviceInfo {
  std::string name;
  int dof_sensed = 6;                           ///< 3 (position) or 6 (position + orientation)
  int dof_actuated = 6;                         ///< 3 (force) or 6 (force + torque)
  double max_force = 0;                         ///< N, continuous
  double max_torque = 0;                        ///< N m (0 when torque is not actuated)
  double max_linear_stiffness = 0;              ///< N/m, stable closed-loop stiffness at 1 kHz
  double max_angular_stiffness = 0;             ///< N m/rad
  double max_linear_damping = 0;                ///< N s/m
  double max_angular_damping = 0;               ///< N m s/rad
  Vec3 workspace_min_D = Vec3::Constant(-0.1);  ///< m, handle reach (axis-aligned box in D)
  Vec3 workspace_max_D = Vec3::Constant(0.1);
  int buttons = 0;  ///< number of user switches
};

/// One reading of the handle.
struct DeviceState {
  Pose X_DH;                   ///< handle pose in the device frame
  Vec3 v_DH_D = Vec3::Zero();  ///< m/s, handle origin velocity, in D
  Vec3 w_DH_D = Vec3::Zero();  ///< rad/s, handle angular velocity, in D
  std::uint32_t buttons = 0;   ///< bit i = switch i pressed
  std::int64_t time_ns = 0;    ///< device clock (the Clock the device was given)
};

enum class DeviceStatus : std::uint8_t {
  kOk,
  kNotOpen,    ///< Read/Command before Open or after Close
  kEndOfData,  ///< a replay reached its last sample (the state holds it)
  kError,      ///< the device reported a fault; `last_error()` says which
};

const char* ToString(DeviceStatus s);

/// The device interface. Open/Close are configuration calls (may block,
/// allocate, throw std::runtime_error with a reason). Read and Command are
/// called from the servo thread once per tick: they must not allocate, lock
/// or log, and report problems through DeviceStatus.
class HapticDevice {
 public:
  virtual ~HapticDevice() = default;
  virtual void Open() = 0;
  virtual void Close() = 0;
  virtual bool is_open() const = 0;
  virtual const DeviceInfo& info() const = 0;
  /// Samples the handle.
  virtual DeviceStatus Read(DeviceState* state) = 0;
  /// Commands a wrench on the handle (F_H_D: force and torque about the
  /// handle origin, in D), held until the next Command. The caller clamps it
  /// to info() limits; implementations clamp again (safety).
  virtual DeviceStatus Command(const Wrench& F_H_D) = 0;
  /// The reason of the last kError (configuration thread only).
  virtual std::string last_error() const { return {}; }
};

}  // namespace hapticpd::device
