// libFuzzer target of the UDP bridge's packet parser (hrt/udp_protocol.h,
// docs/udp-protocol.md). One input is one datagram.
//
// The input goes to every parser (header, pose, wrench, object poses with a
// full-size and a 4-object array). Besides ASan/UBSan (a read past the
// datagram is a heap-buffer-overflow: libFuzzer's input buffer has exactly
// `size` bytes), the target checks the parser's contract and aborts on:
//   - a result outside the enum, or ok from two typed parsers at once;
//   - an accepted packet with a non-finite double or a zero quaternion;
//   - an accepted packet that does not re-encode to the same bytes (with the
//     reserved bytes zeroed and the clutch byte as 0/1: the encoder's only
//     freedoms), or whose re-encoding parses differently;
//   - the order filter breaking its rules over the input read as a stream of
//     (sequence, flags, source) records: an accepted packet becomes the last;
//     a rejected one changes nothing and was not later than the last.
// Findings are saved by libFuzzer (runtime/fuzz/README.md, "UDP packets").
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "hrt/udp_protocol.h"

namespace udp = hrt::udp;

namespace {

[[noreturn]] void fail(const char* what) {
  std::fprintf(stderr, "fuzz_udp: %s\n", what);
  std::abort();
}

bool finite_all(const double* v, int n) {
  for (int i = 0; i < n; ++i)
    if (!std::isfinite(v[i])) return false;
  return true;
}

bool nonzero(const double* q) { return q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3] >= 1e-12; }

bool valid(udp::Result r) { return r >= udp::Result::ok && r <= udp::Result::buffer_too_small; }

// `expect` = the input with the bytes the encoder normalizes set as it writes them.
void check_same(const uint8_t* encoded, size_t n, const std::vector<uint8_t>& expect) {
  if (n != expect.size() || std::memcmp(encoded, expect.data(), n) != 0) fail("re-encoding differs from the input");
}

std::vector<uint8_t> normalized_header(const uint8_t* data, size_t size) {
  std::vector<uint8_t> v(data, data + size);
  std::memset(&v[12], 0, 4);
  return v;
}

bool same_header(const udp::Header& a, const udp::Header& b) {
  return a.type == b.type && a.flags == b.flags && a.sequence == b.sequence &&
         std::memcmp(&a.timestamp, &b.timestamp, sizeof(double)) == 0;
}

udp::ObjectPose g_objects[udp::kMaxObjectsPerPacket];
udp::ObjectPose g_objects2[udp::kMaxObjectsPerPacket];
uint8_t g_out[udp::kMaxPacketSize];

void check_pose(const uint8_t* data, size_t size) {
  udp::PoseMessage m;
  if (udp::parse_pose(data, size, m) != udp::Result::ok) return;
  if (size != udp::kPoseSize) fail("pose accepted at a wrong size");
  if (!finite_all(m.position, 3) || !finite_all(m.quaternion, 4) || !std::isfinite(m.header.timestamp))
    fail("pose accepted with a non-finite value");
  if (!nonzero(m.quaternion)) fail("pose accepted with a zero quaternion");
  size_t n = 0;
  if (udp::encode_pose(m, g_out, sizeof g_out, n) != udp::Result::ok) fail("accepted pose does not encode");
  std::vector<uint8_t> expect = normalized_header(data, size);
  expect[84] = data[84] ? 1 : 0;
  expect[85] = expect[86] = expect[87] = 0;
  check_same(g_out, n, expect);
  udp::PoseMessage again;
  if (udp::parse_pose(g_out, n, again) != udp::Result::ok || !same_header(m.header, again.header) ||
      std::memcmp(m.position, again.position, sizeof m.position) != 0 ||
      std::memcmp(m.quaternion, again.quaternion, sizeof m.quaternion) != 0 || m.buttons != again.buttons ||
      m.clutch != again.clutch)
    fail("pose round trip differs");
}

void check_wrench(const uint8_t* data, size_t size) {
  udp::WrenchMessage m;
  if (udp::parse_wrench(data, size, m) != udp::Result::ok) return;
  if (size != udp::kWrenchSize) fail("wrench accepted at a wrong size");
  if (!finite_all(m.force, 3) || !finite_all(m.torque, 3)) fail("wrench accepted with a non-finite value");
  size_t n = 0;
  if (udp::encode_wrench(m, g_out, sizeof g_out, n) != udp::Result::ok) fail("accepted wrench does not encode");
  std::vector<uint8_t> expect = normalized_header(data, size);
  std::memset(&expect[28], 0, 4);
  check_same(g_out, n, expect);
  udp::WrenchMessage again;
  if (udp::parse_wrench(g_out, n, again) != udp::Result::ok || !same_header(m.header, again.header) ||
      m.answers != again.answers || std::memcmp(m.force, again.force, sizeof m.force) != 0 ||
      std::memcmp(m.torque, again.torque, sizeof m.torque) != 0)
    fail("wrench round trip differs");
}

void check_objects(const uint8_t* data, size_t size) {
  udp::ObjectPosesMessage m;
  const udp::Result r = udp::parse_object_poses(data, size, m, g_objects, udp::kMaxObjectsPerPacket);
  // A small array: the same verdict, except buffer_too_small when more objects came.
  udp::ObjectPosesMessage small;
  const udp::Result rs = udp::parse_object_poses(data, size, small, g_objects2, 4);
  if (!valid(rs)) fail("object poses: result out of range (small array)");
  if (r == udp::Result::ok && m.count > 4 && rs != udp::Result::buffer_too_small) fail("small array overfilled");
  if (r == udp::Result::ok && m.count <= 4 && rs != udp::Result::ok) fail("small array refused a small packet");
  if (r != udp::Result::ok) return;
  if (m.count > udp::kMaxObjectsPerPacket) fail("object count above the maximum accepted");
  if (size != udp::kObjectPosesHeaderSize + udp::kObjectPoseSize * m.count)
    fail("object poses accepted at a wrong size");
  for (uint32_t k = 0; k < m.count; ++k) {
    const udp::ObjectPose& o = g_objects[k];
    if (o.index >= m.total) fail("object index not below total accepted");
    if (!finite_all(o.position, 3) || !finite_all(o.quaternion, 4) || !nonzero(o.quaternion))
      fail("object pose accepted with a non-finite value or a zero quaternion");
  }
  size_t n = 0;
  if (udp::encode_object_poses(m, g_objects, g_out, sizeof g_out, n) != udp::Result::ok)
    fail("accepted object poses do not encode");
  std::vector<uint8_t> expect = normalized_header(data, size);
  for (uint32_t k = 0; k < m.count; ++k)
    std::memset(&expect[udp::kObjectPosesHeaderSize + udp::kObjectPoseSize * k + 4], 0, 4);
  check_same(g_out, n, expect);
}

void check_filter(const uint8_t* data, size_t size) {
  udp::SequenceFilter f;
  // Records of 6 bytes: sequence (4), flags (1), source (1).
  for (size_t off = 0; off + 6 <= size; off += 6) {
    uint32_t seq;
    std::memcpy(&seq, data + off, 4);
    const uint8_t flags = data[off + 4];
    const uint64_t source = data[off + 5] & 3;
    const bool started = f.started();
    const uint32_t last = f.last();
    const uint64_t streams = f.streams();
    if (f.accept(seq, flags, source)) {
      if (f.last() != seq) fail("filter: an accepted packet is not the last");
      if (started && f.streams() == streams && !udp::sequence_after(seq, last)) fail("filter: accepted a late packet");
    } else {
      if (!started) fail("filter: refused the first packet");
      if (flags & udp::kFlagRestart) fail("filter: refused a restart");
      if (f.last() != last || f.streams() != streams) fail("filter: a refused packet changed the state");
      if (udp::sequence_after(seq, last)) fail("filter: refused a later packet");
    }
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  udp::Header h;
  const udp::Result rh = udp::parse_header(data, size, h);
  udp::PoseMessage p;
  udp::WrenchMessage w;
  udp::ObjectPosesMessage o;
  const udp::Result rp = udp::parse_pose(data, size, p);
  const udp::Result rw = udp::parse_wrench(data, size, w);
  const udp::Result ro = udp::parse_object_poses(data, size, o, g_objects, udp::kMaxObjectsPerPacket);
  if (!valid(rh) || !valid(rp) || !valid(rw) || !valid(ro)) fail("result out of range");
  if ((rp == udp::Result::ok) + (rw == udp::Result::ok) + (ro == udp::Result::ok) > 1) fail("two types accepted");
  if ((rp == udp::Result::ok || rw == udp::Result::ok || ro == udp::Result::ok) && rh != udp::Result::ok)
    fail("a typed parser accepted what the header parser refused");
  check_pose(data, size);
  check_wrench(data, size);
  check_objects(data, size);
  check_filter(data, size);
  return 0;
}
