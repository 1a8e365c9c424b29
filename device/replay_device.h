// Recording and replaying device trajectories.
//
// CSV format ("hapticpd device trajectory v1"), one line per servo tick:
//
//   # hapticpd device trajectory v1
//   # device: <DeviceInfo::name>
//   t_s,px,py,pz,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz,buttons,fx,fy,fz,tx,ty,tz
//   0.000000000,0.0,0.0,0.12,1,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0
//
// t_s: seconds since the first sample (non-decreasing); p: handle position
// (m) and q: orientation (w, x, y, z, unit) in the device frame D; v, w:
// handle velocity (m/s, rad/s) in D; buttons: bit mask; f, t: the wrench
// commanded on the handle at that tick (N, N m, in D; zero when nothing was
// commanded). Lines starting with '#' are comments; the header line is
// required. Numbers are written with 9 significant digits after the point.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "device/haptic_device.h"

namespace hapticpd::device {

struct TrajectorySample {
  double t_s = 0;
  DeviceState state;
  Wrench F_cmd_D;
};

/// Loads a trajectory CSV; throws std::runtime_error naming the file and
/// line on a malformed file (bad header, wrong column count, non-finite
/// number, decreasing time, non-unit quaternion).
std::vector<TrajectorySample> LoadTrajectoryCsv(const std::filesystem::path& path);
/// Writes samples in the format above; throws std::runtime_error on I/O errors.
void WriteTrajectoryCsv(const std::filesystem::path& path, const std::string& device_name,
                        const std::vector<TrajectorySample>& samples);

/// Records what a device reads and is commanded by wrapping it (decorator):
/// Read/Command forward to the wrapped device and append to a buffer
/// reserved up front (no allocation on the servo thread; samples past the
/// capacity are dropped and counted). Write the file with Save() once the
/// loop has stopped.
class RecordingDevice final : public HapticDevice {
 public:
  RecordingDevice(HapticDevice* inner, std::size_t capacity_samples);
  void Open() override { inner_->Open(); }
  void Close() override { inner_->Close(); }
  bool is_open() const override { return inner_->is_open(); }
  const DeviceInfo& info() const override { return inner_->info(); }
  DeviceStatus Read(DeviceState* state) override;
  DeviceStatus Command(const Wrench& F_H_D) override;
  std::string last_error() const override { return inner_->last_error(); }

  const std::vector<TrajectorySample>& samples() const { return samples_; }
  std::uint64_t dropped() const { return dropped_; }
  void Save(const std::filesystem::path& path) const;

 private:
  HapticDevice* inner_;
  std::vector<TrajectorySample> samples_;
  std::int64_t t0_ns_ = 0;
  std::uint64_t dropped_ = 0;
  bool pending_ = false;  // the last sample awaits its command
};

/// Plays a recorded trajectory open-loop: Read returns the sample at the
/// clock's time since Open (position interpolated linearly, orientation by
/// slerp, velocities linearly, buttons of the earlier sample). Commands are
/// accepted and kept (last_command()) but do not move the handle. After the
/// last sample it holds it and reports kEndOfData (or wraps with `loop`).
/// Without `info` limits it reports SimulatedDeviceInfo()'s.
class ReplayDevice final : public HapticDevice {
 public:
  ReplayDevice(std::vector<TrajectorySample> samples, const Clock* clock, bool loop = false,
               const DeviceInfo& info = {});
  /// Loads `path` (throws like LoadTrajectoryCsv).
  ReplayDevice(const std::filesystem::path& path, const Clock* clock, bool loop = false);

  void Open() override;
  void Close() override { open_ = false; }
  bool is_open() const override { return open_; }
  const DeviceInfo& info() const override { return info_; }
  DeviceStatus Read(DeviceState* state) override;
  DeviceStatus Command(const Wrench& F_H_D) override;
  const Wrench& last_command() const { return last_cmd_; }
  double duration_s() const { return samples_.empty() ? 0 : samples_.back().t_s; }

 private:
  std::vector<TrajectorySample> samples_;
  const Clock* clock_;
  bool loop_;
  DeviceInfo info_;
  bool open_ = false;
  std::int64_t t0_ns_ = 0;
  std::size_t cursor_ = 0;
  Wrench last_cmd_;
};

}  // namespace hapticpd::device
