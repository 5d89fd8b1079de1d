// The UDP bridge (docs/udp-protocol.md): the wire format's golden bytes (the
// same hex strings are asserted by tests/integration/test_udp_client.py against the
// Python client's encoder), the parsers' rejection classes, the order filter,
// and UdpDevice on real loopback sockets: bad packets dropped and counted,
// valid ones change the pose read, wrenches answer the client, object poses
// reach the display at its rate, the socket is bound to 127.0.0.1 by default.
#include <gtest/gtest.h>

#include <arpa/inet.h>
#include <dirent.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "hrt/device.h"
#include "hrt/udp_protocol.h"

namespace {

namespace udp = hrt::udp;
using Bytes = std::vector<uint8_t>;

// Shared with tests/integration/test_udp_client.py and docs/udp-protocol.md.
const char* kGoldenPose =
    "48525455010001010700000000000000000000000000e03f9a9999999999b93f9a9999999999c9bf333333333333d33f"
    "00000000000000000000000000000000333333333333e33f9a9999999999e93f0500000001000000";
const char* kGoldenWrench =
    "48525455010002000300000000000000000000000000f43f0700000000000000000000000000f83f00000000000000c0"
    "0000000000000840000000000000d03f0000000000000000000000000000c0bf";

std::string hex(const uint8_t* p, size_t n) {
  static const char* d = "0123456789abcdef";
  std::string s;
  for (size_t i = 0; i < n; ++i) {
    s += d[p[i] >> 4];
    s += d[p[i] & 15];
  }
  return s;
}

udp::PoseMessage golden_pose() {
  udp::PoseMessage m;
  m.header.flags = udp::kFlagRestart;
  m.header.sequence = 7;
  m.header.timestamp = 0.5;
  m.position[0] = 0.1, m.position[1] = -0.2, m.position[2] = 0.3;
  m.quaternion[0] = 0, m.quaternion[1] = 0, m.quaternion[2] = 0.6, m.quaternion[3] = 0.8;
  m.buttons = 5;
  m.clutch = true;
  return m;
}

Bytes encode(const udp::PoseMessage& m) {
  Bytes b(udp::kPoseSize);
  size_t n = 0;
  EXPECT_EQ(udp::encode_pose(m, b.data(), b.size(), n), udp::Result::ok);
  EXPECT_EQ(n, udp::kPoseSize);
  return b;
}

udp::PoseMessage pose_msg(uint32_t seq, double x, uint8_t flags = 0) {
  udp::PoseMessage m;
  m.header.sequence = seq;
  m.header.flags = flags;
  m.header.timestamp = seq * 1e-3;
  m.position[0] = x;
  m.position[1] = 0.02;
  m.position[2] = -0.03;
  m.quaternion[0] = 0, m.quaternion[1] = 0, m.quaternion[2] = 0, m.quaternion[3] = 2;  // normalized by the device
  return m;
}

void put_f64(uint8_t* p, double d) {
  uint64_t u;
  std::memcpy(&u, &d, 8);
  for (int i = 0; i < 8; ++i) p[i] = uint8_t(u >> (8 * i));
}

// A client socket on 127.0.0.1, port chosen by the kernel.
struct Client {
  int fd = -1;
  int port = 0;
  Client() {
    fd = socket(AF_INET, SOCK_DGRAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    EXPECT_EQ(bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
    socklen_t len = sizeof a;
    getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
    port = ntohs(a.sin_port);
  }
  ~Client() { close(fd); }
  void send_to(int to_port, const Bytes& b) const {
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    a.sin_port = htons(static_cast<uint16_t>(to_port));
    ASSERT_EQ(sendto(fd, b.data(), b.size(), 0, reinterpret_cast<sockaddr*>(&a), sizeof a),
              static_cast<ssize_t>(b.size()));
  }
  // The next datagram within `ms` milliseconds, or empty.
  Bytes receive(int ms = 1000) const {
    pollfd p{fd, POLLIN, 0};
    if (poll(&p, 1, ms) <= 0) return {};
    Bytes b(70000);
    const ssize_t n = recv(fd, b.data(), b.size(), 0);
    b.resize(n > 0 ? static_cast<size_t>(n) : 0);
    return b;
  }
};

// Reads until the device has received `n` datagrams in all (loopback
// delivery is immediate on Linux, the loop only guards against a slow kernel).
bool read_until(hrt::UdpDevice& dev, uint64_t n, hrt::DeviceSample& s) {
  bool got = false;
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(2);
  do {
    got = dev.read(0.0, s);
    if (dev.counters().received >= n) return got;
  } while (std::chrono::steady_clock::now() < until);
  ADD_FAILURE() << "the device received " << dev.counters().received << " datagrams, expected " << n;
  return got;
}

hrt::UdpOptions any_port() {
  hrt::UdpOptions o;
  o.port = 0;
  return o;
}

}  // namespace

// The byte layout of docs/udp-protocol.md, field by field.
TEST(UdpProtocol, GoldenBytesMatchTheDocumentedLayout) {
  const Bytes pose = encode(golden_pose());
  EXPECT_EQ(hex(pose.data(), pose.size()), kGoldenPose);

  udp::WrenchMessage w;
  w.header.sequence = 3;
  w.header.timestamp = 1.25;
  w.answers = 7;
  const double f[6] = {1.5, -2, 3, 0.25, 0, -0.125};
  for (int i = 0; i < 3; ++i) w.force[i] = f[i], w.torque[i] = f[3 + i];
  uint8_t buf[udp::kWrenchSize];
  size_t n = 0;
  ASSERT_EQ(udp::encode_wrench(w, buf, sizeof buf, n), udp::Result::ok);
  EXPECT_EQ(hex(buf, n), kGoldenWrench);

  udp::WrenchMessage back;
  ASSERT_EQ(udp::parse_wrench(buf, n, back), udp::Result::ok);
  EXPECT_EQ(back.answers, 7u);
  EXPECT_EQ(back.torque[2], -0.125);
  udp::PoseMessage p;
  ASSERT_EQ(udp::parse_pose(pose.data(), pose.size(), p), udp::Result::ok);
  EXPECT_EQ(p.header.sequence, 7u);
  EXPECT_EQ(p.header.flags, udp::kFlagRestart);
  EXPECT_EQ(p.position[1], -0.2);
  EXPECT_EQ(p.quaternion[3], 0.8);
  EXPECT_EQ(p.buttons, 5u);
  EXPECT_TRUE(p.clutch);

  // Object poses: 32-byte head, 64 bytes per object (index at +0, position at +8, quaternion at +32).
  udp::ObjectPose objs[2];
  objs[1].index = 1;
  objs[1].position[2] = 0.5;
  objs[1].quaternion[0] = 1, objs[1].quaternion[3] = 0;
  udp::ObjectPosesMessage om;
  om.header.sequence = 9;
  om.total = 2;
  om.count = 2;
  uint8_t ob[udp::kObjectPosesHeaderSize + 2 * udp::kObjectPoseSize];
  ASSERT_EQ(udp::encode_object_poses(om, objs, ob, sizeof ob, n), udp::Result::ok);
  ASSERT_EQ(n, sizeof ob);
  EXPECT_EQ(hex(ob, 8), "4852545501000300");
  EXPECT_EQ(hex(ob + 24, 8), "0200000002000000");
  EXPECT_EQ(hex(ob + 32 + 64, 4), "01000000");
  EXPECT_EQ(hex(ob + 32 + 64 + 24, 8), "000000000000e03f");  // z = 0.5
  EXPECT_EQ(hex(ob + 32 + 64 + 32, 8), "000000000000f03f");  // qx = 1
  udp::ObjectPose got[2];
  ASSERT_EQ(udp::parse_object_poses(ob, n, om, got, 2), udp::Result::ok);
  EXPECT_EQ(om.count, 2u);
  EXPECT_EQ(got[1].position[2], 0.5);
  EXPECT_EQ(udp::parse_object_poses(ob, n, om, got, 1), udp::Result::buffer_too_small);
}

// Each rejection class of the parsers, on an otherwise valid packet.
TEST(UdpProtocol, ParsersRejectEachClassOfBadPacket) {
  const Bytes good = encode(golden_pose());
  udp::PoseMessage m;
  auto parse = [&](const Bytes& b) { return udp::parse_pose(b.data(), b.size(), m); };
  ASSERT_EQ(parse(good), udp::Result::ok);
  EXPECT_EQ(udp::parse_pose(nullptr, 0, m), udp::Result::bad_size);
  for (size_t n : {size_t(0), size_t(1), size_t(23), size_t(24), size_t(87)})
    EXPECT_EQ(parse(Bytes(good.begin(), good.begin() + n)), udp::Result::bad_size) << n;
  Bytes longer = good;
  longer.push_back(0);
  EXPECT_EQ(parse(longer), udp::Result::bad_size);
  Bytes b = good;
  b[0] = 'X';
  EXPECT_EQ(parse(b), udp::Result::bad_magic);
  b = good;
  b[4] = 2;
  EXPECT_EQ(parse(b), udp::Result::bad_version);
  b = good;
  b[5] = 1;  // version 257: the high byte counts too
  EXPECT_EQ(parse(b), udp::Result::bad_version);
  b = good;
  b[6] = 2;  // a wrench where a pose is expected
  EXPECT_EQ(parse(b), udp::Result::bad_type);
  b[6] = 9;
  EXPECT_EQ(parse(b), udp::Result::bad_type);
  // A NaN or an infinity in any double: timestamp, position, quaternion.
  for (size_t off : {size_t(16), size_t(24), size_t(40), size_t(48), size_t(72)}) {
    for (double bad : {NAN, INFINITY, -INFINITY}) {
      b = good;
      put_f64(&b[off], bad);
      EXPECT_EQ(parse(b), udp::Result::non_finite) << off;
    }
  }
  b = good;
  for (size_t off = 48; off < 80; off += 8) put_f64(&b[off], 0.0);
  EXPECT_EQ(parse(b), udp::Result::bad_value);  // zero quaternion
  // Encoders refuse the same.
  udp::PoseMessage nanpose = golden_pose();
  nanpose.position[0] = NAN;
  uint8_t out[udp::kPoseSize];
  size_t n = 99;
  EXPECT_EQ(udp::encode_pose(nanpose, out, sizeof out, n), udp::Result::non_finite);
  EXPECT_EQ(n, 0u);
  EXPECT_EQ(udp::encode_pose(golden_pose(), out, sizeof out - 1, n), udp::Result::buffer_too_small);

  // Object poses: the count fixes the size; indices below total; at most 1000.
  udp::ObjectPose o;
  udp::ObjectPosesMessage om;
  om.total = 1;
  om.count = 1;
  uint8_t ob[udp::kObjectPosesHeaderSize + udp::kObjectPoseSize];
  ASSERT_EQ(udp::encode_object_poses(om, &o, ob, sizeof ob, n), udp::Result::ok);
  udp::ObjectPose got;
  EXPECT_EQ(udp::parse_object_poses(ob, sizeof ob - 1, om, &got, 1), udp::Result::bad_size);
  ob[24] = 2;  // count 2 in a packet of one
  EXPECT_EQ(udp::parse_object_poses(ob, sizeof ob, om, &got, 1), udp::Result::bad_size);
  ob[24] = 0xff, ob[25] = 0xff, ob[26] = 0xff, ob[27] = 0xff;
  EXPECT_EQ(udp::parse_object_poses(ob, sizeof ob, om, &got, 1), udp::Result::bad_value);
  ob[24] = 1, ob[25] = ob[26] = ob[27] = 0;
  ob[28] = 0;  // total 0: index 0 out of range
  EXPECT_EQ(udp::parse_object_poses(ob, sizeof ob, om, &got, 1), udp::Result::bad_value);
  o.index = 1;
  om.total = 1;
  om.count = 1;
  EXPECT_EQ(udp::encode_object_poses(om, &o, ob, sizeof ob, n), udp::Result::bad_value);
  EXPECT_STREQ(udp::to_string(udp::Result::non_finite), "non_finite");
}

// Order: later packets pass, duplicates and late ones do not; the sequence
// wraps; a restart flag or another source starts a new stream.
TEST(UdpProtocol, SequenceFilterOrdersWrapsAndRestarts) {
  udp::SequenceFilter f;
  EXPECT_TRUE(f.accept(100, 0, 1));  // the first packet, whatever its number
  EXPECT_TRUE(f.accept(101, 0, 1));
  EXPECT_FALSE(f.accept(101, 0, 1));  // duplicate
  EXPECT_FALSE(f.accept(99, 0, 1));   // late
  EXPECT_TRUE(f.accept(105, 0, 1));   // a gap is fine (lost packets)
  EXPECT_FALSE(f.accept(0, 0, 1));    // a restart without the flag looks late
  EXPECT_TRUE(f.accept(0, udp::kFlagRestart, 1));
  EXPECT_TRUE(f.accept(1, 0, 1));
  EXPECT_TRUE(f.accept(7, 0, 2));  // another source: a new stream
  EXPECT_FALSE(f.accept(6, 0, 2));
  EXPECT_EQ(f.streams(), 3u);
  udp::SequenceFilter w;
  EXPECT_TRUE(w.accept(0xfffffffeu, 0, 1));
  EXPECT_TRUE(w.accept(0xffffffffu, 0, 1));
  EXPECT_TRUE(w.accept(0u, 0, 1));  // wraps
  EXPECT_TRUE(w.accept(1u, 0, 1));
  EXPECT_FALSE(w.accept(0xffffffffu, 0, 1));
  EXPECT_TRUE(udp::sequence_after(0x7fffffffu, 0u));
  EXPECT_FALSE(udp::sequence_after(0x80000000u, 0u));  // half the circle away counts as behind
}

// Nothing listens beyond loopback unless configured: the socket's own
// address (getsockname, found through /proc/self/fd) is 127.0.0.1, and port 0
// gives a free port. 0.0.0.0 when asked (so the check can tell them apart).
TEST(UdpDevice, BindsToLoopbackByDefaultOnAFreePort) {
  auto bound_address = [](int port) -> std::string {
    DIR* d = opendir("/proc/self/fd");
    if (!d) return "(no /proc/self/fd)";
    std::string found = "(no socket on that port)";
    while (dirent* e = readdir(d)) {
      const int fd = atoi(e->d_name);
      sockaddr_in a{};
      socklen_t len = sizeof a;
      int type = 0;
      socklen_t tl = sizeof type;
      if (getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) == 0 && a.sin_family == AF_INET &&
          ntohs(a.sin_port) == port && getsockopt(fd, SOL_SOCKET, SO_TYPE, &type, &tl) == 0 && type == SOCK_DGRAM) {
        char buf[INET_ADDRSTRLEN];
        found = inet_ntop(AF_INET, &a.sin_addr, buf, sizeof buf);
      }
    }
    closedir(d);
    return found;
  };
  EXPECT_EQ(hrt::UdpOptions().bind_address, "127.0.0.1");
  hrt::UdpDevice dev(any_port(), hrt::DeviceInfo{});
  EXPECT_EQ(dev.bound_port(), -1);
  dev.open();
  const int port = dev.bound_port();
  ASSERT_GT(port, 0);
  EXPECT_EQ(bound_address(port), "127.0.0.1");
  dev.close();
  EXPECT_EQ(dev.bound_port(), -1);
  EXPECT_EQ(bound_address(port), "(no socket on that port)");

  hrt::UdpOptions all = any_port();
  all.bind_address = "0.0.0.0";
  hrt::UdpDevice wide(all, hrt::DeviceInfo{});
  wide.open();
  EXPECT_EQ(bound_address(wide.bound_port()), "0.0.0.0");
}

TEST(UdpDevice, ErrorsNameTheAddressAndPort) {
  hrt::UdpDevice a(any_port(), hrt::DeviceInfo{});
  a.open();
  hrt::UdpOptions same;
  same.port = a.bound_port();
  auto error = [](const hrt::UdpOptions& o) -> std::string {
    try {
      hrt::UdpDevice d(o, hrt::DeviceInfo{});
      d.open();
    } catch (const hrt::DeviceError& e) {
      return e.what();
    }
    return "(no error)";
  };
  EXPECT_EQ(error(same), "udp: cannot bind 127.0.0.1:" + std::to_string(same.port) + ": Address already in use");
  hrt::UdpOptions o = any_port();
  o.bind_address = "300.1.2.3";
  EXPECT_EQ(error(o).rfind("udp: cannot resolve bind address 300.1.2.3:0: ", 0), 0u) << error(o);
  o = any_port();
  o.port = 70000;
  EXPECT_EQ(error(o), "udp: bind 127.0.0.1:70000: port out of range 0..65535");
  o = any_port();
  o.display_port = 5000;
  o.display_rate_hz = 0;
  EXPECT_EQ(error(o).rfind("udp: display 127.0.0.1:5000: display rate must be > 0 Hz", 0), 0u) << error(o);
  o = any_port();
  o.reply_address = "127.0.0.1";
  EXPECT_EQ(error(o), "udp: reply 127.0.0.1:0: a reply address needs a reply port");
}

// Valid packets change the pose read (quaternion normalized, buttons,
// clutch); a drain of several keeps the newest; wrenches go back to the
// client, answering the newest pose's sequence.
TEST(UdpDevice, ValidPosesMoveThePoseAndWrenchesAnswerTheClient) {
  hrt::UdpDevice dev(any_port(), hrt::DeviceInfo{});
  dev.open();
  hrt::DeviceSample s;
  EXPECT_FALSE(dev.read(0.0, s));     // nothing yet
  dev.write(0.0, hrt::Vec6::Ones());  // nobody to answer: not sent
  EXPECT_EQ(dev.counters().sent_wrenches, 0u);

  Client c;
  c.send_to(dev.bound_port(), encode(golden_pose()));
  ASSERT_TRUE(read_until(dev, 1, s));
  EXPECT_TRUE(s.pose.position.isApprox(hrt::Vec3(0.1, -0.2, 0.3)));
  EXPECT_NEAR(s.pose.rotation.z(), 0.6, 1e-15);
  EXPECT_NEAR(s.pose.rotation.w(), 0.8, 1e-15);
  EXPECT_EQ(s.buttons, 5u);
  EXPECT_TRUE(s.clutch);

  for (uint32_t seq = 10; seq <= 12; ++seq) c.send_to(dev.bound_port(), encode(pose_msg(seq, 0.001 * seq)));
  ASSERT_TRUE(read_until(dev, 4, s));
  EXPECT_DOUBLE_EQ(s.pose.position.x(), 0.012);
  EXPECT_EQ(s.pose.rotation.coeffs(), Eigen::Quaterniond::Identity().coeffs());  // (0, 0, 0, 2) normalized
  EXPECT_FALSE(s.clutch);
  EXPECT_EQ(dev.counters().accepted, 4u);

  hrt::Vec6 w;
  w << 1.0, -2.0, 3.0, 0.1, -0.2, 0.3;
  dev.write(2.5, w);
  dev.write(2.501, 2 * w);
  const Bytes r1 = c.receive(), r2 = c.receive();
  udp::WrenchMessage m1, m2;
  ASSERT_EQ(udp::parse_wrench(r1.data(), r1.size(), m1), udp::Result::ok);
  ASSERT_EQ(udp::parse_wrench(r2.data(), r2.size(), m2), udp::Result::ok);
  EXPECT_EQ(m1.answers, 12u);
  EXPECT_EQ(m1.header.timestamp, 2.5);
  EXPECT_EQ(m1.header.flags, udp::kFlagRestart);  // hrt's first wrench of this stream
  EXPECT_EQ(m2.header.flags, 0);
  EXPECT_TRUE(udp::sequence_after(m2.header.sequence, m1.header.sequence));
  EXPECT_EQ(m1.force[1], -2.0);
  EXPECT_EQ(m1.torque[2], 0.3);
  EXPECT_EQ(m2.force[0], 2.0);
  EXPECT_EQ(dev.counters().sent_wrenches, 2u);
  EXPECT_EQ(dev.counters().send_errors, 0u);
}

// Each class of bad packet is dropped (the pose read does not change) and
// counted under its own counter; the device keeps working after them.
TEST(UdpDevice, BadPacketsAreDroppedAndCounted) {
  hrt::UdpDevice dev(any_port(), hrt::DeviceInfo{});
  dev.open();
  Client c;
  hrt::DeviceSample s;
  c.send_to(dev.bound_port(), encode(pose_msg(50, 0.5)));
  ASSERT_TRUE(read_until(dev, 1, s));
  ASSERT_DOUBLE_EQ(s.pose.position.x(), 0.5);

  uint64_t sent = 1;
  auto expect_dropped = [&](const Bytes& b, uint64_t hrt::UdpCounters::* counter, const char* what) {
    const uint64_t before = dev.counters().*counter;
    c.send_to(dev.bound_port(), b);
    ++sent;
    hrt::DeviceSample t;
    ASSERT_TRUE(read_until(dev, sent, t)) << what;
    EXPECT_DOUBLE_EQ(t.pose.position.x(), 0.5) << what;
    EXPECT_EQ(dev.counters().*counter, before + 1) << what;
    EXPECT_EQ(dev.counters().accepted, 1u) << what;
  };
  std::mt19937 rng(3);
  Bytes garbage(88);
  for (auto& x : garbage) x = static_cast<uint8_t>(rng());
  expect_dropped(garbage, &hrt::UdpCounters::bad_magic, "garbage");
  expect_dropped(Bytes(10, 0x48), &hrt::UdpCounters::bad_size, "short");
  expect_dropped(Bytes(), &hrt::UdpCounters::bad_size, "empty");
  Bytes b = encode(pose_msg(51, 0.9));
  b[4] = 2;
  expect_dropped(b, &hrt::UdpCounters::bad_version, "wrong version");
  b = encode(pose_msg(51, 0.9));
  b[6] = 3;
  expect_dropped(b, &hrt::UdpCounters::bad_type, "object poses sent to the device");
  b = encode(pose_msg(51, 0.9));
  put_f64(&b[32], NAN);
  expect_dropped(b, &hrt::UdpCounters::non_finite, "NaN y");
  b = encode(pose_msg(51, 0.9));
  put_f64(&b[72], INFINITY);
  expect_dropped(b, &hrt::UdpCounters::non_finite, "infinite qw");
  b = encode(pose_msg(51, 0.9));
  for (size_t off = 48; off < 80; off += 8) put_f64(&b[off], 0.0);
  expect_dropped(b, &hrt::UdpCounters::non_finite, "zero quaternion");
  expect_dropped(encode(pose_msg(49, 0.9)), &hrt::UdpCounters::out_of_order, "late");
  expect_dropped(encode(pose_msg(50, 0.9)), &hrt::UdpCounters::out_of_order, "duplicate");
  b = encode(pose_msg(51, 0.9));
  b.push_back(0);
  expect_dropped(b, &hrt::UdpCounters::bad_size, "one byte long");

  // Still working: a newer packet, then a restart flag with a low sequence.
  c.send_to(dev.bound_port(), encode(pose_msg(51, 0.6)));
  ASSERT_TRUE(read_until(dev, ++sent, s));
  EXPECT_DOUBLE_EQ(s.pose.position.x(), 0.6);
  c.send_to(dev.bound_port(), encode(pose_msg(0, 0.7, udp::kFlagRestart)));
  ASSERT_TRUE(read_until(dev, ++sent, s));
  EXPECT_DOUBLE_EQ(s.pose.position.x(), 0.7);
  const hrt::UdpCounters k = dev.counters();
  EXPECT_EQ(k.received, sent);
  EXPECT_EQ(k.accepted, 3u);
  EXPECT_EQ(k.bad_size + k.bad_magic + k.bad_version + k.bad_type + k.non_finite + k.out_of_order + k.accepted,
            k.received);
}

// Wrenches go to reply_address:reply_port when one is set.
TEST(UdpDevice, RepliesGoToTheConfiguredAddress) {
  Client listener;
  hrt::UdpOptions o = any_port();
  o.reply_address = "127.0.0.1";
  o.reply_port = listener.port;
  hrt::UdpDevice dev(o, hrt::DeviceInfo{});
  dev.open();
  dev.write(0.25, hrt::Vec6::Constant(0.5));  // before any pose: the reply address is known anyway
  const Bytes r = listener.receive();
  udp::WrenchMessage m;
  ASSERT_EQ(udp::parse_wrench(r.data(), r.size(), m), udp::Result::ok);
  EXPECT_EQ(m.force[2], 0.5);
  EXPECT_EQ(m.answers, 0u);
}

// Object poses reach the display at display_rate_hz (the simulation calls at
// 1 kHz for 1 s: 10 packets at 10 Hz, each carrying every object).
TEST(UdpDevice, PublishesObjectPosesAtTheDisplayRate) {
  Client display;
  hrt::UdpOptions o = any_port();
  o.display_port = display.port;
  o.display_rate_hz = 10.0;
  hrt::UdpDevice dev(o, hrt::DeviceInfo{});
  dev.open();
  hrt::Pose poses[3];
  for (int i = 0; i < 1000; ++i) {
    const double t = i * 1e-3;
    poses[2].position = hrt::Vec3(t, 0, 0);
    dev.publish_poses(t, poses, 3);
  }
  EXPECT_EQ(dev.counters().sent_display, 10u);
  int packets = 0;
  double last_t = -1;
  while (true) {
    const Bytes b = display.receive(100);
    if (b.empty()) break;
    udp::ObjectPosesMessage m;
    udp::ObjectPose objs[3];
    ASSERT_EQ(udp::parse_object_poses(b.data(), b.size(), m, objs, 3), udp::Result::ok);
    ASSERT_EQ(m.count, 3u);
    EXPECT_EQ(m.total, 3u);
    EXPECT_EQ(objs[2].index, 2u);
    EXPECT_DOUBLE_EQ(objs[2].position[0], m.header.timestamp);
    EXPECT_NEAR(m.header.timestamp, 0.1 * packets, 1.5e-3);  // due times are whole periods, the calls 1 ms apart
    EXPECT_GT(m.header.timestamp, last_t);
    last_t = m.header.timestamp;
    ++packets;
  }
  EXPECT_EQ(packets, 10);

  // More objects than fit a packet: one frame spans two packets.
  std::vector<hrt::Pose> many(1500);
  dev.publish_poses(5.0, many.data(), static_cast<int>(many.size()));
  const Bytes a = display.receive(), b = display.receive();
  EXPECT_EQ(a.size(), udp::kObjectPosesHeaderSize + 1000 * udp::kObjectPoseSize);
  EXPECT_EQ(b.size(), udp::kObjectPosesHeaderSize + 500 * udp::kObjectPoseSize);
  std::vector<udp::ObjectPose> got(1000);
  udp::ObjectPosesMessage m;
  ASSERT_EQ(udp::parse_object_poses(b.data(), b.size(), m, got.data(), got.size()), udp::Result::ok);
  EXPECT_EQ(m.total, 1500u);
  EXPECT_EQ(got[0].index, 1000u);
}
