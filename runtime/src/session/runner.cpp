// hrt::Runner (hrt/runner.h): a scene file's session, lockstep or real time.
#include "hrt/runner.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>

namespace hrt {
namespace {

std::unique_ptr<Device> make_device(const RunConfig& cfg) {
  const DeviceConfig& d = cfg.device;
  if (d.type == "scripted")
    return std::make_unique<ScriptedDevice>(Trajectory::load_csv(d.trajectory, d.trajectory_prefix), d.info);
  if (d.type == "udp") return std::make_unique<UdpDevice>(d.udp, d.info);
  if (d.type == "plugin") return std::make_unique<PluginDevice>(d.plugin, d.plugin_config);
  if (d.type == "virtual") return std::make_unique<VirtualDevice>(d.start, d.info);
  // load_run_config accepts only these kinds; a RunConfig built in code may not.
  throw std::invalid_argument("device.type: unknown device type '" + d.type + "' (scripted, udp, plugin, virtual)");
}

// A plugin reports its own limits; the scene file may override them.
DeviceInfo effective_info(const RunConfig& cfg, const Device& dev) {
  DeviceInfo info = dev.info();
  const DeviceConfig& d = cfg.device;
  if (d.type != "plugin") return d.info;
  if (d.max_force_set) info.max_force = d.info.max_force;
  if (d.max_torque_set) info.max_torque = d.info.max_torque;
  if (d.max_stiffness_set) info.max_stiffness = d.info.max_stiffness;
  if (d.max_angular_stiffness_set) info.max_angular_stiffness = d.info.max_angular_stiffness;
  if (d.dof_actuated_set) info.dof_actuated = d.info.dof_actuated;
  return info;
}

// The device with the scene's limits applied (a plugin's own figures
// overridden where the file says so). The Runner opens and closes the inner one.
class LimitedDevice : public Device {
 public:
  LimitedDevice(Device& inner, DeviceInfo info) : inner_(inner), info_(std::move(info)) {}
  const DeviceInfo& info() const override { return info_; }
  void open() override {}
  void close() override {}
  bool read(double t, DeviceSample& s) noexcept override { return inner_.read(t, s); }
  void write(double t, const Vec6& w) noexcept override { inner_.write(t, w); }
  void publish_poses(double t, const Pose* p, int n) noexcept override { inner_.publish_poses(t, p, n); }

 private:
  Device& inner_;
  DeviceInfo info_;
};

}  // namespace

struct Runner::Impl {
  RunConfig cfg;
  std::vector<Model> models;
  std::unique_ptr<Scene> scene;
  std::vector<Trajectory> trajectories;
  DepthBackend* backend = nullptr;

  std::unique_ptr<Device> raw;
  bool raw_open = false;
  DeviceInfo info;
  std::unique_ptr<LimitedDevice> device;
  std::unique_ptr<Session> session;
  ManualClock manual;
  std::unique_ptr<SessionClock> wall;
  std::unique_ptr<DeviceLoop> loop;
  DeviceTarget target;
  size_t ticks_total = 0;
  size_t next_tick = 0;  // lockstep: the next device tick
  bool loop_running = false;
  std::vector<double> periods;

  ~Impl() {
    if (loop_running) loop->stop();
    if (raw_open) raw->close();
  }
  bool faulted() const { return !raw->fault().empty(); }
};

Runner::Runner(RunConfig cfg) : impl_(std::make_unique<Impl>()) {
  Impl& m = *impl_;
  m.cfg = std::move(cfg);
  m.models.reserve(m.cfg.objects.size());
  for (const ObjectConfig& o : m.cfg.objects) m.models.push_back(load_bundle(o.bundle));
  std::vector<const Model*> ptrs;
  for (const Model& x : m.models) ptrs.push_back(&x);
  m.scene = std::make_unique<Scene>(ptrs, m.cfg.scene);
  m.trajectories.resize(m.cfg.objects.size());
  for (size_t b = 1; b < m.cfg.objects.size(); ++b)
    if (!m.cfg.objects[b].trajectory.empty()) m.trajectories[b] = Trajectory::load_csv(m.cfg.objects[b].trajectory);
  m.ticks_total = static_cast<size_t>(std::llround(m.cfg.duration / m.cfg.loop.period));
}

Runner::~Runner() = default;

void Runner::open() {
  Impl& m = *impl_;
  if (m.session) throw std::logic_error("Runner::open: already open");
  const RunConfig& cfg = m.cfg;
  if (cfg.lockstep && cfg.device.type != "scripted" && cfg.device.type != "virtual")
    throw std::invalid_argument("lockstep needs a scripted or virtual device (device.type = \"" + cfg.device.type +
                                "\")");
  m.raw = make_device(cfg);
  m.raw->open();
  m.raw_open = true;
  m.info = effective_info(cfg, *m.raw);
  check_device_limits(m.info, cfg.device.type == "plugin" ? "plugin " + cfg.device.plugin : cfg.file);
  m.device = std::make_unique<LimitedDevice>(*m.raw, m.info);

  std::vector<Pose> initial;
  for (const ObjectConfig& o : cfg.objects) initial.push_back(o.pose);
  SessionOptions so = cfg.session;
  so.max_device_stiffness = m.info.max_stiffness;
  so.max_device_angular_stiffness = m.info.max_angular_stiffness;
  if (cfg.coupling_from_device) so.coupling = default_coupling(m.info, RigidBody::from_model(m.models[0], so.density));
  auto session = std::make_unique<Session>(*m.scene, so, initial);
  for (size_t b = 1; b < cfg.objects.size(); ++b)
    if (!m.trajectories[b].empty()) session->set_trajectory(static_cast<int>(b), &m.trajectories[b]);
  session->set_depth_backend(m.backend);

  m.wall = std::make_unique<SessionClock>();
  const Clock& clock = cfg.lockstep ? static_cast<const Clock&>(m.manual) : *m.wall;
  // Period errors for the jitter summary: one per tick, at most kMaxJitterSamples.
  m.loop = std::make_unique<DeviceLoop>(*m.device, cfg.loop, clock,
                                        cfg.lockstep ? 0 : std::min(m.ticks_total + 1024, kMaxJitterSamples));
  m.session = std::move(session);
  if (!cfg.lockstep) m.periods.reserve(size_t{1} << 20);
}

bool Runner::is_open() const { return impl_->session != nullptr; }

void Runner::set_depth_backend(DepthBackend* backend) {
  impl_->backend = backend;
  if (impl_->session) impl_->session->set_depth_backend(backend);
}

const SessionFrame* Runner::step() {
  Impl& m = *impl_;
  if (!m.session) throw std::logic_error("Runner::step: open() first");
  if (!m.cfg.lockstep) throw std::logic_error("Runner::step: a real-time session runs with run()");
  const size_t every = static_cast<size_t>(std::max(1, m.cfg.sim_every));
  while (m.next_tick <= m.ticks_total && !m.faulted()) {
    const size_t i = m.next_tick++;
    const double t = static_cast<double>(i) * m.cfg.loop.period;
    m.manual.set(t);
    m.loop->tick();
    if (i % every != 0) continue;
    if (!m.loop->target(m.target)) continue;
    const SessionFrame& fr = m.session->step(t, static_cast<double>(every) * m.cfg.loop.period, m.target.target);
    m.loop->publish(m.session->command());
    return &fr;
  }
  return nullptr;
}

void Runner::run(const std::function<bool(const SessionFrame&)>& on_frame, const std::atomic<bool>* stop) {
  Impl& m = *impl_;
  if (!m.session) throw std::logic_error("Runner::run: open() first");
  auto stopped = [&] { return stop && stop->load(); };
  if (m.cfg.lockstep) {
    while (!stopped()) {
      const SessionFrame* fr = step();
      if (!fr || (on_frame && !on_frame(*fr))) break;
    }
    return;
  }
  const Clock& clock = *m.wall;
  m.loop->start();
  m.loop_running = true;
  try {
    double t_prev = -1;
    while (!stopped() && !m.faulted()) {
      const double t = clock.now();
      if (t >= m.cfg.duration) break;
      if (!m.loop->target(m.target)) {
        std::this_thread::sleep_for(std::chrono::microseconds(200));
        continue;
      }
      const double h = t_prev < 0 ? m.cfg.loop.period : std::min(m.cfg.max_step, std::max(1e-6, t - t_prev));
      if (t_prev >= 0 && m.periods.size() < m.periods.capacity()) m.periods.push_back(t - t_prev);
      t_prev = t;
      const SessionFrame& fr = m.session->step(t, h, m.target.target);
      m.loop->publish(m.session->command());
      // Poses for a visual display: the device forwards them at its own
      // display rate (UdpDevice: [device] display_rate), others ignore them.
      m.device->publish_poses(t, m.session->state().poses.data(), m.scene->size());
      if (on_frame && !on_frame(fr)) break;
    }
  } catch (...) {
    m.loop->stop();  // the device ramps to zero whatever stopped the session
    m.loop_running = false;
    throw;
  }
  m.loop->stop();
  m.loop_running = false;
}

const RunConfig& Runner::config() const { return impl_->cfg; }
const std::vector<Model>& Runner::models() const { return impl_->models; }
const Scene& Runner::scene() const { return *impl_->scene; }

namespace {
template <class T>
T& opened(const std::unique_ptr<T>& p, const char* what) {
  if (!p) throw std::logic_error(std::string("Runner::") + what + ": open() first");
  return *p;
}
}  // namespace

Session& Runner::session() { return opened(impl_->session, "session"); }
const Session& Runner::session() const { return opened(impl_->session, "session"); }
Device& Runner::device() { return opened(impl_->raw, "device"); }
VirtualDevice* Runner::virtual_device() { return dynamic_cast<VirtualDevice*>(&opened(impl_->raw, "device")); }
const DeviceInfo& Runner::device_info() const {
  opened(impl_->raw, "device_info");
  return impl_->info;
}
const DeviceLoop& Runner::loop() const { return opened(impl_->loop, "loop"); }
const DeviceTarget& Runner::target() const { return impl_->target; }
size_t Runner::ticks_total() const { return impl_->ticks_total; }
const std::vector<double>& Runner::frame_periods() const { return impl_->periods; }

}  // namespace hrt
