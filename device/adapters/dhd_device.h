// Force Dimension devices (omega.x, sigma.x, delta.x) through the DHD SDK.
// Compiled only when the SDK is found (device/adapters/CMakeLists.txt).
#pragma once

#include "device/haptic_device.h"

namespace hapticpd::device {

/// The first Force Dimension device on the bus. Limits are CHAI3D's
/// closed-loop values for the detected model (sigma.7 when unknown).
class DhdDevice final : public HapticDevice {
 public:
  explicit DhdDevice(const Clock* clock = &SteadyClock::Instance()) : clock_(clock) {}
  ~DhdDevice() override { Close(); }
  void Open() override;
  void Close() override;
  bool is_open() const override { return id_ >= 0; }
  const DeviceInfo& info() const override { return info_; }
  DeviceStatus Read(DeviceState* state) override;
  DeviceStatus Command(const Wrench& F_H_D) override;
  std::string last_error() const override { return error_; }

 private:
  const Clock* clock_;
  DeviceInfo info_;
  int id_ = -1;
  std::string error_;
};

}  // namespace hapticpd::device
