// UdpDevice (hrt/device.h): a device driven over UDP (docs/udp-protocol.md).
//
// One non-blocking IPv4 socket, bound to UdpOptions::bind_address (loopback
// by default): pose packets arrive on it, wrench packets and the display's
// object-pose packets leave from it. read() and write() run on the device
// thread, publish_poses() on the simulation thread; they share only the
// socket (sendto/recvfrom are thread-safe) and the atomic counters. Every
// buffer is allocated by the constructor, so none of them allocates or
// blocks (MSG_DONTWAIT on a non-blocking socket).
#include <arpa/inet.h>
#include <netdb.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <string>

#include "hrt/device.h"
#include "hrt/udp_protocol.h"

namespace hrt {
namespace {

// A flood must not hold the device thread: at most this many datagrams per
// read() (the rest wait for the next period). The kernel's default receive
// buffer holds fewer pose packets than this anyway.
constexpr int kMaxDrainPerRead = 4096;

std::string endpoint(const std::string& address, int port) { return address + ":" + std::to_string(port); }

void check_port(const char* what, const std::string& address, int port) {
  if (port < 0 || port > 65535)
    throw DeviceError(std::string("udp: ") + what + " " + endpoint(address, port) + ": port out of range 0..65535");
}

// IPv4 address of `host` (numeric or a name; open() may block on a lookup).
sockaddr_in resolve(const char* what, const std::string& host, int port) {
  addrinfo hints{};
  hints.ai_family = AF_INET;
  hints.ai_socktype = SOCK_DGRAM;
  addrinfo* res = nullptr;
  const int rc = getaddrinfo(host.c_str(), nullptr, &hints, &res);
  if (rc != 0 || res == nullptr)
    throw DeviceError(std::string("udp: cannot resolve ") + what + " " + endpoint(host, port) + ": " +
                      (rc != 0 ? gai_strerror(rc) : "no IPv4 address"));
  sockaddr_in out;
  std::memcpy(&out, res->ai_addr, sizeof out);
  freeaddrinfo(res);
  out.sin_port = htons(static_cast<uint16_t>(port));
  return out;
}

uint64_t source_id(const sockaddr_in& a) { return uint64_t(ntohl(a.sin_addr.s_addr)) << 16 | ntohs(a.sin_port); }

}  // namespace

struct UdpDevice::Impl {
  UdpOptions opt;
  int fd = -1;
  int port = -1;

  // Device thread only.
  udp::SequenceFilter filter;
  DeviceSample latest;
  bool have_pose = false;
  uint32_t latest_sequence = 0;
  sockaddr_in client{};
  bool have_client = false;
  sockaddr_in reply{};  // fixed reply destination (reply_address set)
  bool reply_fixed = false;
  uint32_t wrench_sequence = 0;
  bool wrench_first = true;
  uint8_t rx[65536];  // any UDP datagram fits: a longer one is never cut to look valid
  uint8_t tx[udp::kWrenchSize];

  // Simulation thread only.
  sockaddr_in display{};
  bool display_on = false;
  double display_period = 0.0;
  double next_display = 0.0;
  bool display_timed = false;  // next_display is set
  bool display_first = true;   // no display packet sent yet (the restart flag)
  uint32_t display_sequence = 0;
  udp::ObjectPose objects[udp::kMaxObjectsPerPacket];
  uint8_t display_tx[udp::kMaxPacketSize];

  std::atomic<uint64_t> received{0}, accepted{0}, bad_size{0}, bad_magic{0}, bad_version{0}, bad_type{0}, non_finite{0},
      out_of_order{0}, sent_wrenches{0}, sent_display{0}, send_errors{0};

  void send(int sock, const uint8_t* data, size_t size, const sockaddr_in& to, std::atomic<uint64_t>& sent) {
    const ssize_t n = sendto(sock, data, size, MSG_DONTWAIT, reinterpret_cast<const sockaddr*>(&to), sizeof to);
    if (n == static_cast<ssize_t>(size))
      sent.fetch_add(1, std::memory_order_relaxed);
    else
      send_errors.fetch_add(1, std::memory_order_relaxed);
  }
};

UdpDevice::UdpDevice(UdpOptions options, DeviceInfo info) : impl_(new Impl), info_(std::move(info)) {
  impl_->opt = std::move(options);
}

UdpDevice::~UdpDevice() { close(); }

void UdpDevice::open() {
  close();
  Impl& m = *impl_;
  const UdpOptions& o = m.opt;
  check_port("bind", o.bind_address, o.port);
  check_port("reply", o.reply_address.empty() ? "(client)" : o.reply_address, o.reply_port);
  check_port("display", o.display_address, o.display_port);
  if (!o.reply_address.empty() && o.reply_port == 0)
    throw DeviceError("udp: reply " + endpoint(o.reply_address, 0) + ": a reply address needs a reply port");
  if (o.display_port != 0 && !(std::isfinite(o.display_rate_hz) && o.display_rate_hz > 0))
    throw DeviceError("udp: display " + endpoint(o.display_address, o.display_port) +
                      ": display rate must be > 0 Hz (got " + std::to_string(o.display_rate_hz) + ")");

  const sockaddr_in local = resolve("bind address", o.bind_address, o.port);
  if (!o.reply_address.empty()) {
    m.reply = resolve("reply address", o.reply_address, o.reply_port);
    m.reply_fixed = true;
  }
  if (o.display_port != 0) {
    m.display = resolve("display address", o.display_address, o.display_port);
    m.display_on = true;
    m.display_period = 1.0 / o.display_rate_hz;
  }

  const int fd = socket(AF_INET, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd < 0)
    throw DeviceError("udp: cannot create a socket for " + endpoint(o.bind_address, o.port) + ": " +
                      std::strerror(errno));
  // No SO_REUSEADDR: a second session on the same port is an error, not two
  // processes splitting one client's packets.
  if (bind(fd, reinterpret_cast<const sockaddr*>(&local), sizeof local) != 0) {
    const int e = errno;
    ::close(fd);
    throw DeviceError("udp: cannot bind " + endpoint(o.bind_address, o.port) + ": " + std::strerror(e));
  }
  sockaddr_in bound{};
  socklen_t len = sizeof bound;
  getsockname(fd, reinterpret_cast<sockaddr*>(&bound), &len);
  m.fd = fd;
  m.port = ntohs(bound.sin_port);
  m.filter.reset();
  m.have_pose = m.have_client = false;
  m.wrench_first = m.display_first = true;
  m.display_timed = false;
}

void UdpDevice::close() {
  if (impl_ && impl_->fd >= 0) {
    ::close(impl_->fd);
    impl_->fd = -1;
    impl_->port = -1;
  }
}

int UdpDevice::bound_port() const { return impl_->port; }

UdpCounters UdpDevice::counters() const {
  const Impl& m = *impl_;
  auto get = [](const std::atomic<uint64_t>& a) { return a.load(std::memory_order_relaxed); };
  UdpCounters c;
  c.received = get(m.received);
  c.accepted = get(m.accepted);
  c.bad_size = get(m.bad_size);
  c.bad_magic = get(m.bad_magic);
  c.bad_version = get(m.bad_version);
  c.bad_type = get(m.bad_type);
  c.non_finite = get(m.non_finite);
  c.out_of_order = get(m.out_of_order);
  c.sent_wrenches = get(m.sent_wrenches);
  c.sent_display = get(m.sent_display);
  c.send_errors = get(m.send_errors);
  return c;
}

bool UdpDevice::read(double /*t*/, DeviceSample& out) noexcept {
  Impl& m = *impl_;
  if (m.fd >= 0) {
    for (int k = 0; k < kMaxDrainPerRead; ++k) {
      sockaddr_in from{};
      socklen_t len = sizeof from;
      const ssize_t n = recvfrom(m.fd, m.rx, sizeof m.rx, MSG_DONTWAIT, reinterpret_cast<sockaddr*>(&from), &len);
      if (n < 0) {
        if (errno == EINTR) continue;
        break;  // EAGAIN: drained (other errors: try again next period)
      }
      m.received.fetch_add(1, std::memory_order_relaxed);
      udp::PoseMessage msg;
      const udp::Result r = udp::parse_pose(m.rx, static_cast<size_t>(n), msg);
      switch (r) {
        case udp::Result::ok: break;
        case udp::Result::bad_size: m.bad_size.fetch_add(1, std::memory_order_relaxed); continue;
        case udp::Result::bad_magic: m.bad_magic.fetch_add(1, std::memory_order_relaxed); continue;
        case udp::Result::bad_version: m.bad_version.fetch_add(1, std::memory_order_relaxed); continue;
        case udp::Result::bad_type: m.bad_type.fetch_add(1, std::memory_order_relaxed); continue;
        // A zero quaternion (bad_value) is no finite pose either: one counter.
        default: m.non_finite.fetch_add(1, std::memory_order_relaxed); continue;
      }
      if (!m.filter.accept(msg.header.sequence, msg.header.flags, source_id(from))) {
        m.out_of_order.fetch_add(1, std::memory_order_relaxed);
        continue;
      }
      m.accepted.fetch_add(1, std::memory_order_relaxed);
      // Packets of a stream arrive in order after the filter, so the last
      // accepted one of the drain is the newest.
      Eigen::Quaterniond q(msg.quaternion[3], msg.quaternion[0], msg.quaternion[1], msg.quaternion[2]);
      q.normalize();
      m.latest.pose.position = Vec3(msg.position[0], msg.position[1], msg.position[2]);
      m.latest.pose.rotation = info_.dof_sensed == 3 ? Eigen::Quaterniond::Identity() : q;
      m.latest.buttons = msg.buttons;
      m.latest.clutch = msg.clutch;
      m.latest_sequence = msg.header.sequence;
      m.client = from;
      m.have_client = true;
      m.have_pose = true;
    }
  }
  if (!m.have_pose) return false;
  out = m.latest;
  return true;
}

void UdpDevice::write(double t, const Vec6& wrench) noexcept {
  Impl& m = *impl_;
  if (m.fd < 0) return;
  sockaddr_in to;
  if (m.reply_fixed) {
    to = m.reply;
  } else if (m.have_client) {
    to = m.client;
    if (m.opt.reply_port != 0) to.sin_port = htons(static_cast<uint16_t>(m.opt.reply_port));
  } else {
    return;  // nobody to answer yet
  }
  udp::WrenchMessage w;
  w.header.type = udp::MessageType::wrench;
  w.header.flags = m.wrench_first ? udp::kFlagRestart : 0;
  w.header.sequence = m.wrench_sequence;
  w.header.timestamp = t;
  w.answers = m.latest_sequence;
  for (int i = 0; i < 3; ++i) {
    w.force[i] = wrench[i];
    w.torque[i] = wrench[3 + i];
  }
  size_t size = 0;
  if (udp::encode_wrench(w, m.tx, sizeof m.tx, size) != udp::Result::ok) {
    m.send_errors.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  ++m.wrench_sequence;
  m.wrench_first = false;
  m.send(m.fd, m.tx, size, to, m.sent_wrenches);
}

void UdpDevice::publish_poses(double t, const Pose* poses, int count) noexcept {
  Impl& m = *impl_;
  if (m.fd < 0 || !m.display_on || count <= 0 || poses == nullptr || !std::isfinite(t)) return;
  if (m.display_timed) {
    if (t < m.next_display) return;
    // Due times advance by whole periods so the average rate is the rate
    // asked for; after a pause (or a time reset) they restart from t.
    m.next_display += m.display_period;
    if (m.next_display <= t || m.next_display > t + 2 * m.display_period) m.next_display = t + m.display_period;
  } else {
    m.next_display = t + m.display_period;
    m.display_timed = true;
  }
  // A scene of more than kMaxObjectsPerPacket objects spans several packets
  // of one timestamp (each object carries its index, `total` says how many).
  for (int first = 0; first < count; first += static_cast<int>(udp::kMaxObjectsPerPacket)) {
    const int n = std::min(count - first, static_cast<int>(udp::kMaxObjectsPerPacket));
    for (int k = 0; k < n; ++k) {
      const Pose& p = poses[first + k];
      udp::ObjectPose& o = m.objects[k];
      o.index = static_cast<uint32_t>(first + k);
      for (int i = 0; i < 3; ++i) o.position[i] = p.position[i];
      o.quaternion[0] = p.rotation.x();
      o.quaternion[1] = p.rotation.y();
      o.quaternion[2] = p.rotation.z();
      o.quaternion[3] = p.rotation.w();
    }
    udp::ObjectPosesMessage msg;
    msg.header.type = udp::MessageType::object_poses;
    msg.header.flags = m.display_first ? udp::kFlagRestart : 0;
    msg.header.sequence = m.display_sequence;
    msg.header.timestamp = t;
    msg.total = static_cast<uint32_t>(count);
    msg.count = static_cast<uint32_t>(n);
    size_t size = 0;
    if (udp::encode_object_poses(msg, m.objects, m.display_tx, sizeof m.display_tx, size) != udp::Result::ok) {
      m.send_errors.fetch_add(1, std::memory_order_relaxed);
      continue;
    }
    ++m.display_sequence;
    m.display_first = false;
    m.send(m.fd, m.display_tx, size, m.display, m.sent_display);
  }
}

}  // namespace hrt
