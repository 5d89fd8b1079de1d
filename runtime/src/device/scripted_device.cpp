// ScriptedDevice (hrt/device.h): plays a trajectory at session time.
#include "hrt/device.h"

namespace hrt {

ScriptedDevice::ScriptedDevice(Trajectory trajectory, DeviceInfo info)
    : trajectory_(std::move(trajectory)), info_(std::move(info)) {}

bool ScriptedDevice::read(double t, DeviceSample& out) noexcept {
  if (trajectory_.empty()) return false;
  out.pose = trajectory_.sample(t);
  // A 3-DoF device senses no orientation: it reads identity whatever the file says.
  if (info_.dof_sensed == 3) out.pose.rotation = Eigen::Quaterniond::Identity();
  out.clutch = false;
  out.buttons = 0;
  return true;
}

void ScriptedDevice::write(double /*t*/, const Vec6& wrench) noexcept { last_ = wrench; }

}  // namespace hrt
