// 3D Systems devices (Touch, Touch X, Phantom Premium) through the
// OpenHaptics HD API. Compiled only when the SDK is found
// (device/adapters/CMakeLists.txt); it has not been compiled or run here.
//
// The HD API owns the device's servo thread (the "scheduler"): device state
// may only be read, and forces set, inside an hdBeginFrame/hdEndFrame pair in
// a scheduler callback. The adapter runs one asynchronous callback
// (hdScheduleAsynchronous) that, every scheduler tick, reads the handle state
// into a LatestMailbox and applies the newest commanded wrench from another
// one, so Read() and Command() on the ServoLoop's thread are wait-free and
// never call the HD API (no lock, no allocation, no logging there).
#pragma once

#include <atomic>
#include <string>
#include <utility>

#include "device/haptic_device.h"
#include "device/mailbox.h"

namespace hapticpd::device {

/// The default OpenHaptics device ("Default Device" in Touch Setup), or the
/// named one. Units: the HD API's millimetres and newtons (torque in
/// newton-millimetres) are converted to SI here. Limits are CHAI3D's
/// closed-loop values for a Phantom Touch class device, replaced by the
/// device's own nominal figures (HD_NOMINAL_MAX_*) where it reports them.
class OpenHapticsDevice final : public HapticDevice {
 public:
  explicit OpenHapticsDevice(std::string name = {}, const Clock* clock = &SteadyClock::Instance())
      : name_(std::move(name)), clock_(clock) {}
  ~OpenHapticsDevice() override { Close(); }
  void Open() override;
  void Close() override;
  bool is_open() const override { return open_; }
  const DeviceInfo& info() const override { return info_; }
  DeviceStatus Read(DeviceState* state) override;
  DeviceStatus Command(const Wrench& F_H_D) override;
  std::string last_error() const override { return error_; }

  /// Scheduler side (the HD servo thread): one frame. Public for the C
  /// callback only.
  void SchedulerTick();

 private:
  struct Sample {
    DeviceState state;
    bool ok = false;
  };
  std::string name_;
  const Clock* clock_;
  DeviceInfo info_;
  std::string error_;
  bool open_ = false;
  unsigned int handle_ = 0;          // HHD
  unsigned long callback_ = 0;       // HDSchedulerHandle
  LatestMailbox<Sample> state_out_;  // scheduler -> Read()
  LatestMailbox<Wrench> wrench_in_;  // Command() -> scheduler
  Wrench applied_;                   // scheduler's current wrench
  std::atomic<bool> fault_{false};   // an HD error inside the scheduler
};

}  // namespace hapticpd::device
