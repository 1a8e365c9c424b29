#include "device/adapters/openhaptics_device.h"

#include <HD/hd.h>

#include <algorithm>
#include <stdexcept>

namespace hapticpd::device {

namespace {

// HD units: mm, mm/s, N, N/mm, N s/mm, mN m.
constexpr double kMm = 1e-3;

std::string HdError(const char* what) {
  const HDErrorInfo e = hdGetError();
  if (!HD_DEVICE_ERROR(e)) return {};
  const char* text = hdGetErrorString(e.errorCode);
  return std::string("openhaptics: ") + what + ": " + (text ? text : "unknown error") + " (code " +
         std::to_string(e.errorCode) + ", internal " + std::to_string(e.internalErrorCode) + ")";
}

HDCallbackCode HDCALLBACK ServoCallback(void* user) {
  static_cast<OpenHapticsDevice*>(user)->SchedulerTick();
  return HD_CALLBACK_CONTINUE;
}

HDCallbackCode HDCALLBACK OnceCallback(void*) { return HD_CALLBACK_DONE; }

Vec3 Clamp(const Vec3& v, double max_norm) {
  const double n = v.norm();
  return (max_norm > 0 && n > max_norm) ? Vec3(v * (max_norm / n)) : v;
}

}  // namespace

void OpenHapticsDevice::Open() {
  if (open_) return;
  const HHD hhd = hdInitDevice(name_.empty() ? HD_DEFAULT_DEVICE : name_.c_str());
  if (std::string e = HdError("hdInitDevice"); !e.empty()) throw std::runtime_error(e);
  handle_ = hhd;
  hdMakeCurrentDevice(hhd);

  info_ = DeviceInfo{};
  const char* model = reinterpret_cast<const char*>(hdGetString(HD_DEVICE_MODEL_TYPE));
  info_.name = model ? model : "OpenHaptics device";
  HDint input_dof = 3, output_dof = 3;
  hdGetIntegerv(HD_INPUT_DOF, &input_dof);
  hdGetIntegerv(HD_OUTPUT_DOF, &output_dof);
  info_.dof_sensed = input_dof >= 6 ? 6 : 3;
  info_.dof_actuated = output_dof >= 6 ? 6 : 3;
  // CHAI3D 3.3's closed-loop values for a Phantom Touch (Omni); the
  // device's own nominal figures replace them when it reports them.
  info_.max_force = 3.3;
  info_.max_linear_stiffness = 700;
  info_.max_linear_damping = 5;
  HDdouble f = 0, k = 0, b = 0;
  hdGetDoublev(HD_NOMINAL_MAX_CONTINUOUS_FORCE, &f);
  hdGetDoublev(HD_NOMINAL_MAX_STIFFNESS, &k);  // N/mm
  hdGetDoublev(HD_NOMINAL_MAX_DAMPING, &b);    // N s/mm
  if (f > 0) info_.max_force = f;
  if (k > 0) info_.max_linear_stiffness = k / kMm;
  if (b > 0) info_.max_linear_damping = b / kMm;
  if (info_.dof_actuated == 6) {
    // Phantom Premium 6-DoF class (CHAI3D): 0.5 N m, 1 N m/rad.
    info_.max_torque = 0.5;
    info_.max_angular_stiffness = 1.0;
    info_.max_angular_damping = 0.02;
    HDdouble kt = 0;
    hdGetDoublev(HD_NOMINAL_MAX_TORQUE_STIFFNESS, &kt);  // mN m/rad
    if (kt > 0) info_.max_angular_stiffness = kt * kMm;
  }
  HDdouble ws[6] = {0, 0, 0, 0, 0, 0};  // min x, y, z, max x, y, z (mm)
  hdGetDoublev(HD_USABLE_WORKSPACE_DIMENSIONS, ws);
  if (ws[3] > ws[0]) {
    info_.workspace_min_D = kMm * Vec3(ws[0], ws[1], ws[2]);
    info_.workspace_max_D = kMm * Vec3(ws[3], ws[4], ws[5]);
  }
  info_.buttons = 2;
  if (std::string e = HdError("device queries"); !e.empty()) {
    hdDisableDevice(hhd);
    throw std::runtime_error(e);
  }

  fault_ = false;
  applied_ = Wrench{};
  wrench_in_.Write(Wrench{});
  hdEnable(HD_FORCE_OUTPUT);
  callback_ = hdScheduleAsynchronous(ServoCallback, this, HD_MAX_SCHEDULER_PRIORITY);
  hdStartScheduler();
  if (std::string e = HdError("hdStartScheduler"); !e.empty()) {
    hdUnschedule(static_cast<HDSchedulerHandle>(callback_));
    hdDisableDevice(hhd);
    throw std::runtime_error(e);
  }
  // A synchronous no-op runs after the (highest-priority) servo callback
  // in the same scheduler tick: Read() has a state from the first call on.
  hdScheduleSynchronous(OnceCallback, nullptr, HD_DEFAULT_SCHEDULER_PRIORITY);
  open_ = true;
}

void OpenHapticsDevice::Close() {
  if (!open_) return;
  // Stopping the scheduler stops force output; unschedule before the
  // callback's `this` goes away.
  hdStopScheduler();
  hdUnschedule(static_cast<HDSchedulerHandle>(callback_));
  hdDisableDevice(static_cast<HHD>(handle_));
  open_ = false;
}

void OpenHapticsDevice::SchedulerTick() {
  hdBeginFrame(static_cast<HHD>(handle_));
  Sample& out = state_out_.back();
  HDdouble T[16];  // column-major 4x4, translation in mm
  HDdouble v[3] = {0, 0, 0}, w[3] = {0, 0, 0};
  HDint buttons = 0;
  hdGetDoublev(HD_CURRENT_TRANSFORM, T);
  hdGetDoublev(HD_CURRENT_VELOCITY, v);                                     // mm/s
  if (info_.dof_sensed == 6) hdGetDoublev(HD_CURRENT_ANGULAR_VELOCITY, w);  // rad/s
  hdGetIntegerv(HD_CURRENT_BUTTONS, &buttons);
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) out.state.X_DH.R(i, j) = T[4 * j + i];
  }
  out.state.X_DH.t = kMm * Vec3(T[12], T[13], T[14]);
  out.state.v_DH_D = kMm * Vec3(v[0], v[1], v[2]);
  out.state.w_DH_D = Vec3(w[0], w[1], w[2]);
  out.state.buttons = static_cast<std::uint32_t>(buttons);
  out.state.time_ns = clock_->NowNs();

  if (wrench_in_.Fetch()) applied_ = wrench_in_.front();
  const HDdouble force[3] = {applied_.force.x(), applied_.force.y(), applied_.force.z()};
  hdSetDoublev(HD_CURRENT_FORCE, force);
  if (info_.dof_actuated == 6) {
    const HDdouble torque[3] = {applied_.torque.x() / kMm, applied_.torque.y() / kMm,
                                applied_.torque.z() / kMm};  // mN m
    hdSetDoublev(HD_CURRENT_TORQUE, torque);
  }
  hdEndFrame(static_cast<HHD>(handle_));
  const HDErrorInfo e = hdGetError();
  out.ok = !HD_DEVICE_ERROR(e);
  if (!out.ok) fault_.store(true, std::memory_order_relaxed);
  state_out_.Publish();
}

DeviceStatus OpenHapticsDevice::Read(DeviceState* s) {
  if (!open_) return DeviceStatus::kNotOpen;
  state_out_.Fetch();
  const Sample& in = state_out_.front();
  if (!in.ok || fault_.load(std::memory_order_relaxed)) return DeviceStatus::kError;
  *s = in.state;
  return DeviceStatus::kOk;
}

DeviceStatus OpenHapticsDevice::Command(const Wrench& F) {
  if (!open_) return DeviceStatus::kNotOpen;
  Wrench& out = wrench_in_.back();
  out.force = Clamp(F.force, info_.max_force);
  out.torque = info_.dof_actuated == 6 ? Clamp(F.torque, info_.max_torque) : Vec3::Zero();
  wrench_in_.Publish();
  return fault_.load(std::memory_order_relaxed) ? DeviceStatus::kError : DeviceStatus::kOk;
}

}  // namespace hapticpd::device
