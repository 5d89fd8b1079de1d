// VirtualDevice (hrt/device.h): a handle moved by the application.
#include <cmath>

#include "hrt/device.h"

namespace hrt {

VirtualDevice::VirtualDevice(Pose start, DeviceInfo info) : info_(std::move(info)) {
  for (auto& w : pose_) w.store(0.0, std::memory_order_relaxed);
  for (auto& w : wrench_) w.store(0.0, std::memory_order_relaxed);
  if (!set_pose(start)) set_pose(Pose{});
  read(0.0, last_);  // the start pose: what a read that finds the writer mid-store holds
}

// A sequence lock (one writer at a time is the caller's business: the
// viewer's thread): the writer makes seq odd, stores, makes it even; a
// reader retries while seq is odd or changed. The words are atomics, so no
// torn double is ever read and the pattern is free of data races.
bool VirtualDevice::set_pose(const Pose& pose, bool clutch) noexcept {
  const Eigen::Quaterniond& q = pose.rotation;
  const double qn = q.norm();
  if (!pose.position.allFinite() || !q.coeffs().allFinite() || !(qn > 1e-12)) return false;
  const double w[kWords] = {pose.position.x(), pose.position.y(), pose.position.z(), q.x() / qn,
                            q.y() / qn,        q.z() / qn,        q.w() / qn,        clutch ? 1.0 : 0.0};
  const uint64_t s = seq_.load(std::memory_order_relaxed);
  seq_.store(s + 1, std::memory_order_relaxed);
  std::atomic_thread_fence(std::memory_order_release);
  for (int k = 0; k < kWords; ++k) pose_[k].store(w[k], std::memory_order_relaxed);
  seq_.store(s + 2, std::memory_order_release);
  return true;
}

bool VirtualDevice::read(double /*t*/, DeviceSample& out) noexcept {
  // A few tries; a writer caught mid-store on every one (descheduled between
  // its stores) leaves the previous pose in place: read() never waits on it.
  double w[kWords];
  bool got = false;
  for (int attempt = 0; attempt < kReadAttempts && !got; ++attempt) {
    const uint64_t s0 = seq_.load(std::memory_order_acquire);
    if (s0 & 1) continue;
    for (int k = 0; k < kWords; ++k) w[k] = pose_[k].load(std::memory_order_relaxed);
    std::atomic_thread_fence(std::memory_order_acquire);
    got = seq_.load(std::memory_order_relaxed) == s0;
  }
  if (!got) {
    out = last_;
    return true;
  }
  out.pose.position = Vec3(w[0], w[1], w[2]);
  out.pose.rotation = Eigen::Quaterniond(w[6], w[3], w[4], w[5]);
  // A 3-DoF device senses no orientation (as ScriptedDevice).
  if (info_.dof_sensed == 3) out.pose.rotation = Eigen::Quaterniond::Identity();
  out.clutch = w[7] != 0.0;
  out.buttons = 0;
  last_ = out;
  return true;
}

void VirtualDevice::write(double /*t*/, const Vec6& wrench) noexcept {
  for (int k = 0; k < 6; ++k) wrench_[k].store(wrench[k], std::memory_order_relaxed);
}

Vec6 VirtualDevice::last_wrench() const noexcept {
  Vec6 w;
  for (int k = 0; k < 6; ++k) w[k] = wrench_[k].load(std::memory_order_relaxed);
  return w;
}

}  // namespace hrt
