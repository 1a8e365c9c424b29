#include "device/adapters/dhd_device.h"

#include <dhdc.h>

#include <stdexcept>

namespace hapticpd::device {

void DhdDevice::Open() {
  if (id_ >= 0) return;
  id_ = dhdOpen();
  if (id_ < 0) throw std::runtime_error(std::string("dhd: ") + dhdErrorGetLastStr());
  info_ = DeviceInfo{};
  info_.name = dhdGetSystemName(id_) ? dhdGetSystemName(id_) : "Force Dimension";
  const bool wrist = dhdHasWrist(id_);
  const bool active_wrist = dhdHasActiveWrist(id_);
  info_.dof_sensed = wrist ? 6 : 3;
  info_.dof_actuated = active_wrist ? 6 : 3;
  // CHAI3D 3.3 closed-loop limits (sigma.7 / omega.6 class).
  info_.max_force = 12;
  info_.max_torque = active_wrist ? 0.2 : 0;
  info_.max_linear_stiffness = active_wrist ? 4000 : 5000;
  info_.max_angular_stiffness = active_wrist ? 1.0 : 0;
  info_.max_linear_damping = 20;
  info_.max_angular_damping = active_wrist ? 0.02 : 0;
  info_.workspace_min_D = Vec3::Constant(-0.08);
  info_.workspace_max_D = Vec3::Constant(0.08);
  info_.buttons = 1;
  dhdEnableForce(DHD_ON, id_);
}

void DhdDevice::Close() {
  if (id_ < 0) return;
  dhdSetForceAndTorque(0, 0, 0, 0, 0, 0, id_);
  dhdClose(id_);
  id_ = -1;
}

DeviceStatus DhdDevice::Read(DeviceState* s) {
  if (id_ < 0) return DeviceStatus::kNotOpen;
  double px, py, pz, vx, vy, vz, wx = 0, wy = 0, wz = 0, R[3][3];
  if (dhdGetPosition(&px, &py, &pz, id_) < 0 || dhdGetOrientationFrame(R, id_) < 0 ||
      dhdGetLinearVelocity(&vx, &vy, &vz, id_) < 0) {
    return DeviceStatus::kError;
  }
  if (info_.dof_sensed == 6) dhdGetAngularVelocityRad(&wx, &wy, &wz, id_);
  s->X_DH.t = Vec3(px, py, pz);
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) s->X_DH.R(i, j) = R[i][j];
  }
  s->v_DH_D = Vec3(vx, vy, vz);
  s->w_DH_D = Vec3(wx, wy, wz);
  s->buttons = static_cast<std::uint32_t>(dhdGetButtonMask(id_));
  s->time_ns = clock_->NowNs();
  return DeviceStatus::kOk;
}

DeviceStatus DhdDevice::Command(const Wrench& F) {
  if (id_ < 0) return DeviceStatus::kNotOpen;
  const int rc = dhdSetForceAndTorque(F.force.x(), F.force.y(), F.force.z(), F.torque.x(),
                                      F.torque.y(), F.torque.z(), id_);
  return rc < 0 ? DeviceStatus::kError : DeviceStatus::kOk;
}

}  // namespace hapticpd::device
