#include "device/replay_device.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include "device/math.h"
#include "device/simulated_device.h"

namespace hapticpd::device {

namespace {
constexpr const char* kMagicV1 = "# hapticpd device trajectory v1";
constexpr const char* kMagicV2 = "# hapticpd device trajectory v2";
constexpr const char* kColumns =
    "t_s,px,py,pz,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz,buttons,fx,fy,fz,tx,ty,tz";
constexpr const char* kColumnsV2Extra = ",ax,ay,az,aqw,aqx,aqy,aqz,source,rows";
constexpr int kNumColumns = 21;
constexpr int kNumColumnsV2 = 30;

[[noreturn]] void Fail(const std::filesystem::path& path, int line, const std::string& why) {
  throw std::runtime_error(path.string() + ":" + std::to_string(line) + ": " + why);
}

/// Whitespace-separated finite numbers; false on anything else.
bool ParseNumbers(const std::string& text, double* out, int count) {
  std::istringstream ss(text);
  for (int i = 0; i < count; ++i) {
    std::string tok;
    if (!(ss >> tok)) return false;
    char* end = nullptr;
    out[i] = std::strtod(tok.c_str(), &end);
    if (end == tok.c_str() || *end != '\0' || !std::isfinite(out[i])) return false;
  }
  std::string extra;
  return !(ss >> extra);
}

Pose PoseOrThrow(const double* v, const char* what) {
  const Quat q(v[3], v[4], v[5], v[6]);
  if (!IsUnitQuaternion(q))
    throw std::invalid_argument(std::string(what) + ": quaternion is not unit");
  return Pose::FromQuaternion(q.normalized(), Vec3(v[0], v[1], v[2]));
}

void ParseRows(const std::string& cell, RecordedTick* t) {
  t->num_rows = 0;
  std::size_t start = 0;
  while (start < cell.size()) {
    std::size_t end = cell.find(';', start);
    if (end == std::string::npos) end = cell.size();
    if (t->num_rows >= kMaxRecordedRows) {
      throw std::invalid_argument("more than " + std::to_string(kMaxRecordedRows) + " rows");
    }
    double v[7];
    if (!ParseNumbers(cell.substr(start, end - start), v, 7)) {
      throw std::invalid_argument("row " + std::to_string(t->num_rows + 1) +
                                  " is not 7 finite numbers 'x y z nx ny nz depth'");
    }
    RecordedRow& r = t->rows[static_cast<std::size_t>(t->num_rows++)];
    r.p_W = Vec3(v[0], v[1], v[2]);
    r.n_W = Vec3(v[3], v[4], v[5]);
    r.depth = v[6];
    start = end + 1;
  }
}
}  // namespace

std::string Recording::Header(const std::string& key) const {
  for (const auto& [k, v] : header) {
    if (k == key) return v;
  }
  return "";
}

std::string PoseValue(const Pose& X) {
  const Quat q = X.Rotation().normalized();
  char buf[256];
  std::snprintf(buf, sizeof buf, "%.9g %.9g %.9g %.9g %.9g %.9g %.9g", X.t.x(), X.t.y(), X.t.z(),
                q.w(), q.x(), q.y(), q.z());
  return buf;
}

Pose ParsePoseValue(const std::string& value) {
  double v[7];
  if (!ParseNumbers(value, v, 7)) {
    throw std::invalid_argument("expected 7 finite numbers 'px py pz qw qx qy qz', got '" + value +
                                "'");
  }
  return PoseOrThrow(v, "pose");
}

Recording LoadRecording(const std::filesystem::path& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path.string() + ": cannot open trajectory file");
  Recording out;
  std::string line;
  int lineno = 0;
  bool magic = false, header = false;
  while (std::getline(in, line)) {
    ++lineno;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) continue;
    if (line[0] == '#') {
      if (line.rfind(kMagicV1, 0) == 0) {
        magic = true;
        out.version = 1;
      } else if (line.rfind(kMagicV2, 0) == 0) {
        magic = true;
        out.version = 2;
      } else if (magic && !header) {
        const std::size_t colon = line.find(": ");
        if (colon != std::string::npos && colon > 2) {
          out.header.emplace_back(line.substr(2, colon - 2), line.substr(colon + 2));
        }
      }
      continue;
    }
    const int columns = out.version == 2 ? kNumColumnsV2 : kNumColumns;
    if (!header) {
      if (!magic) Fail(path, lineno, std::string("missing '") + kMagicV2 + "' (or v1) line");
      const std::string want =
          out.version == 2 ? std::string(kColumns) + kColumnsV2Extra : std::string(kColumns);
      if (line != want) Fail(path, lineno, "expected header '" + want + "'");
      header = true;
      continue;
    }
    double v[kNumColumnsV2];
    std::string rows_cell;
    std::size_t pos = 0;
    int n = 0;
    while (pos <= line.size()) {
      std::size_t comma = line.find(',', pos);
      if (comma == std::string::npos) comma = line.size();
      if (n >= columns) Fail(path, lineno, "too many columns");
      const std::string cell = line.substr(pos, comma - pos);
      if (out.version == 2 && n == kNumColumnsV2 - 1) {
        rows_cell = cell;
      } else {
        char* end = nullptr;
        v[n] = std::strtod(cell.c_str(), &end);
        if (end == cell.c_str() || *end != '\0' || !std::isfinite(v[n])) {
          Fail(path, lineno, "column " + std::to_string(n + 1) + " is not a finite number");
        }
      }
      ++n;
      pos = comma + 1;
    }
    if (n != columns) {
      Fail(path, lineno,
           "expected " + std::to_string(columns) + " columns, got " + std::to_string(n));
    }
    TrajectorySample s;
    s.t_s = v[0];
    if (!out.samples.empty() && s.t_s < out.samples.back().t_s)
      Fail(path, lineno, "time decreases");
    const Quat q(v[4], v[5], v[6], v[7]);
    if (!IsUnitQuaternion(q)) Fail(path, lineno, "quaternion is not unit (norm within 1e-3 of 1)");
    s.state.X_DH = Pose::FromQuaternion(q, Vec3(v[1], v[2], v[3]));
    s.state.v_DH_D = Vec3(v[8], v[9], v[10]);
    s.state.w_DH_D = Vec3(v[11], v[12], v[13]);
    if (v[14] < 0 || v[14] != std::floor(v[14])) Fail(path, lineno, "buttons is not a mask");
    s.state.buttons = static_cast<std::uint32_t>(v[14]);
    s.state.time_ns = std::llround(s.t_s * 1e9);
    s.F_cmd_D.force = Vec3(v[15], v[16], v[17]);
    s.F_cmd_D.torque = Vec3(v[18], v[19], v[20]);
    out.samples.push_back(s);
    if (out.version == 2) {
      RecordedTick t;
      try {
        t.X_WA = PoseOrThrow(v + 21, "the proxy pose (columns 22-28)");
        if (v[28] < 1 || v[28] > 3 || v[28] != std::floor(v[28])) {
          throw std::invalid_argument("source is not 1, 2 or 3");
        }
        t.source = static_cast<std::uint8_t>(v[28]);
        ParseRows(rows_cell, &t);
      } catch (const std::invalid_argument& e) {
        Fail(path, lineno, e.what());
      }
      out.ticks.push_back(t);
    }
  }
  if (!header) Fail(path, lineno, "no header line");
  if (out.samples.empty()) Fail(path, lineno, "no samples");
  return out;
}

std::vector<TrajectorySample> LoadTrajectoryCsv(const std::filesystem::path& path) {
  return LoadRecording(path).samples;
}

namespace {
void WriteSampleColumns(std::FILE* f, const TrajectorySample& s) {
  const Quat q = s.state.X_DH.Rotation().normalized();
  const Vec3& p = s.state.X_DH.t;
  const Vec3& v = s.state.v_DH_D;
  const Vec3& w = s.state.w_DH_D;
  const Vec3& F = s.F_cmd_D.force;
  const Vec3& T = s.F_cmd_D.torque;
  std::fprintf(f,
               "%.9f,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%u,"
               "%.9g,%.9g,%.9g,%.9g,%.9g,%.9g",
               s.t_s, p.x(), p.y(), p.z(), q.w(), q.x(), q.y(), q.z(), v.x(), v.y(), v.z(), w.x(),
               w.y(), w.z(), s.state.buttons, F.x(), F.y(), F.z(), T.x(), T.y(), T.z());
}

void CloseOrThrow(std::FILE* f, const std::filesystem::path& path) {
  const bool ok = std::ferror(f) == 0;
  if (std::fclose(f) != 0 || !ok) {
    throw std::runtime_error(path.string() + ": error writing trajectory file");
  }
}
}  // namespace

void WriteTrajectoryCsv(const std::filesystem::path& path, const std::string& device_name,
                        const std::vector<TrajectorySample>& samples) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (!f) throw std::runtime_error(path.string() + ": cannot write trajectory file");
  std::fprintf(f, "%s\n# device: %s\n%s\n", kMagicV1, device_name.c_str(), kColumns);
  for (const TrajectorySample& s : samples) {
    WriteSampleColumns(f, s);
    std::fputc('\n', f);
  }
  CloseOrThrow(f, path);
}

RecordingDevice::RecordingDevice(HapticDevice* inner, std::size_t capacity_samples)
    : inner_(inner) {
  samples_.reserve(capacity_samples);
  ticks_.reserve(capacity_samples);
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

void RecordingDevice::OnTick(const TickRecord& r, const ProxySample& s, const IntermediateRep* ir) {
  (void)r;
  // One tick per sample Read kept (none when it was dropped or failed).
  if (ticks_.size() >= samples_.size() || ticks_.size() == ticks_.capacity()) return;
  RecordedTick& t = ticks_.emplace_back();
  t.X_WA = s.X_WA;
  t.source = static_cast<std::uint8_t>(r.source);
  if (ir == nullptr || ir->use_target) return;
  // The rows touching at the proxy, the deepest kept.
  const Vec3 dp = s.X_WP.t - ir->X_WP_ref.t;
  const Vec3 dth = internal::LogRotation(s.X_WP.R * ir->X_WP_ref.R.transpose());
  for (int i = 0; i < ir->num_rows; ++i) {
    const IrRow& row = ir->rows[static_cast<std::size_t>(i)];
    const double depth = row.depth - row.n_W.dot(dp) - row.m_W.dot(dth);
    if (depth <= 0) continue;
    RecordedRow rr{row.p_W, row.n_W, depth};
    if (t.num_rows < kMaxRecordedRows) {
      t.rows[static_cast<std::size_t>(t.num_rows++)] = rr;
      continue;
    }
    auto shallowest = std::min_element(
        t.rows.begin(), t.rows.end(),
        [](const RecordedRow& a, const RecordedRow& b) { return a.depth < b.depth; });
    if (shallowest->depth < depth) *shallowest = rr;
  }
}

void RecordingDevice::Save(const std::filesystem::path& path) const {
  if (ticks_.empty()) {
    WriteTrajectoryCsv(path, inner_->info().name, samples_);
    return;
  }
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (!f) throw std::runtime_error(path.string() + ": cannot write trajectory file");
  std::fprintf(f, "%s\n# device: %s\n", kMagicV2, inner_->info().name.c_str());
  for (const auto& [k, v] : header_) std::fprintf(f, "# %s: %s\n", k.c_str(), v.c_str());
  std::fprintf(f, "# start_ns: %lld\n", static_cast<long long>(t0_ns_));
  std::fprintf(f, "%s%s\n", kColumns, kColumnsV2Extra);
  // Samples past the last tick (the loop stopped between Read and OnTick)
  // are left out so that every line has both.
  const std::size_t n = std::min(samples_.size(), ticks_.size());
  for (std::size_t i = 0; i < n; ++i) {
    WriteSampleColumns(f, samples_[i]);
    const RecordedTick& t = ticks_[i];
    const Quat q = t.X_WA.Rotation().normalized();
    std::fprintf(f, ",%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%u,", t.X_WA.t.x(), t.X_WA.t.y(),
                 t.X_WA.t.z(), q.w(), q.x(), q.y(), q.z(), static_cast<unsigned>(t.source));
    for (int k = 0; k < t.num_rows; ++k) {
      const RecordedRow& rr = t.rows[static_cast<std::size_t>(k)];
      std::fprintf(f, "%s%.6g %.6g %.6g %.6g %.6g %.6g %.6g", k > 0 ? ";" : "", rr.p_W.x(),
                   rr.p_W.y(), rr.p_W.z(), rr.n_W.x(), rr.n_W.y(), rr.n_W.z(), rr.depth);
    }
    std::fputc('\n', f);
  }
  CloseOrThrow(f, path);
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
