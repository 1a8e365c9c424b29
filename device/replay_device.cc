#include "device/replay_device.h"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include "device/simulated_device.h"

namespace hapticpd::device {

namespace {
constexpr const char* kMagic = "# hapticpd device trajectory v1";
constexpr const char* kColumns =
    "t_s,px,py,pz,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz,buttons,fx,fy,fz,tx,ty,tz";
constexpr int kNumColumns = 21;

[[noreturn]] void Fail(const std::filesystem::path& path, int line, const std::string& why) {
  throw std::runtime_error(path.string() + ":" + std::to_string(line) + ": " + why);
}
}  // namespace

std::vector<TrajectorySample> LoadTrajectoryCsv(const std::filesystem::path& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path.string() + ": cannot open trajectory file");
  std::vector<TrajectorySample> out;
  std::string line;
  int lineno = 0;
  bool magic = false, header = false;
  while (std::getline(in, line)) {
    ++lineno;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) continue;
    if (line[0] == '#') {
      if (line.rfind(kMagic, 0) == 0) magic = true;
      continue;
    }
    if (!header) {
      if (!magic) Fail(path, lineno, std::string("missing '") + kMagic + "' line");
      if (line != kColumns) Fail(path, lineno, std::string("expected header '") + kColumns + "'");
      header = true;
      continue;
    }
    double v[kNumColumns];
    std::istringstream ss(line);
    std::string cell;
    int n = 0;
    while (std::getline(ss, cell, ',')) {
      if (n >= kNumColumns) Fail(path, lineno, "too many columns");
      char* end = nullptr;
      v[n] = std::strtod(cell.c_str(), &end);
      if (end == cell.c_str() || *end != '\0' || !std::isfinite(v[n])) {
        Fail(path, lineno, "column " + std::to_string(n + 1) + " is not a finite number");
      }
      ++n;
    }
    if (n != kNumColumns) {
      Fail(path, lineno,
           "expected " + std::to_string(kNumColumns) + " columns, got " + std::to_string(n));
    }
    TrajectorySample s;
    s.t_s = v[0];
    if (!out.empty() && s.t_s < out.back().t_s) Fail(path, lineno, "time decreases");
    const Quat q(v[4], v[5], v[6], v[7]);
    if (std::abs(q.norm() - 1) > 1e-3) Fail(path, lineno, "quaternion is not unit");
    s.state.X_DH = Pose::FromQuaternion(q, Vec3(v[1], v[2], v[3]));
    s.state.v_DH_D = Vec3(v[8], v[9], v[10]);
    s.state.w_DH_D = Vec3(v[11], v[12], v[13]);
    if (v[14] < 0 || v[14] != std::floor(v[14])) Fail(path, lineno, "buttons is not a mask");
    s.state.buttons = static_cast<std::uint32_t>(v[14]);
    s.state.time_ns = std::llround(s.t_s * 1e9);
    s.F_cmd_D.force = Vec3(v[15], v[16], v[17]);
    s.F_cmd_D.torque = Vec3(v[18], v[19], v[20]);
    out.push_back(s);
  }
  if (!header) Fail(path, lineno, "no header line");
  if (out.empty()) Fail(path, lineno, "no samples");
  return out;
}

void WriteTrajectoryCsv(const std::filesystem::path& path, const std::string& device_name,
                        const std::vector<TrajectorySample>& samples) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (!f) throw std::runtime_error(path.string() + ": cannot write trajectory file");
  std::fprintf(f, "%s\n# device: %s\n%s\n", kMagic, device_name.c_str(), kColumns);
  for (const TrajectorySample& s : samples) {
    const Quat q = s.state.X_DH.Rotation().normalized();
    const Vec3& p = s.state.X_DH.t;
    const Vec3& v = s.state.v_DH_D;
    const Vec3& w = s.state.w_DH_D;
    const Vec3& F = s.F_cmd_D.force;
    const Vec3& T = s.F_cmd_D.torque;
    std::fprintf(f,
                 "%.9f,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%u,"
                 "%.9g,%.9g,%.9g,%.9g,%.9g,%.9g\n",
                 s.t_s, p.x(), p.y(), p.z(), q.w(), q.x(), q.y(), q.z(), v.x(), v.y(), v.z(), w.x(),
                 w.y(), w.z(), s.state.buttons, F.x(), F.y(), F.z(), T.x(), T.y(), T.z());
  }
  const bool ok = std::ferror(f) == 0;
  if (std::fclose(f) != 0 || !ok) {
    throw std::runtime_error(path.string() + ": error writing trajectory file");
  }
}

RecordingDevice::RecordingDevice(HapticDevice* inner, std::size_t capacity_samples)
    : inner_(inner) {
  samples_.reserve(capacity_samples);
}

DeviceStatus RecordingDevice::Read(DeviceState* state) {
  const DeviceStatus s = inner_->Read(state);
  if (s != DeviceStatus::kOk && s != DeviceStatus::kEndOfData) return s;
  if (samples_.size() == samples_.capacity()) {
    ++dropped_;
    pending_ = false;
    return s;
  }
  if (samples_.empty()) t0_ns_ = state->time_ns;
  TrajectorySample& r = samples_.emplace_back();
  r.t_s = 1e-9 * static_cast<double>(state->time_ns - t0_ns_);
  r.state = *state;
  pending_ = true;
  return s;
}

DeviceStatus RecordingDevice::Command(const Wrench& F_H_D) {
  if (pending_) {
    samples_.back().F_cmd_D = F_H_D;
    pending_ = false;
  }
  return inner_->Command(F_H_D);
}

void RecordingDevice::Save(const std::filesystem::path& path) const {
  WriteTrajectoryCsv(path, inner_->info().name, samples_);
}

ReplayDevice::ReplayDevice(std::vector<TrajectorySample> samples, const Clock* clock, bool loop,
                           const DeviceInfo& info)
    : samples_(std::move(samples)), clock_(clock), loop_(loop), info_(info) {
  if (samples_.empty()) throw std::runtime_error("replay: empty trajectory");
  if (info_.max_force <= 0) info_ = SimulatedDeviceInfo();  // limits for the coupling
  info_.name = "replay";
}

ReplayDevice::ReplayDevice(const std::filesystem::path& path, const Clock* clock, bool loop)
    : ReplayDevice(LoadTrajectoryCsv(path), clock, loop) {
  info_.name = "replay of " + path.filename().string();
}

void ReplayDevice::Open() {
  open_ = true;
  t0_ns_ = clock_->NowNs();
  cursor_ = 0;
  last_cmd_ = Wrench{};
}

DeviceStatus ReplayDevice::Read(DeviceState* state) {
  if (!open_) return DeviceStatus::kNotOpen;
  const std::int64_t now = clock_->NowNs();
  double t = 1e-9 * static_cast<double>(now - t0_ns_);
  const double T = duration_s();
  DeviceStatus status = DeviceStatus::kOk;
  if (t >= T) {
    if (loop_ && T > 0) {
      t = std::fmod(t, T);
      if (t < samples_[cursor_].t_s) cursor_ = 0;
    } else {
      *state = samples_.back().state;
      state->time_ns = now;
      return DeviceStatus::kEndOfData;
    }
  }
  while (cursor_ + 1 < samples_.size() && samples_[cursor_ + 1].t_s <= t) ++cursor_;
  const TrajectorySample& a = samples_[cursor_];
  const TrajectorySample& b = samples_[std::min(cursor_ + 1, samples_.size() - 1)];
  const double span = b.t_s - a.t_s;
  const double u = span > 0 ? std::clamp((t - a.t_s) / span, 0.0, 1.0) : 0.0;
  state->X_DH.t = (1 - u) * a.state.X_DH.t + u * b.state.X_DH.t;
  state->X_DH.R =
      a.state.X_DH.Rotation().slerp(u, b.state.X_DH.Rotation()).normalized().toRotationMatrix();
  state->v_DH_D = (1 - u) * a.state.v_DH_D + u * b.state.v_DH_D;
  state->w_DH_D = (1 - u) * a.state.w_DH_D + u * b.state.w_DH_D;
  state->buttons = a.state.buttons;
  state->time_ns = now;
  return status;
}

DeviceStatus ReplayDevice::Command(const Wrench& F_H_D) {
  if (!open_) return DeviceStatus::kNotOpen;
  last_cmd_ = F_H_D;
  return DeviceStatus::kOk;
}

}  // namespace hapticpd::device
