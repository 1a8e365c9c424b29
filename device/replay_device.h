// Recording and replaying device trajectories.
//
// CSV format, one line per servo tick. Version 1 ("hapticpd device
// trajectory v1") holds what the device read and was commanded:
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
//
// Version 2 ("hapticpd device trajectory v2", what `hapticpd device
// --record` writes) adds what a replay needs to show the session
// (`hapticpd view --replay`): `# key: value` header lines (device, scene,
// server, probe, mode, X_WD and X_PA as "px py pz qw qx qy qz"; start_ns,
// the device clock's reading at t_s = 0 in ns, CLOCK_MONOTONIC for
// `hapticpd device`, to line a recording up with other processes' events;
// unknown keys are kept and ignored) and, per tick, after the 21 columns above:
//
//   ...,ax,ay,az,aqw,aqx,aqy,aqz,source,rows
//
// a: the probe's mesh frame (the proxy, X_WA) in the world W; source: the
// model the tick's contact came from (TickSource: 1 the server, 2 the local
// patch, 3 none or faded); rows: the IR's contact rows touching at the proxy (at most
// kMaxRecordedRows, the deepest), each "x y z nx ny nz depth" (contact point
// and unit normal in W, depth at the proxy in m), separated by ';' (empty:
// none). Both versions load with LoadTrajectoryCsv (the trajectory) and
// LoadRecording (everything).
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "device/haptic_device.h"
#include "device/servo_loop.h"

namespace hapticpd::device {

struct TrajectorySample {
  double t_s = 0;
  DeviceState state;
  Wrench F_cmd_D;
};

/// Most contact rows a recorded tick keeps (the deepest at the proxy).
inline constexpr int kMaxRecordedRows = 8;

struct RecordedRow {
  Vec3 p_W = Vec3::Zero();  ///< contact point (W)
  Vec3 n_W = Vec3::Zero();  ///< unit normal, from the body towards the probe
  double depth = 0;         ///< m, at the proxy pose
};

/// What version 2 adds to a tick: the proxy and its contacts.
struct RecordedTick {
  Pose X_WA;                ///< the probe's mesh frame (the proxy) in W
  std::uint8_t source = 3;  ///< TickSource (1 server, 2 local, 3 none or faded)
  int num_rows = 0;
  std::array<RecordedRow, kMaxRecordedRows> rows{};
};

struct Recording {
  int version = 1;
  /// `# key: value` header lines (v2; v1 has "device" only).
  std::vector<std::pair<std::string, std::string>> header;
  std::vector<TrajectorySample> samples;
  /// One per sample (v2), empty for v1.
  std::vector<RecordedTick> ticks;
  /// The value of a header key, or "" when absent.
  std::string Header(const std::string& key) const;
};

/// Loads a v1 or v2 recording; throws std::runtime_error naming the file
/// and line on a malformed file (bad header, wrong column count, non-finite
/// number, decreasing time, non-unit quaternion, a malformed row).
Recording LoadRecording(const std::filesystem::path& path);
/// Formats a pose as a header value, "px py pz qw qx qy qz"; ParsePoseValue
/// reads it back (throws std::invalid_argument naming the problem).
std::string PoseValue(const Pose& X);
Pose ParsePoseValue(const std::string& value);

/// The trajectory of a v1 or v2 recording (LoadRecording(path).samples).
std::vector<TrajectorySample> LoadTrajectoryCsv(const std::filesystem::path& path);
/// Writes samples in the format above; throws std::runtime_error on I/O errors.
void WriteTrajectoryCsv(const std::filesystem::path& path, const std::string& device_name,
                        const std::vector<TrajectorySample>& samples);

/// Records what a device reads and is commanded by wrapping it (decorator):
/// Read/Command forward to the wrapped device and append to a buffer
/// reserved up front (no allocation on the servo thread; samples past the
/// capacity are dropped and counted). Set as the loop's
/// ServoConfig::recorder it also keeps each tick's proxy and contact rows,
/// and Save() writes version 2 with the header given to SetHeader. Write
/// the file with Save() once the loop has stopped.
class RecordingDevice final : public HapticDevice, public TickRecorder {
 public:
  RecordingDevice(HapticDevice* inner, std::size_t capacity_samples);
  /// Header lines for version 2 (e.g. {"scene", "default"}); call before
  /// the loop starts.
  void SetHeader(std::vector<std::pair<std::string, std::string>> header) {
    header_ = std::move(header);
  }
  void OnTick(const TickRecord& r, const ProxySample& s, const IntermediateRep* ir) override;
  const std::vector<RecordedTick>& ticks() const { return ticks_; }
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
  std::vector<RecordedTick> ticks_;
  std::vector<std::pair<std::string, std::string>> header_;
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
